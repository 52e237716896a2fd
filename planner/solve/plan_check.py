"""The planner's models and the exact check of a plan: the linear model of the scenario's
dynamics (:func:`make_model`), each vehicle's start state, the dense check times, and the
exact robustness of the trajectories with the weakest sub-formula (:func:`evaluate`) and
what the start alone allows (:func:`start_bound`); the check that ends a search
(:func:`check_plan`: the :class:`~planner.results.PlanResult`).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from planner.checks import LimitReport, check_trajectories
from planner.dynamics import DoubleIntegrator, MinimumJerkChain
from planner.problem import DynamicsModel, Problem
from planner.results import ClauseReport, PlanResult, SolveStats, StartBound, Weakest
from planner.scenario.spec import clause_formulas
from planner.solve.explain import needs
from planner.solve.leaves import is_direct
from planner.solve.solver_runs import SigintWatch, SolverRun, min_leaf, user_status
from planner.spec.heading import heading_signals, uses_heading
from planner.stl import Formula, conjunction, explanation
from planner.trajectory import Trajectory

if TYPE_CHECKING:
    from planner.solve.coarse_start import CoarseOutcome
    from planner.solve.nlp import Structure
    from planner.solve.screen import Screen

__all__ = [
    "SearchState",
    "check_plan",
    "clause_robustness",
    "dense_signals",
    "dense_times",
    "evaluate",
    "initial_states",
    "make_model",
    "recheck",
    "start_bound",
    "verdict",
]


def make_model(problem: Problem) -> MinimumJerkChain | DoubleIntegrator:
    """The linear model of the scenario (one for all vehicles: same timing)."""
    t = problem.timing
    if problem.model is DynamicsModel.MINIMUM_JERK:
        return MinimumJerkChain(t.horizon_s, t.segment_s, t.sample_dt_s, explicit_acc=True)
    a_max = np.max([v.a_max_m_s2 for v in problem.vehicles], axis=0)
    return DoubleIntegrator(t.horizon_s, t.segment_s, 3, a_max, sample_dt_s=t.sample_dt_s)


def initial_states(problem: Problem, model: Any) -> list[np.ndarray]:
    """Start states (n_init, 3): position then zeros (at rest)."""
    out = []
    for v in problem.vehicles:
        x0 = np.zeros((model.n_init, 3))
        x0[0] = v.start_enu_m
        out.append(x0)
    return out


def dense_times(problem: Problem) -> np.ndarray:
    t = problem.timing
    n = round(t.horizon_s / t.check_dt_s) + 1
    return np.arange(n) * t.check_dt_s


def evaluate(
    problem: Problem,
    formula: Formula,
    formulas: Sequence[Formula],
    trajectories: Sequence[Trajectory],
    heading: bool = False,
) -> tuple[float, float, Weakest | None, tuple[ClauseReport, ...]]:
    """Exact robustness (dense and planning grid), weakest sub-formula, per clause."""
    sig = dense_signals(problem, trajectories, heading)
    dt = problem.timing.check_dt_s
    clause_rob = clause_robustness(problem, formulas, sig).tolist()
    clauses = tuple(
        ClauseReport(c.key_path, c.text, r)
        for c, r in zip(problem.clauses, clause_rob, strict=True)
    )
    rob = float(min(clause_rob)) if clause_rob else math.inf
    ts = problem.timing.sample_dt_s
    n = problem.timing.n_samples
    sig_grid = heading_signals(trajectories, np.arange(n) * ts, heading)
    rob_grid = float(formula.robustness(sig_grid, ts))
    weakest = None
    if formulas:
        i = int(np.argmin(clause_rob))
        # the deciding sub-formula in the clause's own sign (a `not` explained as itself)
        leaf = explanation(formulas[i].weakest(sig, dt))[-1]
        weakest = Weakest(
            formula=str(_witness_formula(leaf)),
            robustness=float(_witness_value(leaf)),
            t_s=float(_witness_time(leaf, dt)),
            clause_key=problem.clauses[i].key_path,
        )
    return rob, rob_grid, weakest, clauses


def dense_signals(
    problem: Problem, trajectories: Sequence[Trajectory], heading: bool = False
) -> dict[str, Any]:
    """Each vehicle's positions on the exact check's dense samples (every check_dt_s), with
    ``heading`` also its yaw (:func:`planner.spec.heading.heading_signals`)."""
    return heading_signals(trajectories, dense_times(problem), heading)


def clause_robustness(
    problem: Problem, formulas: Sequence[Formula], sig: Mapping[str, Any]
) -> np.ndarray:
    """Each clause's exact robustness on the dense signals ``sig``."""
    dt = problem.timing.check_dt_s
    return np.array([f.robustness(sig, dt) for f in formulas], dtype=float)


def start_bound(
    problem: Problem,
    formulas: Sequence[Formula],
    trajectories: Sequence[Trajectory],
    clauses: Sequence[ClauseReport],
    weakest: Weakest | None,
    heading: bool = False,
) -> StartBound | None:
    """Whether the headline figure is a margin of the start state: the weakest sub-formula
    is a predicate of positions at t = 0 (the vehicles' given starts); then the least
    robustness of the clauses whose own weakest point is elsewhere."""
    if weakest is None or weakest.t_s != 0.0:
        return None
    sig = dense_signals(problem, trajectories, heading)
    dt = problem.timing.check_dt_s

    def at_start(f: Formula) -> bool:
        leaf = f.weakest(sig, dt)[-1]
        return _witness_time(leaf, dt) == 0.0 and is_direct(_witness_formula(leaf))

    i = min(range(len(clauses)), key=lambda j: clauses[j].robustness)
    if not at_start(formulas[i]):
        return None
    others = [c.robustness for f, c in zip(formulas, clauses, strict=True) if not at_start(f)]
    return StartBound(min(others) if others else None)


def _witness_formula(w: Any) -> Any:
    return w.formula


def _witness_value(w: Any) -> float:
    return w.robustness


def _witness_time(w: Any, dt: float) -> float:
    return w.t_s


def verdict(
    problem: Problem, rob: float, weakest: Weakest | None, limits: Sequence[LimitReport]
) -> tuple[bool, str]:
    """Whether a plan succeeds (exact robustness at least epsilon, and every vehicle within
    its limits and the workspace) and why, in words, for its status."""
    success = bool(rob >= problem.epsilon and all(lim.ok for lim in limits))
    if success:
        return True, f"robustness {rob:.4g} >= epsilon {problem.epsilon:g}"
    if rob < problem.epsilon:
        w_txt = (
            f" (weakest: {weakest.formula} = {weakest.robustness:.4g} at t={weakest.t_s:g} s)"
            if weakest
            else ""
        )
        return False, f"robustness {rob:.4g} < epsilon {problem.epsilon:g}{w_txt}"
    bad = [lim.name for lim in limits if not lim.limits_ok]
    out = [lim.name for lim in limits if not lim.in_workspace]
    return False, "; ".join(
        ([f"limits violated by {', '.join(bad)}"] if bad else [])
        + ([f"outside the workspace: {', '.join(out)}"] if out else [])
    )


def recheck(result: PlanResult, problem: Problem, note: str = "") -> PlanResult:
    """``result``'s trajectories judged against ``problem`` instead of the problem they were
    planned for (a plan made for tightened clauses, :mod:`planner.spec.margins`, judged
    against the spec as written): its robustness, clauses, weakest sub-formula, limits and
    verdict; the solver's figures kept.  ``note`` is added to the status."""
    formulas = clause_formulas(problem)
    heading = uses_heading(formulas)
    rob, rob_grid, weakest, clauses = evaluate(
        problem, conjunction(formulas), formulas, result.trajectories, heading
    )
    t = problem.timing
    limits = check_trajectories(
        problem, result.trajectories, problem.vehicles, t.check_dt_s, t.horizon_s
    )
    success, said = verdict(problem, rob, weakest, limits)
    status = ("the mission is met: " if success else "the mission is not met: ") + said
    return dataclasses.replace(
        result,
        problem=problem,
        success=success,
        status=status + (f" ({note})" if note else ""),
        robustness=rob,
        robustness_planning_grid=rob_grid,
        weakest=weakest,
        clauses=clauses,
        limits=tuple(limits),
        needs=(),
        start_bound=None,
    )


class SearchState(Protocol):
    """What :func:`check_plan` reads of the search that found a plan
    (:class:`planner.optimize.PlanSearch`)."""

    problem: Problem
    formula: Formula
    formulas: list[Formula]
    heading: bool
    #: the NLP's structure (absent: the time limit came in the build)
    struct: Structure
    p_val: np.ndarray
    n_starts: int
    combinatorial: CoarseOutcome | None
    screen: Screen | None
    screen_rounds: int
    build_s: float
    cached: bool
    check_s: float
    t_start: float
    time_limit_s: float | None
    say: Callable[[str], None]

    def trajectories_of(self, w: np.ndarray) -> list[Trajectory]: ...


def check_plan(
    search: SearchState,
    w_opt: np.ndarray,
    status: str,
    converged: bool,
    run: SolverRun,
    stop: SigintWatch,
    by_time: bool,
) -> PlanResult:
    """Check the plan at the NLP's point ``w_opt`` on dense samples: exact robustness, the
    weakest sub-formula, each clause, the limits, what falls short (:func:`needs`) and what
    the start alone allows; with the search's figures, the :class:`PlanResult`.

    Args:
        search: the search that found it (its ``check_s`` grows by this check's time).
        w_opt: the NLP's point.
        status: the solver's status line so far.
        converged: whether the solver converged there.
        run: what the solves cost.
        stop: the search's Ctrl-C watch.
        by_time: whether the time limit ended the search.
    """
    problem, formula, formulas = search.problem, search.formula, search.formulas
    search.say("checking on dense samples")
    struct: Structure | None = getattr(search, "struct", None)  # None: stopped in the build
    # The smooth value at the point returned (r itself may sit on a bound, eq. (1)).
    smooth = (
        math.nan
        if struct is None
        else min_leaf(struct, w_opt, search.p_val, default=float(w_opt[-1]))
    )
    t_check = time.perf_counter()
    trajectories = search.trajectories_of(w_opt)
    rob, rob_grid, weakest, clauses = evaluate(
        problem, formula, formulas, trajectories, search.heading
    )
    limits = check_trajectories(
        problem, trajectories, problem.vehicles, problem.timing.check_dt_s,
        problem.timing.horizon_s,
    )  # fmt: skip
    success, said = verdict(problem, rob, weakest, limits)
    stopped_by_time = by_time and not stop.hit
    lines = (
        needs(
            problem,
            formula,
            solver_status=status,
            stopped_by_time=stopped_by_time,
            starts=search.n_starts,
            combinatorial=search.combinatorial,
        )
        if rob < problem.epsilon
        else []
    )
    at_start = start_bound(problem, formulas, trajectories, clauses, weakest, search.heading)
    search.check_s += time.perf_counter() - t_check
    screen = search.screen
    stats = SolveStats(
        build_s=search.build_s,
        solver_s=run.solver_s,
        function_eval_s=run.eval_s,
        check_s=search.check_s,
        n_variables=0 if struct is None else struct.n_w,
        n_constraints=0 if struct is None else struct.n_g,
        n_smooth_leaves=0 if struct is None else struct.n_smooth,
        k=math.nan if struct is None else struct.k,
        solver=problem.solver.method.value,
        cached=search.cached,
        starts=search.n_starts,
        coarse=None if search.combinatorial is None else search.combinatorial.summary(),
        screen=None
        if screen is None
        else {"kept": screen.kept, "total": screen.total, "rounds": search.screen_rounds},
    )
    return PlanResult(
        problem=problem,
        success=success,
        status=user_status(
            status,
            converged,
            success,
            rob < problem.epsilon,
            said,
            interrupted=stop.hit,
            time_limit_s=search.time_limit_s if stopped_by_time else None,
        ),
        robustness=rob,
        robustness_planning_grid=rob_grid,
        smooth_robustness=smooth,
        weakest=weakest,
        clauses=clauses,
        solve_time_s=time.perf_counter() - search.t_start,
        iterations=run.iterations,
        trajectories=tuple(trajectories),
        limits=limits,
        decision=w_opt,
        stats=stats,
        needs=tuple(lines),
        start_bound=at_start,
    )
