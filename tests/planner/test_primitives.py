"""Mueller's minimum-jerk primitive: closed forms, boundary conditions, optimality, chains."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, optimize

from planner.dynamics import DynamicsError, EndState, MinimumJerkChain
from planner.dynamics.primitives import (
    jerk_cost,
    min_jerk_parameters,
    optimality_system,
    primitive_coefficients,
)

RNG_SEED = 20150601


def _random_states(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    p0, v0, a0 = rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(-2, 2, n)
    pf, vf, af = rng.uniform(-5, 5, n), rng.uniform(-2, 2, n), rng.uniform(-2, 2, n)
    T = rng.uniform(0.3, 4.0, n)
    return p0, v0, a0, pf, vf, af, T


def _eval(c: np.ndarray, t: np.ndarray, order: int) -> np.ndarray:
    """Independent evaluation through numpy's polynomial class."""
    out = np.empty(c.shape[0])
    for i in range(c.shape[0]):
        out[i] = (
            np.polynomial.Polynomial(c[i]).deriv(order)(t[i])
            if order
            else np.polynomial.Polynomial(c[i])(t[i])
        )
    return out


@pytest.mark.parametrize("end", list(EndState))
def test_closed_forms_solve_the_optimality_conditions(end: EndState) -> None:
    rng = np.random.default_rng(RNG_SEED)
    p0, v0, a0, pf, vf, af, T = _random_states(rng, 50)
    prm = min_jerk_parameters(p0, v0, a0, pf, vf, af, T, end)
    for i in range(T.size):
        d = np.array(
            [
                pf[i] - p0[i] - v0[i] * T[i] - a0[i] * T[i] ** 2 / 2,
                vf[i] - v0[i] - a0[i] * T[i],
                af[i] - a0[i],
            ]
        )
        rhs = np.where(end.fixed, d, 0.0)
        ref = np.linalg.solve(optimality_system(float(T[i]), end), rhs)
        np.testing.assert_allclose(prm[i], ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())


@pytest.mark.parametrize("end", list(EndState))
def test_boundary_conditions_are_met(end: EndState) -> None:
    rng = np.random.default_rng(RNG_SEED + 1)
    p0, v0, a0, pf, vf, af, T = _random_states(rng, 200)
    c = primitive_coefficients(p0, v0, a0, pf, vf, af, T, end)
    zero = np.zeros_like(T)
    for order, start in enumerate((p0, v0, a0)):
        assert np.max(np.abs(_eval(c, zero, order) - start)) <= 1e-9
    for order, (fixed, target) in enumerate(zip(end.fixed, (pf, vf, af), strict=True)):
        if fixed:
            assert np.max(np.abs(_eval(c, T, order) - target)) <= 1e-9
    # Free components satisfy the transversality conditions (the costate vanishes).
    j_end = _eval(c, T, 3)
    snap_end = _eval(c, T, 4)
    crackle = _eval(c, T, 5)
    if not end.fixed[2]:
        assert np.max(np.abs(j_end)) <= 1e-8 * max(1.0, np.abs(c).max())
    if not end.fixed[1]:
        assert np.max(np.abs(snap_end)) <= 1e-8 * max(1.0, np.abs(c).max())
    if not end.fixed[0]:
        assert np.max(np.abs(crackle)) <= 1e-8 * max(1.0, np.abs(c).max())


def _numerical_optimum(p0, v0, a0, pf, vf, af, T, end: EndState) -> float:
    """Minimise 1/T int j^2 over the free quintic coefficients (c3, c4, c5) with SLSQP.

    The cost is integrated by Gauss-Legendre quadrature (exact for the degree-4
    integrand) and the end constraints are written on the polynomial directly: nothing
    here uses Mueller's formulas. The unknowns are scaled as ``x_k = c_k T^k`` so that
    the problem is well conditioned for any duration.
    """
    scale = np.array([T**3, T**4, T**5])

    def poly(x: np.ndarray) -> np.polynomial.Polynomial:
        return np.polynomial.Polynomial([p0, v0, a0 / 2, *(x / scale)])

    def cost(x: np.ndarray) -> float:
        j = poly(x).deriv(3)
        return integrate.fixed_quad(lambda t: j(t) ** 2, 0.0, T, n=5)[0] / T

    cons = []
    for order, (fixed, target) in enumerate(zip(end.fixed, (pf, vf, af), strict=True)):
        if fixed:
            cons.append(
                {"type": "eq", "fun": lambda x, o=order, g=target: (poly(x).deriv(o)(T) - g) * T**o}
            )
    best = np.inf
    for x0 in (np.zeros(3), np.array([1.0, -1.0, 0.5])):
        res = optimize.minimize(
            cost, x0, method="SLSQP", constraints=cons, options={"ftol": 1e-12, "maxiter": 1000}
        )
        assert res.success, res.message
        best = min(best, float(res.fun))
    return best


@pytest.mark.parametrize("end", list(EndState))
def test_jerk_cost_equals_numerical_optimum(end: EndState) -> None:
    rng = np.random.default_rng(RNG_SEED + 2)
    p0, v0, a0, pf, vf, af, T = _random_states(rng, 4)
    prm = min_jerk_parameters(p0, v0, a0, pf, vf, af, T, end)
    closed = jerk_cost(prm, T)
    for i in range(T.size):
        args = (p0[i], v0[i], a0[i], pf[i], vf[i], af[i], float(T[i]))
        numeric = _numerical_optimum(*args, end)
        assert closed[i] == pytest.approx(numeric, rel=1e-6, abs=1e-12)
        # The closed-form cost is the integral of the closed-form jerk.
        c = primitive_coefficients(*args, end)
        j = np.polynomial.Polynomial(c).deriv(3)
        quad = integrate.quad(lambda t, j=j: j(t) ** 2, 0, T[i], epsabs=1e-13, epsrel=1e-13)[0]
        assert closed[i] == pytest.approx(quad / T[i], rel=1e-9, abs=1e-12)


def test_primitive_rejects_bad_duration() -> None:
    with pytest.raises(DynamicsError, match="duration"):
        min_jerk_parameters(0, 0, 0, 1, 0, 0, np.array([1.0, 0.0]))


# --------------------------------------------------------------------------- chains
def _random_decision(
    model: MinimumJerkChain, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    Z = np.empty((model.n_dec, 3))
    Z[model.pos_rows] = np.cumsum(rng.normal(0, 1.0, (model.n_segments, 3)), axis=0)
    Z[model.vel_rows] = rng.normal(0, 1.0, (model.n_segments, 3))
    X0 = rng.normal(0, 0.5, (3, 3))
    return Z, X0


def test_chain_segments_are_mueller_primitives_with_free_end_acceleration() -> None:
    rng = np.random.default_rng(RNG_SEED + 3)
    model = MinimumJerkChain(horizon_s=8.0, segment_s=2.0, sample_dt_s=0.1)
    Z, X0 = _random_decision(model, rng)
    traj = model.trajectory(Z, X0, "d1")
    p, v, a = X0
    for s in range(model.n_segments):
        last = s == model.n_segments - 1
        end = EndState.POS_VEL_ACC if last else EndState.POS_VEL
        pf, vf = Z[s], Z[model.n_segments + s]
        ref = primitive_coefficients(p, v, a, pf, vf, 0.0, 2.0, end)
        np.testing.assert_allclose(traj.coeffs[s], ref, rtol=1e-10, atol=1e-10)
        # Waypoints (boundary conditions) are met to 1e-9 and acceleration is continuous.
        end_state = [
            np.polynomial.polynomial.polyval(2.0, np.polynomial.polynomial.polyder(ref[ax], o))
            if o
            else np.polynomial.polynomial.polyval(2.0, ref[ax])
            for o in range(3)
            for ax in range(3)
        ]
        end_state = np.array(end_state).reshape(3, 3)
        assert np.max(np.abs(end_state[0] - pf)) <= 1e-9
        assert np.max(np.abs(end_state[1] - vf)) <= 1e-9
        if last:
            assert np.max(np.abs(end_state[2])) <= 1e-9
        p, v, a = pf, vf, end_state[2]


def test_sample_matrices_match_exact_evaluation() -> None:
    rng = np.random.default_rng(RNG_SEED + 4)
    model = MinimumJerkChain(horizon_s=12.0, segment_s=1.5, sample_dt_s=0.05)
    assert model.times_s[0] == 0.0 and model.times_s[-1] == pytest.approx(12.0)
    assert model.Mp.shape == (241, model.n_dec) and model.Np.shape == (241, 3)
    Z, X0 = _random_decision(model, rng)
    traj = model.trajectory(Z, X0)
    t = model.times_s
    np.testing.assert_allclose(model.Mp @ Z + model.Np @ X0, traj.position(t), atol=1e-9)
    np.testing.assert_allclose(model.Mv @ Z + model.Nv @ X0, traj.velocity(t), atol=1e-9)
    np.testing.assert_allclose(model.Ma @ Z + model.Na @ X0, traj.acceleration(t), atol=1e-9)
    np.testing.assert_allclose(traj.position(model.waypoint_times_s), Z[model.pos_rows], atol=1e-9)
    np.testing.assert_allclose(traj.velocity(model.waypoint_times_s), Z[model.vel_rows], atol=1e-9)
    np.testing.assert_allclose(traj.position([0.0])[0], X0[0], atol=1e-12)


def test_explicit_acceleration_chain_is_the_same_family_with_banded_matrices() -> None:
    rng = np.random.default_rng(RNG_SEED + 9)
    dense = MinimumJerkChain(horizon_s=12.0, segment_s=1.5, sample_dt_s=0.05)
    banded = MinimumJerkChain(horizon_s=12.0, segment_s=1.5, sample_dt_s=0.05, explicit_acc=True)
    n = dense.n_segments
    assert banded.n_dec == 3 * n and dense.equality_constraints()[0].shape == (0, 2 * n)
    Z, X0 = _random_decision(dense, rng)
    # The accelerations the chain implies: the dense trajectory's, at the waypoints.
    acc = dense.trajectory(Z, X0).acceleration(dense.waypoint_times_s)
    Zb = np.vstack([Z, acc])
    G, H = banded.equality_constraints()
    assert G.shape == (n, 3 * n) and H.shape == (n, 3)
    np.testing.assert_allclose(G @ Zb + H @ X0, 0.0, atol=1e-9)
    for order in "pva":
        M, N = getattr(dense, f"M{order}"), getattr(dense, f"N{order}")
        Mb, Nb = getattr(banded, f"M{order}"), getattr(banded, f"N{order}")
        np.testing.assert_allclose(Mb @ Zb + Nb @ X0, M @ Z + N @ X0, atol=1e-9)
    # Banded: a sample inside segment s depends on waypoints s-1 and s only.
    seg = np.minimum((banded.times_s / 1.5 + 1e-9).astype(int), n - 1)
    for row, s in zip(banded.Mp, seg, strict=True):
        cols = np.nonzero(row)[0]
        assert set(cols % n) <= {s - 1, s} - {-1}
    # A trajectory from a Z violating the chain is caught by the equalities.
    Zb[2 * n + 2] += 0.5
    assert np.max(np.abs(G @ Zb + H @ X0)) > 0.4
    # initial_guess fills the accelerations consistently.
    Zg = banded.initial_guess([0, 0, 1], [5, -3, 2])
    np.testing.assert_allclose(
        G @ Zg + H @ np.array([[0, 0, 1], [0, 0, 0], [0, 0, 0]]), 0, atol=1e-9
    )


def test_sample_matrices_work_with_casadi_symbols() -> None:
    ca = pytest.importorskip("casadi")
    rng = np.random.default_rng(RNG_SEED + 5)
    model = MinimumJerkChain(horizon_s=6.0, segment_s=1.0, sample_dt_s=0.1)
    Z, X0 = _random_decision(model, rng)
    for sym in (ca.SX, ca.MX):
        Zs = sym.sym("Z", model.n_dec, 3)
        f = ca.Function("f", [Zs], [model.positions(Zs, X0), model.accelerations(Zs, X0)])
        pos, acc = f(Z)
        np.testing.assert_allclose(np.array(pos), model.positions(Z, X0), atol=1e-12)
        np.testing.assert_allclose(np.array(acc), model.accelerations(Z, X0), atol=1e-12)
    # The plain numpy matrices combine with CasADi symbols directly (Mp @ Z) ...
    Zs = ca.SX.sym("Z", model.n_dec, 3)
    expr = model.Mp @ Zs + model.Np @ X0
    np.testing.assert_allclose(
        np.array(ca.Function("h", [Zs], [expr])(Z)), model.positions(Z, X0), atol=1e-12
    )
    # ... and through ca.mtimes.
    Zs = ca.SX.sym("Z", model.n_dec, 3)
    expr = ca.mtimes(ca.DM(model.Mv), Zs) + ca.DM(model.Nv @ X0)
    np.testing.assert_allclose(
        np.array(ca.Function("g", [Zs], [expr])(Z)), model.velocities(Z, X0), atol=1e-12
    )


def test_chain_rejects_bad_parameters_and_shapes() -> None:
    with pytest.raises(DynamicsError, match="multiple"):
        MinimumJerkChain(horizon_s=10.0, segment_s=3.0, sample_dt_s=0.1)
    with pytest.raises(DynamicsError, match="multiple"):
        MinimumJerkChain(horizon_s=10.0, segment_s=1.0, sample_dt_s=0.3)
    model = MinimumJerkChain(horizon_s=4.0, segment_s=1.0, sample_dt_s=0.1)
    with pytest.raises(DynamicsError, match=r"Z must have shape \(8, 3\)"):
        model.positions(np.zeros((7, 3)), np.zeros((3, 3)))
    with pytest.raises(DynamicsError, match=r"X0 must have shape \(3, 3\)"):
        model.trajectory(np.zeros((8, 3)), np.zeros((2, 3)))


def test_initial_guess_is_a_rest_to_rest_straight_line() -> None:
    model = MinimumJerkChain(horizon_s=10.0, segment_s=1.0, sample_dt_s=0.1)
    start, goal = np.array([0.0, 0.0, 2.0]), np.array([10.0, -5.0, 4.0])
    Z = model.initial_guess(start, goal)
    X0 = np.vstack([start, np.zeros(3), np.zeros(3)])
    pos = model.positions(Z, X0)
    np.testing.assert_allclose(pos[-1], goal, atol=1e-12)
    np.testing.assert_allclose(model.velocities(Z, X0)[-1], 0.0, atol=1e-12)
    # Every sample lies on the segment from start to goal.
    d = (goal - start) / np.linalg.norm(goal - start)
    off = (pos - start) - ((pos - start) @ d)[:, None] * d
    assert np.max(np.abs(off)) <= 1e-9
