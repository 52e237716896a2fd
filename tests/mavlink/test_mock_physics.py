"""The mock's vectorised quad-rotor model and controller, without sockets."""

from __future__ import annotations

import numpy as np
import pytest

from mavlink.mock.sim.config import NoiseConfig, WindConfig
from mavlink.mock.sim.physics import FleetPhysics


def airborne_fleet(n: int, seed: int = 0, wind: WindConfig | None = None, noise: NoiseConfig | None = None) -> FleetPhysics:  # fmt: skip
    p = FleetPhysics(n, 0.01, np.random.default_rng(seed), wind, noise or NoiseConfig(0.0, 0.0))
    p.armed[:] = True
    p.true_pos_ned_m[:, 2] = -5.0
    p.update_estimate()  # bare physics: no estimator errors, the estimate is the truth
    for i in range(n):
        p.hold_here(i)
    return p


def run(p: FleetPhysics, seconds: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step for ``seconds``; positions, velocities, accelerations per step, (k, n, 3)."""
    pos, vel, acc = [], [], []
    for _ in range(round(seconds / p.dt_s)):
        p.step()
        pos.append(p.pos_ned_m.copy())
        vel.append(p.vel_ned_m_s.copy())
        acc.append(p.acc_ned_m_s2.copy())
    return np.array(pos), np.array(vel), np.array(acc)


def test_position_steps_converge_and_respect_speed_and_acceleration_limits() -> None:
    p = airborne_fleet(3)
    p.vel_xy_max_m_s[:] = (12.0, 3.0, 5.0)
    p.acc_xy_max_m_s2[:] = (5.0, 2.0, 3.0)
    targets = np.array([[20.0, 0.0, -5.0], [-10.0, 10.0, -5.0], [0.0, 0.0, -15.0]])
    for i in range(3):
        p.set_position(i, targets[i])
    pos, vel, acc = run(p, 30.0)
    assert np.abs(pos[-1] - targets).max() < 0.05
    speed_h = np.hypot(vel[..., 0], vel[..., 1])
    acc_h = np.hypot(acc[..., 0], acc[..., 1])
    # the first-order thrust lag never exceeds what the controller commands
    assert (acc_h <= p.acc_xy_max_m_s2 + 1e-9).all()
    # speed may exceed the limit only by the velocity loop's small tracking error
    assert (speed_h.max(axis=0) <= p.vel_xy_max_m_s * 1.05).all()
    assert speed_h[:, 1].max() > 0.95 * 3.0  # the limit is actually reached
    assert -vel[:, 2, 2].min() <= 3.0 * 1.05  # climb limit MPC_Z_VEL_MAX_UP
    # and the step is flown without a large overshoot
    assert pos[:, 0, 0].max() < 20.0 + 0.3


def test_feed_forward_tracks_a_circle_better_than_position_alone() -> None:
    radius_m, omega = 5.0, 0.8
    t = np.arange(0.0, 20.0, 0.01) + 0.01
    ref = np.stack([radius_m * np.cos(omega * t), radius_m * np.sin(omega * t), -5.0 + 0 * t], 1)
    ref_v = np.stack(
        [-radius_m * omega * np.sin(omega * t), radius_m * omega * np.cos(omega * t), 0 * t], 1
    )
    ref_a = np.stack([-radius_m * omega**2 * np.cos(omega * t), -radius_m * omega**2 * np.sin(omega * t), 0 * t], 1)  # fmt: skip

    def track(feed_forward: bool) -> float:
        p = airborne_fleet(1)
        p.true_pos_ned_m[0] = (radius_m, 0.0, -5.0)
        p.true_vel_ned_m_s[0] = (0.0, radius_m * omega, 0.0)
        p.update_estimate()
        errors = []
        for k in range(len(t)):
            if feed_forward:
                p.set_position(0, ref[k], ref_v[k], ref_a[k])
            else:
                p.set_position(0, ref[k])
            p.step()
            errors.append(np.linalg.norm(p.pos_ned_m[0] - ref[k]))
        return float(np.max(errors[500:]))

    with_ff, without = track(True), track(False)
    assert with_ff < 0.15
    assert without > 5 * with_ff


def test_velocity_and_acceleration_only_setpoints() -> None:
    p = airborne_fleet(2)
    p.set_axes(0, np.zeros(3), np.array([2.0, -1.0, 0.0]), np.zeros(3), np.zeros(3), np.ones(3), np.zeros(3))  # fmt: skip
    p.set_axes(1, np.zeros(3), np.zeros(3), np.array([1.0, 0.0, 0.0]), np.zeros(3), np.zeros(3), np.ones(3))  # fmt: skip
    _, vel, _ = run(p, 3.0)
    # a constant 1 m/s^2 gives ~3 m/s after 3 s (minus the thrust lag)
    assert vel[-1, 1, 0] == pytest.approx(3.0 - 0.05, abs=0.05)
    _, vel, _ = run(p, 7.0)
    assert vel[-1, 0] == pytest.approx([2.0, -1.0, 0.0], abs=0.03)


def test_integrator_rejects_steady_wind() -> None:
    wind = WindConfig(mean_ne_m_s=(5.0, -3.0), drag_per_s=0.35)
    p = airborne_fleet(1, wind=wind)
    pos, _, _ = run(p, 25.0)
    assert np.abs(pos[-1, 0] - [0.0, 0.0, -5.0]).max() < 0.05
    assert np.abs(pos[200:600, 0, :2]).max() > 0.1  # the gust of wind did push it first


def test_disarmed_vehicle_falls_and_stays_on_the_ground() -> None:
    p = airborne_fleet(1)
    p.armed[:] = False
    pos, vel, _ = run(p, 2.0)
    assert pos[-1, 0, 2] == 0.0 and vel[-1, 0, 2] == 0.0
    t_hit = np.argmax(pos[:, 0, 2] >= 0.0) * p.dt_s
    assert t_hit == pytest.approx(np.sqrt(2 * 5.0 / 9.80665), abs=0.03)


def test_same_seed_same_flight_other_seed_other_flight() -> None:
    def flight(seed: int) -> np.ndarray:
        p = airborne_fleet(4, seed, WindConfig(gust_sigma_m_s=1.0), NoiseConfig(0.05, 0.05))
        for i in range(4):
            p.set_position(i, np.array([3.0 * i, 2.0, -6.0]))
        out = []
        for _ in range(300):
            p.step()
            out.append(np.concatenate([p.pos_ned_m.ravel(), p.noise_pos_m.ravel()]))
        return np.array(out)

    a, b, c = flight(11), flight(11), flight(12)
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)


def test_tilt_follows_the_attitude_loop_then_the_rotors_and_thrust_only_the_rotors() -> None:
    # PX4 on SIH: the horizontal acceleration comes from the tilt, which the attitude loop
    # brings to its setpoint with time constant 1 / MC_ROLL_P (0.25 s at PX4's gain 4);
    # the rotors then follow with SIH_T_TAU (0.05 s).  Vertical acceleration is thrust
    # alone.  An acceleration-only setpoint (no position or velocity loop) shows the two.
    tau_att, tau_rot, dt = 0.25, 0.05, 0.01
    p = airborne_fleet(2)
    p.att_tau_s[:] = (tau_att, 0.0)  # vehicle 1: the ideal tilt, at once
    for i in range(2):
        p.set_thrust_tau(i, tau_rot)
        p.set_axes(i, np.zeros(3), np.zeros(3), np.array([2.0, 0.0, -1.0]), np.zeros(3), np.zeros(3), np.ones(3))  # fmt: skip
    _, _, acc = run(p, 1.5)
    t = np.arange(1, len(acc) + 1) * dt

    def two_lags(t: np.ndarray, a: float, b: float) -> np.ndarray:
        return 1.0 - (a * np.exp(-t / a) - b * np.exp(-t / b)) / (a - b)

    # (Euler steps of 0.01 s against the continuous responses)
    assert np.allclose(acc[:, 0, 0] / 2.0, two_lags(t, tau_att, tau_rot), atol=0.035)
    assert np.allclose(acc[:, 1, 0] / 2.0, 1.0 - np.exp(-t / tau_rot), atol=0.05)
    for i in range(2):
        assert np.allclose(acc[:, i, 2] / -1.0, 1.0 - np.exp(-t / tau_rot), atol=0.05)
    # 63 % of the horizontal step after about tau_att + tau_rot, not after tau_rot
    k63 = int(np.argmax(acc[:, 0, 0] >= 0.63 * 2.0))
    assert 0.26 <= t[k63] <= 0.34
