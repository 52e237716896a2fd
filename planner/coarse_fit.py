"""The combinatorial stage's plan as a start of the NLP: its waypoints fitted within the
vehicles' limits as the NLP states them (:func:`waypoint_guess`).

The initial guess (:func:`planner.guess._fitted`) fits each axis on its own, within a
per-axis box inside the horizontal speed and acceleration polygon (:meth:`Bounds.box`): 3.5
m/s along x for a 5 m/s vehicle.  The coarse plan moves at up to the limits in any
direction, so that box made its fit fall behind it: on the allocation mission one drone
trailed its coarse plan by 23 m after 36 s of flight along the line, and the start was at
-15.5 m where the coarse plan had +0.3.  Here the horizontal axes are fitted together,
within the per-axis bounds and the :data:`planner.limits.NORM_DIRECTIONS` rows, the
polygon the NLP itself keeps (:func:`planner.nlp.vehicle_limit_bounds`); the vertical axis
alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import casadi as ca
import numpy as np

from planner.cache import BoundedCache
from planner.guess import _fit_within_limits
from planner.limits import NORM_DIRECTIONS, vehicle_bounds
from planner.nlp import _limit_bounds, _two_sided_rows
from planner.problem import Problem, Vehicle
from planner.regions import Region

__all__ = ["waypoint_guess"]

_QPS: BoundedCache[Any] = BoundedCache(16)


def _qp(n: int, m: int) -> Any:
    def build() -> Any:
        return ca.conic(
            "coarse_fit",
            "daqp",
            {"h": ca.Sparsity.dense(n, n), "a": ca.Sparsity.dense(m, n)},
            {"error_on_fail": False},
        )

    return _QPS.get_or_build((n, m), build)[0]


def _fit_xy(
    model: Any, path: np.ndarray, x0: np.ndarray, vehicle: Vehicle, ws: Region, end_at_rest: bool
) -> np.ndarray | None:
    """``Z`` (n_dec, 3) closest (least squares at the samples) to ``path`` (n, 3) among the
    trajectories within the NLP's limit rows (horizontal polygon included), at rest at the
    end when asked, in the workspace's box at the samples; None when the QP fails."""
    Mp, Np = np.asarray(model.Mp), np.asarray(model.Np)
    vel, acc = vehicle_bounds(vehicle)
    (vlo, vhi, vb), (alo, ahi, ab) = vel.linear(), acc.linear()
    cons = model.limit_constraints(vhi, ahi, -vlo, -alo)
    half = _two_sided_rows(cons)
    lo_all, hi_all = _limit_bounds(cons, half)
    Ge, He = model.equality_constraints()
    n_fix = 1 + len(Ge)
    fix_lo, fix_hi = np.zeros(n_fix), np.zeros(n_fix)
    if not end_at_rest:
        fix_lo[0], fix_hi[0] = -np.inf, np.inf
    A1 = np.vstack([model.Mv[-1:], Ge, cons.G[:half], Mp])
    n, m1 = model.n_dec, len(A1)
    G, Hh = cons.G[:half], cons.H[:half]
    blocks = [np.zeros((3 * m1, 3 * n))]
    lba, uba, g = [], [], []
    for a in range(3):
        blocks[0][a * m1 : (a + 1) * m1, a * n : (a + 1) * n] = A1
        xa = x0[:, a]
        off = np.concatenate([model.Nv[-1:] @ xa, He @ xa, Hh @ xa, Np @ xa])
        lba.append(np.concatenate([fix_lo, lo_all[:, a], np.full(len(Mp), ws.lo_enu_m[a])]) - off)
        uba.append(np.concatenate([fix_hi, hi_all[:, a], np.full(len(Mp), ws.hi_enu_m[a])]) - off)
        g.append(-2 * Mp.T @ (path[:, a] - Np @ xa))
    if np.isfinite(vb) or np.isfinite(ab):
        b = np.where(cons.kind[:half] == "vel", vb, ab)
        for c, s in NORM_DIRECTIONS:
            row = np.zeros((half, 3 * n))
            row[:, :n], row[:, n : 2 * n] = c * G, s * G
            blocks.append(row)
            off = c * (Hh @ x0[:, 0]) + s * (Hh @ x0[:, 1])
            lba.append(-b - off)
            uba.append(b - off)
    A = np.vstack(blocks)
    H1 = 2 * (Mp.T @ Mp) + 1e-6 * np.eye(n)
    H = np.kron(np.eye(3), H1)
    qp = _qp(3 * n, len(A))
    sol = qp(h=H, g=np.concatenate(g), a=A, lba=np.concatenate(lba), uba=np.concatenate(uba))
    z = np.asarray(sol["x"]).reshape(-1)
    if not qp.stats().get("success", False) or not np.all(np.isfinite(z)):
        return None
    return z.reshape(3, n).T


def waypoint_guess(
    problem: Problem,
    model: Any,
    x0s: list[np.ndarray],
    times_s: np.ndarray,
    positions_enu_m: Sequence[np.ndarray],
) -> np.ndarray:
    """The decision vector whose trajectories follow given waypoints (the combinatorial
    stage's coarse plan, :mod:`planner.milp`): each vehicle's ``(N + 1, 3)`` positions at
    ``times_s`` (``(N + 1,)`` s), joined by straight lines, sampled on the model's grid and
    fitted within the vehicle's limits as the NLP keeps them and the workspace (the
    per-axis fit of the initial guess where that QP fails).

    Returns:
        the flat decision vector, vehicles in ``problem.vehicles`` order (as
        :func:`planner.guess._initial_guess`).
    """
    t_model = np.asarray(model.times_s, dtype=float)
    tq = np.clip(t_model, float(times_s[0]), float(times_s[-1]))
    cols = []
    end = problem.timing.end_at_rest
    for pts, x0, v in zip(positions_enu_m, x0s, problem.vehicles, strict=True):
        p = np.asarray(pts, dtype=float)
        path = np.column_stack([np.interp(tq, times_s, p[:, a]) for a in range(3)])
        z = _fit_xy(model, path, x0, v, problem.workspace, end)
        if z is None:
            z = _fit_within_limits(model, path, x0, v, problem.workspace, end)
        cols.append(z.reshape(-1, order="F"))
    return np.concatenate(cols)
