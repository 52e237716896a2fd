"""The checks of a plan and of flown telemetry (``gcs verify``; ``gcs fly``'s interlock).

Exact semantics and dense sampling only: numpy, no CasADi, no optimiser
(:mod:`planner.checks`, :mod:`planner.stl`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Longest hole in a vehicle's flown telemetry that verification interpolates across (s).
MAX_TELEMETRY_GAP_S = 1.0


@dataclass(frozen=True, slots=True)
class Check:
    """One verified property: its name, the measured value, the bound and the verdict."""

    name: str
    value: float
    bound: float
    ok: bool
    detail: str = ""


def check_step_s(plan: Any, dt_s: float | None) -> float:
    """The check step: ``dt_s`` (``--dt``) if given, else the plan's ``check_dt_s``.

    Raises:
        UserError: ``--dt`` not a positive number, or so small that the plan's horizon would
            take more than :data:`planner.planfile.MAX_CHECK_SAMPLES` samples.
    """
    from gcs.errors import UserError
    from planner.planfile import MAX_CHECK_SAMPLES

    if dt_s is None:
        return float(plan.check_dt_s)  # load_plan checked it
    if not (math.isfinite(dt_s) and dt_s > 0):
        raise UserError(f"--dt: must be a positive number of seconds, got {dt_s:g}")
    if plan.horizon_s / dt_s > MAX_CHECK_SAMPLES:
        raise UserError(
            f"--dt: {dt_s:g} s gives more than {MAX_CHECK_SAMPLES:g} check samples over the "
            f"plan's {plan.horizon_s:g} s horizon"
        )
    return float(dt_s)


def verify_plan(plan: Any, dt_s: float | None = None) -> list[Check]:
    """All checks of a loaded plan (see module docstring).

    Raises:
        PlanFileError: the plan's spec does not fit the plan or cannot be evaluated on it
            (:func:`planner.planfile.plan_formula`, :func:`planner.planfile.spec_errors`).
        UserError: a bad ``dt_s`` (:func:`check_step_s`).
    """
    from planner.checks import RATIO_TOL, check_trajectories
    from planner.planfile import plan_formula, spec_errors

    dt = check_step_s(plan, dt_s)
    n = round(plan.horizon_s / dt) + 1
    t = np.arange(n) * dt
    trajs = [v.trajectory for v in plan.vehicles]
    from planner.planfile import planned_signals

    pos = planned_signals(plan, t)
    checks: list[Check] = []

    phi = plan_formula(plan)
    clause_checks = []
    for clause in phi.clauses:
        with spec_errors(plan):
            rho = clause.robustness(pos, dt)
            detail = ""
            if rho < plan.epsilon:
                detail = weakest_detail(clause.weakest(pos, dt))
        clause_checks.append(
            Check(f"spec: {clause}", rho, plan.epsilon, rho >= plan.epsilon, detail)
        )
    # worst first: the clause to fix first leads (file order among equals)
    checks.extend(sorted(clause_checks, key=lambda c: c.value))

    for lim in check_trajectories(plan, trajs, plan.vehicles, dt, plan.horizon_s):
        # the tolerances are gcs plan's own (planner.checks), so the two never disagree
        checks.append(
            Check(f"{lim.name} velocity / v_max", lim.v_ratio, 1.0, lim.v_ratio <= 1 + RATIO_TOL)
        )
        checks.append(
            Check(
                f"{lim.name} acceleration / a_max",
                lim.a_ratio,
                1.0,
                lim.a_ratio <= 1 + RATIO_TOL,
            )
        )
        checks.append(
            Check(
                f"{lim.name} workspace margin m",
                lim.workspace_margin_m,
                0.0,
                lim.in_workspace,
                "" if lim.in_workspace else f"outside by {-lim.workspace_margin_m:.3g} m",
            )
        )
        if lim.feasibility is not None:
            f = lim.feasibility
            checks.append(
                Check(
                    f"{lim.name} thrust/body rate (Mueller)",
                    float(f.first_violation_t_s if f.first_violation_t_s is not None else 0.0),
                    0.0,
                    f.feasible,
                    "" if f.feasible else f"{f.violation} at t = {f.first_violation_t_s:g} s",
                )
            )
    for a, b in itertools.combinations(plan.vehicles, 2):
        d = np.linalg.norm(pos[a.name] - pos[b.name], axis=1)
        i = int(np.argmin(d))
        checks.append(
            Check(
                f"separation {a.name}-{b.name} m",
                float(d[i]),
                plan.separation_m,
                bool(d[i] >= plan.separation_m),
                f"closest at t = {t[i]:g} s",
            )
        )
    for v in plan.vehicles:
        err = float(np.linalg.norm(v.trajectory.position(np.array([0.0]))[0] - v.start_enu_m))
        checks.append(Check(f"{v.name} start offset m", err, 1e-6, err <= 1e-6))
    for v in plan.vehicles:
        # a plan must leave every vehicle at rest, to hold there (timing.end: free does not)
        speed = float(np.linalg.norm(v.trajectory.velocity(np.array([plan.horizon_s]))[0]))
        checks.append(
            Check(
                f"{v.name} speed at the end m/s",
                speed,
                _END_SPEED_M_S,
                speed <= _END_SPEED_M_S,
                ""
                if speed <= _END_SPEED_M_S
                else "it would coast on after the plan (planned with timing.end: free?)",
            )
        )
    return checks


#: The speed (m/s) a plan may end with and still count as at rest (the planner's end rows
#: hold to IPOPT's constraint tolerance, 1e-8).
_END_SPEED_M_S = 1e-3


def weakest_detail(chain: Sequence[Any]) -> str:
    """What decides a failing clause, from its weakest chain (``Formula.weakest``), in the
    clause's own sign (:func:`planner.stl.explanation`: a failing ``not (...)`` is explained
    by itself, not by the passing value under it): the leaf, or, where the chain passes an
    ``or``, the disjunction's value and its best option (a leaf under an ``or`` is one
    choice, not a requirement)."""
    from planner.stl import Or, explanation

    chain = explanation(tuple(chain))  # in the clause's own sign: a `not` as itself
    for i, w in enumerate(chain):
        if isinstance(w.formula, Or) and i + 1 < len(chain):
            best = chain[i + 1]
            return (
                f"either of {w.formula} = {w.robustness:.4g} at t = {w.t_s:g} s; its best "
                f"option {best.formula} = {best.robustness:.4g}"
            )
    w = chain[-1]
    return f"weakest {w.formula} = {w.robustness:.4g} at t = {w.t_s:g} s"


def verify_telemetry(plan: Any, telemetry: Any, dt_s: float | None = None) -> list[Check]:
    """Checks of flown data (module docstring): coverage and gaps per vehicle, then each
    top-level clause on the flown positions (bound 0: the flown data satisfies it).

    A spec that reads the heading (``face``) also needs each vehicle's flown heading: a
    vehicle whose telemetry has none fails ``flown NAME heading`` (saying so), and the
    clauses that read its heading are not judged; one with a heading has its gaps checked
    like the positions'.

    Args:
        plan: a loaded plan.
        telemetry: a :class:`gcs.telemetry.Telemetry` (flown ENU paths by vehicle name).
        dt_s: check step (default: the plan's ``check_dt_s``).
    """
    from gcs.flight.evaluation import heading_readers
    from mavlink.tracks import NO_HEADING
    from planner.planfile import plan_formula

    dt = check_step_s(plan, dt_s)
    t = np.arange(round(plan.horizon_s / dt) + 1) * dt
    phi = plan_formula(plan)
    readers = heading_readers(phi)
    checks: list[Check] = []
    flown: dict[str, np.ndarray] = {}
    no_heading: set[str] = set()
    for v in plan.vehicles:
        path = telemetry.vehicles.get(v.name)
        if path is None or len(path.t_s) == 0:
            checks.append(Check(f"flown {v.name} telemetry", 0.0, 1.0, False, "no samples"))
            continue
        ts = np.asarray(path.t_s, dtype=float)
        gap = _largest_gap(ts, plan.horizon_s)
        ok = gap <= MAX_TELEMETRY_GAP_S
        detail = f"samples {ts[0]:.2f}..{ts[-1]:.2f} s of 0..{plan.horizon_s:g} s"
        checks.append(Check(f"flown {v.name} largest gap s", gap, MAX_TELEMETRY_GAP_S, ok, detail))
        if not ok:
            continue
        flown[v.name] = path.position(t)
        if v.name not in readers:
            continue
        th = path.heading_t_s
        if th.size == 0:
            no_heading.add(v.name)
            why = f"{NO_HEADING}; the spec's face() reads it"
            checks.append(Check(f"flown {v.name} heading", 0.0, 1.0, False, why))
            continue
        gap = _largest_gap(th, plan.horizon_s)
        ok = gap <= MAX_TELEMETRY_GAP_S
        detail = f"headings {th[0]:.2f}..{th[-1]:.2f} s of 0..{plan.horizon_s:g} s"
        name = f"flown {v.name} heading largest gap s"
        checks.append(Check(name, gap, MAX_TELEMETRY_GAP_S, ok, detail))
        if ok:
            flown[v.name] = path.signal(t, heading=True)
        else:
            no_heading.add(v.name)
    if len(flown) == len(plan.vehicles):
        clause_checks = []
        for clause in phi.clauses:
            if no_heading & heading_readers(clause):
                continue  # its vehicle's heading check failed and says why
            rho = float(clause.robustness(flown, dt))
            detail = "" if rho >= 0.0 else weakest_detail(clause.weakest(flown, dt))
            clause_checks.append(Check(f"flown spec: {clause}", rho, 0.0, rho >= 0.0, detail))
        checks.extend(sorted(clause_checks, key=lambda c: c.value))  # worst first
    return checks


def _largest_gap(t_s: np.ndarray, horizon_s: float) -> float:
    """The longest stretch of ``[0, horizon_s]`` without a sample (s), ``t_s`` sorted."""
    return float(max(t_s[0] - 0.0, horizon_s - t_s[-1], np.diff(t_s).max(initial=0.0)))
