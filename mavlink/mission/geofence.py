"""The geofence: the workspace and full-height no-fly boxes as PX4 ``FENCE`` items.

A geofence (``FENCE`` items) is built from the workspace box (inclusion
polygon) and no-fly boxes (exclusion polygons). PX4 fences are 2-D
polygons; the workspace's height limits are not expressed by them (PX4 takes
those from the ``GF_MAX_VER_DIST`` parameter).

A room of its own because the fence is a plan of its own (mission type FENCE), built from
the scenario's regions rather than from a trajectory; like the mission's items it is pure
computation.
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


def braking_distance_m(speed_m_s: float, acc_hor_m_s2: float = 3.0) -> float:
    """The braking distance PX4's predictive geofence looks ahead at ``speed_m_s``:
    ``v * (v / (2 MPC_ACC_HOR) + 0.6)`` (as :mod:`mavlink.mock.navigator` models it)."""
    v = max(0.0, float(speed_m_s))
    return v * (v / (2.0 * acc_hor_m_s2) + 0.6)


def fence_boxes(
    workspace: Any,
    regions: Sequence[Any],
    exclude_kinds: Sequence[str] = ("obstacle", "no_fly", "pole"),
    *,
    inflate_m: float = 0.0,
) -> tuple[FenceBox, ...]:
    """Fence boxes of a scenario: the workspace to stay in, full-height stay-out boxes to avoid.

    PX4's fence polygons are vertical prisms without floor or ceiling. A stay-out box becomes an
    exclusion polygon only when it spans the workspace's whole height: there its prism and the
    box agree inside the workspace. A lower box (an obstacle the plan may legally fly over) is
    left out, because its prism would forbid paths the spec allows; the plan's own checks cover
    it. The workspace's height cannot be expressed by polygons either (PX4 bounds altitude with
    the GF_MAX_VER_DIST parameter instead).

    Args:
        workspace: a :class:`planner.regions.Region` (``name``, ``lo_enu_m``, ``hi_enu_m``).
        regions: the scenario's other regions; those whose ``kind.value`` is in
            ``exclude_kinds`` and that span the workspace's height become exclusion polygons.
        inflate_m: widen the workspace's polygon by this much on every side: PX4's fence is
            predictive (it fires when the braking distance would cross it), so a fence on
            the workspace's edge stops a plan that flies towards the edge at speed
            (:func:`braking_distance_m`). Exclusions are never shrunk (they stay exact).
    """
    ws_lo_z, ws_hi_z = float(workspace.lo_enu_m[2]), float(workspace.hi_enu_m[2])
    widen = np.array([inflate_m, inflate_m, 0.0])
    lo = _xyz(np.asarray(workspace.lo_enu_m, dtype=float) - widen)
    hi = _xyz(np.asarray(workspace.hi_enu_m, dtype=float) + widen)
    out = [FenceBox(workspace.name, lo, hi, inclusion=True)]
    for r in regions:
        full_height = r.lo_enu_m[2] <= ws_lo_z and r.hi_enu_m[2] >= ws_hi_z
        if r.kind.value in exclude_kinds and full_height:
            out.append(FenceBox(r.name, _xyz(r.lo_enu_m), _xyz(r.hi_enu_m), inclusion=False))
    return tuple(out)


def geofence_items(boxes: Sequence[FenceBox], origin: GeodeticPoint) -> tuple[MissionItem, ...]:
    """FENCE items: one 4-vertex polygon per box (counter-clockwise from the south-west corner)."""
    items: list[MissionItem] = []
    for box in boxes:
        (x0, y0, _), (x1, y1, _) = box.lo_enu_m, box.hi_enu_m
        corners = np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])
        lat, lon, _alt = enu_to_geodetic(corners, origin)
        cmd = (
            Cmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION
            if box.inclusion
            else Cmd.NAV_FENCE_POLYGON_VERTEX_EXCLUSION
        )
        for k in range(4):
            items.append(
                MissionItem(
                    seq=len(items),
                    frame=Frame.GLOBAL_INT,
                    command=cmd,
                    current=1 if not items else 0,
                    autocontinue=1,
                    param1=4.0,  # vertex count of this polygon
                    param2=0.0,  # inclusion group
                    param3=0.0,
                    param4=0.0,
                    x=deg_e7(lat[k]),
                    y=deg_e7(lon[k]),
                    z=0.0,
                    mission_type=MissionType.FENCE,
                )
            )
    return tuple(items)


def _xyz(corner: Sequence[float] | np.ndarray) -> tuple[float, float, float]:
    return (float(corner[0]), float(corner[1]), float(corner[2]))
