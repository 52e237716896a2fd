"""Chains of Mueller minimum-jerk primitives between waypoints: :class:`MinimumJerkChain`.

Decision variables (per axis, one column of ``Z`` each): the waypoint positions and
velocities at ``t_i = i * segment_s``, ``i = 1 .. n_seg``::

    Z[0 : n_seg]         waypoint positions p_1 .. p_n   (m)      rows ``pos_rows``
    Z[n_seg : 2 n_seg]   waypoint velocities v_1 .. v_n  (m/s)    rows ``vel_rows``
    Z[2 n_seg : 3 n_seg] waypoint accelerations a_1 .. a_n (m/s^2) rows ``acc_rows``,
                         only with ``explicit_acc`` (tied by ``equality_constraints``)

and ``X0 = [p0; v0; a0]`` ``(3, 3)``. Segment ``i`` is Mueller's jerk-optimal primitive
from the state reached at ``t_{i-1}`` to ``(p_i, v_i)`` with the **end acceleration free**
([M] "Partially defined end state", closed form in
:func:`planner.dynamics.primitives.min_jerk_parameters` with ``EndState.POS_VEL``); the
next segment starts with the acceleration this one ends with. Why free end accelerations:

* acceleration is continuous across waypoints (the trajectory is C2, so the thrust
  direction never jumps), with no extra decision variables;
* the start acceleration of each segment is a linear function of the earlier waypoints,
  so everything stays linear in ``(Z, X0)``; the recursion contracts (the end
  acceleration depends on the start acceleration with gain 1/3), so long chains are
  numerically benign;
* fixing the waypoint accelerations to zero instead would force a stop of the
  acceleration at every waypoint and waste jerk (and robustness) for nothing.

The last segment uses the fully defined end state with ``a_f = 0`` when
``final_acc_zero`` (default), so a planner that also constrains ``v_n = 0`` ends at rest
and the hover hold after the end is consistent.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.dynamics.errors import DynamicsError
from planner.dynamics.linear import PiecewisePolynomialModel, ratio_steps
from planner.dynamics.primitives import EndState, closed_forms
from planner.trajectory import YawPolicy

__all__ = ["MinimumJerkChain"]


class MinimumJerkChain(PiecewisePolynomialModel):
    """Mueller primitives between waypoints every ``segment_s`` seconds (module docstring).

    Args:
        horizon_s: plan length in seconds, a whole multiple of ``segment_s``.
        segment_s: waypoint spacing in seconds.
        sample_dt_s: sample step ``Ts`` of the planner's matrices; ``horizon_s`` must be a
            whole multiple of it.
        final_acc_zero: last segment ends with zero acceleration (see module docstring).
        explicit_acc: make the waypoint accelerations decision variables too (``Z`` gets
            rows ``acc_rows``) tied to the chain by the linear equalities of
            :meth:`equality_constraints`. The trajectories are the same family; what
            changes is sparsity: each segment then depends only on its two waypoints, so
            ``Mp``/``Mv``/``Ma`` and the limit rows are banded instead of dense lower
            triangular (every sample otherwise depends on all earlier waypoints through
            the acceleration recursion), which keeps the optimiser's KKT factorisation
            small (reach-avoid N = 8: see :mod:`planner.optimize`).
        limit_subdivisions: Bezier pieces per segment for the limit constraints. Worst
            ratio of the true peak to the limit for plans on the constraint boundary
            (random zig-zag plans, 1 s segments): 0.23 / 0.56 / 0.84 / 0.90 / 0.94 / 0.97
            for 1 / 2 / 3 / 4 / 6 / 8 pieces (median 1.0 from 3 on), at about
            13 / 27 / 41 / 55 / 83 / 111 rows per segment and axis. Default 3.
        yaw_policy: yaw rule of the trajectories this model produces.

    Attributes (beyond :class:`~planner.dynamics.linear.LinearModel`):
        n_segments, segment_s, waypoint_times_s ``(n_seg,)``, pos_rows, vel_rows (slices
        of ``Z``).
    """

    def __init__(
        self,
        horizon_s: float,
        segment_s: float,
        sample_dt_s: float,
        *,
        final_acc_zero: bool = True,
        explicit_acc: bool = False,
        limit_subdivisions: int = 3,
        yaw_policy: YawPolicy | None = None,
    ) -> None:
        n = ratio_steps(horizon_s, segment_s, "horizon_s / segment_s")
        self.n_segments = n
        self.segment_s = float(segment_s)
        self.final_acc_zero = bool(final_acc_zero)
        self.explicit_acc = bool(explicit_acc)
        self.pos_rows = slice(0, n)
        self.vel_rows = slice(n, 2 * n)
        self.acc_rows = slice(2 * n, 3 * n) if self.explicit_acc else slice(2 * n, 2 * n)
        self.waypoint_times_s = np.arange(1, n + 1) * self.segment_s
        n_dec = 3 * n if self.explicit_acc else 2 * n
        m = n_dec + 3
        eye = np.eye(m)
        P, V, A = eye[n_dec], eye[n_dec + 1], eye[n_dec + 2]
        T = self.segment_s
        Tarr = np.array(T)
        coef = np.empty((n, 6, m))
        eq = np.zeros((n if self.explicit_acc else 0, m))
        for i in range(n):
            last = i == n - 1
            end = EndState.POS_VEL_ACC if (last and self.final_acc_zero) else EndState.POS_VEL
            Pf, Vf = eye[i], eye[n + i]
            d = np.stack([Pf - P - V * T - 0.5 * A * T * T, Vf - V - A * T, -A])
            alpha, beta, gamma = closed_forms(Tarr, end) @ d
            coef[i] = np.stack([P, V, A / 2.0, gamma / 6.0, beta / 24.0, alpha / 120.0])
            A_end = A + gamma * T + beta * T**2 / 2.0 + alpha * T**3 / 6.0
            if self.explicit_acc:  # a_i (a variable) equals the segment's end acceleration
                eq[i] = eye[2 * n + i] - A_end
                A_end = eye[2 * n + i]
            P, V, A = Pf, Vf, A_end
        eq[np.abs(eq) < 1e-14] = 0.0
        self._equalities = eq
        self._build(
            horizon_s=float(horizon_s),
            sample_dt_s=float(sample_dt_s),
            n_dec=n_dec,
            n_init=3,
            segment_t0_s=np.asarray(np.arange(n) * self.segment_s, dtype=np.float64),
            segment_duration_s=np.full(n, self.segment_s),
            coef_maps=coef,
            limit_subdivisions=limit_subdivisions,
            yaw_policy=yaw_policy if yaw_policy is not None else YawPolicy(),
        )

    def equality_constraints(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(G, H)`` with ``G @ Z + H @ X0 = 0`` (per axis) for every valid ``Z``: the
        acceleration chain when ``explicit_acc`` (``n_segments`` rows), else no rows."""
        return self._equalities[:, : self.n_dec], self._equalities[:, self.n_dec :]

    def initial_guess(self, start: ArrayLike, goal: ArrayLike) -> NDArray[np.float64]:
        """Straight line from ``start`` to ``goal`` (ENU m, ``(3,)``) over the horizon.

        The waypoints follow the rest-to-rest minimum-jerk profile
        ``s(u) = 10u^3 - 15u^4 + 6u^5`` along the line, so the guess starts and ends at
        rest and its speed stays within ``1.875 |goal - start| / horizon_s``.

        Returns:
            ``Z`` ``(n_dec, 3)``.
        """
        p_a = np.asarray(start, dtype=float).reshape(-1)
        p_b = np.asarray(goal, dtype=float).reshape(-1)
        if p_a.shape != (3,) or p_b.shape != (3,):
            raise DynamicsError("initial_guess: start and goal must be 3-vectors (ENU m)")
        u = self.waypoint_times_s / self.horizon_s
        s = 10 * u**3 - 15 * u**4 + 6 * u**5
        ds = (30 * u**2 - 60 * u**3 + 30 * u**4) / self.horizon_s
        Z = np.empty((self.n_dec, 3))
        Z[self.pos_rows] = p_a + s[:, None] * (p_b - p_a)
        Z[self.vel_rows] = ds[:, None] * (p_b - p_a)
        if self.explicit_acc:  # the chain's accelerations: solve G_acc a = -(G_pv z + H x0)
            G, H = self.equality_constraints()
            x0 = np.zeros((3, 3))
            x0[0] = p_a
            pv = np.r_[self.pos_rows, self.vel_rows]
            Z[self.acc_rows] = np.linalg.solve(G[:, self.acc_rows], -(G[:, pv] @ Z[pv] + H @ x0))
        return Z
