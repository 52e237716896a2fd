"""A polygon that is not convex as convex parts that overlap: what ``inside`` of it means.

The planner's regions are convex (:class:`planner.spec.regions.Prism`): their margin is the
smallest of their wall margins, linear in the position, and the initial guess routes through
them as polytopes.  A right of way with a bend, an L-shaped no-fly area, is not.  Such a
polygon ``P`` is read as convex parts ``C_1 .. C_k`` whose union is ``P``, and ``inside(d, P)``
as ``inside(d, C_1) or .. or inside(d, C_k)`` (``outside``: ``and``), so its margin is the
largest of the parts' margins.  That margin keeps the promise of a convex region's:

* inside, a margin ``r`` puts the disc of radius ``r`` (horizontally) in one part, so in ``P``;
  it is at most the distance to ``P``'s boundary (equal wherever the deepest part reaches
  the nearest wall), never above it;
* outside, it is minus the smallest of the parts' violations, each at most the distance to
  its part, so at most the distance to ``P``.

Parts that only touch would give a seam of zero margin through the polygon's inside (an L
split at its corner square: the point 1 m inside the corner would score 0).  So the parts
*overlap*: every point inside ``P`` is inside some part, not on its edge.  The cover is built
(:func:`convex_cover`) from the cells of ``P`` cut by both edges of every reflex corner
extended into it until they meet the boundary (each cell convex: every corner of a cell is
at most a straight angle), then:

1. from each cell, the largest union of cells grown one neighbour at a time while it stays
   convex (an L: its two arms, each with the corner square);
2. for each two cells that share an edge and each crossing of cut lines inside ``P`` that no
   part holds whole, a part that does (their union where it is convex, else a convex bridge
   over the seam: a quadrilateral across the edge, a fan round the crossing);
3. parts another part contains are dropped, then any part the others make redundant,
   smallest first.

Shapely (GEOS) does the polygon work: validity, the cut lines' arrangement, unions.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely
from shapely.ops import polygonize, unary_union

from planner.spec.regions import Prism, Region, RegionKind, ShapeError

__all__ = [
    "MAX_PARTS",
    "Outline",
    "OutlineShape",
    "convex_cover",
    "crossing_fan",
    "drawn_regions",
    "part_name",
    "polygon_regions",
    "reflex_corners",
    "seam_bridge",
]

#: Relative tolerance of the geometry (times the polygon's size in metres).
_REL_TOL = 1e-9
#: The most convex parts a polygon is read as: each is a disjunct of ``inside`` of it (a
#: conjunct of ``outside``) wherever the spec names it, for every vehicle and sample.
MAX_PARTS = 32
#: The most pieces the cuts may make before the parts are grown (the growing is about
#: quadratic in them): past it the polygon is refused before the work.
_MAX_CELLS = 400


def part_name(name: str, k: int) -> str:
    """The name of part ``k`` (from 1) of the polygon called ``name``."""
    return f"{name}_part{k}"


def polygon_regions(
    name: str, kind: RegionKind, vertices_xy: Any, z_lo_m: float, z_hi_m: float
) -> tuple[Region, ...]:
    """The regions of a vertical prism over a simple polygon: the prism itself when the
    polygon is convex, else one per part of its cover (:func:`convex_cover`), named
    :func:`part_name` with :attr:`Region.part_of` ``name``.  Corners on a straight line
    through their neighbours are dropped (they change nothing).

    Raises:
        ShapeError: fewer than 3 corners, one repeated, edges that cross or touch, an empty
            height range.
    """
    v = np.asarray(vertices_xy, dtype=float)
    if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3 or not np.all(np.isfinite(v)):
        Prism.from_polygon(v, z_lo_m, z_hi_m)  # says what is wrong
    edges = np.hypot(*(np.roll(v, -1, axis=0) - v).T)
    if np.any(edges <= _tol(v)):  # convex_cover would drop it with the straight corners
        raise ShapeError("a polygon repeats a corner")
    parts = convex_cover(v)
    if len(parts) == 1:
        return (Region.of_shape(name, kind, Prism.from_polygon(parts[0], z_lo_m, z_hi_m)),)
    return tuple(
        Region.of_shape(part_name(name, k), kind, Prism.from_polygon(p, z_lo_m, z_hi_m), name)
        for k, p in enumerate(parts, start=1)
    )


@dataclass(frozen=True, slots=True)
class OutlineShape:
    """What the figures read of a polygon that is not convex: its corners (counter-clockwise,
    ``(m, 2)`` as tuples) and its floor and roof.  No walls: it has no margin of its own (its
    parts have)."""

    vertices_xy: tuple[tuple[float, float], ...]
    z_lo_m: float
    z_hi_m: float


@dataclass(frozen=True, slots=True)
class Outline:
    """A polygon that is not convex as the figures draw it: one outline over its parts,
    with what a figure reads of a region (``name``, ``kind``, ``lo_enu_m``, ``hi_enu_m``,
    ``shape``, :meth:`footprint_xy`, :attr:`center_enu_m`)."""

    name: str
    parts: tuple[Region, ...]
    #: the union of the parts' footprints, over their heights (:meth:`of_parts`)
    shape: OutlineShape

    @classmethod
    def of_parts(cls, name: str, parts: tuple[Region, ...]) -> Outline:
        """The outline of the polygon ``name`` over its parts."""

        union = shapely.union_all([shapely.Polygon(r.footprint_xy()) for r in parts])
        corners = _drop_straight(_corners(union), _tol(np.asarray(parts[0].footprint_xy())))
        z_lo = min(r.lo_enu_m[2] for r in parts)
        z_hi = max(r.hi_enu_m[2] for r in parts)
        xy = tuple((float(x), float(y)) for x, y in corners)
        return cls(name, parts, OutlineShape(xy, float(z_lo), float(z_hi)))

    @property
    def kind(self) -> RegionKind:
        return self.parts[0].kind

    @property
    def lo_enu_m(self) -> tuple[float, float, float]:
        lo = np.min([r.lo_enu_m for r in self.parts], axis=0)
        return (float(lo[0]), float(lo[1]), float(lo[2]))

    @property
    def hi_enu_m(self) -> tuple[float, float, float]:
        hi = np.max([r.hi_enu_m for r in self.parts], axis=0)
        return (float(hi[0]), float(hi[1]), float(hi[2]))

    def footprint_xy(self, sides: int = 48) -> np.ndarray:
        """The polygon's corners, counter-clockwise ``(m, 2)``."""
        return np.asarray(self.shape.vertices_xy, dtype=float)

    @property
    def center_enu_m(self) -> np.ndarray:
        """A point inside the polygon (its label's place), at mid height."""

        p = shapely.Polygon(self.footprint_xy()).representative_point()
        z = 0.5 * (self.lo_enu_m[2] + self.hi_enu_m[2])
        return np.array([p.x, p.y, z])


def drawn_regions(regions: Sequence[Region]) -> list[Region | Outline]:
    """The regions as figures draw them: each polygon's parts as one :class:`Outline` (where
    its first part was), the others as they are."""
    out: list[Region | Outline] = []
    for r in regions:
        if r.part_of is None:
            out.append(r)
        elif not any(isinstance(o, Outline) and o.name == r.part_of for o in out):
            parts = tuple(q for q in regions if q.part_of == r.part_of)
            out.append(Outline.of_parts(r.part_of, parts))
    return out


def reflex_corners(vertices_xy: Any) -> list[int]:
    """Indices of the corners of a simple polygon (either orientation) whose inside angle is
    above a straight angle."""
    v = _ccw(np.asarray(vertices_xy, dtype=float))
    e = np.roll(v, -1, axis=0) - v
    cross = np.roll(e, 1, axis=0)[:, 0] * e[:, 1] - np.roll(e, 1, axis=0)[:, 1] * e[:, 0]
    scale = np.linalg.norm(e, axis=1) * np.linalg.norm(np.roll(e, 1, axis=0), axis=1)
    return [int(i) for i in np.nonzero(cross < -_REL_TOL * scale)[0]]


def _ccw(v: np.ndarray) -> np.ndarray:
    """The corners counter-clockwise (reversed when given clockwise)."""
    area2 = float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
    return v if area2 > 0 else v[::-1].copy()


def convex_cover(vertices_xy: Any) -> list[np.ndarray]:
    """Convex parts of a simple polygon that overlap where they meet (module docstring).

    Args:
        vertices_xy: the polygon's corners, ``(m, 2)`` metres, either orientation, not
            closed (the first corner not repeated).

    Returns:
        The parts, each its corners ``(k, 2)`` counter-clockwise with no straight-angle
        corner; one part (the polygon itself) when it is convex.

    Raises:
        ShapeError: the polygon crosses or touches itself, has no area, or needs more than
            :data:`MAX_PARTS` parts.
    """

    v = np.asarray(vertices_xy, dtype=float)
    poly = shapely.Polygon(v)
    _check_simple(poly)
    v = _ccw(_drop_straight(v, _tol(v)))
    tol = _tol(v)
    if not reflex_corners(v):
        return [v]
    cells = _cells(poly, v, tol)
    if len(cells) > _MAX_CELLS:
        raise ShapeError(
            f"the polygon is too intricate to read: its {len(reflex_corners(v))} reflex corners "
            f"cut it into {len(cells)} pieces (at most {_MAX_CELLS}); give it fewer corners"
        )
    parts = _grow_parts(cells, tol)
    if len(parts) > MAX_PARTS:
        raise ShapeError(
            f"the polygon needs {len(parts)} convex parts (at most {MAX_PARTS}, each a "
            f"disjunct of every clause it is in): give it fewer reflex corners, or split it "
            f"into convex regions that overlap where they meet"
        )
    return [_drop_straight(_corners(p), tol) for p in parts]


def _check_simple(poly: Any) -> None:
    """ShapeError unless the polygon is simple (its edges do not cross or touch) with area."""

    if not poly.is_valid:
        why = shapely.is_valid_reason(poly)
        at = re.search(r"\[(\S+) (\S+)\]", why)
        where = f" at ({float(at[1]):.6g}, {float(at[2]):.6g})" if at else ""
        raise ShapeError(f"the polygon's edges cross or touch{where}: it must be simple")
    if poly.area <= 0.0:
        raise ShapeError("the polygon has no area")


def _tol(v: np.ndarray) -> float:
    return _REL_TOL * max(1.0, float(np.ptp(v, axis=0).max()))


def _drop_straight(v: np.ndarray, tol: float) -> np.ndarray:
    """The corners without those on a straight line through their neighbours (or repeated)."""
    keep = list(range(len(v)))
    changed = True
    while changed and len(keep) > 3:
        changed = False
        for j in range(len(keep)):
            a, b, c = (v[keep[(j + s) % len(keep)]] for s in (-1, 0, 1))
            ab, bc = b - a, c - b
            if abs(ab[0] * bc[1] - ab[1] * bc[0]) <= tol * (np.hypot(*ab) + np.hypot(*bc)) and (
                float(ab @ bc) >= 0.0 or np.hypot(*ab) <= tol or np.hypot(*bc) <= tol
            ):
                del keep[j]
                changed = True
                break
    return v[keep]


def _corners(p: Any) -> np.ndarray:
    """A shapely polygon's corners, counter-clockwise, not closed."""

    ring = np.asarray(shapely.get_coordinates(shapely.geometry.polygon.orient(p).exterior))
    return ring[:-1]


def _cells(poly: Any, v: np.ndarray, tol: float) -> list[Any]:
    """The polygon cut by both edges of each reflex corner, extended into it to the boundary."""

    reach = 4.0 * float(np.ptp(v, axis=0).max()) + 1.0
    cuts = []
    for i in reflex_corners(v):
        corner = v[i]
        for away in (v[i - 1], v[(i + 1) % len(v)]):  # along the incoming, the outgoing edge
            d = corner - away
            d = d / np.hypot(*d)
            ray = shapely.LineString([corner, corner + reach * d])
            hits = shapely.get_coordinates(ray.intersection(poly.exterior))
            along = (hits - corner) @ d
            ahead = along[along > 10.0 * tol]
            if ahead.size == 0:  # cannot be: a ray into a bounded polygon leaves it
                raise ShapeError("the polygon could not be cut into convex parts")
            # a hair past the boundary, so the arrangement nodes the cut there
            cuts.append(shapely.LineString([corner, corner + (ahead.min() + 100.0 * tol) * d]))
    cells = [c for c in polygonize(unary_union([poly.exterior, *cuts])) if c.area > 0]
    inside = [c for c in cells if poly.contains(c.representative_point())]
    if not all(_is_convex(c) for c in inside):
        raise ShapeError("the polygon could not be cut into convex parts")
    return inside


def _is_convex(geom: Any) -> bool:
    return bool(
        geom.geom_type == "Polygon"
        and geom.convex_hull.area - geom.area <= _REL_TOL * max(geom.area, 1.0)
    )


def _grow_parts(cells: Sequence[Any], tol: float) -> list[Any]:
    """Convex unions of cells (and bridges) covering every cell, seam and crossing."""

    n = len(cells)
    adjacent: dict[int, set[int]] = {i: set() for i in range(n)}
    seams: list[frozenset[int]] = []
    touching = shapely.STRtree(cells).query(cells, predicate="intersects")
    for i, j in zip(*touching, strict=True):
        if i < j and cells[i].intersection(cells[j]).length > 10.0 * tol:
            adjacent[int(i)].add(int(j))
            adjacent[int(j)].add(int(i))
            seams.append(frozenset((int(i), int(j))))
    crossings = _crossings(cells, tol)

    def grow(seed: Iterable[int]) -> frozenset[int] | None:
        members = set(seed)
        shape = unary_union([cells[k] for k in members])
        if not _is_convex(shape):
            return None
        while True:
            nearby = sorted(
                {j for k in members for j in adjacent[k]} - members, key=lambda j: -cells[j].area
            )
            for j in nearby:
                bigger = unary_union([shape, cells[j]])
                if _is_convex(bigger):
                    members.add(j)
                    shape = bigger
                    break
            else:
                return frozenset(members)

    unions: set[frozenset[int]] = set()
    for i in range(n):
        got = grow([i])
        if got is None:  # cannot be: a cell is convex (checked in _cells)
            raise ShapeError("the polygon could not be cut into convex parts")
        unions.add(got)
    # what a part must hold whole: each cell, each two cells along a seam, the cells round
    # each crossing; a bridge holds a seam or crossing no convex union of cells can
    needs: list[frozenset[int]] = [frozenset([i]) for i in range(n)]
    bridges: list[Any] = []
    for need in seams + [around for _p, around in crossings]:
        if any(need <= u for u in unions):
            needs.append(need)
            continue
        got = grow(need)
        if got is not None:
            unions.add(got)
            needs.append(need)
        elif len(need) == 2:
            i, j = sorted(need)
            bridges.append(seam_bridge(cells[i], cells[j]))
        else:
            point = next(p for p, around in crossings if around == need)
            bridges.append(crossing_fan(point, [cells[k] for k in sorted(need)], tol))

    # drop unions inside others, then those the rest make redundant (smallest first)
    kept = [u for u in unions if not any(u < w for w in unions)]
    area = {u: sum(cells[k].area for k in u) for u in kept}
    for u in sorted(kept, key=lambda u: (area[u], sorted(u))):
        rest = [w for w in kept if w != u]
        if all(any(need <= w for w in rest) for need in needs):
            kept = rest
    kept.sort(key=lambda u: (-area[u], sorted(u)))
    return [unary_union([cells[k] for k in u]) for u in kept] + bridges


def _crossings(cells: Sequence[Any], tol: float) -> list[tuple[np.ndarray, frozenset[int]]]:
    """Corners of cells inside the polygon (where cut lines cross), with the cells round each."""

    out: list[tuple[np.ndarray, frozenset[int]]] = []
    seen: list[np.ndarray] = []
    for c in cells:
        for p in _corners(c):
            if any(np.hypot(*(p - q)) <= 10.0 * tol for q in seen):
                continue
            seen.append(p)
            pt = shapely.Point(p)
            around = frozenset(k for k, c in enumerate(cells) if c.distance(pt) <= 10.0 * tol)
            # round a point inside the polygon the cells' angles make a full turn
            turn = sum(_angle_at(cells[k], p, tol) for k in around)
            if len(around) >= 3 and abs(turn - 2.0 * math.pi) <= 1e-6:
                out.append((p, around))
    return out


def _angle_at(cell: Any, p: np.ndarray, tol: float) -> float:
    """The cell's inside angle at ``p``: at a corner its angle, on an edge a straight one."""
    v = _corners(cell)
    d = np.hypot(v[:, 0] - p[0], v[:, 1] - p[1])
    k = int(np.argmin(d))
    if d[k] > 10.0 * tol:
        return math.pi
    a, b = v[k - 1] - v[k], v[(k + 1) % len(v)] - v[k]
    return float(np.arccos(np.clip(a @ b / (np.hypot(*a) * np.hypot(*b)), -1.0, 1.0)))


def seam_bridge(a: Any, b: Any) -> Any:
    """A convex quadrilateral over the edge two convex cells share, in their union and holding
    the edge's inside: the edge's ends, and a point into each cell straight off its middle
    (half way to the cell's far side)."""

    ends = shapely.get_coordinates(a.intersection(b))
    e0, e1 = ends[0], ends[-1]
    mid = 0.5 * (e0 + e1)
    normal = np.array([e0[1] - e1[1], e1[0] - e0[0]]) / np.hypot(*(e1 - e0))

    def off_middle(cell: Any) -> np.ndarray:
        side = 1.0 if (np.asarray(cell.centroid.coords[0]) - mid) @ normal > 0 else -1.0
        reach = 2.0 * float(np.ptp(shapely.get_coordinates(cell), axis=0).max())
        ray = shapely.LineString([mid, mid + side * reach * normal])
        return mid + 0.5 * side * ray.intersection(cell).length * normal

    return shapely.Polygon([e0, off_middle(a), e1, off_middle(b)])


def crossing_fan(point: np.ndarray, around: Sequence[Any], tol: float) -> Any:
    """A convex polygon round a point where cut lines cross, in the cells round it: a point
    along each cell edge from it, all at one distance (half the shortest edge), so they lie
    on a circle with gaps under a straight angle."""

    dirs: list[float] = []
    reach = math.inf
    for cell in around:
        v = _corners(cell)
        k = int(np.argmin(np.hypot(v[:, 0] - point[0], v[:, 1] - point[1])))
        for w in (v[k - 1], v[(k + 1) % len(v)]):
            d = w - point
            reach = min(reach, float(np.hypot(*d)))
            dirs.append(math.atan2(d[1], d[0]))
    angles = sorted(set(round(a, 12) for a in dirs))
    ring = [point + 0.5 * reach * np.array([math.cos(a), math.sin(a)]) for a in angles]
    return shapely.Polygon(ring)
