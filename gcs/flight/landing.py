"""Where a vehicle may land at the end of its plan: straight down unless that crosses a keep-out.

``gcs fly --end land`` (offboard and mission) and ``gcs upload --end land`` land each vehicle
where its plan ends, unless the column below it, widened by :data:`CLEARANCE_M` (the drift of
a descent), meets a region that is a keep-out by kind
(obstacle, no-fly zone, pole, conductor): a drone that ends its inspection beside a pole or
above a conductor must not descend there.  Then the vehicle first flies, at the altitude it
ends at, to the nearest point whose column is clear and to which the straight transit at that
altitude is clear too (inside the workspace's footprint), and lands there.  Candidates: the
vehicle's planned start (a place it stood), then rings of points around the end, nearest
first, up to :data:`SEARCH_M`.  When none is clear, :func:`landing_point` says so and the
caller refuses ``--end land`` before anything flies.

Geometry is the mission frame (ENU metres). A keep-out is taken as it is: an axis-aligned box
(grown by the clearance on every side), a prism over a convex polygon (an oriented box among
them: its walls moved out by the clearance, its margin ``> -CLEARANCE_M``) or a vertical
cylinder (its radius grown by the clearance); never its bounding box, which would block the
empty corners around a turned box or a pole.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gcs.errors import UserError
from planner.spec.regions import KEEP_OUT_KINDS, Cylinder, Prism, Region

if TYPE_CHECKING:
    from planner.planfile import Plan

#: Horizontal clearance from a keep-out, for the descent and for the transit, m. It
#: covers a descent's drift (the px4 mock's vehicles land within 0.5 m of where they began
#: it: tests/mavlink/test_mock_mavsdk.py), not a vehicle that ended its plan off track: the
#: landing point is chosen from the plan's end, and the tracking alarm (``gcs fly
#: --max-off-plan``) is what bounds how far from it a vehicle can be.
CLEARANCE_M = 0.5
#: How far from the plan's end a landing point is looked for, m.
SEARCH_M = 60.0
_RING_STEP_M = 0.5
_RING_POINTS = 32


@dataclass(frozen=True, slots=True)
class LandingPoint:
    """Where one vehicle lands.

    Attributes:
        vehicle: its name.
        end_enu_m: where its plan ends (mission ENU).
        point_enu_m: where it lands: horizontally the landing point, vertically the altitude
            of the transit (the end's); equal to ``end_enu_m`` when it lands straight down.
        blocked_by: the keep-out below the end (``None``: the column is clear).
        found: a clear point was found (always, when nothing blocks the end).
    """

    vehicle: str
    end_enu_m: np.ndarray
    point_enu_m: np.ndarray
    blocked_by: Region | None
    found: bool

    @property
    def moved_m(self) -> float:
        """Horizontal distance from the end to the landing point."""
        return float(np.hypot(*(self.point_enu_m[:2] - self.end_enu_m[:2])))

    def describe(self) -> str:
        """One line for the operator (empty when it lands straight down)."""
        if self.blocked_by is None:
            return ""
        r = self.blocked_by
        below = f"straight down from its plan's end would pass {r.kind.value} {r.name!r}"
        if not self.found:
            return (
                f"{self.vehicle}: {below}, and no clear landing point lies within "
                f"{SEARCH_M:g} m at {CLEARANCE_M:g} m from every keep-out"
            )
        e, n = self.point_enu_m[:2] - self.end_enu_m[:2]
        return (
            f"{self.vehicle}: {below}; it flies {self.moved_m:.1f} m ({_bearing(e, n)}) at "
            f"{self.point_enu_m[2]:.1f} m to land clear of it"
        )


def keep_outs(plan: Plan) -> tuple[Region, ...]:
    """The plan's regions a vehicle must keep out of."""
    return tuple(r for r in plan.regions if r.kind in KEEP_OUT_KINDS)


def _wall_margins(r: Region, xy: np.ndarray) -> np.ndarray:
    """Signed horizontal margins of points ``(n, 2)`` to a shaped region's walls, ``(n, k)``
    (a prism's ``k`` walls, a cylinder's mantle): > 0 inside each (:meth:`Region.face_margins`
    without floor and roof)."""
    p = np.asarray(xy, dtype=float).reshape(-1, 2)
    z = 0.5 * (r.lo_enu_m[2] + r.hi_enu_m[2])  # level with it: only the walls count here
    faces = r.face_margins(np.column_stack([p, np.full(len(p), z)]))
    walls = r.shape.walls if isinstance(r.shape, Prism) else 1
    return faces[:, :walls]


def column_blocker(xy: np.ndarray, top_m: float, boxes: tuple[Region, ...]) -> Region | None:
    """The first keep-out whose footprint (widened by the clearance) holds ``xy`` and which
    reaches down below ``top_m``: a descent from ``top_m`` to the ground would meet it.

    A box's footprint is widened by the clearance on every side; a prism's or cylinder's holds
    ``xy`` where its horizontal margin is ``>= -CLEARANCE_M`` (walls moved out, radius grown)."""
    for r in boxes:
        lo, hi = np.asarray(r.lo_enu_m), np.asarray(r.hi_enu_m)
        if r.shape is None:
            inside = bool(np.all(xy >= lo[:2] - CLEARANCE_M) and np.all(xy <= hi[:2] + CLEARANCE_M))
        else:
            inside = bool(_wall_margins(r, xy).min() >= -CLEARANCE_M)
        if inside and lo[2] <= top_m:
            return r
    return None


def transit_clear(a: np.ndarray, b: np.ndarray, z_m: float, boxes: tuple[Region, ...]) -> bool:
    """True if the straight horizontal flight ``a`` -> ``b`` (xy) at ``z_m`` keeps the
    clearance from every keep-out it is level with (a keep-out wholly below or above ``z_m``
    is passed over or under).

    Exact for each shape: the slab test of the segment against a box widened horizontally;
    the same clipping against a prism's walls moved out by the clearance (Cyrus-Beck); the
    segment's distance to a cylinder's axis against its radius plus the clearance."""
    d = b - a
    for r in boxes:
        if not r.lo_enu_m[2] <= z_m <= r.hi_enu_m[2]:
            continue
        if isinstance(r.shape, Cylinder):
            if _segment_distance(a, d, np.asarray(r.shape.center_xy)) <= (
                r.shape.radius_m + CLEARANCE_M
            ):
                return False
            continue
        if isinstance(r.shape, Prism):
            normals = np.asarray(r.shape.normals_xy)
            offsets = np.asarray(r.shape.offsets_m) + CLEARANCE_M
        else:
            lo = np.asarray(r.lo_enu_m) - CLEARANCE_M
            hi = np.asarray(r.hi_enu_m) + CLEARANCE_M
            normals = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
            offsets = np.array([hi[0], hi[1], -lo[0], -lo[1]])
        if _segment_meets(a, d, normals, offsets):
            return False
    return True


def _segment_meets(a: np.ndarray, d: np.ndarray, normals: np.ndarray, offsets: np.ndarray) -> bool:
    """Whether the segment ``a + t d``, ``t`` in [0, 1], meets the closed convex polygon
    ``normals @ p <= offsets`` (clipping ``t`` against each side)."""
    t0, t1 = 0.0, 1.0
    for n, off in zip(normals, offsets, strict=True):
        room = float(off - n @ a)  # >= 0: a is on the inner side
        rate = float(n @ d)
        if abs(rate) < 1e-12:
            if room < 0.0:
                return False
            continue
        if rate > 0.0:
            t1 = min(t1, room / rate)
        else:
            t0 = max(t0, room / rate)
        if t0 > t1:
            return False
    return True


def _segment_distance(a: np.ndarray, d: np.ndarray, c: np.ndarray) -> float:
    """Distance from the point ``c`` to the segment ``a + t d``, ``t`` in [0, 1]."""
    dd = float(d @ d)
    t = 0.0 if dd < 1e-24 else min(max(float((c - a) @ d) / dd, 0.0), 1.0)
    return float(np.hypot(*(a + t * d - c)))


def landing_point(plan: Plan, name: str) -> LandingPoint:
    """Where vehicle ``name`` of ``plan`` lands with ``--end land`` (module docstring)."""
    pv = next(v for v in plan.vehicles if v.name == name)
    end = np.asarray(pv.trajectory.position(np.array([pv.trajectory.duration_s]))[0], float)
    boxes = keep_outs(plan)
    blocker = column_blocker(end[:2], end[2], boxes)
    if blocker is None:
        return LandingPoint(name, end, end.copy(), None, True)
    ws = plan.workspace
    z = float(end[2])

    def usable(xy: np.ndarray) -> bool:
        in_ws = bool(np.all(xy >= np.asarray(ws.lo_enu_m)[:2]) and np.all(xy <= np.asarray(ws.hi_enu_m)[:2]))  # fmt: skip
        return (
            in_ws and column_blocker(xy, z, boxes) is None and transit_clear(end[:2], xy, z, boxes)
        )

    start = np.asarray(pv.start_enu_m, dtype=float)[:2]
    best: np.ndarray | None = None
    angles = np.arange(_RING_POINTS) * (2.0 * math.pi / _RING_POINTS)
    for r in np.arange(_RING_STEP_M, SEARCH_M + 1e-9, _RING_STEP_M):
        if usable(start) and float(np.hypot(*(start - end[:2]))) <= r:
            best = start
            break
        ring = end[:2] + r * np.column_stack([np.cos(angles), np.sin(angles)])
        ok = [q for q in ring if usable(q)]
        if ok:
            best = ok[0]
            break
    if best is None:
        return LandingPoint(name, end, end.copy(), blocker, False)
    return LandingPoint(name, end, np.array([best[0], best[1], z]), blocker, True)


def landing_points(plan: Plan) -> dict[str, LandingPoint]:
    """:func:`landing_point` of every vehicle of ``plan``."""
    return {v.name: landing_point(plan, v.name) for v in plan.vehicles}


def _checked(plan: Plan) -> dict[str, LandingPoint]:
    """:func:`landing_points`; UserError (``--end land`` refused) if one found none."""

    points = landing_points(plan)
    for lp in points.values():
        if not lp.found:
            raise UserError(f"--end land: {lp.describe()}; end with hold or return instead")
    return points


def landing_targets(plan: Plan) -> dict[str, np.ndarray]:
    """Per vehicle that must not land straight down at its plan's end, where it lands
    instead (mission ENU).

    Raises:
        gcs.errors.UserError: a vehicle with no clear landing point (land refused).
    """
    return {n: lp.point_enu_m for n, lp in _checked(plan).items() if lp.blocked_by is not None}


def landing_lines(plan: Plan) -> list[str]:
    """What ``gcs fly`` / ``gcs upload --end land`` tell the operator before they start:
    one line per vehicle that lands elsewhere than below its plan's end.

    Raises:
        gcs.errors.UserError: a vehicle with no clear landing point (land refused).
    """
    return [f"landing: {lp.describe()}" for lp in _checked(plan).values() if lp.describe()]


def _bearing(east: float, north: float) -> str:
    names = ("north", "north-east", "east", "south-east", "south", "south-west", "west", "north-west")  # fmt: skip
    deg = math.degrees(math.atan2(east, north)) % 360.0
    return names[round(deg / 45.0) % 8]
