"""The planner's two stages (issue 40): the combinatorial stage's plan as the NLP's start
where it beats the initial guess, clauses in conflict named when no coarse plan exists, and
the search as an object that two threads can run on one structure."""

from __future__ import annotations

import dataclasses
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.optimize import plan
from planner.problem import Problem
from planner.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
ZOO = ROOT / "benchmarks" / "scenarios"


def _zoo(name: str, **solver: Any) -> Problem:
    problem = load_scenario(ZOO / f"{name}.yaml")
    return dataclasses.replace(problem, solver=dataclasses.replace(problem.solver, **solver))


@pytest.mark.slow
def test_the_coarse_plan_starts_the_nlp_where_it_beats_the_guess() -> None:
    # The door puzzle (regions): the nearest keys first leave the guess's plan at 0.23; the
    # MILP opens the doors in the right order (its optimum 0.4 on the coarse model, stlpy's
    # certified 0.4), and the NLP keeps most of it.  The guess's start meets the mission, so
    # the stage's plan is tried for margin within solver.polish_s (or as long again as the
    # search took to meet it, which on a busy machine may not be enough for the stage).
    guess_only = plan(_zoo("stlpy_door_puzzle_regions", coarse_s=0.0))
    both = plan(_zoo("stlpy_door_puzzle_regions", coarse_s=30.0, polish_s=30.0, starts=2))
    assert guess_only.success and both.success, (guess_only.status, both.status)
    assert guess_only.stats is not None and guess_only.stats.coarse is None
    assert both.stats is not None and both.stats.coarse is not None
    assert both.stats.coarse["status"] == "optimal"
    assert both.stats.coarse["robustness"] == pytest.approx(0.4, abs=1e-6)
    assert "the combinatorial stage's plan" in both.status
    assert both.robustness > guess_only.robustness + 0.05
    assert both.robustness <= 0.4 + 1e-6  # the certified optimum bounds it


def test_a_guess_that_meets_the_mission_at_its_start_skips_the_milp() -> None:
    got = plan(_zoo("powerline_line4_1drone"))
    assert got.success, got.status
    assert got.stats is not None and got.stats.coarse is None
    assert "combinatorial" not in got.status


@pytest.mark.slow
def test_clauses_in_conflict_are_named_and_nothing_else_is_advised() -> None:
    # Two drones in one 1 m cube at once (diagonal 1.73 m) and 2 m apart; the workspace and
    # a far box for d1 are easy decoys that must not be named.
    got = plan(_zoo("conflict_cube_2drones"))
    assert not got.success
    assert got.stats is not None and got.stats.starts == 1  # no more starts: proven
    assert len(got.needs) == 1 and got.needs[0].startswith("conflict: "), got.needs
    line = got.needs[0]
    assert "spec[0].formula" in line and "spec[1].formula" in line
    assert "spec[2]" not in line and "spec[3]" not in line and "more starts" not in line
    assert got.stats.coarse is not None
    assert got.stats.coarse["conflict"] == ["spec[0].formula", "spec[1].formula"]
    # the guess's NLP, running when the conflict came, stopped for it (not at its iteration
    # limit, 500, as before) and says so, not as an error inside the solver
    assert "for the combinatorial stage's clauses in conflict" in got.status, got.status
    assert got.status.startswith("the solver was stopped for the combinatorial stage's answer")
    assert got.iterations < 500


def test_two_threads_planning_one_structure_take_turns_and_agree() -> None:
    # One search at a time in a process (CasADi is not thread-safe): two plans started in
    # two threads take turns and give what each gives alone.  Without the stage, whose
    # plan is tried or not by how far it got in the time the guess's NLP leaves it.
    problem = _zoo("stlpy_reach_avoid_regions", coarse_s=0.0)
    alone = plan(problem)
    results: list[Any] = [None, None]

    def run(i: int) -> None:
        results[i] = plan(problem)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    for got in results:
        assert got is not None and got.success, got
        assert got.robustness == pytest.approx(alone.robustness, abs=1e-6)
        assert got.iterations == alone.iterations


def test_a_time_limit_that_comes_in_the_build_ends_it_with_the_guess_checked() -> None:
    """``--time-limit`` bounds the build too: the builder gives up between its pieces, and
    the initial guess, checked on dense samples like any plan, is the result."""
    from planner.solve.nlp import clear_cache
    from planner.stl import conjunction

    problem = load_scenario(ZOO / "powerline_line4_2drones_order.yaml")
    clear_cache()  # a cold build (its first template alone takes longer than the limit)
    res = plan(problem, time_limit_s=0.05)
    assert "the time limit came while building the NLP" in res.status
    assert "the initial guess, not refined" in res.status
    assert res.status.startswith("stopped at the time limit (0.05 s)")
    assert res.iterations == 0
    assert res.stats is not None and res.stats.n_variables == 0
    # the robustness reported is the exact one of the trajectories returned
    signals = {tr.name: tr for tr in res.trajectories}
    dt = problem.timing.check_dt_s
    t = np.arange(0.0, problem.timing.horizon_s + 1e-9, dt)
    sampled = {n: np.asarray(tr.position(t)).reshape(-1, 3) for n, tr in signals.items()}
    assert conjunction(list(problem.formulas)).robustness(sampled, dt) == pytest.approx(
        res.robustness, abs=1e-6
    )


def test_a_stage_without_a_coarse_plan_says_why(tmp_path: Path) -> None:
    """When the combinatorial stage makes no plan, the progress says so and why (here a
    product of two coordinates, which no linear encoding holds), and the guess plans alone."""
    from tests.planner.test_milp import scenario

    problem = scenario(tmp_path, ["eventually[0,5] (x(d1) * y(d1) >= 4)"])
    said: list[str] = []
    res = plan(problem, progress=said.append, time_limit_s=30.0)
    lines = [s for s in said if s.startswith("combinatorial stage: no coarse plan")]
    assert len(lines) == 1, said
    assert "not encodable" in lines[0] and "a product of two signals" in lines[0]
    assert res.stats is not None and res.stats.coarse is not None
    assert res.stats.coarse["status"] == "not encodable"


@pytest.mark.slow
def test_the_stage_runs_beside_the_build_and_the_guess_start() -> None:
    """The combinatorial stage starts before the NLP is built and runs in its own thread;
    a guess that falls short (the allocation mission: every drone leaves every pole to the
    others) waits for it and then plans from its plan."""
    said: list[str] = []
    res = plan(_zoo("powerline_alloc6_3drones"), progress=said.append, time_limit_s=60.0)
    assert res.success, res.status
    stage = said.index("choosing options, order and timing (combinatorial stage, beside the NLP)")
    build = next(i for i, s in enumerate(said) if s.startswith("building the NLP"))
    assert stage < build, said
    assert "the combinatorial stage's" in res.status  # its plan, or its choices refined
    assert res.stats is not None and res.stats.coarse is not None
    assert res.stats.coarse["status"] in ("optimal", "feasible")


def _reach_avoid(n: int) -> Problem:
    return load_scenario(ROOT / "configs" / "reach_avoid.yaml", vehicles=n)


@pytest.mark.slow
def test_a_stopped_stage_ends_promptly_and_keeps_its_incumbent() -> None:
    """Stopped from another thread, HiGHS ends at its next interrupt check with the best
    plan it has; that plan is the start made (marked stopped), and the incumbent the stage
    reported while it ran is no better than it."""
    import time

    from planner.optimize import PlanSearch
    from planner.solve.coarse_start import BackgroundStage

    problem = _reach_avoid(4)  # no proof of optimality in 20 s: the bound stays at 0.3
    search = PlanSearch(problem)
    stage = BackgroundStage(problem, search.model, search.x0s, 20.0)
    t0 = time.perf_counter()
    while np.isnan(stage.incumbent) and time.perf_counter() - t0 < 15.0:
        time.sleep(0.05)
    assert not np.isnan(stage.incumbent), "no incumbent in 15 s"
    seen = stage.incumbent
    t_stop = time.perf_counter()
    stage.stop()
    outcome = stage.outcome()
    assert time.perf_counter() - t_stop < 5.0  # not the 20 s budget
    assert outcome.stopped and outcome.conflict is None
    assert outcome.decision is not None
    assert outcome.result.robustness >= seen - 1e-9
    assert outcome.result.robustness >= problem.epsilon - 1e-9  # a constraint of the program
    assert outcome.summary()["stopped"] is True
    assert "kInterrupt" in outcome.result.message


@pytest.mark.slow
def test_two_coarse_programs_in_two_threads_agree_with_each_alone() -> None:
    """HiGHS instances in two threads at once corrupted the heap; the builder runs one at a
    time, so two stages in two threads give what each gives alone."""
    from planner.milp import solve_coarse

    problem = _zoo("stlpy_stepping_stones_regions")  # optimal in about 2 s

    def solve() -> Any:
        return solve_coarse(problem, time_limit_s=60.0, min_robustness=problem.epsilon)

    alone = solve()
    got: list[Any] = [None, None]

    def run(i: int) -> None:
        got[i] = solve()

    threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert alone.status.value == "optimal"
    for r in got:
        assert r is not None and r.status is alone.status
        assert r.robustness == pytest.approx(alone.robustness, abs=1e-9)
