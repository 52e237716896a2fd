"""Refinements of the multi-start's best plan: the rest of the clauses raised once the weakest
is settled (:func:`raise_the_rest`, a lexicographic max-min) and the boxes' smoothing made as
sharp as the leaves' (:func:`sharpen`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.problem import Problem
from planner.solve.nlp import STRUCTURES, Structure, build_structure, structure_key
from planner.solve.screen import Screen
from planner.solve.solver_runs import (
    Attempt,
    SigintWatch,
    SolverRun,
    lower_r,
    min_leaf,
    run_solvers,
    solved,
)
from planner.stl import Formula

__all__ = ["Raised", "leximin_better", "raise_the_rest", "sharpen"]

#: Leaf rows within this (m) of the weakest are settled with it, each held at the weakest
#: value less this, in :func:`raise_the_rest`; clause robustness within twice this counts
#: as equal when its result is compared.
_SETTLE_M = 1e-3


#: A leaf row at the weakest value holds r down when its multiplier is at least this share
#: of the leaf rows' (which sum to 1 at a max-min's optimum); the others there are settled
#: only by the start.
_HOLDING_SHARE = 1e-2


#: How far (m) one solve of :func:`raise_the_rest` may raise r above its start: a trust
#: region.  Unbounded, IPOPT left the refined point and wandered (the ground-start line:
#: 434 iterations with the adaptive barrier, 1,000 and worse with it capped); 0.2 m per
#: solve took 10 iterations.
_RAISE_STEP_M = 0.2


@dataclass(frozen=True, slots=True)
class Raised:
    """What :func:`raise_the_rest` did: the point and a note for the status ("" when it
    kept the plan it was given), and the solver runs it cost."""

    w: np.ndarray
    note: str
    run: SolverRun | None


def raise_the_rest(
    struct: Structure,
    w: np.ndarray,
    lam_g: np.ndarray | None,
    bounds: Mapping[str, np.ndarray],
    problem: Problem,
    clauses_of: Callable[[np.ndarray], np.ndarray],
    say: Callable[[str], None],
    stop: SigintWatch,
    deadline: float,
    budget_s: float,
) -> Raised:
    """Lexicographic refinement after the max-min: hold the weakest leaves, raise the rest.

    The max-min stops at its bottleneck.  When a leaf's margin at t = 0 is that bottleneck
    (fixed by the start state: a drone 1 m up with the floor at 0.5 m), or when the plan
    falls short (one unreachable clause), nothing pushes the other leaves up.  Here the
    leaves whose rows hold r down at the weakest value (the start's rows when the start sets
    it, else the rows with a share of the multipliers ``lam_g``) are settled: their rows'
    weight on r becomes 0, their floor that value less :data:`_SETTLE_M`.  Then r is
    maximised over the other rows from the plan's point, with the refining solvers (the
    point is feasible) and r at most :data:`_RAISE_STEP_M` above its start; a solve that
    reaches that step is followed by another.  A solve's plan is kept only if it converged,
    its clause robustness, sorted, is better in the leximin order (the weakest first, within
    ``2 * _SETTLE_M``), and it does not lose the mission.  At most
    ``solver.lexicographic_rounds`` solves, all within ``budget_s`` (and ``deadline``, the
    user's time limit).
    """
    eps = problem.epsilon
    until = time.perf_counter() + budget_s
    p, lbg, ubx = bounds["p"].copy(), bounds["lbg"].copy(), bounds["ubx"].copy()
    weight = p[struct.n_x0 :]  # a view: each leaf row's weight on r
    rows = np.arange(struct.leaf_group.size) + struct.n_lin  # the leaf rows of g
    clause_rob = clauses_of(w)
    spent: SolverRun | None = None
    notes: list[str] = []  # the settles whose solves were kept
    pending = ""
    settle = True
    for _ in range(problem.solver.lexicographic_rounds):
        if stop.hit or struct.watch.stopped:
            break
        values = np.asarray(struct.leaf_fn(w, p)).reshape(-1)
        if settle:
            free = weight > 0
            weakest = float(values[free].min()) if free.any() else 0.0
            if weakest >= bounds["ubx"][-1] - _SETTLE_M:
                break  # every row is above the robustness cap: no more is asked
            at_bottleneck = free & (values <= weakest + _SETTLE_M)
            by_start = bool(np.any(at_bottleneck & struct.leaf_at_start))
            if not by_start and clause_rob.min() >= eps:
                break  # met, and the weakest is the plan's own: nothing more is asked
            # The start's rows are the bottleneck for certain (constants); other rows there
            # may only have had no reason to rise above it: the ones that hold r down carry
            # its multiplier (the leaf rows' multipliers sum to 1 at a max-min's optimum).
            if by_start:
                held_rows = at_bottleneck & struct.leaf_at_start
            elif lam_g is not None:
                share = np.abs(lam_g[rows])
                held_rows = at_bottleneck & (share >= _HOLDING_SHARE * max(share.sum(), 1e-12))
            else:
                held_rows = at_bottleneck
            held_rows = held_rows if held_rows.any() else at_bottleneck
            settled = free & np.isin(struct.leaf_group, struct.leaf_group[held_rows])
            if settled.sum() == free.sum():
                break
            weight[settled] = 0.0
            lbg[rows[settled]] = weakest - _SETTLE_M
            names = sorted({struct.leaf_names[i] for i in struct.leaf_group[settled]})
            held = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
            why = "the start sets it" if by_start else "the plan falls short"
            pending = f"then raised the other clauses with {held} held at {weakest:.4g} ({why})"
            say(f"raising the other clauses, {held} held at {weakest:.4g} ({why})")
        start = w.copy()
        start[-1] = float(values[weight > 0].min())
        step = _RAISE_STEP_M + max(0.0, eps - start[-1])  # a failing leaf may reach epsilon
        ubx[-1] = min(bounds["ubx"][-1], start[-1] + step)
        struct.watch.deadline = min(deadline, until)
        run = run_solvers(
            struct,
            start,
            {**bounds, "p": p, "lbg": lbg, "ubx": ubx},
            say,
            "the rest raised",
            stop,
            refine=True,
        )
        spent = run if spent is None else spent.then(run)
        got = clauses_of(run.w)
        if (
            not solved(run.status)  # an iterate off the dynamics' rows is no plan
            or not leximin_better(got, clause_rob, 2 * _SETTLE_M)
            or clause_rob.min() >= eps > got.min()
        ):
            break
        w, clause_rob, lam_g = run.w, got, run.lam_g
        if pending:
            notes.append(pending)
            pending = ""
        settle = bool(w[-1] < ubx[-1] - _SETTLE_M)  # below the step: its own bottleneck
    return Raised(w, "; ".join(notes), spent)


def sharpen(
    problem: Problem,
    model: Any,
    formula: Formula,
    best: Attempt,
    bounds: Mapping[str, np.ndarray],
    p_val: np.ndarray,
    exact_of: Callable[[np.ndarray], float],
    say: Callable[[str], None],
    stop: SigintWatch,
    deadline: float,
    on_iteration: Callable[[np.ndarray, float], None] | None,
    screen: Screen | None = None,
    fixed: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[Structure, Attempt, dict[str, np.ndarray], float] | None:
    """Solve again from ``best`` with the smooth leaves' box predicates at the leaves' own
    sharpness (:func:`planner.solve.nlp.build_structure` with ``sharp``: a box is smoothed exactly as its
    faces spelled as comparisons would be); the structure, the attempt, its bounds and the
    seconds its build took if that is better in exact robustness, else ``None``.

    The boxes' own sharpness (``log(6)/k`` = 10 % of the smallest half-size) keeps IPOPT's
    landscape gentle from rough starts (smoothed at the leaves' k from the start, the PX4-
    limits flight and the paddock clearance took IPOPT's iteration limit), but where the
    plan's margin is within that error the smoothing, not the geometry, decides it (stlpy's
    stepping stones, regions: 0.0003, and 0.0527, the certified optimum, sharpened).
    The solve stops at ``deadline``; ``on_iteration`` is the plan's progress callback; the
    NLP keeps the row-wise steps of ``screen`` (:mod:`planner.solve.screen`), if given, and
    the decisions ``fixed`` (indices, values: a replan's kept prefix) at their values."""
    built: list[float] = []

    def build() -> Structure:
        say("building the NLP with sharper box margins")
        t0 = time.perf_counter()
        got = build_structure(problem, model, formula, sharp=True, screen=screen)
        built.append(time.perf_counter() - t0)
        return got

    sharp, _ = STRUCTURES.get_or_build(structure_key(problem, sharp=True, screen=screen), build)
    lbx, ubx = sharp.lbx.copy(), sharp.ubx.copy()
    if fixed is not None:
        lbx[fixed[0]] = ubx[fixed[0]] = fixed[1]
    if problem.solver.robustness_constraint:
        lower_r(lbx, ubx, problem.epsilon + sharp.margin)
    sharp_bounds = {**bounds, "lbx": lbx, "ubx": ubx}
    w0 = best.w.copy()
    if sharp.n_s:  # the chunks' values at the same decisions, sharper
        w0[-1 - sharp.n_s : -1] = np.asarray(sharp.chunk_fn(w0, p_val)).reshape(-1)
    w0[-1] = min_leaf(sharp, w0, p_val, default=float(w0[-1]))
    sharp.watch.arm(deadline, on_iteration)
    refine = best.robustness >= problem.epsilon
    run = run_solvers(sharp, w0, sharp_bounds, say, "sharper box margins", stop, refine)
    sharp.watch.on_iteration = None
    rob = exact_of(run.w)
    if not rob > best.robustness:
        return None
    status = (
        f"{best.status}; then sharpened the boxes' smoothing: {best.robustness:.4g} -> "
        f"{rob:.4g} ({run.status})"
    )
    attempt = Attempt(rob, run.w, status, solved(run.status), run)
    return sharp, attempt, sharp_bounds, sum(built)


def leximin_better(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    """Whether ``a`` beats ``b`` in the leximin order: sorted ascending, the first entry
    that differs by more than ``tol`` is larger in ``a``."""
    for x, y in zip(np.sort(a), np.sort(b), strict=True):
        if x > y + tol:
            return True
        if x < y - tol:
            return False
    return False
