"""``gcs verify PLAN.json``: re-check a plan from its stored segments.

Rebuilds every trajectory from ``segments`` (not the samples), samples it every
``check_dt_s`` (or ``--dt``), and checks:

* the spec: exact robustness of every top-level clause >= the plan's epsilon;
* limits: per-axis |v| <= v_max and |a| <= a_max, and Mueller's thrust/body-rate test
  where the plan gives those limits;
* separation: every pair of vehicles at least ``separation_m`` apart at every sample;
* workspace: every sample inside the workspace box;
* starts: each trajectory starts at the vehicle's recorded start.

With ``--telemetry LOG`` (a CSV of flown positions, or a ``.tlog`` with ``--t0``, as
``gcs plot`` reads them) it also checks the flown data: the log must cover the plan's horizon
for every vehicle without gaps longer than ``MAX_TELEMETRY_GAP_S`` (interpolating across a
hole could hide a violation), and every top-level clause must hold on the flown positions
(exact robustness >= 0 on the check grid).

Exit 0 when all hold, 1 when one fails (each failure named, the failing clause included),
2 for an unreadable or malformed plan file, or a spec that does not fit the plan (an unknown
vehicle or region, a horizon shorter than the spec), in one line naming the plan file and field.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

HELP = "re-check a plan file: spec robustness, limits, separation and workspace"

#: Longest hole in a vehicle's flown telemetry that verification interpolates across (s).
MAX_TELEMETRY_GAP_S = 1.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``gcs verify``."""
    p.add_argument("plan", help="plan file written by gcs plan")
    p.add_argument("--dt", type=float, help="check sample step in s (default: the plan's)")
    p.add_argument(
        "--telemetry",
        metavar="LOG",
        help="also check flown telemetry against the spec: CSV (t,vehicle,x,y,z or the link's "
        "track CSV) or .tlog (with --t0)",
    )
    p.add_argument("--t0", type=float, metavar="UNIX_S", help="for a .tlog: Unix time of t = 0")
    p.add_argument("--json", action="store_true", help="print the checks as JSON")


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
    from planner.optimize import check_trajectories
    from planner.planfile import plan_formula, spec_errors

    dt = check_step_s(plan, dt_s)
    n = round(plan.horizon_s / dt) + 1
    t = np.arange(n) * dt
    trajs = [v.trajectory for v in plan.vehicles]
    pos = {v.name: v.trajectory.position(t) for v in plan.vehicles}
    checks: list[Check] = []

    phi = plan_formula(plan)
    for clause in phi.clauses:
        with spec_errors(plan):
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


def verify_telemetry(plan: Any, telemetry: Any, dt_s: float | None = None) -> list[Check]:
    """Checks of flown data (module docstring): coverage and gaps per vehicle, then each
    top-level clause on the flown positions (bound 0: the flown data satisfies it).

    Args:
        plan: a loaded plan.
        telemetry: a :class:`gcs.plot.Telemetry` (flown ENU paths by vehicle name).
        dt_s: check step (default: the plan's ``check_dt_s``).
    """
    from planner.planfile import plan_formula

    dt = check_step_s(plan, dt_s)
    t = np.arange(round(plan.horizon_s / dt) + 1) * dt
    checks: list[Check] = []
    flown: dict[str, np.ndarray] = {}
    for v in plan.vehicles:
        path = telemetry.vehicles.get(v.name)
        if path is None or len(path.t_s) == 0:
            checks.append(Check(f"flown {v.name} telemetry", 0.0, 1.0, False, "no samples"))
            continue
        ts = np.asarray(path.t_s, dtype=float)
        gap = float(max(ts[0] - 0.0, plan.horizon_s - ts[-1], np.diff(ts).max(initial=0.0)))
        ok = gap <= MAX_TELEMETRY_GAP_S
        detail = f"samples {ts[0]:.2f}..{ts[-1]:.2f} s of 0..{plan.horizon_s:g} s"
        checks.append(Check(f"flown {v.name} largest gap s", gap, MAX_TELEMETRY_GAP_S, ok, detail))
        if ok:
            flown[v.name] = path.position(t)
    if len(flown) == len(plan.vehicles):
        for clause in plan_formula(plan).clauses:
            rho = float(clause.robustness(flown, dt))
            checks.append(Check(f"flown spec: {clause}", rho, 0.0, rho >= 0.0))
    return checks


def run(args: argparse.Namespace) -> int:
    """Verify; 0 if every check holds, 1 otherwise."""
    from gcs.plot import load_telemetry
    from planner.planfile import load_plan

    plan = load_plan(args.plan)
    checks = verify_plan(plan, args.dt)
    if args.telemetry:
        telemetry = load_telemetry(args.telemetry, plan, args.t0)
        checks += verify_telemetry(plan, telemetry, args.dt)
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
