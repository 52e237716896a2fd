"""PX4's navigation geometry for one simulated vehicle: the auto modes' trajectory setpoint,
corner speeds, and the geofence with its predicted braking point.

What PX4 v1.17 computes between a mission item and the position controller, apart from the
mission items themselves (those, their MAVLink commands and what the vehicle reports about
them are the endpoint's: :mod:`mavlink.mock.navigator`):

* :class:`AutoTrajectory`: the trajectory setpoint of ``FlightTaskAuto`` and its
  ``PositionSmoothing``: along the leg from the previous waypoint to the target, limited by
  the cruise speed, MPC_ACC_HOR and MPC_JERK_AUTO, arriving at the corner speed; back on the
  line first when the vehicle is off it by more than the acceptance radius; its clock slowed
  while the vehicle trails it (MPC_XY_ERR_MAX).
* :func:`corner_speed`: ``min(sqrt(MPC_XY_TRAJ_P * MPC_ACC_HOR * R * tan(alpha / 2)), exit
  speed)`` (``TrajectoryConstraints.hpp``), with :func:`max_speed_from_distance`
  (``TrajMath.hpp``).
* :class:`Geofence`: inclusion and exclusion polygons and circles in the local frame, and
  the point where PX4's predictive geofence (GF_PREDICT) expects the vehicle to stop:
  ``v * (v / (2 MPC_ACC_HOR) + 0.6)`` ahead (``computeBrakingDistanceFromVelocity``).

Sources: PX4 v1.17.0 ``src/modules/flight_mode_manager/tasks/Auto/FlightTaskAuto.cpp``,
``src/lib/motion_planning/PositionSmoothing.cpp``, ``TrajectoryConstraints.hpp``,
``TrajMath.hpp``, ``src/modules/navigator/geofence.cpp``; what SITL showed of them is in
docs/px4-behaviour.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

__all__ = [
    "GF_DELAY_FACTOR",
    "AutoTrajectory",
    "FenceZone",
    "Geofence",
    "braking_point",
    "corner_speed",
    "max_speed_from_distance",
    "point_in_polygon",
]

#: PX4's braking-distance delay: accel_delay_max = 0.6 * MPC_JERK_AUTO, in seconds of speed.
GF_DELAY_FACTOR = 0.6


def max_speed_from_distance(jerk: float, accel: float, dist_m: float, final_m_s: float) -> float:
    """PX4's ``computeMaxSpeedFromDistance`` (TrajMath.hpp): the speed from which a
    jerk- and acceleration-limited stop ends at ``final_m_s`` after ``dist_m``."""
    b = 4.0 * accel * accel / jerk
    c = -2.0 * accel * max(dist_m, 0.0) - final_m_s * final_m_s
    return 0.5 * (-b + math.sqrt(b * b - 4.0 * c))


def corner_speed(
    prev: np.ndarray,
    target: np.ndarray,
    nxt: np.ndarray | None,
    radius_m: float,
    p: Mapping[str, float],
) -> float:
    """PX4's speed at ``target`` heading for ``nxt`` (TrajectoryConstraints.hpp), m/s.

    ``alpha`` is the angle at the waypoint between the legs (pi: straight on); the speed
    is 0 without a next waypoint or when the next one lies within the acceptance radius.
    """
    if nxt is None:
        return 0.0
    out = nxt - target
    d_next = float(np.linalg.norm(out))
    if d_next < radius_m:
        return 0.0
    inc = prev - target
    n_in = float(np.linalg.norm(inc))
    if n_in < 1e-6:
        alpha = math.pi
    else:
        cos_a = float(np.dot(inc, out)) / (n_in * d_next)
        alpha = math.acos(max(-1.0, min(1.0, cos_a)))
    acc, jerk = p["MPC_ACC_HOR"], p["MPC_JERK_AUTO"]
    half = alpha / 2.0
    turn = (
        math.inf
        if half >= math.pi / 2 - 1e-9
        else math.sqrt(max(0.0, p["MPC_XY_TRAJ_P"] * acc * radius_m * math.tan(half)))
    )
    return min(turn, max_speed_from_distance(jerk, acc, d_next, 0.0))


class AutoTrajectory:
    """PX4's trajectory setpoint in the auto modes, for one vehicle (local NED, m and m/s).

    :meth:`begin` starts a leg (from where the setpoint is, or from the vehicle when none is
    active); :meth:`step` advances the setpoint one physics step and returns what the
    position controller is to track.
    """

    def __init__(self) -> None:
        #: whether a setpoint is being flown (False: the next leg starts at the vehicle)
        self.active = False
        self.pos = np.zeros(3)
        self.vel = np.zeros(3)
        #: where the setpoint was when the leg began
        self.start = np.zeros(3)
        #: the speed the setpoint may keep at the target (the corner speed)
        self.exit_m_s = 0.0
        #: PX4's previous triplet waypoint, the current item's acceptance radius, the next
        self.prev = np.zeros(3)
        self.radius_m = 2.0
        self.next: np.ndarray | None = None

    def begin(
        self,
        vehicle_pos: np.ndarray,
        target: np.ndarray,
        prev: np.ndarray,
        nxt: np.ndarray | None,
        radius_m: float,
        prm: Mapping[str, float],
        cruise_m_s: float,
    ) -> None:
        """Start the leg ``prev`` -> ``target`` (then ``nxt``, None: stop there) with
        acceptance radius ``radius_m``."""
        if not self.active:
            self.pos = np.asarray(vehicle_pos, dtype=float).copy()
            self.vel = np.zeros(3)
            self.active = True
        self.start = self.pos.copy()
        self.exit_m_s = min(corner_speed(self.start, target, nxt, radius_m, prm), cruise_m_s)
        self.prev = np.asarray(prev, dtype=float).copy()
        self.radius_m = radius_m
        self.next = nxt

    def aim(
        self, pos: np.ndarray, target: np.ndarray, prm: Mapping[str, float]
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Where PX4's trajectory heads this cycle for a vehicle (estimate) at ``pos``:
        ``(aim, from, exit speed)``.

        PX4's ``FlightTaskAuto::_getCurrentState`` / ``_updateInternalWaypoints``, on the
        vehicle's estimate against the leg from the previous waypoint to the target:
        the target behind the vehicle, it goes straight for the target; the previous
        waypoint still ahead (and farther than the acceptance radius), for that one;
        farther than the acceptance radius from the leg ("offtrack"), for the closest
        point on the leg, turning there toward the target at the corner speed.  With a
        small radius a vehicle that PX4's own lag or its estimate keeps off the line
        hunts for it, stopping and turning back: PX4 SITL lost 18-35 s on one waypoint.
        """
        prev, radius = self.prev, self.radius_m
        leg = target - prev
        length = float(np.linalg.norm(leg))
        if length < 1e-6:
            return target, self.start, self.exit_m_s
        u = leg / length
        if float(np.dot(u, target - pos)) < 0.0:  # target behind
            return target, pos, self.exit_m_s
        to_pos = pos - prev
        if float(np.dot(u, to_pos)) < 0.0 and float(np.linalg.norm(to_pos)) > radius:
            return prev, pos, corner_speed(pos, prev, target, radius, prm)
        closest = prev + u * float(np.dot(to_pos, u))
        if float(np.linalg.norm(pos - closest)) > radius:  # offtrack
            return closest, pos, corner_speed(pos, closest, target, radius, prm)
        return target, self.start, self.exit_m_s

    def step(
        self,
        pos: np.ndarray,
        target: np.ndarray,
        dt_s: float,
        prm: Mapping[str, float],
        cruise_m_s: float,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance the setpoint one step of ``dt_s`` toward ``target`` for a vehicle at
        ``pos``: the ``(position, velocity, acceleration)`` to command.

        The setpoint heads for the target (or where :meth:`aim` sends it) at the speed
        from which it can still slow to the exit (corner) speed there, within the cruise
        speed, turning at MPC_ACC_HOR; having passed it (the vehicle not yet accepted) it
        comes back and waits there, as PX4 does when the vehicle misses the acceptance
        circle.  While the vehicle is behind the setpoint, the setpoint's clock is slowed
        by ``1 - error / MPC_XY_ERR_MAX`` (PX4's ``PositionSmoothing`` time stretch): a
        vehicle trailing by its drag lag holds its own setpoint back.
        """
        dt = dt_s
        acc, jerk = prm["MPC_ACC_HOR"], prm["MPC_JERK_AUTO"]
        aim, start, v_exit = self.aim(pos, target, prm)
        behind = self.pos[:2] - pos[:2]
        if float(np.dot(behind, self.vel[:2])) >= 0.0:
            dt *= 1.0 - min(1.0, float(np.linalg.norm(behind)) / prm["MPC_XY_ERR_MAX"])
        if dt <= 1e-9:  # the vehicle a whole MPC_XY_ERR_MAX behind: the setpoint waits
            return self.pos.copy(), self.vel.copy(), np.zeros(3)
        to = aim - self.pos
        dist = float(np.linalg.norm(to))
        passed = float(np.dot(aim - start, to)) < 0.0
        v_exit = 0.0 if passed else v_exit
        speed = min(cruise_m_s, max_speed_from_distance(jerk, acc, dist, v_exit))
        if dist < 1e-3 and v_exit == 0.0:
            self.pos = aim.copy()
            self.vel[:] = 0.0
            a = np.zeros(3)
        else:
            v_des = to / max(dist, 1e-9) * speed
            up, dn = prm["MPC_Z_VEL_MAX_UP"], prm["MPC_Z_VEL_MAX_DN"]
            if v_des[2] < -up or v_des[2] > dn:
                v_des *= (up if v_des[2] < 0 else dn) / abs(v_des[2])
            dv = v_des - self.vel
            n = float(np.linalg.norm(dv))
            a = dv / dt if n <= acc * dt else dv / n * acc
            self.vel = self.vel + a * dt
            self.pos = self.pos + self.vel * dt
        return self.pos.copy(), self.vel.copy(), a

    def hold_height(self, down_m: float) -> None:
        """Keep the setpoint, its leg and its vertical speed at the height ``down_m`` (a
        land item has no altitude: PX4 keeps the horizontal trajectory at the vehicle's)."""
        self.pos[2] = self.prev[2] = down_m
        self.vel[2] = 0.0


#: One geofence zone: ``("polygon" | "circle", inclusion, vertices (k, 2) | centre (2,),
#: radius (circles; 0 for polygons))``, north-east in metres.
FenceZone = tuple[str, bool, np.ndarray, float]


class Geofence:
    """Inclusion and exclusion zones in the local frame (north, east; unlimited height)."""

    def __init__(self, zones: Sequence[FenceZone] = ()) -> None:
        self.zones = list(zones)

    def __bool__(self) -> bool:
        return bool(self.zones)

    def violated(self, pos_ned_m: np.ndarray) -> bool:
        """True if the local point (3,) lies outside an inclusion or inside an exclusion zone."""
        ne = pos_ned_m[:2]
        for kind, inclusion, data, radius in self.zones:
            if kind == "circle":
                inside = float(np.hypot(*(ne - data))) <= radius
            else:
                inside = point_in_polygon(ne, data)
            if inside != inclusion:
                return True
        return False


def braking_point(
    pos_ned_m: np.ndarray, vel_ned_m_s: np.ndarray, acc_hor_m_s2: float
) -> np.ndarray:
    """Where PX4's geofence expects a vehicle at ``pos`` moving at ``vel`` to stop:
    ``computeBrakingDistanceFromVelocity(v, MPC_JERK_AUTO, MPC_ACC_HOR, 0.6 *
    MPC_JERK_AUTO)`` = ``v * (v / (2 MPC_ACC_HOR) + 0.6)`` along the horizontal velocity."""
    pos = np.asarray(pos_ned_m, dtype=float).copy()
    speed = math.hypot(vel_ned_m_s[0], vel_ned_m_s[1])
    if speed > 1e-3:
        dist = speed * (speed / (2.0 * acc_hor_m_s2) + GF_DELAY_FACTOR)
        pos[:2] += vel_ned_m_s[:2] / speed * dist
    return pos


def point_in_polygon(pt: np.ndarray, poly: np.ndarray) -> bool:
    """Even-odd rule for a point (2,) and polygon vertices (k, 2)."""
    x, y = float(pt[0]), float(pt[1])
    xs, ys = poly[:, 0], poly[:, 1]
    xj, yj = np.roll(xs, 1), np.roll(ys, 1)
    crosses = (ys > y) != (yj > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_int = (xj - xs) * (y - ys) / (yj - ys) + xs
    return bool(np.count_nonzero(crosses & (x < x_int)) % 2)
