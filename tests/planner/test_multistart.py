"""The multi-start (planner.solve.guess.starts, planner.optimize.plan): when the first guess's plan
falls short, other route choices and shifted legs are solved in turn and the best exact
robustness wins.

References: stlpy's benchmarks as scenarios (benchmarks/scenarios), whose optima a mixed-integer
program certifies (EitherOr and ReachAvoid 0.5, DoorPuzzle 0.4; HiGHS over stlpy's own formula
objects, the files' headers): a plan can reach them but never exceed them.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from planner.optimize import plan
from planner.problem import Problem
from planner.scenario import load_scenario, parse_scenario
from planner.scenario.sections import ScenarioError
from planner.solve.guess import starts, visit_targets
from planner.stl import conjunction

ZOO = Path(__file__).resolve().parents[2] / "benchmarks" / "scenarios"


def _zoo(name: str, **solver: Any) -> Problem:
    """A zoo scenario with these solver options; the initial guess's starts only (these
    tests are about them: no combinatorial stage unless asked for)."""
    solver.setdefault("coarse_s", 0.0)
    problem = load_scenario(ZOO / f"{name}.yaml")
    return dataclasses.replace(problem, solver=dataclasses.replace(problem.solver, **solver))


def _route(problem: Problem, start: Any) -> list[str]:
    formula = conjunction(list(problem.formulas))
    x0 = np.asarray(problem.vehicles[0].start_enu_m, dtype=float)
    return [pl.name for pl in visit_targets(formula, "d1", problem, x0, start.choices("d1"))]


def test_the_starts_are_the_nearest_route_then_runners_up_and_shifted_legs() -> None:
    problem = load_scenario(ZOO / "stlpy_either_or_regions.yaml")
    formula = conjunction(list(problem.formulas))
    got = list(starts(problem, formula, limit=10))
    # first: the nearest choice everywhere (target1 is 4.5 m away, target2 6.3 m)
    assert got[0].flips == frozenset() and got[0].offset_m == 0.0
    assert _route(problem, got[0]) == ["inside(d1, target1)", "inside(d1, goal)"]
    routes = [tuple(_route(problem, s)) for s in got if s.flips]
    # each flipped start is a route no start before it had; the cheapest detour first
    assert len(set(routes)) == len(routes)
    assert routes[0] == ("inside(d1, target2)", "inside(d1, goal)")
    # the first route's legs shifted to either side by the obstacle's half-width (1 m)
    assert sorted(s.offset_m for s in got if not s.flips) == [-1.0, 0.0, 1.0]
    # at most the limit, the first included
    assert len(list(starts(problem, formula, limit=2))) == 2
    assert len(list(starts(problem, formula, limit=1))) == 1


def test_a_runner_up_option_meets_what_the_nearest_choices_do_not(monkeypatch) -> None:
    # Stepping stones (half-planes), with the guess blind to "stay on the stones"
    # (planner.solve.guess.stay_within, which now routes over them at the first start): the
    # nearest stones first leave the plan short of the mission; turning one choice to its
    # runner-up stone meets it.
    # (no lexicographic rounds: they would raise the other clauses of the failed plan)
    import planner.solve.guess

    monkeypatch.setattr(planner.solve.guess, "stay_within", lambda *_: [])
    one = plan(_zoo("stlpy_stepping_stones_halfplanes", starts=1, lexicographic_rounds=0))
    assert not one.success and one.stats is not None and one.stats.starts == 1
    many = plan(_zoo("stlpy_stepping_stones_halfplanes"))
    assert many.success, many.status
    assert many.stats is not None and many.stats.starts >= 2
    assert 0.0 <= many.robustness <= 0.05272 + 1e-6  # the certified optimum (0.05272) bounds it
    # the status says which start the plan came from
    assert f"of {many.stats.starts}: d1 via " in many.status
    # the iterations of every start are counted
    assert many.iterations > one.iterations


@pytest.mark.parametrize("spelling", ["regions", "halfplanes"])
def test_either_or_is_met_in_both_spellings(spelling: str) -> None:
    got = plan(_zoo(f"stlpy_either_or_{spelling}"))
    assert got.success, got.status
    assert 0.0 <= got.robustness <= 0.5 + 1e-6  # the certified optimum bounds it


@pytest.mark.slow
def test_reach_avoid_leaves_the_obstacle_corner_on_a_shifted_start() -> None:
    # The straight route grazes both corners of the obstacle; the first plan converges onto
    # one (robustness -0.0000).  Legs shifted to one side pass it with the goal's margin.
    one = plan(_zoo("stlpy_reach_avoid_regions", starts=1))
    assert not one.success and abs(one.robustness) < 1e-3
    many = plan(_zoo("stlpy_reach_avoid_regions"))
    assert many.success, many.status
    assert 0.45 <= many.robustness <= 0.5 + 1e-6
    assert "legs 1 m to the" in many.status


@pytest.mark.slow
def test_the_polish_budget_keeps_the_best_of_more_starts() -> None:
    first = plan(_zoo("stlpy_door_puzzle_regions"))
    assert first.success and first.stats is not None and first.stats.starts == 1
    polished = plan(_zoo("stlpy_door_puzzle_regions", polish_s=60.0))
    assert polished.success, polished.status
    assert polished.stats is not None and polished.stats.starts == 4  # every start solved
    assert first.robustness <= polished.robustness <= 0.4 + 1e-6
    assert polished.robustness > first.robustness + 0.05  # key2 first: 0.39 vs 0.23
    # a polish that ran out is not the user's time limit
    assert not polished.status.startswith("stopped at the time limit")


@pytest.mark.slow
def test_a_given_guess_is_the_only_start() -> None:
    problem = _zoo("stlpy_either_or_regions")
    first = plan(_zoo("stlpy_either_or_regions", starts=1))
    again = plan(problem, initial_guess=first.decision)
    assert again.stats is not None and again.stats.starts == 1


def test_the_time_limit_ends_the_multi_start() -> None:
    short = plan(_zoo("stlpy_either_or_halfplanes"), time_limit_s=0.01)
    # one start if this process has built the structure before, none if the limit came
    # in a cold build (then the initial guess is checked as the plan)
    assert short.stats is not None and short.stats.starts <= 1
    assert short.status.startswith("stopped at the time limit (0.01 s)")


@pytest.mark.parametrize(
    ("solver", "message"),
    [
        ({"starts": 0}, r"solver.starts: .*1"),
        ({"starts": 2.5}, r"solver.starts: "),
        ({"polish_s": -1}, r"solver.polish_s: "),
    ],
)
def test_bad_multistart_settings_name_the_key(solver: dict[str, Any], message: str) -> None:
    data = yaml.safe_load((ZOO / "stlpy_reach_avoid_regions.yaml").read_text())
    data["solver"] = solver
    with pytest.raises(ScenarioError, match=message):
        parse_scenario(data, "ms.yaml")
