"""The geofence: the workspace and full-height keep-out regions as PX4 ``FENCE`` items.

A geofence (``FENCE`` items) is built from the workspace box (inclusion polygon) and the
keep-out regions that span the workspace's height (exclusions): a box becomes a 4-vertex
polygon, a prism (a convex polygon extruded, an oriented box among them) the polygon of its
corners, a vertical cylinder an exclusion circle. PX4 fences are 2-D (polygons and circles
without floor or ceiling); the workspace's height limits are not expressed by them (PX4 takes
those from the ``GF_MAX_VER_DIST`` parameter).

A room of its own because the fence is a plan of its own (mission type FENCE), built from
the scenario's regions rather than from a trajectory; like the mission's items it is pure
computation. Regions are read by duck typing (``name``, ``kind.value``, ``lo_enu_m``,
``hi_enu_m`` and ``shape``: ``None``, an object with ``vertices_xy`` or one with
``center_xy`` and ``radius_m``, as :class:`planner.spec.regions.Region` has them), since the
package uses nothing of ``planner`` but its frames, trajectories and STL semantics.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mavlink.mission.items import Cmd, Frame, MissionItem, MissionType, deg_e7
from planner.frames import GeodeticPoint, enu_to_geodetic


@dataclass(frozen=True, slots=True)
class FenceBox:
    """An axis-aligned box of the mission frame, as a fence polygon (its footprint).

    Attributes:
        name: region name (for messages).
        lo_enu_m, hi_enu_m: corners (only x/y are used: PX4 fences are 2-D).
        inclusion: True for the workspace (stay inside), False for a no-fly zone.
    """

    name: str
    lo_enu_m: tuple[float, float, float]
    hi_enu_m: tuple[float, float, float]
    inclusion: bool

    def vertices_xy(self) -> np.ndarray:
        """The footprint's corners, (4, 2), counter-clockwise from the south-west one."""
        (x0, y0, _), (x1, y1, _) = self.lo_enu_m, self.hi_enu_m
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)

    def distance_m(self, pos_xy: np.ndarray) -> np.ndarray:
        """Horizontal distance of points ``(n, 2)`` (mission ENU, m) to the footprint,
        ``(n,)``: 0 inside."""
        p = np.asarray(pos_xy, dtype=float).reshape(-1, 2)
        (x0, y0, _), (x1, y1, _) = self.lo_enu_m, self.hi_enu_m
        dx = np.maximum(np.maximum(x0 - p[:, 0], 0.0), p[:, 0] - x1)
        dy = np.maximum(np.maximum(y0 - p[:, 1], 0.0), p[:, 1] - y1)
        return np.hypot(dx, dy)


@dataclass(frozen=True, slots=True)
class FencePolygon:
    """A convex polygon of the mission frame as a fence polygon (a prism's footprint).

    Attributes:
        name: region name (for messages).
        corners_xy: the polygon's corners, ``(m, 2)`` as tuples, ENU metres, in order.
        inclusion: True to stay inside, False for a no-fly zone.
    """

    name: str
    corners_xy: tuple[tuple[float, float], ...]
    inclusion: bool

    def vertices_xy(self) -> np.ndarray:
        """The corners, (m, 2)."""
        return np.asarray(self.corners_xy, dtype=float).reshape(-1, 2)

    def distance_m(self, pos_xy: np.ndarray) -> np.ndarray:
        """Horizontal distance of points ``(n, 2)`` to the (convex) polygon, ``(n,)``: 0
        inside, else the distance to the nearest side."""
        p = np.asarray(pos_xy, dtype=float).reshape(-1, 2)
        a = self.vertices_xy()
        e = np.roll(a, -1, axis=0) - a  # (m, 2) sides
        rel = p[:, None, :] - a[None, :, :]  # (n, m, 2)
        cross = e[None, :, 0] * rel[:, :, 1] - e[None, :, 1] * rel[:, :, 0]
        area2 = float(np.sum(a[:, 0] * np.roll(a[:, 1], -1) - np.roll(a[:, 0], -1) * a[:, 1]))
        inside = np.all(cross * np.sign(area2) >= 0.0, axis=1)
        s = np.clip(np.einsum("nmk,mk->nm", rel, e) / np.einsum("mk,mk->m", e, e), 0.0, 1.0)
        gap = np.linalg.norm(rel - s[:, :, None] * e[None, :, :], axis=2).min(axis=1)
        return np.where(inside, 0.0, gap)


@dataclass(frozen=True, slots=True)
class FenceCircle:
    """A circle of the mission frame as a fence circle (a vertical cylinder's footprint).

    Attributes:
        name: region name (for messages).
        center_xy: centre, ENU metres.
        radius_m: radius, m (> 0).
        inclusion: True to stay inside, False for a no-fly zone.
    """

    name: str
    center_xy: tuple[float, float]
    radius_m: float
    inclusion: bool

    def distance_m(self, pos_xy: np.ndarray) -> np.ndarray:
        """Horizontal distance of points ``(n, 2)`` to the disc, ``(n,)``: 0 inside."""
        p = np.asarray(pos_xy, dtype=float).reshape(-1, 2)
        r = np.linalg.norm(p - np.asarray(self.center_xy, dtype=float), axis=1)
        return np.maximum(r - self.radius_m, 0.0)


#: One zone of a geofence.
FenceZone = FenceBox | FencePolygon | FenceCircle


def braking_distance_m(speed_m_s: float, acc_hor_m_s2: float = 3.0) -> float:
    """The braking distance PX4's predictive geofence looks ahead at ``speed_m_s``:
    ``v * (v / (2 MPC_ACC_HOR) + 0.6)`` (as :mod:`mavlink.mock.navigator` models it)."""
    v = max(0.0, float(speed_m_s))
    return v * (v / (2.0 * acc_hor_m_s2) + 0.6)


def fence_zones(
    workspace: Any,
    regions: Sequence[Any],
    exclude_kinds: Sequence[str] = ("obstacle", "no_fly", "pole"),
    *,
    inflate_m: float = 0.0,
) -> tuple[FenceZone, ...]:
    """Fence zones of a scenario: the workspace to stay in, full-height keep-outs to avoid.

    PX4's fence polygons and circles are vertical prisms and cylinders without floor or
    ceiling. A keep-out becomes an exclusion only when it spans the workspace's whole height:
    there its fence zone and the region agree inside the workspace. A lower one (an obstacle
    the plan may legally fly over) is left out, because its zone would forbid paths the spec
    allows; the plan's own checks cover it. The workspace's height cannot be expressed by
    polygons either (PX4 bounds altitude with the GF_MAX_VER_DIST parameter instead).

    Args:
        workspace: a :class:`planner.spec.regions.Region` (``name``, ``lo_enu_m``, ``hi_enu_m``;
            always an axis-aligned box).
        regions: the scenario's other regions; those whose ``kind.value`` is in
            ``exclude_kinds`` and that span the workspace's height become exclusions: a box
            a :class:`FenceBox`, a prism (``shape.vertices_xy``) a :class:`FencePolygon` of
            its corners, a cylinder (``shape.center_xy``, ``shape.radius_m``) a
            :class:`FenceCircle`.
        inflate_m: widen the workspace's polygon by this much on every side: PX4's fence is
            predictive (it fires when the braking distance would cross it), so a fence on
            the workspace's edge stops a plan that flies towards the edge at speed
            (:func:`braking_distance_m`). Exclusions are never shrunk (they stay exact).
    """
    ws_lo_z, ws_hi_z = float(workspace.lo_enu_m[2]), float(workspace.hi_enu_m[2])
    widen = np.array([inflate_m, inflate_m, 0.0])
    lo = _xyz(np.asarray(workspace.lo_enu_m, dtype=float) - widen)
    hi = _xyz(np.asarray(workspace.hi_enu_m, dtype=float) + widen)
    out: list[FenceZone] = [FenceBox(workspace.name, lo, hi, inclusion=True)]
    for r in regions:
        # a shaped region's lo/hi are its bounding box: its z range is the shape's own
        full_height = r.lo_enu_m[2] <= ws_lo_z and r.hi_enu_m[2] >= ws_hi_z
        if r.kind.value not in exclude_kinds or not full_height:
            continue
        shape = getattr(r, "shape", None)
        if shape is None:
            out.append(FenceBox(r.name, _xyz(r.lo_enu_m), _xyz(r.hi_enu_m), inclusion=False))
        elif hasattr(shape, "vertices_xy"):
            corners = tuple((float(x), float(y)) for x, y in shape.vertices_xy)
            out.append(FencePolygon(r.name, corners, inclusion=False))
        elif hasattr(shape, "radius_m"):
            c = shape.center_xy
            centre = (float(c[0]), float(c[1]))
            out.append(FenceCircle(r.name, centre, float(shape.radius_m), inclusion=False))
        else:
            raise TypeError(f"region {r.name!r}: unknown shape {type(shape).__name__}")
    return tuple(out)


#: The name of :func:`fence_zones` from when every zone was a box (kept for its callers).
fence_boxes = fence_zones


def geofence_items(zones: Sequence[FenceZone], origin: GeodeticPoint) -> tuple[MissionItem, ...]:
    """FENCE items: one polygon per box (4 vertices, counter-clockwise from the south-west
    corner) or polygon zone (its corners), then one item per circle.

    The circles come after every polygon, in the order of ``zones``: the order in which a
    QGroundControl plan file holds them (``geoFence.polygons``, then ``circles``), so an
    exported fence imports back item for item. A circle's ``param1`` is its radius (m) and
    ``x``/``y`` its centre.
    """
    items: list[MissionItem] = []
    polygons = [z for z in zones if not isinstance(z, FenceCircle)]
    circles = [z for z in zones if isinstance(z, FenceCircle)]
    for zone in polygons:
        xy = zone.vertices_xy()
        corners = np.column_stack([xy, np.zeros(len(xy))])
        lat, lon, _alt = enu_to_geodetic(corners, origin)
        cmd = (
            Cmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION
            if zone.inclusion
            else Cmd.NAV_FENCE_POLYGON_VERTEX_EXCLUSION
        )
        for k in range(len(xy)):
            items.append(
                _fence_item(len(items), cmd, float(len(xy)), lat[k], lon[k])  # vertex count
            )
    for circle in circles:
        cx, cy = circle.center_xy
        lat, lon, _alt = enu_to_geodetic(np.array([[cx, cy, 0.0]]), origin)
        cmd = Cmd.NAV_FENCE_CIRCLE_INCLUSION if circle.inclusion else Cmd.NAV_FENCE_CIRCLE_EXCLUSION
        items.append(_fence_item(len(items), cmd, float(circle.radius_m), lat[0], lon[0]))
    return tuple(items)


def _fence_item(seq: int, cmd: Cmd, param1: float, lat_deg: float, lon_deg: float) -> MissionItem:
    return MissionItem(
        seq=seq,
        frame=Frame.GLOBAL_INT,
        command=cmd,
        current=1 if seq == 0 else 0,
        autocontinue=1,
        param1=param1,  # a vertex's polygon size, or a circle's radius
        param2=0.0,  # inclusion group
        param3=0.0,
        param4=0.0,
        x=deg_e7(lat_deg),
        y=deg_e7(lon_deg),
        z=0.0,
        mission_type=MissionType.FENCE,
    )


def _xyz(corner: Sequence[float] | np.ndarray) -> tuple[float, float, float]:
    return (float(corner[0]), float(corner[1]), float(corner[2]))
