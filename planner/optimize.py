"""Problem -> PlanResult: maximise STL robustness with CasADi/IPOPT (or sqpmethod).

Formulation (for vehicles ``i`` with decision matrices ``Z_i`` of the chosen
:class:`~planner.dynamics.LinearModel` and start states ``X0_i``)::

    maximise    r
    subject to  c_l(Z) >= r                  every conjunctive leaf l (see below)
                G Z_i + H X0_i <= h_i        continuous-time |v|, |a| limits per axis
                v_i(horizon) = 0             every vehicle ends at rest (then holds)
                lo_ws <= p_i(t_k) <= hi_ws   workspace, at every constraint sample
                [r >= epsilon + margin]      the paper's eq. (1) constraint, if asked for

The spec is a conjunction; its robustness is the min over the clauses, and the min over
time of an ``always``.  Instead of smoothing these mins (log-sum-exp over N^2 separation
clauses times 121 samples would be both inaccurate and dense), they are handled *exactly*
by the epigraph variable ``r``: the tree is walked from the root through ``and`` and
``always`` nodes, collecting leaves with the set of sample steps at which they must hold.
A leaf is then

* a comparison of arithmetic over function values (``dist(a, b) >= 0.2``, ``x(d) <= 4``)
  or a function atom (``outside(d, pole1)``): one constraint per step, with the smooth
  predicate implementations of :mod:`planner.predicates` (never above the exact value);
* ``inside(d, box)``: six *linear* constraints per step (the face margins; exact);
* anything else (``eventually``, ``or``, ``until``, ``not``, ``implies``): the STL engine's
  smooth robustness with sharpness ``k`` of that sub-formula at each step (one CasADi
  expression per step, over only the samples its windows reach), built as a call of a
  template shared by every leaf of the same shape (:mod:`planner.leaf_templates`).

So the separation pairs become sparse constraints (each touches two vehicles), the
Hessian stays sparse, no term drowns another, and smoothing error remains only where
there is a genuine max (a disjunction).  The sampled positions are lifted into variables
(``P_i = Mp Z_i + Np X0_i`` as linear equalities) so the row-wise leaves are local; the
smooth leaves, which couple whole windows, are written in ``Z`` where their dense Hessian
block is ``3 n_dec`` wide.  Row-wise leaves are sampled every
:attr:`SolverOptions.constraint_dt_s` (default ``max(Ts, 0.1 s)``); the exact check is
dense anyway.  A small acceleration penalty (``_REG_WEIGHT``) gives curvature in the
directions ``r`` ignores (reach-avoid N = 1: 207 -> 75 iterations).

Smoothing: ``k`` is fitted so that the engine's error bound of the smooth leaves
(``smooth_error_bound``) is 6 % of the smallest region half-size (reach-avoid k = 320,
power line k = 410; 2 % gave k = 960 and IPOPT stalled).  Measured against k/2, 2k and a
continuation k/3 -> k (benchmarks/bench_solvers.py): no variant is better on every case.
k/2 gained a few millimetres of exact robustness on reach-avoid N = 2 to 8 but failed the
power line (N = 4: -11 after 580 iterations) and reach-avoid N = 16 (-0.04); 2k cost up to
twice the iterations for +-2 mm; the continuation (later stages warm started: multipliers
kept, small barrier) added iterations on reach-avoid N = 2 (38 -> 155) and gained 0.03 on
the power line N = 4 at 1.5x the time.  So the fitted k is the default, and
``solver.k``/``solver.continuation`` stay available.  Scale and arity do not need the
smoothing to fit them: mins over clauses and time are exact (the epigraph above), so the
N^2 separation rows do not drown the reach terms whatever N is.

Solver (measured on this 2-core machine): IPOPT with MUMPS, ``mu_strategy adaptive``,
exact Hessian by default (the scenario may choose ``solver.hessian: limited-memory``).
What made it fast, in the order found:

* the primitive chain is built with ``explicit_acc`` (waypoint accelerations are variables
  tied by linear equalities), so every sample depends on two waypoints, not on all earlier
  ones: the Jacobians and the KKT factorisation stay banded (power-line N = 4 with L-BFGS:
  355 -> 80 ms per iteration; its build 5.1 -> 1.8 s);
* the velocity/acceleration limits are two-sided rows ``-h <= A z <= h`` instead of two
  one-sided ones (reach-avoid N = 4: 17.3 -> 3.6 s of IPOPT);
* the initial guess is fitted to the limits by a QP (below), so IPOPT starts feasible for
  every linear constraint (reach-avoid N = 4: 120 -> 84 iterations);
* the exact Hessian on the power line too (N = 4: 14-19 iterations and 2.2-2.8 s of
  IPOPT, against 30-500 iterations with L-BFGS, whose speed depended erratically on its
  history length).  Its price was the build (~12 s cold for N = 4, CasADi differentiating
  the nested ``eventually always``/``until`` leaves), until the smooth leaves became calls
  of shared templates, differentiated once per shape (:mod:`planner.leaf_templates`;
  power-line N = 4: 9.8 -> 1.6 s, N = 8: 20.8 -> 5.5 s; reach-avoid N = 16: 8.5 -> 2.3 s);
* the separation rows' curvature is left out of that Hessian (:func:`_derivatives`): it
  is negative, and IPOPT corrected the inertia with it in most iterations (reach-avoid
  N = 8: 7.3 -> 6.0 s of IPOPT, N = 16: 144 -> 133 iterations and build 12.0 -> 9.3 s);
  the power line keeps it (``solver.separation_curvature: true``: N = 8 took 189
  iterations without it, 27 with); leaving out the obstacle's curvature as well was
  faster still on reach-avoid but broke the power line (500+ iterations);
* ``tol`` 1e-4 instead of 1e-6 (robustness is in metres): the last digits took a third of
  the iterations (reach-avoid N = 8: 91 -> 75; power-line N = 4: 17 -> 10).

The paper solves with SQP.  CasADi's ``sqpmethod`` runs on the same NLP and derivatives
(:func:`_sqpsol`; ``solver.method: sqpmethod``, ``solver.qpsol``): with the exact
Hessian regularised to convexity it crawls (150 iterations of ~1 mm steps on reach-avoid
N = 1); with BFGS it converges, to the same robustness, 60x slower than IPOPT with PIQP on
reach-avoid N = 1 (3.0 s against 0.05 s of solver), 100x on N = 2 (20 s), 200 s on N = 4;
qpOASES was slower than PIQP.  IPOPT is the default.  L-BFGS in IPOPT took 2-7x the
iterations of the exact Hessian and failed reach-avoid N = 8 (-0.03).  The constraint
Jacobian and Lagrangian Hessian are assembled block by block (:func:`_derivatives`).

Where the time goes now (benchmarks/bench_planner.py): the build is 0.3-3 s; reach-avoid
is IPOPT's linear algebra (N = 16: 89 iterations of ~230 ms with eq. (1), most of it MUMPS
factorising a KKT system in which the 7,320 separation rows couple every vehicle's
decisions at every segment: without them an iteration takes 65 ms; a second thread did
not help); function evaluations are 10-20 %.  IPOPT's iteration count on reach-avoid is
chaotic (N = 8: 45-85 for rounding-level changes; 9 from the optimum, 148 from it
perturbed by 5 cm), and it finds different local optima (N = 8: 0.047 by default, 0.106
with a monotone barrier from mu = 0.01, which fails N = 16).
Tried on reach-avoid N = 16 and not kept: MUMPS without scaling or permutation, pivot
tolerance 1e-8, the PORD ordering, less memory slack, slack-based scaling, no mmap in
malloc (75-89 iterations of 220-245 ms: the changes only reshuffled the iteration count);
the ``probing``/``loqo`` barrier oracles (271-300 iterations); lifting each ``eventually``
leaf into a chain of per-segment log-sum-exp variables (the same value, exactly, by
associativity), so no row couples a vehicle across the horizon: largest front 1,130 -> 897,
8.7e8 -> 7.2e8 flops, but 110 iterations instead of 89.  The front is set by the separation
rows, which tie all vehicles at every sample; keeping only the pairs that pass within 1 m
of each other in the optimum found (3,193 of the 7,320 rows) made an iteration 153 ms
instead of 230, but IPOPT then took 685 iterations and let unconstrained pairs collide, so
row selection would need re-solves with the violated rows added, each a new build.
Caching the templates on disk was not worth it either: CasADi serialises the power-line
N = 4 templates to 198 MB and reads them back in 3.8 s, slower than building them.

Initial guess (:func:`_initial_guess`): grid paths through each vehicle's target boxes,
each leg timed rest to rest by a trapezoid within 75 % of the per-axis limits, dwelling in
each box for the spec's hover + 0.75 s, the horizon's slack split between slower legs and
longer dwells, each vehicle shifted into a lateral lane where its path would pass
another's, and the timed path fitted by the closest trajectory that respects the limits,
ends at rest and stays in the workspace (:func:`_fit_within_limits`; the plain
least-squares fit overshot the acceleration limit 2.4x on reach-avoid N = 4).  Without the
timing and the lanes (power-line N = 4; the guess now satisfies every mission clause) it
timed the west climb at ~3 m/s against 2 m/s and IPOPT ended at robustness -1 to -4.
Vehicles sharing a target box aim at distinct points of a lattice in it, as deep inside
as they are apart beyond the separation (:func:`_box_slots`; power-line N = 4: 19 -> 14
iterations, robustness 0.57 -> 0.77; with this and the new starts of drones 9-16,
reach-avoid N = 16 plans).
``solver.robustness_cap_m`` bounds r above: once the spec holds by that margin the NLP
only settles (power-line N = 4: 72 instead of 300+ iterations).
``solver.robustness_constraint`` (the paper's eq. 1) bounds r below by ``epsilon`` plus the
smooth leaves' error bound, a margin grown by the shortfall (up to three re-solves, each
from the point the last one reached, the best kept) if the exact robustness still misses
``epsilon``; a constraint that cannot hold falls back to the plain maximisation from the
same start.  With it IPOPT satisfies the spec before widening the margin: reach-avoid
N = 4 / 8 / 16 took 65 / 30 / 89 iterations instead of 95 / 65 / 153 for the same
robustness, so reach_avoid.yaml sets it; the power line did not gain (N = 8: 74 against 27).

After the solve the trajectories are re-sampled every ``check_dt_s`` and evaluated with
the *exact* semantics of the same formula tree (numpy predicates); the result reports
that robustness, the weakest sub-formula (``Formula.weakest``), limits and workspace
checked on the dense samples, and Mueller's thrust/body-rate test where the scenario
gives those limits.  ``success`` means exact robustness >= epsilon with all of those
checks passing; anything else is a ``success=False`` result with the best trajectories
found, never an exception.

Errors: bad scenarios are :class:`~planner.scenario.ScenarioError` (raised by
:mod:`planner.scenario`); this module raises nothing else for bad input.
"""

from __future__ import annotations

import itertools
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

# IPOPT's MUMPS (and its BLAS) read this when CasADi loads the ipopt plugin, at the first
# nlpsol: threads only fight on a small shared machine (power-line N = 4 measured 19 s
# with one thread, > 90 s unset on 2 loaded cores).  An explicit setting is respected.
os.environ.setdefault("OMP_NUM_THREADS", "1")

import casadi as ca
import numpy as np

from planner.checks import LimitReport, check_trajectories
from planner.dynamics import DoubleIntegrator, MinimumJerkChain
from planner.leaf_templates import (
    LeafInstance,
    clear_templates,
    instance,
    local_hessian,
    selection,
)
from planner.planfile import Plan, PlannedVehicle
from planner.predicates import (
    build_registry,
    ca_box_margins,
    casadi_functions,
    parse_clause,
    predicate_sharpness,
)
from planner.scenario import DynamicsModel, Problem, SolverMethod
from planner.stl import (
    Always,
    And,
    BinOp,
    BoolConst,
    Call,
    CmpOp,
    Comparison,
    Const,
    Expr,
    Formula,
    Neg,
    Not,
    Or,
    Predicate,
    Signal,
    conjunction,
)
from planner.trajectory import Trajectory

__all__ = [
    "K_MIN",
    "ClauseReport",
    "LimitReport",
    "PlanResult",
    "SolveStats",
    "Weakest",
    "check_trajectories",
    "clear_cache",
    "make_model",
    "plan",
]

#: Lower bound of the fitted smoothing sharpness (1/m).
K_MIN = 10.0
#: Fraction of the smallest region half-size the smooth leaves may be off by.
_K_TOLERANCE = 0.06
#: Weight of the mean squared acceleration ((m/s^2)^2) subtracted from r in the objective.
_REG_WEIGHT = 1e-3
#: Upper bound of the epigraph variable r (m): keeps IPOPT bounded on trivial specs.
_R_MAX = 1e3


# ------------------------------------------------------------------------------ results


@dataclass(frozen=True, slots=True)
class Weakest:
    """The sub-formula that decides the robustness, with its value and time (s)."""

    formula: str
    robustness: float
    t_s: float
    clause_key: str


@dataclass(frozen=True, slots=True)
class ClauseReport:
    """Exact robustness of one top-level clause of the expanded spec (dense samples)."""

    key_path: str
    text: str
    robustness: float


@dataclass(frozen=True, slots=True)
class SolveStats:
    """Where the time went (seconds) and the problem size."""

    build_s: float
    solver_s: float
    function_eval_s: float
    check_s: float
    n_variables: int
    n_constraints: int
    n_smooth_leaves: int
    k: float
    solver: str
    cached: bool


@dataclass(frozen=True, slots=True)
class PlanResult:
    """Outcome of :func:`plan` (python-control style: a failed solve is a result).

    Attributes:
        success: exact robustness >= epsilon and every limit/workspace check passed.
        status: solver status and the verdict, in words.
        robustness: exact robustness (m) of the whole spec on the dense samples.
        robustness_planning_grid: exact robustness on the planning samples (every Ts).
        smooth_robustness: the optimiser's value r (min over the smooth leaves, m).
        weakest: the deciding sub-formula.
        clauses: per top-level clause robustness.
        solve_time_s: wall time of build + solve + check.
        iterations: NLP iterations (summed over a continuation).
        trajectories: one per vehicle, in the problem's order.
        limits: per vehicle dense checks.
        decision: flat optimal decision vector (warm start for a re-solve).
        stats: sizes and time breakdown.
    """

    problem: Problem
    success: bool
    status: str
    robustness: float
    robustness_planning_grid: float
    smooth_robustness: float
    weakest: Weakest | None
    clauses: tuple[ClauseReport, ...]
    solve_time_s: float
    iterations: int
    trajectories: tuple[Trajectory, ...]
    limits: tuple[LimitReport, ...]
    decision: np.ndarray = field(repr=False)
    stats: SolveStats | None = None

    def to_plan(self, scenario_path: str | None = None) -> Plan:
        """The plan-file view of this result (:mod:`planner.planfile`)."""
        p = self.problem
        vehicles = tuple(
            PlannedVehicle(
                name=v.name,
                sysid=v.sysid,
                trajectory=tr,
                start_enu_m=v.start_enu_m,
                v_max_m_s=v.v_max_m_s,
                a_max_m_s2=v.a_max_m_s2,
                thrust_min_m_s2=v.thrust_min_m_s2,
                thrust_max_m_s2=v.thrust_max_m_s2,
                body_rate_max_rad_s=v.body_rate_max_rad_s,
            )
            for v, tr in zip(p.vehicles, self.trajectories, strict=True)
        )
        return Plan(
            scenario=scenario_path if scenario_path is not None else p.source,
            origin=p.origin,
            spec=p.spec_text,
            robustness=self.robustness,
            smooth_robustness=self.smooth_robustness,
            status=self.status,
            success=self.success,
            solve_time_s=self.solve_time_s,
            vehicles=vehicles,
            workspace=p.workspace,
            regions=p.regions,
            separation_m=p.separation_m,
            epsilon=p.epsilon,
            horizon_s=p.timing.horizon_s,
            sample_dt_s=p.timing.sample_dt_s,
            check_dt_s=p.timing.check_dt_s,
        )


# ------------------------------------------------------------------------------ models


def make_model(problem: Problem) -> MinimumJerkChain | DoubleIntegrator:
    """The linear model of the scenario (one for all vehicles: same timing)."""
    t = problem.timing
    if problem.model is DynamicsModel.MINIMUM_JERK:
        return MinimumJerkChain(t.horizon_s, t.segment_s, t.sample_dt_s, explicit_acc=True)
    a_max = np.max([v.a_max_m_s2 for v in problem.vehicles], axis=0)
    return DoubleIntegrator(t.horizon_s, t.segment_s, 3, a_max, sample_dt_s=t.sample_dt_s)


def _x0(problem: Problem, model: Any) -> list[np.ndarray]:
    """Start states (n_init, 3): position then zeros (at rest)."""
    out = []
    for v in problem.vehicles:
        x0 = np.zeros((model.n_init, 3))
        x0[0] = v.start_enu_m
        out.append(x0)
    return out


# --------------------------------------------------------------------------- decompose


def _decompose(node: Formula, steps: np.ndarray, dt: float, out: dict[Formula, set[int]]) -> None:
    """Collect conjunctive leaves: walk ``and``/``always`` from the root, track steps."""
    if isinstance(node, And):
        for child in node.operands:
            _decompose(child, steps, dt, out)
    elif isinstance(node, Always):
        lo, hi = node.steps(dt)
        shifted = np.unique((steps[:, None] + np.arange(lo, hi + 1)[None, :]).ravel())
        _decompose(node.child, shifted, dt, out)
    elif isinstance(node, BoolConst) and node.value:
        return
    else:
        out.setdefault(node, set()).update(int(s) for s in steps)


def _is_direct(node: Formula) -> bool:
    """Leaves evaluated directly (vectorised over steps) rather than through the engine."""
    return isinstance(node, Comparison | Predicate)


def _ca_expr(e: Expr, rows: Mapping[str, Any], fns: Mapping[str, Callable[..., Any]]) -> Any:
    if isinstance(e, Const):
        return e.value
    if isinstance(e, Call):
        return fns[e.name](e.args, rows)
    if isinstance(e, Neg):
        return -_ca_expr(e.operand, rows, fns)
    if isinstance(e, BinOp):
        a = _ca_expr(e.lhs, rows, fns)
        b = _ca_expr(e.rhs, rows, fns)
        return {"+": a + b, "-": a - b, "*": a * b, "/": a / b}[e.op.value]
    if isinstance(e, Signal):
        return rows[e.name]
    raise TypeError(f"unsupported expression node {type(e).__name__}")


# ------------------------------------------------------------------------------ build


@dataclass(slots=True)
class _Structure:
    """A built NLP, reusable for any start states and limits of the same structure."""

    solvers: list[tuple[float, Any]]  # (k, nlpsol) in continuation order
    leaf_fn: Any  # ca.Function (w, p) -> leaf values (for r0)
    n_w: int
    n_z: int  # the first n_z entries of w are the Z matrices (vec, vehicle after vehicle)
    n_g: int
    lbx: np.ndarray
    ubx: np.ndarray
    lbg_fixed: np.ndarray
    ubg_fixed: np.ndarray
    lim_slices: list[slice]  # g rows of each vehicle's limits
    lim_half: int  # rows of the model's limits kept (two-sided rows when they pair up)
    leaves: dict[Formula, set[int]]
    used_steps: list[int]  # planning steps whose positions are lifted into variables
    n_smooth: int
    k: float
    margin: float
    build_s: float


_CACHE: dict[Any, _Structure] = {}
_CACHE_SIZE = 8


def clear_cache() -> None:
    """Forget built solvers and leaf templates (benchmarks measure cold builds with this)."""
    _CACHE.clear()
    clear_templates()


def _structure_key(problem: Problem) -> Any:
    s = problem.solver
    return (
        problem.spec_text,
        tuple((r.name, r.lo_enu_m, r.hi_enu_m) for r in problem.all_regions),
        problem.timing,
        problem.model,
        tuple(v.name for v in problem.vehicles),
        s,
        problem.epsilon,
    )


def _fit_k(problem: Problem, smooth_leaves: Sequence[Formula], dt: float) -> tuple[float, float]:
    """(k, error bound at k) for the smooth leaves: bound = 6 % of the smallest half-size."""
    if problem.solver.k is not None:
        k = problem.solver.k
    elif not smooth_leaves:
        k = K_MIN
    else:
        halves = [0.5 * (np.asarray(r.hi_enu_m) - r.lo_enu_m) for r in problem.all_regions]
        tol = _K_TOLERANCE * float(min(np.min(h) for h in halves))
        unit = max(leaf.smooth_error_bound(1.0, dt) for leaf in smooth_leaves)
        k = max(K_MIN, unit / tol)
    bound = max((leaf.smooth_error_bound(k, dt) for leaf in smooth_leaves), default=0.0)
    return k, bound


def _leaf_values(
    leaf: Formula,
    steps: list[int],
    rows_of: Callable[[list[int]], Mapping[str, Any]],
    problem: Problem,
    fns: Mapping[str, Callable[..., Any]],
) -> Any:
    """SX column of a row-wise leaf's robustness at ``steps`` (from the lifted positions)."""
    rows = rows_of(steps)
    if isinstance(leaf, Predicate) and leaf.call.name == "inside":
        region = problem.region(leaf.call.args[1])
        return ca.vec(ca_box_margins(rows[leaf.call.args[0]], region))
    if isinstance(leaf, Predicate):
        return fns[leaf.call.name](leaf.call.args, rows)
    assert isinstance(leaf, Comparison)
    lhs = _ca_expr(leaf.lhs, rows, fns)
    rhs = _ca_expr(leaf.rhs, rows, fns)
    out = lhs - rhs if leaf.op in (CmpOp.GE, CmpOp.GT) else rhs - lhs
    return out * ca.DM.ones(len(steps), 1) if not hasattr(out, "shape") else out


def _build(problem: Problem, model: Any, formula: Formula) -> _Structure:
    t0 = time.perf_counter()
    dt = problem.timing.sample_dt_s
    n = len(model.times_s)
    names = [v.name for v in problem.vehicles]
    nv = len(names)
    opts = problem.solver

    # Lifted formulation: the sampled positions P_i (n, 3) are variables tied to Z_i by
    # linear equalities.  Row-wise leaves (separation, obstacles, boxes) then touch a few
    # variables each, so the constraint Jacobian and the Lagrangian Hessian are very sparse
    # and CasADi's symbolic derivatives need few directions (colouring) whatever N is.
    # Smooth leaves couple many samples (a window's soft max): they are written in Z (the
    # same positions through Mp), where their dense Hessian block is n_dec*3 wide, not n*3.
    leaves: dict[Formula, set[int]] = {}
    _decompose(formula, np.array([0]), dt, leaves)
    smooth_leaves = [leaf for leaf in leaves if not _is_direct(leaf)]
    k_final, margin = _fit_k(problem, smooth_leaves, dt)
    k_list = [*[kk for kk in opts.continuation if kk < k_final], k_final]
    k_pred = predicate_sharpness(problem)
    fns = casadi_functions(problem, k_pred)
    c_dt = opts.constraint_dt_s if opts.constraint_dt_s is not None else max(dt, 0.1)
    stride = max(1, round(c_dt / dt))
    direct_steps: dict[Formula, list[int]] = {}
    for leaf, steps_set in leaves.items():
        if _is_direct(leaf):
            steps = sorted(steps_set)
            direct_steps[leaf] = sorted(set(steps[::stride]) | {steps[-1]})
    # The workspace bounds the lifted positions, so every constraint step of the horizon is
    # lifted, whether or not the spec itself constrains it there.
    grid = {*range(0, n, stride), n - 1}
    used = sorted(grid.union(*direct_steps.values()))
    row_of = {st: i for i, st in enumerate(used)}

    Z = [ca.SX.sym(f"Z_{nm}", model.n_dec, 3) for nm in names]
    P = [ca.SX.sym(f"P_{nm}", len(used), 3) for nm in names]
    X0 = [ca.SX.sym(f"X0_{nm}", model.n_init, 3) for nm in names]
    r = ca.SX.sym("r")
    w = ca.vertcat(*[ca.vec(z) for z in Z], *[ca.vec(q) for q in P], r)
    p = ca.vertcat(*[ca.vec(x) for x in X0])
    Mp, Np = ca.sparsify(ca.DM(model.Mp)), ca.sparsify(ca.DM(model.Np))
    pos_from_z = {nm: ca.mtimes(Mp, Z[i]) + ca.mtimes(Np, X0[i]) for i, nm in enumerate(names)}
    Pd = dict(zip(names, P, strict=True))

    def rows_of(steps: list[int]) -> dict[str, Any]:
        idx = [row_of[st] for st in steps]
        return {nm: q[idx, :] for nm, q in Pd.items()}

    direct_parts = [
        _leaf_values(leaf, steps, rows_of, problem, fns) for leaf, steps in direct_steps.items()
    ]
    direct = ca.vertcat(*direct_parts) if direct_parts else ca.SX(0, 1)

    # Linear parts: lifting equalities, limits, rest at the end.
    lift_g = [ca.vec(P[i] - pos_from_z[nm][used, :]) for i, nm in enumerate(names)]
    n_lift = len(used) * 3 * nv
    lim_g, lim_slices = [], []
    row = n_lift
    cons = model.limit_constraints(np.ones(3), np.ones(3))
    half = _two_sided_rows(cons)
    G = ca.sparsify(ca.DM(cons.G[:half]))
    H = ca.sparsify(ca.DM(cons.H[:half]))
    for i in range(nv):
        gi = ca.vec(ca.mtimes(G, Z[i]) + ca.mtimes(H, X0[i]))
        lim_g.append(gi)
        lim_slices.append(slice(row, row + gi.shape[0]))
        row += gi.shape[0]
    n_lim = row - n_lift
    Mv_end = ca.DM(model.Mv[-1:, :])
    Nv_end = ca.DM(model.Nv[-1:, :])
    end_g = [ca.vec(ca.mtimes(Mv_end, Z[i]) + ca.mtimes(Nv_end, X0[i])) for i in range(nv)]
    # The model's own equalities (the acceleration chain of an explicit-acc primitive chain).
    Ge, He = (ca.sparsify(ca.DM(m)) for m in model.equality_constraints())
    eq_g = [ca.vec(ca.mtimes(Ge, Z[i]) + ca.mtimes(He, X0[i])) for i in range(nv)]
    n_eq = Ge.shape[0] * 3 * nv

    # A small acceleration penalty gives the NLP curvature in the directions r does not
    # care about (the max-min objective is flat there); measured to cut iterations.
    Ma, Na = ca.sparsify(ca.DM(model.Ma)), ca.sparsify(ca.DM(model.Na))
    acc_sq = 0
    for i in range(nv):
        acc = ca.mtimes(Ma, Z[i]) + ca.mtimes(Na, X0[i])
        acc_sq = acc_sq + ca.sumsqr(acc)
    reg_term = _REG_WEIGHT * acc_sq / (n * nv)

    # Workspace: simple bounds on the lifted positions.
    ws = problem.workspace
    n_z = model.n_dec * 3 * nv
    m = len(used)
    lbx = np.concatenate([np.full(n_z, -np.inf), np.tile(np.repeat(ws.lo_enu_m, m), nv), [-np.inf]])
    r_hi = _R_MAX if opts.robustness_cap_m is None else opts.robustness_cap_m + margin
    ubx = np.concatenate([np.full(n_z, np.inf), np.tile(np.repeat(ws.hi_enu_m, m), nv), [r_hi]])

    # The linear and row-wise blocks (SX, differentiated block by block) do not depend on
    # the temporal sharpness k; the smooth leaves are calls of shared templates, assembled
    # with them into MX functions per k (see :mod:`planner.leaf_templates`).
    linear = [*lift_g, *lim_g, *end_g, *eq_g]
    n_lin = sum(int(b.shape[0]) for b in linear)
    nonlinear = [part - r for part in direct_parts]
    f = -r + reg_term
    # Separation rows enter the Hessian flat unless asked otherwise (see _derivatives).
    flat = [_is_separation(leaf) and not opts.separation_curvature for leaf in direct_steps]
    exact = opts.hessian == "exact"
    sx_derivs = _derivatives(w, p, f, linear, nonlinear, exact, flat)
    # Values and derivatives are separate functions: nlpsol differentiates the MX values once
    # more (reverse mode, for the multipliers) and must not go through derivative outputs.
    sx_derivs["f"] = ca.Function("nlp_f", [w, p], [f])
    sx_derivs["grad_f"] = ca.Function("nlp_grad_f", [w, p], [f, ca.gradient(f, w)])
    sx_derivs["g"] = ca.Function("nlp_g", [w, p], [ca.vertcat(*linear, *nonlinear)])
    n_sx = n_lin + int(direct.shape[0])
    vehicle_index = {nm: i for i, nm in enumerate(names)}
    smooth_items = [(leaf, st) for leaf in smooth_leaves for st in sorted(leaves[leaf])]
    wm = ca.MX.sym("w", w.shape[0])
    pm = ca.MX.sym("p", p.shape[0])

    solvers = []
    leaf_fn = None
    for k in k_list:
        insts = [
            instance(leaf, st, model, dt, k, k_pred, vehicle_index, problem.region)
            for leaf, st in smooth_items
        ]
        nlp, derivs, leaf_fn = _assemble(wm, pm, sx_derivs, insts, n_lin, n_sx, exact)
        solvers.append((k, _nlpsol(nlp, problem, derivs, warm=bool(solvers))))
    n_g = n_sx + len(smooth_items)
    n_leaf = n_g - n_lin
    lbg_fixed = np.concatenate(
        [np.zeros(n_lift), np.full(n_lim, -np.inf), np.zeros(3 * nv + n_eq), np.zeros(n_leaf)]
    )  # the limit rows' bounds are set per vehicle in plan()
    ubg_fixed = np.concatenate(
        [np.zeros(n_lift), np.zeros(n_lim), np.zeros(3 * nv + n_eq), np.full(n_leaf, np.inf)]
    )
    return _Structure(
        solvers=solvers,
        leaf_fn=leaf_fn,
        n_w=int(w.shape[0]),
        n_z=n_z,
        n_g=n_g,
        lbx=lbx,
        ubx=ubx,
        lbg_fixed=lbg_fixed,
        ubg_fixed=ubg_fixed,
        lim_slices=lim_slices,
        lim_half=half,
        leaves=leaves,
        used_steps=used,
        n_smooth=len(smooth_items),
        k=k_final,
        margin=margin,
        build_s=time.perf_counter() - t0,
    )


def _assemble(
    wm: Any,
    pm: Any,
    sx: Mapping[str, Any],
    insts: Sequence[LeafInstance],
    n_lin: int,
    n_sx: int,
    exact: bool,
) -> tuple[dict[str, Any], dict[str, Any], Any]:
    """The NLP, its derivative functions and the leaf-value function, in MX.

    ``g`` is the SX blocks' rows (linear, then row-wise leaves ``- r``) followed by one row
    per smooth leaf instance (``value - r``); their Jacobian rows are the templates'
    gradients scattered into ``w`` and ``-1`` in r's column, their Hessian the templates'
    ``lam * H`` scattered (upper triangle, as IPOPT takes it).
    """
    n_w = wm.shape[0]
    g_sx = sx["g"](wm, pm)
    jac_sx = sx["jac_g"](wm, pm)[1]
    vals, rows, calls = [], [], []
    for inst in insts:
        args = (wm[list(inst.z_index)], pm[list(inst.x0_index)], ca.DM(inst.bounds))
        _, grad = inst.template.value_grad(*args)
        sel = selection(inst.z_index, n_w)
        vals.append(inst.template.value(*args))
        rows.append(ca.mtimes(grad, sel))
        calls.append((args, sel))
    r = wm[n_w - 1]
    n_s = len(insts)
    if n_s:
        e_r = ca.DM(ca.Sparsity.triplet(n_s, n_w, list(range(n_s)), [n_w - 1] * n_s), -1.0)
        g = ca.vertcat(g_sx, ca.vertcat(*vals) - r)
        jac = ca.vertcat(jac_sx, ca.vertcat(*rows) + e_r)
        leaf_all = ca.vertcat(g_sx[n_lin:] + r, *vals)
    else:
        g, jac, leaf_all = g_sx, jac_sx, g_sx[n_lin:] + r
    derivs = {"jac_g": ca.Function("nlp_jac_g", [wm, pm], [g, jac], ["x", "p"], ["g", "jac_g_x"])}
    if exact:
        lam_f = ca.MX.sym("lam_f")
        lam_g = ca.MX.sym("lam_g", n_sx + n_s)
        H = sx["hess_lag"](wm, pm, lam_f, lam_g[:n_sx])
        for i, (inst, (args, sel)) in enumerate(zip(insts, calls, strict=True)):
            h_i = inst.template.hess(*args, lam_g[n_sx + i])
            H = H + ca.triu(ca.mtimes(ca.mtimes(sel.T, h_i), sel))
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
    return nlp, derivs, ca.Function("leaves", [wm, pm], [leaf_all])


def _is_separation(leaf: Formula) -> bool:
    """``dist(a, b) >= c`` (or ``c <= dist(a, b)``) with a constant ``c``: a keep-apart row."""
    if not isinstance(leaf, Comparison):
        return False
    big, small = (leaf.lhs, leaf.rhs) if leaf.op in (CmpOp.GE, CmpOp.GT) else (leaf.rhs, leaf.lhs)
    return isinstance(big, Call) and big.name == "dist" and isinstance(small, Const)


def _two_sided_rows(cons: Any) -> int:
    """Rows of ``cons`` to keep: ``n/2`` when the limits come as ``[A; -A]`` with equal
    right-hand sides (then each kept row is two-sided, ``-h <= A z <= h``, which halves the
    limit rows IPOPT sees), else all of them (one-sided, as given)."""
    n = cons.G.shape[0]
    half = n // 2
    paired = (
        n % 2 == 0
        and np.array_equal(cons.G[half:], -cons.G[:half])
        and np.array_equal(cons.H[half:], -cons.H[:half])
        and np.array_equal(cons.h[half:], cons.h[:half])
    )
    return half if paired else n


def _derivatives(
    w: Any,
    p: Any,
    f: Any,
    linear: list[Any],
    nonlinear: list[Any],
    hessian: bool,
    flat: Sequence[bool] = (),
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
    """
    blocks = [*linear, *nonlinear]
    g = ca.vertcat(*blocks)
    jac = ca.vertcat(*[ca.jacobian(b, w) for b in blocks])
    out = {"jac_g": ca.Function("nlp_jac_g", [w, p], [g, jac], ["x", "p"], ["g", "jac_g_x"])}
    if hessian:
        lam_f = ca.SX.sym("lam_f")
        lam_g = ca.SX.sym("lam_g", g.shape[0])
        H = lam_f * local_hessian(f, w)
        row = sum(b.shape[0] for b in linear)
        for ib, b in enumerate(nonlinear):
            m = b.shape[0]
            if ib >= len(flat) or not flat[ib]:
                H = H + local_hessian(ca.dot(lam_g[row : row + m], b), w)
            row += m
        out["hess_lag"] = ca.Function(
            "nlp_hess_l",
            [w, p, lam_f, lam_g],
            [ca.triu(H)],
            ["x", "p", "lam_f", "lam_g"],
            ["triu_hess_gamma_x_x"],
        )
    return out


def _limit_bounds(cons: Any, half: int) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` ``(half, 3)`` of the kept limit rows (:func:`_two_sided_rows`):
    ``-h`` below each paired row, ``-inf`` when the rows are kept one-sided."""
    h = cons.h
    lo = -h[half:] if 2 * half == len(h) else np.full_like(h, -np.inf)
    return lo, h[:half]


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


def _nlpsol(
    nlp: dict[str, Any], problem: Problem, derivs: dict[str, Any], warm: bool = False
) -> Any:
    """The solver; ``warm``: it starts from an earlier solve's primal-dual point (a later
    stage of the k continuation), so IPOPT keeps the multipliers and a small barrier."""
    s = problem.solver
    if s.method is SolverMethod.SQP:
        return _sqpsol(nlp, s, derivs)
    return ca.nlpsol(
        "stl_ipopt",
        "ipopt",
        nlp,
        {
            "print_time": False,
            "error_on_fail": False,
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
                **(_IPOPT_WARM if warm else {}),
            },
        },
    )


def _sqpsol(nlp: dict[str, Any], s: Any, derivs: dict[str, Any]) -> Any:
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


# ------------------------------------------------------------------------ initial guess


def _targets(formula: Formula, vehicle: str, problem: Problem) -> list[str]:
    """Boxes ``vehicle`` must be inside somewhere (not under a negation), in spec order."""
    out: list[str] = []

    def walk(node: Formula, negated: bool) -> None:
        if isinstance(node, Not):
            walk(node.child, not negated)
            return
        if isinstance(node, Or):
            walk(node.operands[0], negated)  # the guess takes the first alternative
            return
        if isinstance(node, Predicate) and node.call.name == "inside" and not negated:
            v, reg = node.call.args
            if v == vehicle and reg != problem.workspace.name and reg not in out:
                out.append(reg)
        for child in node.children:
            walk(child, negated)

    walk(formula, False)
    return out


def _avoided(leaves: Mapping[Formula, Any], vehicle: str, problem: Problem) -> list[Any]:
    """Boxes the vehicle must always stay out of (``outside`` leaves of the conjunction)."""
    out = []
    for leaf in leaves:
        if (
            isinstance(leaf, Predicate)
            and leaf.call.name == "outside"
            and leaf.call.args[0] == vehicle
        ):
            out.append(problem.region(leaf.call.args[1]))
    return out


#: Cells of the initial-guess search grid (at most).
_GRID_CELLS = 40_000


def _grid_path(problem: Problem, avoid: Sequence[Any], points: Sequence[np.ndarray]) -> np.ndarray:
    """Shortest polyline through ``points`` (in order) on a voxel grid, around ``avoid`` boxes.

    A 26-connected grid over the workspace (cell size from the smallest avoided box and a
    cell budget); cells whose centre lies in a box grown by half a cell are blocked.
    Returns (m, 3) vertices; falls back to straight segments where no path exists.
    """
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    lo = np.asarray(problem.workspace.lo_enu_m)
    hi = np.asarray(problem.workspace.hi_enu_m)
    ext = hi - lo
    feature = min((float(np.min(np.subtract(b.hi_enu_m, b.lo_enu_m))) for b in avoid), default=1.0)
    cell = max(feature / 2.0, float((np.prod(ext) / _GRID_CELLS) ** (1 / 3)))
    shape = np.maximum(1, np.floor(ext / cell).astype(int))
    axes = [lo[a] + (np.arange(shape[a]) + 0.5) * ext[a] / shape[a] for a in range(3)]
    cx, cy, cz = np.meshgrid(*axes, indexing="ij")
    centres = np.column_stack([cx.ravel(), cy.ravel(), cz.ravel()])
    step = ext / shape
    blocked = np.zeros(len(centres), dtype=bool)
    for b in avoid:
        grow = 0.5 * step + 0.05 * feature
        inside = np.all(
            (centres > np.asarray(b.lo_enu_m) - grow) & (centres < np.asarray(b.hi_enu_m) + grow),
            axis=1,
        )
        blocked |= inside
    idx = np.arange(len(centres)).reshape(shape)
    rows, cols, wts = [], [], []
    for off in (
        np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij")).reshape(3, -1).T
    ):
        if not off.any():
            continue
        src = idx[
            max(0, -off[0]) : shape[0] - max(0, off[0]),
            max(0, -off[1]) : shape[1] - max(0, off[1]),
            max(0, -off[2]) : shape[2] - max(0, off[2]),
        ].ravel()
        dst = src + off[0] * shape[1] * shape[2] + off[1] * shape[2] + off[2]
        ok = ~blocked[src] & ~blocked[dst]
        rows.append(src[ok])
        cols.append(dst[ok])
        wts.append(np.full(int(ok.sum()), float(np.linalg.norm(off * step))))
    graph = csr_matrix(
        (np.concatenate(wts), (np.concatenate(rows), np.concatenate(cols))),
        shape=(len(centres), len(centres)),
    )
    free = np.nonzero(~blocked)[0]
    if free.size == 0:
        return np.asarray(points, dtype=float)

    def nearest(pt: np.ndarray) -> int:
        return int(free[np.argmin(np.linalg.norm(centres[free] - pt, axis=1))])

    out = [np.asarray(points[0], dtype=float)]
    for a, b in itertools.pairwise(points):
        ia, ib = nearest(np.asarray(a)), nearest(np.asarray(b))
        _, pred = dijkstra(graph, indices=ia, return_predecessors=True)
        if ia != ib and pred[ib] < 0:
            out.append(np.asarray(b, dtype=float))
            continue
        chain = [ib]
        while chain[-1] != ia:
            chain.append(int(pred[chain[-1]]))
        out.extend(centres[i] for i in reversed(chain[:-1]))
        out.append(np.asarray(b, dtype=float))
    return np.asarray(out)


#: Fraction of the per-axis limits the initial guess's legs use (the Bezier bounds of the
#: limit constraints are conservative, and the least-squares fit overshoots a little).
_GUESS_LIMIT_FRACTION = 0.75
#: Extra time (s) the guess stays in a target box beyond the spec's hover there.
_GUESS_DWELL_MARGIN_S = 0.75


def _hover_times(formula: Formula, vehicle: str) -> dict[str, float]:
    """Longest ``always[a, b] inside(vehicle, box)`` window (b - a, s) per box."""
    out: dict[str, float] = {}

    def walk(node: Formula) -> None:
        if isinstance(node, Always):
            c = node.child
            if isinstance(c, Predicate) and c.call.name == "inside" and c.call.args[0] == vehicle:
                reg = c.call.args[1]
                out[reg] = max(out.get(reg, 0.0), node.end_s - node.start_s)
        for child in node.children:
            walk(child)

    walk(formula)
    return out


def _leg_profile(dist_m: np.ndarray, v_max: np.ndarray, a_max: np.ndarray) -> tuple[float, float]:
    """(duration s, accelerating fraction of it) of the fastest rest-to-rest trapezoidal
    profile over per-axis distances ``dist_m`` (3,) within per-axis ``v_max``/``a_max``.

    Every axis is flown on the same normalised profile; the limiting axis decides.  With
    an accelerating fraction ``phi`` of duration ``T`` the peak speed is ``d / (T (1-phi))``
    and the acceleration ``d / (T^2 phi (1-phi))``.
    """
    d = np.abs(dist_m)
    t_acc = v_max / a_max
    tri = d <= v_max * t_acc  # never reaches v_max
    t = np.where(tri, 2 * np.sqrt(d / a_max), d / v_max + t_acc)
    i = int(np.argmax(t))
    if t[i] <= 0:
        return 0.0, 0.5
    return float(t[i]), float(0.5 if tri[i] else t_acc[i] / t[i])


def _trapezoid_s(t_s: np.ndarray, duration_s: float, phi: float) -> np.ndarray:
    """Normalised path parameter in [0, 1] of a symmetric trapezoidal speed profile that
    accelerates for a fraction ``phi`` (0 < phi <= 0.5) of ``duration_s``."""
    u = np.clip(t_s / max(duration_s, 1e-9), 0.0, 1.0)
    peak = 1.0 / (1.0 - phi)
    acc = peak / phi
    return np.where(
        u < phi,
        0.5 * acc * u**2,
        np.where(u <= 1 - phi, 0.5 * acc * phi**2 + peak * (u - phi), 1 - 0.5 * acc * (1 - u) ** 2),
    )


def _initial_guess(
    problem: Problem,
    model: Any,
    formula: Formula,
    x0s: list[np.ndarray],
    leaves: Mapping[Formula, Any],
) -> np.ndarray:
    """Shortest grid paths through each vehicle's target boxes around the boxes it must
    avoid, fitted to Z by least squares.

    Timing respects the vehicle's limits: each leg (between targets) is flown rest to rest
    with a trapezoidal speed profile (a third accelerating, a third cruising, a third
    braking) along its polyline, no shorter than the per-axis trapezoid time at
    ``_GUESS_LIMIT_FRACTION`` of ``v_max``/``a_max`` over the leg's per-axis travel; at each
    target the vehicle dwells for the spec's hover there (``always[a, b] inside``) plus
    ``_GUESS_DWELL_MARGIN_S``.  The time left over in the horizon is split: half stretches
    the legs (slower is easier on the limits), half lengthens the dwells.  Vehicles sharing
    a target box get points spread along its longest side, so the guess does not put them on
    top of each other.
    """
    times = np.asarray(model.times_s)
    horizon = problem.timing.horizon_s
    per_vehicle = {v.name: _targets(formula, v.name, problem) for v in problem.vehicles}
    sharing: dict[str, list[str]] = {}
    for name, regs in per_vehicle.items():
        for reg in regs:
            sharing.setdefault(reg, []).append(name)

    starts = {v.name: np.asarray(v.start_enu_m, dtype=float) for v in problem.vehicles}
    sep = float(problem.separation_m or 0.0)
    slots = {
        reg: _box_slots(problem.region(reg), users, starts, sep) for reg, users in sharing.items()
    }

    def point(reg: str, name: str) -> np.ndarray:
        return slots[reg][name]

    options: list[list[np.ndarray]] = []
    avoids: list[list[Any]] = []
    for v in problem.vehicles:
        targets = per_vehicle[v.name]
        pts = [np.asarray(v.start_enu_m), *(point(r, v.name) for r in targets)]
        avoid = _avoided(leaves, v.name, problem)
        avoids.append(avoid)
        if len(pts) == 1:
            options.append([np.tile(pts[0], (len(times), 1))])
            continue
        legs = [_grid_path(problem, avoid, [a, b]) for a, b in itertools.pairwise(pts)]
        v_lim = _GUESS_LIMIT_FRACTION * np.asarray(v.v_max_m_s, dtype=float)
        a_lim = _GUESS_LIMIT_FRACTION * np.asarray(v.a_max_m_s2, dtype=float)
        prof = [
            _leg_profile(np.abs(np.diff(leg, axis=0)).sum(axis=0), v_lim, a_lim) for leg in legs
        ]
        leg_s = np.array([d for d, _ in prof])
        phis = [ph for _, ph in prof]
        hovers = _hover_times(formula, v.name)
        dwell_s = np.array([hovers.get(r, 0.0) + _GUESS_DWELL_MARGIN_S for r in targets])
        slack = horizon - leg_s.sum() - dwell_s.sum()
        if slack > 0:
            leg_s = leg_s + 0.5 * slack * leg_s / max(leg_s.sum(), 1e-9)
            dwell_s = dwell_s + 0.5 * slack / len(dwell_s)
        else:  # infeasible as timed: squeeze everything into the horizon
            scale = horizon / (leg_s.sum() + dwell_s.sum())
            leg_s, dwell_s = leg_s * scale, dwell_s * scale
        options.append(
            [
                _timed_path(times, legs, leg_s, phis, dwell_s, lane * _GUESS_LANE_SEP * sep)
                for lane in _GUESS_LANES
            ]
        )
    # Lanes: a few rounds of each vehicle picking the first lane clear of all the others.
    chosen = [opts[0] for opts in options]
    for _ in range(3):
        changed = False
        for i, opts in enumerate(options):
            others = [p for j, p in enumerate(chosen) if j != i]
            pick = _pick_lane(opts, others, avoids[i], sep)
            changed |= pick is not chosen[i]
            chosen[i] = pick
        if not changed:
            break
    cols = []
    for path, x0, v in zip(chosen, x0s, problem.vehicles, strict=True):
        Zv = _fit_within_limits(model, path, x0, v, problem.workspace)
        cols.append(Zv.reshape(-1, order="F"))
    return np.concatenate(cols)


def _fit_within_limits(
    model: Any, path: np.ndarray, x0: np.ndarray, vehicle: Any, ws: Any
) -> np.ndarray:
    """``Z`` (n_dec, 3) whose samples are closest (least squares) to ``path`` (n, 3) among
    the trajectories that respect the vehicle's limits, end at rest and stay in the
    workspace at the samples: a small QP per axis (DAQP, dense, ``n_dec`` variables).

    The unconstrained fit of a timed polyline rings at its corners (reach-avoid N = 4:
    2.4x the acceleration limit), and IPOPT then spends its first iterations restoring
    feasibility instead of raising the robustness.  If the QP fails, falls back to the
    least-squares fit with only the equalities (end at rest, the model's own).
    """
    Mp, Np = np.asarray(model.Mp), np.asarray(model.Np)
    cons = model.limit_constraints(vehicle.v_max_m_s, vehicle.a_max_m_s2)
    half = _two_sided_rows(cons)
    lo_all, hi_all = _limit_bounds(cons, half)
    Ge, He = model.equality_constraints()
    n_fix = 1 + len(Ge)  # rows held at 0: the end velocity, the model's equalities
    A = np.vstack([model.Mv[-1:], Ge, cons.G[:half], Mp])
    qp = _guess_qp(model.n_dec, A)
    H = 2 * (Mp.T @ Mp) + 1e-6 * np.eye(model.n_dec)
    out = np.zeros((model.n_dec, 3))
    for a in range(3):
        xa = x0[:, a]
        off = np.concatenate([model.Nv[-1:] @ xa, He @ xa, cons.H[:half] @ xa, Np @ xa])
        lo_lim, hi_lim = lo_all[:, a], hi_all[:, a]
        lba = np.concatenate([np.zeros(n_fix), lo_lim, np.full(len(Mp), ws.lo_enu_m[a])]) - off
        uba = np.concatenate([np.zeros(n_fix), hi_lim, np.full(len(Mp), ws.hi_enu_m[a])]) - off
        g = -2 * Mp.T @ (path[:, a] - Np @ xa)
        sol = qp(h=H, g=g, a=A, lba=lba, uba=uba)
        za = np.asarray(sol["x"]).reshape(-1)
        if not qp.stats().get("success", False) or not np.all(np.isfinite(za)):
            # Equality-constrained least squares only (limits and workspace dropped).
            E = A[:n_fix]
            kkt = np.block([[H, E.T], [E, np.zeros((n_fix, n_fix))]])
            rhs = np.concatenate([-g, -off[:n_fix]])
            za = np.linalg.lstsq(kkt, rhs, rcond=None)[0][: model.n_dec]
        out[:, a] = za
    return out


_QP_CACHE: dict[tuple[int, int], Any] = {}


def _guess_qp(n_dec: int, A: np.ndarray) -> Any:
    key = (n_dec, A.shape[0])
    if key not in _QP_CACHE:
        _QP_CACHE[key] = ca.conic(
            "guess_fit",
            "daqp",
            {"h": ca.Sparsity.dense(n_dec, n_dec), "a": ca.Sparsity.dense(*A.shape)},
            {"error_on_fail": False},
        )
    return _QP_CACHE[key]


def _box_slots(
    box: Any, users: Sequence[str], starts: Mapping[str, np.ndarray], sep_m: float = 0.0
) -> dict[str, np.ndarray]:
    """Target points for the vehicles sharing ``box``: a k_x x k_y x k_z lattice (the counts
    giving every vehicle its own point with the largest margin), handed out greedily, each
    vehicle taking the free point nearest its start.  A single vehicle gets the centre.

    The margin of a lattice is the smaller of the points' depth inside the box and their
    spacing beyond the separation ``sep_m``, the two robustness terms a vehicle parked there
    is scored by.  Along an axis with ``k > 1`` points both are equal,
    ``m = (ext - sep (k - 1)) / (k + 1)``; an axis with one point puts it mid-box.
    (Reach-avoid, 16 drones in the 0.5 m goal with 0.2 m separation: a 3 x 3 x 2 lattice
    with m = 0.025 m; the cell centres of the same lattice were 0.167 m apart, which
    broke the separation from the start.)
    """
    lo, hi = np.asarray(box.lo_enu_m, dtype=float), np.asarray(box.hi_enu_m, dtype=float)
    ext = hi - lo
    n = len(users)

    def axis_margin(a: int, k: int) -> float:
        return ext[a] / 2 if k == 1 else (ext[a] - sep_m * (k - 1)) / (k + 1)

    best: tuple[float, tuple[int, ...]] = (-np.inf, (1, 1, 1))
    for k in itertools.product(range(1, n + 1), repeat=3):
        if math.prod(k) >= n and math.prod(k) < 2 * n + 2:
            m = min(axis_margin(a, k[a]) for a in range(3))
            if m > best[0] + 1e-12:
                best = (m, k)
    k = best[1]
    axes = []
    for a in range(3):
        if k[a] == 1:
            axes.append(np.array([0.5 * (lo[a] + hi[a])]))
        else:
            m = max(axis_margin(a, k[a]), 0.0)
            axes.append(np.linspace(lo[a] + m, hi[a] - m, k[a]))
    cells = [np.array(c) for c in itertools.product(*axes)]
    out: dict[str, np.ndarray] = {}
    for name in users:
        i = int(np.argmin([np.linalg.norm(c - starts[name]) for c in cells]))
        out[name] = cells.pop(i)
    return out


#: Lateral lanes (multiples of ``_GUESS_LANE_SEP`` x separation) the guess may shift a
#: vehicle's legs into, in order of preference.
_GUESS_LANES = (0, -1, 1, -2, 2, -3, 3)
_GUESS_LANE_SEP = 1.5


def _timed_path(
    times: np.ndarray,
    legs: Sequence[np.ndarray],
    leg_s: np.ndarray,
    phis: Sequence[float],
    dwell_s: np.ndarray,
    lane_m: float,
) -> np.ndarray:
    """Positions (n, 3) at ``times``: each leg flown on its trapezoid, shifted sideways
    (horizontally, left of the leg's direction) by ``lane_m`` away from its two ends."""
    knots_t: list[float] = [0.0]
    knots_p: list[np.ndarray] = [legs[0][0]]
    t_now = 0.0
    for leg, dur, phi, dwell in zip(legs, leg_s, phis, dwell_s, strict=True):
        seg = np.linalg.norm(np.diff(leg, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)]) / max(seg.sum(), 1e-9)
        tt = np.linspace(0.0, dur, 61)[1:]
        arc = _trapezoid_s(tt, dur, phi)
        pos = np.column_stack([np.interp(arc, cum, leg[:, a]) for a in range(3)])
        if lane_m:
            d = leg[-1] - leg[0]
            left = np.array([-d[1], d[0], 0.0])
            norm = float(np.linalg.norm(left))
            if norm > 1e-9:
                u = tt / max(dur, 1e-9)
                bump = np.clip(np.minimum(u, 1 - u) / 0.3, 0.0, 1.0)
                bump = bump * bump * (3 - 2 * bump)
                pos = pos + np.outer(bump, left / norm * lane_m)
        knots_t.extend((t_now + tt).tolist())
        knots_p.extend(pos)
        t_now += dur + dwell
        knots_t.append(t_now)
        knots_p.append(leg[-1])
    poly = np.asarray(knots_p)
    kt = np.asarray(knots_t)
    return np.column_stack([np.interp(times, kt, poly[:, a]) for a in range(3)])


def _pick_lane(
    candidates: Sequence[np.ndarray], placed: Sequence[np.ndarray], avoid: Sequence[Any], sep: float
) -> np.ndarray:
    """The first candidate path clear of the avoided boxes (0.3 m) and 1.3 separations from
    the paths already placed; else the clear one farthest from them."""
    best, best_d = candidates[0], -np.inf
    for path in candidates:
        clear = all(
            np.all(
                np.max(
                    np.maximum(np.asarray(b.lo_enu_m) - path, path - np.asarray(b.hi_enu_m)),
                    axis=1,
                )
                >= 0.3
            )
            for b in avoid
        )
        if not clear:
            continue
        d = min((float(np.min(np.linalg.norm(path - q, axis=1))) for q in placed), default=np.inf)
        if d >= 1.3 * sep:
            return path
        if d > best_d:
            best, best_d = path, d
    return best


# ------------------------------------------------------------------------------ checks


def _dense_times(problem: Problem) -> np.ndarray:
    t = problem.timing
    n = round(t.horizon_s / t.check_dt_s) + 1
    return np.arange(n) * t.check_dt_s


# ------------------------------------------------------------------------------- plan


def plan(
    problem: Problem,
    *,
    initial_guess: np.ndarray | None = None,
    progress: Callable[[str], None] | None = None,
) -> PlanResult:
    """Plan trajectories that maximise the robustness of ``problem``'s spec.

    Args:
        problem: a validated scenario (:func:`planner.scenario.load_scenario`).
        initial_guess: flat decision vector (``PlanResult.decision`` of an earlier solve of
            the same structure) to warm start from; default: straight lines through the
            boxes each vehicle must visit.
        progress: called with a short line at each stage (build, solve, check).

    Returns:
        :class:`PlanResult`; ``success=False`` (with the best trajectories) when the
        exact robustness is below ``epsilon`` or a check fails.
    """
    say = progress or (lambda _msg: None)
    t_start = time.perf_counter()
    registry = build_registry(problem)
    formulas = [parse_clause(problem, c, registry) for c in problem.clauses]
    formula = conjunction(formulas)
    model = make_model(problem)
    x0s = _x0(problem, model)
    p_val = np.concatenate([x.reshape(-1, order="F") for x in x0s])

    key = _structure_key(problem)
    cached = key in _CACHE
    if not cached:
        say(f"building the NLP for {len(problem.vehicles)} vehicle(s)")
        struct = _build(problem, model, formula)
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = struct
    struct = _CACHE[key]
    build_s = struct.build_s if not cached else 0.0

    # Numeric bounds: limits per vehicle into lbg/ubg, r bounds.
    lbg = struct.lbg_fixed.copy()
    ubg = struct.ubg_fixed.copy()
    half = struct.lim_half
    cons_cache: dict[tuple[Any, Any], tuple[np.ndarray, np.ndarray]] = {}
    for i, v in enumerate(problem.vehicles):
        keyl = (v.v_max_m_s, v.a_max_m_s2)
        if keyl not in cons_cache:
            lo, hi = _limit_bounds(model.limit_constraints(v.v_max_m_s, v.a_max_m_s2), half)
            cons_cache[keyl] = (lo.reshape(-1, order="F"), hi.reshape(-1, order="F"))
        lbg[struct.lim_slices[i]], ubg[struct.lim_slices[i]] = cons_cache[keyl]
    lbx = struct.lbx.copy()
    ubx = struct.ubx.copy()
    if problem.solver.robustness_constraint:
        _lower_r(lbx, ubx, problem.epsilon + struct.margin)

    if initial_guess is None:
        z0 = _initial_guess(problem, model, formula, x0s, struct.leaves)
    else:
        z0 = np.asarray(initial_guess, dtype=float).reshape(-1)[: struct.n_z]
    Mp, Np = np.asarray(model.Mp), np.asarray(model.Np)
    nd = model.n_dec * 3
    used = struct.used_steps
    p0 = [
        (Mp @ z0[i * nd : (i + 1) * nd].reshape((model.n_dec, 3), order="F") + Np @ x0)[
            used
        ].reshape(-1, order="F")
        for i, x0 in enumerate(x0s)
    ]
    w0 = np.concatenate([z0, *p0, [0.0]])
    w0[-1] = _min_leaf(struct, w0, p_val, default=0.0)
    bounds = {"p": p_val, "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg}

    def trajectories_of(w: np.ndarray) -> list[Trajectory]:
        return [
            model.trajectory(
                w[i * nd : (i + 1) * nd].reshape((model.n_dec, 3), order="F"), x0, v.name
            )
            for i, (v, x0) in enumerate(zip(problem.vehicles, x0s, strict=True))
        ]

    def exact_of(w: np.ndarray) -> float:
        return _evaluate(problem, formula, formulas, trajectories_of(w))[0]

    run = _run_solvers(struct, w0, bounds, say, problem.solver.method.value)
    w_opt, status = run.w, run.status
    check_s = 0.0
    if problem.solver.robustness_constraint:
        # The paper's eq. (1): smooth robustness >= epsilon + margin as a constraint.  The
        # margin starts at the smooth leaves' error bound; if the exact robustness on the
        # dense samples still falls short (dips between constraint samples), the margin
        # grows by the deficit and the solve restarts from the point it reached.  The best
        # point of these rounds is kept.
        eps = problem.epsilon
        margin = struct.margin
        t_check = time.perf_counter()
        best = (exact_of(w_opt), w_opt, status)
        check_s += time.perf_counter() - t_check
        rob = best[0]
        for _ in range(_EPS_ROUNDS):
            if rob >= eps or not _solved(status):
                break
            margin += eps - rob + _EPS_MARGIN_STEP_M
            _lower_r(lbx, ubx, eps + margin)
            w_start = w_opt.copy()
            w_start[-1] = lbx[-1]
            run = run.then(_run_solvers(struct, w_start, bounds, say, "eq. (1) margin"))
            w_opt, status = run.w, run.status
            t_check = time.perf_counter()
            rob = exact_of(w_opt)
            check_s += time.perf_counter() - t_check
            if rob > best[0]:
                best = (rob, w_opt, status)
        rob, w_opt, status = best
        if rob < eps:
            # Infeasible as constrained: the plain maximisation from the same start finds
            # the best trajectories there are (a failed result carries the best found).
            lbx[-1], ubx[-1] = struct.lbx[-1], struct.ubx[-1]
            plain = _run_solvers(struct, w0, bounds, say, "plain maximisation")
            t_check = time.perf_counter()
            if exact_of(plain.w) > rob:
                w_opt = plain.w
                status = (
                    f"eq. (1) constraint not met ({status}); plain maximisation: {plain.status}"
                )
            check_s += time.perf_counter() - t_check
            run = run.then(plain)

    say("checking on dense samples")
    # The smooth value at the point returned (r itself may sit on a bound, eq. (1)).
    smooth = _min_leaf(struct, w_opt, p_val, default=float(w_opt[-1]))
    t_check = time.perf_counter()
    trajectories = trajectories_of(w_opt)
    result = _evaluate(problem, formula, formulas, trajectories)
    limits = check_trajectories(
        problem, trajectories, problem.vehicles, problem.timing.check_dt_s, problem.timing.horizon_s
    )
    check_s += time.perf_counter() - t_check
    rob, rob_grid, weakest, clauses = result
    limits_ok = all(lim.ok for lim in limits)
    success = bool(rob >= problem.epsilon and limits_ok)
    if success:
        verdict = f"robustness {rob:.4g} >= epsilon {problem.epsilon:g}"
    elif rob < problem.epsilon:
        w_txt = (
            f" (weakest: {weakest.formula} = {weakest.robustness:.4g} at t={weakest.t_s:g} s)"
            if weakest
            else ""
        )
        verdict = f"robustness {rob:.4g} < epsilon {problem.epsilon:g}{w_txt}"
    else:
        bad = [lim.name for lim in limits if not lim.ok]
        verdict = f"limits violated by {', '.join(bad)}"
    total = time.perf_counter() - t_start
    stats = SolveStats(
        build_s=build_s,
        solver_s=run.solver_s,
        function_eval_s=run.eval_s,
        check_s=check_s,
        n_variables=struct.n_w,
        n_constraints=struct.n_g,
        n_smooth_leaves=struct.n_smooth,
        k=struct.k,
        solver=problem.solver.method.value,
        cached=cached,
    )
    return PlanResult(
        problem=problem,
        success=success,
        status=f"{status}; {verdict}",
        robustness=rob,
        robustness_planning_grid=rob_grid,
        smooth_robustness=smooth,
        weakest=weakest,
        clauses=clauses,
        solve_time_s=total,
        iterations=run.iterations,
        trajectories=tuple(trajectories),
        limits=limits,
        decision=w_opt,
        stats=stats,
    )


#: Rounds of margin growth for the eq. (1) constraint, and the extra step (m) per round.
_EPS_ROUNDS = 3
_EPS_MARGIN_STEP_M = 2e-3


def _min_leaf(struct: _Structure, w: np.ndarray, p: np.ndarray, default: float) -> float:
    """The smallest leaf value (the smooth robustness the NLP sees) at ``w``; ``default``
    when the spec has no leaves."""
    values = np.asarray(struct.leaf_fn(w, p)).reshape(-1)
    return float(np.min(values)) if values.size else default


def _lower_r(lbx: np.ndarray, ubx: np.ndarray, value: float) -> None:
    """Raise r's lower bound to ``value`` (in place), lifting a robustness cap above it so
    the bounds stay consistent: a cap below the required margin leaves r pinned there."""
    lbx[-1] = value
    ubx[-1] = max(ubx[-1], value + _EPS_MARGIN_STEP_M)


def _solved(status: str) -> bool:
    return status in (
        "Solve_Succeeded",
        "Solved_To_Acceptable_Level",
        "Search_Direction_Becomes_Too_Small",
    )


@dataclass(frozen=True, slots=True)
class _Run:
    """The end point of one or more solver runs and what they cost."""

    w: np.ndarray
    status: str
    iterations: int
    solver_s: float
    eval_s: float

    def then(self, later: _Run) -> _Run:
        """``later``'s end point, with the costs of both."""
        return _Run(
            later.w,
            later.status,
            self.iterations + later.iterations,
            self.solver_s + later.solver_s,
            self.eval_s + later.eval_s,
        )


def _run_solvers(
    struct: _Structure,
    w0: np.ndarray,
    bounds: Mapping[str, np.ndarray],
    say: Callable[[str], None],
    what: str,
) -> _Run:
    """Run the structure's solvers in turn (the k continuation), each warm started from the
    previous one's primal-dual point.  ``bounds`` are read at call time (``lbx`` may change
    between calls)."""
    iterations = 0
    solver_s = eval_s = 0.0
    status = "not solved"
    w_opt = w0
    lam_x = lam_g = None
    for k, solver in struct.solvers:
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
    return _Run(w_opt, status, iterations, solver_s, eval_s)


def _evaluate(
    problem: Problem,
    formula: Formula,
    formulas: Sequence[Formula],
    trajectories: Sequence[Trajectory],
) -> tuple[float, float, Weakest | None, tuple[ClauseReport, ...]]:
    """Exact robustness (dense and planning grid), weakest sub-formula, per clause."""
    t_dense = _dense_times(problem)
    sig = {tr.name: tr.position(t_dense) for tr in trajectories}
    dt = problem.timing.check_dt_s
    clause_rob = [f.robustness(sig, dt) for f in formulas]
    clauses = tuple(
        ClauseReport(c.key_path, c.text, r)
        for c, r in zip(problem.clauses, clause_rob, strict=True)
    )
    rob = float(min(clause_rob)) if clause_rob else math.inf
    ts = problem.timing.sample_dt_s
    n = problem.timing.n_samples
    sig_grid = {tr.name: tr.position(np.arange(n) * ts) for tr in trajectories}
    rob_grid = float(formula.robustness(sig_grid, ts))
    weakest = None
    if formulas:
        i = int(np.argmin(clause_rob))
        chain = formulas[i].weakest(sig, dt)
        leaf = chain[-1]
        weakest = Weakest(
            formula=str(_witness_formula(leaf)),
            robustness=float(_witness_value(leaf)),
            t_s=float(_witness_time(leaf, dt)),
            clause_key=problem.clauses[i].key_path,
        )
    return rob, rob_grid, weakest, clauses


def _witness_formula(w: Any) -> Any:
    return w.formula


def _witness_value(w: Any) -> float:
    return w.robustness


def _witness_time(w: Any, dt: float) -> float:
    return w.t_s
