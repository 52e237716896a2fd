"""Mission items as PX4 stores them, and the comparison of a read-back with what was sent.

The MAV_CMD, MAV_FRAME and MAV_MISSION_TYPE values used by the package, what a mission
ends with, and :class:`MissionItem` (one MISSION_ITEM_INT). :func:`compare_items` checks a
read-back item by item, field by field, at the wire's precision (float32 params) and as PX4
stores items (fence items without autocontinue, yaw wrapped to [0, 360), ...).

A room of its own because every other module of the package builds, sends or compares these
items; it uses nothing else of the package.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from enum import Enum, IntEnum
from typing import Any

import numpy as np
from mavsdk.plugins.mission_raw import MissionItem as MavsdkMissionItem


class Cmd(IntEnum):
    """MAV_CMD values used here."""

    NAV_WAYPOINT = 16
    NAV_RETURN_TO_LAUNCH = 20
    NAV_LAND = 21
    NAV_TAKEOFF = 22
    DO_CHANGE_SPEED = 178
    DO_SET_ROI_LOCATION = 195
    DO_SET_ROI_NONE = 197
    DO_GIMBAL_MANAGER_PITCHYAW = 1000
    DO_GIMBAL_MANAGER_CONFIGURE = 1001
    IMAGE_START_CAPTURE = 2000
    IMAGE_STOP_CAPTURE = 2001
    NAV_FENCE_POLYGON_VERTEX_INCLUSION = 5001
    NAV_FENCE_POLYGON_VERTEX_EXCLUSION = 5002
    NAV_FENCE_CIRCLE_INCLUSION = 5003
    NAV_FENCE_CIRCLE_EXCLUSION = 5004


class Frame(IntEnum):
    """MAV_FRAME values used here."""

    MISSION = 2
    GLOBAL_INT = 5
    GLOBAL_RELATIVE_ALT_INT = 6


class MissionType(IntEnum):
    """MAV_MISSION_TYPE."""

    MISSION = 0
    FENCE = 1
    RALLY = 2


class MissionEnd(Enum):
    """What the mission ends with."""

    LAND = "land"
    RETURN = "return"
    HOLD = "hold"  # no item: PX4 holds at the last waypoint


@dataclass(frozen=True, slots=True)
class MissionItem:
    """One MISSION_ITEM_INT (lat/lon in degE7, altitude in metres, AMSL in GLOBAL_INT).

    The mock vehicle stores its own (:class:`mavlink.mock.mission.MissionItem`) on purpose: the
    vehicle's side shares only the wire with the ground station it tests.
    """

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    mission_type: int

    def to_mavsdk(self) -> MavsdkMissionItem:
        """The MAVSDK ``mission_raw.MissionItem``."""
        return MavsdkMissionItem(**{f.name: getattr(self, f.name) for f in fields(self)})

    @classmethod
    def from_mavsdk(cls, item: Any) -> MissionItem:
        """From a MAVSDK ``mission_raw.MissionItem``."""
        return cls(**{f.name: getattr(item, f.name) for f in fields(cls)})


def deg_e7(deg: float) -> int:
    return round(deg * 1e7)


#: Fields compared on read-back (``current`` is the vehicle's, not ours).
COMPARED_FIELDS = tuple(f.name for f in fields(MissionItem) if f.name != "current")
_FLOAT_FIELDS = frozenset({"param1", "param2", "param3", "param4", "z"})

#: Commands whose param4 PX4 stores as a yaw (radians wrapped to [0, 2 pi), float32).
_YAW_COMMANDS = frozenset({16, 17, 19, 21, 22})  # WAYPOINT, LOITER_UNLIM/TIME, LAND, TAKEOFF
_VERTEX_COMMANDS = frozenset({5001, 5002})  # fence polygon vertices: param1 = vertex count
_CIRCLE_COMMANDS = frozenset({5003, 5004})  # fence circles: param1 = radius
#: One frame spelled for the int and the float transfer (PX4 answers in the transfer's own).
_SAME_FRAME = {0: 0, 5: 0, 3: 3, 6: 3}
#: Float32 radians of a yaw near 2 pi carry ~2.7e-5 deg: a few of those is still "the same".
_YAW_TOLERANCE_DEG = 1e-4


def _same_value(name: str, a: float, b: float) -> bool:
    if name in _FLOAT_FIELDS:
        fa, fb = np.float32(a), np.float32(b)
        return bool(fa == fb or (np.isnan(fa) and np.isnan(fb)))
    return int(a) == int(b)


def _same_yaw(a: float, b: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs((a - b + 180.0) % 360.0 - 180.0) <= _YAW_TOLERANCE_DEG


def _stored_alike(sent: MissionItem, name: str, a: float, b: float) -> bool:
    """Whether field ``name`` read back as ``b`` is what PX4 stores for ``a`` (docs/px4-behaviour.md).

    PX4 v1.17 (``mavlink_mission.cpp``) keeps of a FENCE item only command, frame, position
    and the vertex count (``(uint16_t)(param1 + 0.5)``) or radius; of a RALLY item no params;
    it answers with autocontinue 0 for fence items and the frame of the transfer; and stores
    a waypoint's yaw as float32 radians wrapped to [0, 2 pi).
    """
    mtype, cmd = int(sent.mission_type), int(sent.command)
    if name == "frame":
        return _SAME_FRAME.get(int(a), int(a)) == _SAME_FRAME.get(int(b), int(b))
    if mtype == MissionType.FENCE:
        if name in ("autocontinue", "param2", "param3", "param4"):
            return True
        if name == "param1" and cmd in _VERTEX_COMMANDS:
            return int(a + 0.5) == int(b + 0.5)
    elif mtype == MissionType.RALLY:
        if name in ("param1", "param2", "param3", "param4"):
            return True
    elif name == "param4" and cmd in _YAW_COMMANDS:
        return _same_yaw(float(a), float(b))
    return _same_value(name, a, b)


def compare_items(
    sent: Sequence[MissionItem], back: Sequence[MissionItem], *, exact: bool = False
) -> list[str]:
    """Differences between two item lists, one line per differing field (empty: identical).

    Floats are compared at float32 precision (what MISSION_ITEM_INT carries), NaN equal to
    NaN; ``current`` is ignored. Unless ``exact``, a field also counts as equal when it reads
    back as PX4 stores it (:func:`_stored_alike`: fence autocontinue and params, rally params,
    the frame's int/float spelling, yaw modulo 360 at float32-radian precision); a position,
    command, count or any value PX4 keeps still has to match.
    """
    out: list[str] = []
    if len(sent) != len(back):
        out.append(f"{len(sent)} items sent, {len(back)} read back")
    for i, (a, b) in enumerate(zip(sent, back, strict=False)):
        for name in COMPARED_FIELDS:
            va, vb = getattr(a, name), getattr(b, name)
            same = _same_value(name, va, vb) if exact else _stored_alike(a, name, va, vb)
            if not same:
                out.append(f"item {i}: {name} sent {va!r}, read back {vb!r}")
    return out
