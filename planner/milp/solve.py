"""Solve the combinatorial stage: :func:`solve_coarse` -> :class:`CoarseResult`."""

from __future__ import annotations

import enum
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from planner.milp.builder import MilpBuilder
from planner.milp.encode import Encoder, NotEncodable
from planner.milp.model import SAMPLE_BUDGET, CoarseModel, choose_dt, second_differences
from planner.problem import Problem
from planner.stl import Formula

__all__ = ["CoarseResult", "CoarseStatus", "problem_formulas", "solve_coarse"]


class CoarseStatus(enum.Enum):
    """How the coarse MILP ended."""

    #: solved to the gap: the incumbent is optimal for the coarse model
    OPTIMAL = "optimal"
    #: the time limit came with an incumbent (``bound`` says how far it may be from optimal)
    FEASIBLE = "feasible"
    #: proven infeasible: no coarse path meets the limits (and ``min_robustness``, if asked)
    INFEASIBLE = "infeasible"
    #: the time limit came before any incumbent
    NO_SOLUTION = "no solution"
    #: the spec uses what the MILP cannot encode (``message`` says what); plan without it
    NOT_ENCODABLE = "not encodable"


@dataclass(frozen=True, slots=True)
class CoarseResult:
    """The coarse stage's answer.

    Attributes:
        status: see :class:`CoarseStatus`.
        robustness: the MILP's robustness of the incumbent (metres, a lower bound of the
            exact robustness of ``waypoints_enu_m`` sampled every ``dt_s``); nan without
            one; +inf when the spec is ``true`` on the coarse model.
        bound: HiGHS's best bound on that robustness (>= robustness; -inf when
            infeasible, +inf when unknown).
        dt_s: the coarse step ``dt_c`` (s).
        times_s: (N + 1,) sample times ``t_j = j dt_c`` (s from the plan's start).
        waypoints_enu_m: vehicle name -> (N + 1, 3) ENU metres at ``times_s`` (empty
            without an incumbent).
        build_s, solve_s: wall time to build the program (rows, matrix, handing it to
            HiGHS) and in HiGHS's ``run``.
        num_vars, num_binaries, num_rows: the program's size.
        clauses: indices of ``problem.clauses`` the program held.
        notes: approximations beyond the sound lower bounds (``face`` read as true).
        message: why, for NOT_ENCODABLE and unexpected solver states.
        cover: whether each ``always`` held over the steps that cover its window.
    """

    status: CoarseStatus
    robustness: float
    bound: float
    dt_s: float
    times_s: NDArray[np.float64]
    waypoints_enu_m: Mapping[str, NDArray[np.float64]]
    build_s: float
    solve_s: float
    num_vars: int = 0
    num_binaries: int = 0
    num_rows: int = 0
    clauses: tuple[int, ...] = ()
    notes: tuple[str, ...] = ()
    message: str = ""
    cover: bool = True
    nodes: int = field(default=0, repr=False)

    @property
    def success(self) -> bool:
        """True when there is an incumbent (OPTIMAL or FEASIBLE)."""
        return self.status in (CoarseStatus.OPTIMAL, CoarseStatus.FEASIBLE)


#: Robustness (m) the smoothing pass may give up against the incumbent's (HiGHS's
#: feasibility tolerance is 1e-9; this only keeps the LP from being infeasible by rounding).
_POLISH_SLACK_M = 1e-7


def _smoothest(
    builder: MilpBuilder,
    model: CoarseModel,
    x: NDArray[np.float64],
    rho_col: int,
    rho: float,
    time_left_s: float,
) -> NDArray[np.float64]:
    """The incumbent's choices kept, the smoothest coarse path with its robustness: with
    every integer column fixed at its value, the LP that minimises the summed absolute second
    differences of the positions subject to robustness >= ``rho`` (less a rounding slack).

    A coarse optimum is rarely unique (the robustness is set by one sample; the others may
    move freely within their margins), and HiGHS returns whichever vertex its search ends
    at: on stlpy's stepping stones a presolve setting alone turned the NLP's start from
    -0.049 into -0.030 and its result from 0.042 into 0.0004.  The smoothest of the
    equivalent paths is a defined answer, and straight legs fitted through it need the least
    correction.  Returns ``x`` itself when the LP does not solve in the time left.
    """
    if time_left_s <= 0.05:
        return x
    ints = builder.integer_columns()
    builder.set_bounds(ints, np.round(x[ints]), np.round(x[ints]))
    builder.set_bounds([rho_col], rho - _POLISH_SLACK_M, rho + 1.0)
    builder.cost.clear()
    for vc in model.vehicles.values():
        c = vc.cols
        if len(c) < 3:
            continue
        stencil = second_differences(c)
        t = builder.add_vars(len(stencil), 0.0, math.inf)
        for sign in (1.0, -1.0):  # t >= +-(p_{j+1} - 2 p_j + p_{j-1})
            vals = np.tile([sign, -2.0 * sign, sign, -1.0], (len(stencil), 1))
            builder.add_rows(np.column_stack([stencil, t]), vals, -math.inf, 0.0)
        for j in t:
            builder.cost[int(j)] = -1.0
    out = builder.solve(time_limit_s=min(time_left_s, 2.0), mip_rel_gap=1e-6)
    return out.x[: len(x)] if out.has_solution else x


def problem_formulas(problem: Problem) -> tuple[Formula, ...]:
    """The parsed clauses of a problem (parsed again when it was made without them)."""
    if len(problem.formulas) == len(problem.clauses):
        return problem.formulas
    from planner.scenario.spec import parse_clause
    from planner.spec.predicates import build_registry

    registry = build_registry(problem)
    return tuple(parse_clause(problem, c, registry) for c in problem.clauses)


def _check_args(problem: Problem, time_limit_s: float, clauses: Sequence[int] | None) -> None:
    if not (isinstance(time_limit_s, int | float) and time_limit_s > 0):
        raise ValueError(f"time_limit_s must be a positive number, got {time_limit_s!r}")
    if clauses is not None:
        bad = [i for i in clauses if not 0 <= i < len(problem.clauses)]
        if bad:
            raise ValueError(f"clause indices {bad} out of range 0..{len(problem.clauses) - 1}")


def solve_coarse(
    problem: Problem,
    *,
    time_limit_s: float,
    dt_c: float | None = None,
    clauses: Sequence[int] | None = None,
    robustness_cap_m: float | None = None,
    min_robustness: float | None = None,
    mip_rel_gap: float = 1e-4,
    sample_budget: int = SAMPLE_BUDGET,
    cover: bool = True,
    legs: bool | None = None,
    stop: threading.Event | None = None,
    on_incumbent: Callable[[float], None] | None = None,
    cpu_until: float | None = None,
) -> CoarseResult:
    """Maximise the spec's robustness on the coarse model with HiGHS, under a time limit.

    The program is :mod:`planner.milp.model` (positions every ``dt_c`` seconds within the
    vehicles' limits, a sound relaxation of them) and :mod:`planner.milp.encode` (a big-M
    lower bound of the STL robustness at the coarse samples). A failed solve is a result
    (INFEASIBLE, NO_SOLUTION, NOT_ENCODABLE), never an exception.

    Args:
        problem: the scenario; its parsed clauses are used (``problem.formulas``).
        time_limit_s: wall-time budget (s) for build and solve together; HiGHS gets what
            the build left (at least 0.05 s) and returns its incumbent when it runs out.
        dt_c: the coarse step (s); None: :func:`planner.milp.model.choose_dt` (the sample
            step ``Ts`` unless vehicles x samples exceed ``sample_budget``).
        clauses: indices of ``problem.clauses`` to encode (None: all), e.g. for
            :func:`planner.milp.conflict.find_conflict`.
        robustness_cap_m: stop raising the robustness beyond this (m); None:
            ``problem.solver.robustness_cap_m`` (None there too: only the bounds of the
            encoding cap it).
        min_robustness: require robustness >= this (a constraint): the program is then
            INFEASIBLE when no coarse path reaches it (e.g. ``problem.epsilon``).
        mip_rel_gap: HiGHS's relative gap at which it stops.
        cover: an ``always`` holds over the coarse steps that cover its window (the straight
            legs between samples then keep a convex predicate throughout; the default), not
            only at the steps inside it (:mod:`planner.milp.encode`).
        legs: a polygon keep-out (a part of a non-convex outline) held out of the straight
            legs between samples too, not only at the samples; None: as ``cover`` (the
            conflict search's weaker reading drops both).
        stop: once set (from another thread), HiGHS stops with the incumbent it has (the
            result then says ``HiGHS: kInterrupt`` in its message).
        on_incumbent: called (from HiGHS's thread) with the robustness of each better
            incumbent, as HiGHS finds it.
        cpu_until: HiGHS also stops when the calling thread's CPU time
            (``time.thread_time()``) passes this (a budget of work, as a time limit).

    Returns:
        :class:`CoarseResult`; ``waypoints_enu_m[name]`` is (N + 1, 3) ENU metres at
        ``times_s`` (N = horizon / dt_c), ``waypoints_enu_m[name][0]`` the start.

    Raises:
        ValueError: a non-positive ``time_limit_s`` or ``dt_c``, clause indices out of range.
    """
    t0 = time.perf_counter()
    _check_args(problem, time_limit_s, clauses)
    every = problem_formulas(problem)
    chosen = tuple(range(len(every))) if clauses is None else tuple(sorted(set(clauses)))
    formulas = [every[i] for i in chosen]
    dt = choose_dt(problem, every, sample_budget) if dt_c is None else float(dt_c)
    builder = MilpBuilder()
    model = CoarseModel(problem, builder, dt)
    times = model.times_s

    def result(status: CoarseStatus, **kw: object) -> CoarseResult:
        base: dict[str, object] = {
            "status": status,
            "robustness": math.nan,
            "bound": math.inf,
            "dt_s": dt,
            "times_s": times,
            "waypoints_enu_m": {},
            "build_s": time.perf_counter() - t0,
            "solve_s": 0.0,
            "num_vars": builder.num_cols,
            "num_binaries": builder.num_integers,
            "num_rows": builder.num_rows,
            "clauses": chosen,
            "cover": cover,
        }
        base.update(kw)
        return CoarseResult(**base)  # type: ignore[arg-type]

    encoder = Encoder(builder, model, cover, legs)
    try:
        root = encoder.encode(formulas)
    except NotEncodable as exc:
        return result(CoarseStatus.NOT_ENCODABLE, message=str(exc))
    notes = tuple(dict.fromkeys(encoder.notes))
    if root is False:
        return result(CoarseStatus.INFEASIBLE, bound=-math.inf, notes=notes,
                      message="the spec is false whatever the paths")  # fmt: skip
    cap = robustness_cap_m if robustness_cap_m is not None else problem.solver.robustness_cap_m
    if root is True:
        rho = builder.add_vars(1, 0.0, 0.0)
    else:
        hi = float(root.hi[0]) if cap is None else min(float(root.hi[0]), float(cap))
        lo = float(root.lo[0]) if min_robustness is None else float(min_robustness)
        if lo > hi:  # the bounds alone rule the requirement out
            return result(CoarseStatus.INFEASIBLE, bound=hi, notes=notes,
                          message=f"robustness cannot exceed {hi:g} m")  # fmt: skip
        rho = builder.add_vars(1, lo, hi)
        builder.add_rows(
            np.hstack([rho[:, None], root.cols]), np.hstack([[[1.0]], -root.vals]),
            -np.inf, root.const,
        )  # fmt: skip
    builder.cost[int(rho[0])] = 1.0
    build_s = time.perf_counter() - t0
    if stop is not None and stop.is_set():
        return result(CoarseStatus.NO_SOLUTION, notes=notes, message="stopped before HiGHS ran")
    out = builder.solve(
        time_limit_s=max(0.05, float(time_limit_s) - build_s),
        mip_rel_gap=mip_rel_gap,
        stop=stop,
        on_incumbent=on_incumbent,
        cpu_until=cpu_until,
    )
    if out.status == "kOptimal" and out.has_solution:
        status = CoarseStatus.OPTIMAL
    elif out.status in ("kInfeasible", "kUnboundedOrInfeasible"):
        status = CoarseStatus.INFEASIBLE
    else:
        status = CoarseStatus.FEASIBLE if out.has_solution else CoarseStatus.NO_SOLUTION
    robustness = out.objective if out.has_solution else math.nan
    bound = out.bound if status is not CoarseStatus.INFEASIBLE else -math.inf
    if root is True:
        robustness = bound = math.inf if out.has_solution else math.nan
    x = out.x
    polish_s = 0.0
    if out.has_solution and root is not True:
        t_polish = time.perf_counter()
        left = float(time_limit_s) - (t_polish - t0)
        x = _smoothest(builder, model, out.x, int(rho[0]), out.objective, left)
        polish_s = time.perf_counter() - t_polish
    waypoints = model.positions(x) if out.has_solution else {}
    return result(
        status,
        robustness=robustness,
        bound=bound if math.isfinite(bound) or status is not CoarseStatus.OPTIMAL else robustness,
        waypoints_enu_m=waypoints,
        build_s=build_s + out.setup_s,
        solve_s=out.solve_s + polish_s,
        notes=notes,
        nodes=out.nodes,
        message=""
        if status is not CoarseStatus.NO_SOLUTION and out.status != "kInterrupt"
        else f"HiGHS: {out.status}",
    )
