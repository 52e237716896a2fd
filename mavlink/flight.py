"""One flight engine for both ways of flying a plan: offboard setpoints and PX4 missions.

A flight has the same phases whatever flies it; :func:`fly` runs them in order, and a
:class:`FlightDriver` supplies what differs between the modes (and its :class:`StartGate`:
how far a start may be, the take-off, the arrival gate):

1. **positions**: every vehicle's EKF origin (GPS_GLOBAL_ORIGIN), local and global position,
   armed and in-air state are known (:meth:`FlightDriver.starts` then gives each vehicle's
   start in its own NED frame, its altitude and the plan's heading there);
2. **checks, before anything is armed or sent**: each vehicle is within the start
   tolerance of its start (horizontally on the ground, in 3-D in the air), and a vehicle on
   the ground is low enough below its start for PX4's take-off
   (:func:`mavlink.preflight.check_start`, :func:`mavlink.preflight.check_takeoff_height`);
   then :meth:`FlightDriver.prepare` (a mission is uploaded and read back here);
3. **take-off**: the vehicles on the ground arm and take off to their start's altitude on
   the plan's heading, all together, and must hover there;
4. **the start gate**: :meth:`FlightDriver.approach` brings every vehicle onto its start
   (offboard: the start setpoint streamed and the switch to OFFBOARD; missions: a
   reposition in Hold) and waits at the arrival gate; a failure holds every vehicle;
5. **release**: the tracks start, and :meth:`FlightDriver.release` starts every vehicle at
   one instant, the plan's t = 0 on the fleet's clock (:mod:`mavlink.clock`);
6. **flight** under the safety monitor (:class:`mavlink.monitor.SafetyMonitor`, expecting
   the driver's mode): :meth:`FlightDriver.run` until the plan is flown or the monitor stops
   it; then :meth:`FlightDriver.finish` (offboard: the end action; a mission carries its own);
7. **record**: the flown tracks in the mission frame from t = 0, in one :class:`FlightResult`.

With a :class:`Replanner` and a driver that can take a new plan in flight
(:class:`Switchable`: offboard), a vehicle that leaves the flight (its link lost, its own
failsafe) does not stop it: the monitor hands it over (``on_departure``), the driver stops
streaming to it, the replanner plans the rest for the others, and the driver switches to the
new plan at its switch time, which the vehicles fly without a break (the new plan equals the
old one until then); the monitor then checks the new plan's clauses.  A replan that finds no
plan, or whose plan comes after its switch time, stops the flight (every vehicle still
flying holds; verdict NO_REPLAN, with the reason).

The drivers: :class:`mavlink.offboard.OffboardDriver` and
:class:`mavlink.mission.flight.MissionDriver`. A failure from the take-off to the release
(phases 3-5) holds every vehicle before it is raised; a cancellation (Ctrl-C) is left to
:meth:`mavlink.link.fleet.Fleet.flight`, which holds every vehicle on the way out.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Awaitable, Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from mavlink.errors import LinkError, LinkLostError, PreflightError, StreamError
from mavlink.monitor import SafetyMonitor, safe_stop
from mavlink.monitor_findings import (
    MonitorStats,
    SafetyAction,
    SafetyClause,
    SafetyEvent,
    VehicleLeft,
    Verdict,
)
from mavlink.preflight import TAKEOFF_MARGIN_M, check_start, check_takeoff_height
from mavlink.px4_modes import Px4Mode
from mavlink.tracks import FlownTrack, track_from_rows
from planner.frames import GeodeticPoint, enu_to_geodetic, enu_to_ned

if TYPE_CHECKING:
    from mavlink.link.fleet import Fleet
    from mavlink.link.vehicle import Vehicle
    from mavlink.link.vehicle_status import VehicleStatus
    from mavlink.mission.run import MissionRun
    from mavlink.offboard.stream import StreamStats
    from mavlink.tlog import TlogStats
    from planner.trajectory import Trajectory

__all__ = [
    "DriverReport",
    "FlightDriver",
    "FlightResult",
    "NewPlan",
    "Replanner",
    "StartGate",
    "StartPoint",
    "Started",
    "Switchable",
    "check_starts",
    "fly",
    "gather_or_raise",
    "start_point",
    "start_together",
]


@dataclass(frozen=True, slots=True)
class StartGate:
    """How a flight gets onto its starts (phases 2-4 of :func:`fly`).

    Attributes:
        start_tolerance_m: refuse a vehicle farther than this from its start (before
            anything is armed; horizontally on the ground, in 3-D in the air); after the
            take-off its altitude must be within it too.
        arrive_m: the arrival gate: the plan starts only when every vehicle (its estimate)
            is this close to its start in 3-D, slower than ``settle_speed_m_s`` and on the
            plan's heading (``yaw_tolerance_deg``), for ``dwell_s`` without a break.
        dwell_s: how long the arrival gate must hold.
        arrive_timeout_s: time allowed for the gate.
        yaw_tolerance_deg: heading error the gate accepts.
        takeoff: take off to the start altitude if a vehicle is on the ground (otherwise
            a vehicle must already hover at its start).
        takeoff_margin_m: a start must be this much more than NAV_MC_ALT_RAD above a
            vehicle on the ground (:func:`mavlink.preflight.check_takeoff_height`).
        takeoff_timeout_s: time allowed to be airborne near the start after the take-off.
        settle_speed_m_s: a vehicle counts as hovering below this speed.
    """

    start_tolerance_m: float = 1.0
    arrive_m: float = 0.3
    dwell_s: float = 1.0
    arrive_timeout_s: float = 20.0
    yaw_tolerance_deg: float = 10.0
    takeoff: bool = True
    takeoff_margin_m: float = TAKEOFF_MARGIN_M
    takeoff_timeout_s: float = 30.0
    settle_speed_m_s: float = 0.3

    def __post_init__(self) -> None:
        for name in (
            "start_tolerance_m",
            "arrive_m",
            "arrive_timeout_s",
            "yaw_tolerance_deg",
            "takeoff_timeout_s",
            "settle_speed_m_s",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise LinkError(f"{name} must be a finite number > 0, got {value!r}")
        for name in ("dwell_s", "takeoff_margin_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise LinkError(f"{name} must be a finite number >= 0, got {value!r}")


@dataclass(frozen=True, slots=True)
class StartPoint:
    """Where a vehicle starts the plan: ``ned_m`` in its own local frame, the same point's
    geodetic coordinates (AMSL), and the plan's heading there (degrees from north)."""

    ned_m: np.ndarray
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    yaw_deg: float


def start_point(
    enu_m: np.ndarray, yaw_deg: float, mission_origin: GeodeticPoint, origin: GeodeticPoint
) -> StartPoint:
    """The :class:`StartPoint` of mission-frame point ``enu_m`` for a vehicle whose EKF
    origin is ``origin``."""
    p = np.asarray(enu_m, dtype=float).reshape(3)
    lat, lon, alt = (float(np.ravel(x)[0]) for x in enu_to_geodetic(p, mission_origin))
    return StartPoint(enu_to_ned(p, mission_origin, origin), lat, lon, alt, float(yaw_deg))


@dataclass(frozen=True, slots=True)
class DriverReport:
    """What a driver adds to the result (:meth:`FlightDriver.finish`).

    Attributes:
        completed: the driver flew all of the plan (every setpoint streamed; every mission
            finished).
        end_failures: vehicles whose end action failed, with the reason.
        stats: offboard: the stream's statistics per vehicle.
        runs: missions: what each vehicle reported of its mission.
        start_skew_s: missions: each vehicle's confirmed start minus the shared one.
    """

    completed: bool
    end_failures: dict[str, str] = field(default_factory=dict)
    stats: dict[str, StreamStats] = field(default_factory=dict)
    runs: dict[str, MissionRun] = field(default_factory=dict)
    start_skew_s: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True, slots=True, eq=False)
class FlightResult:
    """What :func:`fly` did.

    Attributes:
        completed: the whole plan was flown (the driver's report), no safety stop, no
            failed end action.
        t0_monotonic_s: the shared start on the fleet's clock (:mod:`mavlink.clock`).
        t0_unix_s: the same instant as Unix time (to align a ``.tlog``).
        tracks: flown tracks per vehicle, in the mission frame, times from t0.
        safety_event: what stopped the flight, if the monitor did.
        end_failures: vehicles whose end action failed, with the reason.
        origins: each vehicle's EKF origin used for the transform.
        monitor: what the safety monitor did.
        stats: offboard: stream statistics per vehicle (the main stream only).
        runs: missions: what each vehicle reported (MISSION_CURRENT, reached items).
        start_skew_s: missions: each vehicle's confirmed start minus the shared one.
        tlog: what a ``.tlog`` recording holds, if one was asked for.
    """

    completed: bool
    t0_monotonic_s: float
    t0_unix_s: float
    tracks: dict[str, FlownTrack]
    safety_event: SafetyEvent | None
    end_failures: dict[str, str] = field(default_factory=dict)
    origins: dict[str, GeodeticPoint] = field(default_factory=dict)
    monitor: MonitorStats | None = None
    stats: dict[str, StreamStats] = field(default_factory=dict)
    runs: dict[str, MissionRun] = field(default_factory=dict)
    start_skew_s: dict[str, float] = field(default_factory=dict)
    tlog: TlogStats | None = None


class FlightDriver(Protocol):
    """What a mode of flight supplies to :func:`fly` (the module docstring's phases).

    Attributes:
        names: the vehicles flown, in plan order.
        gate: how the vehicles get onto their starts (checks, take-off, arrival gate).
        expected_mode: the PX4 mode the vehicles fly the plan in (the monitor stops a
            vehicle found in another).
        mode_grace_s: how long after t0 a heartbeat may still show another mode.
        plans: the trajectories the monitor predicts each vehicle along (``None``: it
            predicts at constant velocity, and the tracking alarm is off).
        on_board: the plan runs on board (a mission): a vehicle whose link is lost flies
            on, so the monitor rides the loss out (offboard: PX4's offboard-loss failsafe
            takes over, and the flight stops).
    """

    names: Sequence[str]
    gate: StartGate
    expected_mode: Px4Mode
    mode_grace_s: float
    plans: Mapping[str, Trajectory] | None
    on_board: bool

    def starts(self, origins: Mapping[str, GeodeticPoint]) -> dict[str, StartPoint]:
        """Each vehicle's start (phase 1)."""
        ...

    async def prepare(self, fleet: Fleet, vehicles: Sequence[Vehicle]) -> None:
        """After the checks, before anything is armed (phase 2)."""
        ...

    async def approach(
        self, fleet: Fleet, vehicles: Sequence[Vehicle], starts: Mapping[str, StartPoint]
    ) -> None:
        """Onto the starts, through the arrival gate (phase 4)."""
        ...

    async def release(self, fleet: Fleet, vehicles: Sequence[Vehicle]) -> float:
        """Start every vehicle at one instant; that instant, t0 (phase 5)."""
        ...

    async def abort(self) -> None:
        """End whatever of the driver runs (idempotent): called when the flight ends before
        the release or during the run (a failure, a cancellation), or after a release that
        no :meth:`run` follows; never after a release that :meth:`run` and :meth:`finish`
        follow."""
        ...

    def done(self, name: str) -> bool:
        """Whether vehicle ``name`` is at its plan's end (PX4 may leave the mode there)."""
        ...

    async def run(
        self, fleet: Fleet, vehicles: Sequence[Vehicle], t0: float, stop: asyncio.Event
    ) -> None:
        """Fly from t0 until the plan is flown or ``stop`` is set (phase 6)."""
        ...

    async def finish(
        self, fleet: Fleet, vehicles: Sequence[Vehicle], t0: float, event: SafetyEvent | None
    ) -> DriverReport:
        """After the monitor stopped (``event``: what it stopped, if it did)."""
        ...


@dataclass(frozen=True, slots=True)
class NewPlan:
    """A replan's answer (:class:`Replanner`).

    Attributes:
        switch_s: plan time from which ``trajectories`` differ from the plan flown.
        trajectories: the vehicles' new trajectories (those that fly on), on the plan's clock.
        clauses: the invariants the monitor checks from then on.
    """

    switch_s: float
    trajectories: Mapping[str, Trajectory]
    clauses: Sequence[SafetyClause]


class Replanner(Protocol):
    """Plans the rest of a flight for the vehicles that fly on (``gcs fly --replan``)."""

    async def __call__(self, left: Sequence[VehicleLeft], now_s: float) -> NewPlan | str:
        """The new plan after ``left`` left at plan time ``now_s`` (none: a replan it asked
        for itself), or why there is none."""
        ...

    def attach(self, request: Callable[[], bool] | None) -> None:
        """Given at the flight's start: ``request()`` begins a replan with no departure (on
        the event loop; False while one runs or after a stop); None when the flight ends."""
        ...


@runtime_checkable
class Switchable(Protocol):
    """A driver that can drop vehicles and take new trajectories in flight (offboard)."""

    plans: Mapping[str, Trajectory] | None

    def drop(self, names: Sequence[str]) -> None:
        """Send nothing more to ``names``."""
        ...

    def switch(self, trajectories: Mapping[str, Trajectory], switch_s: float) -> None:
        """Fly ``trajectories`` from now on (raises StreamError past ``switch_s``)."""
        ...


@dataclass(frozen=True, slots=True)
class Started:
    """The fleet released into the plan (:func:`start_together`).

    Attributes:
        t0_monotonic_s: the shared start (the plan's t = 0) on the fleet's clock.
        t0_unix_s: the same instant as Unix time.
        origins: each vehicle's EKF origin.
    """

    t0_monotonic_s: float
    t0_unix_s: float
    origins: dict[str, GeodeticPoint]


async def start_together(
    fleet: Fleet,
    driver: FlightDriver,
    mission_origin: GeodeticPoint,
    *,
    record: bool = False,
) -> Started:
    """Phases 1-5 of the module docstring: the checks, the take-off, the arrival gate and
    one release. :func:`fly` goes on with the flight; ``gcs upload --start`` leaves the
    missions to fly on board from here, and a caller that does so ends the driver with
    :meth:`FlightDriver.abort` (a mission driver's follower holds MAVSDK subscriptions).

    Args:
        record: start every vehicle's track just before the release (:func:`fly`).

    Raises:
        PreflightError, LinkError: as :func:`fly`; a failure from the take-off on holds
            every vehicle before it is raised.
    """
    vehicles = [fleet[name] for name in driver.names]
    gate = driver.gate
    origins, starts, needs_takeoff = await _checked_starts(fleet, driver, mission_origin)
    await driver.prepare(fleet, vehicles)
    released = False
    try:
        try:
            await gather_or_raise(
                _takeoff(v, starts[v.name], gate, mission_origin, origins[v.name])
                for v in needs_takeoff
            )
            await driver.approach(fleet, vehicles, starts)
            if record:  # the tracks start before the release, so that they cover t = 0
                for v in vehicles:
                    v.start_track()
            t0 = await driver.release(fleet, vehicles)
            released = True
        except Exception as exc:
            await driver.abort()
            failed = await fleet.for_each(lambda v: safe_stop(v, SafetyAction.HOLD), vehicles)
            for name, err in failed.items():
                exc.add_note(f"vehicle {name}: hold after the failed start also failed: {err}")
            raise
    finally:
        if not released:  # a failure or a cancellation: nothing of the driver runs on
            await driver.abort()
    return Started(t0, t0 + fleet.clock.unix_offset(), dict(origins))


async def fly(
    fleet: Fleet,
    driver: FlightDriver,
    mission_origin: GeodeticPoint,
    monitor: SafetyMonitor | None = None,
    replanner: Replanner | None = None,
) -> FlightResult:
    """Fly ``driver``'s plan on ``fleet`` (the module docstring's phases).

    Args:
        fleet: a connected :class:`~mavlink.link.fleet.Fleet` holding every vehicle named.
        driver: the mode of flight.
        mission_origin: the geodetic origin of the plan's frame.
        monitor: the safety monitor (default: one that only watches the links).
        replanner: plans the rest when a vehicle leaves the flight (the module docstring;
            only with a :class:`Switchable` driver).

    Returns:
        A :class:`FlightResult`; a safety stop is a result, not an exception.

    Raises:
        PreflightError: a vehicle may not start (too far from its start, too low for a
            take-off, not reaching or settling at it, refusing the start).
        LinkError: a vehicle unknown, its origin unknown, its link lost before t0, or a
            transfer failed.
    """
    vehicles = [fleet[name] for name in driver.names]
    started = await start_together(fleet, driver, mission_origin, record=True)
    t0, origins = started.t0_monotonic_s, started.origins

    mon = monitor or SafetyMonitor(())
    replans: list[asyncio.Task[None]] = []
    if replanner is not None and isinstance(driver, Switchable):
        mon.on_departure = _departure_handler(fleet, driver, mon, replanner, t0, replans)
    stop = asyncio.Event()
    mon_task = asyncio.create_task(
        mon.run(
            fleet,
            vehicles,
            t0_monotonic_s=t0,
            mission_origin=mission_origin,
            origins=origins,
            stop=stop,
            plans=driver.plans,
            expected_mode=driver.expected_mode,
            mode_grace_s=driver.mode_grace_s,
            done=driver.done,
        )
    )
    flown = False
    try:
        await driver.run(fleet, vehicles, t0, stop)
        flown = True
    finally:
        stop.set()
        if mon.on_departure is not None and replanner is not None:
            replanner.attach(None)
        for task in replans:
            task.cancel()
        event = await mon_task
        if not flown:
            await driver.abort()
    report = await driver.finish(fleet, vehicles, t0, event)
    tracks = {
        v.name: track_from_rows(v.name, v.stop_track(), t0, mission_origin, origins[v.name])
        for v in vehicles
    }
    return FlightResult(
        completed=report.completed and event is None and not report.end_failures,
        t0_monotonic_s=t0,
        t0_unix_s=started.t0_unix_s,
        tracks=tracks,
        safety_event=event,
        end_failures=report.end_failures,
        origins=dict(origins),
        monitor=mon.stats,
        stats=report.stats,
        runs=report.runs,
        start_skew_s=report.start_skew_s,
    )


def _departure_handler(
    fleet: Fleet,
    driver: Switchable,
    mon: SafetyMonitor,
    replanner: Replanner,
    t0: float,
    tasks: list[asyncio.Task[None]],
) -> Callable[[Sequence[VehicleLeft]], bool]:
    """The monitor's ``on_departure`` for :func:`fly`: drop the vehicles that left, replan in
    a task, and switch to its plan or halt the flight.  One replan at a time: a departure
    during one (a vehicle lost while the plan is made again around an area closed in flight)
    is replanned once that one has ended and been switched to, from its plan."""

    async def replan(left: Sequence[VehicleLeft], now_s: float) -> None:
        names = [d.vehicle for d in left]
        verdict = Verdict.NO_REPLAN
        try:
            got = await replanner(left, now_s)
        except Exception as exc:  # reported as the reason the flight stopped
            got = f"the replan failed: {exc}"
        t_s = fleet.clock.monotonic() - t0
        if isinstance(got, str):
            mon.halt(verdict, names, t_s, got)
            return
        try:
            driver.switch(got.trajectories, got.switch_s)
        except StreamError as exc:
            mon.halt(verdict, names, t_s, f"the new plan came too late: {exc}")
            return
        mon.replace(driver.plans, got.clauses)

    async def after(busy: Sequence[asyncio.Task[None]], left: Sequence[VehicleLeft]) -> None:
        await asyncio.gather(*busy, return_exceptions=True)
        if not mon.halted:
            await replan(left, fleet.clock.monotonic() - t0)

    def on_departure(left: Sequence[VehicleLeft]) -> bool:
        if mon.halted:
            return False
        busy = [t for t in tasks if not t.done()]
        driver.drop([d.vehicle for d in left])
        now_s = fleet.clock.monotonic() - t0
        tasks.append(asyncio.create_task(after(busy, left) if busy else replan(left, now_s)))
        return True

    def request() -> bool:
        """A replan with no departure (regions closed); whether it began."""
        if mon.halted or any(not t.done() for t in tasks):
            return False
        tasks.append(asyncio.create_task(replan((), fleet.clock.monotonic() - t0)))
        return True

    replanner.attach(request)
    return on_departure


async def check_starts(fleet: Fleet, driver: FlightDriver, mission_origin: GeodeticPoint) -> None:
    """Phase 2's checks alone, before anything is sent (``gcs upload --start`` runs them
    before its upload; :func:`start_together` runs them again).

    Raises:
        PreflightError: a vehicle too far from its start, or too low below it to take off.
    """
    await _checked_starts(fleet, driver, mission_origin)


async def _checked_starts(
    fleet: Fleet, driver: FlightDriver, mission_origin: GeodeticPoint
) -> tuple[dict[str, GeodeticPoint], dict[str, StartPoint], list[Vehicle]]:
    """The origins, the starts, and the vehicles that must take off, every start checked."""
    vehicles = [fleet[name] for name in driver.names]
    origins = dict(await fleet.origins())
    await asyncio.gather(*(_wait_position(v) for v in vehicles))
    starts = driver.starts(origins)
    needs_takeoff = await _check_starts(vehicles, starts, driver.gate, mission_origin, origins)
    return origins, starts, needs_takeoff


async def _wait_position(v: Vehicle) -> None:
    await v.wait_for(
        lambda s: (
            s.pos_ned_m is not None
            and s.armed is not None
            and s.in_air is not None
            and s.position is not None
        ),
        "local and global position",
        timeout_s=5.0,
    )


async def _check_starts(
    vehicles: Sequence[Vehicle],
    starts: Mapping[str, StartPoint],
    gate: StartGate,
    mission_origin: GeodeticPoint,
    origins: Mapping[str, GeodeticPoint],
) -> list[Vehicle]:
    """Check every vehicle before arming any; the vehicles that must take off."""
    needs_takeoff: list[Vehicle] = []
    for v in vehicles:
        st = v.status()
        # In the air (EXTENDED_SYS_STATE): judged in 3-D where it is; on the ground:
        # horizontally, as it will climb straight up to its start.
        airborne = bool(st.armed and st.in_air)
        if not airborne and not gate.takeoff:
            raise PreflightError(
                "refused: on the ground and takeoff is disabled", vehicle=v.name, url=v.url
            )
        check_start(
            st,
            starts[v.name].ned_m,
            tolerance_m=gate.start_tolerance_m,
            on_ground=not airborne,
            mission_origin=mission_origin,
            vehicle_origin=origins[v.name],
        )
        if not airborne:
            needs_takeoff.append(v)
    for v in needs_takeoff:
        await check_takeoff_height(v, starts[v.name].alt_amsl_m, gate.takeoff_margin_m)
    return needs_takeoff


def _is_hovering(st: VehicleStatus, settle_speed_m_s: float) -> bool:
    return bool(
        st.armed
        and st.in_air
        and st.mode in (Px4Mode.AUTO_LOITER, Px4Mode.POSCTL, Px4Mode.OFFBOARD)
        and st.vel_ned_m_s is not None
        and float(np.linalg.norm(st.vel_ned_m_s)) < settle_speed_m_s
    )


async def _takeoff(
    v: Vehicle,
    start: StartPoint,
    gate: StartGate,
    mission_origin: GeodeticPoint,
    vehicle_origin: GeodeticPoint,
) -> None:
    """Arm, take off to the start's altitude on the plan's heading, and wait until airborne
    (EXTENDED_SYS_STATE in air) near the start altitude and hovering."""
    await v.arm()
    await v.takeoff_to(start.alt_amsl_m, start.yaw_deg)

    def airborne(s: VehicleStatus) -> bool:
        return (
            s.pos_ned_m is not None
            and bool(s.in_air)
            and abs(float(s.pos_ned_m[2]) - float(start.ned_m[2])) <= gate.start_tolerance_m
            and _is_hovering(s, gate.settle_speed_m_s)
        )

    try:
        await v.wait_for(
            airborne, "airborne near the start after takeoff", timeout_s=gate.takeoff_timeout_s
        )
    except (PreflightError, LinkLostError):
        raise
    except LinkError as exc:
        raise PreflightError(exc.detail, vehicle=v.name, url=v.url) from None
    check_start(
        v.status(),
        start.ned_m,
        tolerance_m=gate.start_tolerance_m,
        on_ground=False,
        mission_origin=mission_origin,
        vehicle_origin=vehicle_origin,
    )


async def gather_or_raise(steps: Iterable[Awaitable[None]]) -> None:
    """Run every step to its end (or failure); then raise the first failure, the others
    noted on it."""
    results = await asyncio.gather(*steps, return_exceptions=True)
    errors = [r for r in results if isinstance(r, BaseException)]
    if errors:
        for other in errors[1:]:
            errors[0].add_note(f"also: {other}")
        raise errors[0]
