"""The planner's models and the exact check of a plan: the linear model of the scenario's
dynamics (:func:`make_model`), each vehicle's start state, the dense check times, and the
exact robustness of the trajectories with the weakest sub-formula (:func:`evaluate`) and
what the start alone allows (:func:`start_bound`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from planner.checks import LimitReport, check_trajectories
from planner.dynamics import DoubleIntegrator, MinimumJerkChain
from planner.problem import DynamicsModel, Problem
from planner.results import ClauseReport, PlanResult, StartBound, Weakest
from planner.scenario.spec import clause_formulas
from planner.solve.leaves import is_direct
from planner.spec.heading import heading_signals, uses_heading
from planner.stl import Formula, conjunction, explanation
from planner.trajectory import Trajectory

__all__ = [
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
