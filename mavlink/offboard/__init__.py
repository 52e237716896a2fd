"""Fly a plan in PX4 offboard mode: every vehicle streams its own trajectory, all in step.

:func:`fly_offboard` does, in order (docs/architecture.md, "Frames and units" and "From a scenario file to UDP bytes"):

1. learns each vehicle's EKF origin (GPS_GLOBAL_ORIGIN) and transforms the
   vehicle's trajectory from the mission ENU frame into its own local NED
   frame (:func:`~mavlink.plan_setpoints.plan_setpoints_ned`);
2. refuses the flight, before anything is armed, if a vehicle is farther
   than ``start_tolerance_m`` from its planned start (horizontally while it
   is on the ground, in 3-D if it is in the air) (:class:`PreflightError`);
3. takes off to the plan's start altitude (or checks the vehicle already
   hovers at its start) and waits until each vehicle is within the
   tolerance of its start;
4. streams the start setpoint for ``prestream_s`` (>= 1 s), switches all
   vehicles to offboard and waits until every one reports OFFBOARD;
5. picks one shared start time and streams position + velocity +
   acceleration + yaw setpoints at ``rate_hz`` against absolute deadlines
   (:mod:`mavlink.offboard.stream`), while a :class:`~mavlink.monitor.SafetyMonitor`
   watches the links and the spec's always-clauses;
6. holds the final setpoint for ``hold_after_s`` and then holds, lands or
   returns as asked, and returns a :class:`FlightResult` with per-vehicle
   stream statistics and the flown tracks in the mission frame.

Setpoints go through MAVSDK's Offboard plugin
(``set_position_velocity_acceleration_ned``: SET_POSITION_TARGET_LOCAL_NED,
frame LOCAL_NED, yaw rate ignored), called directly on the event loop; it
does not block (it packs and queues one UDP datagram).

The flight's settings (:class:`~mavlink.offboard.setpoints.OffboardConfig`) and the
sampling of a plan into setpoints are in :mod:`mavlink.offboard.setpoints`; the start
checks it shares with the mission flight (distance to the start, take-off height, the
arrival gate) are in :mod:`mavlink.preflight`. This module runs the flight.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d as pm
from mavsdk.plugins.offboard import OffboardResult

from mavlink.errors import CommandError, LinkError, LinkLostError, PreflightError
from mavlink.link.fleet import Fleet
from mavlink.link.mavsdk_glue import mavsdk_call
from mavlink.link.vehicle import Vehicle
from mavlink.link.vehicle_status import VehicleStatus
from mavlink.monitor import SafetyMonitor, safe_stop
from mavlink.monitor_findings import MonitorStats, SafetyAction, SafetyEvent
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
from mavlink.plan_setpoints import plan_setpoints_ned
from mavlink.preflight import check_start, check_takeoff_height, wait_settled
from mavlink.px4_modes import Px4Mode
from mavlink.tlog import TlogRecorder, TlogStats
from mavlink.tracks import FlownTrack, track_from_rows, write_tracks_csv
from planner.frames import GeodeticPoint, enu_to_geodetic
from planner.trajectory import Trajectory

#: A vehicle sent to a landing point lands once this close to it (m) and nearly still.
LAND_AT_M = 0.3


@dataclass(frozen=True, slots=True, eq=False)
class FlightResult:
    """The outcome of :func:`fly_offboard`.

    Attributes:
        completed: every setpoint was streamed and no safety stop happened.
        t0_monotonic_s: the shared start on the fleet's clock (:mod:`mavlink.clock`).
        t0_unix_s: the same instant as Unix time (to align a ``.tlog``).
        stats: stream statistics per vehicle (the main stream only).
        tracks: flown tracks per vehicle, in the mission frame.
        safety_event: what stopped the flight, if the monitor did.
        end_failures: vehicles whose end action failed, with the reason.
        origins: each vehicle's EKF origin used for the transform.
        tlog: what the ``.tlog`` recording holds, if one was asked for.
        monitor: what the safety monitor did (evaluations, their cost, vehicles checked
            on their prediction while their telemetry was late).
    """

    completed: bool
    t0_monotonic_s: float
    t0_unix_s: float
    stats: dict[str, StreamStats]
    tracks: dict[str, FlownTrack]
    safety_event: SafetyEvent | None
    end_failures: dict[str, str] = field(default_factory=dict)
    origins: dict[str, GeodeticPoint] = field(default_factory=dict)
    tlog: TlogStats | None = None
    monitor: MonitorStats | None = None


# --------------------------------------------------------------------------
# Take-off
# --------------------------------------------------------------------------


def _is_hovering(st: VehicleStatus, settle_speed_m_s: float) -> bool:
    return bool(
        st.armed
        and st.in_air
        and st.mode in (Px4Mode.AUTO_LOITER, Px4Mode.POSCTL, Px4Mode.OFFBOARD)
        and st.vel_ned_m_s is not None
        and float(np.linalg.norm(st.vel_ned_m_s)) < settle_speed_m_s
    )


async def _takeoff_to_start(
    v: Vehicle,
    start_ned_m: np.ndarray,
    start_alt_amsl_m: float,
    yaw_deg: float,
    cfg: OffboardConfig,
    mission_origin: GeodeticPoint,
    vehicle_origin: GeodeticPoint,
) -> None:
    """Arm, take off to the start's altitude on the plan's heading, and wait until airborne
    (EXTENDED_SYS_STATE in air) near the start altitude and hovering."""
    await v.arm()
    await v.takeoff_to(start_alt_amsl_m, yaw_deg)

    def airborne(s: VehicleStatus) -> bool:
        return (
            s.pos_ned_m is not None
            and bool(s.in_air)
            and abs(float(s.pos_ned_m[2]) - float(start_ned_m[2])) <= cfg.start_tolerance_m
            and _is_hovering(s, cfg.settle_speed_m_s)
        )

    try:
        await v.wait_for(
            airborne, "airborne near the start after takeoff", timeout_s=cfg.takeoff_timeout_s
        )
    except (PreflightError, LinkLostError):
        raise
    except LinkError as exc:
        raise PreflightError(exc.detail, vehicle=v.name, url=v.url) from None
    check_start(
        v.status(),
        start_ned_m,
        tolerance_m=cfg.start_tolerance_m,
        on_ground=False,
        mission_origin=mission_origin,
        vehicle_origin=vehicle_origin,
    )


# --------------------------------------------------------------------------
# The flight
# --------------------------------------------------------------------------


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


async def _end(v: Vehicle, action: EndAction, cfg: OffboardConfig | None = None) -> None:
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
    recorder = TlogRecorder(fleet, tlog_path) if tlog_path is not None else None
    if recorder is not None:
        recorder.start()
    try:
        result = await _fly(
            fleet, trajectories, mission_origin, config or OffboardConfig(), monitor
        )
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


async def _fly(
    fleet: Fleet,
    trajectories: Mapping[str, Trajectory],
    mission_origin: GeodeticPoint,
    cfg: OffboardConfig,
    monitor: SafetyMonitor | None,
) -> FlightResult:
    vehicles = [fleet[name] for name in trajectories]
    clock = fleet.clock
    origins = await fleet.origins()
    groups = auto_send_groups(len(vehicles)) if cfg.send_groups is None else cfg.send_groups
    groups = min(groups, len(vehicles))
    offsets = send_offsets(len(vehicles), cfg.rate_hz, groups)
    setpoints = {
        v.name: plan_setpoints_ned(
            trajectories[v.name],
            cfg.rate_hz,
            mission_origin,
            origins[v.name],
            t_offset_s=float(offsets[i]),
            drag_per_s=cfg.drag_of(v.name),
        )
        for i, v in enumerate(vehicles)
    }
    await asyncio.gather(
        *(
            v.wait_for(
                lambda s: s.pos_ned_m is not None and s.armed is not None and s.in_air is not None,
                "local position",
                timeout_s=5.0,
            )
            for v in vehicles
        )
    )

    # Preflight: check every vehicle before arming any.
    needs_takeoff: list[Vehicle] = []
    for v in vehicles:
        st = v.status()
        start = setpoints[v.name].pos_ned_m[0]
        # In the air (EXTENDED_SYS_STATE): judged in 3-D where it is; on the ground:
        # horizontally, as it will climb straight up to its start.
        airborne = bool(st.armed and st.in_air)
        if not airborne and not cfg.takeoff:
            raise PreflightError(
                "refused: on the ground and takeoff is disabled",
                vehicle=v.name,
                url=v.url,
            )
        check_start(
            st,
            start,
            tolerance_m=cfg.start_tolerance_m,
            on_ground=not airborne,
            mission_origin=mission_origin,
            vehicle_origin=origins[v.name],
        )
        if not airborne:
            needs_takeoff.append(v)
    start_alt: dict[str, float] = {}
    for v in needs_takeoff:
        alt = float(enu_to_geodetic(trajectories[v.name].position(0.0), mission_origin)[2][0])
        await check_takeoff_height(v, alt, cfg.takeoff_margin_m)
        start_alt[v.name] = alt
    yaw0 = {v.name: math.degrees(float(setpoints[v.name].yaw_ned_rad[0])) for v in vehicles}

    # Take off together; every vehicle finishes (or fails) before the first failure is raised.
    results = await asyncio.gather(
        *(
            _takeoff_to_start(
                v,
                setpoints[v.name].pos_ned_m[0],
                start_alt[v.name],
                yaw0[v.name],
                cfg,
                mission_origin,
                origins[v.name],
            )
            for v in needs_takeoff
        ),
        return_exceptions=True,
    )
    errors = [r for r in results if isinstance(r, BaseException)]
    if errors:
        for other in errors[1:]:
            errors[0].add_note(f"also: {other}")
        raise errors[0]

    # Pre-stream the start setpoint, switch everyone to offboard, wait at the starts.
    n_pre = math.ceil(
        (cfg.prestream_s + cfg.mode_timeout_s + cfg.arrive_timeout_s + cfg.dwell_s + 2.0)
        * cfg.rate_hz
    )
    hover = SetpointStreamer(
        [
            StreamTarget(v.name, offboard_sender(v.offboard), setpoints[v.name].constant(0, n_pre))
            for v in vehicles
        ],
        cfg.rate_hz,
        clock=clock.monotonic,
        sleep=clock.sleep,
    )
    hover_stop = asyncio.Event()
    hover_task = asyncio.create_task(hover.run(clock.monotonic(), stop=hover_stop))
    try:
        try:
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
                        setpoints[v.name].pos_ned_m[0],
                        arrive_m=cfg.arrive_m,
                        settle_speed_m_s=cfg.settle_speed_m_s,
                        dwell_s=cfg.dwell_s,
                        timeout_s=cfg.arrive_timeout_s,
                        yaw_deg=yaw0[v.name],
                        yaw_tolerance_deg=cfg.yaw_tolerance_deg,
                    )
                    for v in vehicles
                )
            )
        except Exception as exc:
            await _end_task(hover_task, hover_stop)
            failed = await fleet.for_each(lambda v: safe_stop(v, SafetyAction.HOLD), vehicles)
            for name, err in failed.items():
                exc.add_note(f"vehicle {name}: hold after the failed start also failed: {err}")
            raise

        # One shared start; the hover stream runs until just before it.
        t0 = clock.monotonic() + cfg.start_delay_s
        main = SetpointStreamer(
            [
                StreamTarget(v.name, offboard_sender(v.offboard), setpoints[v.name])
                for v in vehicles
            ],
            cfg.rate_hz,
            late_threshold_s=cfg.late_threshold_s,
            groups=groups,
            clock=clock.monotonic,
            sleep=clock.sleep,
        )
        for v in vehicles:
            v.start_track()
        await clock.sleep(t0 - clock.monotonic() - 0.5 / cfg.rate_hz)
    finally:
        # whatever ends the pre-stream (its end, a failure, a cancellation) ends its task
        failed_stream = await _end_task(hover_task, hover_stop)
    if failed_stream is not None:
        raise failed_stream

    mon = monitor or SafetyMonitor(())
    stop = asyncio.Event()
    mon_task = asyncio.create_task(
        mon.run(
            fleet,
            vehicles,
            t0_monotonic_s=t0,
            mission_origin=mission_origin,
            origins=origins,
            stop=stop,
            plans=trajectories,
            expected_mode=Px4Mode.OFFBOARD,
        )
    )
    extra = round(cfg.hold_after_s * cfg.rate_hz)
    try:
        stats = await main.run(t0, stop=stop, extra_ticks=extra)
    finally:
        stop.set()
        event = await mon_task
    end_failures: dict[str, str] = {}
    if event is None:
        failed = await fleet.for_each(lambda v: _end(v, cfg.end_action, cfg), vehicles)
        end_failures = {k: str(e) for k, e in failed.items()}
    tracks = {
        v.name: track_from_rows(v.name, v.stop_track(), t0, mission_origin, origins[v.name])
        for v in vehicles
    }
    completed = event is None and all(s.sent + s.skipped >= main.n_ticks for s in stats.values())
    return FlightResult(
        completed=completed,
        t0_monotonic_s=t0,
        t0_unix_s=t0 + clock.unix_offset(),
        stats=stats,
        tracks=tracks,
        safety_event=event,
        end_failures=end_failures,
        origins=origins,
        monitor=mon.stats,
    )
