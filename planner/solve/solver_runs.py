"""One solver run of the planner's NLP and its bookkeeping.

:func:`run_solvers` runs a built structure's solvers (the k continuation) from a start;
:class:`SolverRun` is what they reached and cost, :class:`Attempt` one start of the
multi-start judged by its exact robustness.  Also the status the user reads
(:func:`user_status`), Ctrl-C noted during a solve (:func:`watch_sigint`) and the bounds of
the robustness variable ``r`` (:func:`lower_r`, :func:`min_leaf`), and the paper's eq. (1)
as rounds of a growing margin (:func:`margin_rounds`).
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.dynamics.limits import vehicle_bounds
from planner.problem import Vehicle
from planner.solve.nlp import Structure, vehicle_limit_bounds

__all__ = [
    "EPS_MARGIN_STEP_M",
    "Attempt",
    "SigintWatch",
    "SolverRun",
    "lower_r",
    "margin_rounds",
    "min_leaf",
    "nlp_bounds",
    "run_solvers",
    "solved",
    "start_point",
    "user_status",
    "watch_sigint",
]

#: The extra step (m) of each round of margin growth for the eq. (1) constraint (and the
#: room kept above r's raised lower bound).
EPS_MARGIN_STEP_M = 2e-3


def user_status(
    solver: str,
    converged: bool,
    success: bool,
    short: bool,
    verdict: str,
    *,
    interrupted: bool = False,
    time_limit_s: float | None = None,
) -> str:
    """The outcome in the user's terms first, the solver's own status after (in brackets):
    "the solver converged but the mission is not met: robustness -111 < epsilon 0.01 ...",
    never "Solve_Succeeded" on a plan that fails."""
    if interrupted:
        head = "interrupted (Ctrl-C); the best plan so far" + (
            ", and it meets the mission" if success else ""
        )
    elif time_limit_s is not None:
        head = f"stopped at the time limit ({time_limit_s:g} s); the best plan so far" + (
            ", and it meets the mission" if success else ""
        )
    elif success:
        head = "the mission is met"
    elif "for the combinatorial stage's" in solver:  # StageBeside.yielded
        head = "the solver was stopped for the combinatorial stage's answer; the best plan found"
    elif "NonIpopt_Exception_Thrown" in solver or "User_Requested_Stop" in solver:
        head = "the solver stopped on an error inside it; the best plan found"
    elif not converged:
        head = "the solver did not converge; the best plan found"
    elif short:
        head = "the solver converged but the mission is not met"
    else:
        head = "the solver converged but the plan breaks the vehicles' limits"
    return f"{head}: {verdict} (solver: {solver})"


def solved(status: str) -> bool:
    """Whether the solver's status (before any note after a ``;``) is a converged one."""
    return status.split(";", 1)[0] in (
        "Solve_Succeeded",
        "Solved_To_Acceptable_Level",
        "Search_Direction_Becomes_Too_Small",
    )


@dataclass(frozen=True, slots=True)
class Attempt:
    """What one start of the multi-start reached: the exact robustness of its plan."""

    robustness: float
    w: np.ndarray
    status: str
    converged: bool
    run: SolverRun


@dataclass(frozen=True, slots=True)
class SolverRun:
    """The end point of one or more solver runs and what they cost."""

    w: np.ndarray
    status: str
    iterations: int
    solver_s: float
    eval_s: float
    lam_g: np.ndarray | None = None  # the constraints' multipliers at w (the last solve's)

    def then(self, later: SolverRun) -> SolverRun:
        """``later``'s end point, with the costs of both."""
        return SolverRun(
            later.w,
            later.status,
            self.iterations + later.iterations,
            self.solver_s + later.solver_s,
            self.eval_s + later.eval_s,
            later.lam_g,
        )


class SigintWatch:
    """Whether Ctrl-C came during the solve (:func:`watch_sigint`)."""

    hit = False


@contextlib.contextmanager
def watch_sigint() -> Iterator[SigintWatch]:
    """Note a Ctrl-C (SIGINT) and pass it on as usual: CasADi's solver stops at its next
    check and returns its last iterate, which the planner keeps as the best so far.  Only
    in the main thread (signal handlers live there); elsewhere nothing is installed."""
    watch = SigintWatch()
    if threading.current_thread() is not threading.main_thread():
        yield watch
        return
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum: int, frame: Any) -> None:
        watch.hit = True
        if callable(previous):
            previous(signum, frame)
        else:
            raise KeyboardInterrupt

    signal.signal(signal.SIGINT, handler)
    try:
        yield watch
    finally:
        signal.signal(signal.SIGINT, previous)


def run_solvers(
    struct: Structure,
    w0: np.ndarray,
    bounds: Mapping[str, np.ndarray],
    say: Callable[[str], None],
    what: str,
    stop: SigintWatch,
    refine: bool = False,
) -> SolverRun:
    """Run the structure's solvers in turn (the k continuation), each warm started from the
    previous one's primal-dual point, until one is interrupted (``stop``).  ``bounds`` are
    read at call time (``lbx`` may change between calls).  ``refine``: ``w0`` meets the
    mission (or the constraints of :func:`raise_the_rest`), and the solvers that refine
    such a start run (``planner.solve.nlp_solvers.MU_MAX``)."""
    iterations = 0
    solver_s = eval_s = 0.0
    status = "not solved"
    w_opt = w0
    lam_x = lam_g = None
    for k, solver in struct.refining() if refine else struct.solvers:
        if stop.hit or struct.watch.stopped:
            break
        say(f"solving with {what} (k={k:.3g})")
        args: dict[str, Any] = {"x0": w_opt, **bounds}
        if lam_x is not None:
            args["lam_x0"] = lam_x
            args["lam_g0"] = lam_g
        t_s = time.perf_counter()
        try:
            sol = solver(**args)
        except RuntimeError as exc:  # CasADi's own input checks; a failed solve is a result
            solver_s += time.perf_counter() - t_s
            status = f"solver error: {str(exc).splitlines()[-1][:200]}"
            break
        solver_s += time.perf_counter() - t_s
        st = solver.stats()
        iterations += int(st.get("iter_count", 0))
        status = str(st.get("return_status", "unknown"))
        eval_s += sum(
            float(v)
            for kk, v in st.items()
            if kk.startswith("t_wall_nlp_") and isinstance(v, float)
        )
        w_new = np.asarray(sol["x"]).reshape(-1)
        if np.all(np.isfinite(w_new)):
            w_opt = w_new
            lam_x = np.asarray(sol["lam_x"]).reshape(-1)
            lam_g = np.asarray(sol["lam_g"]).reshape(-1)
    return SolverRun(w_opt, status, iterations, solver_s, eval_s, lam_g)


def lower_r(lbx: np.ndarray, ubx: np.ndarray, value: float) -> None:
    """Raise r's lower bound to ``value`` (in place), lifting a robustness cap above it so
    the bounds stay consistent: a cap below the required margin leaves r pinned there."""
    lbx[-1] = value
    ubx[-1] = max(ubx[-1], value + EPS_MARGIN_STEP_M)


def min_leaf(struct: Structure, w: np.ndarray, p: np.ndarray, default: float) -> float:
    """The smallest leaf value (the smooth robustness the NLP sees) at ``w``; ``default``
    when the spec has no leaves."""
    values = np.asarray(struct.leaf_fn(w, p)).reshape(-1)
    return float(np.min(values)) if values.size else default


def margin_rounds(
    struct: Structure,
    w0: np.ndarray,
    first: Attempt,
    bounds: Mapping[str, np.ndarray],
    eps: float,
    say: Callable[[str], None],
    stop: SigintWatch,
    exact: Callable[[np.ndarray], float],
    out_of_time: Callable[[], bool],
    rounds: int,
) -> Attempt:
    """The paper's eq. (1) after a start's first solve (``first``, from ``w0``): smooth
    robustness >= ``eps`` + margin as a constraint (r's lower bound in ``bounds["lbx"]``).

    The margin starts at the smooth leaves' error bound; while the exact robustness
    (``exact``, dense samples) still falls short (dips between constraint samples), the
    margin grows by the deficit and the solve restarts from the point it reached, at most
    ``rounds`` times; the best point of these rounds is kept.  If it still falls short (and
    there is time), the plain maximisation from ``w0`` runs too: a failed result carries the
    best trajectories there are.
    """
    lbx, ubx = bounds["lbx"], bounds["ubx"]
    rob, w_opt, status, run = first.robustness, first.w, first.status, first.run
    margin = struct.margin
    best = (rob, w_opt, status)
    for _ in range(rounds):
        if rob >= eps or not solved(status) or out_of_time():
            break
        margin += eps - rob + EPS_MARGIN_STEP_M
        lower_r(lbx, ubx, eps + margin)
        w_start = w_opt.copy()
        w_start[-1] = lbx[-1]
        run = run.then(run_solvers(struct, w_start, bounds, say, "eq. (1) margin", stop))
        w_opt, status = run.w, run.status
        rob = exact(w_opt)
        if rob > best[0]:
            best = (rob, w_opt, status)
    rob, w_opt, status = best
    converged = solved(status)
    if rob < eps and not out_of_time():
        # Infeasible as constrained: the plain maximisation from the same start.
        lbx[-1], ubx[-1] = struct.lbx[-1], struct.ubx[-1]
        plain = run_solvers(struct, w0, bounds, say, "plain maximisation", stop)
        rob_plain = exact(plain.w)
        if rob_plain > rob:
            rob, w_opt = rob_plain, plain.w
            converged = solved(plain.status)
            status = f"eq. (1) constraint not met ({status}); plain maximisation: {plain.status}"
        run = run.then(plain)
    return Attempt(rob, w_opt, status, converged, run)


def nlp_bounds(
    struct: Structure,
    model: Any,
    vehicles: Sequence[Vehicle],
    p_val: np.ndarray,
    fixed: tuple[np.ndarray, np.ndarray] | None,
) -> dict[str, np.ndarray]:
    """The numeric bounds of ``struct``'s NLP for these vehicles: each vehicle's limits
    into ``lbg``/``ubg`` (vehicles with equal limits share one computation), the decisions
    ``fixed`` (indices, values: a replan's kept prefix) at their values, and the
    parameters ``p_val``; the keys of CasADi's ``nlpsol`` call."""
    lbg = struct.lbg_fixed.copy()
    ubg = struct.ubg_fixed.copy()
    per_limits: dict[tuple[Any, Any], tuple[np.ndarray, np.ndarray]] = {}
    for i, v in enumerate(vehicles):
        key = vehicle_bounds(v)
        if key not in per_limits:
            per_limits[key] = vehicle_limit_bounds(model, v, struct.lim_half, struct.norm_rows)
        lbg[struct.lim_slices[i]], ubg[struct.lim_slices[i]] = per_limits[key]
    lbx, ubx = struct.lbx.copy(), struct.ubx.copy()
    if fixed is not None:
        lbx[fixed[0]] = ubx[fixed[0]] = fixed[1]
    return {"p": p_val, "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg}


def start_point(
    struct: Structure,
    model: Any,
    x0s: Sequence[np.ndarray],
    p_val: np.ndarray,
    z0: np.ndarray,
) -> np.ndarray:
    """The NLP's start point for the decisions ``z0`` (of vehicles starting at ``x0s``):
    the sampled positions lifted, the chunks' values there, and r at the smallest leaf
    value."""
    Mp, Np = np.asarray(model.Mp), np.asarray(model.Np)
    nd = model.n_dec * 3
    p0 = [
        (Mp @ z0[i * nd : (i + 1) * nd].reshape((model.n_dec, 3), order="F") + Np @ x0)[
            struct.used_steps
        ].reshape(-1, order="F")
        for i, x0 in enumerate(x0s)
    ]
    w0 = np.concatenate([z0, *p0, np.zeros(struct.n_s), [0.0]])
    if struct.n_s:  # the chunks' values there (planner.solve.leaves.chunks_of)
        w0[-1 - struct.n_s : -1] = np.asarray(struct.chunk_fn(w0, p_val)).reshape(-1)
    w0[-1] = min_leaf(struct, w0, p_val, default=0.0)
    return w0
