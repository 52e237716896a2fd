"""Dense checks of planned trajectories against the vehicles' limits and the workspace.

Numpy only (no CasADi): ``gcs verify`` and ``gcs fly`` check a plan with these and the exact
STL semantics without loading the optimiser.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.dynamics.feasibility import FeasibilityReport, InputLimits, check_input_feasibility
from planner.dynamics.limits import vehicle_bounds
from planner.spec.heading import YAW_RATE_MAX_DEG_S, yaw_rate_needed
from planner.trajectory import Trajectory

#: How far past a limit (as a ratio, 1 = at the limit) a plan may go and still hold: the
#: planner's constraints hold to IPOPT's tolerance, and ``gcs plan`` and ``gcs verify``
#: judge with these same figures.
RATIO_TOL = 1e-6
#: How far (m) outside the workspace a plan may go and still hold (one micrometre: the
#: planner's box rows hold to IPOPT's constraint tolerance on the control points, the dense
#: samples may sit a hair outside them).
WORKSPACE_TOL_M = 1e-6


@dataclass(frozen=True, slots=True)
class LimitReport:
    """Limits of one vehicle checked on the dense samples (ratios: 1 = at the limit)."""

    name: str
    max_speed_m_s: float
    max_acc_m_s2: float
    path_length_m: float
    v_ratio: float
    a_ratio: float
    workspace_margin_m: float
    feasibility: FeasibilityReport | None
    #: the largest turn rate its heading schedule asks for / the yaw-rate limit (0: none)
    yaw_ratio: float = 0.0

    @property
    def limits_ok(self) -> bool:
        """Speed, acceleration, the yaw rate and (if checked) thrust/body rates hold (ratios
        within :data:`RATIO_TOL` of 1)."""
        feas = self.feasibility is None or self.feasibility.feasible
        return (
            self.v_ratio <= 1 + RATIO_TOL
            and self.a_ratio <= 1 + RATIO_TOL
            and self.yaw_ratio <= 1 + RATIO_TOL
            and feas
        )

    @property
    def in_workspace(self) -> bool:
        """The path stays in the workspace (margin at least ``-WORKSPACE_TOL_M``)."""
        return self.workspace_margin_m >= -WORKSPACE_TOL_M

    @property
    def ok(self) -> bool:
        """Limits and workspace both hold."""
        return self.limits_ok and self.in_workspace


def check_trajectories(
    problem_like: Any,
    trajectories: Sequence[Trajectory],
    vehicles: Sequence[Any],
    dt_s: float,
    horizon_s: float,
) -> tuple[LimitReport, ...]:
    """Dense checks per vehicle: speed/acc vs limits (per axis, up/down, horizontal norm:
    :func:`planner.dynamics.limits.vehicle_bounds`), workspace, Mueller test.

    ``problem_like`` has a ``workspace`` region; ``vehicles`` have the scenario's limit
    fields (``v_max_m_s``, ``a_max_m_s2``, the optional PX4-like ones, thrust/body rates).
    """
    n = round(horizon_s / dt_s) + 1
    t = np.arange(n) * dt_s
    ws = problem_like.workspace
    out = []
    for v, tr in zip(vehicles, trajectories, strict=True):
        pos = tr.position(t)
        vel = tr.velocity(t)
        acc = tr.acceleration(t)
        vb, ab = vehicle_bounds(v)
        v_ratio, a_ratio = vb.ratio(vel), ab.ratio(acc)
        margin = float(
            np.min(np.concatenate([pos - np.asarray(ws.lo_enu_m), np.asarray(ws.hi_enu_m) - pos]))
        )
        feas = None
        if v.thrust_max_m_s2 is not None and v.body_rate_max_rad_s is not None:
            feas = check_input_feasibility(
                tr,
                InputLimits(v.thrust_min_m_s2 or 0.0, v.thrust_max_m_s2, v.body_rate_max_rad_s),
            )
        out.append(
            LimitReport(
                name=v.name,
                max_speed_m_s=float(np.max(np.linalg.norm(vel, axis=1))),
                max_acc_m_s2=float(np.max(np.linalg.norm(acc, axis=1))),
                path_length_m=float(np.sum(np.linalg.norm(np.diff(pos, axis=0), axis=1))),
                v_ratio=v_ratio,
                a_ratio=a_ratio,
                workspace_margin_m=margin,
                feasibility=feas,
                yaw_ratio=yaw_rate_needed(tr)
                / (getattr(v, "yaw_rate_max_deg_s", None) or YAW_RATE_MAX_DEG_S),
            )
        )
    return tuple(out)
