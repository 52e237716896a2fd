"""The coarse plan as a path the smooth model can follow: an ``always`` held over the steps
that cover its window, legs kept out of polygon keep-outs, the smoothest of equally robust
paths, and a fit within the NLP's own limit polygon (planner.milp, planner.solve.coarse_fit).
Checked against the exact semantics on the coarse samples, shapely's geometry of the legs,
and the missions of the issue's classes planned end to end."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import LineString, Polygon

from planner.milp import CoarseStatus, solve_coarse
from planner.milp import solve as solve_mod
from planner.optimize import make_model, plan
from planner.scenario import load_scenario
from planner.solve.coarse_fit import waypoint_guess
from planner.solve.path_fit import fit_within_limits
from planner.solve.plan_check import initial_states
from tests.planner.test_milp import TOL, ZOO, exact, scenario


def _inside(p: np.ndarray, lo: list[float], hi: list[float], margin: float = 0.0) -> np.ndarray:
    return np.all((p >= np.asarray(lo) + margin) & (p <= np.asarray(hi) - margin), axis=1)


def test_an_always_shorter_than_a_step_holds_at_the_steps_that_cover_it(tmp_path: Path):
    # always[0, 1] at 2 s steps: inside the window [t, t + 1] there is one sample; the
    # covering steps are two, and the straight leg between them stays in the (convex) goal
    problem = scenario(tmp_path, ["eventually[0,8] always[0,1] inside(d1, goal)"])
    covered = solve_coarse(problem, time_limit_s=5.0, dt_c=2.0)
    inner = solve_coarse(problem, time_limit_s=5.0, dt_c=2.0, cover=False)
    assert covered.status is inner.status is CoarseStatus.OPTIMAL
    assert covered.cover and not inner.cover
    lo, hi = [5, 0, 1], [7, 3, 5]
    for res, runs in ((covered, 2), (inner, 1)):
        p = res.waypoints_enu_m["d1"]
        inside = _inside(p, lo, hi, res.robustness - TOL).astype(int)
        longest = max(len(r) for r in "".join(map(str, inside)).split("0"))
        assert longest >= runs
        assert exact(problem, dict(res.waypoints_enu_m), res.dt_s) >= res.robustness - TOL
    # the covered plan reaches the goal a step earlier than it must stay: its robustness is
    # still a lower bound of the exact one, and no higher than the inner reading's
    assert covered.robustness <= inner.robustness + TOL


U_REGIONS = (
    "  u: {kind: obstacle, polygon: [[0, 0], [6, 0], [6, 6], [4, 6], [4, 2], [2, 2], [2, 6],"
    " [0, 6]], z: [0, 40]}\n"
    "  goal: {kind: goal, min: [2.5, -4, 1], max: [3.5, -3, 3]}\n"
)


def test_legs_between_samples_stay_out_of_a_polygon_keep_out(tmp_path: Path):
    # a U open to the north, the vehicle in its cup, the goal south of its 2 m bottom: at
    # 2 m/s and 2 s steps a leg could jump the bottom; held legs go round a side
    problem = scenario(
        tmp_path,
        ["eventually[0,20] always[0,2] inside(d1, goal)", "always[0,24] outside(d1, u)"],
        regions=U_REGIONS,
        vehicles="  - {name: d1, start: [3, 4, 2]}\n",
        horizon=24.0,
    )
    u = Polygon([(0, 0), (6, 0), (6, 6), (4, 6), (4, 2), (2, 2), (2, 6), (0, 6)])
    res = solve_coarse(problem, time_limit_s=10.0, dt_c=2.0)
    assert res.success and res.robustness >= problem.epsilon
    p = res.waypoints_enu_m["d1"]
    for a, b in itertools.pairwise(p):
        leg = LineString([a[:2], b[:2]]) if np.any(a[:2] != b[:2]) else None
        if leg is not None:
            assert leg.distance(u) >= res.robustness - 1e-6, (a, b)
    assert exact(problem, dict(res.waypoints_enu_m), res.dt_s) >= res.robustness - TOL


@pytest.mark.slow
def test_the_smoothest_of_equally_robust_paths_is_returned(monkeypatch):
    problem = load_scenario(ZOO / "stlpy_stepping_stones_halfplanes.yaml")
    # proven optimal in a few seconds; the limit is room for a busy machine (HiGHS ends at
    # the proof)
    smooth = solve_coarse(problem, time_limit_s=60.0)
    monkeypatch.setattr(solve_mod, "_smoothest", lambda _b, _m, x, *_a: x)
    raw = solve_coarse(problem, time_limit_s=60.0)
    assert smooth.status is raw.status is CoarseStatus.OPTIMAL
    assert smooth.robustness == pytest.approx(raw.robustness, abs=1e-6)

    def bending(res):  # summed absolute second differences
        return sum(np.abs(np.diff(w, 2, axis=0)).sum() for w in res.waypoints_enu_m.values())

    assert bending(smooth) <= bending(raw) + 1e-6
    # the smoothing keeps the choices and the robustness, under the exact semantics
    assert exact(problem, dict(smooth.waypoints_enu_m), smooth.dt_s) >= smooth.robustness - TOL


def test_the_fit_follows_a_coarse_path_at_full_speed_along_an_axis():
    """A 5 m/s horizontal limit: the coarse plan flies 4.8 m/s along x.  The per-axis box of
    the initial guess (3.5 m/s per axis) falls metres behind; the fit within the NLP's polygon
    keeps up."""
    problem = load_scenario(ZOO / "powerline_alloc6_3drones.yaml")
    problem = dataclasses.replace(problem, vehicles=problem.vehicles[:1], clauses=())
    model = make_model(problem)
    x0s = initial_states(problem, model)
    start = np.asarray(problem.vehicles[0].start_enu_m, dtype=float)
    times = np.arange(0.0, 61.0, 4.0)
    # from rest, 4.8 m/s east from 4 s to 40 s, then hold
    x = np.interp(times, [0, 4, 40, 60], [0, 9.6, 182.4, 182.4]) * (150 / 182.4)
    path = start + np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    z = waypoint_guess(problem, model, x0s, times, [path])
    t_model = np.asarray(model.times_s)
    target = np.column_stack([np.interp(t_model, times, path[:, a]) for a in range(3)])
    pos = np.asarray(model.Mp) @ z.reshape(3, -1).T + np.asarray(model.Np) @ x0s[0]
    box = fit_within_limits(model, target, x0s[0], problem.vehicles[0], problem.workspace)
    pos_box = np.asarray(model.Mp) @ box + np.asarray(model.Np) @ x0s[0]
    lag, lag_box = np.abs(pos - target).max(), np.abs(pos_box - target).max()
    assert lag < 3.0 < 10.0 < lag_box, (lag, lag_box)


@pytest.mark.parametrize("name", ["powerline_row_implies_2drones", "patrol_u_revisits_1drone"])
@pytest.mark.slow
def test_the_issues_implication_and_revisit_missions_plan_with_the_stage(name: str):
    """Issue 40's classes 3 and 4: without the stage both end in a local optimum (under the
    conductors at -0.50; through the U at -4.99, benchmarks/bench_zoo.py --coarse-s 0)."""
    problem = load_scenario(ZOO / f"{name}.yaml")
    res = plan(problem, time_limit_s=60.0)
    assert res.success, res.status
    assert res.robustness >= problem.epsilon
    assert res.stats is not None and res.stats.coarse is not None
    assert res.stats.coarse["status"] == "optimal"
