"""One solver run of the planner's NLP and its bookkeeping.

:func:`run_solvers` runs a built structure's solvers (the k continuation) from a start;
:class:`SolverRun` is what they reached and cost, :class:`Attempt` one start of the
multi-start judged by its exact robustness.  Also the status the user reads
(:func:`user_status`), Ctrl-C noted during a solve (:func:`watch_sigint`) and the bounds of
the robustness variable ``r`` (:func:`lower_r`, :func:`min_leaf`).
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.solve.nlp import Structure

__all__ = [
    "EPS_MARGIN_STEP_M",
    "Attempt",
    "SigintWatch",
    "SolverRun",
    "lower_r",
    "min_leaf",
    "run_solvers",
    "solved",
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
