"""The combinatorial stage as the NLP's first start (DESIGN.md section 5, "Two stages").

:func:`coarse_start` runs :func:`planner.milp.solve_coarse` within a budget: the mixed-integer
program on a coarse model of the vehicles chooses the discrete structure of the spec (which
option of each ``or``, which vehicle takes which task, the order and time of each visit,
which side of each keep-out).  Its incumbent, straight lines between the coarse samples fitted
within the vehicles' limits (:func:`planner.coarse_fit.waypoint_guess`), is the start the NLP
refines.  When the coarse program has no plan that meets the spec, a deletion filter names the
clauses that conflict on the coarse model (:func:`planner.milp.find_conflict`), which
:func:`planner.explain.needs` reports.

What the coarse model is: positions every ``dt_c`` seconds with the vehicles' limits as
bounds on first and second differences, the predicates as linear margins (a cylinder as a
polygon, a separation as the largest per-axis distance): close to the primitives' model, but
neither inside nor outside it, so a coarse answer is a guide for the NLP, not a proof about
the smooth plan; the exact check after the NLP decides.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.coarse_fit import waypoint_guess
from planner.milp import CoarseResult, CoarseStatus, Conflict, find_conflict, solve_coarse
from planner.problem import Problem

__all__ = ["CoarseOutcome", "coarse_budget_s", "coarse_start"]

#: The share of the time limit the combinatorial stage may use at most.
_LIMIT_SHARE = 0.25
#: The least time (s) the conflict search gets once the spec is proven infeasible on the
#: coarse model (its answer is worth more than a few more seconds of the NLP).
_CONFLICT_MIN_S = 2.0


@dataclass(frozen=True, slots=True)
class CoarseOutcome:
    """What the combinatorial stage did for one plan.

    Attributes:
        result: the coarse program's result.
        decision: the NLP start made from its incumbent (None without one).
        conflict: the clauses that conflict on the coarse model, when it found no coarse
            plan that meets the spec (None otherwise, or when the filter ran out of time).
    """

    result: CoarseResult
    decision: np.ndarray | None
    conflict: Conflict | None = None

    def describe(self) -> str:
        """The start's name in the planner's status."""
        r = self.result
        kind = "optimal" if r.status is CoarseStatus.OPTIMAL else "best found"
        return (
            f"the combinatorial stage's plan ({kind} on the coarse model, every "
            f"{r.dt_s:g} s: robustness {r.robustness:+.3g})"
        )

    def summary(self) -> dict[str, Any]:
        """Plain figures for the plan's statistics (``gcs plan --json``)."""
        r = self.result
        return {
            "status": r.status.value,
            "robustness": None if not math.isfinite(r.robustness) else r.robustness,
            "bound": None if not math.isfinite(r.bound) else r.bound,
            "dt_s": r.dt_s,
            "build_s": r.build_s,
            "solve_s": r.solve_s,
            "binaries": r.num_binaries,
            "windows": "covered" if r.cover else "inner samples",
            "message": r.message,
            "conflict": None
            if self.conflict is None
            else [c.key_path for c in self.conflict.clauses],
        }


def coarse_budget_s(problem: Problem, remaining_s: float) -> float:
    """The combinatorial stage's budget: ``solver.coarse_s``, at most a quarter of the time
    left (``remaining_s``; inf without a limit); 0 when it is off."""
    budget = problem.solver.coarse_s
    if math.isfinite(remaining_s):
        budget = min(budget, _LIMIT_SHARE * max(remaining_s, 0.0))
    return budget


def coarse_start(
    problem: Problem, model: Any, x0s: list[np.ndarray], budget_s: float
) -> CoarseOutcome:
    """Run the combinatorial stage within ``budget_s`` seconds (the conflict search, if it
    comes to that, within what is left of it) and make its plan a start of the NLP.

    Args:
        problem: the scenario.
        model: the planner's linear model (:func:`planner.optimize.make_model`).
        x0s: each vehicle's start state ``(n_init, 3)``.
        budget_s: seconds for the whole stage.
    """
    t0 = time.perf_counter()

    # The robustness at least epsilon as a constraint: HiGHS prunes every branch below it
    # (the door puzzle: the optimum 0.4 in 8 s, against no incumbent above -1 in 20 s
    # without), and a spec no coarse path meets is proven INFEASIBLE at once.  Capped like
    # the NLP (solver.robustness_cap_m): more margin is not wanted.
    def solve(cover: bool, time_limit_s: float) -> CoarseResult:
        return solve_coarse(
            problem,
            time_limit_s=time_limit_s,
            robustness_cap_m=problem.solver.robustness_cap_m,
            min_robustness=problem.epsilon,
            cover=cover,
        )

    # Each always over the coarse steps that cover its window first (a plan the smooth
    # model can keep the timing of); when that is proven impossible, the weaker reading
    # (the steps inside the window) before any conflict is named.
    result = solve(True, budget_s)
    if result.status is CoarseStatus.INFEASIBLE:
        left = budget_s - (time.perf_counter() - t0)
        if left > 0.05:
            result = solve(False, left)
    if result.success:
        times = np.asarray(result.times_s, dtype=float)
        points = [np.asarray(result.waypoints_enu_m[v.name]) for v in problem.vehicles]
        return CoarseOutcome(result, waypoint_guess(problem, model, x0s, times, points))
    conflict = None
    if result.status is CoarseStatus.INFEASIBLE:
        # no coarse plan meets the spec (proven): which clauses conflict there (a deletion
        # filter of small MILPs, each proven in a fraction of a second on the zoo's)
        left = max(budget_s - (time.perf_counter() - t0), _CONFLICT_MIN_S)
        conflict = find_conflict(problem, time_limit_s=left, per_solve_s=max(0.5, left / 8))
    return CoarseOutcome(result, None, conflict)
