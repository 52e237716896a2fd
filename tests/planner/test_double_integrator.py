"""planner.dynamics.DoubleIntegrator: exact discretisation, exact limits, same interface."""

from __future__ import annotations

import numpy as np
import pytest

from planner.dynamics import DoubleIntegrator, DynamicsError, LinearModel


def _simulate(U: np.ndarray, X0: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Reference: step the discrete double integrator one step at a time."""
    p, v = X0[0].copy(), X0[1].copy()
    P, V = [p.copy()], [v.copy()]
    for u in U:
        p = p + dt * v + 0.5 * dt * dt * u
        v = v + dt * u
        P.append(p.copy())
        V.append(v.copy())
    return np.array(P), np.array(V)


def test_matrices_reproduce_the_stepped_system() -> None:
    model = DoubleIntegrator(horizon_s=4.0, dt_s=0.25, dims=3, u_max=2.0)
    assert isinstance(model, LinearModel)
    assert (model.n_dec, model.n_init, model.n_samples) == (16, 2, 17)
    rng = np.random.default_rng(0)
    U = rng.uniform(-2, 2, (16, 3))
    X0 = rng.normal(size=(2, 3))
    P, V = _simulate(U, X0, 0.25)
    np.testing.assert_allclose(model.positions(U, X0), P, atol=1e-12)
    np.testing.assert_allclose(model.velocities(U, X0), V, atol=1e-12)
    np.testing.assert_allclose(model.accelerations(U, X0), np.vstack([U, U[-1]]), atol=0)
    traj = model.trajectory(U, X0, "d1")
    np.testing.assert_allclose(traj.position(model.times_s), P, atol=1e-12)
    # Between steps the trajectory is the exact zero-order-hold solution.
    t = 0.25 * 3 + 0.1
    expect = P[3] + 0.1 * V[3] + 0.5 * 0.01 * U[3]
    np.testing.assert_allclose(traj.position([t])[0], expect, atol=1e-12)


def test_finer_samples_than_steps() -> None:
    model = DoubleIntegrator(horizon_s=2.0, dt_s=0.5, sample_dt_s=0.1)
    U = np.ones((4, 3))
    X0 = np.zeros((2, 3))
    np.testing.assert_allclose(model.positions(U, X0)[:, 0], 0.5 * model.times_s**2, atol=1e-12)


def test_limits_are_exact() -> None:
    model = DoubleIntegrator(horizon_s=3.0, dt_s=0.5, dims=3, u_max=[1.0, 1.0, 0.5])
    cons = model.limit_constraints(v_max=1.2, a_max=0.8)
    rng = np.random.default_rng(1)
    t = np.linspace(0, 3, 6001)
    worst = []
    for _ in range(100):
        U = rng.normal(size=(6, 3))
        X0 = np.vstack([np.zeros(3), rng.uniform(-0.5, 0.5, 3)])
        lhs = cons.G @ U + cons.H @ X0
        s = np.min(np.where(lhs > 0, cons.h / lhs, np.inf))
        traj = model.trajectory(s * U, s * X0)
        v = np.abs(traj.velocity(t)).max(axis=0)
        a = np.abs(s * U).max(axis=0)
        assert np.all(v <= 1.2 + 1e-9)
        assert np.all(a <= np.array([0.8, 0.8, 0.5]) + 1e-9)
        worst.append(max(np.max(v / 1.2), np.max(a / [0.8, 0.8, 0.5])))
    # Exact constraints: some limit is always reached on the boundary.
    assert min(worst) == pytest.approx(1.0, abs=1e-9)


def test_planar_model_has_no_vertical_input() -> None:
    model = DoubleIntegrator(horizon_s=2.0, dt_s=0.5, dims=2, u_max=1.0)
    cons = model.limit_constraints(v_max=np.inf)
    acc_rows = cons.kind == "acc"
    assert np.all(cons.h[acc_rows, 2] == 0.0) and np.all(cons.h[acc_rows, :2] == 1.0)
    assert np.all(np.isinf(cons.h[~acc_rows]))
    Z = model.initial_guess([0, 0, 5], [1, 1, 9])
    assert np.all(Z[:, 2] == 0.0)
    np.testing.assert_allclose(
        model.positions(Z, np.array([[0, 0, 5.0], [0, 0, 0]]))[-1], [1, 1, 5]
    )


def test_initial_guess_reaches_goal_at_rest() -> None:
    model = DoubleIntegrator(horizon_s=4.0, dt_s=0.5, u_max=5.0)
    Z = model.initial_guess([0, 0, 0], [4, -2, 1])
    X0 = np.zeros((2, 3))
    np.testing.assert_allclose(model.positions(Z, X0)[-1], [4, -2, 1], atol=1e-12)
    np.testing.assert_allclose(model.velocities(Z, X0)[-1], 0.0, atol=1e-12)


def test_bad_parameters() -> None:
    with pytest.raises(DynamicsError, match="dims"):
        DoubleIntegrator(2.0, 0.5, dims=4)
    with pytest.raises(DynamicsError, match="u_max"):
        DoubleIntegrator(2.0, 0.5, u_max=0.0)
    with pytest.raises(DynamicsError, match="multiple"):
        DoubleIntegrator(2.0, 0.3)
