"""Replanning in flight (issue 43): the power line with one drone lost, replanned and flown on.

The shipped power-line plan (4 drones, ``configs/powerline_inspection.yaml``, planned here)
flown on the px4 mock (``gcs fly --dry-run --replan --json``, real time unless ``--speed``)
with one drone lost at 5, 10 and 15 s of the plan (``--mock-fault VEHICLE:lost@T``; d2 of
the west pair and d3 of the east pair by default).  Per case: when the loss was seen, the
switch time, the replan's wall time, whether the new plan met what was left of the spec (and
why not), what became of the lost drone's clauses (dropped / taken over / met before), the new
plan's robustness, the exit status and the flown robustness of the spec as amended.  Without
``--replan`` every one of these flights ends with the hold when the link is lost
(``benchmarks/bench_loss.py``).

Then ``gcs assess --monitor --replan -d lost=P`` of the same plan (each drone lost with
probability P at a time uniform over the plan), P = 0.02, 0.05, 0.1, ``--runs`` runs each:
the runs stopped on a lost link, replanned, flown on a new plan, and P(the flight completes and
the spec it is judged on holds) with and without replanning (``gcs fly``'s exit status 0).

Printed: two tables, then one JSON line.

    .venv/bin/python benchmarks/bench_replan.py --runs 1000
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

from cli_runs import run_cli

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", default="d2,d3", help="the drones to lose, one per flight")
    ap.add_argument("--times", default="5,10,15", help="loss times (s of the plan)")
    ap.add_argument("--budget", type=float, default=3.0, help="--replan-budget (s)")
    ap.add_argument("--speed", type=float, default=1.0, help="the mock's speed (1: real time)")
    ap.add_argument("--plan", default=None, help="a power-line plan file (default: plan it)")
    ap.add_argument("--runs", type=int, default=1000, help="runs per assessment (0: none)")
    ap.add_argument("--reassign", action="store_true", help="fly and assess with --reassign")
    ap.add_argument("--probabilities", default="0.02,0.05,0.1")
    args = ap.parse_args(argv)
    result: dict[str, Any] = {"bench": "replan", "budget_s": args.budget, "speed": args.speed}
    cases = []
    extra = ["--reassign"] if args.reassign else []
    result["reassign"] = args.reassign
    with tempfile.TemporaryDirectory() as tmp:
        plan = args.plan
        if plan is None:
            plan = str(Path(tmp) / "powerline.json")
            rc, _, plan_s = run_cli(
                ["plan", str(ROOT / "configs/powerline_inspection.yaml"), "-o", plan]
            )
            assert rc == 0, "the power line did not plan"
            print(f"power line planned in {plan_s:.1f} s")
        head = (
            f"{'lost':<10} {'seen s':>6} {'switch':>6} {'solve s':>7} {'new rho':>8} "
            f"{'drop/take/met':>13} {'to':>3} {'exit':>4} {'flown rho':>9}  why not"
        )
        print(head)
        for name in [n for n in args.vehicles.split(",") if n]:
            for t in args.times.split(","):
                rc, out, wall = run_cli(
                    ["fly", plan, "--dry-run", "--json", "--replan", "--scenario",
                     str(ROOT / "configs/powerline_inspection.yaml"),
                     "--replan-budget", f"{args.budget:g}", "--speed", f"{args.speed:g}",
                     "--mock-fault", f"{name}:lost@{t}", *extra]
                )  # fmt: skip
                reps = out.get("replans", [])
                r = reps[0] if reps else {}
                case = {
                    "vehicle": name,
                    "lost_at_s": float(t),
                    "exit": rc,
                    "wall_s": round(wall, 2),
                    "seen_s": r.get("t_s"),
                    "switch_s": r.get("switch_s"),
                    "solve_s": r.get("solve_s"),
                    "replanned": bool(r.get("success")),
                    "new_robustness": r.get("robustness"),
                    "dropped": len(r.get("dropped", [])),
                    "taken_over": len(r.get("taken_over", [])),
                    "met_before": len(r.get("discharged", [])),
                    "reassigned_to": r.get("reassigned_to"),
                    "reason": r.get("reason", "") if r else "no replan",
                    "flown_robustness": out.get("flown_robustness"),
                    "completed": out.get("completed"),
                    "safety_event": out.get("safety_event"),
                }
                cases.append(case)

                def f(x: Any, fmt: str) -> str:
                    return "-" if x is None else format(x, fmt)

                print(
                    f"{name + '@' + t:<10} {f(case['seen_s'], '6.2f')} {f(case['switch_s'], '6g')} "
                    f"{f(case['solve_s'], '7.2f')} {f(case['new_robustness'], '+8.3f')} "
                    f"{case['dropped']:>4}/{case['taken_over']}/{case['met_before']:<6} "
                    f"{case['reassigned_to'] or '-':>3} {rc:>4} {f(case['flown_robustness'], '+9.3f')}  "
                    + (case["reason"][:90] if not case["replanned"] else ""),
                    flush=True,
                )
        result["assess"] = assessments = []
        if args.runs > 0:
            print(
                f"\n{'P(lost)':>7} {'stops':>5} {'replanned':>9} {'flown':>5} {'done':>4} "
                f"{'solve s':>8} {'P(completes) without':>24} {'with replanning':>24} {'wall s':>7}"
            )
        for p in args.probabilities.split(",") if args.runs > 0 else ():
            rc, out, wall = run_cli(
                ["assess", plan, "--monitor", "--replan", "-d", f"lost={p}",
                 "--runs", str(args.runs), "--json", "--scenario",
                 str(ROOT / "configs/powerline_inspection.yaml"), *extra]
            )  # fmt: skip
            r = out["replan"]
            assessments.append({"p_lost": float(p), "wall_s": round(wall, 1), **r})
            ci0, ci1 = r["ci95_without"], r["ci95_with"]
            without = f"{r['p_completed_without']:.3f} [{ci0[0]:.3f}, {ci0[1]:.3f}]"
            with_ = f"{r['p_completed_with']:.3f} [{ci1[0]:.3f}, {ci1[1]:.3f}]"
            solve = r["solve_s_median"] or 0.0
            print(
                f"{float(p):7.2f} {r['lost_links']:5d} {r['replanned']:9d} {r['flown']:5d} "
                f"{r['completed_flown']:4d} {solve:8.2f} {without:>24} {with_:>24} {wall:7.1f}",
                flush=True,
            )
    result["cases"] = cases
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
