"""The safety monitor's evaluation as it runs in flight: vectorised prediction and clauses
against the one-vehicle, one-clause definitions, late telemetry predicted instead of skipped,
and the evaluation kept off the event loop."""

from __future__ import annotations

import asyncio
import threading
import types
from pathlib import Path

import numpy as np
import pytest

from mavlink.monitor import SafetyMonitor
from mavlink.monitor_findings import Verdict, always_clauses
from mavlink.px4_modes import Px4Mode
from planner.frames import GeodeticPoint, NedToEnuMap, enu_to_ned
from planner.scenario import load_scenario
from planner.scenario.spec import parse_clause
from planner.spec.predicates import build_registry
from planner.stl.ast import conjunction
from planner.trajectory import Trajectory

REPO = Path(__file__).resolve().parents[2]


def fleet_spec(n: int):  # type: ignore[no-untyped-def]
    problem = load_scenario(REPO / "configs" / "reach_avoid.yaml", vehicles=n)
    registry = build_registry(problem)
    spec = conjunction([parse_clause(problem, c, registry) for c in problem.clauses])
    return problem, spec


def random_plan(name: str, seed: int, t0=(0.0, 2.0, 4.0), dur=(2.0, 2.0, 2.0)) -> Trajectory:
    rng = np.random.default_rng(seed)
    c = rng.normal(0.0, 0.3, (len(t0), 3, 6))
    c[:, :, 0] += rng.uniform(-2.0, 2.0, 3)
    return Trajectory(list(t0), list(dur), c, name=name)


def reference(mon: SafetyMonitor, t_s, states, plans, ages):  # type: ignore[no-untyped-def]
    """The definition, clause by clause and vehicle by vehicle (no batching, no stacking)."""
    signals = {}
    dt = 1.0
    for name, (p, v) in states.items():
        plan = None if plans is None else plans.get(name)
        age = ages.get(name, 0.0)
        if mon.horizon_s > 0:
            dt = mon.horizon_s / mon.steps
            tau = np.arange(mon.steps + 1) * dt
        else:
            tau = np.zeros(1)
        since = tau + age
        if plan is None:
            signals[name] = p + since[:, None] * v
        else:
            ref = plan.position(t_s + tau)
            t_k = np.array([t_s - age])
            p0, v0 = plan.position(t_k)[0], plan.velocity(t_k)[0]
            signals[name] = ref + (p - p0) + since[:, None] * (v - v0)
    violated, predicted = None, None
    for clause in mon.clauses:
        if not (clause.start_s <= t_s <= clause.end_s):
            continue
        if any(n not in signals for n in clause.vehicles):
            continue
        trace = clause.formula.robustness_trace({n: signals[n] for n in clause.vehicles}, dt)
        if trace[0] < 0 and violated is None:
            violated = (Verdict.VIOLATED, clause, float(trace[0]), 0.0)
        active = t_s + np.arange(trace.size) * dt <= clause.end_s
        bad = np.nonzero((trace < 0) & active)[0]
        if bad.size and predicted is None:
            predicted = (Verdict.PREDICTED, clause, float(trace[active].min()), bad[0] * dt)
    return violated or predicted


@pytest.mark.parametrize("shared_segments", [True, False])
def test_the_vectorised_evaluation_is_the_definition_for_16_vehicles(shared_segments: bool) -> None:
    problem, spec = fleet_spec(16)
    names = [v.name for v in problem.vehicles]
    mon = SafetyMonitor(always_clauses(spec, names), horizon_s=0.5, steps=5)
    assert len(mon.clauses) == 16 + 120 and mon.templates == 2
    plans = {
        n: random_plan(n, i)
        if shared_segments or i % 2
        else random_plan(n, i, t0=(0.0, 3.0), dur=(3.0, 3.0))
        for i, n in enumerate(names)
    }
    rng = np.random.default_rng(5)
    outcomes = set()
    for trial in range(120):
        t = float(rng.uniform(0.0, 6.5))
        # a crowd (every pair checked) or a few vehicles (so that some trials are clear)
        present = list(rng.choice(names, 16 if trial % 4 == 0 else 2, replace=False))
        states = {n: (rng.uniform(-3, 3, 3) * [1, 1, 0.5] + [0, 0, 1.5], rng.normal(0, 1, 3))
                  for n in present}  # fmt: skip
        ages = {n: float(rng.choice([0.0, 0.02, 0.7])) for n in present}
        with_plans = plans if trial % 3 else None
        got = mon.evaluate(t, states, with_plans, ages)
        want = reference(mon, t, states, with_plans, ages)
        if want is None:
            assert got is None
            outcomes.add("none")
            continue
        assert got is not None and got[0] is want[0] and got[1] is want[1]
        assert got[2] == pytest.approx(want[2], abs=1e-9) and got[3] == pytest.approx(want[3])
        outcomes.add(want[0].value)
    assert outcomes == {"none", "violated", "predicted"}


def test_late_telemetry_is_predicted_from_the_last_sample_and_the_plan_not_skipped() -> None:
    problem, spec = fleet_spec(1)
    mon = SafetyMonitor(always_clauses(spec, ["d1"]), horizon_s=0.5)
    # d1 was 0.9 m west of the obstacle's west face, moving east at 1.5 m/s, when its last
    # sample came 0.7 s ago: by now it is inside, though the sample and the 0.5 s horizon
    # from it alone are clear.
    x_face = problem.region("obstacle").lo_enu_m[0]
    p, v = np.array([x_face - 0.9, 0.0, 1.0]), np.array([1.5, 0.0, 0.0])
    fresh = mon.evaluate(1.0, {"d1": (p, v)}, None, {"d1": 0.0})
    late = mon.evaluate(1.0, {"d1": (p, v)}, None, {"d1": 0.7})
    assert fresh is None
    assert late is not None and late[0] is Verdict.VIOLATED


class FakeVehicle:
    """What the monitor reads from a vehicle: ``name`` and ``status(now)``."""

    def __init__(self, name: str, pos_ned, age_s: float, origin: GeodeticPoint) -> None:  # type: ignore[no-untyped-def]
        self.name = name
        self.pos = np.asarray(pos_ned, dtype=float)
        self.age_s = age_s
        self.origin = origin

    def status(self, now: float):  # type: ignore[no-untyped-def]
        return types.SimpleNamespace(
            connected=True, position_age_s=self.age_s, mode=Px4Mode.OFFBOARD,
            heartbeat_age_s=0.1, pos_ned_m=self.pos, vel_ned_m_s=np.zeros(3),
            origin=self.origin,
        )  # fmt: skip


class SimTime:
    """The monitor's clock and wait on simulated time: waiting advances the clock, and the run
    is stopped once ``until_s`` has passed (no wall-clock sleeping, exact tick counts)."""

    def __init__(self, until_s: float) -> None:
        self.t = 1000.0
        self.end = self.t + until_s

    def __call__(self) -> float:
        return self.t

    async def wait(self, stop: asyncio.Event, delay_s: float) -> bool:
        self.t += delay_s
        if self.t >= self.end:
            stop.set()
        await asyncio.sleep(0)
        return stop.is_set()


def test_the_run_evaluates_on_its_own_thread_and_reports_late_vehicles() -> None:
    _, spec = fleet_spec(2)
    names = ["d1", "d2"]
    origin = GeodeticPoint(47.397742, 8.545594, 488.0)
    other = GeodeticPoint(47.397800, 8.545700, 489.0)  # d2's EKF origin differs
    origins = {"d1": origin, "d2": other}
    # both far from the obstacle and apart; d2's telemetry is 0.6 s old (late, not lost)
    starts = {"d1": np.array([-1.5, 1.5, 1.5]), "d2": np.array([1.5, -1.5, 1.5])}
    vehicles = [
        FakeVehicle(
            n, enu_to_ned(starts[n], origin, origins[n]), 0.6 if n == "d2" else 0.01, origins[n]
        )
        for n in names
    ]
    sim = SimTime(until_s=0.5)
    mon = SafetyMonitor(always_clauses(spec, names), horizon_s=0.5, clock=sim, wait=sim.wait)
    threads = set()
    evaluate = mon.evaluate

    def spy(*args, **kwargs):  # type: ignore[no-untyped-def]
        threads.add(threading.get_ident())
        return evaluate(*args, **kwargs)

    mon.evaluate = spy  # type: ignore[method-assign]

    async def run() -> tuple[object, int]:
        stop = asyncio.Event()
        loop_thread = threading.get_ident()
        task = asyncio.create_task(
            mon.run(
                None,  # type: ignore[arg-type]  (the fleet: only needed to stop)
                vehicles,
                t0_monotonic_s=sim.t,
                mission_origin=origin,
                origins=origins,
                stop=stop,
                expected_mode=Px4Mode.OFFBOARD,
            )
        )
        return await task, loop_thread

    event, loop_thread = asyncio.run(run())
    # 20 Hz, half a period after each tick: 0.025, 0.075, ..., 0.475 s in 0.5 s
    assert event is None and mon.checks == 10
    assert threads and loop_thread not in threads
    assert mon.stats.stale == {"d2": mon.checks}
    assert mon.stats.stale_max_age_s["d2"] == pytest.approx(0.6)
    assert "d2" in mon.stats.describe_stale() and "0.60 s old" in mon.stats.describe_stale()
    # the frame map the run used is the exact one
    fmap = NedToEnuMap.between(origin, other)
    np.testing.assert_allclose(fmap.position(vehicles[1].pos), starts["d2"], atol=1e-6)


class FakeFleet:
    """What the monitor's stop needs: the vehicles and ``for_each`` (records the action)."""

    def __init__(self, vehicles: list[FakeVehicle]) -> None:
        self.vehicles = vehicles
        self.stopped: list[str] = []

    def __iter__(self):  # type: ignore[no-untyped-def]
        return iter(self.vehicles)

    async def for_each(self, fn, vehicles):  # type: ignore[no-untyped-def]
        self.stopped += [v.name for v in vehicles]
        return {}


def hover_plan(name: str, at_enu: np.ndarray) -> Trajectory:
    c = np.zeros((1, 3, 6))
    c[0, :, 0] = at_enu
    return Trajectory([0.0], [10.0], c, name=name)


@pytest.mark.parametrize("bound", [None, 1.0])
def test_the_tracking_alarm_warns_past_the_margin_once_and_holds_past_the_bound(bound) -> None:  # type: ignore[no-untyped-def]  # fmt: skip
    origin = GeodeticPoint(47.397742, 8.545594, 488.0)
    plans = {"d1": hover_plan("d1", np.array([-1.5, 1.5, 1.5])),
             "d2": hover_plan("d2", np.array([1.5, -1.5, 1.5]))}  # fmt: skip
    # d1 on its plan, d2 1.2 m east and 0.5 m up of it (1.3 m off)
    flown = {"d1": np.array([-1.5, 1.5, 1.5]), "d2": np.array([2.7, -1.5, 2.0])}
    vehicles = [FakeVehicle(n, enu_to_ned(flown[n], origin, origin), 0.02, origin) for n in plans]
    fleet = FakeFleet(vehicles)
    lines: list[str] = []
    sim = SimTime(until_s=0.4)
    mon = SafetyMonitor((), horizon_s=0.5, warn_off_plan_m=0.5, max_off_plan_m=bound,
                        on_warning=lines.append, clock=sim, wait=sim.wait)  # fmt: skip

    async def run():  # type: ignore[no-untyped-def]
        stop = asyncio.Event()
        task = asyncio.create_task(
            mon.run(
                fleet,  # type: ignore[arg-type]
                vehicles,  # type: ignore[arg-type]
                t0_monotonic_s=sim.t,
                mission_origin=origin,
                origins=dict.fromkeys(plans, origin),
                stop=stop,
                plans=plans,
            )
        )
        return await task

    event = asyncio.run(run())
    off = float(np.hypot(1.2, 0.5))
    assert mon.stats.off_plan_max_m["d2"] == pytest.approx(off, abs=1e-6)
    assert mon.stats.off_plan_max_m["d1"] == pytest.approx(0.0, abs=1e-6)
    assert list(mon.stats.warned) == ["d2"] and len(lines) == 1  # once, however many ticks
    assert "d2 is 1.30 m from its plan" in lines[0] and "margin 0.50 m" in lines[0]
    if bound is None:
        assert event is None and mon.checks == 8 and fleet.stopped == []
    else:
        assert event is not None and event.verdict is Verdict.OFF_PLAN
        assert event.vehicles == ("d2",) and fleet.stopped == ["d1", "d2"]
        assert "d2 1.30 m from the plan, more than the bound 1 m" in event.describe()
    assert mon.stats.as_json()["off_plan_warned"]["d2"]["off_m"] == pytest.approx(off, abs=1e-6)  # type: ignore[index]  # fmt: skip


def test_many_runs_at_once_decide_as_each_flight_would_alone() -> None:
    """:meth:`SafetyMonitor.evaluate_runs` (the batch simulator's monitor) against
    :meth:`SafetyMonitor.evaluate` run by run, and the off-plan alarm against the distance
    to the plan computed here."""
    plan = Path(__file__).resolve().parent / "data" / "reach_avoid_2.plan.json"
    from gcs.flight.evaluation import plan_formula
    from planner.planfile import load_plan

    p = load_plan(plan)
    names = [v.name for v in p.vehicles]
    plans = {v.name: v.trajectory for v in p.vehicles}
    mon = SafetyMonitor(always_clauses(plan_formula(p), names), horizon_s=0.5, max_off_plan_m=2.0)
    rng = np.random.default_rng(7)
    seen: set[str] = set()
    for t in np.linspace(0.0, p.horizon_s, 9):
        at = np.array([t])
        ref = np.array([v.trajectory.position(at)[0] for v in p.vehicles])
        vref = np.array([v.trajectory.derivative(at, 1)[0] for v in p.vehicles])
        runs = 60
        pos = ref + rng.normal(0.0, 1.0, (runs, 2, 3)) * rng.uniform(0.0, 2.0, (runs, 1, 1))
        vel = vref + rng.normal(0.0, 1.0, (runs, 2, 3))
        got = mon.evaluate_runs(float(t), names, pos, vel, plans)
        for r in range(runs):
            far = np.linalg.norm(pos[r] - ref, axis=1).max()
            verdict = got.verdict(r)
            seen.add("none" if verdict is None else verdict.value)
            if far > 2.0:
                assert verdict is Verdict.OFF_PLAN and got.value[r] == pytest.approx(far)
                continue
            one = mon.evaluate(float(t), {n: (pos[r, i], vel[r, i]) for i, n in enumerate(names)},
                               plans)  # fmt: skip
            if one is None:
                assert verdict is None
                continue
            v1, clause, rho, ahead = one
            assert verdict is v1
            assert mon.clauses[int(got.clause[r])] is clause
            assert got.value[r] == pytest.approx(rho, abs=1e-12)
            assert got.ahead_s[r] == pytest.approx(ahead, abs=1e-12)
    assert seen == {"none", "off_plan", "violated", "predicted"}  # every branch was met
