"""The combinatorial stage's plan as a start of the NLP: its waypoints fitted within the
vehicles' limits as the NLP states them (:func:`waypoint_guess`).

The initial guess (:func:`planner.solve.guess._fitted`) fits each axis on its own, within a
per-axis box inside the horizontal speed and acceleration polygon (:meth:`Bounds.box`): 3.5
m/s along x for a 5 m/s vehicle.  The coarse plan moves at up to the limits in any
direction, so that box made its fit fall behind it: on the allocation mission one drone
trailed its coarse plan by 23 m after 36 s of flight along the line, and the start was at
-15.5 m where the coarse plan had +0.3.  Here the horizontal axes are fitted together,
within the per-axis bounds and the :data:`planner.dynamics.limits.NORM_DIRECTIONS` rows, the
polygon the NLP itself keeps (:func:`planner.solve.nlp.vehicle_limit_bounds`); the vertical axis
alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from planner.dynamics.limits import NORM_DIRECTIONS, vehicle_bounds
from planner.problem import Problem, Vehicle
from planner.solve.path_fit import axis_fit, fit_within_limits, guess_qp
from planner.spec.regions import Region

__all__ = ["waypoint_guess"]


def _fit_xy(
    model: Any, path: np.ndarray, x0: np.ndarray, vehicle: Vehicle, ws: Region, end_at_rest: bool
) -> np.ndarray | None:
    """``Z`` (n_dec, 3) closest (least squares at the samples) to ``path`` (n, 3) among the
    trajectories within the NLP's limit rows (horizontal polygon included), at rest at the
    end when asked, in the workspace's box at the samples; None when the QP fails.  The
    initial guess's per-axis pieces (:func:`planner.solve.path_fit.axis_fit`) on the NLP's axis
    bounds, the three axes side by side, and the polygon's rows coupling x and y."""
    vel, acc = vehicle_bounds(vehicle)
    (vlo, vhi, vb), (alo, ahi, ab) = vel.linear(), acc.linear()
    fit = axis_fit(model, path, x0, (vlo, vhi, alo, ahi), ws, end_at_rest)
    n = model.n_dec
    blocks = [np.kron(np.eye(3), fit.A)]
    lba, uba = list(fit.lba), list(fit.uba)
    if np.isfinite(vb) or np.isfinite(ab):
        G, Hh = fit.cons.G[: fit.half], fit.cons.H[: fit.half]
        b = np.where(fit.cons.kind[: fit.half] == "vel", vb, ab)
        for c, s in NORM_DIRECTIONS:
            row = np.zeros((fit.half, 3 * n))
            row[:, :n], row[:, n : 2 * n] = c * G, s * G
            blocks.append(row)
            off = c * (Hh @ x0[:, 0]) + s * (Hh @ x0[:, 1])
            lba.append(-b - off)
            uba.append(b - off)
    A = np.vstack(blocks)
    qp = guess_qp(3 * n, A)
    sol = qp(
        h=np.kron(np.eye(3), fit.H),
        g=np.concatenate(fit.g),
        a=A,
        lba=np.concatenate(lba),
        uba=np.concatenate(uba),
    )
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
        :func:`planner.solve.guess.initial_guess`).
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
            z = fit_within_limits(model, path, x0, v, problem.workspace, end)
        cols.append(z.reshape(-1, order="F"))
    return np.concatenate(cols)
