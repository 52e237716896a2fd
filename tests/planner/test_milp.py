"""The combinatorial stage (planner.milp) against independent references: the exact STL
semantics on the coarse waypoints (soundness), optima worked by hand, stlpy's certified
optimum, and geometry that admits no plan (conflicts)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from planner.milp import CoarseStatus, find_conflict, solve_coarse
from planner.milp.solve import problem_formulas
from planner.problem import Clause, Problem
from planner.scenario import load_scenario
from planner.stl import conjunction

ZOO = Path(__file__).resolve().parents[2] / "benchmarks" / "scenarios"
TOL = 1e-6


def scenario(tmp_path: Path, spec: list[str], *, regions: str = "", vehicles: str = "",
             horizon: float = 10.0, extra: str = "") -> Problem:  # fmt: skip
    """A Problem from a small YAML scenario (1 s samples, per-axis limits 2 m/s, 2 m/s^2)."""
    regions = regions or "  goal: {kind: goal, min: [5, 0, 1], max: [7, 3, 5]}\n"
    vehicles = vehicles or "  - {name: d1, start: [0, 0, 2]}\n  - {name: d2, start: [0, 4, 2]}\n"
    text = (
        "name: milp_test\norigin: {lat: 47.0, lon: 8.0, alt: 400.0}\n"
        "workspace: {min: [-10, -10, 0], max: [20, 20, 10]}\n"
        f"regions:\n{regions}"
        "limits: {v_max_m_s: [2, 2, 2], a_max_m_s2: [2, 2, 2]}\n"
        f"vehicles:\n{vehicles}"
        f"timing: {{horizon_s: {horizon:g}, segment_s: 1, Ts_s: 1, check_dt_s: 1, end: free}}\n"
        "separation_m: 1.0\nepsilon: 0.01\nmodel: double_integrator\n"
        f"{extra}spec:\n" + "".join(f"  - formula: '{s}'\n" for s in spec)
    )
    path = tmp_path / "milp_test.yaml"
    path.write_text(text)
    return load_scenario(path)


def exact(problem: Problem, waypoints: dict[str, np.ndarray], dt: float) -> float:
    """The exact robustness (planner.stl) of the spec on the coarse samples."""
    return conjunction(list(problem_formulas(problem))).robustness(waypoints, dt)


# --------------------------------------------------------------------------- soundness

REGIONS = (
    "  box: {kind: goal, min: [2, 1, 1], max: [4, 3, 3]}\n"
    "  pole: {kind: pole, center: [3, 5], radius: 0.8, z: [0, 6]}\n"
    "  wall: {kind: obstacle, min: [6, -2, 0], max: [7, 8, 6]}\n"
)

ATOMS = (
    "x(d1) >= 3",
    "y(d2) <= 2.5",
    "z(d1) - z(d2) > 0.5",
    "2 * x(d2) + y(d1) / 2 < 7",
    "-x(d1) <= -1",
    "alt(d2) >= 2.5",
    "inside(d1, box)",
    "inside(d2, pole)",
    "outside(d1, pole)",
    "outside(d2, wall)",
    "inside(d1, box) >= 0.3",
    "dist(d1, d2) >= 2",
    "dist(d1, d2) <= 3",
    "x(d1) + dist(d1, d2) >= 4",
)


@st.composite
def spec_texts(draw: st.DrawFn, depth: int = 3) -> str:
    if depth == 0 or draw(st.integers(0, 3)) == 0:
        return draw(st.sampled_from(ATOMS))
    kind = draw(st.sampled_from(["not", "and", "or", "implies", "always", "eventually", "until"]))
    sub = spec_texts(depth - 1)
    a = draw(st.integers(0, 2))
    b = a + draw(st.integers(0, 1))
    if kind == "not":
        return f"not ({draw(sub)})"
    if kind in ("and", "or", "implies"):
        return f"({draw(sub)}) {kind} ({draw(sub)})"
    if kind == "until":
        return f"({draw(sub)}) until[{a},{b}] ({draw(sub)})"
    return f"{kind}[{a},{b}] ({draw(sub)})"


@pytest.fixture(scope="module")
def soundness_problem(tmp_path_factory: pytest.TempPathFactory) -> Problem:
    return scenario(tmp_path_factory.mktemp("milp"), ["true"], regions=REGIONS)


@settings(
    max_examples=80,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(spec_texts())
@pytest.mark.slow
def test_incumbent_is_at_least_as_robust_as_reported(soundness_problem: Problem, text: str):
    problem = dataclasses.replace(soundness_problem, clauses=(Clause("spec[0]", text),))
    res = solve_coarse(problem, time_limit_s=1.0)
    if res.status is CoarseStatus.NOT_ENCODABLE:
        assert "until" in res.message  # a negated until is the one refusal here
        return
    if not res.success or math.isinf(res.robustness):
        return
    assert res.bound >= res.robustness - TOL
    got = exact(problem, dict(res.waypoints_enu_m), res.dt_s)
    assert got >= res.robustness - TOL, (text, got, res.robustness)


@pytest.mark.parametrize(
    "name",
    [
        "stlpy_reach_avoid_regions",
        "stlpy_either_or_halfplanes",
        "stlpy_narrow_passage_regions",
        "two_drones_one_unreachable_hover",
        "powerline_ground_start_2drones",
        "powerline_until_clearance_1drone",
    ],
)
@pytest.mark.slow
def test_zoo_incumbents_are_sound(name: str):
    problem = load_scenario(ZOO / f"{name}.yaml")
    res = solve_coarse(problem, time_limit_s=6.0)
    assert res.success, res
    wp = dict(res.waypoints_enu_m)
    for v in problem.vehicles:
        assert wp[v.name].shape == (len(res.times_s), 3)
        np.testing.assert_allclose(wp[v.name][0], v.start_enu_m)
    assert exact(problem, wp, res.dt_s) >= res.robustness - TOL


def test_coarse_path_respects_the_relaxed_limits(tmp_path: Path):
    problem = scenario(tmp_path, ["eventually[0,10] inside(d1, goal)"])
    res = solve_coarse(problem, time_limit_s=5.0)
    p = res.waypoints_enu_m["d1"]
    dt = res.dt_s
    assert np.all(np.abs(np.diff(p, axis=0)) <= 2.0 * dt + 1e-6)
    assert np.all(np.abs(np.diff(p, 2, axis=0)) <= 2.0 * dt**2 + 1e-6)
    assert np.all(np.abs(p[1] - p[0]) <= 0.5 * 2.0 * dt**2 + 1e-6)  # from rest


# --------------------------------------------------------------------------- optimality


def test_box_goal_within_reach_is_its_smallest_half_size(tmp_path: Path):
    # goal half-sizes (1, 1.5, 2): the Chebyshev margin is at most 1, reached at its centre
    problem = scenario(tmp_path, ["eventually[0,10] inside(d1, goal)"])
    res = solve_coarse(problem, time_limit_s=5.0)
    assert res.status is CoarseStatus.OPTIMAL
    assert res.robustness == pytest.approx(1.0, abs=1e-6)
    assert res.bound == pytest.approx(1.0, abs=1e-4)
    assert exact(problem, dict(res.waypoints_enu_m), res.dt_s) >= 1.0 - TOL


def test_robustness_cap_stops_the_maximisation(tmp_path: Path):
    problem = scenario(tmp_path, ["eventually[0,10] inside(d1, goal)"])
    res = solve_coarse(problem, time_limit_s=5.0, robustness_cap_m=0.25)
    assert res.status is CoarseStatus.OPTIMAL
    assert res.robustness == pytest.approx(0.25, abs=1e-6)


@pytest.mark.parametrize("spelling", ["regions", "halfplanes"])
@pytest.mark.slow
def test_stepping_stones_reach_stlpys_certified_optimum(spelling: str):
    problem = load_scenario(ZOO / f"stlpy_stepping_stones_{spelling}.yaml")
    res = solve_coarse(problem, time_limit_s=10.0)
    assert res.success
    # stlpy (Gurobi, its discretisation): 0.05272; the coarse model relaxes the dynamics,
    # so its optimum is at least that
    assert res.robustness >= 0.05272 - 1e-4
    assert res.robustness <= 0.06
    assert exact(problem, dict(res.waypoints_enu_m), res.dt_s) >= res.robustness - TOL


# --------------------------------------------------------------------------- conflicts

CUBE = "  cube: {kind: goal, min: [4, 2, 2], max: [5, 3, 3]}\n"
CONFLICT_SPEC = [
    "eventually[0,10] x(d1) >= 1",
    "always[6,8] inside(d1, cube)",
    "always[0,10] z(d2) >= 0.5",
    "always[6,8] inside(d2, cube)",
    "always[0,10] dist(d1, d2) >= 2",
]


def test_two_drones_in_one_cube_two_metres_apart_is_infeasible(tmp_path: Path):
    problem = scenario(tmp_path, CONFLICT_SPEC, regions=CUBE)
    res = solve_coarse(problem, time_limit_s=5.0, min_robustness=problem.epsilon)
    assert res.status is CoarseStatus.INFEASIBLE
    plain = solve_coarse(problem, time_limit_s=5.0)  # maximised instead: below epsilon
    assert plain.bound < problem.epsilon


def test_conflict_names_the_three_clauses(tmp_path: Path):
    problem = scenario(tmp_path, CONFLICT_SPEC, regions=CUBE)
    conflict = find_conflict(problem, time_limit_s=10.0, per_solve_s=2.0)
    assert conflict is not None
    assert conflict.indices == (1, 3, 4)
    assert [c.text for c in conflict.clauses] == [CONFLICT_SPEC[i] for i in (1, 3, 4)]
    assert conflict.irreducible


def test_feasible_spec_has_no_conflict(tmp_path: Path):
    problem = scenario(tmp_path, CONFLICT_SPEC[:4], regions=CUBE)
    assert find_conflict(problem, time_limit_s=5.0) is None


# --------------------------------------------------------------------------- allocation

POLES = (
    "  p1: {kind: inspection, min: [-8, -1, 2], max: [-6, 1, 4]}\n"
    "  p2: {kind: inspection, min: [-8, 6, 2], max: [-6, 8, 4]}\n"
    "  p3: {kind: inspection, min: [14, -1, 2], max: [16, 1, 4]}\n"
    "  p4: {kind: inspection, min: [14, 6, 2], max: [16, 8, 4]}\n"
)
DRONES = "  - {name: d1, start: [-4, 3, 3]}\n  - {name: d2, start: [12, 3, 3]}\n"


@pytest.mark.slow
def test_every_pole_is_inspected_by_a_drone_that_goes_there(tmp_path: Path):
    # each drone can reach the two poles on its side in 14 s, not those 18 m away as well
    spec = [
        f"eventually[0,12] (always[0,2] inside(d1, {p}) or always[0,2] inside(d2, {p}))"
        for p in ("p1", "p2", "p3", "p4")
    ]
    problem = scenario(tmp_path, spec, regions=POLES, vehicles=DRONES, horizon=14.0)
    res = solve_coarse(problem, time_limit_s=8.0)
    assert res.success and res.robustness > 0
    wp, dt = dict(res.waypoints_enu_m), res.dt_s
    assert exact(problem, wp, dt) >= res.robustness - TOL
    formulas = problem_formulas(problem)
    for f in formulas:
        options = f.child.operands  # type: ignore[attr-defined]
        visits = [max(opt.robustness_trace(wp, dt)[: round(12 / dt) + 1]) for opt in options]
        assert max(visits) >= res.robustness - TOL  # some drone is there for 2 s
    assert exact(problem, wp, dt) > 0


# --------------------------------------------------------------------------- refusals


def test_nonlinear_and_negated_until_are_not_encodable(tmp_path: Path):
    for text in (
        "eventually[0,5] (x(d1) * y(d1) >= 1)",
        "not ((x(d1) >= 1) until[0,3] (y(d1) >= 1))",
    ):
        problem = scenario(tmp_path, [text])
        res = solve_coarse(problem, time_limit_s=2.0)
        assert res.status is CoarseStatus.NOT_ENCODABLE
        assert not res.success and res.message


def test_bad_arguments_raise(tmp_path: Path):
    problem = scenario(tmp_path, ["eventually[0,10] inside(d1, goal)"])
    with pytest.raises(ValueError):
        solve_coarse(problem, time_limit_s=0.0)
    with pytest.raises(ValueError):
        solve_coarse(problem, time_limit_s=1.0, clauses=[3])
