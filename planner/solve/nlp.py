"""The NLP of :func:`planner.optimize.plan`: the spec's leaves as constraints on the epigraph
variable ``r``, the dynamics and limits, and the IPOPT / sqpmethod glue.

Formulation (maximise ``r`` with every conjunctive leaf of the spec at least ``r`` at its
sample steps, the limits as linear rows on the continuous trajectory, the positions lifted
into variables) and why it is shaped so: ``docs/solver-notes.md``, "The formulation", which
also says what each choice measured.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from planner.cache import BoundedCache
from planner.dynamics.limits import NORM_DIRECTIONS, vehicle_bounds
from planner.errors import PlannerError
from planner.problem import Problem
from planner.solve.leaf_templates import (
    LeafInstance,
    clear_templates,
    instance,
    smoothing_terms,
)
from planner.solve.leaves import (
    chunks_of,
    constraint_stride,
    decompose,
    direct_steps_of,
    is_direct,
    local_positions,
    lse,
)
from planner.solve.nlp_solvers import IterationWatch, derivatives, make_solver
from planner.solve.rowwise import SampleLeaf, sample_leaf
from planner.solve.screen import Screen
from planner.spec.predicates import (
    Role,
    ca_box_margins,
    casadi_functions,
    predicate_sharpness,
    role_of,
)
from planner.stl import (
    CmpOp,
    Comparison,
    Const,
    Expr,
    Formula,
    Predicate,
    comparison_margin,
    fold_expr,
)

#: Lower bound of the fitted smoothing sharpness (1/m).
K_MIN = 10.0
#: Fraction of the smallest region half-size the smooth leaves may be off by.
_K_TOLERANCE = 0.06
#: Weight of the mean squared acceleration ((m/s^2)^2) subtracted from r in the objective.
_REG_WEIGHT = 1e-3
#: Upper bound of the epigraph variable r (m): keeps IPOPT bounded on trivial specs.
_R_MAX = 1e3


def _ca_expr(e: Expr, rows: Mapping[str, Any], fns: Mapping[str, Callable[..., Any]]) -> Any:
    """An expression on the lifted rows (the STL engine's one evaluator, CasADi leaves)."""
    return fold_expr(e, lambda s: rows[s.name], lambda c: fns[c.name](c.args, rows))


# ------------------------------------------------------------------------------ build


class BuildTimeout(PlannerError):
    """The time limit came while the NLP was being built (:class:`NlpBuilder`'s
    ``deadline``, checked between its pieces)."""


@dataclass(slots=True)
class Structure:
    """A built NLP, reusable for any start states and limits of the same structure."""

    solvers: list[tuple[float, Any]]  # (k, nlpsol) in continuation order
    make_refining: Callable[[], list[tuple[float, Any]]]  # the same, refining (make_solver)
    watch: IterationWatch  # every solver's iteration callback
    leaf_fn: Any  # ca.Function (w, p) -> leaf values (for r0)
    chunk_fn: Any  # ca.Function (w, p) -> the chunks' values (S at a point's Z)
    n_w: int
    n_z: int  # the first n_z entries of w are the Z matrices (vec, vehicle after vehicle)
    n_s: int  # the chunks' values (S): w's n_s entries before r
    n_g: int
    lbx: np.ndarray
    ubx: np.ndarray
    lbg_fixed: np.ndarray
    ubg_fixed: np.ndarray
    lim_slices: list[slice]  # g rows of each vehicle's limits
    lim_half: int  # rows of the model's limits kept (two-sided rows when they pair up)
    norm_rows: bool  # whether each vehicle's limit rows end with the horizontal-norm rows
    leaves: dict[Formula, set[int]]
    used_steps: list[int]  # planning steps whose positions are lifted into variables
    n_lin: int  # g's rows before the leaf rows (which follow: direct rows, smooth rows)
    n_x0: int  # p's start states (the leaf rows' weights on r follow)
    leaf_group: np.ndarray  # each leaf row's leaf, an index into leaf_names
    leaf_at_start: np.ndarray  # whether the row is a direct leaf at t = 0 (start states only)
    leaf_names: list[str]
    n_smooth: int
    k: float
    margin: float
    build_s: float
    #: the error bound of the smooth leaves' box predicates (log(6)/k_pred; 0 when they
    #: have none, or when they are smoothed at the leaves' own k: ``sharp``)
    box_bound: float
    _refining: list[tuple[float, Any]] | None = None
    #: held by the search that uses the structure (its watch is one per structure)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def refining(self) -> list[tuple[float, Any]]:
        """The solvers for a start that meets the mission (built at first use)."""
        if self._refining is None:
            self._refining = self.make_refining()
        return self._refining


#: Built NLPs and solvers by problem structure (oldest forgotten first)
STRUCTURES: BoundedCache[Structure] = BoundedCache(8)


def clear_cache() -> None:
    """Forget built solvers and leaf templates (benchmarks measure cold builds with this)."""
    STRUCTURES.clear()
    clear_templates()


def structure_key(problem: Problem, sharp: bool = False, screen: Screen | None = None) -> Any:
    s = problem.solver
    return (
        sharp,
        None if screen is None else screen.key(),
        problem.spec_text,
        tuple((r.name, r.lo_enu_m, r.hi_enu_m, r.shape) for r in problem.all_regions),
        problem.timing,
        problem.model,
        tuple(v.name for v in problem.vehicles),
        dataclasses.replace(s, starts=1, polish_s=0.0, lexicographic_rounds=0, coarse_s=0.0),
        problem.epsilon,
        _has_norm_limits(problem),
        None if problem.terrain is None else problem.terrain.digest,
    )


def _has_norm_limits(problem: Problem) -> bool:
    """Whether a vehicle bounds a horizontal norm (then the NLP has the polygon's rows)."""
    return any(b.has_norm for v in problem.vehicles for b in vehicle_bounds(v))


def _fit_k(
    problem: Problem, smooth_leaves: Sequence[Formula], dt: float, sharp: bool = False
) -> tuple[float, float]:
    """(k, error bound at k) for the smooth leaves: bound = 6 % of the smallest half-size
    (with ``sharp``, the leaves' box predicates smoothed at the same k count in it)."""
    if problem.solver.k is not None:
        k = problem.solver.k
    elif not smooth_leaves:
        k = K_MIN
    else:
        tol = _K_TOLERANCE * min(r.min_half_m for r in problem.all_regions)
        unit = max(_smooth_bound(leaf, 1.0, dt, sharp, problem) for leaf in smooth_leaves)
        k = max(K_MIN, unit / tol)
    bound = max((_smooth_bound(leaf, k, dt, sharp, problem) for leaf in smooth_leaves), default=0.0)
    return k, bound


def _smooth_bound(leaf: Formula, k: float, dt: float, sharp: bool, problem: Problem) -> float:
    """Bound on a smooth leaf's error at sharpness ``k``: its temporal operators', and with
    ``sharp`` its predicates' (smoothed at the same ``k``,
    :func:`planner.solve.leaf_templates.smoothing_terms`)."""
    own = smoothing_terms(leaf, problem) / k if sharp else 0.0
    return leaf.smooth_error_bound(k, dt) + own


def _leaf_values(
    leaf: Formula,
    steps: list[int],
    rows_of: Callable[[list[int]], Mapping[str, Any]],
    problem: Problem,
    fns: Mapping[str, Callable[..., Any]],
) -> Any:
    """SX column of a row-wise leaf's robustness at ``steps`` (from the lifted positions)."""
    rows = rows_of(steps)
    if isinstance(leaf, Predicate):
        if role_of(leaf) is Role.TARGET_BOX:  # exact linear face margins
            region = problem.region(leaf.call.args[1])
            return ca.vec(ca_box_margins(rows[leaf.call.args[0]], region))
        return fns[leaf.call.name](leaf.call.args, rows)
    assert isinstance(leaf, Comparison)
    out = comparison_margin(leaf.op, _ca_expr(leaf.lhs, rows, fns), _ca_expr(leaf.rhs, rows, fns))
    return out * ca.DM.ones(len(steps), 1) if not hasattr(out, "shape") else out


class NlpBuilder:
    """The NLP put together from composable pieces, in the spirit of stlpy's ``STLSolver``.

    Each ``add_*`` method contributes one part: the dynamics (lifting equalities, per-vehicle
    limits, rest at the end, the model's own equalities), the spec's row-wise leaves as
    constraints on the epigraph variable ``r``, the robustness objective, and the variable
    bounds (the workspace, and the robustness cap as ``r``'s upper bound); :meth:`solvers`
    builds one solver per stage of the k continuation.  The paper's eq. (1) (``r >= epsilon +
    margin``) is not a separate structure: it is a lower bound on ``r`` that
    :func:`planner.optimize.plan` sets per solve (:attr:`Structure.lbx`), like the limits'
    bounds.  :func:`build_structure` calls the pieces in order; the rows keep that order.
    """

    def __init__(
        self,
        problem: Problem,
        model: Any,
        formula: Formula,
        sharp: bool = False,
        deadline: float = math.inf,
        screen: Screen | None = None,
    ) -> None:
        self.t0 = time.perf_counter()
        #: when (``time.perf_counter()``) the build must give up (:meth:`check_deadline`)
        self.deadline = deadline
        self.sharp = sharp
        self.problem, self.model = problem, model
        self.dt = problem.timing.sample_dt_s
        self.n = len(model.times_s)
        self.names = [v.name for v in problem.vehicles]
        self.opts = opts = problem.solver
        # Lifted formulation: the sampled positions P_i (n, 3) are variables tied to Z_i by
        # linear equalities.  Row-wise leaves (separation, obstacles, boxes) then touch a few
        # variables each, so the constraint Jacobian and the Lagrangian Hessian are very
        # sparse and CasADi's symbolic derivatives need few directions (colouring) whatever N
        # is.  Smooth leaves couple many samples (a window's soft max): they are written in Z
        # (the same positions through Mp), where their dense Hessian block is n_dec*3 wide,
        # not n*3.
        self.leaves: dict[Formula, set[int]] = {}
        decompose(formula, np.array([0]), self.dt, self.leaves)
        self.smooth_leaves = [leaf for leaf in self.leaves if not is_direct(leaf)]
        self.box_terms = max(
            (smoothing_terms(leaf, problem) for leaf in self.smooth_leaves), default=0.0
        )
        self.k_final, self.margin = _fit_k(problem, self.smooth_leaves, self.dt, sharp)
        self.k_list = [*[kk for kk in opts.continuation if kk < self.k_final], self.k_final]
        self.k_pred = predicate_sharpness(problem)  # the direct rows' (outside: the obstacles)
        self.fns = casadi_functions(problem, self.k_pred)
        stride = constraint_stride(problem)
        self.screen = screen
        self.direct_steps = direct_steps_of(self.leaves, stride)
        # The workspace bounds the lifted positions, so every constraint step of the horizon
        # is lifted, whether or not the spec itself constrains it there; and whatever a
        # screen keeps, so that the NLP's point has one layout in every screen (row
        # generation moves a point from one screen's NLP to the next).
        grid = {*range(0, self.n, stride), self.n - 1}
        self.used = sorted(grid.union(*self.direct_steps.values()))
        self.row_of = {st: i for i, st in enumerate(self.used)}
        if screen is not None:  # only the steps where a row can bind (planner.solve.screen)
            self.direct_steps = {
                leaf: kept
                for leaf, steps in self.direct_steps.items()
                if (kept := [st for st in steps if st in screen.steps.get(leaf, ())])
            }

        # The smooth leaves at their steps; a long eventually's chunks (chunks_of) in S.
        self.smooth_items = [
            (leaf, st) for leaf in self.smooth_leaves for st in sorted(self.leaves[leaf])
        ]
        per_segment = max(1, round(problem.timing.segment_s / self.dt))
        chunked = local_positions(model)
        self.chunks = [
            chunks_of(leaf, st, self.dt, per_segment) if chunked else []
            for leaf, st in self.smooth_items
        ]
        self.n_s = sum(len(c) for c in self.chunks)

        names = self.names
        self.Z = [ca.SX.sym(f"Z_{nm}", model.n_dec, 3) for nm in names]
        self.P = [ca.SX.sym(f"P_{nm}", len(self.used), 3) for nm in names]
        self.X0 = [ca.SX.sym(f"X0_{nm}", model.n_init, 3) for nm in names]
        self.S = ca.SX.sym("S", self.n_s)
        self.r = ca.SX.sym("r")
        self.w = ca.vertcat(
            *[ca.vec(z) for z in self.Z], *[ca.vec(q) for q in self.P], self.S, self.r
        )
        self.wm = ca.MX.sym("w", self.w.shape[0])
        # p: the start states, then each leaf row's weight on r (1: the row is ``>= r``; 0:
        # it is held at a fixed floor instead, :func:`planner.optimize` settling it).
        self.n_x0 = model.n_init * 3 * len(names)
        self._set_parameters(ca.SX(0, 1))
        self._sx: dict[str, Any] | None = None
        self.n_z = model.n_dec * 3 * len(names)
        # the parts, filled by the add_* methods
        self.linear: list[Any] = []
        self.nonlinear: list[Any] = []
        self.direct: Any = ca.SX(0, 1)
        self.f: Any = None
        self.lbx = self.ubx = np.zeros(0)
        self.n_lift = self.n_lim = self.n_eq = 0
        self.direct_rows: list[int] = []  # rows of each direct leaf (direct_steps' order)
        self.lim_slices: list[slice] = []
        self.lim_half = 0
        self.norm_rows = _has_norm_limits(problem)

    def check_deadline(self) -> None:
        """Raise :class:`BuildTimeout` once the deadline has passed; called between the
        build's pieces (a template, a row-wise leaf, a stage), so the build overruns the
        deadline by one piece at most."""
        if time.perf_counter() > self.deadline:
            raise BuildTimeout(
                f"the time limit came while building the NLP "
                f"({time.perf_counter() - self.t0:.1f} s into it)"
            )

    def add_dynamics_constraints(self) -> NlpBuilder:
        """Linear rows: the lifting equalities, the limits, rest at the end (the rows stay,
        free, with ``timing.end: free``), the model's own equalities (the acceleration chain
        of an explicit-acc primitive chain)."""
        model, nv = self.model, len(self.names)
        Z, P, X0 = self.Z, self.P, self.X0
        Mp, Np = ca.sparsify(ca.DM(model.Mp)), ca.sparsify(ca.DM(model.Np))
        pos_from_z = [ca.mtimes(Mp, Z[i]) + ca.mtimes(Np, X0[i]) for i in range(nv)]
        lift_g = [ca.vec(P[i] - pos_from_z[i][self.used, :]) for i in range(nv)]
        self.n_lift = len(self.used) * 3 * nv
        lim_g = []
        row = self.n_lift
        cons = model.limit_constraints(np.ones(3), np.ones(3))
        self.lim_half = half = two_sided_rows(cons)
        G = ca.sparsify(ca.DM(cons.G[:half]))
        H = ca.sparsify(ca.DM(cons.H[:half]))
        for i in range(nv):
            ctrl = ca.mtimes(G, Z[i]) + ca.mtimes(H, X0[i])  # control points (half, 3)
            gi = ca.vec(ctrl)
            if self.norm_rows:  # the inscribed polygon's rows coupling x and y
                gi = ca.vertcat(gi, *[c * ctrl[:, 0] + s * ctrl[:, 1] for c, s in NORM_DIRECTIONS])
            lim_g.append(gi)
            self.lim_slices.append(slice(row, row + gi.shape[0]))
            row += gi.shape[0]
        self.n_lim = row - self.n_lift
        Mv_end = ca.DM(model.Mv[-1:, :])
        Nv_end = ca.DM(model.Nv[-1:, :])
        end_g = [ca.vec(ca.mtimes(Mv_end, Z[i]) + ca.mtimes(Nv_end, X0[i])) for i in range(nv)]
        Ge, He = (ca.sparsify(ca.DM(m)) for m in model.equality_constraints())
        eq_g = [ca.vec(ca.mtimes(Ge, Z[i]) + ca.mtimes(He, X0[i])) for i in range(nv)]
        self.n_eq = Ge.shape[0] * 3 * nv
        self.linear = [*lift_g, *lim_g, *end_g, *eq_g]
        return self

    def add_spec_constraints(self) -> NlpBuilder:
        """The row-wise leaves, each ``>= r`` at its constraint steps (the smooth leaves join
        per k in :meth:`solvers`, as calls of shared templates)."""
        Pd = dict(zip(self.names, self.P, strict=True))

        def rows_of(steps: list[int]) -> dict[str, Any]:
            idx = [self.row_of[st] for st in steps]
            return {nm: q[idx, :] for nm, q in Pd.items()}

        direct_parts = [
            _leaf_values(leaf, steps, rows_of, self.problem, self.fns)
            for leaf, steps in self.direct_steps.items()
        ]
        self.direct = ca.vertcat(*direct_parts) if direct_parts else ca.SX(0, 1)
        self.direct_rows = [int(part.shape[0]) for part in direct_parts]
        self._set_parameters(ca.SX.sym("A", self.direct.shape[0]))
        weights, row = [], 0
        for part in direct_parts:
            weights.append(self.a_direct[row : row + part.shape[0]])
            row += part.shape[0]
        self.nonlinear = [part - a * self.r for part, a in zip(direct_parts, weights, strict=True)]
        return self

    def _set_parameters(self, a_direct: Any) -> None:
        """p = [start states, the direct rows' weights on r, the smooth rows' weights]."""
        self.a_direct = a_direct
        a_smooth = ca.SX.sym("A_smooth", len(self.smooth_items))
        self.p = ca.vertcat(*[ca.vec(x) for x in self.X0], a_direct, a_smooth)
        self.pm = ca.MX.sym("p", self.p.shape[0])

    def parameters(self, x0s: Sequence[np.ndarray]) -> np.ndarray:
        """The value of p for start states ``x0s``: every leaf row ``>= r``."""
        starts = [np.asarray(x).reshape(-1, order="F") for x in x0s]
        return np.concatenate([*starts, np.ones(int(self.p.shape[0]) - self.n_x0)])

    def add_robustness_cost(self) -> NlpBuilder:
        """Maximise ``r``; a small acceleration penalty gives the NLP curvature in the
        directions ``r`` does not care about (the max-min objective is flat there; measured
        to cut iterations)."""
        model, nv = self.model, len(self.names)
        Ma, Na = ca.sparsify(ca.DM(model.Ma)), ca.sparsify(ca.DM(model.Na))
        acc_sq = 0
        for i in range(nv):
            acc = ca.mtimes(Ma, self.Z[i]) + ca.mtimes(Na, self.X0[i])
            acc_sq = acc_sq + ca.sumsqr(acc)
        self.f = -self.r + _REG_WEIGHT * acc_sq / (self.n * nv)
        return self

    def add_bounds(self) -> NlpBuilder:
        """Simple bounds: the workspace on the lifted positions; on ``r`` the robustness cap
        (``solver.robustness_cap_m``) above, and nothing below (eq. (1) sets it per solve)."""
        ws, nv, m = self.problem.workspace, len(self.names), len(self.used)
        cap = self.opts.robustness_cap_m
        r_hi = _R_MAX if cap is None else cap + self.margin
        n_z = self.n_z
        free = np.full(self.n_s, np.inf)  # the chunks' values (equality rows hold them)
        self.lbx = np.concatenate(
            [np.full(n_z, -np.inf), np.tile(np.repeat(ws.lo_enu_m, m), nv), -free, [-np.inf]]
        )
        self.ubx = np.concatenate(
            [np.full(n_z, np.inf), np.tile(np.repeat(ws.hi_enu_m, m), nv), free, [r_hi]]
        )
        return self

    def _sx_derivatives(self) -> dict[str, Any]:
        """The SX blocks' functions (values and derivatives), built once for every k."""
        if self._sx is None:
            w, p = self.w, self.p
            # Separation rows enter the Hessian flat unless asked otherwise (derivatives).
            flat = [
                is_separation(leaf) and not self.opts.separation_curvature
                for leaf in self.direct_steps
            ]
            exact = self.opts.hessian == "exact"
            rowwise = [self.sample_leaf(leaf, steps) for leaf, steps in self.direct_steps.items()]
            sx = derivatives(
                w, p, self.f, self.linear, self.nonlinear, exact, flat, rowwise,
                check=self.check_deadline,
            )  # fmt: skip
            self.check_deadline()
            # Values and derivatives are separate functions: nlpsol differentiates the MX
            # values once more (reverse mode, for the multipliers) and must not go through
            # derivative outputs.
            sx["f"] = ca.Function("nlp_f", [w, p], [self.f])
            sx["grad_f"] = ca.Function("nlp_grad_f", [w, p], [self.f, ca.gradient(self.f, w)])
            sx["g"] = ca.Function("nlp_g", [w, p], [ca.vertcat(*self.linear, *self.nonlinear)])
            self._sx = sx
        return self._sx

    def sample_leaf(self, leaf: Formula, steps: list[int]) -> tuple[SampleLeaf, np.ndarray] | None:
        """A row-wise leaf at one sample (:mod:`planner.solve.rowwise`) and the entries of ``w``
        its positions are at each of its steps (None: constant rows)."""
        self.check_deadline()
        one = sample_leaf(
            lambda xs: _leaf_values(leaf, [0], lambda _steps: xs, self.problem, self.fns),
            self.names,
        )
        if one is None:
            return None
        m = len(self.used)
        rows = np.array([self.row_of[st] for st in steps])
        cols = [self.n_z + i * 3 * m + axis * m + rows for i in one.vehicles for axis in range(3)]
        return one, np.stack(cols, axis=1)

    def assemble(self, k: float) -> tuple[dict[str, Any], dict[str, Any], Any, Any]:
        """The NLP at temporal sharpness ``k``: :func:`_assemble` of the SX blocks and the
        smooth leaves' template instances (a chunked leaf's chunks, :func:`chunks_of`)."""
        vehicle_index = {nm: i for i, nm in enumerate(self.names)}

        k_pred = k if self.sharp else self.k_pred

        def inst(leaf: Formula, st: int) -> LeafInstance:
            self.check_deadline()
            return instance(
                leaf,
                st,
                self.model,
                self.dt,
                k,
                k_pred,
                vehicle_index,
                self.problem.region,
                self.problem.terrain,
            )

        items: list[LeafInstance | list[LeafInstance]] = [
            [inst(cl, cst) for cl, cst in chunks] if chunks else inst(leaf, st)
            for (leaf, st), chunks in zip(self.smooth_items, self.chunks, strict=True)
        ]
        return _assemble(
            self.wm,
            self.pm,
            self._sx_derivatives(),
            items,
            self.n_lin,
            self.n_sx,
            self.n_w - 1 - self.n_s,
            self.n_x0,
            k,
            self.opts.hessian == "exact",
        )

    @property
    def n_lin(self) -> int:
        return sum(int(b.shape[0]) for b in self.linear)

    @property
    def n_sx(self) -> int:
        return self.n_lin + int(self.direct.shape[0])

    @property
    def n_w(self) -> int:
        return int(self.w.shape[0])

    def solvers(self) -> Structure:
        """One solver per stage of the k continuation (warm-started from the stage before),
        and the structure :func:`planner.optimize.plan` solves with."""
        problem, nv = self.problem, len(self.names)
        # The linear and row-wise blocks (SX, differentiated block by block) do not depend on
        # the temporal sharpness k; the smooth leaves are calls of shared templates, assembled
        # with them into MX functions per k (see :mod:`planner.solve.leaf_templates`).
        n_lin, n_sx = self.n_lin, self.n_sx
        n_items = len(self.smooth_items)
        n_g = n_sx + n_items + self.n_s
        solvers: list[tuple[float, Any]] = []
        chunked = self.n_s > 0  # MUMPS ordering (mumps_order)
        leaf_fn = chunk_fn = None
        watch = IterationWatch(self.n_w, n_g, int(self.p.shape[0]))
        stages = []
        for k in self.k_list:
            self.check_deadline()
            nlp, derivs, leaf_fn, chunk_fn = self.assemble(k)
            stages.append((k, nlp, derivs))
            self.check_deadline()
            solvers.append(
                (k, make_solver(nlp, problem, derivs, watch, warm=bool(solvers), chunked=chunked))
            )

        def refining() -> list[tuple[float, Any]]:
            return [
                (
                    k,
                    make_solver(
                        nlp, problem, derivs, watch, warm=i > 0, refine=True, chunked=chunked
                    ),
                )
                for i, (k, nlp, derivs) in enumerate(stages)
            ]

        n_leaf = n_sx + n_items - n_lin
        # Each leaf row's leaf (the direct rows of a leaf are its steps times its faces, in
        # CasADi's column order: the steps run fastest) and whether it is fixed by the start.
        leaf_names: list[str] = []
        group: list[int] = []
        at_start: list[bool] = []
        for (leaf, steps), rows in zip(self.direct_steps.items(), self.direct_rows, strict=True):
            leaf_names.append(str(leaf))
            group.extend([len(leaf_names) - 1] * rows)
            at_start.extend(np.tile(np.asarray(steps) == 0, rows // len(steps)).tolist())
        index = {leaf: i for i, leaf in enumerate(self.smooth_leaves, start=len(leaf_names))}
        leaf_names.extend(str(leaf) for leaf in self.smooth_leaves)
        group.extend(index[leaf] for leaf, _st in self.smooth_items)
        at_start.extend([False] * n_items)
        n_lift, n_lim, n_eq = self.n_lift, self.n_lim, self.n_eq
        # v(horizon) = 0, or free; the limit rows' bounds are set per vehicle in plan()
        end = np.full(3 * nv, 0.0 if self.problem.timing.end_at_rest else np.inf)
        lift, eq = np.zeros(n_lift), np.zeros(n_eq)
        chunk_rows = np.zeros(self.n_s)  # s_c = the chunk's value
        lbg_fixed = np.concatenate(
            [lift, np.full(n_lim, -np.inf), -end, eq, np.zeros(n_leaf), chunk_rows]
        )
        ubg_fixed = np.concatenate(
            [lift, np.zeros(n_lim), end, eq, np.full(n_leaf, np.inf), chunk_rows]
        )
        return Structure(
            solvers=solvers,
            make_refining=refining,
            watch=watch,
            leaf_fn=leaf_fn,
            chunk_fn=chunk_fn,
            n_w=self.n_w,
            n_z=self.n_z,
            n_s=self.n_s,
            n_g=n_g,
            lbx=self.lbx,
            ubx=self.ubx,
            lbg_fixed=lbg_fixed,
            ubg_fixed=ubg_fixed,
            lim_slices=self.lim_slices,
            lim_half=self.lim_half,
            norm_rows=self.norm_rows,
            leaves=self.leaves,
            used_steps=self.used,
            n_lin=n_lin,
            n_x0=self.n_x0,
            leaf_group=np.asarray(group, dtype=int),
            leaf_at_start=np.asarray(at_start, dtype=bool),
            leaf_names=leaf_names,
            n_smooth=n_items,
            k=self.k_final,
            margin=self.margin,
            build_s=time.perf_counter() - self.t0,
            box_bound=0.0 if self.sharp else self.box_terms / self.k_pred,
        )


def build_structure(
    problem: Problem,
    model: Any,
    formula: Formula,
    sharp: bool = False,
    deadline: float = math.inf,
    screen: Screen | None = None,
) -> Structure:
    """The NLP of ``problem``: its pieces in order (:class:`NlpBuilder`); with ``sharp``, the
    smooth leaves' box predicates at the leaves' own sharpness; with ``screen``, the
    row-wise leaves only at the steps it keeps (:mod:`planner.solve.screen`).

    Raises:
        BuildTimeout: ``time.perf_counter()`` passed ``deadline`` during the build.
    """
    return (
        NlpBuilder(problem, model, formula, sharp, deadline, screen)
        .add_spec_constraints()
        .add_dynamics_constraints()
        .add_robustness_cost()
        .add_bounds()
        .solvers()
    )


def _assemble(
    wm: Any,
    pm: Any,
    sx: Mapping[str, Any],
    items: Sequence[LeafInstance | Sequence[LeafInstance]],
    n_lin: int,
    n_sx: int,
    s0: int,
    a0: int,
    k: float,
    exact: bool,
) -> tuple[dict[str, Any], dict[str, Any], Any, Any]:
    """The NLP, its derivative functions, the leaf-value function and the chunk-value
    function, in MX.

    ``g`` is the SX blocks' rows (linear, then row-wise leaves ``- r``), then one row per
    smooth leaf (``value - r``; a chunked leaf's value is the log-sum-exp of its chunks'
    variables ``s_c``, :func:`chunks_of`), then one row per chunk (``value - s_c``, held at 0).
    A leaf row subtracts ``a * r`` with its weight ``a`` from ``p`` (from ``a0`` on: the
    direct rows', then the smooth rows'; 1, or 0 for a row :mod:`planner.optimize` settled).
    ``items[i]`` is a leaf's template instance, or its chunks' instances.  Each row's
    Jacobian is its template's gradient scattered into ``w`` (and ``-1`` in the column of
    ``r`` or ``s_c``), its Hessian the template's ``lam * H`` scattered (upper triangle, as
    IPOPT takes it): all rows at once, through one block-diagonal product.
    """
    n_w = wm.shape[0]
    n_items = len(items)
    r = wm[n_w - 1]
    a_direct = pm[a0 : a0 + n_sx - n_lin]
    a_smooth = pm[a0 + n_sx - n_lin : a0 + n_sx - n_lin + n_items]
    g_sx = sx["g"](wm, pm)
    jac_sx = sx["jac_g"](wm, pm)[1]
    n_chunks = sum(len(it) for it in items if not isinstance(it, LeafInstance))
    lam_g = ca.MX.sym("lam_g", n_sx + n_items + n_chunks)
    # a row: (value, gradient (1, n_i), w entries, its Hessian's function of lam)
    Row = tuple[Any, Any, list[int], Callable[[Any], Any]]
    leaf_rows: list[Row] = []
    chunk_rows: list[Row] = []
    leaf_vals: list[Any] = []  # the smooth leaves' values, for leaf_fn

    def template_row(inst: LeafInstance) -> Row:
        args = (wm[list(inst.z_index)], pm[list(inst.x0_index)], ca.DM(inst.bounds))
        tpl = inst.template
        return (
            tpl.value(*args),
            tpl.value_grad(*args)[1],
            list(inst.z_index),
            lambda lam: tpl.hess(*args, lam),
        )

    for item in items:
        if isinstance(item, LeafInstance):
            row = template_row(item)
            leaf_vals.append(row[0])
        else:
            first = s0 + len(chunk_rows)
            cols = list(range(first, first + len(item)))
            joined = lse(len(item), k)
            s_vec = wm[cols]
            rows = [template_row(inst) for inst in item]
            chunk_rows.extend(rows)
            leaf_vals.append(joined.value(ca.vertcat(*[rw[0] for rw in rows])))
            row = (
                joined.value(s_vec),
                joined.value_grad(s_vec)[1],
                cols,
                functools.partial(joined.hess, s_vec),
            )
        leaf_rows.append(row)
    chunk_vals = [rw[0] for rw in chunk_rows]
    # the w column each row subtracts: r (times the row's weight) for a leaf, its s_c for a
    # chunk
    chunk_cols = list(range(s0, s0 + len(chunk_rows)))
    against = [n_w - 1] * len(leaf_rows) + chunk_cols
    n_mx = len(against)
    if n_mx:
        vals, grads, index, hess = (list(col) for col in zip(*leaf_rows, *chunk_rows, strict=True))
        flat = [i for idx in index for i in idx]
        sel = ca.DM(ca.Sparsity.triplet(len(flat), n_w, list(range(len(flat))), flat), 1.0)
        # nonzeros in column order: the chunks' columns come before r's (the last)
        minus = ca.MX(
            ca.Sparsity.triplet(n_mx, n_w, list(range(n_mx)), against),
            -ca.vertcat(ca.DM.ones(len(chunk_cols)), a_smooth),
        )
        subtracted = ca.vertcat(a_smooth * r, wm[chunk_cols])
        g = ca.vertcat(g_sx, ca.vertcat(*vals) - subtracted)
        jac = ca.vertcat(jac_sx, ca.mtimes(ca.diagcat(*grads), sel) + minus)
    else:
        g, jac = g_sx, jac_sx
    leaf_all = ca.vertcat(g_sx[n_lin:] + a_direct * r, *leaf_vals)
    derivs = {"jac_g": ca.Function("nlp_jac_g", [wm, pm], [g, jac], ["x", "p"], ["g", "jac_g_x"])}
    if exact:
        lam_f = ca.MX.sym("lam_f")
        H = sx["hess_lag"](wm, pm, lam_f, lam_g[:n_sx])
        if n_mx:
            blocks = ca.diagcat(*[h(lam_g[n_sx + i]) for i, h in enumerate(hess)])
            H = H + ca.triu(ca.mtimes(ca.mtimes(sel.T, blocks), sel))
        derivs["hess_lag"] = ca.Function(
            "nlp_hess_l",
            [wm, pm, lam_f, lam_g],
            [H],
            ["x", "p", "lam_f", "lam_g"],
            ["triu_hess_gamma_x_x"],
        )
    derivs["grad_f"] = ca.Function(
        "nlp_grad_f", [wm, pm], list(sx["grad_f"](wm, pm)), ["x", "p"], ["f", "grad_f_x"]
    )
    nlp = {"x": wm, "p": pm, "f": sx["f"](wm, pm), "g": g}
    chunk_out = ca.vertcat(*chunk_vals) if chunk_vals else ca.MX(0, 1)
    return (
        nlp,
        derivs,
        ca.Function("leaves", [wm, pm], [leaf_all]),
        ca.Function("chunks", [wm, pm], [chunk_out]),
    )


def is_separation(leaf: Formula) -> bool:
    """``dist(a, b) >= c`` (or ``c <= dist(a, b)``) with a constant ``c``: a keep-apart row."""
    if not isinstance(leaf, Comparison):
        return False
    big, small = (leaf.lhs, leaf.rhs) if leaf.op in (CmpOp.GE, CmpOp.GT) else (leaf.rhs, leaf.lhs)
    return role_of(big) is Role.KEEP_APART and isinstance(small, Const)


def two_sided_rows(cons: Any) -> int:
    """Rows of ``cons`` to keep: ``n/2`` when the limits come as ``[A; -A]`` (then each kept
    row is two-sided, ``-h_lower <= A z <= h_upper``, which halves the limit rows IPOPT
    sees), else all of them (one-sided, as given)."""
    n = cons.G.shape[0]
    half = n // 2
    paired = (
        n % 2 == 0
        and np.array_equal(cons.G[half:], -cons.G[:half])
        and np.array_equal(cons.H[half:], -cons.H[:half])
    )
    return half if paired else n


def vehicle_limit_bounds(
    model: Any, vehicle: Any, half: int, norm_rows: bool
) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` of one vehicle's limit rows as :class:`NlpBuilder` lays them out: the
    kept model rows per axis (column after column), then, with ``norm_rows``, the
    :data:`planner.dynamics.limits.NORM_DIRECTIONS` rows (``inf`` for a vehicle without a norm
    bound). Together they are :meth:`planner.dynamics.limits.Bounds.linear` on every control point."""
    vel, acc = vehicle_bounds(vehicle)
    (vlo, vhi, vb), (alo, ahi, ab) = vel.linear(), acc.linear()
    cons = model.limit_constraints(vhi, ahi, -vlo, -alo)
    lo, hi = limit_bounds(cons, half)
    lo_parts, hi_parts = [lo.reshape(-1, order="F")], [hi.reshape(-1, order="F")]
    if norm_rows:
        b = np.where(cons.kind[:half] == "vel", vb, ab)
        for _ in NORM_DIRECTIONS:
            lo_parts.append(-b)
            hi_parts.append(b)
    return np.concatenate(lo_parts), np.concatenate(hi_parts)


def limit_bounds(cons: Any, half: int) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` ``(half, 3)`` of the kept limit rows (:func:`two_sided_rows`):
    ``-h`` below each paired row, ``-inf`` when the rows are kept one-sided."""
    h = cons.h
    lo = -h[half:] if 2 * half == len(h) else np.full_like(h, -np.inf)
    return lo, h[:half]
