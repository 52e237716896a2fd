"""Fly a plan in PX4 offboard mode: every vehicle streams its own trajectory, all in step.

:func:`fly_offboard` flies the phases of :func:`mavlink.flight.fly` (docs/architecture.md,
"Frames and units" and "From a scenario file to UDP bytes") with an :class:`OffboardDriver`,
which supplies what is particular to offboard:

1. each vehicle's trajectory is transformed from the mission ENU frame into its own local
   NED frame and sampled into setpoints (:func:`~mavlink.plan_setpoints.plan_setpoints_ned`);
   its start is the first setpoint;
2. onto the starts: the start setpoint is streamed for ``prestream_s`` (>= 1 s), every
   vehicle is switched to offboard (a denial is retried while the stream goes on) and must
   report OFFBOARD; PX4 holds the streamed start until every vehicle has passed the arrival
   gate;
3. from one shared start time, position + velocity + acceleration + yaw setpoints are
   streamed at ``rate_hz`` against absolute deadlines (:mod:`mavlink.offboard.stream`),
   while the safety monitor watches the links and the spec's always-clauses along the
   vehicles' plans;
4. the final setpoint is held for ``hold_after_s``, then every vehicle holds, lands or
   returns as asked; the :class:`~mavlink.flight.FlightResult` has the stream's statistics
   per vehicle and the flown tracks in the mission frame.

Setpoints go through MAVSDK's Offboard plugin
(``set_position_velocity_acceleration_ned``: SET_POSITION_TARGET_LOCAL_NED,
frame LOCAL_NED, yaw rate ignored), called directly on the event loop; it
does not block (it packs and queues one UDP datagram).

The flight's settings (:class:`~mavlink.offboard.setpoints.OffboardConfig`) and the
sampling of a plan into setpoints are in :mod:`mavlink.offboard.setpoints`; the phases it
shares with the mission flight (checks, take-off, release, monitor, tracks) are in
:mod:`mavlink.flight`.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d as pm
from mavsdk.plugins.offboard import OffboardResult

from mavlink.errors import CommandError, PreflightError, StreamError
from mavlink.flight import DriverReport, FlightResult, StartGate, StartPoint, fly, start_point
from mavlink.link.fleet import Fleet
from mavlink.link.mavsdk_glue import mavsdk_call
from mavlink.link.vehicle import Vehicle
from mavlink.link.vehicle_status import VehicleStatus
from mavlink.monitor import SafetyMonitor
from mavlink.monitor_findings import SafetyEvent
from mavlink.offboard.setpoints import (
    EndAction,
    OffboardConfig,
    offboard_sender,
)
from mavlink.offboard.stream import (
    SetpointStreamer,
    StreamStats,
    StreamTarget,
    auto_send_groups,
    send_offsets,
)
from mavlink.plan_setpoints import NedSetpoints, plan_setpoints_ned
from mavlink.preflight import wait_settled
from mavlink.px4_modes import Px4Mode
from mavlink.tlog import TlogRecorder
from mavlink.tracks import write_tracks_csv
from planner.frames import GeodeticPoint
from planner.trajectory import Trajectory

__all__ = ["FlightResult", "OffboardDriver", "end_action_of", "fly_offboard"]

#: A vehicle sent to a landing point lands once this close to it (m) and nearly still.
LAND_AT_M = 0.3


async def _start_offboard(v: Vehicle, retries: int = 3, retry_after_s: float = 0.5) -> None:
    # PX4 denies the switch until it has seen the setpoint stream for long enough by
    # its own clock; a denial right at the end of the pre-stream is retried while the
    # stream goes on.
    for _ in range(retries):
        result = await mavsdk_call(v.offboard.start_async)
        if result != OffboardResult.COMMAND_DENIED:
            break
        await v.clock.sleep(retry_after_s)  # the vehicle's time: PX4 counts on its own
    if result != OffboardResult.SUCCESS:
        raise CommandError(
            f"offboard start failed: {result.name}", result=result.name, vehicle=v.name, url=v.url
        )


async def _stop_offboard(v: Vehicle) -> None:
    # MAVSDK stops re-sending the last setpoint and commands Hold.
    result = await mavsdk_call(v.offboard.stop_async)
    if result != OffboardResult.SUCCESS:
        raise CommandError(
            f"offboard stop failed: {result.name}", result=result.name, vehicle=v.name, url=v.url
        )


async def end_action_of(v: Vehicle, action: EndAction, cfg: OffboardConfig | None = None) -> None:
    """Leave offboard into ``action`` (hold, land, return) at the end of the stream; with
    ``cfg.land_at`` a vehicle lands at its landing point, flown to first."""
    # Hold first, while MAVSDK still re-sends the last setpoint, and only then stop the
    # setpoints: stopping first leaves the vehicle without setpoints until the Hold command
    # arrives, and on a lossy or busy link that can outlast COM_OF_LOSS_T, so PX4's own
    # offboard-loss failsafe (COM_OBL_RC_ACT: possibly Land or RTL) would decide the end
    try:
        await v.hold()
    finally:
        await _stop_offboard(v)
    at = cfg.land_at.get(v.name) if cfg is not None else None
    if action is EndAction.LAND and at is not None and cfg is not None:
        # not straight down: to the landing point first, at the altitude given, then land
        lat, lon, alt = at
        st = v.status()
        away = 0.0
        if st.position is not None:
            n, e, _ = pm.geodetic2ned(lat, lon, alt, st.position.lat_deg, st.position.lon_deg, st.position.alt_m)  # fmt: skip
            away = math.hypot(n, e)
        await v.goto(lat, lon, alt, math.nan)

        def there(s: VehicleStatus) -> bool:
            if s.position is None:
                return False
            n, e, _ = pm.geodetic2ned(lat, lon, alt, s.position.lat_deg, s.position.lon_deg, s.position.alt_m)  # fmt: skip
            speed = math.inf if s.vel_ned_m_s is None else float(np.linalg.norm(s.vel_ned_m_s[:2]))  # fmt: skip
            return math.hypot(n, e) < LAND_AT_M and speed < 0.3

        await v.wait_for(there, "the landing point", timeout_s=cfg.land_goto_timeout_s + away)
        await v.land()
    elif action is EndAction.LAND:
        await v.land()
    elif action is EndAction.RETURN:
        await v.return_to_launch()


class OffboardDriver:
    """Offboard mode for :func:`mavlink.flight.fly` (the module docstring).

    Args:
        trajectories: mission-frame (ENU) trajectory per vehicle name, in plan order.
        mission_origin: geodetic origin of the mission frame.
        config: the flight's settings.
    """

    expected_mode = Px4Mode.OFFBOARD
    mode_grace_s = 0.5
    on_board = False

    def __init__(
        self,
        trajectories: Mapping[str, Trajectory],
        mission_origin: GeodeticPoint,
        config: OffboardConfig,
    ) -> None:
        self.names: Sequence[str] = list(trajectories)
        self.trajectories = trajectories
        self.plans: Mapping[str, Trajectory] | None = trajectories  # the monitor's
        self.mission_origin = mission_origin
        self.cfg = config
        self.gate: StartGate = config
        n = len(self.names)
        groups = auto_send_groups(n) if config.send_groups is None else config.send_groups
        self.groups = min(groups, n) if n else 1
        self.setpoints: dict[str, NedSetpoints] = {}
        self._offsets: dict[str, float] = {}
        self._origins: dict[str, GeodeticPoint] = {}
        self._main: SetpointStreamer | None = None
        self._hover: asyncio.Task[Any] | None = None
        self._hover_stop = asyncio.Event()
        self._stats: dict[str, StreamStats] = {}
        #: vehicles that left the flight (:meth:`drop`)
        self.dropped: set[str] = set()

    def starts(self, origins: Mapping[str, GeodeticPoint]) -> dict[str, StartPoint]:
        cfg = self.cfg
        offsets = send_offsets(len(self.names), cfg.rate_hz, self.groups)
        for i, name in enumerate(self.names):
            self._offsets[name] = float(offsets[i])
            self._origins[name] = origins[name]
            self.setpoints[name] = self._setpoints_of(name, self.trajectories[name])
        return {
            name: start_point(
                self.trajectories[name].position(0.0),
                math.degrees(float(self.setpoints[name].yaw_ned_rad[0])),
                self.mission_origin,
                origins[name],
            )
            for name in self.names
        }

    def _setpoints_of(self, name: str, trajectory: Trajectory) -> NedSetpoints:
        cfg = self.cfg
        return plan_setpoints_ned(
            trajectory,
            cfg.rate_hz,
            self.mission_origin,
            self._origins[name],
            t_offset_s=self._offsets[name],
            drag_per_s=cfg.drag_of(name),
        )

    def drop(self, names: Sequence[str]) -> None:
        """Stream nothing more to ``names`` (they left the flight); no end action for them."""
        for name in names:
            self.dropped.add(name)
            if self._main is not None:
                self._main.drop(name)

    def switch(self, trajectories: Mapping[str, Trajectory], switch_s: float) -> None:
        """Stream ``trajectories`` from the next setpoint on (a replan: each equals the
        trajectory it replaces up to ``switch_s``, so the vehicles see one stream)."""
        assert self._main is not None
        k = self._main.next_tick
        if k > switch_s * self.cfg.rate_hz + 1e-6:
            raise StreamError(f"the switch at t = {switch_s:g} s came after setpoint {k}")
        plans = dict(self.trajectories)
        for name, tr in trajectories.items():
            if name in self.dropped:  # left the flight while the plan was made
                continue
            self._main.splice(name, self._setpoints_of(name, tr), k)
            plans[name] = tr
        self.trajectories = plans
        self.plans = plans

    async def prepare(self, fleet: Fleet, vehicles: Sequence[Vehicle]) -> None:
        return None

    async def approach(
        self, fleet: Fleet, vehicles: Sequence[Vehicle], starts: Mapping[str, StartPoint]
    ) -> None:
        """Pre-stream the start setpoint, switch everyone to offboard, wait at the starts."""
        cfg, clock = self.cfg, fleet.clock
        n_pre = math.ceil(
            (cfg.prestream_s + cfg.mode_timeout_s + cfg.arrive_timeout_s + cfg.dwell_s + 2.0)
            * cfg.rate_hz
        )
        hover = SetpointStreamer(
            [
                StreamTarget(
                    v.name, offboard_sender(v.offboard), self.setpoints[v.name].constant(0, n_pre)
                )
                for v in vehicles
            ],
            cfg.rate_hz,
            clock=clock.monotonic,
            sleep=clock.sleep,
        )
        self._hover = asyncio.create_task(hover.run(clock.monotonic(), stop=self._hover_stop))
        await clock.sleep(cfg.prestream_s)
        failures = await fleet.for_each(_start_offboard, vehicles)
        if failures:
            name, exc = next(iter(failures.items()))
            raise PreflightError(
                f"did not switch to offboard: {exc}", vehicle=name, url=fleet[name].url
            )
        await asyncio.gather(
            *(
                v.wait_for(
                    lambda s: s.mode is Px4Mode.OFFBOARD,
                    "mode OFFBOARD",
                    timeout_s=cfg.mode_timeout_s,
                )
                for v in vehicles
            )
        )
        # The arrival gate: PX4 holds the streamed start in offboard; the plan starts once
        # every vehicle is on it (a fraction of the plan's margin), still and on heading.
        await asyncio.gather(
            *(
                wait_settled(
                    v,
                    starts[v.name].ned_m,
                    arrive_m=cfg.arrive_m,
                    settle_speed_m_s=cfg.settle_speed_m_s,
                    dwell_s=cfg.dwell_s,
                    timeout_s=cfg.arrive_timeout_s,
                    yaw_deg=starts[v.name].yaw_deg,
                    yaw_tolerance_deg=cfg.yaw_tolerance_deg,
                )
                for v in vehicles
            )
        )

    async def release(self, fleet: Fleet, vehicles: Sequence[Vehicle]) -> float:
        """One shared start; the hover stream runs until just before it."""
        cfg, clock = self.cfg, fleet.clock
        t0 = clock.monotonic() + cfg.start_delay_s
        self._main = SetpointStreamer(
            [
                StreamTarget(v.name, offboard_sender(v.offboard), self.setpoints[v.name])
                for v in vehicles
            ],
            cfg.rate_hz,
            late_threshold_s=cfg.late_threshold_s,
            groups=self.groups,
            clock=clock.monotonic,
            sleep=clock.sleep,
        )
        await clock.sleep(t0 - clock.monotonic() - 0.5 / cfg.rate_hz)
        failed = await self._end_hover()
        if failed is not None:
            raise failed
        return t0

    async def _end_hover(self) -> BaseException | None:
        if self._hover is None:
            return None
        task, self._hover = self._hover, None
        return await _end_task(task, self._hover_stop)

    async def abort(self) -> None:
        await self._end_hover()

    def done(self, name: str) -> bool:
        return False

    async def run(
        self, fleet: Fleet, vehicles: Sequence[Vehicle], t0: float, stop: asyncio.Event
    ) -> None:
        assert self._main is not None
        extra = round(self.cfg.hold_after_s * self.cfg.rate_hz)
        self._stats = await self._main.run(t0, stop=stop, extra_ticks=extra)

    async def finish(
        self, fleet: Fleet, vehicles: Sequence[Vehicle], t0: float, event: SafetyEvent | None
    ) -> DriverReport:
        """The end action, unless the monitor stopped the flight (it held every vehicle)."""
        end_failures: dict[str, str] = {}
        flying = [v for v in vehicles if v.name not in self.dropped]
        if event is None:
            cfg = self.cfg
            failed = await fleet.for_each(lambda v: end_action_of(v, cfg.end_action, cfg), flying)
            end_failures = {k: str(e) for k, e in failed.items()}
        assert self._main is not None
        stats = dict(self._stats)
        flown = all(
            s.sent + s.skipped >= self._main.n_ticks
            for name, s in stats.items()
            if name not in self.dropped
        )
        return DriverReport(completed=flown, end_failures=end_failures, stats=stats)


async def fly_offboard(
    fleet: Fleet,
    trajectories: Mapping[str, Trajectory],
    mission_origin: GeodeticPoint,
    config: OffboardConfig | None = None,
    *,
    monitor: SafetyMonitor | None = None,
    tlog_path: str | Path | None = None,
    csv_path: str | Path | None = None,
) -> FlightResult:
    """Fly each vehicle's trajectory in offboard mode, all from one shared start time.

    Args:
        fleet: a connected :class:`Fleet`; every name in ``trajectories`` must be in it.
        trajectories: mission-frame (ENU) trajectory per vehicle name.
        mission_origin: geodetic origin of the mission frame.
        config: :class:`OffboardConfig` (defaults: 20 Hz, 1 s pre-stream, 1 m tolerance).
        monitor: safety monitor to run during the stream (default: one that
            only watches the links and holds every vehicle if one is lost).
        tlog_path: record everything the vehicles send, from before the
            preflight checks to the end action, to this ``.tlog``.
        csv_path: write the flown tracks (mission frame) to this CSV.

    Returns:
        A :class:`FlightResult`. A safety stop is a result (``completed``
        false, ``safety_event`` set), not an exception.

    Raises:
        PreflightError: a vehicle is too far from its start, cannot reach it
            or does not switch to offboard (nothing was streamed).
        LinkError: a vehicle is unknown, its origin unknown or its link lost
            before the stream starts.
    """
    cfg = config or OffboardConfig()
    recorder = TlogRecorder(fleet, tlog_path) if tlog_path is not None else None
    if recorder is not None:
        recorder.start()
    try:
        driver = OffboardDriver(trajectories, mission_origin, cfg)
        result = await fly(fleet, driver, mission_origin, monitor)
    finally:
        stats = recorder.stop() if recorder is not None else None
    if csv_path is not None:
        write_tracks_csv(csv_path, result.tracks)
    return dataclasses.replace(result, tlog=stats)


async def _end_task(task: asyncio.Task[Any], stop: asyncio.Event) -> BaseException | None:
    """End a stream task: ask it to stop (it finishes its tick) and wait; if the caller is
    being cancelled, cancel it outright. Idempotent; returns what the task raised, if it did."""
    stop.set()
    current = asyncio.current_task()
    if current is not None and current.cancelling():
        task.cancel()
    outcome: Any = (await asyncio.gather(task, return_exceptions=True))[0]
    return outcome if isinstance(outcome, BaseException) else None
