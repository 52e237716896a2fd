"""Mueller's thrust / body-rate feasibility test against brute-force dense evaluation."""

from __future__ import annotations

import numpy as np
import pytest

from planner.dynamics import (
    DoubleIntegrator,
    DynamicsError,
    EndState,
    InputFeasibility,
    InputLimits,
    MinimumJerkChain,
    check_input_feasibility,
    primitive_coefficients,
    primitive_input_feasibility,
)
from planner.dynamics.feasibility import thrust_and_body_rate
from planner.trajectory import Trajectory

G = 9.81
LIMITS = InputLimits(f_min_m_s2=5.0, f_max_m_s2=25.0, omega_max_rad_s=15.0)


def _brute_force(
    coeffs: np.ndarray, T: float, n: int = 20001
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Thrust and roll/pitch rate from the definitions, on a dense grid (one primitive)."""
    t = np.linspace(0.0, T, n)
    acc = np.column_stack([np.polynomial.Polynomial(coeffs[a]).deriv(2)(t) for a in range(3)])
    jerk = np.column_stack([np.polynomial.Polynomial(coeffs[a]).deriv(3)(t) for a in range(3)])
    thrust = acc + np.array([0.0, 0.0, G])
    f = np.linalg.norm(thrust, axis=1)
    e3 = thrust / f[:, None]
    # omega x e3 = d e3 / dt = (j - (j.e3) e3) / f  ->  |omega_xy| = |j_perp| / f
    w = np.linalg.norm(jerk - np.sum(jerk * e3, axis=1)[:, None] * e3, axis=1) / f
    return t, f, w


@pytest.mark.slow
def test_recursive_test_agrees_with_brute_force() -> None:
    rng = np.random.default_rng(11)
    n = 400
    p0 = rng.uniform(-1, 1, (n, 3))
    v0 = rng.uniform(-3, 3, (n, 3))
    a0 = rng.uniform(-4, 4, (n, 3))
    pf = rng.uniform(-6, 6, (n, 3))
    vf = rng.uniform(-3, 3, (n, 3))
    T = rng.uniform(0.8, 3.0, n)
    c = primitive_coefficients(p0, v0, a0, pf, vf, 0.0, T[:, None], EndState.POS_VEL)
    codes = primitive_input_feasibility(c, T, LIMITS, min_section_s=0.02)
    seen = set()
    for i in range(n):
        _, f, w = _brute_force(c[i], float(T[i]))
        code = InputFeasibility(int(codes[i]))
        seen.add(code)
        if code is InputFeasibility.FEASIBLE:
            assert f.max() <= LIMITS.f_max_m_s2 and f.min() >= LIMITS.f_min_m_s2
            assert w.max() <= LIMITS.omega_max_rad_s
        elif code is InputFeasibility.INFEASIBLE_THRUST_HIGH:
            assert f.max() > LIMITS.f_max_m_s2 - 1e-6
        elif code is InputFeasibility.INFEASIBLE_THRUST_LOW:
            assert f.min() < LIMITS.f_min_m_s2 + 1e-6
    # The sample exercises every verdict.
    assert seen == set(InputFeasibility)


def test_report_gives_the_first_violating_time() -> None:
    # Hover for 2 s, then a violent climb.
    model = MinimumJerkChain(horizon_s=4.0, segment_s=1.0, sample_dt_s=0.1)
    Z = np.zeros((model.n_dec, 3))
    Z[model.pos_rows][2:, 2] = [6.0, 6.0]  # waypoints at 3 s and 4 s
    X0 = np.zeros((3, 3))
    traj = model.trajectory(Z, X0)
    report = check_input_feasibility(traj, LIMITS)
    assert not report.feasible
    # Brute force over the whole trajectory at 0.1 ms.
    t = np.linspace(0.0, traj.duration_s, 40001)
    acc = traj.acceleration(t) + np.array([0.0, 0.0, G])
    f = np.linalg.norm(acc, axis=1)
    jerk = traj.jerk(t)
    e3 = acc / f[:, None]
    w = np.linalg.norm(jerk - np.sum(jerk * e3, axis=1)[:, None] * e3, axis=1) / f
    f_lib, w_lib = thrust_and_body_rate(traj, t)
    np.testing.assert_allclose(f_lib, f, rtol=1e-12)
    np.testing.assert_allclose(w_lib, w, rtol=1e-9, atol=1e-12)
    viol = (f > LIMITS.f_max_m_s2) | (f < LIMITS.f_min_m_s2) | (w > LIMITS.omega_max_rad_s)
    t_first = t[np.argmax(viol)]
    assert report.first_violation_t_s == pytest.approx(t_first, abs=1.1e-3)
    assert 2.0 <= report.first_violation_t_s < 3.0  # the climb is segment 2 (2 s .. 3 s)
    k = np.argmax(viol)
    expected = "thrust_high" if f[k] > 25 else ("thrust_low" if f[k] < 5 else "body_rate")
    assert report.violation == expected
    assert report.max_thrust_m_s2 == pytest.approx(f.max(), rel=1e-4)


def test_gentle_plan_is_proven_feasible() -> None:
    model = MinimumJerkChain(horizon_s=10.0, segment_s=1.0, sample_dt_s=0.1)
    Z = model.initial_guess([0, 0, 2], [5, 3, 4])
    traj = model.trajectory(Z, np.vstack([[0, 0, 2.0], np.zeros((2, 3))]))
    report = check_input_feasibility(traj, LIMITS)
    assert report.feasible and report.first_violation_t_s is None and report.violation is None
    assert report.verdict is InputFeasibility.FEASIBLE
    assert report.n_proven_segments == model.n_segments


def test_free_fall_start_is_thrust_low_at_time_zero() -> None:
    c = np.zeros((1, 3, 6))
    c[0, 2, 2] = -G / 2  # a_z = -g: zero thrust
    report = check_input_feasibility(Trajectory([0.0], [1.0], c), LIMITS)
    assert report.violation == "thrust_low" and report.first_violation_t_s == 0.0
    assert report.verdict is InputFeasibility.INFEASIBLE_THRUST_LOW


def test_acceleration_jumps_need_infinite_body_rate() -> None:
    model = DoubleIntegrator(horizon_s=2.0, dt_s=0.5, u_max=2.0)
    U = np.zeros((4, 3))
    U[2:, 0] = 1.0  # the input steps at t = 1 s
    report = check_input_feasibility(model.trajectory(U, np.zeros((2, 3))), LIMITS)
    assert report.violation == "body_rate" and report.first_violation_t_s == 1.0


def test_limits_are_validated() -> None:
    with pytest.raises(DynamicsError, match="f_min_m_s2 < f_max_m_s2"):
        InputLimits(10.0, 5.0, 1.0)
    with pytest.raises(DynamicsError, match="omega_max_rad_s"):
        InputLimits(1.0, 5.0, 0.0)
