"""Name the clauses that conflict when no coarse path meets the spec (a deletion filter)."""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

from planner.milp.model import choose_dt
from planner.milp.solve import CoarseResult, CoarseStatus, problem_formulas, solve_coarse
from planner.problem import Clause, Problem

__all__ = ["Conflict", "find_conflict"]


@dataclass(frozen=True, slots=True)
class Conflict:
    """A set of clauses that together admit no coarse path with robustness >= epsilon.

    Attributes:
        indices: positions in ``problem.clauses``, ascending.
        clauses: those clauses (``key_path`` and ``text``).
        irreducible: True when every deletion was decided by a proof (dropping any one of
            them leaves a feasible set); False when a time limit left one undecided (that
            clause was kept: the set still conflicts, but may not be minimal).
        solves: MILPs solved; elapsed_s: wall time of the filter.
    """

    indices: tuple[int, ...]
    clauses: tuple[Clause, ...]
    irreducible: bool
    solves: int
    elapsed_s: float


def _infeasible(res: CoarseResult, epsilon: float) -> bool | None:
    """True: proven below epsilon; False: an incumbent meets it; None: undecided."""
    if res.status is CoarseStatus.INFEASIBLE:
        return True
    if res.status is CoarseStatus.NOT_ENCODABLE:
        return None
    if res.success and res.robustness >= epsilon:
        return False
    return True if res.bound < epsilon else None


def find_conflict(
    problem: Problem,
    *,
    time_limit_s: float = 10.0,
    per_solve_s: float = 2.0,
    dt_c: float | None = None,
    stop: threading.Event | None = None,
) -> Conflict | None:
    """An irreducible set of clauses with no coarse path of robustness >= ``problem.epsilon``.

    The deletion filter: prove the whole spec infeasible (robustness >= epsilon as a
    constraint), then drop each clause in turn and keep it out when the rest is still
    infeasible. Every clause left is needed for the conflict. All solves use one coarse step
    (that of the whole spec) so that they answer the same question, and read each ``always``
    at the steps inside its window only (``cover=False`` of :func:`solve_coarse`, the weaker
    requirement), so that a conflict is not an artefact of the covering windows.

    Returns:
        The conflict, or None when the whole spec is not proven infeasible (a coarse path
        meets it, or the time ran out first, or ``stop`` was set from another thread).
    """
    if not (time_limit_s > 0 and per_solve_s > 0):
        raise ValueError("time_limit_s and per_solve_s must be positive")
    t0 = time.perf_counter()
    eps = problem.epsilon
    dt = dt_c if dt_c is not None else choose_dt(problem, problem_formulas(problem))

    def check(keep: list[int], budget: float) -> bool | None:
        res = solve_coarse(problem, time_limit_s=budget, dt_c=dt, clauses=keep, min_robustness=eps,
                           cover=False, stop=stop)  # fmt: skip
        return _infeasible(res, eps)

    solves = 1
    keep = list(range(len(problem.clauses)))
    if check(keep, max(per_solve_s, time_limit_s / 2)) is not True:
        return None
    irreducible = True
    for i in list(keep):
        left = time_limit_s - (time.perf_counter() - t0)
        if left <= 0 or (stop is not None and stop.is_set()):
            irreducible = False
            break
        trial = [j for j in keep if j != i]
        verdict = check(trial, min(per_solve_s, left)) if trial else False
        solves += 1 if trial else 0
        if verdict is True:
            keep = trial
        elif verdict is None:
            irreducible = False
    return Conflict(
        indices=tuple(keep),
        clauses=tuple(problem.clauses[i] for i in keep),
        irreducible=irreducible and math.isfinite(eps),
        solves=solves,
        elapsed_s=time.perf_counter() - t0,
    )
