"""Fly a plan in PX4 offboard mode: every vehicle streams its own trajectory, all in step.

:func:`fly_offboard` does, in order (DESIGN.md sections 3 and 7):

1. learns each vehicle's EKF origin (GPS_GLOBAL_ORIGIN) and transforms the
   vehicle's trajectory from the mission ENU frame into its own local NED
   frame (:func:`plan_setpoints_ned`);
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
   (:mod:`mavlink.stream`), while a :class:`~mavlink.monitor.SafetyMonitor`
   watches the links and the spec's always-clauses;
6. holds the final setpoint for ``hold_after_s`` and then holds, lands or
   returns as asked, and returns a :class:`FlightResult` with per-vehicle
   stream statistics and the flown tracks in the mission frame.

Setpoints go through MAVSDK's Offboard plugin
(``set_position_velocity_acceleration_ned``: SET_POSITION_TARGET_LOCAL_NED,
frame LOCAL_NED, yaw rate ignored), called directly on the event loop; it
does not block (it packs and queues one UDP datagram).
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d as pm
from mavsdk.plugins.offboard import (
    AccelerationNed,
    Offboard,
    OffboardResult,
    PositionNedYaw,
    VelocityNedYaw,
)

from mavlink.errors import CommandError, LinkError, LinkLostError, PreflightError
from mavlink.fleet import Fleet, Vehicle, VehicleStatus, mavsdk_call
from mavlink.monitor import MonitorStats, SafetyAction, SafetyEvent, SafetyMonitor, safe_stop
from mavlink.px4_modes import Px4Mode
from mavlink.stream import (
    MAX_RATE_HZ,
    NedSetpoints,
    SetpointStreamer,
    StreamStats,
    StreamTarget,
    auto_send_groups,
    send_offsets,
)
from mavlink.tlog import FlownTrack, TlogRecorder, TlogStats, write_tracks_csv
from planner.frames import (
    GeodeticPoint,
    enu_to_geodetic,
    enu_to_ned,
    enu_vector_to_ned,
    ned_to_enu,
    ned_vector_to_enu,
    yaw_enu_to_ned,
)
from planner.trajectory import Trajectory

#: How far above NAV_MC_ALT_RAD a start must be for a take-off from the ground (m): PX4
#: counts a take-off within NAV_MC_ALT_RAD as reached at once (PX4-BEHAVIOUR.md).
TAKEOFF_MARGIN_M = 0.2
#: A vehicle sent to a landing point lands once this close to it (m) and nearly still.
LAND_AT_M = 0.3


class EndAction(Enum):
    """What every vehicle does after the last setpoint has been held."""

    HOLD = "hold"
    LAND = "land"
    RETURN = "return"


@dataclass(frozen=True, slots=True)
class OffboardConfig:
    """Settings of an offboard flight.

    Attributes:
        rate_hz: setpoint rate, 2 < rate <= 100 (default 20 Hz).
        prestream_s: how long the start setpoint is streamed before the
            switch to offboard (>= 1 s; PX4 needs a live stream; a denied
            switch is retried twice, 0.5 s apart, while the stream goes on).
        start_tolerance_m: refuse a vehicle farther than this from its planned start
            (before anything is armed; horizontally on the ground, in 3-D in the air).
        arrive_m: the arrival gate: the plan starts only when every vehicle (its estimate)
            is this close to its start in 3-D, slower than ``settle_speed_m_s`` and on the
            plan's heading (``yaw_tolerance_deg``), for ``dwell_s`` without a break.
            ``gcs fly`` sets it from the plan's margin.
        dwell_s: how long the arrival gate must hold.
        arrive_timeout_s: time allowed for the gate after the switch to offboard.
        yaw_tolerance_deg: heading error the gate accepts.
        takeoff: take off to the start altitude if a vehicle is on the ground
            (otherwise a vehicle must already hover at its start).
        takeoff_margin_m: a start must be this much more than NAV_MC_ALT_RAD above the
            vehicle for a take-off: PX4 counts a take-off within NAV_MC_ALT_RAD as reached
            at once, and below ~1 m the ground-effect creep of its altitude estimate keeps
            the vehicle on the ground (PX4-BEHAVIOUR.md).
        takeoff_timeout_s: time allowed to be airborne near the start after takeoff.
        drag_per_s: the vehicles' drag per unit mass (1/s; one for all or per vehicle name),
            added to the acceleration feed-forward (:func:`plan_setpoints_ned`); 0: none.
        settle_speed_m_s: a vehicle counts as hovering below this speed.
        mode_timeout_s: time allowed for all vehicles to report OFFBOARD.
        start_delay_s: the shared start time is this long after the switch.
        hold_after_s: keep streaming the final setpoint this long.
        end_action: hold, land or return to launch afterwards.
        land_at: with ``end_action`` LAND, per vehicle name a point ``(lat_deg, lon_deg,
            alt_amsl_m)`` to fly to first (at the altitude given) and land at, where landing
            straight down would not be safe (:mod:`gcs.landing`); others land where they are.
        land_goto_timeout_s: time allowed to reach that point (plus 1 s per metre away);
            a vehicle that does not arrive is left holding, and the end action is reported
            failed for it.
        late_threshold_s: lateness that counts as late (default a quarter period).
        send_groups: spread the vehicles over this many send instants per
            period (:class:`~mavlink.stream.SetpointStreamer`); each vehicle's
            setpoints are sampled at its own send times. ``None``: one group
            per 16 vehicles (measured in ``benchmarks/bench_stream.py``:
            bursts of more vehicles raise the p99 lateness); 1: all at the tick.
    """

    rate_hz: float = 20.0
    prestream_s: float = 1.2
    start_tolerance_m: float = 1.0
    arrive_m: float = 0.3
    dwell_s: float = 1.0
    arrive_timeout_s: float = 20.0
    yaw_tolerance_deg: float = 10.0
    takeoff: bool = True
    takeoff_margin_m: float = TAKEOFF_MARGIN_M
    takeoff_timeout_s: float = 30.0
    drag_per_s: float | Mapping[str, float] = 0.0
    settle_speed_m_s: float = 0.3
    mode_timeout_s: float = 5.0
    start_delay_s: float = 0.3
    hold_after_s: float = 1.0
    end_action: EndAction = EndAction.HOLD
    land_at: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    land_goto_timeout_s: float = 20.0
    late_threshold_s: float | None = None
    send_groups: int | None = None

    def drag_of(self, name: str) -> float:
        """The drag fed forward for vehicle ``name`` (1/s)."""
        if isinstance(self.drag_per_s, Mapping):
            return float(self.drag_per_s.get(name, 0.0))
        return float(self.drag_per_s)

    def __post_init__(self) -> None:
        if self.send_groups is not None and not (
            isinstance(self.send_groups, int) and self.send_groups >= 1
        ):
            raise LinkError(f"send_groups must be an integer >= 1, got {self.send_groups!r}")
        if not (2.0 < self.rate_hz <= MAX_RATE_HZ):
            raise LinkError(f"offboard rate_hz {self.rate_hz!r} outside (2, {MAX_RATE_HZ:g}]")
        if not self.prestream_s >= 1.0:
            raise LinkError(f"prestream_s {self.prestream_s!r} must be >= 1 s (PX4 offboard rule)")
        for name in (
            "start_tolerance_m",
            "arrive_m",
            "arrive_timeout_s",
            "yaw_tolerance_deg",
            "takeoff_timeout_s",
            "mode_timeout_s",
            "settle_speed_m_s",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise LinkError(f"{name} must be a finite number > 0, got {value!r}")
        drags = (
            self.drag_per_s.values() if isinstance(self.drag_per_s, Mapping) else [self.drag_per_s]
        )
        if not all(math.isfinite(c) and c >= 0 for c in drags):
            raise LinkError(f"drag_per_s must be finite numbers >= 0, got {self.drag_per_s!r}")
        for name in ("start_delay_s", "hold_after_s", "dwell_s", "takeoff_margin_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise LinkError(f"{name} must be a finite number >= 0, got {value!r}")


def plan_setpoints_ned(
    trajectory: Trajectory,
    rate_hz: float,
    mission_origin: GeodeticPoint,
    vehicle_origin: GeodeticPoint,
    *,
    t_offset_s: float = 0.0,
    drag_per_s: float | Mapping[str, float] = 0.0,
) -> NedSetpoints:
    """Sample ``trajectory`` at ``rate_hz`` and express it in the vehicle's local NED frame.

    Positions go mission ENU -> geodetic -> vehicle NED; velocity and
    acceleration are rotated between the two tangent planes; yaw becomes a
    NED heading (planner.frames).

    Args:
        t_offset_s: sample at ``k / rate_hz + t_offset_s`` (the vehicle's send
            offset within the period, :func:`mavlink.stream.send_offsets`).
        drag_per_s: the vehicle's linear drag per unit mass ``c`` (1/s). PX4's position
            controller does not model drag, so without help the vehicle settles
            ``c / (MPC_XY_P * MPC_XY_VEL_P_ACC)`` seconds behind a moving setpoint
            (0.585 s on SIH's quad); the acceleration feed-forward then carries the force
            the drag takes: ``a_ff = a_plan + c * v_plan``.

    Returns:
        :class:`NedSetpoints` for ``k = 0 .. ceil(T * rate)`` (the trajectory
        holds its end state past its duration).
    """
    n = math.ceil(trajectory.duration_s * rate_hz - 1e-9) + 1  # as Trajectory.sample
    t = np.arange(n) / rate_hz + t_offset_s
    vel = trajectory.velocity(t)
    acc = trajectory.acceleration(t) + drag_per_s * vel
    return NedSetpoints(
        t_s=t,
        pos_ned_m=enu_to_ned(trajectory.position(t), mission_origin, vehicle_origin),
        vel_ned_m_s=enu_vector_to_ned(vel, mission_origin, vehicle_origin),
        acc_ned_m_s2=enu_vector_to_ned(acc, mission_origin, vehicle_origin),
        yaw_ned_rad=np.asarray(
            yaw_enu_to_ned(trajectory.yaw_rad(t), mission_origin, vehicle_origin), dtype=float
        ),
    )


def offboard_sender(offboard: Offboard) -> Callable[..., None]:
    """A :class:`StreamTarget` sender over MAVSDK's blocking-free setpoint call."""
    set_pva = offboard.set_position_velocity_acceleration_ned

    def send(
        n: float,
        e: float,
        d: float,
        vn: float,
        ve: float,
        vd: float,
        an: float,
        ae: float,
        ad: float,
        yaw_deg: float,
    ) -> None:
        set_pva(
            PositionNedYaw(n, e, d, yaw_deg),
            VelocityNedYaw(vn, ve, vd, yaw_deg),
            AccelerationNed(an, ae, ad),
        )

    return send


@dataclass(frozen=True, slots=True, eq=False)
class FlightResult:
    """The outcome of :func:`fly_offboard`.

    Attributes:
        completed: every setpoint was streamed and no safety stop happened.
        t0_monotonic_s: ``time.monotonic()`` of the shared start.
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
# Preflight
# --------------------------------------------------------------------------


def _vec(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:.2f}" for x in np.ravel(p)) + ")"


def _is_hovering(st: VehicleStatus, settle_speed_m_s: float) -> bool:
    return bool(
        st.armed
        and st.in_air
        and st.mode in (Px4Mode.AUTO_LOITER, Px4Mode.POSCTL, Px4Mode.OFFBOARD)
        and st.vel_ned_m_s is not None
        and float(np.linalg.norm(st.vel_ned_m_s)) < settle_speed_m_s
    )


def check_start(
    st: VehicleStatus,
    start_ned_m: np.ndarray,
    *,
    tolerance_m: float,
    on_ground: bool,
    mission_origin: GeodeticPoint,
    vehicle_origin: GeodeticPoint,
) -> None:
    """Refuse a vehicle that is too far from its planned start.

    On the ground only the horizontal distance counts (it will climb
    vertically to the start); in the air the 3-D distance.

    Raises:
        PreflightError: naming the vehicle, both positions in the mission
            frame, the distance and the tolerance.
    """
    if st.pos_ned_m is None:
        raise PreflightError("no local position reported", vehicle=st.name, url=st.url)
    here = np.asarray(st.pos_ned_m)
    delta = here - start_ned_m
    dist = float(np.linalg.norm(delta[:2] if on_ground else delta))
    if dist > tolerance_m:
        here_enu = ned_to_enu(here, mission_origin, vehicle_origin)
        start_enu = ned_to_enu(start_ned_m, mission_origin, vehicle_origin)
        what = "horizontally " if on_ground else ""
        raise PreflightError(
            f"refused: it is {dist:.2f} m {what}from its planned start "
            f"(tolerance {tolerance_m:.2f} m): at ENU {_vec(here_enu)} m, "
            f"plan starts at ENU {_vec(start_enu)} m (mission frame)",
            vehicle=st.name,
            url=st.url,
        )


async def check_takeoff_height(v: Vehicle, start_alt_amsl_m: float, margin_m: float) -> None:
    """Refuse a take-off to a start PX4 would not leave the ground for.

    PX4 counts a take-off (and a mission's take-off item: ``MissionBase::checkClimbRequired``)
    within NAV_MC_ALT_RAD of the vehicle as reached at once, and below about 1 m its altitude
    estimate creeps up in ground effect while the vehicle sits on the ground
    (PX4-BEHAVIOUR.md: such starts stayed on the ground, then were auto-disarmed).

    Raises:
        PreflightError: the start is less than NAV_MC_ALT_RAD + ``margin_m`` above the
            vehicle (its altitude estimate), naming both figures.
    """
    st = await v.wait_for(lambda s: s.position is not None, "global position", timeout_s=5.0)
    assert st.position is not None
    alt_rad = await v.param("NAV_MC_ALT_RAD")
    said = "" if alt_rad is not None else " (PX4's default; the vehicle did not report it)"
    alt_rad = 0.8 if alt_rad is None else alt_rad
    above = start_alt_amsl_m - st.position.alt_m
    if above <= alt_rad + margin_m:
        raise PreflightError(
            f"refused: the plan starts {above:.2f} m above the vehicle; PX4 takes off only "
            f"to a first waypoint more than NAV_MC_ALT_RAD = {alt_rad:g} m{said} above it "
            f"(this check keeps {margin_m:g} m more): plan a higher start, or take off by "
            "hand and fly from the air",
            vehicle=v.name,
            url=v.url,
        )


def _heading_error_deg(st: VehicleStatus, yaw_deg: float) -> float:
    if not math.isfinite(yaw_deg):
        return 0.0
    if st.heading_deg is None:
        return math.inf
    return abs((st.heading_deg - yaw_deg + 180.0) % 360.0 - 180.0)


async def wait_settled(
    v: Vehicle,
    target_ned_m: np.ndarray,
    *,
    arrive_m: float,
    settle_speed_m_s: float,
    dwell_s: float,
    timeout_s: float,
    yaw_deg: float = math.nan,
    yaw_tolerance_deg: float = 10.0,
    poll_s: float = 0.05,
) -> VehicleStatus:
    """Wait until ``v`` has settled on ``target_ned_m``: the arrival gate of a start.

    Settled means, over the last ``dwell_s``: the mean of its position estimate within
    ``arrive_m`` of the target (3-D), the mean velocity below ``settle_speed_m_s``, no
    sample farther than ``arrive_m`` + 0.3 m, and the heading on ``yaw_deg`` (NED, if
    finite). Means, because PX4's estimate is noisy (velocity noise of 0.1-0.3 m/s on SIH):
    a vehicle holding its start still jitters around it.

    Raises:
        PreflightError: not settled within ``timeout_s`` (names the distance, speed, heading).
        LinkLostError: the link was lost meanwhile.
    """
    t_end = time.monotonic() + timeout_s
    window: list[tuple[float, np.ndarray, np.ndarray]] = []
    dist = speed = math.inf
    yaw_err = 0.0
    while True:
        st = v.status()
        if st.heartbeat_age_s is not None and not st.connected:
            raise LinkLostError("link lost while waiting at the start", vehicle=v.name, url=v.url)
        now = time.monotonic()
        if st.pos_ned_m is not None and st.vel_ned_m_s is not None:
            window.append((now, np.asarray(st.pos_ned_m, float), np.asarray(st.vel_ned_m_s, float)))
            while window and window[0][0] < now - dwell_s:
                window.pop(0)
            pos = np.array([w[1] for w in window])
            vel = np.array([w[2] for w in window])
            dist = float(np.linalg.norm(pos.mean(axis=0) - target_ned_m))
            speed = float(np.linalg.norm(vel.mean(axis=0)))
            worst = float(np.linalg.norm(pos - target_ned_m, axis=1).max())
            yaw_err = _heading_error_deg(st, yaw_deg)
            spans = now - window[0][0] >= dwell_s * 0.9 or dwell_s == 0.0
            if (
                spans
                and dist <= arrive_m
                and worst <= arrive_m + 0.3
                and speed <= settle_speed_m_s
                and yaw_err <= yaw_tolerance_deg
            ):
                return st
        if now >= t_end:
            raise PreflightError(
                f"did not settle at its start in {timeout_s:.0f} s: {dist:.2f} m away on average "
                f"(gate {arrive_m:.2f} m), {speed:.2f} m/s, heading off by {yaw_err:.0f} deg",
                vehicle=v.name,
                url=v.url,
            )
        await asyncio.sleep(poll_s)


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
        await asyncio.sleep(retry_after_s)
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
    await _stop_offboard(v)
    at = cfg.land_at.get(v.name) if cfg is not None else None
    if action is EndAction.LAND and at is not None:
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


def _track(
    name: str, rows: np.ndarray, t0: float, mission_origin: GeodeticPoint, origin: GeodeticPoint
) -> FlownTrack:
    if rows.shape[0] == 0:
        z = np.zeros((0, 3))
        return FlownTrack(name, np.zeros(0), z, z.copy(), z.copy())
    ned = rows[:, 1:4]
    return FlownTrack(
        name=name,
        t_s=rows[:, 0] - t0,
        pos_enu_m=ned_to_enu(ned, mission_origin, origin),
        vel_enu_m_s=ned_vector_to_enu(rows[:, 4:7], mission_origin, origin),
        pos_ned_m=ned,
    )


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
    (outcome,) = await asyncio.gather(task, return_exceptions=True)
    return outcome if isinstance(outcome, BaseException) else None


async def _fly(
    fleet: Fleet,
    trajectories: Mapping[str, Trajectory],
    mission_origin: GeodeticPoint,
    cfg: OffboardConfig,
    monitor: SafetyMonitor | None,
) -> FlightResult:
    vehicles = [fleet[name] for name in trajectories]
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
    )
    hover_stop = asyncio.Event()
    hover_task = asyncio.create_task(hover.run(time.monotonic(), stop=hover_stop))
    try:
        try:
            await asyncio.sleep(cfg.prestream_s)
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
        t0 = time.monotonic() + cfg.start_delay_s
        main = SetpointStreamer(
            [
                StreamTarget(v.name, offboard_sender(v.offboard), setpoints[v.name])
                for v in vehicles
            ],
            cfg.rate_hz,
            late_threshold_s=cfg.late_threshold_s,
            groups=groups,
        )
        for v in vehicles:
            v.start_track()
        await asyncio.sleep(max(0.0, t0 - time.monotonic() - 0.5 / cfg.rate_hz))
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
        v.name: _track(v.name, v.stop_track(), t0, mission_origin, origins[v.name])
        for v in vehicles
    }
    completed = event is None and all(s.sent + s.skipped >= main.n_ticks for s in stats.values())
    return FlightResult(
        completed=completed,
        t0_monotonic_s=t0,
        t0_unix_s=t0 + (time.time() - time.monotonic()),
        stats=stats,
        tracks=tracks,
        safety_event=event,
        end_failures=end_failures,
        origins=origins,
        monitor=mon.stats,
    )
