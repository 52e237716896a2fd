"""``gcs verify PLAN.json``: re-check a plan from its stored segments.

Rebuilds every trajectory from ``segments`` (not the samples), samples it every
``check_dt_s`` (or ``--dt``), and checks:

* the spec: exact robustness of every top-level clause >= the plan's epsilon;
* limits: per-axis |v| <= v_max and |a| <= a_max, and Mueller's thrust/body-rate test
  where the plan gives those limits;
* separation: every pair of vehicles at least ``separation_m`` apart at every sample;
* workspace: every sample inside the workspace box;
* starts: each trajectory starts at the vehicle's recorded start.

Exit 0 when all hold, 1 when one fails (each failure named, the failing clause included),
2 for an unreadable or malformed plan file (one line).
"""

from __future__ import annotations

import argparse
import itertools
import json
from dataclasses import dataclass
from typing import Any

import numpy as np

HELP = "re-check a plan file: spec robustness, limits, separation and workspace"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``gcs verify``."""
    p.add_argument("plan", help="plan file written by gcs plan")
    p.add_argument("--dt", type=float, help="check sample step in s (default: the plan's)")
    p.add_argument("--json", action="store_true", help="print the checks as JSON")


@dataclass(frozen=True, slots=True)
class Check:
    """One verified property: its name, the measured value, the bound and the verdict."""

    name: str
    value: float
    bound: float
    ok: bool
    detail: str = ""


def verify_plan(plan: Any, dt_s: float | None = None) -> list[Check]:
    """All checks of a loaded plan (see module docstring)."""
    from planner.optimize import check_trajectories
    from planner.planfile import PlanFileError
    from planner.predicates import build_registry
    from planner.stl.errors import SpecError
    from planner.stl.parser import parse

    dt = plan.check_dt_s if dt_s is None else dt_s
    if not dt > 0:
        raise PlanFileError("--dt", "", f"must be > 0, got {dt}")
    n = round(plan.horizon_s / dt) + 1
    t = np.arange(n) * dt
    trajs = [v.trajectory for v in plan.vehicles]
    pos = {v.name: v.trajectory.position(t) for v in plan.vehicles}
    checks: list[Check] = []

    try:
        phi = parse(plan.spec, build_registry(plan))
    except SpecError as exc:
        raise PlanFileError(plan.scenario, "spec", str(exc)) from None
    for clause in phi.clauses:
        rho = clause.robustness(pos, dt)
        detail = ""
        if rho < plan.epsilon:
            w = clause.weakest(pos, dt)[-1]
            detail = f"weakest {w.formula} = {w.robustness:.4g} at t = {w.t_s:g} s"
        checks.append(Check(f"spec: {clause}", rho, plan.epsilon, rho >= plan.epsilon, detail))

    for lim in check_trajectories(plan, trajs, plan.vehicles, dt, plan.horizon_s):
        checks.append(
            Check(f"{lim.name} velocity / v_max", lim.v_ratio, 1.0, lim.v_ratio <= 1 + 1e-6)
        )
        checks.append(
            Check(f"{lim.name} acceleration / a_max", lim.a_ratio, 1.0, lim.a_ratio <= 1 + 1e-6)
        )
        checks.append(
            Check(
                f"{lim.name} workspace margin m",
                lim.workspace_margin_m,
                0.0,
                lim.workspace_margin_m >= -1e-9,
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
    return checks


def run(args: argparse.Namespace) -> int:
    """Verify; 0 if every check holds, 1 otherwise."""
    from planner.planfile import load_plan

    plan = load_plan(args.plan)
    checks = verify_plan(plan, args.dt)
    failed = [c for c in checks if not c.ok]
    if args.json:
        print(
            json.dumps(
                {
                    "ok": not failed,
                    "checks": [
                        {
                            "name": c.name,
                            "value": c.value,
                            "bound": c.bound,
                            "ok": c.ok,
                            "detail": c.detail,
                        }
                        for c in checks
                    ],
                }
            )
        )
    else:
        shown = failed or checks
        if not failed and len(checks) > 30:
            print(f"{len(checks)} checks, all hold; the closest ones:")
            shown = sorted(checks, key=lambda c: c.value - c.bound if "ratio" not in c.name else 0)[
                :10
            ]
        for c in shown:
            mark = "ok  " if c.ok else "FAIL"
            print(f"{mark} {c.name}: {c.value:.4g} (bound {c.bound:.4g}) {c.detail}".rstrip())
        if failed:
            print(f"FAILED: {len(failed)} of {len(checks)} checks; first: {failed[0].name}")
        else:
            print(f"OK: {len(checks)} checks hold")
    return 1 if failed else 0
