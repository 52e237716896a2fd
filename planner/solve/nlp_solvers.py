"""The NLP's solvers: IPOPT (or CasADi's sqpmethod) made from a built NLP, with its
derivatives assembled per block (:func:`derivatives`), the iteration watch that stops a
solve at its deadline (:class:`IterationWatch`), MUMPS's ordering and the one-thread BLAS
(:func:`one_blas_thread`).  What each option measured: ``docs/solver-notes.md``.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from typing import Any

import casadi as ca
import numpy as np

from planner.problem import Problem, SolverMethod
from planner.solve.leaf_templates import local_hessian
from planner.solve.rowwise import SampleLeaf, block_hessian, block_jacobian

__all__ = [
    "MU_MAX",
    "IterationWatch",
    "derivatives",
    "make_solver",
    "mumps_order",
    "one_blas_thread",
]


class IterationWatch(ca.Callback):
    """Called by the solver after every iteration: counts them, shows the iterate to
    ``on_iteration`` (decision vector, objective), and asks the solver to stop once
    ``time.perf_counter()`` passes ``deadline`` (IPOPT then returns User_Requested_Stop
    with its last iterate).  One per built structure, shared by its solvers; a plan sets
    ``deadline`` and ``on_iteration`` before it solves."""

    def __init__(self, n_x: int, n_g: int, n_p: int) -> None:
        ca.Callback.__init__(self)
        self._dims = {"x": n_x, "f": 1, "g": n_g, "lam_x": n_x, "lam_g": n_g, "lam_p": n_p}
        self.deadline = math.inf
        self.iterations = 0
        self.stopped = False
        self.on_iteration: Callable[[np.ndarray, float], None] | None = None
        self.construct("stl_iteration_watch", {})

    def arm(
        self, deadline: float, on_iteration: Callable[[np.ndarray, float], None] | None
    ) -> None:
        """Before a solve: no iterations yet, not stopped, stop at ``deadline``, show each
        iterate to ``on_iteration``."""
        self.deadline = deadline
        self.iterations = 0
        self.stopped = False
        self.on_iteration = on_iteration

    def take_over(self, old: IterationWatch) -> None:
        """Go on with ``old``'s solve (another structure's: a grown screen): its deadline,
        its iterations and its ``on_iteration``, which ``old`` gives up."""
        self.arm(old.deadline, old.on_iteration)
        self.iterations = old.iterations
        old.on_iteration = None

    def get_n_in(self) -> int:
        return int(ca.nlpsol_n_out())

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return str(ca.nlpsol_out(i))

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> Any:
        n = self._dims.get(str(ca.nlpsol_out(i)), 0)
        return ca.Sparsity.dense(n, 1) if n else ca.Sparsity(0, 0)

    def get_sparsity_out(self, i: int) -> Any:
        return ca.Sparsity.scalar()

    def eval(self, arg: Sequence[Any]) -> list[Any]:
        self.iterations += 1
        if self.on_iteration is not None:
            self.on_iteration(np.asarray(arg[0]).reshape(-1), float(arg[1]))
        if time.perf_counter() > self.deadline:
            self.stopped = True
            return [1]
        return [0]


def derivatives(
    w: Any,
    p: Any,
    f: Any,
    linear: list[Any],
    nonlinear: list[Any],
    hessian: bool,
    flat: Sequence[bool] = (),
    rowwise: Sequence[tuple[SampleLeaf, np.ndarray] | None] = (),
    check: Callable[[], None] = lambda: None,
) -> dict[str, Any]:
    """Constraint Jacobian and Lagrangian Hessian assembled block by block.

    CasADi differentiates a whole SX graph with one colouring and one mode; here the
    blocks differ (dense rows of the smooth leaves in Z, the dense column of r in every
    leaf, sparse local rows), and one colouring for all of them costs several times the
    sum of the per-block derivatives (measured 4.7 s vs 1.1 s on power-line N = 2).

    ``flat[i]`` leaves the i-th nonlinear block's curvature out of the Hessian (its
    gradient stays exact, so the KKT point is the same; only IPOPT's step model changes).
    The planner does this for the separation rows: ``dist >= s`` is reverse-convex, its
    curvature term is negative, and with it IPOPT corrected the inertia (factorised again)
    in 60 of 63 iterations on reach-avoid N = 8, without it in 27 of 76 (tol 1e-4).  Linearising keep-apart constraints is
    what sequential convex programming does for collision avoidance.

    ``rowwise[i]``, where given, is the i-th nonlinear block as one sample's leaf and the
    entries of ``w`` at its steps: its Jacobian and Hessian are then that sample's mapped over
    the steps (:mod:`planner.solve.rowwise`), not the block's differentiated whole, and they join
    the SX blocks' in MX functions, so that no SX graph of every step's derivatives is built
    (the 40-pole line: 21 s of symbolic derivatives and 18 s of SX functions of its 53 s
    build).

    ``check`` is called between the pieces (the build's deadline, :class:`NlpBuilder`).
    """
    n_w = int(w.shape[0])
    blocks = [*linear, *nonlinear]
    g = ca.vertcat(*blocks)
    mapped = [rowwise[ib] if ib < len(rowwise) else None for ib in range(len(nonlinear))]
    jacs = [ca.jacobian(b, w) for b in linear]
    for b, one in zip(nonlinear, mapped, strict=True):
        check()
        if one is None:
            jacs.append(ca.jacobian(b, w))
        else:  # only -a in r's column here (b = rows - a r, linear in r); the rows in MX
            jacs.append(ca.horzcat(ca.SX(int(b.shape[0]), n_w - 1), ca.jacobian(b, w[n_w - 1])))
    check()
    jac_sx = ca.Function("nlp_jac_g_sx", [w, p], [g, ca.vertcat(*jacs)])
    check()
    wm, pm = ca.MX.sym("w", n_w), ca.MX.sym("p", int(p.shape[0]))
    g_m, jac_m = jac_sx(wm, pm)
    n_lin = sum(int(b.shape[0]) for b in linear)
    if any(one is not None for one in mapped):
        parts = [ca.MX(n_lin, n_w)]
        for b, one in zip(nonlinear, mapped, strict=True):
            rows = int(b.shape[0])
            parts.append(ca.MX(rows, n_w) if one is None else block_jacobian(one[0], wm, one[1]))
        jac_m = jac_m + ca.vertcat(*parts)
    out = {"jac_g": ca.Function("nlp_jac_g", [wm, pm], [g_m, jac_m], ["x", "p"], ["g", "jac_g_x"])}
    if hessian:
        lam_f = ca.SX.sym("lam_f")
        lam_g = ca.SX.sym("lam_g", g.shape[0])
        H = lam_f * local_hessian(f, w)
        lam_fm, lam_gm = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.shape[0])
        mapped_h = []
        row = n_lin
        for ib, (b, one) in enumerate(zip(nonlinear, mapped, strict=True)):
            m = int(b.shape[0])
            check()
            if ib >= len(flat) or not flat[ib]:
                if one is not None:
                    mapped_h.append(block_hessian(one[0], wm, one[1], lam_gm[row : row + m]))
                else:
                    H = H + local_hessian(ca.dot(lam_g[row : row + m], b), w)
            row += m
        check()
        h_sx = ca.Function("nlp_hess_sx", [w, p, lam_f, lam_g], [H])
        check()
        H_m = h_sx(wm, pm, lam_fm, lam_gm)
        for h in mapped_h:
            H_m = H_m + h
        out["hess_lag"] = ca.Function(
            "nlp_hess_l",
            [wm, pm, lam_fm, lam_gm],
            [ca.triu(H_m)],
            ["x", "p", "lam_f", "lam_g"],
            ["triu_hess_gamma_x_x"],
        )
    return out


#: Largest barrier parameter IPOPT's adaptive rule may choose when the start already meets
#: the mission (m, the scale of r).  Unbounded, the rule raised mu to 1-4 at the second
#: iteration and threw such starts away (r fell to -4 m; road no-fly zone: 1,183 iterations
#: and a failure, paddock clearance: 1,000 and -3.1 m); capped, they are refined (7 and
#: 133 iterations).  From a start that falls short the unbounded rule explores better
#: (stlpy's benchmarks: median 0.92 of the optimum against 0.73 capped).
MU_MAX = 0.1


#: Fleets up to this size factorise with MUMPS's QAMD ordering, larger ones with MUMPS's
#: own choice (:func:`mumps_order`).
_QAMD_MAX_VEHICLES = 8


def mumps_order(problem: Problem, chunked: bool = False) -> int:
    """MUMPS's fill-reducing ordering (ICNTL(7)): 6, QAMD (minimum degree that sets
    quasi-dense rows aside), for small fleets and for any NLP with chunked leaves; 7,
    MUMPS's own choice (METIS here), for large fleets without.  Every leaf row shares r's
    column: with METIS the fill around it cost 24 s per iteration on the 20-pole line (4
    drones, 74,000 rows), 0.4 s with QAMD, and 88 s against 0.2 s on the 12-pole line; the
    12-drone, 6-pole line (chunked) ran 3 iterations in 140 s with METIS, 11 in 6.4 s with
    QAMD.  Where separation rows couple every pair of a large fleet at every sample and no
    long window is chunked, nested dissection wins instead (reach-avoid N = 16: 26.5 s with
    METIS, 81 s with QAMD; N = 12: 5.2 s against 10.5 s); N = 8 is even (power line: 3.3 s
    of IPOPT against 2.0 s)."""
    return 6 if chunked or len(problem.vehicles) <= _QAMD_MAX_VEHICLES else 7


def one_blas_thread() -> bool:
    """IPOPT's MUMPS calls the BLAS CasADi ships (its own OpenBLAS,
    ``libcasadi-tp-openblas``), whose threads only fight on a small shared machine (power
    line N = 4: 19 s with one thread, over 90 s with its default on 2 loaded cores).  Unless
    the user chose (``OMP_NUM_THREADS`` or ``OPENBLAS_NUM_THREADS`` set), that library runs
    one thread: set with its own ``openblas_set_num_threads``, nothing else in the process
    changed (no environment variable, no other library's threads).  Whether it was set
    (False: chosen by the user, or no such library in this CasADi)."""
    global _BLAS_SET
    if _BLAS_SET is None:
        _BLAS_SET = False
        chosen = any(os.environ.get(v) for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"))
        path = os.path.join(os.path.dirname(ca.__file__), "libcasadi-tp-openblas.so.0")
        if not chosen and os.path.exists(path):
            import ctypes

            try:
                ctypes.CDLL(path).openblas_set_num_threads(1)
                _BLAS_SET = True
            except (OSError, AttributeError):
                pass
    return _BLAS_SET


_BLAS_SET: bool | None = None


def make_solver(
    nlp: dict[str, Any],
    problem: Problem,
    derivs: dict[str, Any],
    watch: IterationWatch,
    warm: bool = False,
    refine: bool = False,
    chunked: bool = False,
) -> Any:
    """The solver; ``warm``: it starts from an earlier solve's primal-dual point (a later
    stage of the k continuation), so IPOPT keeps the multipliers and a small barrier;
    ``refine``: it starts from a point that meets the mission, and IPOPT's barrier is capped
    (``MU_MAX``) so that the start is refined, not re-centred."""
    s = problem.solver
    one_blas_thread()
    if s.method is SolverMethod.SQP:
        return _sqpsol(nlp, s, derivs, watch)
    return ca.nlpsol(
        "stl_ipopt",
        "ipopt",
        nlp,
        {
            "print_time": False,
            "error_on_fail": False,
            # The parameters' multipliers are never read (IPOPT gives the bounds' own):
            # computing them needs the reverse derivative of every row ("nlp_grad"), which
            # nlpsol otherwise builds when it is made (power line, 12 poles: 0.9 s of each
            # solver's construction; the 40-pole line: 7.3 s).
            "calc_lam_p": False,
            "no_nlp_grad": True,
            "iteration_callback": watch,
            **derivs,
            "ipopt": {
                "print_level": s.print_level,
                "sb": "yes",
                "max_iter": s.max_iter,
                "tol": s.tol,
                "acceptable_tol": 1e-4,
                "hessian_approximation": s.hessian,
                "limited_memory_max_history": s.lbfgs_history,
                "mu_strategy": "adaptive",
                "mumps_pivot_order": mumps_order(problem, chunked),
                **({"mu_max": MU_MAX} if refine else {}),
                **(_IPOPT_WARM if warm else {}),
            },
        },
    )


#: IPOPT options of a warm-started stage: start from the given multipliers with a small
#: barrier and pushes, instead of re-centring (which undoes the earlier stage).
_IPOPT_WARM: dict[str, Any] = {
    "warm_start_init_point": "yes",
    "mu_init": 1e-4,
    "warm_start_bound_push": 1e-6,
    "warm_start_bound_frac": 1e-6,
    "warm_start_slack_bound_push": 1e-6,
    "warm_start_slack_bound_frac": 1e-6,
    "warm_start_mult_bound_push": 1e-6,
}


def _sqpsol(nlp: dict[str, Any], s: Any, derivs: dict[str, Any], watch: IterationWatch) -> Any:
    """CasADi's ``sqpmethod`` on the same NLP and derivatives, with a QP solver of the wheel.

    sqpmethod takes the objective gradient and the constraint Jacobian as one function
    (``jac_fg``) and the full symmetric Hessian; an exact Hessian, indefinite here, is
    convexified by regularisation (CasADi's ``eigen-clip`` failed before the first
    iteration).  Measured (benchmarks/bench_solvers.py): IPOPT is faster on every scenario.
    """
    x, p = nlp["x"], nlp["p"]
    f, grad_f = derivs["grad_f"](x, p)
    g, jac_g = derivs["jac_g"](x, p)
    jac_fg = ca.Function(
        "nlp_jac_fg", [x, p], [f, grad_f.T, g, jac_g], ["x", "p"], ["f", "jac_f_x", "g", "jac_g_x"]
    )
    opts: dict[str, Any] = {
        "jac_fg": jac_fg,
        "qpsol": s.qpsol,
        "qpsol_options": {"error_on_fail": False, **_QPSOL_QUIET.get(s.qpsol, {})},
        "max_iter": s.max_iter,
        "print_header": False,
        "print_iteration": s.print_level > 0,
        "print_status": False,
        "print_time": False,
        "error_on_fail": False,
        "tol_pr": s.tol,
        "tol_du": s.tol,
        "iteration_callback": watch,
    }
    if s.hessian == "exact":
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.shape[0])
        upper = derivs["hess_lag"](x, p, lam_f, lam_g)
        opts["hess_lag"] = ca.Function(
            "nlp_hess_l",
            [x, p, lam_f, lam_g],
            [upper + ca.triu(upper, False).T],
            ["x", "p", "lam_f", "lam_g"],
            ["hess_gamma_x_x"],
        )
        opts["convexify_strategy"] = "regularize"
    else:
        opts["hessian_approximation"] = "limited-memory"
    return ca.nlpsol("stl_sqp", "sqpmethod", nlp, opts)


#: Options that keep the QP solvers quiet (their banners and per-iteration output).
_QPSOL_QUIET: dict[str, dict[str, Any]] = {
    "qpoases": {"printLevel": "none"},
    "osqp": {"osqp": {"verbose": False}},
    "qrqp": {"print_iter": False, "print_header": False},
    "highs": {"highs": {"output_flag": False}},
}
