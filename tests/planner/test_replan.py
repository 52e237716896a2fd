"""Replanning after a vehicle left (:mod:`planner.replan`, :mod:`planner.dynamics.prefix`):
the spec amended clause by clause, the flown part kept exactly, the rest planned."""

from __future__ import annotations

import dataclasses
import itertools
import re

import numpy as np
import pytest
import yaml

from planner.dynamics.prefix import Prefix, PrefixError, fixed_entries
from planner.optimize import plan
from planner.problem import DynamicsModel, Problem
from planner.replan import (
    Departure,
    ReplanError,
    amend,
    reassign_candidates,
    replan,
    switch_time,
)
from planner.results import PlanResult
from planner.scenario import parse_scenario
from planner.scenario.spec import clause_formulas
from planner.solve.plan_check import make_model
from planner.spec.regions import Region, RegionKind

pytestmark = pytest.mark.slow  # whole solves

# Three drones along a line: pole a is inspected by some drone (an allocation), d3 also
# inspects b; every drone stays in the workspace and 1 m from every other.
SCENARIO = """
name: replan_line
origin: {lat: 47.397742, lon: 8.545594, alt: 488.0}
workspace: {min: [-4, -6, 0.5], max: [26, 6, 8]}
regions:
  a: {kind: inspection, min: [9, 2, 3], max: [11, 4, 5]}
  b: {kind: inspection, min: [19, -4, 3], max: [21, -2, 5]}
limits: {v_max_m_s: [4, 4, 2], a_max_m_s2: [2, 2, 1.5]}
vehicles:
  count: 3
  name: "d{i}"
  starts: {positions: [[0, -3, 4], [0, 0, 4], [0, 3, 4]]}
timing: {horizon_s: 20, segment_s: 1, Ts_s: 0.25, check_dt_s: 0.05}
separation_m: 1.0
epsilon: 0.01
model: minimum_jerk
solver: {coarse_s: 0}  # no combinatorial stage beside the NLP: the same plan on any load
spec:
  - formula: >-
      eventually[0, 18] (always[0, 1] inside(d1, a) or always[0, 1] inside(d2, a)
      or always[0, 1] inside(d3, a))
  - formula: eventually[0, 18] always[0, 1] inside(d3, b)
  - each: d in all
    formula: always[0, 20] inside(d, workspace)
  - each: (p, q) in pairs(all)
    formula: always[0, 20] dist(p, q) >= 1
"""


@pytest.fixture(scope="module")
def planned() -> PlanResult:
    problem = parse_scenario(yaml.safe_load(SCENARIO), "replan_line.yaml")
    result = plan(problem)
    assert result.success, result.status
    return result


def _trajectories(result: PlanResult) -> dict:
    return {tr.name: tr for tr in result.trajectories}


def _who_inspects_a(result: PlanResult) -> str:
    """The drone whose option of the allocation clause holds best on the plan."""
    problem = result.problem
    dt = problem.timing.check_dt_s
    t = np.arange(round(problem.timing.horizon_s / dt) + 1) * dt
    sig = {tr.name: tr.position(t) for tr in result.trajectories}
    alloc = clause_formulas(problem)[0]
    options = alloc.children[0].children  # eventually[0, 18] (option or option or option)
    best = max(range(3), key=lambda i: options[i].robustness_trace(sig, dt).max())
    return f"d{best + 1}"


def _departure(result: PlanResult, name: str, t_s: float) -> Departure:
    pos = np.ravel(_trajectories(result)[name].position(t_s))
    return Departure(name, t_s, (float(pos[0]), float(pos[1]), float(pos[2])), "link lost")


def test_the_amended_spec_drops_takes_over_and_discharges_clause_by_clause(
    planned: PlanResult,
) -> None:
    trs = _trajectories(planned)
    # d3 lost at the start: its own inspection is dropped, its separations held until then
    a = amend(planned.problem, trs, [_departure(planned, "d3", 0.5)], 4.0)
    assert a.dropped == (
        "eventually[0, 18] always[0, 1] inside(d3, b)",
        "always[0, 20] inside(d3, workspace)",
    )
    assert set(a.discharged) == {
        "always[0, 20] dist(d1, d3) >= 1",
        "always[0, 20] dist(d2, d3) >= 1",
    }
    # nobody has inspected a by 0.5 s: d3's option of the allocation goes, the others must
    assert a.taken_over == (planned.problem.clauses[0].text,)
    kept = [c.text for c in a.problem.clauses]
    assert not any(re.search(r"\bd3\b", text) for text in kept)  # left_d3 is a region
    assert [v.name for v in a.problem.vehicles] == ["d1", "d2"]
    assert a.problem.groups["all"] == ("d1", "d2")
    # the allocation, pruned to the drones that fly on, is still the first clause
    assert kept[0] == ("eventually[0,18] (always[0,1] inside(d1, a) or always[0,1] inside(d2, a))")
    # one keep-out where d3 stops, for each drone that flies on, from the switch on
    assert [r.name for r in a.keep_outs] == ["left_d3"]
    assert kept[-2:] == [
        "always[4, 20] outside(d1, left_d3)",
        "always[4, 20] outside(d2, left_d3)",
    ]
    box = a.keep_outs[0]
    p3 = np.ravel(trs["d3"].position(0.5))
    assert np.all(np.asarray(box.lo_enu_m[:2]) <= p3[:2] - 1.0 + 1e-9)
    assert np.all(np.asarray(box.hi_enu_m[:2]) >= p3[:2] + 1.0 - 1e-9)
    assert box.lo_enu_m[2] <= 0.0  # from the ground: it may land


def test_a_vehicle_lost_after_its_inspection_leaves_it_discharged(planned: PlanResult) -> None:
    inspector = _who_inspects_a(planned)
    problem, trs = planned.problem, _trajectories(planned)
    dt = problem.timing.check_dt_s
    t = np.arange(round(problem.timing.horizon_s / dt) + 1) * dt
    alloc = clause_formulas(problem)[0]
    sig = {n: tr.position(t) for n, tr in trs.items()}
    option = alloc.children[0].children[int(inspector[1]) - 1]
    trace = option.robustness_trace(sig, dt)
    done = float(t[np.argmax(trace > 0)]) + 1.0  # its hover at a is over
    a = amend(problem, trs, [_departure(planned, inspector, done + 0.5)], done + 3.0)
    assert alloc_text(problem) in a.discharged
    assert alloc_text(problem) not in a.taken_over


def alloc_text(problem: Problem) -> str:
    return problem.clauses[0].text


def test_the_replan_keeps_the_flown_part_exactly_and_meets_what_is_left(
    planned: PlanResult,
) -> None:
    trs = _trajectories(planned)
    lost = "d3"
    switch = switch_time(planned.problem, 3.2, 3.0)
    assert switch == 7.0  # the first waypoint at least the budget after the departure
    got = replan(planned.problem, trs, [_departure(planned, lost, 2.0)], switch)
    assert got.result.success, got.result.status
    new = got.trajectories
    assert set(new) == {"d1", "d2"}
    t = np.linspace(0.0, switch, 200)
    for name, tr in new.items():
        assert np.abs(tr.position(t) - trs[name].position(t)).max() < 1e-6
        assert np.abs(tr.velocity(t) - trs[name].velocity(t)).max() < 1e-6
    # independently: every amended clause holds on the new plan (exact semantics)
    amended = got.amendment.problem
    dt = amended.timing.check_dt_s
    tt = np.arange(round(amended.timing.horizon_s / dt) + 1) * dt
    sig = {n: tr.position(tt) for n, tr in new.items()}
    rob = [f.robustness(sig, dt) for f in clause_formulas(amended)]
    assert min(rob) >= amended.epsilon
    assert min(rob) == pytest.approx(got.result.robustness, abs=1e-6)


def test_a_keep_out_over_a_vehicle_that_flies_on_is_no_plan(planned: PlanResult) -> None:
    trs = _trajectories(planned)
    # d3 "stops" where d2 is at the switch: d2 cannot be outside it there
    at = np.ravel(trs["d2"].position(6.0))
    d = Departure("d3", 5.9, (float(at[0]), float(at[1]), float(at[2])), "link lost")
    got = replan(planned.problem, trs, [d], 6.0, time_limit_s=20)
    assert not got.result.success
    assert got.result.robustness < 0


def test_prefix_entries_are_the_waypoints_before_the_switch(planned: PlanResult) -> None:
    problem = planned.problem
    model = make_model(problem)
    names = [v.name for v in problem.vehicles]
    idx, vals = fixed_entries(model, names, Prefix(3.0, _trajectories(planned)))
    # 3 waypoints (t = 1, 2, 3 s) x position, velocity, acceleration x 3 axes x 3 vehicles
    assert idx.size == vals.size == 3 * 3 * 3 * 3
    z = np.asarray(planned.decision)[: model.n_dec * 3 * 3]
    assert np.abs(z[idx] - vals).max() < 1e-8


def test_what_cannot_be_replanned_is_refused_in_one_line(planned: PlanResult) -> None:
    problem, trs = planned.problem, _trajectories(planned)
    dep = _departure(planned, "d1", 1.0)
    with pytest.raises(ReplanError, match="unknown vehicle"):
        amend(problem, trs, [dataclasses.replace(dep, vehicle="d9")], 3.0)
    with pytest.raises(ReplanError, match="no vehicle is left"):
        amend(problem, trs, [dataclasses.replace(dep, vehicle=n) for n in trs], 3.0)
    with pytest.raises(ReplanError, match="outside the horizon"):
        amend(problem, trs, [dep], 25.0)
    di = dataclasses.replace(problem, model=DynamicsModel.DOUBLE_INTEGRATOR)
    with pytest.raises(ReplanError, match="minimum-jerk"):
        replan(di, trs, [dep], 3.0)
    with pytest.raises(PrefixError, match="minimum-jerk"):
        fixed_entries(make_model(di), ["d1"], Prefix(3.0, trs))


def test_a_lost_vehicles_own_inspection_is_handed_to_the_nearest_that_can_and_done(
    planned: PlanResult,
) -> None:
    trs = _trajectories(planned)
    switch = 4.0
    a = amend(planned.problem, trs, [_departure(planned, "d3", 0.5)], switch)
    order = reassign_candidates(a, trs)
    # nearest to b (the only region d3's own dropped clauses name) at the switch first
    b = a.problem.region("b")

    def gap(name: str) -> float:
        p = np.ravel(trs[name].position(switch))
        return float(
            np.linalg.norm(
                np.maximum(0.0, np.maximum(np.subtract(b.lo_enu_m, p), np.subtract(p, b.hi_enu_m)))
            )
        )

    assert sorted(order) == ["d1", "d2"] and gap(order[0]) <= gap(order[1])
    got = replan(
        planned.problem, trs, [_departure(planned, "d3", 0.5)], switch, reassign_clauses=True
    )
    am = got.amendment
    assert am.reassigned_to in ("d1", "d2") and got.result.success, got.result.status
    assert am.reassigned == (
        "eventually[0, 18] always[0, 1] inside(d3, b)",
        "always[0, 20] inside(d3, workspace)",
    )
    assert am.dropped == ()
    # the workspace clause the receiver has already is not added twice
    texts = [c.text for c in am.problem.clauses]
    assert texts.count(f"always[0, 20] inside({am.reassigned_to}, workspace)") == 1
    # independently: the receiver hovers in b for a second within [0, 18]
    dt = 0.05
    t = np.arange(0.0, 20.0 + dt / 2, dt)
    p = got.trajectories[am.reassigned_to].position(t)
    inside = np.all((p >= np.asarray(b.lo_enu_m)) & (p <= np.asarray(b.hi_enu_m)), axis=1)
    run = max((len(list(g)) for k, g in itertools.groupby(inside) if k), default=0)
    assert run * dt >= 1.0


def test_a_region_closed_in_flight_is_kept_out_of_from_the_switch_or_is_no_plan(
    planned: PlanResult,
) -> None:
    trs = _trajectories(planned)
    problem = planned.problem
    far = Region("closed", RegionKind.NO_FLY, (22.0, 4.0, 0.0), (25.0, 6.0, 8.0))
    got = replan(problem, trs, [], 5.0, keep_outs=[far])
    assert got.result.success, got.result.status
    texts = [c.text for c in got.amendment.problem.clauses]
    assert [t for t in texts if "closed" in t] == [
        f"always[5, 20] outside({n}, closed)" for n in ("d1", "d2", "d3")
    ]
    assert [v.name for v in got.amendment.problem.vehicles] == ["d1", "d2", "d3"]
    t = np.linspace(0.0, 5.0, 100)
    for name, tr in got.trajectories.items():
        assert np.abs(tr.position(t) - trs[name].position(t)).max() < 1e-6
    # closed over d1 where it is at the switch: no plan can be out of it then
    at = np.ravel(trs["d1"].position(5.0))
    over = Region("over", RegionKind.NO_FLY, tuple(at - 1.0), tuple(at + 1.0))
    assert not replan(problem, trs, [], 5.0, keep_outs=[over], time_limit_s=20).result.success
    with pytest.raises(ReplanError, match="already a region"):
        amend(problem, trs, [], 5.0, [dataclasses.replace(far, name="a")])
    with pytest.raises(ReplanError, match="nothing to replan"):
        amend(problem, trs, [], 5.0)
