"""Discrete double integrator behind the same linear interface: :class:`DoubleIntegrator`.

Per axis ``p' = v``, ``v' = u`` with the input ``u`` (m/s^2) held constant over each step
of ``dt_s`` (zero-order hold), so the trajectory is piecewise quadratic and exact between
steps. Decision variables: ``Z[k] = u_k`` for ``k = 0 .. n_steps - 1``; ``X0 = [p0; v0]``
``(2, 3)``. Exact discretisation::

    p_{k+1} = p_k + dt v_k + dt^2 / 2 u_k,      v_{k+1} = v_k + dt u_k

The sampled acceleration at a step boundary is the input that starts there (the last
sample, at the horizon, reports the last input: the left limit, as
:class:`~planner.trajectory.Trajectory` evaluates it). With ``dims=2`` the third (up)
axis has no input: its acceleration bound is 0 in :meth:`limit_constraints`, so the
planner keeps ``u_z = 0`` (pass ``X0`` with zero vertical velocity). Velocity is
piecewise linear and acceleration piecewise constant, so the Bernstein limits of
:mod:`planner.dynamics.linear` are exact here (no conservatism).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.dynamics.errors import DynamicsError
from planner.dynamics.linear import (
    LimitConstraints,
    PiecewisePolynomialModel,
    as_axis_limit,
    ratio_steps,
)
from planner.trajectory import YawPolicy

__all__ = ["DoubleIntegrator"]


class DoubleIntegrator(PiecewisePolynomialModel):
    """Textbook STL dynamics: a zero-order-hold double integrator (module docstring).

    Args:
        horizon_s: plan length, a whole multiple of ``dt_s``.
        dt_s: input step in seconds.
        dims: 2 (east, north; up has no input) or 3.
        u_max: input bound (m/s^2), scalar or per axis ``(3,)``.
        sample_dt_s: sample step of the matrices (default ``dt_s``).
        yaw_policy: yaw rule of the trajectories this model produces.
    """

    def __init__(
        self,
        horizon_s: float,
        dt_s: float,
        dims: int = 3,
        u_max: ArrayLike = np.inf,
        *,
        sample_dt_s: float | None = None,
        yaw_policy: YawPolicy | None = None,
    ) -> None:
        if dims not in (2, 3):
            raise DynamicsError(f"dims must be 2 or 3, got {dims!r}")
        u = np.broadcast_to(np.asarray(u_max, dtype=float), (3,)).copy()
        if np.any(np.isnan(u)) or np.any(u <= 0.0):
            raise DynamicsError("u_max must be > 0 (scalar or 3 per-axis values)")
        self.dims = dims
        self.dt_s = float(dt_s)
        self.u_max = u
        n = ratio_steps(horizon_s, dt_s, "horizon_s / dt_s")
        self.n_steps = n
        m = n + 2
        eye = np.eye(m)
        P, V = eye[n], eye[n + 1]
        coef = np.empty((n, 3, m))
        dt = self.dt_s
        for k in range(n):
            U = eye[k]
            coef[k] = np.stack([P, V, U / 2.0])
            P, V = P + dt * V + dt * dt / 2.0 * U, V + dt * U
        self._build(
            horizon_s=float(horizon_s),
            sample_dt_s=float(sample_dt_s if sample_dt_s is not None else dt_s),
            n_dec=n,
            n_init=2,
            segment_t0_s=np.asarray(np.arange(n) * dt, dtype=np.float64),
            segment_duration_s=np.full(n, dt),
            coef_maps=coef,
            limit_subdivisions=1,
            yaw_policy=yaw_policy if yaw_policy is not None else YawPolicy(),
        )

    def limit_constraints(
        self,
        v_max: ArrayLike,
        a_max: ArrayLike = np.inf,
        v_down: ArrayLike | None = None,
        a_down: ArrayLike | None = None,
    ) -> LimitConstraints:
        """Exact limits: ``-v_down[i] <= v_i(t) <= v_max[i]`` and
        ``-min(a_down[i], u_max[i]) <= u_i <= min(a_max[i], u_max[i])`` (``v_down``,
        ``a_down`` default to ``v_max``, ``a_max``).

        Infinite bounds are allowed here (rows with ``h = inf`` are always satisfied).
        With ``dims=2`` the up-axis input bound is 0.
        """
        vm = np.broadcast_to(np.asarray(v_max, dtype=float), (3,))
        am = np.broadcast_to(np.asarray(a_max, dtype=float), (3,))
        vd = vm if v_down is None else np.broadcast_to(np.asarray(v_down, dtype=float), (3,))
        ad = am if a_down is None else np.broadcast_to(np.asarray(a_down, dtype=float), (3,))
        if any(np.any(np.isnan(x)) or np.any(x < 0) for x in (vm, am, vd, ad)):
            raise DynamicsError("v_max and a_max must be >= 0 (scalar or 3 per-axis values)")
        acc_hi, acc_lo = np.minimum(am, self.u_max), np.minimum(ad, self.u_max)
        if self.dims == 2:
            acc_hi, acc_lo = acc_hi.copy(), acc_lo.copy()
            acc_hi[2] = acc_lo[2] = 0.0
        # Parent validates finiteness; pass finite placeholders, then restore inf bounds.
        cons = PiecewisePolynomialModel.limit_constraints(
            self, as_axis_limit(np.where(np.isfinite(vm), vm, 0.0), "v_max"), np.zeros(3)
        )
        n = len(cons.kind) // 2
        vel = (cons.kind[:n] == "vel")[:, None]
        h = np.vstack(
            [
                np.where(vel, vm[None, :], acc_hi[None, :]),
                np.where(vel, vd[None, :], acc_lo[None, :]),
            ]
        )
        return LimitConstraints(G=cons.G, H=cons.H, h=h, kind=cons.kind)

    def initial_guess(self, start: ArrayLike, goal: ArrayLike) -> NDArray[np.float64]:
        """Inputs ``(n_steps, 3)`` for a rest-to-rest straight line from ``start`` to ``goal``.

        Bang-bang: ``+a`` for the first half of the steps, ``-a`` for the rest, with
        ``a = 4 (goal - start) / horizon^2`` (exact for an even step count; clipped to
        ``u_max``, so a too-short horizon gives a guess that falls short).
        """
        p_a = np.asarray(start, dtype=float).reshape(-1)
        p_b = np.asarray(goal, dtype=float).reshape(-1)
        if p_a.shape != (3,) or p_b.shape != (3,):
            raise DynamicsError("initial_guess: start and goal must be 3-vectors (ENU m)")
        a = np.clip(4.0 * (p_b - p_a) / self.horizon_s**2, -self.u_max, self.u_max)
        if self.dims == 2:
            a[2] = 0.0
        sign = np.where(np.arange(self.n_steps) < self.n_steps / 2.0, 1.0, -1.0)
        if self.n_steps % 2 == 1:
            sign[self.n_steps // 2] = 0.0
        return sign[:, None] * a[None, :]
