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

Where the spec asks a vehicle to face an inspection target (``face(d, T)``), the flight's
pictures are checked too (:mod:`gcs.plot.coverage`): every target pictured at least once from
within its inspection place with the view within face's tolerance, one check per target.
The pictures come from the ``.tlog`` (CAMERA_IMAGE_CAPTURED) or from the flight's image log
(``--images images.csv``, which ``gcs fly --log`` writes).

Exit 0 when all hold, 1 when one fails (each failure named, the failing clause included),
2 for an unreadable or malformed plan file, or a spec that does not fit the plan (an unknown
vehicle or region, a horizon shorter than the spec), in one line naming the plan file and field.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from gcs.checks import MAX_TELEMETRY_GAP_S, Check, check_step_s, verify_plan, verify_telemetry
from gcs.plot.coverage import compute_coverage, coverage_checks, coverage_json, coverage_lines
from gcs.telemetry import load_images, load_telemetry
from mavlink.link.camera import images_from_tlog
from planner.planfile import load_plan

__all__ = ["MAX_TELEMETRY_GAP_S", "Check", "add_arguments", "check_step_s", "run",
           "verify_plan", "verify_telemetry"]  # fmt: skip

HELP = "re-check a plan file: spec robustness, limits, separation and workspace"


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
    p.add_argument(
        "--images",
        metavar="CSV",
        help="the flight's image log (images.csv of gcs fly --log): check that every "
        "inspection target was pictured (a .tlog telemetry carries its pictures itself)",
    )
    p.add_argument("--json", action="store_true", help="print the checks as JSON")


def run(args: argparse.Namespace) -> int:
    """Verify; 0 if every check holds, 1 otherwise."""

    plan = load_plan(args.plan)
    checks = verify_plan(plan, args.dt)
    if args.telemetry:
        telemetry = load_telemetry(args.telemetry, plan, args.t0)
        checks += verify_telemetry(plan, telemetry, args.dt)
    report = _coverage(plan, args)
    if report is not None:
        checks += coverage_checks(report)
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
                    "coverage": None if report is None else coverage_json(report),
                    "assurance": None if plan.assurance is None else plan.assurance.to_json(),
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
        if report is not None:
            print("\n".join(coverage_lines(report)))
        if plan.assurance is not None:
            print(plan.assurance.summary())
        if failed:
            print(f"FAILED: {len(failed)} of {len(checks)} checks; first: {failed[0].name}")
        else:
            print(f"OK: {len(checks)} checks hold")
    return 1 if failed else 0


def _coverage(plan: Any, args: argparse.Namespace) -> Any:
    """The flight's coverage report from ``--images`` or a ``.tlog``'s pictures; ``None``
    when neither is given.

    Raises:
        gcs.errors.InputFileError: an unreadable image log (file, line, column), or one with a
            vehicle that is not in the plan.
    """

    tlog = args.telemetry and Path(args.telemetry).suffix.lower() == ".tlog"
    infos: dict[str, Any] = {}
    images: dict[str, Any]
    if args.images:
        images = load_images(args.images, plan)
    elif tlog and args.t0 is not None:
        images, infos = images_from_tlog(
            args.telemetry, {v.sysid: v.name for v in plan.vehicles}, float(args.t0)
        )
    else:
        return None
    return compute_coverage(plan, images, cameras=infos)
