"""The mock's ``px4`` profile against PX4 v1.17 SITL (SIH): control and estimation.

Row by row of docs/px4-behaviour.md: the profiles as parameter tables, drag and the lag it
makes, the estimator, yaw.  Take-off, missions, storage and the geofence are in
test_mock_px4_navigator.py.

The fleet is stepped offline (:meth:`MockFleet.advance`: simulated time, no sockets), and
the vehicles are spoken to in MAVLink bytes through :meth:`MockVehicle.receive`, so every
figure here is deterministic for its seed.  The references are PX4's own: its source's
formulas (PositionControl, TrajMath, TrajectoryConstraints, mavlink_mission.cpp) and the
figures observed on PX4 SITL.
"""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import MockConfigError, MockFleet
from tests.mavlink.mock_px4_helpers import NO_CREEP, QUIET, cmd, fleet, offboard_hover, stream

# ------------------------------------------------------------------ profiles and parameters


def test_profiles_are_parameter_tables_readable_and_settable_over_mavlink() -> None:
    px4, ideal = MockFleet(n=1).vehicles[0], MockFleet(n=1, profile="ideal").vehicles[0]
    assert px4.params["SIH_KDV"] == 1.0 and ideal.params["SIH_KDV"] == 0.0
    assert px4.params["GF_PREDICT"] == 1 and ideal.params["GF_PREDICT"] == 0
    assert px4.params["MOCK_PX4_NAV"] == 1 and ideal.params["MOCK_PX4_NAV"] == 0
    f = fleet()
    v = f.vehicles[0]
    v.receive(mavlink2.MAVLink_param_request_read_message(1, 1, b"MPC_XY_TRAJ_P", -1))
    (pv,) = [m for m in v.sent_messages() if m.get_type() == "PARAM_VALUE"]
    assert pv.param_id == "MPC_XY_TRAJ_P" and pv.param_value == pytest.approx(0.5)
    v.receive(mavlink2.MAVLink_param_set_message(1, 1, b"SIH_KDV", 0.25, 9))
    assert f.physics.kdv_per_s[0] == 0.25
    v.sent_messages()
    # out of PX4's range: refused, the old value answered
    v.receive(mavlink2.MAVLink_param_set_message(1, 1, b"SIH_KDV", 50.0, 9))
    (pv,) = [m for m in v.sent_messages() if m.get_type() == "PARAM_VALUE"]
    assert pv.param_value == pytest.approx(0.25) and f.physics.kdv_per_s[0] == 0.25
    # the tilt's lag is PX4's attitude gain: 1 / min(MC_ROLL_P, MC_PITCH_P); at once on ideal
    assert f.physics.att_tau_s[0] == pytest.approx(0.25)
    assert MockFleet(n=1, profile="ideal").physics.att_tau_s[0] == 0.0
    v.receive(mavlink2.MAVLink_param_set_message(1, 1, b"MC_PITCH_P", 8.0, 9))
    v.receive(mavlink2.MAVLink_param_set_message(1, 1, b"MC_ROLL_P", 10.0, 9))
    assert f.physics.att_tau_s[0] == pytest.approx(1.0 / 8.0)
    with pytest.raises(MockConfigError, match=r"unknown mock profile 'sitl'.*px4, ideal"):
        MockFleet(n=1, profile="sitl")
    with pytest.raises(MockConfigError, match=r"MPC_JERK_AUTO = 0.0 outside \[1, 80\]"):
        MockFleet(n=1, params={"MPC_JERK_AUTO": 0.0})


# ------------------------------------------------------------------ drag and the lag it makes


@pytest.mark.parametrize(
    ("kdv", "kp", "kv", "speed"),
    [(1.0, 0.95, 1.8, 0.75), (1.0, 0.95, 1.8, 4.0), (0.6, 1.2, 2.5, 2.0)],
)
def test_steady_lag_emerges_as_drag_over_the_cascade_gains(
    kdv: float, kp: float, kv: float, speed: float
) -> None:
    # the integrator off ("before the integrator catches up") and a quiet estimator
    f = fleet(**QUIET, **NO_CREEP, SIH_KDV=kdv, MPC_XY_P=kp, MPC_XY_VEL_P_ACC=kv, MPC_XY_VEL_I_ACC=0.0)  # fmt: skip
    v = f.vehicles[0]
    offboard_hover(f, v)
    y0 = f.physics.pos_ned_m[0, 1]
    lags = []
    for k in range(1500):  # 15 s at constant speed east
        y = y0 + speed * k * 0.01
        stream(v, (0.0, y, -3.0), (0.0, speed, 0.0))
        f.advance(0.01)
        # after the step the plan is one step further on
        lags.append((y + speed * 0.01 - f.physics.pos_ned_m[0, 1]) / speed)
    closed_form = kdv / (kp * kv)
    assert np.mean(lags[-300:]) == pytest.approx(closed_form, rel=0.02)


@pytest.mark.parametrize("kdv", [0.5, 1.0, 1.5])
@pytest.mark.slow
def test_drag_fed_forward_as_acceleration_takes_the_steady_lag_out(kdv: float) -> None:
    # The ground station's remedy (mavlink.plan_setpoints.plan_setpoints_ned, drag_per_s): the
    # acceleration feed-forward carries the drag force, a_ff = c * v, so PX4's cascade
    # needs no position error to hold the speed. Integrator off, as above.
    speed = 3.0
    for c_ff, lag_max in ((0.0, None), (kdv, 0.02)):
        f = fleet(**QUIET, **NO_CREEP, SIH_KDV=kdv, MPC_XY_VEL_I_ACC=0.0)
        v = f.vehicles[0]
        offboard_hover(f, v)
        y0 = f.physics.pos_ned_m[0, 1]
        lags = []
        for k in range(1200):
            y = y0 + speed * k * 0.01
            stream(v, (0.0, y, -3.0), (0.0, speed, 0.0), (0.0, c_ff * speed, 0.0))
            f.advance(0.01)
            lags.append((y + speed * 0.01 - f.physics.pos_ned_m[0, 1]) / speed)
        steady = float(np.mean(lags[-300:]))
        if lag_max is None:
            assert steady == pytest.approx(kdv / (0.95 * 1.8), rel=0.02)
        else:
            assert abs(steady) < lag_max, steady


@pytest.mark.slow
def test_velocity_integrator_and_no_drag_remove_the_lag() -> None:
    def lag_after(seconds: float, **params: float) -> float:
        f = fleet(**QUIET, **NO_CREEP, **params)
        v = f.vehicles[0]
        offboard_hover(f, v)
        y0 = f.physics.pos_ned_m[0, 1]
        for k in range(round(seconds * 100)):
            stream(v, (0.0, y0 + 3.0 * k * 0.01, -3.0), (0.0, 3.0, 0.0))
            f.advance(0.01)
        return float(
            (y0 + 3.0 * (round(seconds * 100) - 1) * 0.01 - f.physics.pos_ned_m[0, 1]) / 3.0
        )

    # PX4's integrator (MPC_XY_VEL_I_ACC 0.4) eats the lag with time constant P_ACC / I_ACC
    assert lag_after(2.0) > 0.3 and lag_after(12.0) < 0.12
    # PX4 with SIH_KDV = 0: -0.13..+0.17 s (the integrator overshoots a speed step a little)
    assert abs(lag_after(4.0, SIH_KDV=0.0)) < 0.2


# ------------------------------------------------------------------ estimator


def test_ekf_origin_is_a_noisy_first_fix_below_and_beside_the_spawn_every_boot() -> None:
    offsets = []
    for seed in range(30):
        v = MockFleet(n=1, seed=seed).vehicles[0]
        offsets.append(pymap3d.geodetic2ned(*v.origin_lla, *v.spawn_lla))
    n, e, d = np.array(offsets).T
    assert np.all((np.hypot(n, e) >= 0.2 - 1e-9) & (np.hypot(n, e) <= 0.4 + 1e-9))
    assert np.all((d >= 0.1 - 1e-9) & (d <= 0.6 + 1e-9))  # below the ground
    assert len({round(x, 6) for x in n}) == 30  # different at every boot
    ideal = MockFleet(n=1, profile="ideal").vehicles[0]
    assert ideal.origin_lla == ideal.spawn_lla


@pytest.mark.slow
def test_controller_flies_the_estimate_and_the_truth_is_off_by_its_error() -> None:
    f = fleet(seed=3, **NO_CREEP)
    v = f.vehicles[0]
    offboard_hover(f, v, down_m=-3.0)
    est, truth, vel_err, bias = [], [], [], []
    for _ in range(2000):
        stream(v, (0.0, 0.0, -3.0))
        f.advance(0.01)
        st = v.state
        est.append(st.est_pos_ned_m)
        truth.append(st.pos_ned_m)
        vel_err.append(np.subtract(st.est_vel_ned_m_s, st.vel_ned_m_s))
        bias.append(f.physics.estimator.vel_bias_m_s[0].copy())
    est, truth, bias = np.array(est), np.array(truth), np.array(bias)
    # The estimate holds the setpoint but for the velocity bias: PX4's cascade settles
    # where the *estimated* velocity equals MPC_XY_P x position error, so a bias b keeps
    # the hovering estimate -b / MPC_XY_P off (PX4 SITL's static 0.2-0.35 m offsets).
    expect = np.array([0.0, 0.0, -3.0]) - bias.mean(axis=0) / 0.95
    assert np.abs(est.mean(axis=0) - expect).max() < 0.06
    err = (est - truth).mean(axis=0)
    origin_err = f.physics.estimator.boot_origin_ned_m[0]
    # ... and the truth sits off the estimate by the origin's error and the bias's drift
    assert np.allclose(err, origin_err + bias.mean(axis=0) * 1.0, atol=0.15)
    rms_v = np.sqrt(np.mean(np.square(vel_err), axis=0))
    assert np.all(rms_v < 0.35) and np.all(rms_v > 0.03)
    # the truth as the simulator knows it, in the mission frame
    e, n, u = f.truth_enu_m()[0]  # vehicle 0 spawns at the mission origin
    assert np.allclose(
        (n, e, -u), np.array(v.state.pos_ned_m) + f.physics.estimator.origin_ned_m[0], atol=1e-6
    )


@pytest.mark.parametrize("bias", [(0.2, 0.0), (-0.1, 0.25)])
def test_a_velocity_bias_holds_the_hover_off_its_setpoint_by_bias_over_mpc_xy_p(bias) -> None:  # type: ignore[no-untyped-def]  # fmt: skip
    # closed form of PX4's cascade at rest (PositionControl.cpp): vel_sp = MPC_XY_P x
    # (pos_sp - pos_est), and the velocity PID's integrator settles only where vel_est
    # = vel_sp; the true velocity is 0, so pos_est - pos_sp = -b / MPC_XY_P.
    kp = 1.3
    f = fleet(seed=5, **QUIET, **NO_CREEP, MPC_XY_P=kp, MOCK_EST_VB_TAU=1000.0)
    v = f.vehicles[0]
    f.physics.estimator.vel_bias_m_s[0] = (*bias, 0.0)
    f.physics.estimator.active = True
    offboard_hover(f, v, down_m=-3.0)
    for _ in range(1500):
        stream(v, (0.0, 0.0, -3.0))
        f.advance(0.01)
    n, e, _ = v.state.est_pos_ned_m
    assert (n, e) == pytest.approx((-bias[0] / kp, -bias[1] / kp), abs=0.01)
    assert np.hypot(*v.state.vel_ned_m_s[:2]) < 0.01  # really at rest


def test_truth_and_estimator_status_are_on_the_link() -> None:
    f = fleet(seed=1)
    v = f.vehicles[0]
    f.advance(1.0)
    status = [m for m in v.sent_messages() if m.get_type() == "ESTIMATOR_STATUS"]
    assert status and status[-1].pos_horiz_accuracy > 0.2 and status[-1].pos_vert_accuracy > 0.3
    assert status[-1].flags & mavlink2.ESTIMATOR_POS_HORIZ_ABS
    cmd(v, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAVLINK_MSG_ID_HIL_STATE_QUATERNION, 1e5)
    f.advance(0.5)
    truth = [m for m in v.sent_messages() if m.get_type() == "HIL_STATE_QUATERNION"]
    assert len(truth) >= 4
    # ground truth: the spawn itself, not the EKF's belief
    assert truth[-1].lat == round(v.spawn_lla[0] * 1e7)
    assert truth[-1].lon == round(v.spawn_lla[1] * 1e7)
    gpi = [m for m in v.sent_messages() if m.get_type() == "GLOBAL_POSITION_INT"]
    assert not gpi or abs(gpi[-1].lat - truth[-1].lat) > 5  # the estimate is elsewhere


# ------------------------------------------------------------------ yaw


def test_vehicles_boot_facing_north_and_a_90_degree_turn_takes_px4s_time_and_shakes_the_estimate() -> None:  # fmt: skip
    f = fleet(seed=2, **NO_CREEP)
    v = f.vehicles[0]
    assert f.physics.yaw_rad[0] == 0.0
    offboard_hover(f, v)
    quiet, turning, t_settle = [], [], None
    for k in range(300):
        stream(v, (0.0, 0.0, -3.0), yaw=math.pi / 2 if k >= 100 else 0.0)
        f.advance(0.01)
        err = np.linalg.norm(np.subtract(v.state.est_vel_ned_m_s, v.state.vel_ned_m_s))
        (quiet if k < 100 else turning).append(err)
        if k >= 100 and t_settle is None and abs(f.physics.yaw_rad[0] - math.pi / 2) < math.radians(5):  # fmt: skip
            t_settle = (k - 100) * 0.01
    # PX4 SITL: about 1.2 s for 90 degrees (MC_YAW_P 2.8)
    assert t_settle is not None and 0.8 < t_settle < 1.5
    # PX4 SITL: the turn adds up to ~0.3 m/s to the velocity error
    extra = np.mean(turning[:100]) - np.mean(quiet)
    assert 0.0 < extra < 0.3, extra
