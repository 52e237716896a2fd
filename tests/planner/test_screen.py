"""Row screening and row generation (planner.solve.screen): the NLP keeps a row-wise leaf's
steps only where it can bind, and rows it left out that come near binding at a solution join
it, solved again.

References: the leaves' exact robustness traces (planner.stl.exact) for which steps are
kept; the same mission planned with every row for what a screened plan reaches; the exact
check of the plan for whether a keep-out the screen left out is kept.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.optimize import plan
from planner.problem import Problem
from planner.scenario import load_scenario, parse_scenario
from planner.scenario.sections import ScenarioError
from planner.solve.screen import REACH_M, Screen, chosen_screen, near_rows
from planner.stl import parse
from planner.stl.exact import robustness_trace

ZOO = Path(__file__).resolve().parents[2] / "benchmarks" / "scenarios"

#: One drone flies 40 m east to a goal box, south of the line y = 0; a keep-out stands south
#: of that line halfway, 1.5 m below it.
_EAST = {
    "origin": {"lat": 47.4, "lon": 8.5, "alt": 488.0},
    "workspace": {"min": [-30, -30, 0], "max": [30, 30, 20]},
    "regions": {
        "goal": {"kind": "goal", "center": [20, -1, 5], "half_size": 1.0},
        "north": {"kind": "goal", "center": [0, 15, 5], "half_size": 1.0},
        "wall": {"kind": "obstacle", "min": [-1, -4, 0], "max": [1, -1.5, 20]},
    },
    "limits": {"v_max_m_s": 5, "a_max_m_s2": 3},
    "vehicles": [{"name": "d1", "start": [-20, -1, 5]}],
    "timing": {"horizon_s": 30, "segment_s": 2, "Ts_s": 0.25},
    "solver": {"coarse_s": 0, "starts": 1},
}


def _solver(problem: Problem, **kw: Any) -> Problem:
    return dataclasses.replace(problem, solver=dataclasses.replace(problem.solver, **kw))


def test_near_rows_are_the_steps_below_the_reach_and_a_spread_either_side() -> None:
    leaf = parse("a >= 0")
    x = np.array([9.0, 9, 9, 4, 9, 9, 9, 9, 9, 2])
    sig = {"a": x}
    assert np.array_equal(robustness_trace(leaf, sig, 1.0), x)  # the reference itself
    rows = {leaf: [0, 2, 4, 6, 8, 9]}  # the constraint steps: every other, the last
    assert near_rows(rows, sig, 1.0, 5.0, 0) == {leaf: {9}}  # step 3 is no constraint step
    assert near_rows(rows, sig, 1.0, 5.0, 1) == {leaf: {2, 4, 8, 9}}
    assert near_rows(rows, sig, 1.0, 1.0, 3) == {}  # nowhere below 1 m


def test_a_screen_grows_covers_and_keys_by_content() -> None:
    a, b = parse("a >= 0"), parse("b >= 0")
    s = Screen({a: frozenset({1, 2})}, total=20)
    assert s.kept == 2 and s.covers({a: {1}}) and not s.covers({b: {1}})
    g = s.grown({a: {3}, b: {1}})
    assert g.kept == 4 and g.covers({a: {1, 2, 3}, b: {1}}) and g.total == 20
    assert g.key() == Screen({b: frozenset({1}), a: frozenset({3, 2, 1})}, 20).key()
    assert g.key() != s.key()


def test_auto_screens_lines_not_crowded_missions() -> None:
    line = load_scenario(ZOO / "powerline_line20_4drones_300s.yaml")
    rows = {parse("a >= 0"): list(range(3000))}
    few, most = {}, {next(iter(rows)): set(range(2000))}
    assert chosen_screen(line, rows, lambda: few) is not None  # many rows, few near
    assert chosen_screen(line, rows, lambda: most) is None  # most near: all rows
    assert chosen_screen(_solver(line, screen=True), rows, lambda: most) is not None
    assert chosen_screen(_solver(line, screen=False), rows, lambda: few) is None
    small = {parse("a >= 0"): list(range(100))}
    assert chosen_screen(line, small, lambda: few) is None  # too few to pay


def test_a_screened_line_plans_as_well_as_with_every_row_and_keeps_few() -> None:
    problem = load_scenario(ZOO / "powerline_line8_3drones.yaml")
    full = plan(_solver(problem, screen=False))
    screened = plan(_solver(problem, screen=True))
    assert full.success and screened.success, screened.status
    assert screened.stats is not None and screened.stats.screen is not None
    kept, total = screened.stats.screen["kept"], screened.stats.screen["total"]
    assert kept < 0.25 * total
    assert screened.stats.n_constraints < full.stats.n_constraints  # type: ignore[union-attr]
    # the same mission, judged on every clause by the exact check: no less robust (the
    # objective is capped at 0.3 m, both plans reach it)
    assert screened.robustness >= min(full.robustness, 0.3) - 1e-3


def test_a_keep_out_the_screen_left_out_joins_the_nlp_when_the_solution_comes_near() -> None:
    # The start goes around by the north (16 m off the line), so the screen keeps no row of
    # the wall; the spec keeps the drone in a band south of y = 0, which pulls the path down to the
    # wall's rows: they join, and the plan solved again keeps out of the wall.
    goal = "eventually[0, 28] always[0, 1] inside(d1, goal)"
    band = "always[0, 30] (y(d1) <= 0 and y(d1) >= -3)"
    # (from 0.25 s with a row every 0.5 s: the wall's rows are at the odd samples, which
    # only it lifts, and the NLP's point must keep its layout when they join)
    wall_clause = "always[0.25, 30] outside(d1, wall)"
    north = "eventually[0, 14] always[0, 1] inside(d1, north)"
    east = parse_scenario({**_EAST, "spec": [goal, band, wall_clause]}, "east.yaml")
    detour = parse_scenario({**_EAST, "spec": [north, goal]}, "detour.yaml")
    around = plan(detour)
    assert around.success
    # the rows of the wall were left out at first: the detour stays beyond the reach
    p = around.trajectories[0].position(np.arange(0, 30, 0.25))
    gap = np.hypot(np.maximum(np.abs(p[:, 0]) - 1, 0), np.maximum(p[:, 1] + 1.5, 0))
    assert gap.min() > REACH_M
    east = _solver(east, screen=True, constraint_dt_s=0.5)
    got = plan(east, initial_guess=around.decision)
    assert got.stats is not None and got.stats.screen is not None
    assert got.stats.screen["rounds"] >= 1, got.status
    assert got.success, got.status
    wall = {c.text: c.robustness for c in got.clauses}[wall_clause]
    assert wall >= got.robustness > 0
    # with every row from the same start: the same plan quality
    full = plan(_solver(east, screen=False), initial_guess=around.decision)
    assert full.success
    assert got.robustness >= full.robustness - 0.05
    assert got.stats.n_variables == full.stats.n_variables  # type: ignore[union-attr]


def test_solver_screen_takes_auto_true_or_false_and_names_the_key_otherwise() -> None:
    base = {**_EAST, "spec": "always[0, 30] outside(d1, wall)"}
    for value, want in (("auto", None), (True, True), (False, False)):
        data = {**base, "solver": {"screen": value}}
        assert parse_scenario(data, "s.yaml").solver.screen is want
    with pytest.raises(ScenarioError, match=r"solver\.screen.*auto, true or false"):
        parse_scenario({**base, "solver": {"screen": "sometimes"}}, "s.yaml")


def test_gcs_plan_says_how_many_rows_it_kept(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from gcs import cli

    scenario = ZOO / "powerline_line8_3drones.yaml"  # auto screens it (749 of 5,973 rows)
    assert cli.main(["plan", str(scenario), "-o", str(tmp_path / "p.json")]) == 0
    out = capsys.readouterr().out
    assert "rows screened: 749 of 5,973 kept" in out
    assert cli.main(["plan", str(scenario), "-o", str(tmp_path / "p.json"), "--json"]) == 0
    data = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert data["stats"]["screen"] == {"kept": 749, "total": 5973, "rounds": 0}
