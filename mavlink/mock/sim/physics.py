"""Translational quad-rotor dynamics of the whole fleet, vectorised over vehicles.

Each vehicle is a point mass in its own local NED frame (origin at its spawn
point, ground at ``down = 0``, or under a terrain where :attr:`FleetPhysics.ground_of`
puts it) driven by a PX4-like cascaded controller:

* position loop: ``v_cmd = v_ff + Kp_pos * (p_sp - p)``, the P term capped by the
  braking speed ``sqrt(2 a d)`` (no overshoot on large steps), limited to the
  horizontal speed ``vel_xy_max_m_s`` and the vertical speeds
  ``vel_up_max_m_s`` / ``vel_dn_max_m_s``;
* velocity loop (PI): ``a_cmd = a_ff + Kp_vel * (v_cmd - v) + Ki_vel * int(v_cmd - v)``,
  limited to ``acc_xy_max_m_s2`` horizontally and ``acc_up_max_m_s2`` /
  ``acc_dn_max_m_s2`` vertically;
* the airframe turns ``a_cmd`` into acceleration through two lags, as PX4 on SIH does:
  horizontally the tilt follows PX4's attitude loop, a first-order lag of
  ``1 / MC_ROLL_P`` (``att_tau_s``, 0.25 s with PX4's default gain 4; the rate loop
  inside it is fast), and every axis then the rotors' thrust lag (SIH_T_TAU, 0.05 s);
  ``att_tau_s = 0`` (the ideal profile) makes the tilt follow at once.  It feels
  linear aerodynamic drag ``-kdv * (v - wind)`` (SIH_KDV, 1/s for SIH's 1 kg quad), which
  the controller does not model: at a steady speed ``v`` it trails its setpoint by
  ``kdv / (Kp_pos * Kp_vel)`` seconds until the velocity integrator catches up, as PX4
  does on SIH.  With ``kdv = 0`` (the ideal profile) wind pushes with
  ``WindConfig.drag_per_s * wind`` instead.

The controller closes its loops on the *estimate* (:mod:`mavlink.mock.sim.estimator`):
``pos_ned_m`` / ``vel_ned_m_s`` are what the vehicle believes, in its local frame (origin
at its EKF origin); ``true_pos_ned_m`` / ``true_vel_ned_m_s`` are the truth in the spawn
frame (origin at the spawn point, ground at ``down = 0``).

Per axis, a setpoint may carry a position, a velocity and an acceleration
(``m_pos``/``m_vel``/``m_acc`` masks, 0 or 1): position (+ optional velocity and
acceleration feed-forward), velocity only, or acceleration only, as PX4 accepts
in ``SET_POSITION_TARGET_LOCAL_NED``.  A disarmed vehicle gets no thrust and
falls until it reaches the ground.  All arrays have one row per vehicle:
``(n, 3)`` for vectors in NED (m, m/s, m/s^2), ``(n,)`` for scalars.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from mavlink.mock.sim.config import NoiseConfig, WindConfig
from mavlink.mock.sim.estimator import FleetEstimator

GRAVITY_M_S2 = 9.80665


class Ground(Protocol):
    """The ground under the mission frame (a plan's :class:`planner.spec.terrain.Terrain`;
    the link layer does not import the planner's spec, docs/architecture.md)."""

    def ground(self, xy: np.ndarray) -> np.ndarray:
        """The ground's mission-frame ``z`` under points ``(n, 2)``."""
        ...


_BRAKE_MARGIN = 0.6


class FleetPhysics:
    """State, setpoints and limits of ``n`` vehicles, advanced by :meth:`step`."""

    def __init__(
        self,
        n: int,
        dt_s: float,
        rng: np.random.Generator,
        wind: WindConfig | None = None,
        noise: NoiseConfig | None = None,
        thrust_tau_s: float = 0.05,
    ) -> None:
        self.n = n
        self.dt_s = dt_s
        self.rng = rng
        self.wind = wind or WindConfig()
        #: per vehicle: the mean wind (north, east, m/s), the gusts' stationary std per
        #: horizontal axis and their correlation time (from ``wind``; the batch simulator
        #: (:mod:`mavlink.mock.sim.batch`) gives every row its own)
        self.wind_mean_ne_m_s = np.tile(np.asarray(self.wind.mean_ne_m_s, dtype=float), (n, 1))
        self.gust_sigma_m_s = np.full(n, self.wind.gust_sigma_m_s)
        self.gust_tau_s = np.full(n, self.wind.gust_tau_s)
        self.noise = noise or NoiseConfig()
        self._alpha = np.full(n, min(1.0, dt_s / thrust_tau_s))
        #: per vehicle: the tilt's time constant (1 / MC_ROLL_P; 0: the tilt follows at once)
        self.att_tau_s = np.zeros(n)
        self._acc_tilt = np.zeros((n, 2))  # the horizontal acceleration the tilt asks for
        # true state (spawn frame) and the estimate the controller flies on (local frame)
        self.true_pos_ned_m = np.zeros((n, 3))
        self.true_vel_ned_m_s = np.zeros((n, 3))
        self.pos_ned_m = np.zeros((n, 3))
        self.vel_ned_m_s = np.zeros((n, 3))
        self.estimator = FleetEstimator(n, dt_s, rng)
        self.acc_ned_m_s2 = np.zeros((n, 3))
        self.yaw_rad = np.zeros(n)
        self.yaw_rate_rad_s = np.zeros(n)
        self.armed = np.zeros(n, dtype=bool)
        #: armed but idling on the ground (PX4 spins up only when a take-off is wanted)
        self.idle = np.zeros(n, dtype=bool)
        self._vel_int = np.zeros((n, 3))
        # setpoints
        self.sp_pos_ned_m = np.zeros((n, 3))
        self.sp_vel_ned_m_s = np.zeros((n, 3))
        self.sp_acc_ned_m_s2 = np.zeros((n, 3))
        self.m_pos = np.zeros((n, 3))
        self.m_vel = np.zeros((n, 3))
        self.m_acc = np.zeros((n, 3))
        self.sp_yaw_rad = np.zeros(n)
        self.sp_yaw_rate_rad_s = np.zeros(n)
        self.m_yaw = np.zeros(n, dtype=bool)
        self.m_yaw_rate = np.zeros(n, dtype=bool)
        # limits and gains (PX4 defaults; vehicles overwrite them from their parameters)
        self.vel_xy_max_m_s = np.full(n, 12.0)
        self.vel_up_max_m_s = np.full(n, 3.0)
        self.vel_dn_max_m_s = np.full(n, 1.5)
        self.acc_xy_max_m_s2 = np.full(n, 5.0)
        self.acc_up_max_m_s2 = np.full(n, 4.0)
        self.acc_dn_max_m_s2 = np.full(n, 3.0)
        self.yaw_rate_max_rad_s = np.full(n, np.deg2rad(45.0))
        self.kp_pos = np.tile([0.95, 0.95, 1.0], (n, 1))
        self.kp_vel = np.tile([1.8, 1.8, 4.0], (n, 1))
        self.ki_vel = np.tile([0.4, 0.4, 2.0], (n, 1))
        self.kd_vel = np.zeros((n, 3))
        self._vel_dot = np.zeros((n, 3))  # the velocity's derivative (PX4's D term input)
        self.kdv_per_s = np.zeros(n)
        self.yaw_p = np.full(n, 2.0)
        # wind and telemetry noise
        self._gust_ne_m_s = np.zeros((n, 2))
        self.noise_pos_m = np.zeros((n, 3))
        self.noise_vel_m_s = np.zeros((n, 3))
        #: compute the attitude the specific force implies (ATTITUDE telemetry) every step
        self.attitude = True
        self.roll_rad = np.zeros(n)
        self.pitch_rad = np.zeros(n)
        self.roll_rate_rad_s = np.zeros(n)
        self.pitch_rate_rad_s = np.zeros(n)
        #: the ground's ``down`` under each vehicle in its spawn frame (0: flat at the spawn)
        self.ground_d_m = np.zeros(n)
        #: ``(n, 3)`` true spawn-frame positions -> ``(n,)`` the ground's ``down`` under them
        #: (:func:`terrain_ground`), or None for flat ground at each spawn
        self.ground_of: Callable[[np.ndarray], np.ndarray] | None = None

    def set_thrust_tau(self, i: int | slice | np.ndarray, tau_s: float) -> None:
        """The rotors' first-order time constant of vehicle(s) ``i`` (SIH_T_TAU)."""
        self._alpha[i] = min(1.0, self.dt_s / max(tau_s, 1e-9))

    def update_estimate(self) -> None:
        """Recompute the estimate from the truth without advancing time (after a reset)."""
        self.estimator.step(
            self.true_pos_ned_m, self.true_vel_ned_m_s, np.zeros(self.n),
            np.zeros(self.n, dtype=bool), self.pos_ned_m, self.vel_ned_m_s,
        )  # fmt: skip

    def hold_here(self, i: int | np.ndarray) -> None:
        """Make vehicle ``i`` (or the rows ``i`` selects) hold its current position and yaw."""
        self.set_position(i, self.pos_ned_m[i].copy())
        self.sp_yaw_rad[i] = self.yaw_rad[i]
        self.m_yaw[i] = True
        self.m_yaw_rate[i] = False

    def set_position(
        self,
        i: int | np.ndarray,
        pos_ned_m: np.ndarray,
        vel_ff_ned_m_s: np.ndarray | None = None,
        acc_ff_ned_m_s2: np.ndarray | None = None,
    ) -> None:
        """Position setpoint (all axes) with optional feed-forward for vehicle ``i``."""
        self.sp_pos_ned_m[i] = pos_ned_m
        self.m_pos[i] = 1.0
        if vel_ff_ned_m_s is None:
            self.m_vel[i] = 0.0
        else:
            self.sp_vel_ned_m_s[i] = vel_ff_ned_m_s
            self.m_vel[i] = 1.0
        if acc_ff_ned_m_s2 is None:
            self.m_acc[i] = 0.0
        else:
            self.sp_acc_ned_m_s2[i] = acc_ff_ned_m_s2
            self.m_acc[i] = 1.0

    def set_axes(
        self,
        i: int,
        pos_ned_m: np.ndarray,
        vel_ned_m_s: np.ndarray,
        acc_ned_m_s2: np.ndarray,
        m_pos: np.ndarray,
        m_vel: np.ndarray,
        m_acc: np.ndarray,
    ) -> None:
        """Per-axis setpoint with masks (each (3,), 1.0 where the component is used)."""
        self.sp_pos_ned_m[i] = pos_ned_m
        self.sp_vel_ned_m_s[i] = vel_ned_m_s
        self.sp_acc_ned_m_s2[i] = acc_ned_m_s2
        self.m_pos[i] = m_pos
        self.m_vel[i] = m_vel
        self.m_acc[i] = m_acc

    def step(self) -> None:
        """Advance every vehicle by ``dt_s``."""
        dt = self.dt_s
        pos, vel = self.pos_ned_m, self.vel_ned_m_s  # the estimate: PX4 flies on it
        # position loop
        err_pos = self.m_pos * (self.sp_pos_ned_m - pos)
        p_term = self.kp_pos * err_pos
        # the P term never asks for more speed than can be braked away before the target
        # (sqrt(2 a d) with margin for the loop lag), so large steps do not overshoot
        e_h = np.hypot(err_pos[:, 0], err_pos[:, 1])
        p_h = np.hypot(p_term[:, 0], p_term[:, 1])
        brake_h = np.sqrt(2.0 * _BRAKE_MARGIN * self.acc_xy_max_m_s2 * e_h)
        scale = np.minimum(1.0, brake_h / np.maximum(p_h, 1e-9))
        p_term[:, 0] *= scale
        p_term[:, 1] *= scale
        acc_v = np.where(err_pos[:, 2] > 0, self.acc_up_max_m_s2, self.acc_dn_max_m_s2)
        brake_v = np.sqrt(2.0 * _BRAKE_MARGIN * acc_v * np.abs(err_pos[:, 2]))
        np.clip(p_term[:, 2], -brake_v, brake_v, out=p_term[:, 2])
        v_cmd = p_term + self.m_vel * self.sp_vel_ned_m_s
        v_h = np.hypot(v_cmd[:, 0], v_cmd[:, 1])
        scale = np.minimum(1.0, self.vel_xy_max_m_s / np.maximum(v_h, 1e-9))
        v_cmd[:, 0] *= scale
        v_cmd[:, 1] *= scale
        np.clip(v_cmd[:, 2], -self.vel_up_max_m_s, self.vel_dn_max_m_s, out=v_cmd[:, 2])
        # velocity loop (PI with PX4's back-calculation anti-windup), inactive on axes that
        # only carry an acceleration
        vel_ctl = np.maximum(self.m_pos, self.m_vel)
        err = (v_cmd - vel) * vel_ctl
        a_cmd = (
            self.kp_vel * err
            + self._vel_int
            + self.m_acc * self.sp_acc_ned_m_s2
            - self.kd_vel * self._vel_dot * vel_ctl
        )
        a_unsat = a_cmd.copy()
        a_h = np.hypot(a_cmd[:, 0], a_cmd[:, 1])
        scale = np.minimum(1.0, self.acc_xy_max_m_s2 / np.maximum(a_h, 1e-9))
        a_cmd[:, 0] *= scale
        a_cmd[:, 1] *= scale
        np.clip(a_cmd[:, 2], -self.acc_up_max_m_s2, self.acc_dn_max_m_s2, out=a_cmd[:, 2])
        thrusting = self.armed & ~self.idle
        armed_col = thrusting[:, None]
        err_arw = err - (2.0 / self.kp_vel) * (a_unsat - a_cmd)
        self._vel_int += err_arw * self.ki_vel * dt * armed_col
        self._vel_int *= vel_ctl * armed_col  # PX4 resets the integrators on the ground
        a_cmd *= armed_col
        # airframe: the tilt's lag (horizontal), the rotors' (all axes), wind, gravity
        tilt = self._acc_tilt
        follow = np.minimum(1.0, dt / np.maximum(self.att_tau_s, 1e-9))
        tilt += (a_cmd[:, :2] - tilt) * follow[:, None]
        acc = self.acc_ned_m_s2
        alpha = self._alpha[:, None]
        acc[:, :2] += (tilt - acc[:, :2]) * alpha
        acc[:, 2] += (a_cmd[:, 2] - acc[:, 2]) * alpha[:, 0]
        a_total = acc.copy()
        pos, vel = self.true_pos_ned_m, self.true_vel_ned_m_s
        ground = self.ground_d_m
        airborne = pos[:, 2] < ground - 1e-3
        w = self.wind
        gusty = self.gust_sigma_m_s > 0.0
        if gusty.any():
            decay = dt / self.gust_tau_s
            self._gust_ne_m_s += -self._gust_ne_m_s * decay[:, None] + (
                self.gust_sigma_m_s * np.sqrt(2.0 * decay)
            )[:, None] * self.rng.standard_normal((self.n, 2))
        wind_ne = self.wind_mean_ne_m_s + self._gust_ne_m_s
        kdv = self.kdv_per_s
        has_drag = kdv > 0.0
        # ideal profile: wind as a force through WindConfig.drag_per_s, no drag on motion
        a_total[:, :2] += w.drag_per_s * wind_ne * (airborne & self.armed & ~has_drag)[:, None]
        # drag on the air-relative velocity (SIH: F = -KDV * v)
        air = vel.copy()
        air[:, :2] -= wind_ne
        a_total -= (kdv * airborne)[:, None] * air
        falling = ~thrusting & airborne
        a_total[falling, 2] = GRAVITY_M_S2 - kdv[falling] * vel[falling, 2]
        a_total[falling, :2] = -(kdv[falling])[:, None] * air[falling, :2]
        vel += a_total * dt
        pos += vel * dt
        self._vel_dot = a_total
        # ground contact: no penetration, no sliding
        if self.ground_of is not None:
            self.ground_d_m = ground = self.ground_of(pos)
        grounded = pos[:, 2] >= ground
        if grounded.any():
            pos[grounded, 2] = ground[grounded]
            vel[grounded, 2] = np.minimum(vel[grounded, 2], 0.0)
            vel[grounded, :2] = 0.0
            acc[grounded & (acc[:, 2] > 0.0), 2] = 0.0
        # yaw
        err_yaw = np.angle(np.exp(1j * (self.sp_yaw_rad - self.yaw_rad)))
        rate = np.where(
            self.m_yaw, self.yaw_p * err_yaw, np.where(self.m_yaw_rate, self.sp_yaw_rate_rad_s, 0.0)
        )
        rate = np.clip(rate, -self.yaw_rate_max_rad_s, self.yaw_rate_max_rad_s) * (
            self.armed & airborne
        )
        self.yaw_rate_rad_s = rate
        self.yaw_rad = np.angle(np.exp(1j * (self.yaw_rad + rate * dt)))
        # attitude implied by the specific force (for ATTITUDE telemetry)
        if self.attitude:
            self._attitude(acc, dt)
        # what the vehicle believes (its controller's input in the next step)
        # (the ground-effect creep runs whenever the motors spin: armed, idling or not)
        self.estimator.step(
            pos, vel, rate, self.armed, self.pos_ned_m, self.vel_ned_m_s, ground_d_m=ground
        )
        # telemetry noise for this tick
        nz = self.noise
        if nz.pos_m > 0.0 or nz.vel_m_s > 0.0:
            draw = self.rng.standard_normal((self.n, 6))
            self.noise_pos_m = draw[:, :3] * nz.pos_m
            self.noise_vel_m_s = draw[:, 3:] * nz.vel_m_s

    def _attitude(self, acc: np.ndarray, dt: float) -> None:
        """Roll and pitch (and their rates) implied by the specific force ``acc``."""
        c, s = np.cos(self.yaw_rad), np.sin(self.yaw_rad)
        a_fwd = acc[:, 0] * c + acc[:, 1] * s
        a_right = -acc[:, 0] * s + acc[:, 1] * c
        lift = GRAVITY_M_S2 - acc[:, 2]
        pitch = np.arctan2(-a_fwd, lift)
        roll = np.arctan2(a_right * np.cos(pitch), lift)
        self.roll_rate_rad_s = (roll - self.roll_rad) / dt
        self.pitch_rate_rad_s = (pitch - self.pitch_rad) / dt
        self.roll_rad, self.pitch_rad = roll, pitch


def terrain_ground(
    terrain: Ground, spawns_enu_m: Sequence[Sequence[float]] | np.ndarray
) -> Callable[[np.ndarray], np.ndarray]:
    """:attr:`FleetPhysics.ground_of` over a terrain (:class:`Ground`) for vehicles spawned at ``spawns_enu_m`` (mission ENU, one per physics row): the ground's
    ``down`` under a spawn-frame position is the spawn's height less the terrain's there. A
    spawn above the terrain stands on a platform: within half a metre of it the ground is
    the spawn's own height. (The spawn frame's axes are the mission frame's to within the
    tangent planes' turn, 1e-4 rad per km: a few millimetres of ground.)"""
    spawns = np.asarray(spawns_enu_m, dtype=float).reshape(-1, 3)

    def ground_of(pos_ned_m: np.ndarray) -> np.ndarray:
        xy = spawns[:, :2] + pos_ned_m[:, 1::-1]  # east, north
        down = spawns[:, 2] - terrain.ground(xy)
        pad = np.hypot(pos_ned_m[:, 0], pos_ned_m[:, 1]) < 0.5
        return np.where(pad, np.minimum(down, 0.0), down)

    return ground_of
