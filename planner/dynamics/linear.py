"""Linear trajectory models: the interface the planner builds on, and the shared machinery.

Every model is linear and the three axes are decoupled. For one vehicle the decision
matrix ``Z`` ``(n_dec, 3)`` (one column per ENU axis) and the initial state ``X0``
``(n_init, 3)`` (rows ``p0, v0[, a0]``) give, at the sample times
``t_k = k * sample_dt_s``, ``k = 0 .. n_samples - 1`` (``0 .. horizon_s`` inclusive)::

    POS = Mp @ Z + Np @ X0,   VEL = Mv @ Z + Nv @ X0,   ACC = Ma @ Z + Na @ X0

(``(n_samples, 3)``), and continuous-time per-axis limits ``-v_down <= v <= v_max``,
``-a_down <= a <= a_max`` as ``G @ Z + H @ X0 <= h`` (elementwise, ``(n_con, 3)``; rows
``[A; -A]``, the upper bounds then the lower ones).

Soundness of the limits (why they hold on the whole trajectory, not only at samples):
inside each segment the velocity and acceleration are polynomials; on a sub-interval a
polynomial lies in the convex hull of its Bernstein (Bezier) control points, which are
linear in the polynomial's coefficients and hence in ``(Z, X0)``. Bounding every control
point by the limit is therefore a sufficient linear condition. Each segment is split
into ``limit_subdivisions`` equal pieces (de Casteljau subdivision) to make the hull
tight; the tests measure the remaining conservatism (ratio of the true peak to the
limit for trajectories on the constraint boundary). Rows whose ``G`` part is zero (the
start state's own velocity and acceleration) are kept, so the constraints also reject a
start state that itself violates the limits. The closed-form extremum locations of [M] are not used for the
constraints because they depend nonlinearly on the decision variables (the planner needs
linear constraints); they are used by the input-feasibility check instead.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb, factorial
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.dynamics.errors import DynamicsError
from planner.trajectory import Trajectory, YawPolicy

__all__ = ["LimitConstraints", "LinearModel", "PiecewisePolynomialModel", "bernstein_map"]


@dataclass(frozen=True, slots=True)
class LimitConstraints:
    """Linear limits ``G @ Z + H @ X0 <= h`` (elementwise, per axis).

    Attributes:
        G: ``(n_con, n_dec)``.
        H: ``(n_con, n_init)``.
        h: ``(n_con, 3)`` right-hand side (per-axis limits may differ).
        kind: ``(n_con,)`` strings ``"vel"`` or ``"acc"`` naming what each row bounds.
    """

    G: NDArray[np.float64]
    H: NDArray[np.float64]
    h: NDArray[np.float64]
    kind: NDArray[np.str_]

    def __iter__(self) -> Any:
        """Unpack as ``G, H, h = model.limit_constraints(...)``."""
        return iter((self.G, self.H, self.h))

    def residual(self, Z: ArrayLike, X0: ArrayLike) -> NDArray[np.float64]:
        """``G @ Z + H @ X0 - h`` ``(n_con, 3)`` for numpy inputs (<= 0 means satisfied)."""
        return self.G @ np.asarray(Z, float) + self.H @ np.asarray(X0, float) - self.h


@runtime_checkable
class LinearModel(Protocol):
    """What the planner needs from a dynamics model (see module docstring for shapes)."""

    horizon_s: float
    sample_dt_s: float
    n_dec: int
    n_init: int
    times_s: NDArray[np.float64]
    Mp: NDArray[np.float64]
    Np: NDArray[np.float64]
    Mv: NDArray[np.float64]
    Nv: NDArray[np.float64]
    Ma: NDArray[np.float64]
    Na: NDArray[np.float64]

    def limit_constraints(
        self,
        v_max: ArrayLike,
        a_max: ArrayLike,
        v_down: ArrayLike | None = None,
        a_down: ArrayLike | None = None,
    ) -> LimitConstraints: ...

    def initial_guess(self, start: ArrayLike, goal: ArrayLike) -> NDArray[np.float64]: ...

    def trajectory(self, Z: ArrayLike, X0: ArrayLike, name: str = "") -> Trajectory: ...


def bernstein_map(degree: int, order: int, s0: float, s1: float) -> NDArray[np.float64]:
    """Matrix ``(degree - order + 1, degree + 1)`` from power coefficients to control points.

    For ``p(t) = sum_j c_j t^j`` it maps ``c`` to the Bernstein control points of the
    ``order``-th derivative of ``p`` restricted to ``[s0, s1]``.
    """
    n = degree - order
    if n < 0:
        raise DynamicsError(f"derivative order {order} exceeds polynomial degree {degree}")
    D = np.zeros((n + 1, degree + 1))
    for j in range(n + 1):
        D[j, j + order] = factorial(j + order) / factorial(j)
    h = s1 - s0
    R = np.zeros((n + 1, n + 1))  # reparametrise t = s0 + h u: e_k = sum_j d_j C(j,k) s0^(j-k) h^k
    for j in range(n + 1):
        for k in range(j + 1):
            R[k, j] = comb(j, k) * s0 ** (j - k) * h**k
    P = np.zeros((n + 1, n + 1))  # power (in u) -> Bernstein on [0, 1]
    for i in range(n + 1):
        for k in range(i + 1):
            P[i, k] = comb(i, k) / comb(n, k)
    return P @ R @ D


def as_axis_limit(value: ArrayLike, field: str) -> NDArray[np.float64]:
    arr = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()
    if not np.all(np.isfinite(arr)) or np.any(arr < 0.0):
        raise DynamicsError(f"{field} must be finite and >= 0 (scalar or 3 per-axis values)")
    return arr


def _is_casadi(x: object) -> bool:
    return type(x).__module__.startswith("casadi")


def ratio_steps(total_s: float, step_s: float, what: str) -> int:
    if not (np.isfinite(total_s) and np.isfinite(step_s)) or total_s <= 0 or step_s <= 0:
        raise DynamicsError(f"{what}: durations must be finite and > 0")
    n = round(total_s / step_s)
    if n < 1 or abs(n * step_s - total_s) > 1e-9 * max(1.0, total_s):
        raise DynamicsError(f"{what}: {total_s} s is not a whole multiple of {step_s} s")
    return n


class PiecewisePolynomialModel:
    """A linear model given by segment polynomials whose coefficients are linear in ``(Z, X0)``.

    Subclasses call :meth:`_build` with ``coef_maps`` ``(n_seg, deg + 1, n_dec + n_init)``:
    coefficient ``j`` (of ``(t - t0)^j``) of segment ``s`` is ``coef_maps[s, j] @ [Z; X0]``
    per axis. Everything the planner needs (sample matrices, limits, trajectories) follows.
    """

    horizon_s: float
    sample_dt_s: float
    n_dec: int
    n_init: int
    n_samples: int
    times_s: NDArray[np.float64]
    segment_t0_s: NDArray[np.float64]
    segment_duration_s: NDArray[np.float64]
    coef_maps: NDArray[np.float64]
    limit_subdivisions: int
    yaw_policy: YawPolicy
    Mp: NDArray[np.float64]
    Np: NDArray[np.float64]
    Mv: NDArray[np.float64]
    Nv: NDArray[np.float64]
    Ma: NDArray[np.float64]
    Na: NDArray[np.float64]

    def _build(
        self,
        *,
        horizon_s: float,
        sample_dt_s: float,
        n_dec: int,
        n_init: int,
        segment_t0_s: NDArray[np.float64],
        segment_duration_s: NDArray[np.float64],
        coef_maps: NDArray[np.float64],
        limit_subdivisions: int,
        yaw_policy: YawPolicy,
    ) -> None:
        if limit_subdivisions < 1:
            raise DynamicsError("limit_subdivisions must be >= 1")
        self.horizon_s = float(horizon_s)
        self.sample_dt_s = float(sample_dt_s)
        self.n_dec = n_dec
        self.n_init = n_init
        self.segment_t0_s = segment_t0_s
        self.segment_duration_s = segment_duration_s
        self.coef_maps = coef_maps
        self.limit_subdivisions = limit_subdivisions
        self.yaw_policy = yaw_policy
        n_steps = ratio_steps(horizon_s, sample_dt_s, "horizon_s / sample_dt_s")
        self.n_samples = n_steps + 1
        self.times_s = np.asarray(np.arange(self.n_samples) * self.sample_dt_s, dtype=np.float64)
        seg = np.clip(
            np.searchsorted(segment_t0_s, self.times_s + 1e-12, side="right") - 1,
            0,
            len(segment_t0_s) - 1,
        )
        tau = self.times_s - segment_t0_s[seg]
        deg = coef_maps.shape[1] - 1
        mats = []
        for order in range(3):
            w = np.zeros((self.n_samples, deg + 1))
            for j in range(order, deg + 1):
                w[:, j] = factorial(j) / factorial(j - order) * tau ** (j - order)
            full = np.einsum("kj,kjm->km", w, coef_maps[seg])
            mats.append((full[:, :n_dec].copy(), full[:, n_dec:].copy()))
        (self.Mp, self.Np), (self.Mv, self.Nv), (self.Ma, self.Na) = mats
        for m in (self.Mp, self.Np, self.Mv, self.Nv, self.Ma, self.Na, self.times_s):
            m.setflags(write=False)
        self._limit_rows = self._build_limit_rows()

    def _build_limit_rows(self) -> tuple[NDArray[np.float64], NDArray[np.str_]]:
        """Bernstein control-point rows ``(n, n_dec + n_init)`` for velocity and acceleration."""
        deg = self.coef_maps.shape[1] - 1
        rows: list[NDArray[np.float64]] = []
        kinds: list[str] = []
        Q = self.limit_subdivisions
        n_seg, _, m = self.coef_maps.shape
        durations, group = np.unique(self.segment_duration_s, return_inverse=True)
        for order, kind in ((1, "vel"), (2, "acc")):
            if order > deg:
                continue
            cp = np.empty((n_seg, Q, deg - order + 1, m))
            for g, T in enumerate(durations):  # one set of maps per distinct duration
                edges = np.linspace(0.0, T, Q + 1)
                B = np.stack([bernstein_map(deg, order, edges[q], edges[q + 1]) for q in range(Q)])
                segs = np.nonzero(group == g)[0]
                cp[segs] = np.einsum("qij,sjm->sqim", B, self.coef_maps[segs])
            rows.append(cp.reshape(-1, m))
            kinds.extend([kind] * (cp.size // m))
        A = np.vstack(rows)
        # Drop all-zero rows and duplicates (the shared end/start control points of
        # adjacent pieces).
        scale = np.abs(A).max(axis=1, keepdims=True)
        keep = scale[:, 0] > 0.0
        A, kinds_arr, scale = A[keep], np.asarray(kinds)[keep], scale[keep]
        key = np.round(A / scale, 12)
        _, first = np.unique(
            np.column_stack([key, (kinds_arr == "acc")]), axis=0, return_index=True
        )
        first = np.sort(first)
        return A[first], kinds_arr[first]

    def equality_constraints(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(G, H)`` with ``G @ Z + H @ X0 = 0`` for every valid ``Z`` (none by default;
        a model whose ``Z`` carries redundant variables ties them down here)."""
        return np.zeros((0, self.n_dec)), np.zeros((0, self.n_init))

    def limit_constraints(
        self,
        v_max: ArrayLike,
        a_max: ArrayLike,
        v_down: ArrayLike | None = None,
        a_down: ArrayLike | None = None,
    ) -> LimitConstraints:
        """Sound continuous-time limits ``-v_down[i] <= v_i(t) <= v_max[i]``,
        ``-a_down[i] <= a_i(t) <= a_max[i]``.

        Args:
            v_max: m/s, scalar or per-axis ``(3,)``: the upper bounds.
            a_max: m/s^2, scalar or per-axis ``(3,)``.
            v_down, a_down: the lower bounds' magnitudes (default: ``v_max``, ``a_max``,
                symmetric limits).

        Returns:
            :class:`LimitConstraints` ``[A; -A]`` with ``G @ Z + H @ X0 <= h`` meaning all
            limits hold for every ``t`` in ``[0, horizon_s]`` (see module docstring).
        """
        vm = as_axis_limit(v_max, "v_max")
        am = as_axis_limit(a_max, "a_max")
        vd = vm if v_down is None else as_axis_limit(v_down, "v_down")
        ad = am if a_down is None else as_axis_limit(a_down, "a_down")
        A, kinds = self._limit_rows
        vel = (kinds == "vel")[:, None]
        upper = np.where(vel, vm[None, :], am[None, :])
        lower = np.where(vel, vd[None, :], ad[None, :])
        G = np.vstack([A[:, : self.n_dec], -A[:, : self.n_dec]])
        H = np.vstack([A[:, self.n_dec :], -A[:, self.n_dec :]])
        return LimitConstraints(
            G=G, H=H, h=np.vstack([upper, lower]), kind=np.concatenate([kinds, kinds])
        )

    def _check_state(self, Z: Any, X0: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        Zn = np.asarray(Z, dtype=float)
        Xn = np.asarray(X0, dtype=float)
        if Zn.shape != (self.n_dec, 3):
            raise DynamicsError(f"Z must have shape ({self.n_dec}, 3), got {Zn.shape}")
        if Xn.shape != (self.n_init, 3):
            raise DynamicsError(f"X0 must have shape ({self.n_init}, 3), got {Xn.shape}")
        if not (np.all(np.isfinite(Zn)) and np.all(np.isfinite(Xn))):
            raise DynamicsError("Z and X0 must be finite")
        return Zn, Xn

    def _apply(self, M: NDArray[np.float64], N: NDArray[np.float64], Z: Any, X0: Any) -> Any:
        if _is_casadi(Z) or _is_casadi(X0):
            import casadi as ca

            return ca.mtimes(ca.DM(M), Z) + ca.mtimes(ca.DM(N), X0)
        Zn, Xn = self._check_state(Z, X0)
        return M @ Zn + N @ Xn

    def positions(self, Z: Any, X0: Any) -> Any:
        """``Mp @ Z + Np @ X0`` ``(n_samples, 3)`` in m; numpy or CasADi (SX/MX/DM) ``Z``."""
        return self._apply(self.Mp, self.Np, Z, X0)

    def velocities(self, Z: Any, X0: Any) -> Any:
        """``Mv @ Z + Nv @ X0`` ``(n_samples, 3)`` in m/s; numpy or CasADi ``Z``."""
        return self._apply(self.Mv, self.Nv, Z, X0)

    def accelerations(self, Z: Any, X0: Any) -> Any:
        """``Ma @ Z + Na @ X0`` ``(n_samples, 3)`` in m/s^2; numpy or CasADi ``Z``."""
        return self._apply(self.Ma, self.Na, Z, X0)

    def segment_coefficients(self, Z: ArrayLike, X0: ArrayLike) -> NDArray[np.float64]:
        """Power coefficients ``(n_seg, 3, deg + 1)`` of every segment (local time, ascending)."""
        Zn, Xn = self._check_state(Z, X0)
        W = np.vstack([Zn, Xn])
        return np.einsum("sjm,ma->saj", self.coef_maps, W)

    def trajectory(self, Z: ArrayLike, X0: ArrayLike, name: str = "") -> Trajectory:
        """The exact piecewise-polynomial trajectory for numeric ``Z`` ``(n_dec, 3)``, ``X0``."""
        return Trajectory(
            segment_t0_s=self.segment_t0_s,
            segment_duration_s=self.segment_duration_s,
            coeffs=self.segment_coefficients(Z, X0),
            name=name,
            yaw_policy=self.yaw_policy,
        )
