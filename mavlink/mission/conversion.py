"""Trajectories as PX4 missions: the items of a plan, and the straight-leg path they fly.

PX4 has no local-frame mission items, so a vehicle's mission-frame trajectory
becomes global ``*_INT`` items (docs/architecture.md, "The MAVLink side"):

* ``NAV_TAKEOFF`` to the start point (lat/lon/alt AMSL of the plan's start);
* a ``NAV_WAYPOINT`` at the start (its hold time is the plan's initial hover);
* per segment of the trajectory that moves: ``DO_CHANGE_SPEED`` to the
  straight-line length / duration of the segment, so the mission's timing
  follows the plan, then ``NAV_WAYPOINT`` at the segment's end point with
  ``acceptance_radius_m`` (param2) and, where the plan then hovers, the hover
  time as hold time (param1);
* ``NAV_LAND`` at the last point, ``NAV_RETURN_TO_LAUNCH``, or nothing (PX4
  then holds at the last waypoint);
* per :class:`CaptureSpan` (a stretch in which the camera takes pictures, from the plan's
  capture windows): ``DO_GIMBAL_MANAGER_PITCHYAW`` (pitch to the target, yaw straight ahead:
  the vehicle faces it) and ``IMAGE_START_CAPTURE`` at its start (for as many pictures as fit
  in the span at its interval), ``IMAGE_STOP_CAPTURE`` at its end; all in MAV_FRAME_MISSION,
  the one frame PX4 v1.17 accepts them in (``parse_mavlink_mission_item``). Before the first
  PITCHYAW the mission takes the gimbal (``DO_GIMBAL_MANAGER_CONFIGURE(-2, -2, -1, -1)``, as
  MAVSDK's mission plugin does): PX4's gimbal manager ignores a PITCHYAW from the mission
  otherwise, since nobody is in control of it at boot.  The camera's items make at most 4 DO
  commands in a row (a stop, the configure, the pitch, a start; PX4's vehicle_command queue
  holds 8 and loses the oldest beyond).  PX4 sends each on to the camera
  (component 100) as a COMMAND_LONG and never waits for it.  PX4 runs a DO item when the NAV item before it is
  completed (a waypoint after its hold), so a span starting or ending within a hold splits
  the hold: the waypoint with the hold so far, the DO items, the same waypoint with the rest
  (a waypoint where the vehicle already is is reached at once).  A span starting on a leg
  starts at the next waypoint, one ending on a leg stops at the last one (or, when that is
  the start, by its count), so the pictures are all taken inside the span when the mission
  keeps the plan's clock; a span with no waypoint in it is dropped
  (:attr:`MissionPlan.captures` says when each is taken).

A segment whose peak speed stays below ``hover_speed_m_s`` (or which ends
less than the acceptance radius from where it started) is a hover; one of at least half the
radius that ends a leg before a hover extends the leg to where the plan hovers.
``simplify_m`` drops the waypoints flown through that straight legs at constant speed can skip
while they stay that close to the plan at every instant (:func:`keep_waypoints`): PX4 slows at
every waypoint to a speed from which it could stop at the next one, so the plan's dense segment
ends are too close for its speeds (:mod:`gcs.flight.missions` chooses the tolerance).

The mission flies straight legs at constant speed: :class:`PiecewiseLinearPath`
is that path as a function of time (knots at the segment boundaries, so it
meets the plan exactly at every waypoint). :func:`path_deviation` measures how
far it strays from the planned trajectory and :func:`path_robustness`
evaluates the exact STL robustness of the paths (docs/stl.md, "Semantics"), so the
mission can be judged before it is flown.

A room of its own because it is pure computation: it speaks to no vehicle.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mavlink.errors import MissionError, MissionResult
from mavlink.mission.items import Cmd, Frame, MissionEnd, MissionItem, MissionType, deg_e7
from mavlink.tracks import wrap_pi
from planner.frames import GeodeticPoint, enu_to_geodetic, yaw_enu_to_ned
from planner.trajectory import Trajectory

if TYPE_CHECKING:
    from planner.stl.ast import Formula


@dataclass(frozen=True, slots=True, eq=False)
class PiecewiseLinearPath:
    """Straight legs at constant speed with holds: position linear between knots.

    Attributes:
        knots_t_s: ``(m,)`` non-decreasing times from the plan's start.
        knots_enu_m: ``(m, 3)`` mission-frame positions at those times.
        knots_yaw_enu_rad: ``(m,)`` the heading at those times (mission ENU yaw, rad,
            unwrapped: the shorter turn between knots), or ``None``.
    """

    knots_t_s: np.ndarray
    knots_enu_m: np.ndarray
    knots_yaw_enu_rad: np.ndarray | None = None

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

    def signal(self, t_s: np.ndarray) -> np.ndarray:
        """The STL signal at ``t_s`` ``(n,)``: positions ``(n, 3)``, with the heading (turned
        linearly between knots, held outside) a fourth column ``(n, 4)`` when the path has one."""
        pos = self.position(t_s)
        if self.knots_yaw_enu_rad is None:
            return pos
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        yaw = np.interp(t, self.knots_t_s, self.knots_yaw_enu_rad)
        return np.column_stack([pos, wrap_pi(yaw)])


@dataclass(frozen=True, slots=True)
class CaptureSpan:
    """A stretch of a vehicle's plan in which its camera takes pictures.

    Attributes:
        t_start_s, t_end_s: the stretch, seconds from the plan's start.
        gimbal_pitch_deg: the camera's pitch there (degrees, negative: down), facing forward.
        interval_s: time between pictures (> 0).
        target: what it pictures (a name, for the reports).
    """

    t_start_s: float
    t_end_s: float
    gimbal_pitch_deg: float = 0.0
    interval_s: float = 1.0
    target: str = ""

    def pictures(self, from_s: float | None = None) -> int:
        """Pictures taken from ``from_s`` (default its start) to its end: one at once, then
        one per interval."""
        start = self.t_start_s if from_s is None else from_s
        return max(1, math.floor((self.t_end_s - start) / self.interval_s + 1e-9) + 1)


@dataclass(frozen=True, slots=True)
class ScheduledCapture:
    """A :class:`CaptureSpan` as the mission takes it: IMAGE_START_CAPTURE at ``start_s``
    (plan time: a waypoint's arrival, departure or a time within its hold) for as many
    pictures as fit in the span at its interval, IMAGE_STOP_CAPTURE at ``stop_s`` (the last
    such time within the span; ``None``: none after the start), or nothing (``start_s``
    ``None``: no waypoint within the span).

    Attributes:
        span: the span asked for.
        start_s, stop_s: when the mission starts and stops capturing, or ``None``.
        start_seq: the seq of its IMAGE_START_CAPTURE item (-1: dropped).
    """

    span: CaptureSpan
    start_s: float | None
    stop_s: float | None
    start_seq: int = -1

    @property
    def images(self) -> int:
        """Pictures the camera takes in it when the mission keeps the plan's clock (0 when
        dropped): the START's count, or fewer where the STOP comes first."""
        if self.start_s is None:
            return 0
        n = self.span.pictures(self.start_s)
        if self.stop_s is not None:
            n = min(n, math.floor((self.stop_s - self.start_s) / self.span.interval_s + 1e-9) + 1)
        return n


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
        waypoint_seq: ``(k,)`` the seq of each waypoint's last NAV_WAYPOINT item (the one
            left at its departure: a hold split for a capture is two items).
        captures: the capture spans as the mission takes them, in the order given.
    """

    name: str
    items: tuple[MissionItem, ...]
    waypoints_enu_m: np.ndarray
    arrival_t_s: np.ndarray
    hold_s: np.ndarray
    leg_speed_m_s: np.ndarray
    acceptance_m: np.ndarray
    path: PiecewiseLinearPath
    waypoint_seq: np.ndarray
    captures: tuple[ScheduledCapture, ...] = ()


def _capture_times(
    span: CaptureSpan, arrival: Sequence[float], hold: Sequence[float]
) -> tuple[tuple[float, int], tuple[float, int] | None] | None:
    """When and at which waypoint a mission can start and stop ``span`` (module docstring):
    ``((t_start, j_start), (t_stop, j_stop) or None)``, or ``None`` if no waypoint lies within
    it (the stop is ``None`` when the last waypoint within it is the start's instant)."""
    eps = 1e-6
    start: tuple[float, int] | None = None
    stop: tuple[float, int] | None = None
    for j, (a, h) in enumerate(zip(arrival, hold, strict=True)):
        d = a + h
        if start is None and d >= span.t_start_s - eps:
            start = (max(a, span.t_start_s), j)
        if a <= span.t_end_s + eps:
            stop = (min(d, span.t_end_s), j)
    if start is None or start[0] > span.t_end_s + eps:
        return None
    if stop is None or stop[0] <= start[0] + eps:
        return start, None
    return start, stop


def keep_waypoints(
    trajectory: Trajectory,
    arrival: Sequence[float],
    hold: Sequence[float],
    tolerance_m: float,
    *,
    fixed: set[int] | frozenset[int] = frozenset(),
    samples_per_s: float = 20.0,
) -> list[int]:
    """The waypoints to keep (indices, in order) so that the straight legs between them,
    each flown at constant speed from one waypoint's departure to the next one's arrival,
    stay within ``tolerance_m`` of the planned position at every instant.

    Douglas-Peucker on time-stamped points with the synchronous Euclidean distance
    (Meratnia and de By, "Spatiotemporal compression techniques for moving point objects",
    EDBT 2004): the distance at the same instant, not to the nearest point of the chord, so
    a simplified mission keeps the plan's clock as well as its path. The first and last
    waypoints, every waypoint with a hold and those in ``fixed`` are always kept; between two
    kept ones the plan is sampled ``samples_per_s`` times a second, and where it strays too
    far the interval is split at the waypoint with the largest distance.
    """
    n = len(arrival)
    keep = {0, n - 1, *fixed, *(j for j in range(n) if hold[j] > 0)}
    anchors = sorted(keep)

    def split(a: int, b: int) -> None:
        if b - a < 2:
            return
        t_a, t_b = arrival[a] + hold[a], arrival[b]
        if t_b - t_a <= 1e-9:
            return
        p_a, p_b = trajectory.position(np.array([t_a, t_b]))
        t = np.linspace(t_a, t_b, max(3, math.ceil((t_b - t_a) * samples_per_s) + 1))
        chord = p_a + ((t - t_a) / (t_b - t_a))[:, None] * (p_b - p_a)
        if float(np.max(np.linalg.norm(trajectory.position(t) - chord, axis=1))) <= tolerance_m:
            return
        inner = list(range(a + 1, b))
        t_in = np.array([float(arrival[j]) for j in inner])
        chord_in = p_a + ((t_in - t_a) / (t_b - t_a))[:, None] * (p_b - p_a)
        err = np.linalg.norm(trajectory.position(t_in) - chord_in, axis=1)
        m = inner[int(np.argmax(err))]
        keep.add(m)
        split(a, m)
        split(m, b)

    for a, b in itertools.pairwise(anchors):
        split(a, b)
    return sorted(keep)


def trajectory_to_mission(
    trajectory: Trajectory,
    origin: GeodeticPoint,
    *,
    acceptance_radius_m: float = 0.3,
    hover_speed_m_s: float = 0.05,
    end: MissionEnd = MissionEnd.LAND,
    name: str | None = None,
    leg_speed_m_s: Sequence[float] | np.ndarray | None = None,
    pass_lag_s: float = 0.0,
    land_at_enu_m: Sequence[float] | np.ndarray | None = None,
    captures: Sequence[CaptureSpan] = (),
    simplify_m: float = 0.0,
    hold_time_s: Sequence[float] | np.ndarray | None = None,
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
            (:func:`gcs.flight.missions.convert_plan` times them so PX4 keeps the plan's clock);
            the path and the planned arrival times stay the plan's.
        pass_lag_s: the vehicle's lag behind its setpoint (s). A waypoint flown through
            (no hold, a turn under 30 degrees) gets the radius ``lag * speed + R / 2`` if
            larger (at most 45 % of its shorter leg): PX4 accepts a waypoint by where the
            vehicle is, which trails its setpoint by the drag lag, so with a radius
            smaller than that trail the setpoint stops at the waypoint and waits.
        land_at_enu_m: with ``end`` LAND, land here (east, north; the mission frame)
            instead of below the last point: a NAV_WAYPOINT there at the last point's
            altitude, then the NAV_LAND (a multicopter's NAV_LAND descends on its way to
            its position); :mod:`gcs.flight.landing` picks the point clear of keep-outs.
        captures: where the camera takes pictures (:class:`CaptureSpan`; module docstring).
        simplify_m: drop waypoints flown through while the straight legs, flown at constant
            speed between the waypoints kept, stay within this distance of the plan at
            every instant (:func:`keep_waypoints`); 0 keeps every segment's end. PX4 slows
            at every waypoint to a speed from which it could stop at the next one, so
            waypoints closer than the braking distance of the plan's speed make it late.
        hold_time_s: the hold (param1) commanded at each waypoint instead of the plan's
            hover there (:func:`gcs.flight.missions.convert_plan` lengthens a hold where
            PX4 is predicted to arrive early and shortens it where late, so the departures
            keep the plan's clock); the planned arrival times, hovers and path stay the plan's.

    Raises:
        MissionError: ``INVALID_ITEM`` for a non-positive acceptance radius, a speed list of
            the wrong length or with a non-positive speed, or a hold list of the wrong length
            or with a negative hold.
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

    waypoints = [pts[0]]
    arrival = [0.0]
    hold = [0.0]
    for s in range(t0.size):
        if moving[s] and lengths[s] >= acceptance_radius_m:
            waypoints.append(pts[s + 1])
            arrival.append(float(bounds[s + 1]))
            hold.append(0.0)
        elif (
            moving[s]
            and lengths[s] >= 0.5 * acceptance_radius_m
            and len(waypoints) > 1
            and hold[-1] == 0.0
            and (s + 1 == t0.size or lengths[s + 1] < 0.5 * acceptance_radius_m)
            and not any(c.t_start_s <= bounds[s + 1] and c.t_end_s >= bounds[s] for c in captures)
        ):
            # a move shorter than the radius (but not a hover's drift) at the end of a leg,
            # before a hover: the leg goes on to where it ends (the end of the approach; not
            # where pictures are taken, whose waypoints stay where the plan has them)
            waypoints[-1] = pts[s + 1]
            arrival[-1] = float(bounds[s + 1])
        else:
            hold[-1] += float(dur[s])
    if simplify_m > 0 and len(waypoints) > 2:
        # the waypoints within a capture span stay: the pictures are taken where planned
        fixed = {
            j
            for span in captures
            for j in range(len(arrival))
            if arrival[j] <= span.t_end_s and arrival[j] + hold[j] >= span.t_start_s
        }
        kept = keep_waypoints(trajectory, arrival, hold, simplify_m, fixed=fixed)
        waypoints = [waypoints[j] for j in kept]
        arrival = [arrival[j] for j in kept]
        hold = [hold[j] for j in kept]
    leg_speed = [
        float(np.linalg.norm(waypoints[j] - waypoints[j - 1]))
        / (arrival[j] - arrival[j - 1] - hold[j - 1])
        for j in range(1, len(waypoints))
    ]
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
    if hold_time_s is not None:
        holds = [float(x) for x in hold_time_s]
        if len(holds) != len(hold) or not all(math.isfinite(x) and x >= 0 for x in holds):
            raise MissionError(
                MissionResult.INVALID_ITEM,
                "trajectory_to_mission",
                f"hold_time_s: {len(hold)} holds >= 0 wanted, got {holds!r}",
                vehicle=vname,
            )
    else:
        holds = list(hold)
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
    yaw_enu = np.asarray(trajectory.yaw_rad(np.asarray(arrival)), dtype=float)
    yaw_deg = np.degrees(np.asarray(yaw_enu_to_ned(yaw_enu), dtype=float))

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
        deg_e7(lat[0]),
        deg_e7(lon[0]),
        float(alt[0]),
    )
    # The capture actions per waypoint: (time, order, span index, start?).
    acts: dict[int, list[tuple[float, int, int, bool]]] = {}
    times: list[tuple[tuple[float, int], tuple[float, int] | None] | None] = []
    for which, span in enumerate(captures):
        got = _capture_times(span, arrival, hold)
        times.append(got)
        if got is not None:
            (ts, js), stop = got
            acts.setdefault(js, []).append((ts, 1, which, True))
            if stop is not None:
                acts.setdefault(stop[1], []).append((stop[0], 0, which, False))  # stop first
    start_seq: dict[int, int] = {}
    wp_seq: list[int] = []
    gimbal_taken = False
    for j in range(wp.shape[0]):
        if j > 0:
            add(Cmd.DO_CHANGE_SPEED, Frame.MISSION, 1.0, commanded[j - 1], -1.0, 0.0, 0, 0, 0.0)
        here = (
            float(radius[j]),
            float(yaw_deg[j]),
            deg_e7(lat[j]),
            deg_e7(lon[j]),
            float(alt[j]),
        )
        r_j, yaw_j, x_j, y_j, z_j = here
        t_prev = arrival[j]
        t_dep = arrival[j] + holds[j]
        pending = sorted(acts.get(j, ()))
        # a commanded hold longer than the plan's hover waits first (an early arrival), a
        # shorter one has lost its start (a late one): the actions keep their time to the
        # departure
        shift = holds[j] - hold[j]
        at = [max(arrival[j], act[0] + shift) for act in pending]
        k = 0
        while True:
            t_next = at[k] if k < len(pending) else t_dep
            if k == len(pending) and pending and t_dep - t_prev <= 1e-6:
                break  # the last actions ran at the departure: no rest of the hold
            add(Cmd.NAV_WAYPOINT, g, max(0.0, t_next - t_prev), r_j, 0.0, yaw_j, x_j, y_j, z_j)
            if k == len(pending):
                break
            t_prev = t_next
            while k < len(pending) and at[k] <= t_next + 1e-9:
                _, _, which, starts = pending[k]
                span = captures[which]
                if starts:
                    if not gimbal_taken:
                        add(
                            Cmd.DO_GIMBAL_MANAGER_CONFIGURE, Frame.MISSION,
                            -2.0, -2.0, -1.0, -1.0, 0, 0, 0.0,
                        )  # fmt: skip
                        gimbal_taken = True
                    add(
                        Cmd.DO_GIMBAL_MANAGER_PITCHYAW, Frame.MISSION,
                        float(span.gimbal_pitch_deg), 0.0, math.nan, math.nan, 0, 0, 0.0,
                    )  # fmt: skip
                    start_seq[which] = len(items)
                    # one picture (a span shorter than the interval) PX4 sends on to the
                    # camera as DO_DIGICAM_CONTROL, a single shot (Navigator::
                    # publish_vehicle_command); more, as IMAGE_START_CAPTURE with the count
                    count = span.pictures(pending[k][0])
                    add(
                        Cmd.IMAGE_START_CAPTURE, Frame.MISSION,
                        0.0, float(span.interval_s), float(count), 0.0, 0, 0, 0.0,
                    )  # fmt: skip
                else:
                    add(Cmd.IMAGE_STOP_CAPTURE, Frame.MISSION, 0.0, 0.0, 0.0, 0.0, 0, 0, 0.0)
                k += 1
        wp_seq.append(next(it.seq for it in reversed(items) if it.command == Cmd.NAV_WAYPOINT))
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
                deg_e7(land_lat), deg_e7(land_lon), float(alt[-1]),
            )  # fmt: skip
        add(
            Cmd.NAV_LAND, g, 0.0, 0.0, 0.0, float("nan"), deg_e7(land_lat), deg_e7(land_lon),
            float(alt[-1]),
        )  # fmt: skip
    elif end is MissionEnd.RETURN:
        add(Cmd.NAV_RETURN_TO_LAUNCH, Frame.MISSION, 0.0, 0.0, 0.0, 0.0, 0, 0, 0.0)

    # Knots: arrive at each waypoint at its planned time, hold, leave; on the waypoint's
    # heading (param4) there, turning the shorter way between waypoints.
    kt: list[float] = []
    kp: list[np.ndarray] = []
    ky: list[float] = []
    for j in range(wp.shape[0]):
        kt += [arrival[j], arrival[j] + hold[j]]
        kp += [wp[j], wp[j]]
        ky += [float(yaw_enu[j]), float(yaw_enu[j])]
    path = PiecewiseLinearPath(np.asarray(kt), np.asarray(kp), np.unwrap(np.asarray(ky)))
    return MissionPlan(
        name=vname,
        items=tuple(items),
        waypoints_enu_m=wp,
        arrival_t_s=np.asarray(arrival),
        hold_s=np.asarray(hold),
        leg_speed_m_s=np.asarray(commanded),
        acceptance_m=radius,
        path=path,
        waypoint_seq=np.asarray(wp_seq, dtype=int),
        captures=tuple(
            ScheduledCapture(
                span, got[0][0], got[1][0] if got[1] is not None else None, start_seq[i]
            )
            if got is not None
            else ScheduledCapture(span, None, None)
            for i, (span, got) in enumerate(zip(captures, times, strict=True))
        ),
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
    """Exact STL robustness of the vehicles flying ``paths`` (signals: name -> ``(n, 3)`` ENU,
    ``(n, 4)`` with the heading where the path has one: :meth:`PiecewiseLinearPath.signal`).

    Sampled at ``t = 0, dt, ..., horizon`` (paths hold their last point beyond their end).
    """
    n = math.floor(horizon_s / dt_s + 1e-9) + 1
    t = np.arange(n) * dt_s
    signals = {name: p.signal(t) for name, p in paths.items()}
    return float(spec.robustness(signals, dt_s))
