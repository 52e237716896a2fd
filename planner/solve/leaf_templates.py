"""Smooth leaves as shared CasADi templates: one symbolic Hessian per leaf *shape*.

The planner (:mod:`planner.optimize`) keeps the temporal sub-formulas it cannot handle by
constraints (``eventually``, ``until``, ``or``, ...) as smooth robustness expressions, and
IPOPT wants their exact Hessian.  Differentiating such a leaf twice is the expensive part of
building the NLP: ``eventually[0, 29] always[0, 1] inside(d, insp1)`` of the power-line
scenario is ~3,500 soft-min terms whose Hessian in the vehicle's 132 decision variables is
dense, 0.75 s of CasADi per leaf, and a scenario has one per vehicle and box.

Those leaves differ only in *which* vehicle and *which* box they name.  Here a leaf is
renamed to a canonical shape (vehicles ``v0, v1, ...`` and regions ``r0, r1, ...`` in order
of appearance: the text above becomes ``eventually[0, 29] always[0, 1] inside(v0, r0)``), and
one :class:`LeafTemplate` per shape, sample step and sharpness holds two CasADi functions:

``value_grad(z, x0, b) -> (value, d value / d z)``
``hess(z, x0, b, lam) -> lam * d2 value / d z2``

with ``z`` the leaf's vehicles' decisions that its window's samples use (per vehicle the
rows of ``Z_v`` those samples depend on, axis after axis), ``x0`` their start states
(``vec(X0_v)``) and ``b`` the regions' numbers (a box's ``lo_enu_m`` then ``hi_enu_m``; a
prism's or cylinder's :meth:`planner.spec.regions.Region.params`, its kind part of the key).  A
window ``[a, b]`` at a step is the same leaf from 0 at ``step + a``, and the template is keyed
by its block of the sample matrices, so windows of the same width and phase share one
wherever they lie (the chunks of a long ``eventually``, :func:`planner.solve.leaves.chunks_of`).  Every
leaf of that shape is then a *call* of
the same functions with its own arguments, so the symbolic work is done once per shape, not
once per vehicle (power-line N = 4: 8 leaves, 2 shapes), and it is cached for the process
(the latest 64): re-planning with another fleet size, or with boxes moved,
reuses it; a change of the smallest box's size changes the fitted sharpness and so the
templates.

The box bounds entering as inputs rather than constants changes nothing in the values: the
predicates (:func:`planner.spec.predicates.casadi_functions`) are the same code, fed symbols.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from planner.cache import BoundedCache
from planner.spec.predicates import PREDICATES, build_registry
from planner.spec.regions import Region
from planner.stl import Always, Call, Eventually, Expr, Formula

__all__ = [
    "LeafInstance",
    "LeafTemplate",
    "canonical_leaf",
    "clear_templates",
    "local_hessian",
    "smoothing_terms",
]


def local_hessian(expr: Any, w: Any) -> Any:
    """Hessian of the scalar ``expr`` w.r.t. ``w`` (n_w x n_w), differentiated only in the
    entries of ``w`` it depends on and scattered into place.

    A smooth leaf touches one or two vehicles' decisions out of thousands; differentiating
    it against the whole ``w`` adds sparsity detection over all of them (power-line N = 4,
    exact Hessian: build 13.5 -> 11.7 s).
    """
    dep = np.nonzero(np.asarray(ca.which_depends(expr, w, 2, False), dtype=bool))[0]
    n_w = w.shape[0]
    if dep.size == 0:
        return ca.SX(n_w, n_w)
    h_loc = ca.hessian(expr, w[dep.tolist()])[0]
    sel = ca.DM(ca.Sparsity.triplet(dep.size, n_w, list(range(dep.size)), dep.tolist()), 1.0)
    return ca.mtimes(ca.mtimes(sel.T, h_loc), sel)


# ----------------------------------------------------------------------- canonical shape


def _rebuild(node: Any, on_call: Callable[[Call], Call]) -> Any:
    """A copy of a formula/expression tree with every :class:`Call` replaced by ``on_call``
    (fields visited in declaration order, so the traversal order is fixed)."""
    if isinstance(node, Call):
        return on_call(node)
    if not isinstance(node, Formula | Expr):
        return node
    changes: dict[str, Any] = {}
    for f in dataclasses.fields(node):
        value = getattr(node, f.name)
        if isinstance(value, Formula | Expr):
            new = _rebuild(value, on_call)
        elif isinstance(value, tuple) and any(isinstance(v, Formula | Expr) for v in value):
            new = tuple(_rebuild(v, on_call) for v in value)
        else:
            continue
        if new is not value:
            changes[f.name] = new
    return dataclasses.replace(node, **changes) if changes else node


def smoothing_terms(formula: Formula, regions: Any = None) -> float:
    """``log`` of the most margins a predicate called in ``formula`` smooths over (0 when
    none does; :attr:`planner.spec.predicates.PredicateKind.terms`, or with ``regions`` (a
    region source) the faces of the region it names): at sharpness ``k`` its smooth value is
    within ``that / k`` of the exact one, to add to the temporal bound
    (:meth:`Formula.smooth_error_bound`).  A call inside arithmetic
    (``2 * inside(d, box) >= 1``) is counted unscaled."""
    most = 1

    def see(call: Call) -> Call:
        nonlocal most
        kind = PREDICATES.get(call.name)
        if kind is None:
            return call
        terms = kind.terms
        if regions is not None and terms > 1:
            named = [a for a, r in zip(call.args, kind.args, strict=False) if r == "r"]
            terms = max([regions.region(a).faces for a in named] or [terms])
        most = max(most, terms)
        return call

    _rebuild(formula, see)  # every call, wherever it is; the tree is returned unchanged
    return math.log(most)


def _canonical_tree(
    leaf: Formula, registry: Any = None
) -> tuple[Formula, tuple[str, ...], tuple[str, ...]]:
    """The renamed tree (its calls bound to ``registry``'s functions when given), and the
    original vehicle and region names in placeholder order."""
    vehicles: list[str] = []
    regions: list[str] = []

    def rename(call: Call) -> Call:
        signal = set(call.function.signal_names(call.args))
        args = []
        for a in call.args:
            names, prefix = (vehicles, "v") if a in signal else (regions, "r")
            if a not in names:
                names.append(a)
            args.append(f"{prefix}{names.index(a)}")
        fn = call.function if registry is None else registry[call.name]
        return dataclasses.replace(call, args=tuple(args), function=fn)

    shape = _rebuild(leaf, rename)
    return shape, tuple(vehicles), tuple(regions)


def canonical_leaf(leaf: Formula) -> tuple[str, tuple[str, ...], tuple[str, ...]]:
    """``(shape text, vehicles, regions)``: the leaf with its vehicle arguments renamed
    ``v0, v1, ...`` and its other (region) arguments ``r0, r1, ...`` in order of first
    appearance, and the original names in that order."""
    shape, vehicles, regions = _canonical_tree(leaf)
    return str(shape), vehicles, regions


# ------------------------------------------------------------------------------ templates


@dataclass(frozen=True, slots=True)
class _SymbolicRegions:
    """A region source (:class:`planner.spec.predicates.RegionSource`) whose boxes are symbols."""

    all_regions: tuple[Any, ...]
    #: the ground ``agl`` reads (:class:`planner.spec.terrain.Terrain`), a constant of the
    #: template (its digest part of the key)
    terrain: Any = None

    def region(self, name: str) -> Any:
        for r in self.all_regions:
            if r.name == name:
                return r
        raise KeyError(name)


@dataclass(frozen=True, slots=True)
class LeafTemplate:
    """The CasADi functions of one leaf shape at one sample step (see module docstring).

    Attributes:
        value: ``(z, x0, b) -> value (1, 1)`` (the constraint row; its reverse derivative,
            which nlpsol builds for the multipliers, is first order only).
        value_grad: ``(z, x0, b) -> (value (1, 1), gradient (1, n_z))``.
        hess: ``(z, x0, b, lam) -> lam * Hessian (n_z, n_z)``, nonzero only in the entries
            of ``z`` the leaf depends on twice.
        n_vehicles: vehicles the shape names (``z`` holds ``n_vehicles`` decision blocks).
        n_regions: regions the shape names (``b`` holds their :meth:`Region.params`, in
            order: 6 entries for a box).
    """

    value: Any
    value_grad: Any
    hess: Any
    n_vehicles: int
    n_regions: int


#: Templates kept per process (oldest forgotten first)
_TEMPLATES: BoundedCache[LeafTemplate] = BoundedCache(64)


def clear_templates() -> None:
    """Forget every built template (benchmarks measure cold builds with this)."""
    _TEMPLATES.clear()


def _shifted(leaf: Formula, step: int, dt: float) -> tuple[Formula, int]:
    """``eventually[a, b] psi`` (or ``always``) at ``step`` as the same leaf from 0 at
    ``step + a``: the same values, and one shape for every window of the same width."""
    if isinstance(leaf, Eventually | Always) and leaf.start_s > 0:
        a, b = leaf.steps(dt)
        return type(leaf)(leaf.child, 0.0, (b - a) * dt), step + a
    return leaf, step


def _local_block(model: Any, step: int, hz: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(columns, Mp block, Np block)`` of the samples ``step .. step + hz``: the rows of
    ``Mp`` restricted to the decision rows they use, and those rows of ``Np``.  A leaf
    depends only on the decisions of the segments its window touches, and away from the
    start those blocks are the same for every window of the same width and phase."""
    rows = np.arange(step, step + hz + 1)
    mp = np.asarray(model.Mp)[rows]
    cols = np.nonzero(np.any(np.abs(mp) > 0.0, axis=0))[0]
    return cols, mp[:, cols], np.asarray(model.Np)[rows]


def template(
    leaf: Formula,
    step: int,
    model: Any,
    dt: float,
    k: float,
    k_pred: float,
    region_of: Callable[[str], Region] | None = None,
    terrain: Any = None,
) -> tuple[LeafTemplate, tuple[str, ...], tuple[str, ...], np.ndarray]:
    """The template of ``leaf`` evaluated at sample ``step`` (built or from the cache), the
    leaf's vehicles and regions in the template's argument order, and the decision rows
    (of a vehicle's ``Z``) the template's ``z`` holds per vehicle.

    Args:
        leaf: a sub-formula whose robustness is a smooth expression of vehicle positions.
        step: the planning sample the leaf is evaluated at (its window starts there).
        model: the linear model (``Mp``, ``Np`` map decisions and start to sampled positions).
        dt: planning sample step (s); k: temporal sharpness; k_pred: predicate sharpness.
        region_of: the regions by name (their kinds of shape, :attr:`Region.signature`, are
            part of the template; default: every region a box).
        terrain: the ground of ``agl`` (:class:`planner.spec.terrain.Terrain`), if any.
    """
    leaf, step = _shifted(leaf, step, dt)
    shape_text, vehicles, regions = canonical_leaf(leaf)
    signatures = tuple(("box",) if region_of is None else region_of(r).signature for r in regions)
    cols, mp, np_ = _local_block(model, step, leaf.horizon_steps(dt))
    digest = hashlib.sha1()
    for a in (mp, np_):
        a = np.ascontiguousarray(a, dtype=float)
        digest.update(repr(a.shape).encode())
        digest.update(a.tobytes())
    ground = terrain if terrain is not None and "agl(" in shape_text else None
    key = (shape_text, signatures, digest.hexdigest(), model.n_init, dt, k, k_pred,
           None if ground is None else ground.digest)  # fmt: skip
    tpl, _ = _TEMPLATES.get_or_build(
        key,
        lambda: _build_template(
            leaf, mp, np_, model.n_init, dt, k, k_pred, len(vehicles), signatures, ground
        ),
    )
    return tpl, vehicles, regions, cols


def _build_template(
    leaf: Formula,
    mp: np.ndarray,
    np_: np.ndarray,
    n_init: int,
    dt: float,
    k: float,
    k_pred: float,
    n_veh: int,
    signatures: tuple[tuple[Any, ...], ...],
    terrain: Any = None,
) -> LeafTemplate:
    n_loc = mp.shape[1]
    nd, ni = n_loc * 3, n_init * 3
    z = ca.SX.sym("z", nd * n_veh)
    x0 = ca.SX.sym("x0", ni * n_veh)
    sizes = [Region.params_size(sig) for sig in signatures]
    b = ca.SX.sym("b", sum(sizes))
    at = np.concatenate([[0], np.cumsum(sizes)]).astype(int).tolist()
    sym_regions = tuple(
        Region.symbolic(f"r{j}", sig, b[at[j] : at[j + 1]]) for j, sig in enumerate(signatures)
    )
    registry = build_registry(_SymbolicRegions(sym_regions, terrain), k_pred)
    shape, _, _ = _canonical_tree(leaf, registry)
    hz = shape.horizon_steps(dt)
    Mp = ca.sparsify(ca.DM(mp))
    Np = ca.sparsify(ca.DM(np_))
    view = {}
    for j in range(n_veh):
        Zj = ca.reshape(z[j * nd : (j + 1) * nd], n_loc, 3)
        X0j = ca.reshape(x0[j * ni : (j + 1) * ni], n_init, 3)
        view[f"v{j}"] = ca.mtimes(Mp, Zj) + ca.mtimes(Np, X0j)
    if not view:
        # A leaf of constants only (``eventually[0, 1] (1 >= 0)``): the engine still needs
        # a trace to tell the window's length.
        view["_"] = ca.SX.zeros(hz + 1, 1)
    value = shape.smooth_robustness(view, dt, k)
    grad = ca.jacobian(value, z)
    lam = ca.SX.sym("lam")
    return LeafTemplate(
        value=ca.Function("leaf_value", [z, x0, b], [value], ["z", "x0", "b"], ["value"]),
        value_grad=ca.Function(
            "leaf_value_grad", [z, x0, b], [value, grad], ["z", "x0", "b"], ["value", "grad"]
        ),
        hess=ca.Function(
            "leaf_hess",
            [z, x0, b, lam],
            [lam * local_hessian(value, z)],
            ["z", "x0", "b", "lam"],
            ["hess"],
        ),
        n_vehicles=n_veh,
        n_regions=len(signatures),
    )


@dataclass(frozen=True, slots=True)
class LeafInstance:
    """One smooth leaf at one step: a template and where its arguments come from.

    Attributes:
        template: the shape's functions.
        z_index: entries of the NLP vector ``w`` forming the template's ``z`` (per vehicle,
            the decision rows its window uses, axis by axis).
        x0_index: entries of the NLP parameter ``p`` forming its ``x0``.
        bounds: the template's ``b`` (numbers: the named boxes' bounds).
    """

    template: LeafTemplate
    z_index: tuple[int, ...]
    x0_index: tuple[int, ...]
    bounds: np.ndarray


def instance(
    leaf: Formula,
    step: int,
    model: Any,
    dt: float,
    k: float,
    k_pred: float,
    vehicle_index: dict[str, int],
    region_of: Callable[[str], Region],
    terrain: Any = None,
) -> LeafInstance:
    """The :class:`LeafInstance` of ``leaf`` at ``step`` in an NLP whose ``w`` starts with
    the vehicles' ``vec(Z)`` blocks and whose ``p`` is their ``vec(X0)`` blocks, in the
    order of ``vehicle_index``."""
    tpl, vehicles, regions, cols = template(leaf, step, model, dt, k, k_pred, region_of, terrain)
    nd, ni = model.n_dec * 3, model.n_init * 3
    z_index: list[int] = []
    x0_index: list[int] = []
    for name in vehicles:
        i = vehicle_index[name]
        for axis in range(3):
            z_index.extend((i * nd + axis * model.n_dec + cols).tolist())
        x0_index.extend(range(i * ni, (i + 1) * ni))
    bounds = np.concatenate([region_of(r).params() for r in regions] or [np.zeros(0)])
    return LeafInstance(tpl, tuple(z_index), tuple(x0_index), bounds.astype(float))
