"""Trajectories as PX4 missions: conversion, geofence, upload, read-back, the path flown.

PX4 has no local-frame mission items, so a vehicle's mission-frame trajectory
becomes global ``*_INT`` items (DESIGN.md section 7):

* ``NAV_TAKEOFF`` to the start point (lat/lon/alt AMSL of the plan's start);
* a ``NAV_WAYPOINT`` at the start (its hold time is the plan's initial hover);
* per segment of the trajectory that moves: ``DO_CHANGE_SPEED`` to the
  straight-line length / duration of the segment, so the mission's timing
  follows the plan, then ``NAV_WAYPOINT`` at the segment's end point with
  ``acceptance_radius_m`` (param2) and, where the plan then hovers, the hover
  time as hold time (param1);
* ``NAV_LAND`` at the last point, ``NAV_RETURN_TO_LAUNCH``, or nothing (PX4
  then holds at the last waypoint).

A segment whose peak speed stays below ``hover_speed_m_s`` (or which ends
less than the acceptance radius from where it started) is a hover.

The mission flies straight legs at constant speed: :class:`PiecewiseLinearPath`
is that path as a function of time (knots at the segment boundaries, so it
meets the plan exactly at every waypoint). :func:`path_deviation` measures how
far it strays from the planned trajectory and :func:`path_robustness`
evaluates the exact STL robustness of the paths (DESIGN.md section 4), so the
mission can be judged before it is flown.

A geofence (``FENCE`` items) is built from the workspace box (inclusion
polygon) and no-fly boxes (exclusion polygons). PX4 fences are 2-D
polygons; the workspace's height limits are not expressed by them (PX4 takes
those from the ``GF_MAX_VER_DIST`` parameter).

Upload and download go through MAVSDK's ``mission_raw`` plugin (the
MISSION_COUNT / MISSION_REQUEST_INT / MISSION_ITEM_INT / MISSION_ACK
transactions with their retries); :func:`compare_items` checks a read-back
item by item, field by field, at the wire's precision (float32 params) and as PX4 stores
items (fence items without autocontinue, yaw wrapped to [0, 360), ...).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import logging
import math
import random
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, fields
from enum import Enum, IntEnum
from typing import TYPE_CHECKING, Any

import numpy as np
from mavsdk.plugins.mission_raw import MissionItem as MavsdkMissionItem
from mavsdk.plugins.mission_raw import MissionRawResult

from mavlink.errors import MissionError, MissionResult
from planner.frames import GeodeticPoint, enu_to_geodetic, yaw_enu_to_ned
from planner.trajectory import Trajectory

if TYPE_CHECKING:
    from mavlink.fleet import Vehicle, VehicleStatus
    from planner.stl.ast import Formula

log = logging.getLogger(__name__)


class Cmd(IntEnum):
    """MAV_CMD values used here."""

    NAV_WAYPOINT = 16
    NAV_RETURN_TO_LAUNCH = 20
    NAV_LAND = 21
    NAV_TAKEOFF = 22
    DO_CHANGE_SPEED = 178
    NAV_FENCE_POLYGON_VERTEX_INCLUSION = 5001
    NAV_FENCE_POLYGON_VERTEX_EXCLUSION = 5002


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
    """One MISSION_ITEM_INT (lat/lon in degE7, altitude in metres, AMSL in GLOBAL_INT)."""

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
    """Whether field ``name`` read back as ``b`` is what PX4 stores for ``a`` (PX4-BEHAVIOUR.md).

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


# --------------------------------------------------------------------------
# The piecewise-linear path a mission flies
# --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class PiecewiseLinearPath:
    """Straight legs at constant speed with holds: position linear between knots.

    Attributes:
        knots_t_s: ``(m,)`` non-decreasing times from the plan's start.
        knots_enu_m: ``(m, 3)`` mission-frame positions at those times.
    """

    knots_t_s: np.ndarray
    knots_enu_m: np.ndarray

    @property
    def duration_s(self) -> float:
        """Time of the last knot."""
        return float(self.knots_t_s[-1])

    def position(self, t_s: np.ndarray) -> np.ndarray:
        """``(n, 3)`` positions at times ``t_s`` ``(n,)`` (held before/after the knots)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        return np.column_stack(
            [np.interp(t, self.knots_t_s, self.knots_enu_m[:, a]) for a in range(3)]
        )


@dataclass(frozen=True, slots=True, eq=False)
class MissionPlan:
    """A vehicle's mission and what it means in the mission frame.

    Attributes:
        name: vehicle name.
        items: the MISSION items, ``seq`` 0..n-1.
        waypoints_enu_m: ``(k, 3)`` the NAV_WAYPOINT positions (the first is the start).
        arrival_t_s: ``(k,)`` planned arrival time at each waypoint.
        hold_s: ``(k,)`` hold time at each waypoint.
        leg_speed_m_s: ``(k-1,)`` commanded speed of each leg.
        acceptance_m: ``(k,)`` acceptance radius of each waypoint (param2).
        path: the piecewise-linear path the mission flies.
    """

    name: str
    items: tuple[MissionItem, ...]
    waypoints_enu_m: np.ndarray
    arrival_t_s: np.ndarray
    hold_s: np.ndarray
    leg_speed_m_s: np.ndarray
    acceptance_m: np.ndarray
    path: PiecewiseLinearPath


def _e7(deg: float) -> int:
    return round(deg * 1e7)


def trajectory_to_mission(
    trajectory: Trajectory,
    origin: GeodeticPoint,
    *,
    acceptance_radius_m: float = 0.3,
    hover_speed_m_s: float = 0.05,
    end: MissionEnd = MissionEnd.LAND,
    name: str | None = None,
    leg_speed_m_s: Sequence[float] | None = None,
    pass_lag_s: float = 0.0,
    land_at_enu_m: Sequence[float] | None = None,
) -> MissionPlan:
    """Convert one mission-frame trajectory into PX4 mission items (module docstring).

    Args:
        trajectory: the vehicle's planned trajectory (mission ENU frame).
        origin: geodetic origin of the mission frame.
        acceptance_radius_m: NAV_WAYPOINT acceptance radius (param2), > 0.
        hover_speed_m_s: segments slower than this everywhere are hovers.
        end: land, return to launch, or hold at the last waypoint.
        name: vehicle name (default the trajectory's).
        leg_speed_m_s: the DO_CHANGE_SPEED of each leg instead of its length / duration
            (:func:`gcs.missions.convert_plan` times them so PX4 keeps the plan's clock);
            the path and the planned arrival times stay the plan's.
        pass_lag_s: the vehicle's lag behind its setpoint (s). A waypoint flown through
            (no hold, a turn under 30 degrees) gets the radius ``lag * speed + R / 2`` if
            larger (at most 45 % of its shorter leg): PX4 accepts a waypoint by where the
            vehicle is, which trails its setpoint by the drag lag, so with a radius
            smaller than that trail the setpoint stops at the waypoint and waits.
        land_at_enu_m: with ``end`` LAND, land here (east, north; the mission frame)
            instead of below the last point: a NAV_WAYPOINT there at the last point's
            altitude, then the NAV_LAND (a multicopter's NAV_LAND descends on its way to
            its position); :mod:`gcs.landing` picks the point clear of keep-outs.

    Raises:
        MissionError: ``INVALID_ITEM`` for a non-positive acceptance radius or a speed
            list of the wrong length or with a non-positive speed.
    """
    vname = name if name is not None else trajectory.name
    if not (math.isfinite(acceptance_radius_m) and acceptance_radius_m > 0):
        raise MissionError(
            MissionResult.INVALID_ITEM,
            "trajectory_to_mission",
            f"acceptance_radius_m must be > 0, got {acceptance_radius_m!r}",
            vehicle=vname,
        )
    t0 = np.asarray(trajectory.segment_t0_s, dtype=float)
    dur = np.asarray(trajectory.segment_duration_s, dtype=float)
    bounds = np.append(t0, t0[-1] + dur[-1])
    pts = trajectory.position(bounds)
    # Peak speed per segment on a dense grid (21 points per segment).
    u = np.linspace(0.0, 1.0, 21)
    dense_t = (t0[:, None] + dur[:, None] * u[None, :]).ravel()
    speed = np.linalg.norm(trajectory.velocity(dense_t), axis=1).reshape(t0.size, u.size)
    moving = speed.max(axis=1) >= hover_speed_m_s
    lengths = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    moving &= lengths >= acceptance_radius_m

    waypoints = [pts[0]]
    arrival = [0.0]
    hold = [0.0]
    leg_speed: list[float] = []
    leg_index: list[int] = []
    for s in range(t0.size):
        if moving[s]:
            waypoints.append(pts[s + 1])
            arrival.append(float(bounds[s + 1]))
            hold.append(0.0)
            leg_speed.append(float(lengths[s] / dur[s]))
            leg_index.append(s)
        else:
            hold[-1] += float(dur[s])
    if leg_speed_m_s is not None:
        given = [float(x) for x in leg_speed_m_s]
        if len(given) != len(leg_speed) or not all(math.isfinite(x) and x > 0 for x in given):
            raise MissionError(
                MissionResult.INVALID_ITEM,
                "trajectory_to_mission",
                f"leg_speed_m_s: {len(leg_speed)} speeds > 0 wanted, got {given!r}",
                vehicle=vname,
            )
        commanded = given
    else:
        commanded = leg_speed
    wp = np.asarray(waypoints)
    radius = np.full(wp.shape[0], float(acceptance_radius_m))
    if pass_lag_s > 0:
        for j in range(1, wp.shape[0] - 1):
            a_in, a_out = wp[j] - wp[j - 1], wp[j + 1] - wp[j]
            l_in, l_out = float(np.linalg.norm(a_in)), float(np.linalg.norm(a_out))
            if hold[j] > 0 or l_in < 1e-6 or l_out < 1e-6:
                continue
            if float(np.dot(a_in, a_out)) / (l_in * l_out) < math.cos(math.radians(30.0)):
                continue
            v = min(commanded[j - 1], commanded[j])
            want = pass_lag_s * v + 0.5 * acceptance_radius_m
            radius[j] = max(radius[j], min(want, 0.45 * min(l_in, l_out)))
    lat, lon, alt = enu_to_geodetic(wp, origin)
    yaw_deg = np.degrees(
        np.asarray(yaw_enu_to_ned(trajectory.yaw_rad(np.asarray(arrival))), dtype=float)
    )

    items: list[MissionItem] = []

    def add(
        command: int,
        frame: int,
        p1: float,
        p2: float,
        p3: float,
        p4: float,
        x: int,
        y: int,
        z: float,
    ) -> None:
        items.append(
            MissionItem(
                seq=len(items),
                frame=frame,
                command=command,
                current=1 if not items else 0,  # MAVSDK requires item 0 to be current
                autocontinue=1,
                param1=p1,
                param2=p2,
                param3=p3,
                param4=p4,
                x=x,
                y=y,
                z=z,
                mission_type=MissionType.MISSION,
            )
        )

    g = Frame.GLOBAL_INT
    add(
        Cmd.NAV_TAKEOFF,
        g,
        0.0,
        0.0,
        0.0,
        float(yaw_deg[0]),
        _e7(lat[0]),
        _e7(lon[0]),
        float(alt[0]),
    )
    add(
        Cmd.NAV_WAYPOINT,
        g,
        hold[0],
        acceptance_radius_m,
        0.0,
        float(yaw_deg[0]),
        _e7(lat[0]),
        _e7(lon[0]),
        float(alt[0]),
    )
    for j in range(1, wp.shape[0]):
        add(Cmd.DO_CHANGE_SPEED, Frame.MISSION, 1.0, commanded[j - 1], -1.0, 0.0, 0, 0, 0.0)
        add(
            Cmd.NAV_WAYPOINT,
            g,
            hold[j],
            float(radius[j]),
            0.0,
            float(yaw_deg[j]),
            _e7(lat[j]),
            _e7(lon[j]),
            float(alt[j]),
        )
    if end is MissionEnd.LAND:
        land_lat, land_lon = lat[-1], lon[-1]
        if land_at_enu_m is not None:
            e, n = float(land_at_enu_m[0]), float(land_at_enu_m[1])
            pe = enu_to_geodetic(np.array([e, n, float(wp[-1, 2])]), origin)
            land_lat, land_lon = float(np.ravel(pe[0])[0]), float(np.ravel(pe[1])[0])
            # PX4 moves to a land point itself only until within NAV_ACC_RAD (2 m) and then
            # descends while closing the rest (Mission::do_need_move_to_land; seen on SITL):
            # a waypoint first, within the mission's own radius, starts the descent over the
            # clear point rather than up to 2 m short of it, beside what it keeps clear of.
            add(
                Cmd.NAV_WAYPOINT, g, 0.0, float(acceptance_radius_m), 0.0, float("nan"),
                _e7(land_lat), _e7(land_lon), float(alt[-1]),
            )  # fmt: skip
        add(
            Cmd.NAV_LAND, g, 0.0, 0.0, 0.0, float("nan"), _e7(land_lat), _e7(land_lon),
            float(alt[-1]),
        )  # fmt: skip
    elif end is MissionEnd.RETURN:
        add(Cmd.NAV_RETURN_TO_LAUNCH, Frame.MISSION, 0.0, 0.0, 0.0, 0.0, 0, 0, 0.0)

    # Knots: arrive at each waypoint at its planned time, hold, leave.
    kt: list[float] = []
    kp: list[np.ndarray] = []
    for j in range(wp.shape[0]):
        kt += [arrival[j], arrival[j] + hold[j]]
        kp += [wp[j], wp[j]]
    path = PiecewiseLinearPath(np.asarray(kt), np.asarray(kp))
    return MissionPlan(
        name=vname,
        items=tuple(items),
        waypoints_enu_m=wp,
        arrival_t_s=np.asarray(arrival),
        hold_s=np.asarray(hold),
        leg_speed_m_s=np.asarray(commanded),
        acceptance_m=radius,
        path=path,
    )


@dataclass(frozen=True, slots=True)
class PathDeviation:
    """How far a mission's straight-leg path strays from the planned trajectory.

    Attributes:
        max_m: largest distance between the two at the same time.
        rms_m: root-mean-square distance.
        t_at_max_s: when the largest distance occurs.
    """

    max_m: float
    rms_m: float
    t_at_max_s: float


def path_deviation(
    trajectory: Trajectory, path: PiecewiseLinearPath, dt_s: float = 0.01
) -> PathDeviation:
    """Distance between ``path`` and ``trajectory`` at equal times, sampled every ``dt_s``."""
    t_end = max(trajectory.duration_s, path.duration_s)
    t = np.linspace(0.0, t_end, math.ceil(t_end / dt_s) + 1)
    d = np.linalg.norm(path.position(t) - trajectory.position(t), axis=1)
    i = int(np.argmax(d))
    return PathDeviation(float(d[i]), float(np.sqrt(np.mean(d**2))), float(t[i]))


def path_robustness(
    spec: Formula, paths: Mapping[str, PiecewiseLinearPath], dt_s: float, horizon_s: float
) -> float:
    """Exact STL robustness of the vehicles flying ``paths`` (signals: name -> ``(n, 3)`` ENU).

    Sampled at ``t = 0, dt, ..., horizon`` (paths hold their last point beyond their end).
    """
    n = math.floor(horizon_s / dt_s + 1e-9) + 1
    t = np.arange(n) * dt_s
    signals = {name: p.position(t) for name, p in paths.items()}
    return float(spec.robustness(signals, dt_s))


# --------------------------------------------------------------------------
# Geofence
# --------------------------------------------------------------------------


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
        workspace: a :class:`planner.scenario.Region` (``name``, ``lo_enu_m``, ``hi_enu_m``).
        regions: the scenario's other regions; those whose ``kind.value`` is in
            ``exclude_kinds`` and that span the workspace's height become exclusion polygons.
        inflate_m: widen the workspace's polygon by this much on every side: PX4's fence is
            predictive (it fires when the braking distance would cross it), so a fence on
            the workspace's edge stops a plan that flies towards the edge at speed
            (:func:`braking_distance_m`). Exclusions are never shrunk (they stay exact).
    """
    ws_lo_z, ws_hi_z = float(workspace.lo_enu_m[2]), float(workspace.hi_enu_m[2])
    lo = tuple(float(c) - (inflate_m if a < 2 else 0.0) for a, c in enumerate(workspace.lo_enu_m))
    hi = tuple(float(c) + (inflate_m if a < 2 else 0.0) for a, c in enumerate(workspace.hi_enu_m))
    out = [FenceBox(workspace.name, lo, hi, inclusion=True)]
    for r in regions:
        full_height = r.lo_enu_m[2] <= ws_lo_z and r.hi_enu_m[2] >= ws_hi_z
        if r.kind.value in exclude_kinds and full_height:
            out.append(FenceBox(r.name, tuple(r.lo_enu_m), tuple(r.hi_enu_m), inclusion=False))
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
                    x=_e7(lat[k]),
                    y=_e7(lon[k]),
                    z=0.0,
                    mission_type=MissionType.FENCE,
                )
            )
    return tuple(items)


# --------------------------------------------------------------------------
# Transfers
# --------------------------------------------------------------------------


def _raise_for(result: Any, origin: str, v: Vehicle) -> None:
    if result != MissionRawResult.SUCCESS:
        name = getattr(result, "name", str(result))
        kind = (
            MissionResult.TOO_MANY_ITEMS
            if result == MissionRawResult.TOO_MANY_MISSION_ITEMS
            else MissionResult.TRANSFER_FAILED
        )
        raise MissionError(kind, origin, mavsdk_result=name, vehicle=v.name, url=v.url)


async def upload(
    v: Vehicle, items: Sequence[MissionItem], mission_type: MissionType = MissionType.MISSION
) -> None:
    """Upload a MISSION or FENCE plan with MAVSDK mission_raw (replacing the vehicle's)."""
    from mavlink.fleet import mavsdk_call

    raw = [i.to_mavsdk() for i in items]
    if mission_type is MissionType.MISSION:
        origin, start = "upload_mission", v.mission_raw.upload_mission_async
    elif mission_type is MissionType.FENCE:
        origin, start = "upload_geofence", v.mission_raw.upload_geofence_async
    else:
        origin, start = "upload_rally_points", v.mission_raw.upload_rally_points_async
    try:
        result = await mavsdk_call(start, raw, timeout_s=60.0)
    except TimeoutError:
        result = "TIMEOUT"
    _raise_for(result, origin, v)


async def download(
    v: Vehicle, mission_type: MissionType = MissionType.MISSION
) -> tuple[MissionItem, ...]:
    """Download the vehicle's MISSION, FENCE or RALLY plan."""
    from mavlink.fleet import mavsdk_call

    if mission_type is MissionType.MISSION:
        origin, start = "download_mission", v.mission_raw.download_mission_async
    elif mission_type is MissionType.FENCE:
        origin, start = "download_geofence", v.mission_raw.download_geofence_async
    else:
        origin, start = "download_rallypoints", v.mission_raw.download_rallypoints_async
    try:
        result, raw = await mavsdk_call(start, timeout_s=60.0)
    except TimeoutError:
        result, raw = "TIMEOUT", None
    _raise_for(result, origin, v)
    return tuple(MissionItem.from_mavsdk(r) for r in raw)


@dataclass(frozen=True, slots=True)
class TransferStep:
    """One upload or read-back of a transfer (:func:`upload_with_retries`).

    Attributes:
        attempt: the upload it belongs to (1-based).
        kind: ``"upload"``, ``"clear"`` (an empty MISSION plan) or ``"read-back"``.
        t_start_s: when it began, seconds from the transfer's start.
        duration_s: how long it took.
        outcome: ``"ok"`` (acknowledged), ``"identical"`` (read back as sent),
            ``"mismatch"`` (read back, differs) or ``"failed"`` (no answer / refused).
        detail: the error or the first differences (empty when it went well).
    """

    attempt: int
    kind: str
    t_start_s: float
    duration_s: float
    outcome: str
    detail: str = ""


@dataclass(frozen=True, slots=True)
class TransferReport:
    """Timing of an upload + read-back + comparison, and of its retries.

    Attributes:
        vehicle: name.
        items: items sent.
        upload_s, download_s: time spent uploading / reading back (and comparing), summed
            over the attempts.
        mission_type: MISSION, FENCE or RALLY.
        attempts: uploads it took (1 without a retry).
        elapsed_s: wall time from the first upload to the read-back that matched.
        steps: every upload and read-back, in order (empty from :func:`upload_and_verify`).
        last_error: the last failure that a retry overcame (empty if none).
    """

    vehicle: str
    items: int
    upload_s: float
    download_s: float
    mission_type: MissionType = MissionType.MISSION
    attempts: int = 1
    elapsed_s: float = math.nan
    steps: tuple[TransferStep, ...] = ()
    last_error: str = ""


async def upload_and_verify(
    v: Vehicle, items: Sequence[MissionItem], mission_type: MissionType = MissionType.MISSION
) -> TransferReport:
    """Upload, download back and compare item by item (``download_s`` includes the comparison).

    An upload that times out but whose read-back is identical succeeded (the vehicle's final
    MISSION_ACK was lost; see below).

    Raises:
        MissionError: ``MISMATCH`` naming the first differing items and fields,
            or the transfer's own failure.
    """
    t0 = time.perf_counter()
    try:
        await upload(v, items, mission_type)
    except MissionError as exc:
        if exc.mavsdk_result != "TIMEOUT":
            raise
        # MAVSDK 4.1 never recovers a lost final MISSION_ACK: the vehicle then holds the
        # complete plan while the upload reports TIMEOUT. The read-back decides; if it differs,
        # the upload's own failure is what the caller gets.
        t1 = time.perf_counter()
        try:
            await verify(v, items, mission_type)
        except MissionError:
            raise exc from None
        t2 = time.perf_counter()
        return TransferReport(v.name, len(items), t1 - t0, t2 - t1, mission_type, 1, t2 - t0)
    t1 = time.perf_counter()
    await verify(v, items, mission_type)
    t2 = time.perf_counter()
    return TransferReport(v.name, len(items), t1 - t0, t2 - t1, mission_type, 1, t2 - t0)


async def verify(
    v: Vehicle, items: Sequence[MissionItem], mission_type: MissionType = MissionType.MISSION
) -> None:
    """Download the vehicle's plan and require it to equal ``items`` (:func:`compare_items`).

    Raises:
        MissionError: ``MISMATCH`` naming the first three differences.
    """
    back = await download(v, mission_type)
    diffs = compare_items(items, back)
    if diffs:
        more = f" (+{len(diffs) - 3} more)" if len(diffs) > 3 else ""
        raise MissionError(
            MissionResult.MISMATCH,
            f"verify_{mission_type.name.lower()}",
            "; ".join(diffs[:3]) + more,
            vehicle=v.name,
            url=v.url,
        )


# --------------------------------------------------------------------------
# Transfers on a bad link: whole-transfer retries within a time budget
# --------------------------------------------------------------------------

#: MAVSDK results after which another attempt can succeed: the link failed (or a stale
#: message of an earlier attempt confused this one), not the plan. The others
#: (TOO_MANY_MISSION_ITEMS, UNSUPPORTED, DENIED, INVALID_ARGUMENT, ...) are the vehicle's
#: answer to the plan itself, and a retry would get the same.
_TRANSIENT_RESULTS = frozenset(
    {
        "TIMEOUT",
        "BUSY",
        "TRANSFER_CANCELLED",
        "PROTOCOL_ERROR",
        "ERROR",
        "UNKNOWN",
        "NO_SYSTEM",
        "INVALID_SEQUENCE",
    }
)
#: MAV_MISSION_OPERATION_CANCELLED (MISSION_ACK.type).
_OPERATION_CANCELLED = 15
#: Copies of that cancel sent: each lost one would leave PX4 busy for its 5 s timeout.
_CANCEL_COPIES = 3
#: The operation names :func:`upload` and :func:`download` give each plan type.
_UPLOAD_ORIGIN = {
    MissionType.MISSION: "upload_mission",
    MissionType.FENCE: "upload_geofence",
    MissionType.RALLY: "upload_rally_points",
}
_DOWNLOAD_ORIGIN = {
    MissionType.MISSION: "download_mission",
    MissionType.FENCE: "download_geofence",
    MissionType.RALLY: "download_rallypoints",
}


@dataclass(frozen=True, slots=True)
class RetryPolicy:
    """How :func:`upload_with_retries` retries a whole transfer on a bad link.

    Attributes:
        budget_s: total time for the transfer, every upload, read-back and wait included (s).
        backoff_s: wait after the first failure in a row (s); it doubles with each further
            one, up to ``backoff_max_s``.
        backoff_max_s: the longest wait (s).
        jitter: the wait is drawn from ``[(1 - jitter) w, w]``, so vehicles that failed
            together do not retry in step on a shared radio.
        readbacks: read-backs of an acknowledged upload that may fail in transfer before
            the plan is uploaded again.
        seed: seeds the jitter (``None``: from the OS); tests pass one.
    """

    budget_s: float = 60.0
    backoff_s: float = 0.25
    backoff_max_s: float = 2.0
    jitter: float = 0.5
    readbacks: int = 3
    seed: int | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.budget_s) and self.budget_s > 0):
            raise ValueError(f"budget_s must be a number > 0, got {self.budget_s!r}")
        if not (0.0 <= self.backoff_s <= self.backoff_max_s < math.inf):
            raise ValueError(
                f"need 0 <= backoff_s <= backoff_max_s < inf, got {self.backoff_s!r}, "
                f"{self.backoff_max_s!r}"
            )
        if not 0.0 <= self.jitter <= 1.0:
            raise ValueError(f"jitter must be in [0, 1], got {self.jitter!r}")
        if self.readbacks < 1:
            raise ValueError(f"readbacks must be >= 1, got {self.readbacks!r}")

    def backoff(self, failures: int, rng: random.Random) -> float:
        """The wait (s) after the ``failures``-th failure in a row (see the attributes)."""
        wait = min(self.backoff_max_s, self.backoff_s * 2.0 ** max(0, failures - 1))
        return wait * (1.0 - self.jitter * rng.random())


@dataclass(frozen=True, slots=True)
class TransferProgress:
    """Where a transfer of :func:`upload_with_retries` stands (its ``progress`` callback).

    Attributes:
        vehicle, mission_type: whose plan, which plan.
        attempt: the upload under way (1-based).
        step: ``"upload"`` or ``"read-back"`` (starting), ``"retry"`` (a step failed:
            ``detail`` says why; the next comes in ``wait_s``), ``"verified"`` (read back as
            sent: done) or ``"failed"`` (given up: ``detail`` says why).
        items: items of the plan.
        elapsed_s: seconds since the transfer began.
        detail: why a step failed, or the verdict.
        wait_s: the back-off before the next step (``"retry"`` only).
    """

    vehicle: str
    mission_type: MissionType
    attempt: int
    step: str
    items: int
    elapsed_s: float
    detail: str = ""
    wait_s: float = 0.0


def _transient(exc: MissionError) -> bool:
    """Whether another attempt can mend ``exc`` (a lost datagram, a differing read-back)."""
    if exc.result is MissionResult.MISMATCH:
        return True
    return exc.result is MissionResult.TRANSFER_FAILED and exc.mavsdk_result in _TRANSIENT_RESULTS


def _send_cancel(v: Vehicle, mission_type: MissionType) -> None:
    """Tell the vehicle to drop a transfer MAVSDK abandoned (MISSION_ACK, OPERATION_CANCELLED).

    MAVSDK 4.1 gives up on a transfer without telling the vehicle, which stays in it until
    its own protocol timeout (PX4: 5 s, during which a new upload gets "IGN MISSION_COUNT:
    Busy"). PX4 v1.17 leaves an upload or a download at once on this ACK from its transfer
    partner and ignores it when idle, so sending it after every failed step is safe.
    Best effort: a send that fails is logged (the vehicle then times out by itself).
    """
    from mavsdk.plugins.mavlink_direct import MavlinkDirectError, MavlinkMessage

    fields_json = json.dumps(
        {
            "target_system": v.spec.sysid,
            "target_component": 1,
            "type": _OPERATION_CANCELLED,
            "mission_type": int(mission_type),
            "opaque_id": 0,
        }
    )
    msg = MavlinkMessage(
        message_name="MISSION_ACK",
        target_system_id=v.spec.sysid,
        target_component_id=1,
        fields_json=fields_json,
    )
    try:
        for _ in range(_CANCEL_COPIES):
            v.direct.send_message(msg)
    except MavlinkDirectError as exc:
        log.info("vehicle %s: cancel of the %s transfer not sent: %s", v.name, mission_type, exc)


def _abandon(v: Vehicle, kind: str) -> None:
    """Cancel MAVSDK's own transfer still under way (the budget ran out before it ended)."""
    from mavsdk.plugins.mission_raw import MissionRawError

    cancel = (
        v.mission_raw.cancel_mission_download
        if kind == "read-back"
        else v.mission_raw.cancel_mission_upload
    )
    try:
        cancel()
    except MissionRawError as exc:  # nothing under way: it ended meanwhile
        log.debug("vehicle %s: no %s to cancel: %s", v.name, kind, exc)


@contextlib.contextmanager
def _requests_watched(v: Vehicle, mission_type: MissionType) -> Iterator[list[int]]:
    """The highest item seq ``v`` asks for (MISSION_REQUEST_INT of ``mission_type``) while the
    block runs, as ``[seq]`` (-1: none). A vehicle that never asked for the last item cannot
    hold the plan: PX4 stores an upload only once it is complete."""
    highest = [-1]
    sysid, mtype = v.spec.sysid, int(mission_type)

    def on_request(msg: Any, _ud: Any) -> None:
        if msg.system_id != sysid:
            return
        f = json.loads(msg.fields_json)
        if int(f.get("mission_type", 0)) == mtype:
            highest[0] = max(highest[0], int(f.get("seq", -1)))

    handle = v.direct.subscribe_message("MISSION_REQUEST_INT", on_request)
    try:
        yield highest
    finally:
        v.direct.unsubscribe_message(handle)


async def _put(v: Vehicle, items: Sequence[MissionItem], mission_type: MissionType) -> None:
    """Upload ``items``; an empty MISSION plan is cleared instead (MAVSDK uploads none)."""
    if items:
        await upload(v, items, mission_type)
        return
    from mavlink.fleet import mavsdk_call

    try:
        result = await mavsdk_call(v.mission_raw.clear_mission_async, timeout_s=60.0)
    except TimeoutError:
        result = "TIMEOUT"
    _raise_for(result, "clear_mission", v)


async def upload_with_retries(
    v: Vehicle,
    items: Sequence[MissionItem],
    mission_type: MissionType = MissionType.MISSION,
    *,
    policy: RetryPolicy | None = None,
    progress: Callable[[TransferProgress], None] | None = None,
) -> TransferReport:
    """Upload ``items`` until the vehicle reads back exactly them, within ``policy.budget_s``.

    MAVSDK retries single items (5 times each); on a link that loses a third of its
    datagrams both ways a 15-item upload + read-back still fails most of the time
    (``benchmarks/bench_faults.py``). This retries the transfer as a whole, on top:

    * every upload is followed by a read-back compared with :func:`compare_items`; only a
      read-back equal to the plan is a success, so a partial or different plan is never
      reported as the plan;
    * an acknowledged upload whose read-back fails in transfer is read back again (up to
      ``policy.readbacks`` times) before it is uploaded again; a failed upload is read back
      only if the vehicle asked for the last item (its final MISSION_ACK may be what was
      lost: MAVSDK never recovers that), since before that PX4 keeps its previous plan;
    * after a failed step the vehicle is told to drop the transfer (MISSION_ACK
      OPERATION_CANCELLED, which MAVSDK does not send) and the next step waits an
      exponential back-off with jitter (:meth:`RetryPolicy.backoff`);
    * every step counts against the budget; one still running when it runs out is cancelled.

    An empty MISSION plan is a clear (MISSION_CLEAR_ALL), read back as 0 items.

    Args:
        v: the vehicle.
        items: the plan, ``seq`` 0..n-1, all of ``mission_type``.
        mission_type: MISSION, FENCE or RALLY.
        policy: budget, back-off and read-backs (default :class:`RetryPolicy`).
        progress: called on the event loop at each step (:class:`TransferProgress`).

    Returns:
        The report: attempts, times, every step, the last failure overcome.

    Raises:
        TransferGaveUpError: the budget ran out first; names the vehicle, the attempts, the
            last cause and what the vehicle held at its last read-back (or that it is
            unknown).
        MissionError: a failure no retry mends (too many items, an item the vehicle
            refuses, an empty FENCE or RALLY plan), at once.
    """
    from mavlink.errors import TransferGaveUpError

    policy = policy if policy is not None else RetryPolicy()
    plan = tuple(items)
    origin = _UPLOAD_ORIGIN[mission_type]
    if not plan and mission_type is not MissionType.MISSION:
        raise MissionError(
            MissionResult.INVALID_ITEM,
            origin,
            f"no {mission_type.name} items: MAVSDK's mission_raw clears the MISSION plan only",
            vehicle=v.name,
            url=v.url,
        )
    rng = random.Random(policy.seed)
    t0 = time.monotonic()
    deadline = t0 + policy.budget_s
    steps: list[TransferStep] = []
    spent = {"upload": 0.0, "read-back": 0.0}
    attempt = failures = readbacks_left = 0
    last: MissionError | None = None
    held: int | None = None  # items read back at the last read-back since the last upload

    def tell(step: str, detail: str = "", wait_s: float = 0.0) -> None:
        if progress is not None:
            progress(
                TransferProgress(
                    v.name,
                    mission_type,
                    attempt,
                    step,
                    len(plan),
                    time.monotonic() - t0,
                    detail,
                    wait_s,
                )
            )

    async def run(kind: str, call: Callable[[], Any]) -> tuple[Any, MissionError | None]:
        """One MAVSDK transfer, cut short where the budget ends; recorded as a step."""
        t_step = time.monotonic()
        value: Any = None
        err: MissionError | None = None
        try:
            value = await asyncio.wait_for(call(), max(0.0, deadline - t_step))
        except TimeoutError:
            _abandon(v, kind)
            err = MissionError(
                MissionResult.TRANSFER_FAILED,
                _DOWNLOAD_ORIGIN[mission_type] if kind == "read-back" else origin,
                "the time budget ran out during it",
                mavsdk_result="TIMEOUT",
                vehicle=v.name,
                url=v.url,
            )
        except MissionError as exc:
            err = exc
        dt = time.monotonic() - t_step
        spent["read-back" if kind == "read-back" else "upload"] += dt
        outcome = "ok" if err is None else "failed"
        steps.append(
            TransferStep(attempt, kind, t_step - t0, dt, outcome, "" if err is None else err.detail)
        )
        return value, err

    def failed_step(err: MissionError) -> None:
        """A step failed: a refusal no retry mends is raised; otherwise the vehicle is told to
        drop the transfer and the failure counted."""
        nonlocal last, failures
        if not _transient(err):
            tell("failed", err.detail)
            raise err
        last = err
        _send_cancel(v, mission_type)
        failures += 1

    async def back_off(err: MissionError) -> None:
        wait = min(policy.backoff(failures, rng), max(0.0, deadline - time.monotonic()))
        tell("retry", err.detail, wait)
        await asyncio.sleep(wait)

    def give_up() -> TransferGaveUpError:
        cause = last or MissionError(
            MissionResult.TRANSFER_FAILED,
            origin,
            "the time budget ran out before the plan was read back",
            mavsdk_result="TIMEOUT",
            vehicle=v.name,
            url=v.url,
        )
        exc = TransferGaveUpError(
            origin,
            cause,
            attempts=attempt,
            elapsed_s=time.monotonic() - t0,
            budget_s=policy.budget_s,
            held=held,
            mission_type=mission_type.name,
        )
        tell("failed", exc.detail)
        return exc

    while True:
        if time.monotonic() >= deadline:
            raise give_up()
        if readbacks_left <= 0:
            attempt += 1
            held = None  # what an earlier read-back showed may be overwritten from here on
            tell("upload")
            with _requests_watched(v, mission_type) as asked:
                _, err = await run(
                    "upload" if plan else "clear", lambda: _put(v, plan, mission_type)
                )
            if err is None:
                failures = 0
                readbacks_left = policy.readbacks
            else:
                failed_step(err)
                if plan and asked[0] >= len(plan) - 1:
                    readbacks_left = 1  # complete on the vehicle, its final ACK lost?
                    tell(
                        "retry", f"{err.detail}; the vehicle asked for the last item: reading back"
                    )
                else:
                    await back_off(err)
                    continue
            if time.monotonic() >= deadline:
                raise give_up()
        tell("read-back")
        back, err = await run("read-back", lambda: download(v, mission_type))
        readbacks_left -= 1
        if err is not None:
            failed_step(err)
            await back_off(err)
            continue
        diffs = compare_items(plan, back)
        if not diffs:
            steps[-1] = dataclasses.replace(steps[-1], outcome="identical")
            report = TransferReport(
                v.name,
                len(plan),
                spent["upload"],
                spent["read-back"],
                mission_type,
                attempt,
                time.monotonic() - t0,
                tuple(steps),
                last.detail if last is not None else "",
            )
            tell("verified", f"read back identical after {attempt} attempt(s)")
            return report
        held = len(back)
        more = f" (+{len(diffs) - 3} more)" if len(diffs) > 3 else ""
        last = MissionError(
            MissionResult.MISMATCH,
            f"verify_{mission_type.name.lower()}",
            "; ".join(diffs[:3]) + more,
            vehicle=v.name,
            url=v.url,
        )
        steps[-1] = dataclasses.replace(steps[-1], outcome="mismatch", detail=last.detail)
        readbacks_left = 0
        failures += 1
        await back_off(last)


# --------------------------------------------------------------------------
# Starting a mission, confirmed
# --------------------------------------------------------------------------

#: MAV_CMD_DO_SET_MODE and MAV_CMD_MISSION_START: the commands a mission start is made of.
_START_COMMANDS = frozenset({176, 300})


@dataclass(frozen=True, slots=True)
class MissionStart:
    """What became of one vehicle's mission start (:func:`start_mission_confirmed`).

    Attributes:
        vehicle: name.
        started: the vehicle is in AUTO.MISSION, armed (and climbing, when asked).
        attempts: start commands sent.
        detail: what was seen: the confirmation, or why not (mode, acks, PX4's STATUSTEXT).
        t_accepted_monotonic_s: when the start that took effect was sent (``nan`` if none).
    """

    vehicle: str
    started: bool
    attempts: int
    detail: str
    t_accepted_monotonic_s: float = math.nan


async def start_mission_confirmed(
    v: Vehicle,
    *,
    timeout_s: float = 10.0,
    climb_m: float | None = 0.3,
    climb_timeout_s: float = 15.0,
    mode_wait_s: float = 1.6,
    retry_after_s: float = 0.3,
) -> MissionStart:
    """Start ``v``'s uploaded mission and confirm it took effect, retrying a refused start.

    PX4 acknowledges a mode change before its commander decides on it: right after an upload
    it answers ACCEPTED and ~12 ms later TEMPORARILY_REJECTED, and stays in its mode
    (PX4-BEHAVIOUR.md). So a start counts only when the heartbeat shows AUTO.MISSION and
    armed; a late rejection or a mode that does not change within ``mode_wait_s`` (PX4
    heartbeats come at 1 Hz) is retried until ``timeout_s`` (re-arming a vehicle that
    disarmed meanwhile). With ``climb_m`` the vehicle must also leave the ground: in air
    (EXTENDED_SYS_STATE) and ``climb_m`` above where it started, within ``climb_timeout_s``
    (PX4 skips the take-off of a mission whose first waypoint is within NAV_MC_ALT_RAD of the
    vehicle, and auto-disarms it on the ground).

    Never raises for a refusal: the result says what happened, with PX4's STATUSTEXTs.
    """
    from mavlink.errors import CommandError
    from mavlink.fleet import mavsdk_call
    from mavlink.px4_modes import Px4Mode

    t_begin = time.monotonic()
    deadline = t_begin + timeout_s
    late: list[tuple[float, int]] = []

    def on_ack(msg: Any, _ud: Any) -> None:
        if msg.system_id != v.spec.sysid:
            return
        f = json.loads(msg.fields_json)
        if int(f.get("command", -1)) in _START_COMMANDS and int(f.get("result", 0)) != 0:
            late.append((time.monotonic(), int(f["result"])))

    def texts() -> str:
        said = [t for sev, t in v.statustexts(t_begin) if sev <= 4]
        return f"; PX4 said: {' / '.join(dict.fromkeys(said))}" if said else ""

    st0 = v.status()
    alt0 = -st0.pos_ned_m[2] if st0.pos_ned_m is not None else math.nan
    handle = v.direct.subscribe_message("COMMAND_ACK", on_ack)
    attempts, why = 0, "no start command was accepted"
    t_ok = math.nan
    try:
        while time.monotonic() < deadline:
            if attempts:
                await asyncio.sleep(retry_after_s)
            attempts += 1
            st = v.status()
            if not st.armed:
                try:
                    await v.arm()
                except CommandError as exc:
                    why = f"arm: {exc.result}"
                    continue
            t_cmd = time.monotonic()
            try:
                result = await mavsdk_call(v.mission_raw.start_mission_async)
            except TimeoutError:
                result = "TIMEOUT"
            name = getattr(result, "name", str(result))
            if name != "SUCCESS":
                why = f"start refused: {name}"
                continue
            # Accepted: wait for the heartbeat's mode, or PX4's late rejection.
            t_wait = time.monotonic() + mode_wait_s
            while time.monotonic() < t_wait and not any(t >= t_cmd for t, _ in late):
                st = v.status()
                if st.mode is Px4Mode.AUTO_MISSION and st.armed:
                    break
                await asyncio.sleep(0.02)
            rejected = [r for t, r in late if t >= t_cmd]
            st = v.status()
            if st.mode is Px4Mode.AUTO_MISSION and st.armed and not rejected:
                t_ok = t_cmd
                break
            mode = st.mode.label if st.mode is not None else str(st.custom_mode)
            if rejected:
                from mavlink.fleet import MAV_RESULT_NAMES

                why = (
                    f"start ACCEPTED, then {MAV_RESULT_NAMES.get(rejected[-1], rejected[-1])} "
                    f"(mode {mode}, armed {st.armed})"
                )
            else:
                why = f"start ACCEPTED but the vehicle stayed in {mode} (armed {st.armed})"
        else:
            return MissionStart(
                v.name, False, attempts, f"not started after {attempts} attempt(s): {why}{texts()}"
            )
    finally:
        v.direct.unsubscribe_message(handle)
    if climb_m is None:
        return MissionStart(v.name, True, attempts, "AUTO.MISSION", t_ok)

    def climbing(s: VehicleStatus) -> bool:
        up = -s.pos_ned_m[2] - alt0 if s.pos_ned_m is not None else -math.inf
        return bool(s.in_air and up >= climb_m)

    def gave_up(s: VehicleStatus) -> bool:
        return not s.armed or s.mode is not Px4Mode.AUTO_MISSION

    t_climb = time.monotonic() + climb_timeout_s
    while time.monotonic() < t_climb:
        s = v.status()
        if climbing(s):
            up = -s.pos_ned_m[2] - alt0 if s.pos_ned_m is not None else math.nan
            return MissionStart(
                v.name, True, attempts, f"AUTO.MISSION, climbing ({up:.1f} m up)", t_ok
            )
        if gave_up(s):
            mode = s.mode.label if s.mode is not None else str(s.custom_mode)
            return MissionStart(
                v.name,
                False,
                attempts,
                f"AUTO.MISSION accepted but the vehicle never left the ground (now {mode}, "
                f"armed {s.armed}){texts()}",
            )
        await asyncio.sleep(0.05)
    return MissionStart(
        v.name,
        False,
        attempts,
        f"AUTO.MISSION accepted but the vehicle did not climb {climb_m:.1f} m in "
        f"{climb_timeout_s:.0f} s{texts()}",
    )


@dataclass(frozen=True, slots=True)
class MissionRun:
    """What a vehicle reported while flying its mission (PX4's way: PX4-BEHAVIOUR.md).

    PX4 reports in MISSION_ITEM_REACHED the last item *processed* (a DO item that follows a
    waypoint overwrites the waypoint's report) and re-sends it about once a second; progress
    is therefore read from MISSION_CURRENT, and each reached seq is kept once.

    Attributes:
        vehicle: name.
        current: ``(seq, t_s)`` each time MISSION_CURRENT's seq changed, s from ``t_start``.
        reached: ``(seq, t_s)`` the first MISSION_ITEM_REACHED of each seq (re-sends dropped).
        finished: the vehicle reported the mission finished in time.
        duration_s: time from ``t_start`` to the end (or the timeout).
        start: the confirmed start (:func:`start_mission_confirmed`), if this call started it.
    """

    vehicle: str
    current: tuple[tuple[int, float], ...]
    reached: tuple[tuple[int, float], ...]
    finished: bool
    duration_s: float
    start: MissionStart | None = None

    def left_s(self, seq: int) -> float | None:
        """When the vehicle moved on past item ``seq`` (MISSION_CURRENT above it, or a reached
        report of a later item), seconds from ``t_start``; ``None`` if it never did."""
        times = [t for s, t in self.current if s > seq] + [t for s, t in self.reached if s > seq]
        return min(times) if times else None

    def passed(self, seqs: Sequence[int]) -> list[int]:
        """The items of ``seqs`` the vehicle has left behind or reached, in mission order."""
        done = {s for s, _ in self.reached}
        return [s for s in seqs if s in done or self.left_s(s) is not None]


def _seq_of(msg: Any, sysid: int) -> int | None:
    """The ``seq`` of a mavlink_direct MISSION_CURRENT / MISSION_ITEM_REACHED from ``sysid``
    (``None``: another system's)."""
    if msg.system_id != sysid:
        return None
    return int(json.loads(msg.fields_json)["seq"])


#: How long (s) fly_missions keeps listening after a vehicle reports its mission finished,
#: for the last MISSION_CURRENT progress update.
_FINISH_GRACE_S = 1.0


class MissionFollower:
    """Records MISSION_CURRENT and MISSION_ITEM_REACHED of some vehicles (see MissionRun).

    Subscribe with :meth:`attach` before the start, read with :meth:`runs`, :meth:`detach`
    at the end. Times are seconds from :attr:`t_start` (``time.monotonic()``; settable).
    """

    def __init__(self, vehicles: Sequence[Vehicle]) -> None:
        self.vehicles = list(vehicles)
        self.t_start = time.monotonic()
        self._reached: dict[str, dict[int, float]] = {v.name: {} for v in vehicles}
        self._current: dict[str, list[tuple[int, float]]] = {v.name: [] for v in vehicles}
        self.totals: dict[str, int] = {}
        self._progress: dict[str, int] = {}
        self._handles: list[tuple[Any, Any]] = []

    def attach(self) -> None:
        for v in self.vehicles:

            def on_reached(
                msg: Any, _ud: Any, name: str = v.name, sysid: int = v.spec.sysid
            ) -> None:
                seq = _seq_of(msg, sysid)
                if seq is not None:
                    self._reached[name].setdefault(seq, time.monotonic() - self.t_start)

            def on_current(
                msg: Any, _ud: Any, name: str = v.name, sysid: int = v.spec.sysid
            ) -> None:
                # MISSION_CURRENT itself: MAVSDK's mission progress mixes in reached items
                seq = _seq_of(msg, sysid)
                cur = self._current[name]
                if seq is not None and (not cur or cur[-1][0] != seq):
                    cur.append((seq, time.monotonic() - self.t_start))

            def on_progress(progress: Any, _ud: Any, name: str = v.name) -> None:
                self.totals[name] = int(progress.total)
                self._progress[name] = int(progress.current)

            self._handles.append(
                (
                    v.direct.unsubscribe_message,
                    v.direct.subscribe_message("MISSION_ITEM_REACHED", on_reached),
                )
            )
            self._handles.append(
                (
                    v.direct.unsubscribe_message,
                    v.direct.subscribe_message("MISSION_CURRENT", on_current),
                )
            )
            self._handles.append(
                (
                    v.mission_raw.unsubscribe_mission_progress,
                    v.mission_raw.subscribe_mission_progress(on_progress),
                )
            )

    def detach(self) -> None:
        handles, self._handles = self._handles, []
        for unsub, handle in handles:
            unsub(handle)

    def current_seq(self, name: str) -> int | None:
        cur = self._current[name]
        return cur[-1][0] if cur else None

    def run(self, name: str, *, finished: bool, duration_s: float) -> MissionRun:
        return MissionRun(
            vehicle=name,
            current=tuple(self._current[name]),
            reached=tuple(sorted(self._reached[name].items(), key=lambda kv: kv[1])),
            finished=finished,
            duration_s=duration_s,
        )

    def _finish_s(self, name: str, seen_s: float) -> float:
        """When ``name``'s mission finished, MAVSDK having seen it finished at ``seen_s``.

        PX4 reports the last item reached the moment it completes it (after its hold), and
        the mission is over in the same cycle; MAVSDK's verdict waits for MISSION_CURRENT,
        which on the API link mostly comes with PX4's once-a-second report (up to 1 s late).
        """
        total = self.totals.get(name, 0)
        t_last = self._reached[name].get(total - 1) if total > 0 else None
        return seen_s if t_last is None else min(seen_s, t_last)

    async def until_finished(
        self, *, timeout_s: float, poll_s: float = 0.1, stop: asyncio.Event | None = None
    ) -> dict[str, float]:
        """Wait until every vehicle reports its mission finished (MAVSDK), ``timeout_s`` from
        now or ``stop``; the finish time of each that did (s from :attr:`t_start`)."""
        done: dict[str, float] = {}
        t_end = time.monotonic() + timeout_s
        while len(done) < len(self.vehicles) and time.monotonic() < t_end:
            if stop is not None and stop.is_set():
                break
            await asyncio.sleep(poll_s)
            for v in self.vehicles:
                if v.name not in done and v.mission_raw.is_mission_finished():
                    done[v.name] = self._finish_s(v.name, time.monotonic() - self.t_start)
        # MAVSDK can report the mission finished before its progress callback has delivered
        # the final current == total (seen under load): keep listening a moment for it.
        t_grace = time.monotonic()
        while time.monotonic() - t_grace < _FINISH_GRACE_S and any(
            self._progress.get(n, 0) < self.totals.get(n, 0) for n in done
        ):
            await asyncio.sleep(poll_s)
        return done


async def fly_missions(
    vehicles: Sequence[Vehicle], *, timeout_s: float, poll_s: float = 0.1
) -> dict[str, MissionRun]:
    """Arm, start the uploaded missions together (each start confirmed) and follow them
    until finished or timeout.

    Progress comes from MISSION_CURRENT (MAVSDK's mission progress),
    MISSION_ITEM_REACHED (mavlink_direct, each seq once) and MAVSDK's ``is_mission_finished``.

    Raises:
        CommandError: a vehicle refused to arm.
        MissionError: a vehicle's start did not take effect (names it and what PX4 said).
    """
    follower = MissionFollower(vehicles)
    follower.attach()
    try:
        await asyncio.gather(*(v.arm() for v in vehicles))
        follower.t_start = time.monotonic()
        starts = await asyncio.gather(*(start_mission_confirmed(v, climb_m=None) for v in vehicles))
        for v, st in zip(vehicles, starts, strict=True):
            if not st.started:
                raise MissionError(
                    MissionResult.TRANSFER_FAILED,
                    "start_mission",
                    st.detail,
                    vehicle=v.name,
                    url=v.url,
                )
        done = await follower.until_finished(timeout_s=timeout_s, poll_s=poll_s)
    finally:
        follower.detach()
    now = time.monotonic() - follower.t_start
    out = {}
    for v, st in zip(vehicles, starts, strict=True):
        run = follower.run(v.name, finished=v.name in done, duration_s=done.get(v.name, now))
        out[v.name] = dataclasses.replace(run, start=st)
    return out
