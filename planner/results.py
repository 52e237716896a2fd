"""What :func:`planner.optimize.plan` returns: the result, its clause reports and solve
statistics."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.checks import LimitReport
from planner.dynamics.limits import PX4_LIMIT_KEYS
from planner.planfile import Plan, PlannedVehicle
from planner.problem import Problem
from planner.trajectory import Trajectory

# ------------------------------------------------------------------------------ results


@dataclass(frozen=True, slots=True)
class Weakest:
    """The sub-formula that decides the robustness, with its value and time (s)."""

    formula: str
    robustness: float
    t_s: float
    clause_key: str


@dataclass(frozen=True, slots=True)
class StartBound:
    """The headline robustness is a margin at t = 0, where the vehicles start: no plan
    changes it (a drone 1 m up with the workspace floor at 0.5 m: 0.5).  ``others`` is the
    least robustness of the clauses whose weakest point the plan does set (None: every
    clause's weakest point is at the start)."""

    others: float | None


@dataclass(frozen=True, slots=True)
class ClauseReport:
    """Exact robustness of one top-level clause of the expanded spec (dense samples)."""

    key_path: str
    text: str
    robustness: float


@dataclass(frozen=True, slots=True)
class SolveStats:
    """Where the time went (seconds) and the problem size."""

    build_s: float
    solver_s: float
    function_eval_s: float
    check_s: float
    n_variables: int
    n_constraints: int
    n_smooth_leaves: int
    k: float
    solver: str
    cached: bool
    #: starts of the multi-start solved (1: the first guess met the mission, or was the only)
    starts: int = 1
    #: the combinatorial stage's figures (:meth:`planner.solve.coarse_start.CoarseOutcome.summary`;
    #: None when it did not run)
    coarse: Mapping[str, Any] | None = None
    #: the row-wise constraints kept (:mod:`planner.solve.screen`): ``{"kept", "total",
    #: "rounds"}`` (step rows kept at the end, in all, and the solves again with rows
    #: added); None when the NLP was not screened
    screen: Mapping[str, int] | None = None


@dataclass(frozen=True, slots=True)
class PlanResult:
    """Outcome of :func:`plan` (python-control style: a failed solve is a result).

    Attributes:
        success: exact robustness >= epsilon and every limit/workspace check passed.
        status: solver status and the verdict, in words.
        robustness: exact robustness (m) of the whole spec on the dense samples.
        robustness_planning_grid: exact robustness on the planning samples (every Ts).
        smooth_robustness: the optimiser's value r (min over the smooth leaves, m).
        weakest: the deciding sub-formula.
        clauses: per top-level clause robustness.
        solve_time_s: wall time of build + solve + check.
        iterations: NLP iterations (summed over a continuation).
        trajectories: one per vehicle, in the problem's order.
        limits: per vehicle dense checks.
        decision: flat optimal decision vector (warm start for a re-solve).
        stats: sizes and time breakdown.
        needs: when the mission is not met, what the plan would need, one line each
            (:func:`planner.solve.explain.needs`).
        start_bound: when the start state sets the headline robustness, the figure the
            plan sets for the other clauses (None otherwise).
    """

    problem: Problem
    success: bool
    status: str
    robustness: float
    robustness_planning_grid: float
    smooth_robustness: float
    weakest: Weakest | None
    clauses: tuple[ClauseReport, ...]
    solve_time_s: float
    iterations: int
    trajectories: tuple[Trajectory, ...]
    limits: tuple[LimitReport, ...]
    decision: np.ndarray = field(repr=False)
    stats: SolveStats | None = None
    needs: tuple[str, ...] = ()
    start_bound: StartBound | None = None

    def to_plan(self, scenario_path: str | None = None) -> Plan:
        """The plan-file view of this result (:mod:`planner.planfile`)."""
        p = self.problem
        vehicles = tuple(
            PlannedVehicle(
                name=v.name,
                sysid=v.sysid,
                trajectory=tr,
                start_enu_m=v.start_enu_m,
                v_max_m_s=v.v_max_m_s,
                a_max_m_s2=v.a_max_m_s2,
                thrust_min_m_s2=v.thrust_min_m_s2,
                thrust_max_m_s2=v.thrust_max_m_s2,
                body_rate_max_rad_s=v.body_rate_max_rad_s,
                **{key: getattr(v, key) for key in PX4_LIMIT_KEYS},
            )
            for v, tr in zip(p.vehicles, self.trajectories, strict=True)
        )
        return Plan(
            scenario=scenario_path if scenario_path is not None else p.source,
            origin=p.origin,
            spec=p.spec_text,
            robustness=self.robustness,
            smooth_robustness=self.smooth_robustness,
            status=self.status,
            success=self.success,
            solve_time_s=self.solve_time_s,
            vehicles=vehicles,
            workspace=p.workspace,
            regions=p.regions,
            separation_m=p.separation_m,
            epsilon=p.epsilon,
            horizon_s=p.timing.horizon_s,
            sample_dt_s=p.timing.sample_dt_s,
            check_dt_s=p.timing.check_dt_s,
            face_tolerance_deg=p.face_tolerance_deg,
            terrain=p.terrain,
        )
