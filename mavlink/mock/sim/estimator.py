"""What the mock vehicles believe about themselves: a PX4-in-SIH-like state estimate.

PX4 flies on its EKF2 estimate, not on the truth, and on PX4 v1.17 SITL with the SIH
quad-rotor that estimate is measurably off (``docs/px4-behaviour.md``):

* the local origin is the first GPS fix, 0.2-0.4 m horizontally and 0.1-0.6 m below
  where the vehicle really stands, different at every boot, and the estimate
  keeps that offset: the vehicle believes it is at its origin when it boots, so in the
  mission frame everything it reports (and flies to) is off by the origin's error;
* on top of that a slowly varying bias and noise; the velocity estimate is off by up
  to ~0.3 m/s rms, more during a yaw turn, and part of that error is a slow horizontal
  bias (~0.1 m/s per axis, correlated over tens of seconds).  PX4's position loop settles where
  the *estimated* velocity is zero-error, so a velocity bias ``b`` holds the hovering
  estimate about ``b / MPC_XY_P`` off its setpoint: the static 0.2-0.35 m hover offsets
  PX4 SITL showed, which the tracking error of every flight carries;
* near the ground (EKF2's ground-effect baro dead zone) the estimated altitude creeps up
  0.5-1.2 m while the vehicle really stays low or on the ground.

:class:`FleetEstimator` models exactly these effects, vectorised over the fleet, with its
magnitudes taken from the vehicles' ``MOCK_*`` parameters (:mod:`mavlink.mock.px4`); all
zero gives the ideal estimate (the truth).  Frames: the truth is kept in a *spawn frame*
(NED, origin at the spawn point, ground at ``down = 0``); the estimate is in the
vehicle's *local frame*, whose origin is its (noisy) EKF origin.  With ``origin_ned_m``
the EKF origin expressed in the spawn frame::

    est_pos = true_pos - origin_ned_m + boot_origin_ned_m + bias_slow + drift + white - creep * e_down
    est_vel = true_vel + vel_err + vel_bias

(``origin_ned_m`` equals ``boot_origin_ned_m`` until a client moves the origin with
SET_GPS_GLOBAL_ORIGIN.)  The estimate's error against the truth is therefore
``boot_origin_ned_m + bias_slow + drift + white - creep * e_down`` in any frame.

``drift`` integrates the velocity error (noise and bias) and is pulled back by GPS with
``_GPS_TAU_S`` so a velocity disturbance (a yaw turn) shows in the position estimate for
about a second, as on PX4.  Arrays have one row per vehicle: ``(n, 3)`` NED vectors, ``(n,)`` scalars.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_GPS_TAU_S = 1.0  # how fast GPS pulls a velocity-error drift out of the position estimate
_CREEP_DECAY_TAU_S = 2.0  # baro fused again out of ground effect


@dataclass(frozen=True, slots=True)
class EstimatorParams:
    """Magnitudes of the estimate's errors for one vehicle (from its ``MOCK_*`` parameters).

    Attributes:
        origin_xy_m: (min, max) horizontal distance of the EKF origin from the spawn.
        origin_z_m: (min, max) depth of the EKF origin below the true ground.  On PX4 SITL
            the in-flight estimate read about 0.26 m low (NED +0.26) and no 0.75 m start
            ever came out less than 0.3 m above home: the origin (and home) lay below the
            ground, so the vehicle flies that much higher than it believes.
        bias_slow_m: std of the slowly varying bias, per axis (correlation ``bias_tau_s``).
        bias_tau_s: correlation time of the slow bias.
        pos_noise_m: white noise on the position estimate, per axis.
        vel_noise_m_s: std of the velocity error, per axis (correlation ``vel_tau_s``).
        vel_tau_s: correlation time of the velocity error.
        vel_bias_m_s: std of the slow horizontal velocity bias, per axis.
        vel_bias_tau_s: correlation time of that bias.
        yaw_vel_m_s_per_rad_s: extra velocity-error std per rad/s of yaw rate.
        creep_height_m: below this true height above ground the altitude creeps (0: never).
        creep_rate_m_s: how fast it creeps while armed there (props spinning).
        creep_max_m: (min, max) of the per-boot creep ceiling.
    """

    origin_xy_m: tuple[float, float] = (0.0, 0.0)
    origin_z_m: tuple[float, float] = (0.0, 0.0)
    bias_slow_m: float = 0.0
    bias_tau_s: float = 20.0
    pos_noise_m: float = 0.0
    vel_noise_m_s: float = 0.0
    vel_tau_s: float = 0.3
    vel_bias_m_s: float = 0.0
    vel_bias_tau_s: float = 30.0
    yaw_vel_m_s_per_rad_s: float = 0.0
    creep_height_m: float = 0.0
    creep_rate_m_s: float = 0.0
    creep_max_m: tuple[float, float] = (0.0, 0.0)

    @classmethod
    def from_params(cls, p: dict[str, float]) -> EstimatorParams:
        """From a vehicle's parameter table (``MOCK_*`` names)."""
        return cls(
            origin_xy_m=(p["MOCK_ORG_XY_MIN"], p["MOCK_ORG_XY_MAX"]),
            origin_z_m=(p["MOCK_ORG_Z_MIN"], p["MOCK_ORG_Z_MAX"]),
            bias_slow_m=p["MOCK_EST_SLOW_B"],
            bias_tau_s=max(p["MOCK_EST_B_TAU"], 1e-3),
            pos_noise_m=p["MOCK_EST_P_N"],
            vel_noise_m_s=p["MOCK_EST_V_N"],
            vel_tau_s=max(p["MOCK_EST_V_TAU"], 1e-3),
            vel_bias_m_s=p["MOCK_EST_VB"],
            vel_bias_tau_s=max(p["MOCK_EST_VB_TAU"], 1e-3),
            yaw_vel_m_s_per_rad_s=p["MOCK_EST_YAW_V"],
            creep_height_m=p["MOCK_GE_HGT"],
            creep_rate_m_s=p["MOCK_GE_RATE"],
            creep_max_m=(p["MOCK_GE_MIN"], p["MOCK_GE_MAX"]),
        )


def _ou_step(x: np.ndarray, a: np.ndarray, sd: np.ndarray, draw: np.ndarray) -> None:
    """One step of a stationary Ornstein-Uhlenbeck process in place: ``a = dt / tau``,
    stationary std ``sd``, ``draw`` standard normal."""
    x += -x * a + sd * np.sqrt(2 * a) * draw


class FleetEstimator:
    """The estimated state of ``n`` vehicles, updated from the truth every physics step."""

    def __init__(self, n: int, dt_s: float, rng: np.random.Generator) -> None:
        self.n = n
        self.dt_s = dt_s
        self.rng = rng
        #: EKF origin of each vehicle in its spawn frame (NED, m).
        self.origin_ned_m = np.zeros((n, 3))
        #: the EKF origin at boot, in the spawn frame: the estimate's per-boot error
        self.boot_origin_ned_m = np.zeros((n, 3))
        self.bias_slow_m = np.zeros((n, 3))
        self.drift_m = np.zeros((n, 3))
        self.vel_err_m_s = np.zeros((n, 3))
        #: the slow horizontal velocity bias (down component always 0)
        self.vel_bias_m_s = np.zeros((n, 3))
        self.creep_m = np.zeros(n)
        self.creep_max_m = np.zeros(n)
        # per-vehicle magnitudes, (n,) each
        self._slow_sd = np.zeros((n, 1))
        self._slow_tau = np.ones((n, 1))
        self._pos_sd = np.zeros((n, 1))
        self._vel_sd = np.zeros((n, 1))
        self._vel_tau = np.ones((n, 1))
        self._vb_sd = np.zeros((n, 1))
        self._vb_tau = np.ones((n, 1))
        self._yaw_gain = np.zeros((n, 1))
        self._creep_h = np.zeros(n)
        self._creep_rate = np.zeros(n)
        self.active = False

    def configure(self, i: int, prm: EstimatorParams, *, new_boot: bool) -> None:
        """Set vehicle ``i``'s magnitudes; ``new_boot`` also draws its origin and biases."""
        rng = self.rng
        if new_boot:
            lo, hi = prm.origin_xy_m
            r = rng.uniform(lo, hi) if hi > 0 else 0.0
            ang = rng.uniform(0.0, 2.0 * np.pi)
            lo, hi = prm.origin_z_m
            below = rng.uniform(lo, hi) if hi > 0 else 0.0
            self.origin_ned_m[i] = (r * np.cos(ang), r * np.sin(ang), below)
            self.boot_origin_ned_m[i] = self.origin_ned_m[i]
            self.bias_slow_m[i] = rng.standard_normal(3) * prm.bias_slow_m
            self.vel_bias_m_s[i, :2] = rng.standard_normal(2) * prm.vel_bias_m_s
            lo, hi = prm.creep_max_m
            self.creep_max_m[i] = rng.uniform(lo, hi) if hi > 0 else 0.0
        self._slow_sd[i] = prm.bias_slow_m
        self._slow_tau[i] = prm.bias_tau_s
        self._pos_sd[i] = prm.pos_noise_m
        self._vel_sd[i] = prm.vel_noise_m_s
        self._vel_tau[i] = prm.vel_tau_s
        self._vb_sd[i] = prm.vel_bias_m_s
        self._vb_tau[i] = prm.vel_bias_tau_s
        if not prm.vel_bias_m_s:
            self.vel_bias_m_s[i] = 0.0
        self._yaw_gain[i] = prm.yaw_vel_m_s_per_rad_s
        self._creep_h[i] = prm.creep_height_m
        self._creep_rate[i] = prm.creep_rate_m_s
        self.active = bool(
            np.any(self._slow_sd)
            or np.any(self._pos_sd)
            or np.any(self._vel_sd)
            or np.any(self._vb_sd)
            or np.any(self._yaw_gain)
            or np.any(self._creep_rate)
        )

    def set_origin(self, i: int, origin_ned_m: np.ndarray) -> None:
        """Vehicle ``i``'s EKF origin moved to ``origin_ned_m`` (its spawn frame, m)."""
        self.origin_ned_m[i] = origin_ned_m

    def step(
        self,
        true_pos_ned_m: np.ndarray,
        true_vel_ned_m_s: np.ndarray,
        yaw_rate_rad_s: np.ndarray,
        motors_on: np.ndarray,
        out_pos_ned_m: np.ndarray,
        out_vel_ned_m_s: np.ndarray,
        ground_d_m: np.ndarray | float = 0.0,
    ) -> None:
        """Advance the error processes by one step and write the estimate into ``out_*``.

        ``motors_on`` (n,) bool: armed (props spinning, idling on the ground or not).
        ``ground_d_m``: the ground's ``down`` under each vehicle (spawn frame; 0: flat).
        """
        dt = self.dt_s
        if self.active:
            rng = self.rng
            draw = rng.standard_normal((self.n, 11))
            _ou_step(self.bias_slow_m, dt / self._slow_tau, self._slow_sd, draw[:, :3])
            sd_v = np.sqrt(self._vel_sd**2 + (self._yaw_gain * yaw_rate_rad_s[:, None]) ** 2)
            _ou_step(self.vel_err_m_s, dt / self._vel_tau, sd_v, draw[:, 3:6])
            _ou_step(self.vel_bias_m_s[:, :2], dt / self._vb_tau, self._vb_sd, draw[:, 9:11])
            self.drift_m += (self.vel_err_m_s + self.vel_bias_m_s - self.drift_m / _GPS_TAU_S) * dt
            white = self._pos_sd * draw[:, 6:9]
            agl = ground_d_m - true_pos_ned_m[:, 2]
            in_effect = motors_on & (agl < self._creep_h)
            grow = np.minimum(self.creep_m + self._creep_rate * dt, self.creep_max_m)
            decayed = self.creep_m * np.exp(-dt / _CREEP_DECAY_TAU_S)
            self.creep_m = np.where(
                in_effect,
                np.maximum(self.creep_m, grow),
                np.where(agl >= self._creep_h, decayed, self.creep_m),
            )
        else:
            white = np.zeros(1)
        np.subtract(true_pos_ned_m, self.origin_ned_m, out=out_pos_ned_m)
        out_pos_ned_m += self.boot_origin_ned_m + self.bias_slow_m + self.drift_m + white
        out_pos_ned_m[:, 2] -= self.creep_m
        np.add(true_vel_ned_m_s, self.vel_err_m_s, out=out_vel_ned_m_s)
        out_vel_ned_m_s += self.vel_bias_m_s
