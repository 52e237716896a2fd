"""Fault-matrix runs shared by the reliability tests and ``benchmarks/bench_faults.py``.

One run = a fresh :class:`~mavlink.mock.MockFleet` vehicle and a MAVSDK
:class:`~mavlink.link.fleet.Fleet` connected to it over loopback UDP (clean link),
then the faults are switched on and the GCS link's own code
(:func:`mavlink.mission.upload_and_verify`, one attempt, or with a
:class:`~mavlink.mission.RetryPolicy` :func:`mavlink.mission.upload_with_retries`)
uploads a plan's mission and reads it back.  The outcome is judged against the
vehicle's own stored copy, so a "success" can never hide a partial mission.
"""

from __future__ import annotations

import asyncio
import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

from mavlink.errors import MissionError
from mavlink.link.fleet import Fleet
from mavlink.link.vehicle_status import VehicleSpec
from mavlink.mission import (
    MissionItem,
    RetryPolicy,
    compare_items,
    trajectory_to_mission,
    upload_and_verify,
    upload_with_retries,
)
from mavlink.mock import FaultConfig, MockFleet
from mavlink.mock.testing import free_udp_ports
from planner.planfile import Plan, load_plan

PLAN_PATH = Path(__file__).resolve().parents[1] / "mavlink" / "data" / "reach_avoid_2.plan.json"

#: Named link conditions of the mission matrix (applied after the connection is up).
CONDITIONS: dict[str, FaultConfig] = {
    "clean": FaultConfig(),
    "loss 10% up": FaultConfig(loss_to_vehicle=0.10),
    "loss 10% down": FaultConfig(loss_to_gcs=0.10),
    "loss 10% both": FaultConfig(loss_to_vehicle=0.10, loss_to_gcs=0.10),
    "loss 30% up": FaultConfig(loss_to_vehicle=0.30),
    "loss 30% down": FaultConfig(loss_to_gcs=0.30),
    "loss 30% both": FaultConfig(loss_to_vehicle=0.30, loss_to_gcs=0.30),
    "loss 50% up": FaultConfig(loss_to_vehicle=0.50),
    "loss 50% down": FaultConfig(loss_to_gcs=0.50),
    "loss 50% both": FaultConfig(loss_to_vehicle=0.50, loss_to_gcs=0.50),
    "duplicate 30%": FaultConfig(duplicate=0.30),
    "reorder 30% (+30 ms)": FaultConfig(reorder=0.30, reorder_delay_s=0.03),
    "latency 200 ms": FaultConfig(latency_s=0.20),
    "duplicate 5%": FaultConfig(duplicate=0.05),
    "reorder+loss 10%+latency 50 ms": FaultConfig(
        loss_to_vehicle=0.1, loss_to_gcs=0.1, reorder=0.2, latency_s=0.05
    ),
}


@dataclass(frozen=True, slots=True)
class MissionRunResult:
    """Outcome of one upload + read-back under faults.

    ``ok``: the GCS reported success.  ``error``: the GCS's error line when it
    did not.  ``stored_ok``: the vehicle's stored mission equals the plan.
    ``stored_len``: how many items the vehicle holds; ``stored_previous``: it
    still holds the mission it had before (``previous``).  ``elapsed_s``: wall time
    from the start of the upload to success or error.  ``attempts``: uploads tried.
    """

    condition: str
    seed: int
    ok: bool
    error: str
    stored_ok: bool
    stored_len: int
    stored_previous: bool
    elapsed_s: float
    attempts: int = 1

    @property
    def silent_partial(self) -> bool:
        """The GCS said success but the vehicle does not hold exactly the plan."""
        return self.ok and not self.stored_ok

    @property
    def partial_on_vehicle(self) -> bool:
        """The vehicle holds something that is neither its previous mission nor the full plan."""
        return not (self.stored_ok or self.stored_previous)


def plan_items(plan: Plan | None = None) -> tuple[MissionItem, ...]:
    """The mission items of the stored two-vehicle plan's first vehicle."""
    plan = plan or load_plan(PLAN_PATH)
    v = plan.vehicles[0]
    return trajectory_to_mission(v.trajectory, plan.origin, acceptance_radius_m=0.3).items


async def mission_run(
    condition: str,
    faults: FaultConfig,
    seed: int,
    items: tuple[MissionItem, ...],
    origin: object,
    previous: tuple[MissionItem, ...] = (),
    policy: RetryPolicy | None = None,
) -> MissionRunResult:
    """One upload + read-back of ``items`` with ``faults`` on the link (see module doc).

    ``previous`` is uploaded first over the clean link (the vehicle's mission
    before the faulty transfer).  With ``policy`` the transfer is retried as a whole
    (:func:`mavlink.mission.upload_with_retries`), else tried once.
    """
    gcs_port, veh_port = free_udp_ports(2)
    async with MockFleet(
        n=1, origin=origin, gcs_ports=[gcs_port], vehicle_ports=[veh_port], seed=seed
    ) as mock:
        spec = VehicleSpec("d1", f"udpin://127.0.0.1:{gcs_port}", 1)
        async with Fleet([spec], connect_timeout_s=10.0, telemetry_rate_hz=None) as fleet:
            vehicle = mock.vehicles[0]
            if previous:
                await upload_and_verify(fleet["d1"], previous)
            vehicle.set_faults(faults)
            t0 = time.perf_counter()
            error = ""
            attempts = 1
            try:
                if policy is None:
                    await upload_and_verify(fleet["d1"], items)
                else:
                    attempts = (
                        await upload_with_retries(fleet["d1"], items, policy=policy)
                    ).attempts
                ok = True
            except MissionError as exc:
                ok, error = False, str(exc)
                attempts = getattr(exc, "attempts", 1)
            elapsed = time.perf_counter() - t0
            vehicle.set_faults(FaultConfig())
            stored = [MissionItem(**dataclasses.asdict(i)) for i in vehicle.mission_items(0)]
    return MissionRunResult(
        condition,
        seed,
        ok,
        error,
        compare_items(items, stored) == [],
        len(stored),
        compare_items(previous, stored) == [],
        elapsed,
        attempts,
    )


# --------------------------------------------------------------------------
# Connecting under faults
# --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ConnectRunResult:
    """Outcome of connecting a :class:`~mavlink.link.fleet.Fleet` to ``n`` mock vehicles whose links
    have faults from the start: discovery, first heartbeats, telemetry rates set.

    ``ok``: connected; ``error``: the error line otherwise; ``elapsed_s``: wall time of
    the connect.
    """

    condition: str
    seed: int
    ok: bool
    error: str
    elapsed_s: float


async def connect_run(
    condition: str,
    faults: FaultConfig,
    seed: int,
    *,
    n: int = 2,
    telemetry_rate_hz: float | None = 20.0,
    connect_timeout_s: float = 10.0,
) -> ConnectRunResult:
    """Connect to ``n`` mock vehicles with ``faults`` on every link (see the class doc)."""
    from mavlink.errors import LinkError

    plan = load_plan(PLAN_PATH)
    ports = free_udp_ports(2 * n)
    async with MockFleet(
        n=n,
        origin=plan.origin,
        gcs_ports=ports[:n],
        vehicle_ports=ports[n:],
        seed=seed,
        faults=faults,
    ):
        specs = [VehicleSpec(f"d{i + 1}", f"udpin://127.0.0.1:{ports[i]}", i + 1) for i in range(n)]
        fleet = Fleet(
            specs, connect_timeout_s=connect_timeout_s, telemetry_rate_hz=telemetry_rate_hz
        )
        t0 = time.perf_counter()
        try:
            await fleet.connect()
            ok, error = len(fleet) == n, ""
        except LinkError as exc:
            ok, error = False, str(exc)
        finally:
            elapsed = time.perf_counter() - t0
            fleet.close()
    return ConnectRunResult(condition, seed, ok, error, elapsed)


# --------------------------------------------------------------------------
# Offboard flights under faults
# --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class FlightRunResult:
    """Outcome of one offboard flight of the two-vehicle reach-avoid plan under faults.

    ``rho_flown``: exact robustness of the mock's true positions (mission ENU)
    over the plan's horizon.  ``completed`` / ``verdict``: what
    :func:`mavlink.offboard.fly_offboard` reported.  ``failsafe``: per vehicle,
    the mock's failsafe flag at the end; ``failsafe_seen``: it was raised at
    some point of the flight.  ``setpoints_after_return``: setpoints that
    reached each vehicle after ``fly_offboard`` returned (a GCS that went on
    streaming shows here).  ``setpoints_after_failsafe``: setpoints that reached
    a vehicle after its offboard failsafe engaged (it had left offboard).
    ``modes_after``: the mock's modes at the end; ``gcs_modes_after``: the
    GCS's view of them.
    """

    condition: str
    seed: int
    completed: bool
    verdict: str
    rho_flown: float
    failsafe: tuple[bool, ...]
    setpoints_after_return: tuple[int, ...]
    failsafe_seen: tuple[bool, ...]
    setpoints_after_failsafe: tuple[int, ...]
    modes_after: tuple[str, ...]
    gcs_modes_after: tuple[str, ...]
    elapsed_s: float


def _setpoints_received(mock: MockFleet) -> list[int]:
    return [v.received.get("SET_POSITION_TARGET_LOCAL_NED", 0) for v in mock.vehicles]


async def flight_run(
    condition: str,
    faults: FaultConfig,
    seed: int,
    *,
    outage_after_start_s: float | None = None,
    outage_s: float = 3.0,
    link_timeout_s: float = 2.0,
    settle_after_s: float = 1.5,
    profile: str = "ideal",
) -> FlightRunResult:
    """Fly the stored two-vehicle plan with ``faults`` on vehicle d1's link from the start.

    The vehicles are the mock's ``ideal`` profile by default: the fault matrix measures
    what the *link* does to a flight, so the link is the only cause of a difference
    (what PX4's own drag lag and estimator do to a reach-avoid flight is issue 16's).

    With ``outage_after_start_s``, d1's link also goes silent (both ways) for
    ``outage_s`` that long after both vehicles report OFFBOARD.  After the
    flight the run waits until the outage is over plus ``settle_after_s`` and
    counts the setpoints that still arrived.
    """
    import numpy as np

    from mavlink.mock import Outage
    from mavlink.mock.sim.px4 import Px4Mode
    from mavlink.offboard import fly_offboard
    from mavlink.offboard.setpoints import OffboardConfig
    from planner.frames import GeodeticPoint, ned_to_enu
    from tests.mavlink.linkutil import mock_and_fleet, scenario, spec_formula

    plan, problem = load_plan(PLAN_PATH), scenario(2)
    spec = spec_formula(problem)
    names = [v.name for v in plan.vehicles]
    trajs = {v.name: v.trajectory for v in plan.vehicles}
    spawns = [(v.start_enu_m[0], v.start_enu_m[1], 0.0) for v in plan.vehicles]
    dt, horizon = problem.timing.check_dt_s, problem.timing.horizon_s
    truth: list[tuple[float, list[np.ndarray]]] = []
    outage_end: list[float] = []
    failsafe_at: dict[int, int] = {}

    async def watch(mock: MockFleet, stop: asyncio.Event) -> None:
        origins = [GeodeticPoint(*v.origin_lla) for v in mock.vehicles]
        cut_at: float | None = None
        while not stop.is_set():
            states = [v.state for v in mock.vehicles]
            counts = _setpoints_received(mock)
            for i, s in enumerate(states):
                if s.failsafe and i not in failsafe_at:
                    failsafe_at[i] = counts[i]
            truth.append(
                (
                    time.monotonic(),
                    [
                        ned_to_enu(np.asarray(s.pos_ned_m), mock.origin, o)
                        for s, o in zip(states, origins, strict=True)
                    ],
                )
            )
            if outage_after_start_s is not None and not outage_end:
                if cut_at is None and all(s.mode is Px4Mode.OFFBOARD for s in states):
                    cut_at = time.monotonic() + outage_after_start_s
                if cut_at is not None and time.monotonic() >= cut_at:
                    now = mock.time_s
                    out = Outage(now, now + outage_s)
                    mock.vehicles[0].set_faults(dataclasses.replace(faults, outages=(out,)))
                    outage_end.append(time.monotonic() + outage_s)
            await asyncio.sleep(0.02)

    # in real time, as against PX4: the faults are the link's, and MAVSDK's timeouts are real
    async with mock_and_fleet(
        names,
        plan.origin,
        spawns,
        link_timeout_s=link_timeout_s,
        seed=seed,
        profile=profile,
        real_time=True,
    ) as (mock, fleet):
        mock.vehicles[0].set_faults(faults)
        stop = asyncio.Event()
        watcher = asyncio.create_task(watch(mock, stop))
        t_start = time.perf_counter()
        try:
            # the link is under test: the plan starts as soon as OFFBOARD is confirmed (no dwell
            # at the start), so the outage falls at a known plan time
            cfg = OffboardConfig(rate_hz=20.0, dwell_s=0.0, arrive_m=1.0, yaw_tolerance_deg=180.0)
            result = await fly_offboard(fleet, trajs, plan.origin, cfg)
        finally:
            stop.set()
            await watcher
        elapsed = time.perf_counter() - t_start
        at_return = _setpoints_received(mock)
        wait_until = max(outage_end, default=time.monotonic()) + settle_after_s
        await asyncio.sleep(max(0.0, wait_until - time.monotonic()))
        after = _setpoints_received(mock)
        states = [v.state for v in mock.vehicles]
        gcs_modes = tuple(str(getattr(s.mode, "name", s.mode)) for s in fleet.statuses())
    t0 = result.t0_monotonic_s
    t = np.array([row[0] for row in truth]) - t0
    grid = np.arange(round(horizon / dt) + 1) * dt
    signals = {}
    for i, name in enumerate(names):
        p = np.array([row[1][i] for row in truth])
        signals[name] = np.column_stack([np.interp(grid, t, p[:, a]) for a in range(3)])
    rho = float(spec.robustness(signals, dt))
    ev = result.safety_event
    return FlightRunResult(
        condition,
        seed,
        result.completed,
        ev.verdict.name if ev is not None else "",
        rho,
        tuple(s.failsafe for s in states),
        tuple(b - a for a, b in zip(at_return, after, strict=True)),
        tuple(i in failsafe_at for i in range(len(names))),
        tuple(after[i] - failsafe_at[i] if i in failsafe_at else 0 for i in range(len(names))),
        tuple(s.mode.name for s in states),
        gcs_modes,
        elapsed,
    )


# --------------------------------------------------------------------------
# A vehicle that reboots
# --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RebootRunResult:
    """Outcome of a reboot of d1 (of two) on the ground, with the GCS connected.

    ``status_during``: connected flags by name while d1 is silent.
    ``hold_failures``: the vehicles whose Hold failed while d1 was silent.
    ``hold_s``: wall time of that Hold on the whole fleet (bounded by MAVSDK's
    command timeout).  ``back``: d1 reported connected again, disarmed, and
    answered a command.  ``mission_kept``: its stored mission survived.
    """

    status_during: dict[str, bool]
    hold_failures: tuple[str, ...]
    hold_s: float
    back: bool
    mission_kept: bool
    elapsed_s: float


async def reboot_run(seed: int, silent_s: float = 8.0) -> RebootRunResult:
    """Upload a mission to d1, reboot it (``silent_s`` without any traffic), watch the GCS.

    The link timeout is 3 s: d1 is silent long enough to be seen lost and to fail the Hold,
    and d2, which talks throughout, is not taken for lost when a loaded machine stalls the
    process for 1.5 s (it was, beside the test suite and a planner: issue 41)."""
    plan = load_plan(PLAN_PATH)
    items = plan_items(plan)
    ports = free_udp_ports(4)
    t0 = time.perf_counter()
    async with MockFleet(
        n=2, origin=plan.origin, gcs_ports=ports[:2], vehicle_ports=ports[2:], seed=seed
    ) as mock:
        specs = [VehicleSpec(f"d{i + 1}", f"udpin://127.0.0.1:{ports[i]}", i + 1) for i in (0, 1)]
        async with Fleet(specs, link_timeout_s=3.0, telemetry_rate_hz=None) as fleet:
            await upload_and_verify(fleet["d1"], items)
            mock.vehicles[0].reboot(silent_s=silent_s)
            async with asyncio.timeout(10.0):
                while fleet["d1"].status().connected:
                    await asyncio.sleep(0.05)
            during = {s.name: s.connected for s in fleet.statuses()}
            t_hold = time.perf_counter()
            failures = await fleet.hold_all()
            hold_s = time.perf_counter() - t_hold
            async with asyncio.timeout(silent_s + 10.0):
                while not (st := fleet["d1"].status()).connected:
                    await asyncio.sleep(0.05)
            await fleet["d1"].hold()
            back = st.connected and st.armed is False
            stored = [
                MissionItem(**dataclasses.asdict(i)) for i in mock.vehicles[0].mission_items(0)
            ]
    return RebootRunResult(
        during,
        tuple(sorted(failures)),
        hold_s,
        back,
        compare_items(items, stored) == [],
        time.perf_counter() - t0,
    )
