"""Named regions of a mission: boxes, prisms and cylinders in the mission frame, and what
they mean.

A region is an axis-aligned box (``lo_enu_m``/``hi_enu_m``), or a shape in any direction
(:attr:`Region.shape`, with ``lo_enu_m``/``hi_enu_m`` its bounding box):

* :class:`Prism`: a vertical prism over a convex polygon (a no-fly area, a right of way, an
  inspection box turned about the vertical: :meth:`Prism.oriented_box`); a polygon that is
  not convex is read as convex parts that overlap (:func:`planner.spec.cover.polygon_regions`),
  each a region with :attr:`Region.part_of` its name;
* :class:`Cylinder`: a vertical cylinder (a pole).

Every region has the same *margin* (:meth:`Region.margin`): the smallest of its face margins,
each a signed distance to one face (a box's six faces; a prism's walls, floor and roof; a
cylinder's mantle ``r - |p_xy - c|``, floor and roof). Inside, it is the Euclidean distance
to the boundary; outside, minus the largest face violation (at most the Euclidean distance,
equal to it beside a face). A box's margin is what it was (the L-infinity one).

Shared by the scenario reader (:mod:`planner.scenario`), the predicates
(:mod:`planner.spec.predicates`) and the plan files, with no dependency on any of them.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import linprog

from planner.errors import PlannerError

__all__ = [
    "KEEP_OUT_KINDS",
    "Cylinder",
    "Prism",
    "Region",
    "RegionKind",
    "ShapeError",
    "chebyshev_ball",
]


class RegionKind(enum.Enum):
    """What a named box means to the mission (documentation and plots; the spec decides)."""

    WORKSPACE = "workspace"
    OBSTACLE = "obstacle"
    NO_FLY = "no_fly"
    POLE = "pole"
    CONDUCTOR = "conductor"
    INSPECTION = "inspection"
    GOAL = "goal"
    REGION = "region"


#: Kinds of region no vehicle may ever be inside of, whatever the spec says: where it
#: may not start (:mod:`planner.scenario.checks`) and not descend or fly through when it
#: lands (:mod:`gcs.flight.landing`).
KEEP_OUT_KINDS = frozenset(
    {RegionKind.OBSTACLE, RegionKind.NO_FLY, RegionKind.POLE, RegionKind.CONDUCTOR}
)


class ShapeError(PlannerError, ValueError):
    """A shape that cannot be: fewer than three corners, a polygon whose edges cross (or, for
    a :class:`Prism`, that is not convex), an empty height range, a radius <= 0 (the scenario
    reader names the field)."""


#: Sides of the regular polygon a cylinder is read as where a linear form is needed
#: (:meth:`Region.half_spaces`): inscribed for a place, circumscribed for a keep-out.
CYLINDER_SIDES = 16


@dataclass(frozen=True, slots=True)
class Prism:
    """A vertical prism over a convex polygon, ENU metres.

    Attributes:
        vertices_xy: the polygon's corners, counter-clockwise, ``(m, 2)`` as tuples (empty for
            the symbolic prisms of :mod:`planner.solve.leaf_templates`).
        normals_xy: the outward unit normal of each wall (wall ``i`` runs from corner ``i``
            to ``i + 1``), ``(m, 2)``.
        offsets_m: ``n_i . p <= offset_i`` inside each wall, ``(m,)``.
        z_lo_m, z_hi_m: floor and roof.
        inradius_m: radius of the largest circle in the polygon (0 for a symbolic prism).
    """

    vertices_xy: tuple[tuple[float, float], ...]
    normals_xy: tuple[tuple[float, float], ...]
    offsets_m: tuple[float, ...]
    z_lo_m: float
    z_hi_m: float
    inradius_m: float = 0.0

    @classmethod
    def from_polygon(cls, vertices_xy: Any, z_lo_m: float, z_hi_m: float) -> Prism:
        """The prism over a convex polygon given in either orientation (ShapeError if the
        polygon has fewer than 3 corners, repeats one, or is not strictly convex)."""
        v = np.asarray(vertices_xy, dtype=float)
        if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3:
            raise ShapeError("a polygon needs at least 3 corners [x, y]")
        if not np.all(np.isfinite(v)):
            raise ShapeError("a polygon's corners must be finite numbers")
        if not z_lo_m < z_hi_m:
            raise ShapeError(f"empty height range: {z_lo_m:g} is not below {z_hi_m:g}")
        edges = np.roll(v, -1, axis=0) - v
        lengths = np.linalg.norm(edges, axis=1)
        if np.any(lengths <= 1e-9 * (1.0 + np.abs(v).max())):
            raise ShapeError("a polygon repeats a corner")
        area2 = float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
        if area2 < 0:  # clockwise: turn it round
            v = v[::-1]
            edges = np.roll(v, -1, axis=0) - v
            lengths = np.linalg.norm(edges, axis=1)
        cross = edges[:, 0] * np.roll(edges[:, 1], -1) - edges[:, 1] * np.roll(edges[:, 0], -1)
        if abs(area2) <= 1e-12 or np.any(cross <= 1e-12 * lengths * np.roll(lengths, -1)):
            i = int(np.argmin(cross))
            raise ShapeError(
                f"the polygon is not convex at corner {(i + 1) % len(v) + 1} "
                f"({v[(i + 1) % len(v), 0]:g}, {v[(i + 1) % len(v), 1]:g}) (a prism is convex: "
                f"planner.spec.cover.polygon_regions reads one that is not as its convex parts)"
            )
        dots = np.einsum("ij,ij->i", edges, np.roll(edges, -1, axis=0))
        if np.sum(np.arctan2(cross, dots)) > 3.0 * np.pi:  # turns the same way, winds twice
            raise ShapeError("the polygon's edges cross (it winds round more than once)")
        normals = np.column_stack([edges[:, 1], -edges[:, 0]]) / lengths[:, None]
        offsets = np.einsum("ij,ij->i", normals, v)
        return cls(
            tuple(map(tuple, v.tolist())),
            tuple(map(tuple, normals.tolist())),
            tuple(offsets.tolist()),
            float(z_lo_m),
            float(z_hi_m),
            chebyshev_ball(normals, offsets)[1],
        )

    @classmethod
    def oriented_box(cls, center_enu_m: Any, half_size_m: Any, yaw_rad: float) -> Prism:
        """A box with half-sizes ``(hx, hy, hz)`` along its own axes, turned ``yaw_rad``
        about the vertical (counter-clockwise from east, the mission frame's x)."""
        c = np.asarray(center_enu_m, dtype=float)
        h = np.asarray(half_size_m, dtype=float)
        if np.any(h <= 0):
            raise ShapeError("a box's half-sizes must be > 0")
        u = np.array([math.cos(yaw_rad), math.sin(yaw_rad)])
        w = np.array([-u[1], u[0]])
        corners = [
            c[:2] + sx * h[0] * u + sy * h[1] * w for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))
        ]
        return cls.from_polygon(corners, c[2] - h[2], c[2] + h[2])

    @property
    def walls(self) -> int:
        """Number of walls (the polygon's sides)."""
        return len(self.offsets_m)


@dataclass(frozen=True, slots=True)
class Cylinder:
    """A vertical cylinder, ENU metres: axis through ``center_xy``, ``radius_m``, from
    ``z_lo_m`` to ``z_hi_m``."""

    center_xy: tuple[float, float]
    radius_m: float
    z_lo_m: float
    z_hi_m: float

    def __post_init__(self) -> None:
        if isinstance(self.radius_m, float | int) and not self.radius_m > 0:
            raise ShapeError(f"a cylinder's radius must be > 0, got {self.radius_m:g}")
        if isinstance(self.z_lo_m, float | int) and not self.z_lo_m < self.z_hi_m:
            raise ShapeError(f"empty height range: {self.z_lo_m:g} is not below {self.z_hi_m:g}")


Shape = Prism | Cylinder


def _polygon_sides(c: np.ndarray, r: float, outer: bool) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (n, 2) and offsets of the regular ``CYLINDER_SIDES``-gon inscribed in the
    circle (``outer``: circumscribed about it)."""
    n = CYLINDER_SIDES
    ang = (np.arange(n) + 0.5) * 2.0 * np.pi / n
    normals = np.column_stack([np.cos(ang), np.sin(ang)])
    apothem = r if outer else r * math.cos(math.pi / n)
    return normals, normals @ c + apothem


@dataclass(frozen=True, slots=True)
class Region:
    """A named region in the mission frame (ENU, metres).

    Attributes:
        name, kind: as the scenario names it, and what it means (:class:`RegionKind`).
        lo_enu_m, hi_enu_m: the axis-aligned box; for a shaped region its bounding box.
        shape: ``None`` for a box; else the :class:`Prism` or :class:`Cylinder` it is.
        part_of: the name of the polygon that is not convex this is a convex part of
            (:mod:`planner.spec.cover`: the spec's ``inside`` of it is that of one of its parts);
            ``None`` for a region of its own.
    """

    name: str
    kind: RegionKind
    lo_enu_m: tuple[float, float, float]
    hi_enu_m: tuple[float, float, float]
    shape: Shape | None = None
    part_of: str | None = None

    @classmethod
    def of_shape(
        cls, name: str, kind: RegionKind, shape: Shape, part_of: str | None = None
    ) -> Region:
        """A region of ``shape``, with its bounding box."""
        if isinstance(shape, Prism):
            v = np.asarray(shape.vertices_xy)
            lo_xy, hi_xy = v.min(axis=0), v.max(axis=0)
        else:
            c = np.asarray(shape.center_xy)
            lo_xy, hi_xy = c - shape.radius_m, c + shape.radius_m
        lo = (float(lo_xy[0]), float(lo_xy[1]), float(shape.z_lo_m))
        hi = (float(hi_xy[0]), float(hi_xy[1]), float(shape.z_hi_m))
        return cls(name, kind, lo, hi, shape, part_of)

    @classmethod
    def turned_box(
        cls, name: str, kind: RegionKind, center_enu_m: Any, half_size_m: Any, yaw_rad: float
    ) -> Region:
        """A box with half-sizes ``(hx, hy, hz)`` along its own axes, turned ``yaw_rad`` about
        the vertical: a prism (:meth:`Prism.oriented_box`), or, turned by a multiple of 90
        degrees, the axis-aligned box itself (the planner's plainest form)."""
        c = np.asarray(center_enu_m, dtype=float)
        h = np.asarray(half_size_m, dtype=float)
        cos, sin = math.cos(yaw_rad), math.sin(yaw_rad)
        if abs(cos) > 1.0 - 1e-12 or abs(sin) > 1.0 - 1e-12:
            if abs(sin) > 0.5:  # a quarter turn: its x half-size lies along north
                h = np.array([h[1], h[0], h[2]])
            return cls(name, kind, tuple((c - h).tolist()), tuple((c + h).tolist()))
        return cls.of_shape(name, kind, Prism.oriented_box(c, h, yaw_rad))

    @property
    def center_enu_m(self) -> np.ndarray:
        """Centre of the region, shape (3,): of the box, the polygon's vertex mean, the axis."""
        if isinstance(self.shape, Prism):
            xy = np.asarray(self.shape.vertices_xy).mean(axis=0)
            return np.array([xy[0], xy[1], 0.5 * (self.shape.z_lo_m + self.shape.z_hi_m)])
        if isinstance(self.shape, Cylinder):
            c = self.shape.center_xy
            return np.array([c[0], c[1], 0.5 * (self.shape.z_lo_m + self.shape.z_hi_m)])
        return (np.asarray(self.lo_enu_m) + np.asarray(self.hi_enu_m)) / 2.0

    def face_margins(self, pos_enu_m: np.ndarray) -> np.ndarray:
        """Signed margin of points to each face, shape (n, faces); >= 0 inside that face."""
        p = np.asarray(pos_enu_m, dtype=float).reshape(-1, 3)
        z = p[:, 2:3]
        s = self.shape
        if isinstance(s, Prism):
            walls = np.asarray(s.offsets_m) - p[:, :2] @ np.asarray(s.normals_xy).T
            return np.concatenate([walls, z - s.z_lo_m, s.z_hi_m - z], axis=1)
        if isinstance(s, Cylinder):
            radial = s.radius_m - np.linalg.norm(p[:, :2] - np.asarray(s.center_xy), axis=1)
            return np.column_stack([radial, z[:, 0] - s.z_lo_m, s.z_hi_m - z[:, 0]])
        return np.concatenate([p - np.asarray(self.lo_enu_m), np.asarray(self.hi_enu_m) - p], 1)

    def margin(self, pos_enu_m: np.ndarray) -> np.ndarray:
        """The region's margin at each point, shape (n,) (module docstring): > 0 inside."""
        if self.shape is not None:
            return self.face_margins(pos_enu_m).min(axis=1)
        # a box per axis first (four times faster on long signals)
        p = np.asarray(pos_enu_m, dtype=float).reshape(-1, 3)
        d = np.minimum(p - np.asarray(self.lo_enu_m), np.asarray(self.hi_enu_m) - p)
        return np.minimum(np.minimum(d[:, 0], d[:, 1]), d[:, 2])

    def contains(self, pos_enu_m: np.ndarray) -> np.ndarray:
        """Whether each point (shape (n, 3) or (3,)) lies in the closed region."""
        p = np.asarray(pos_enu_m, dtype=float)
        inside = self.margin(p.reshape(-1, 3)) >= 0.0
        return inside if p.ndim > 1 else inside[0]

    @property
    def faces(self) -> int:
        """How many face margins its margin is the smallest of."""
        if isinstance(self.shape, Prism):
            return self.shape.walls + 2
        return 3 if isinstance(self.shape, Cylinder) else 6

    @property
    def min_half_m(self) -> float:
        """The smallest half-size: a box's smallest half side; a prism's half height or the
        radius of the largest circle in its polygon; a cylinder's half height or radius."""
        s = self.shape
        if s is None:
            return float(np.min(np.subtract(self.hi_enu_m, self.lo_enu_m))) / 2.0
        half_h = 0.5 * (s.z_hi_m - s.z_lo_m)
        if isinstance(s, Cylinder):
            return min(half_h, s.radius_m)
        return min(half_h, s.inradius_m)

    def half_spaces(self, outer: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """``(A (m, 3), b (m,))`` with unit normals: the region as ``A p <= b``; a cylinder
        as the prism over the regular polygon inscribed in its circle (``outer``: the one
        circumscribed about it, for a keep-out)."""
        s = self.shape
        up, down = np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, -1.0]])
        if s is None:
            eye = np.eye(3)
            return np.vstack([eye, -eye]), np.concatenate(
                [self.hi_enu_m, -np.asarray(self.lo_enu_m)]
            )
        if isinstance(s, Prism):
            n, off = np.asarray(s.normals_xy), np.asarray(s.offsets_m)
        else:
            n, off = _polygon_sides(np.asarray(s.center_xy), s.radius_m, outer)
        walls = np.column_stack([n, np.zeros(len(n))])
        return np.vstack([walls, up, down]), np.concatenate([off, [s.z_hi_m, -s.z_lo_m]])

    def footprint_xy(self, sides: int = 48) -> np.ndarray:
        """The region's outline seen from above, (m, 2) counter-clockwise (a cylinder's as a
        ``sides``-gon through its circle)."""
        s = self.shape
        if isinstance(s, Prism):
            return np.asarray(s.vertices_xy, dtype=float)
        if isinstance(s, Cylinder):
            a = np.arange(sides) * 2.0 * np.pi / sides
            return np.asarray(s.center_xy) + s.radius_m * np.column_stack([np.cos(a), np.sin(a)])
        (x0, y0, _), (x1, y1, _) = self.lo_enu_m, self.hi_enu_m
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)

    # -- the parameters of the planner's templates (planner.solve.leaf_templates) -------------

    @property
    def signature(self) -> tuple[Any, ...]:
        """What kind of parameters :meth:`params` holds (the same for regions one template
        can take: boxes; prisms of as many walls; cylinders)."""
        if isinstance(self.shape, Prism):
            return ("prism", self.shape.walls)
        return ("cylinder",) if isinstance(self.shape, Cylinder) else ("box",)

    def params(self) -> np.ndarray:
        """The numbers that place it: a box ``lo, hi``; a prism its normals (row by row),
        offsets, floor and roof; a cylinder ``cx, cy, r, z_lo, z_hi``."""
        s = self.shape
        if isinstance(s, Prism):
            return np.concatenate(
                [np.ravel(s.normals_xy), s.offsets_m, [s.z_lo_m, s.z_hi_m]]
            ).astype(float)
        if isinstance(s, Cylinder):
            return np.array([*s.center_xy, s.radius_m, s.z_lo_m, s.z_hi_m], dtype=float)
        return np.concatenate([self.lo_enu_m, self.hi_enu_m]).astype(float)

    @staticmethod
    def params_size(signature: tuple[Any, ...]) -> int:
        """Length of :meth:`params` for a signature."""
        if signature[0] == "prism":
            return 3 * int(signature[1]) + 2
        return 5 if signature[0] == "cylinder" else 6

    @classmethod
    def symbolic(cls, name: str, signature: tuple[Any, ...], p: Any) -> Region:
        """A region whose numbers are the entries of ``p`` (CasADi symbols, in
        :meth:`params` order): what the predicates' CasADi code is fed in a template."""
        if signature[0] == "prism":
            m = int(signature[1])
            normals = ca_reshape_rows(p[: 2 * m], m, 2)
            prism = Prism((), normals, p[2 * m : 3 * m], p[3 * m], p[3 * m + 1])
            return cls(name, RegionKind.REGION, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), prism)
        if signature[0] == "cylinder":
            cyl = Cylinder((p[0], p[1]), p[2], p[3], p[4])
            return cls(name, RegionKind.REGION, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), cyl)
        return cls(name, RegionKind.REGION, p[0:3], p[3:6])


def ca_reshape_rows(v: Any, rows: int, cols: int) -> Any:
    """A CasADi column holding a ``(rows, cols)`` matrix row by row, as that matrix."""
    import casadi as ca

    return ca.reshape(v, cols, rows).T


def chebyshev_ball(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray | None, float]:
    """Centre and radius of the largest ball in ``A p <= b`` (any dimension; an LP, HiGHS);
    ``(None, 0)`` when there is none (empty or unbounded)."""

    A = np.asarray(A, dtype=float)
    dim = A.shape[1]
    res = linprog(
        np.concatenate([np.zeros(dim), [-1.0]]),
        A_ub=np.column_stack([A, np.linalg.norm(A, axis=1)]),
        b_ub=np.asarray(b, dtype=float),
        bounds=[(None, None)] * dim + [(0.0, None)],
        method="highs",
    )
    if res.status != 0:
        return None, 0.0
    return np.asarray(res.x[:dim]), float(res.x[dim])
