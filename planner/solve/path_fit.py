"""A trajectory of the planner's linear model fitted to a timed path, within the vehicle's
velocity and acceleration limits and the workspace: per axis, a small QP
(:func:`fit_within_limits`, DAQP through CasADi) over the pieces :func:`axis_fit` builds.
The initial guess (:mod:`planner.solve.guess`) and the combinatorial stage's start
(:mod:`planner.solve.coarse_fit`) both fit their paths with it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from planner.cache import BoundedCache
from planner.dynamics.limits import vehicle_bounds
from planner.solve.nlp import limit_bounds, two_sided_rows

__all__ = ["AxisFit", "axis_fit", "fit_within_limits", "guess_qp"]


@dataclass(frozen=True, slots=True)
class AxisFit:
    """The least-squares fit of one vehicle's samples to a path, axis by axis, as a QP in
    the decisions of one axis (:func:`axis_fit`).

    Attributes:
        A: (m, n_dec) rows: the end velocity, the model's equalities, the kept limit rows,
            the sampled positions (the workspace).
        H: (n_dec, n_dec) the objective's Hessian.
        g, lba, uba, off: per axis: the objective's gradient, the rows' bounds, and what the
            start state adds to the rows (already taken off the bounds).
        n_fix: the leading rows held at 0 (the end velocity, free without rest at the end;
            the model's equalities).
        cons, half: the limit rows (:meth:`limit_constraints`) and how many are kept.
    """

    A: np.ndarray
    H: np.ndarray
    g: list[np.ndarray]
    lba: list[np.ndarray]
    uba: list[np.ndarray]
    off: list[np.ndarray]
    n_fix: int
    cons: Any
    half: int


def axis_fit(
    model: Any,
    path: np.ndarray,
    x0: np.ndarray,
    limits: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    ws: Any,
    end_at_rest: bool,
) -> AxisFit:
    """The per-axis QP pieces of fitting ``path`` (n, 3) from start ``x0`` within per-axis
    ``limits`` ``(vlo, vhi, alo, ahi)`` and the workspace's box (:class:`AxisFit`)."""
    Mp, Np = np.asarray(model.Mp), np.asarray(model.Np)
    vlo, vhi, alo, ahi = limits
    cons = model.limit_constraints(vhi, ahi, -vlo, -alo)
    half = two_sided_rows(cons)
    lo_all, hi_all = limit_bounds(cons, half)
    Ge, He = model.equality_constraints()
    n_fix = 1 + len(Ge)  # rows held at 0: the end velocity, the model's equalities
    fix_lo, fix_hi = np.zeros(n_fix), np.zeros(n_fix)
    if not end_at_rest:  # the end velocity free
        fix_lo[0], fix_hi[0] = -np.inf, np.inf
    A = np.vstack([model.Mv[-1:], Ge, cons.G[:half], Mp])
    H = 2 * (Mp.T @ Mp) + 1e-6 * np.eye(model.n_dec)
    g, lba, uba, offs = [], [], [], []
    for a in range(3):
        xa = x0[:, a]
        off = np.concatenate([model.Nv[-1:] @ xa, He @ xa, cons.H[:half] @ xa, Np @ xa])
        offs.append(off)
        lba.append(np.concatenate([fix_lo, lo_all[:, a], np.full(len(Mp), ws.lo_enu_m[a])]) - off)
        uba.append(np.concatenate([fix_hi, hi_all[:, a], np.full(len(Mp), ws.hi_enu_m[a])]) - off)
        g.append(-2 * Mp.T @ (path[:, a] - Np @ xa))
    return AxisFit(A, H, g, lba, uba, offs, n_fix, cons, half)


def fit_within_limits(
    model: Any, path: np.ndarray, x0: np.ndarray, vehicle: Any, ws: Any, end_at_rest: bool = True
) -> np.ndarray:
    """``Z`` (n_dec, 3) whose samples are closest (least squares) to ``path`` (n, 3) among
    the trajectories that respect the vehicle's limits, end at rest and stay in the
    workspace at the samples: a small QP per axis (DAQP, dense, ``n_dec`` variables).

    The unconstrained fit of a timed polyline rings at its corners (reach-avoid N = 4:
    2.4x the acceleration limit), and IPOPT then spends its first iterations restoring
    feasibility instead of raising the robustness.  If the QP fails, falls back to the
    least-squares fit with only the equalities (end at rest, the model's own).
    """
    (vlo, vhi), (alo, ahi) = (b.box() for b in vehicle_bounds(vehicle))
    fit = axis_fit(model, path, x0, (vlo, vhi, alo, ahi), ws, end_at_rest)
    A, H = fit.A, fit.H
    qp = guess_qp(model.n_dec, A)
    out = np.zeros((model.n_dec, 3))
    for a in range(3):
        g = fit.g[a]
        sol = qp(h=H, g=g, a=A, lba=fit.lba[a], uba=fit.uba[a])
        za = np.asarray(sol["x"]).reshape(-1)
        if not qp.stats().get("success", False) or not np.all(np.isfinite(za)):
            # Equality-constrained least squares only (limits and workspace dropped).
            held = slice(0 if end_at_rest else 1, fit.n_fix)
            E = A[held]
            kkt = np.block([[H, E.T], [E, np.zeros((len(E), len(E)))]])
            rhs = np.concatenate([-g, -fit.off[a][held]])
            za = np.linalg.lstsq(kkt, rhs, rcond=None)[0][: model.n_dec]
        out[:, a] = za
    return out


#: the initial guess's QP solvers by size (oldest forgotten first)
_QP_SOLVERS: BoundedCache[Any] = BoundedCache(16)


def guess_qp(n_dec: int, A: np.ndarray) -> Any:
    def build() -> Any:
        return ca.conic(
            "guess_fit",
            "daqp",
            {"h": ca.Sparsity.dense(n_dec, n_dec), "a": ca.Sparsity.dense(*A.shape)},
            {"error_on_fail": False},
        )

    return _QP_SOLVERS.get_or_build((n_dec, A.shape[0]), build)[0]
