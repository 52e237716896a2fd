"""The spec's geometry whatever its spelling: where a vehicle must be, and where it must not.

A *place* of vehicle ``d`` is a convex polytope ``{p : A p <= b}`` in its position, read from
any formula that means one:

* ``inside(d, R)`` (the region's faces: :meth:`planner.spec.regions.Region.half_spaces`),
  ``not outside(d, R)``;
* a comparison affine in ``d``'s coordinates: ``x(d) >= 3``, ``-y(d) <= 2``,
  ``x(d) + y(d) <= 5``, ``z(d) - 1 > 0`` (found by evaluating the comparison's exact margin,
  so any arithmetic the spec language allows is understood, and a non-affine one refused);
* a conjunction of those for the same vehicle, and the negation of a disjunction of them
  (De Morgan).

A *keep-out* is a formula whose negation is a place: ``outside(d, R)``, a disjunction of
half-planes of one vehicle (stlpy's ``outside_rectangle_formula``), ``not inside(d, R)``.

The initial guess (:mod:`planner.solve.guess`) routes each vehicle through its places (a target
point deep inside: the centre of an axis-aligned box, the Chebyshev centre of any other
polytope) and around its keep-outs. The NLP writes every leaf as it is; only the guess needs
the geometry.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import linprog

from planner.cache import BoundedCache
from planner.spec.predicates import Role, role_of
from planner.spec.regions import chebyshev_ball
from planner.stl import And, BinOp, Call, Comparison, Expr, Formula, Neg, Not, Or, Predicate

__all__ = ["Place", "keep_out", "place"]

#: Positions at which a comparison's margin is evaluated to read its affine form: the origin,
#: the unit vectors, and two generic points that check the form is affine.
_PROBES = np.array(
    [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0],
     [0.37, -1.91, 2.63], [-4.1, 3.3, -0.7]]
)  # fmt: skip
_AXIS_TOL = 1e-12


@dataclass(frozen=True, slots=True, eq=False)
class Place:
    """A convex polytope ``A p <= b`` of one vehicle, within the workspace.

    Attributes:
        vehicle: whose position it constrains.
        name: the formula it was read from (for messages and as a key).
        A, b: ``(m, 3)``, ``(m,)`` its half-spaces (unit normals).
        lo_enu_m, hi_enu_m: an axis-aligned box inside it (the box itself when the polytope
            is one; else the cube inscribed in its Chebyshev ball), clipped to the workspace.
        point: a point deep inside (the box's centre; the Chebyshev centre).
        depth_m: how deep ``point`` is (the Chebyshev radius; 0 for an empty polytope).
        clear_of: keep-outs the route to this place must stay out of until it gets there
            (the left side of ``phi until psi`` when ``phi`` is a keep-out's negation).
    """

    vehicle: str
    name: str
    A: np.ndarray
    b: np.ndarray
    lo_enu_m: tuple[float, float, float]
    hi_enu_m: tuple[float, float, float]
    point: np.ndarray
    depth_m: float
    clear_of: tuple[Place, ...] = ()

    @property
    def shape(self) -> tuple[Any, ...]:
        """The same for the same polytope, whatever its spelling and whoever's it is (a box:
        its bounds within the workspace; else its face rows)."""
        if bool(np.all(np.abs(self.A).max(axis=1) >= 1.0 - _AXIS_TOL)):
            rows = np.round(np.concatenate([self.lo_enu_m, self.hi_enu_m]), 9) + 0.0
            return ("box", *rows.tolist())
        face = np.round(np.column_stack([self.A, self.b]), 9) + 0.0
        return ("polytope", *sorted(set(map(tuple, face.tolist()))))

    @property
    def key(self) -> tuple[Any, ...]:
        """:attr:`shape` of this vehicle's place (the same place, however spelled)."""
        return (self.vehicle, *self.shape)

    def contains(self, p: np.ndarray, margin: float = 0.0) -> bool:
        """Whether ``p`` (3,) lies inside, at least ``margin`` from every face."""
        return bool(np.all(self.A @ np.asarray(p, dtype=float) <= self.b - margin))


def _half_spaces(
    node: Formula, positive: bool, problem: Any, outer: bool = False
) -> tuple[str, list[Any]] | None:
    """``(vehicle, [(a, c), ...])`` with ``node`` (negated unless ``positive``) equivalent to
    ``a . p <= c`` for all rows; ``None`` if it is not such a conjunction of one vehicle (a
    ``face`` in the conjunction asks nothing of the position: the place is the rest).  A
    cylinder is the prism over the polygon inscribed in its circle (``outer``: circumscribed
    about it, for a keep-out)."""
    if isinstance(node, Not):
        return _half_spaces(node.child, not positive, problem, outer)
    if isinstance(node, And if positive else Or):
        vehicle: str | None = None
        rows: list[Any] = []
        for child in node.operands:
            if positive and isinstance(child, Predicate) and role_of(child) is Role.HEADING:
                continue  # a heading asked for in the place: the position is the place's
            got = _half_spaces(child, positive, problem, outer)
            if got is None or (vehicle is not None and got[0] != vehicle):
                return None
            vehicle = got[0]
            rows.extend(got[1])
        return None if vehicle is None else (vehicle, rows)
    if isinstance(node, Predicate):
        role = role_of(node)
        if role not in (Role.TARGET_BOX, Role.KEEP_OUT):
            return None
        vehicle, region = node.call.args
        if (role is Role.TARGET_BOX) != positive:
            return None  # outside (or not inside) is a keep-out, not a conjunction
        A, b = problem.region(region).half_spaces(outer)
        return vehicle, [(a, float(c)) for a, c in zip(A, b, strict=True)]
    if isinstance(node, Comparison):
        names = node.signal_names()
        if len(names) != 1 or _reads_ground(node):
            return None  # a height above the terrain is no place (nor affine, but for a plane)
        (vehicle,) = names
        try:
            m = np.asarray(node.robustness_trace({vehicle: _PROBES}, 1.0), dtype=float)
        except Exception:  # a function that is not a vehicle's position: not geometry
            return None
        if m.shape != (len(_PROBES),) or not np.all(np.isfinite(m)):
            return None
        c0, g = m[0], m[1:4] - m[0]
        if not np.allclose(m[4:], c0 + _PROBES[4:] @ g, atol=1e-9 * (1 + np.abs(m[4:]))):
            return None  # not affine in the position
        norm = float(np.linalg.norm(g))
        if norm == 0.0:
            return None
        # margin g . p + c0 >= 0 (its negation: <= 0), as a . p <= c with |a| = 1
        if positive:
            return vehicle, [(-g / norm, c0 / norm)]
        return vehicle, [(g / norm, -c0 / norm)]
    return None


def _reads_ground(node: Comparison) -> bool:
    """Whether a comparison reads a call of the terrain (``agl``)."""

    def calls(e: Expr) -> bool:
        if isinstance(e, Call):
            return role_of(e) is Role.TERRAIN
        if isinstance(e, BinOp):
            return calls(e.lhs) or calls(e.rhs)
        if isinstance(e, Neg):
            return calls(e.operand)
        return False

    return calls(node.lhs) or calls(node.rhs)


def _make(vehicle: str, name: str, rows: list[Any], problem: Any, outer: bool = False) -> Place:
    """The place of ``rows``; its box is inside it, or, with ``outer``, around it (what a
    route must keep clear of)."""
    ws = problem.workspace
    ws_lo, ws_hi = np.asarray(ws.lo_enu_m, dtype=float), np.asarray(ws.hi_enu_m, dtype=float)
    A = np.array([a for a, _ in rows], dtype=float).reshape(-1, 3)
    b = np.array([c for _, c in rows], dtype=float)
    axis = np.abs(A).max(axis=1) >= 1.0 - _AXIS_TOL
    if axis.all():  # a box: the bounds per axis, the workspace where none is given
        lo, hi = ws_lo.copy(), ws_hi.copy()
        for a, c in zip(A, b, strict=True):
            i = int(np.argmax(np.abs(a)))
            if a[i] > 0:
                hi[i] = min(hi[i], c)
            else:
                lo[i] = max(lo[i], -c)
        point = 0.5 * (lo + hi)
        depth = max(float(np.min(hi - lo)) / 2.0, 0.0)
        return Place(vehicle, name, A, b, tuple(lo), tuple(hi), point, depth)
    key = (A.tobytes(), b.tobytes(), ws_lo.tobytes(), ws_hi.tobytes(), outer)
    point, depth, lo, hi = _POLYTOPES.get_or_build(
        key, lambda: _polytope_boxes(A, b, ws_lo, ws_hi, outer)
    )[0]
    return Place(vehicle, name, A, b, tuple(lo), tuple(hi), point.copy(), depth)


#: The LPs of a polytope's place, by its rows and the workspace: a route's guess asks for
#: the same keep-outs again and again (the 40-pole line: 9,448 LPs, 13.9 s of its 20 s guess).
_POLYTOPES: BoundedCache[tuple[np.ndarray, float, np.ndarray, np.ndarray]] = BoundedCache(4096)


def _polytope_boxes(
    A: np.ndarray, b: np.ndarray, ws_lo: np.ndarray, ws_hi: np.ndarray, outer: bool
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """``(centre, depth, lo, hi)`` of :func:`_make` for a polytope that is not a box."""
    point, depth = _chebyshev(A, b, ws_lo, ws_hi)
    if outer:
        lo, hi = _bounding_box(A, b, ws_lo, ws_hi)
    else:
        half = depth / np.sqrt(3.0)
        lo, hi = point - half, point + half
    return point, depth, lo, hi


def _bounding_box(
    A: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The smallest box around ``A p <= b`` within ``[lo, hi]`` (six LPs, HiGHS)."""

    out_lo, out_hi = lo.copy(), hi.copy()
    for i in range(3):
        for sign in (1.0, -1.0):
            c = np.zeros(3)
            c[i] = sign
            res = linprog(c, A_ub=A, b_ub=b, bounds=list(zip(lo, hi, strict=True)), method="highs")
            if res.status == 0:
                if sign > 0:
                    out_lo[i] = res.x[i]
                else:
                    out_hi[i] = res.x[i]
    return out_lo, out_hi


def _chebyshev(
    A: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[np.ndarray, float]:
    """Centre and radius of the largest ball in ``A p <= b`` within the box ``[lo, hi]`` (an
    LP, HiGHS); the workspace centre and 0 when the polytope is empty there."""
    eye = np.eye(3)
    centre, radius = chebyshev_ball(np.vstack([A, eye, -eye]), np.concatenate([b, hi, -lo]))
    return (0.5 * (lo + hi), 0.0) if centre is None else (centre, radius)


def place(node: Formula, problem: Any) -> Place | None:
    """The place ``node`` means (a polytope of one vehicle), or ``None``."""
    got = _half_spaces(node, True, problem)
    return None if got is None else _make(got[0], str(node), got[1], problem)


def keep_out(node: Formula, problem: Any) -> Place | None:
    """The place ``node`` keeps its vehicle out of (``node`` is ``not place``), or ``None``."""
    got = _half_spaces(node, False, problem, outer=True)
    return None if got is None else _make(got[0], str(node), got[1], problem, outer=True)
