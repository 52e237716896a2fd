"""Mueller's input-feasibility test (thrust and body rates), run after planning.

A quad-rotor following ``p(t)`` needs the mass-normalised collective thrust
``f(t) = |a(t) + g e_up|`` (m/s^2) and, for its thrust direction
``e3 = (a + g e_up) / f``, the roll/pitch body rates ``|omega_xy| = |j - (j.e3) e3| / f``
(yaw rate depends on the yaw policy and is not limited here). Feasible means
``f_min <= f(t) <= f_max`` and ``|omega_xy(t)| <= omega_max`` for all ``t``.

Two parts (both vectorised):

* :func:`primitive_input_feasibility` is the recursive test of Mueller et al. (IEEE
  T-RO 2015, "Input feasibility"): on a section ``[t1, t2]`` bound each axis's
  acceleration by its exact extrema (acceleration is a cubic, so the extrema are at the
  ends or at the roots of the quadratic jerk), bound the thrust from these boxes and the
  body rate by ``omega <= |j|_max / f_min``; decide feasible, definitely infeasible
  (thrust too high / too low), or bisect until sections are shorter than
  ``min_section_s`` (then "indeterminable"). It runs breadth-first over all primitives
  and sections at once instead of recursing per primitive. Difference from the
  reference: when one half is indeterminable and a later one infeasible, this reports
  infeasible (the reference stops at the first non-feasible half).
* :func:`check_input_feasibility` applies it to a planned :class:`Trajectory` and, for
  every segment the test does not prove feasible, evaluates the exact ``f(t)`` and
  ``omega(t)`` on a dyadic grid (``2^K + 1`` points per segment with spacing at most
  ``check_dt_s``, which contains every section end the recursive test looked at) plus
  every acceleration extremum; it reports the first time a limit is violated. A
  "definitely infeasible" verdict is always witnessed by one of these points.
  Acceleration jumps between segments (the double integrator) need an infinite body rate
  and are reported as body-rate violations at the jump when ``omega_max`` is finite.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.dynamics.errors import DynamicsError
from planner.trajectory import Trajectory

__all__ = [
    "FeasibilityReport",
    "InputFeasibility",
    "InputLimits",
    "check_input_feasibility",
    "primitive_input_feasibility",
    "thrust_and_body_rate",
]

GRAVITY_M_S2 = 9.81


class InputFeasibility(enum.IntEnum):
    """Verdict of Mueller's recursive test (ordered by severity for aggregation)."""

    FEASIBLE = 0
    INDETERMINABLE = 1
    INFEASIBLE_THRUST_HIGH = 2
    INFEASIBLE_THRUST_LOW = 3


@dataclass(frozen=True, slots=True)
class InputLimits:
    """Mass-normalised thrust range (m/s^2) and roll/pitch body-rate bound (rad/s)."""

    f_min_m_s2: float
    f_max_m_s2: float
    omega_max_rad_s: float
    gravity_m_s2: float = GRAVITY_M_S2

    def __post_init__(self) -> None:
        if not (0.0 <= self.f_min_m_s2 < self.f_max_m_s2) or not math.isfinite(self.f_max_m_s2):
            raise DynamicsError(
                f"InputLimits: need 0 <= f_min_m_s2 < f_max_m_s2 < inf, "
                f"got {self.f_min_m_s2}, {self.f_max_m_s2}"
            )
        if not self.omega_max_rad_s > 0.0:
            raise DynamicsError(
                f"InputLimits: omega_max_rad_s must be > 0, got {self.omega_max_rad_s}"
            )


@dataclass(frozen=True, slots=True)
class FeasibilityReport:
    """Result of :func:`check_input_feasibility`.

    Attributes:
        feasible: no violation found (proven by the recursive test or on the dense grid).
        verdict: worst recursive-test verdict over the segments.
        first_violation_t_s: earliest violating time in s (None if feasible).
        violation: ``"thrust_high"``, ``"thrust_low"`` or ``"body_rate"`` at that time.
        max_thrust_m_s2, min_thrust_m_s2, max_body_rate_rad_s: extremes over the checked
            points of the segments not proven feasible (NaN when all were proven).
        n_proven_segments: segments the recursive test proved feasible.
    """

    feasible: bool
    verdict: InputFeasibility
    first_violation_t_s: float | None
    violation: str | None
    max_thrust_m_s2: float
    min_thrust_m_s2: float
    max_body_rate_rad_s: float
    n_proven_segments: int


def _poly_eval(c: NDArray[np.float64], t: NDArray[np.float64], order: int) -> NDArray[np.float64]:
    """Derivative ``order`` of ascending polynomials ``c (..., deg+1)`` at ``t (...)``."""
    deg = c.shape[-1] - 1
    out = np.zeros(np.broadcast_shapes(c.shape[:-1], t.shape))
    for j in range(deg, order - 1, -1):
        out = out * t + math.factorial(j) / math.factorial(j - order) * c[..., j]
    return out


def _jerk_roots(c: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The (up to two) roots of the quadratic jerk of quintics ``c (..., 6)``; NaN if none."""
    A, B, C = 60.0 * c[..., 5], 24.0 * c[..., 4], 6.0 * c[..., 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = B * B - 4.0 * A * C
        sq = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
        q = -0.5 * (B + np.where(B >= 0.0, 1.0, -1.0) * sq)
        r1 = q / A
        r2 = C / q
    return r1, r2


def _pad6(coeffs: NDArray[np.float64]) -> NDArray[np.float64]:
    deg = coeffs.shape[-1] - 1
    if deg > 5:
        raise DynamicsError(f"input feasibility supports polynomials up to degree 5, got {deg}")
    if deg == 5:
        return coeffs
    pad = [(0, 0)] * (coeffs.ndim - 1) + [(0, 5 - deg)]
    return np.pad(coeffs, pad)


def primitive_input_feasibility(
    coeffs: ArrayLike,
    duration_s: ArrayLike,
    limits: InputLimits,
    min_section_s: float = 0.02,
) -> NDArray[np.int_]:
    """Mueller's recursive input-feasibility test for many primitives at once.

    Args:
        coeffs: ``(n, 3, deg+1)`` ENU power coefficients (``deg <= 5``) in local time.
        duration_s: ``(n,)`` durations.
        limits: thrust and body-rate limits.
        min_section_s: bisection stops below this section length ("indeterminable").

    Returns:
        ``(n,)`` :class:`InputFeasibility` codes (ints).
    """
    c = _pad6(np.asarray(coeffs, dtype=float))
    T = np.broadcast_to(np.asarray(duration_s, dtype=float), c.shape[:1])
    if c.ndim != 3 or c.shape[1] != 3:
        raise DynamicsError(f"coeffs must have shape (n, 3, deg+1), got {c.shape}")
    n = c.shape[0]
    g = np.array([0.0, 0.0, limits.gravity_m_s2])
    fmin2, fmax2 = limits.f_min_m_s2**2, limits.f_max_m_s2**2
    r1, r2 = _jerk_roots(c)  # (n, 3)
    vertex = np.where(
        c[..., 5] != 0.0,
        -(24.0 * c[..., 4]) / (120.0 * np.where(c[..., 5] != 0.0, c[..., 5], 1.0)),
        np.nan,
    )
    result = np.zeros(n, dtype=int)
    prim = np.arange(n)
    t1 = np.zeros(n)
    t2 = T.astype(float).copy()
    while prim.size:
        live = result[prim] < InputFeasibility.INFEASIBLE_THRUST_HIGH
        prim, t1, t2 = prim[live], t1[live], t2[live]
        if not prim.size:
            break
        short = (t2 - t1) < min_section_s
        if np.any(short):
            idx = prim[short]
            result[idx] = np.maximum(result[idx], InputFeasibility.INDETERMINABLE)
            prim, t1, t2 = prim[~short], t1[~short], t2[~short]
            if not prim.size:
                break
        cp = c[prim]  # (k, 3, 6)
        a1 = _poly_eval(cp, t1[:, None], 2) + g
        a2 = _poly_eval(cp, t2[:, None], 2) + g
        f1 = np.sum(a1 * a1, axis=1)
        f2 = np.sum(a2 * a2, axis=1)
        code = np.zeros(prim.size, dtype=int)
        code[np.maximum(f1, f2) > fmax2] = InputFeasibility.INFEASIBLE_THRUST_HIGH
        code[(code == 0) & (np.minimum(f1, f2) < fmin2)] = InputFeasibility.INFEASIBLE_THRUST_LOW
        amin = np.minimum(a1, a2)
        amax = np.maximum(a1, a2)
        for r in (r1[prim], r2[prim]):
            inside = (r > t1[:, None]) & (r < t2[:, None])
            ar = _poly_eval(cp, np.where(inside, r, t1[:, None]), 2) + g
            amin = np.where(inside, np.minimum(amin, ar), amin)
            amax = np.where(inside, np.maximum(amax, ar), amax)
        big2 = np.maximum(amin * amin, amax * amax)
        code[(code == 0) & np.any(big2 > fmax2, axis=1)] = InputFeasibility.INFEASIBLE_THRUST_HIGH
        small2 = np.where(amin * amax < 0.0, 0.0, np.minimum(amin * amin, amax * amax))
        fmin_sq = small2.sum(axis=1)
        fmax_sq = big2.sum(axis=1)
        j1 = _poly_eval(cp, t1[:, None], 3)
        j2 = _poly_eval(cp, t2[:, None], 3)
        jmax2 = np.maximum(j1 * j1, j2 * j2)
        vt = vertex[prim]
        vin = (vt > t1[:, None]) & (vt < t2[:, None])
        jv = _poly_eval(cp, np.where(vin, vt, t1[:, None]), 3)
        jmax2 = np.where(vin, np.maximum(jmax2, jv * jv), jmax2).sum(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            w_bound = np.where(fmin_sq > 1e-6, np.sqrt(jmax2 / fmin_sq), np.inf)
        code[(code == 0) & (fmax_sq < fmin2)] = InputFeasibility.INFEASIBLE_THRUST_LOW
        code[(code == 0) & (fmin_sq > fmax2)] = InputFeasibility.INFEASIBLE_THRUST_HIGH
        bad = code > 0
        np.maximum.at(result, prim[bad], code[bad])
        split = (code == 0) & (
            (fmin_sq < fmin2) | (fmax_sq > fmax2) | (w_bound > limits.omega_max_rad_s)
        )
        tm = 0.5 * (t1[split] + t2[split])
        prim = np.concatenate([prim[split], prim[split]])
        t1, t2 = np.concatenate([t1[split], tm]), np.concatenate([tm, t2[split]])
    return result


def thrust_and_body_rate(
    traj: Trajectory, t_s: ArrayLike, gravity_m_s2: float = GRAVITY_M_S2
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact thrust ``f(t)`` (m/s^2) and roll/pitch rate ``|omega_xy(t)|`` (rad/s), ``(n,)``."""
    t = np.asarray(t_s, dtype=float)
    thrust_vec = traj.acceleration(t) + np.array([0.0, 0.0, gravity_m_s2])
    f = np.linalg.norm(thrust_vec, axis=1)
    j = traj.jerk(t)
    with np.errstate(divide="ignore", invalid="ignore"):
        e3 = thrust_vec / f[:, None]
        perp = j - np.sum(j * e3, axis=1, keepdims=True) * e3
        w = np.where(
            f > 0.0, np.linalg.norm(perp, axis=1) / f, np.where(np.any(j != 0, axis=1), np.inf, 0.0)
        )
    return f, w


def check_input_feasibility(
    traj: Trajectory,
    limits: InputLimits,
    *,
    min_section_s: float = 0.02,
    check_dt_s: float = 1e-3,
) -> FeasibilityReport:
    """Thrust and body-rate feasibility of a planned trajectory (module docstring).

    Args:
        traj: the trajectory (segments of degree <= 5).
        limits: thrust range and body-rate bound.
        min_section_s: smallest section of the recursive test.
        check_dt_s: largest spacing of the dense check (at most ``min_section_s``).

    Returns:
        :class:`FeasibilityReport` with the first violating time, if any.
    """
    if not (0.0 < check_dt_s <= min_section_s):
        raise DynamicsError("check_dt_s must be > 0 and <= min_section_s")
    codes = primitive_input_feasibility(traj.coeffs, traj.segment_duration_s, limits, min_section_s)
    verdict = InputFeasibility(int(codes.max()))
    todo = np.nonzero(codes != InputFeasibility.FEASIBLE)[0]
    first_t: float | None = None
    what: str | None = None
    fmax = fmin = wmax = float("nan")
    if todo.size:
        T = traj.segment_duration_s[todo]
        K = int(np.ceil(np.log2(max(float(T.max()) / check_dt_s, 1.0))))
        u = np.linspace(0.0, 1.0, 2**K + 1)
        c = _pad6(traj.coeffs[todo])
        r1, r2 = _jerk_roots(c)
        extra = np.concatenate([r1, r2], axis=1) / T[:, None]  # (k, 6) in units of T
        extra = np.where((extra > 0.0) & (extra < 1.0), extra, 0.0)
        uu = np.sort(
            np.concatenate([np.broadcast_to(u, (todo.size, u.size)), extra], axis=1), axis=1
        )
        t = (traj.segment_t0_s[todo][:, None] + uu * T[:, None]).ravel()
        # Keep each point inside its own segment (the end point belongs to it too).
        t = np.minimum(t, traj.segment_t0_s[todo].repeat(uu.shape[1]) + T.repeat(uu.shape[1]))
        f, w = _eval_in_segments(
            traj, todo.repeat(uu.shape[1]), uu.ravel() * T.repeat(uu.shape[1]), limits
        )
        high = f > limits.f_max_m_s2
        low = f < limits.f_min_m_s2
        rate = w > limits.omega_max_rad_s
        viol = high | low | rate
        fmax, fmin, wmax = float(f.max()), float(f.min()), float(w.max())
        if np.any(viol):
            k = int(np.argmin(np.where(viol, t, np.inf)))
            first_t = float(t[k])
            what = "thrust_high" if high[k] else ("thrust_low" if low[k] else "body_rate")
    # Acceleration jumps between segments need an infinite body rate.
    if traj.n_segments > 1 and math.isfinite(limits.omega_max_rad_s):
        tb = traj.segment_t0_s[1:]
        left = _eval_acc(traj, np.arange(traj.n_segments - 1), traj.segment_duration_s[:-1])
        right = _eval_acc(traj, np.arange(1, traj.n_segments), np.zeros(tb.size))
        jump = np.linalg.norm(left - right, axis=1) > 1e-9 * np.maximum(
            1.0, np.linalg.norm(left, axis=1)
        )
        if np.any(jump):
            tj = float(tb[np.argmax(jump)])
            wmax = float("inf")
            if first_t is None or tj < first_t:
                first_t, what = tj, "body_rate"
    return FeasibilityReport(
        feasible=first_t is None,
        verdict=verdict,
        first_violation_t_s=first_t,
        violation=what,
        max_thrust_m_s2=fmax,
        min_thrust_m_s2=fmin,
        max_body_rate_rad_s=wmax,
        n_proven_segments=int(np.sum(codes == InputFeasibility.FEASIBLE)),
    )


def _eval_acc(
    traj: Trajectory, seg: NDArray[np.intp], tau: NDArray[np.float64]
) -> NDArray[np.float64]:
    return _poly_eval(traj.coeffs[seg], tau[:, None], 2)


def _eval_in_segments(
    traj: Trajectory, seg: NDArray[np.intp], tau: NDArray[np.float64], limits: InputLimits
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact thrust and body rate at local times ``tau`` of segments ``seg`` (no hold logic)."""
    c = traj.coeffs[seg]
    a = _poly_eval(c, tau[:, None], 2) + np.array([0.0, 0.0, limits.gravity_m_s2])
    j = _poly_eval(c, tau[:, None], 3)
    f = np.linalg.norm(a, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        e3 = a / f[:, None]
        perp = j - np.sum(j * e3, axis=1, keepdims=True) * e3
        w = np.where(f > 0.0, np.linalg.norm(perp, axis=1) / f, np.inf)
    return f, w
