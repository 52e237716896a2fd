"""Planning to a probability: P before and after, margins, robustness given up, time.

For each case, ``gcs.assess.target.plan_to_probability`` (what ``gcs plan
--target-probability`` runs) under the given wind, then an independent assessment of the plan
it keeps, on a campaign seed the loop never used (``--check-runs``, 10,000 by default).
Printed per case: the first plan's P (its tuning runs), the kept plan's P on the loop's fresh
runs and on the independent runs (each with its 95 % interval), the clauses tightened and the
largest margin, the robustness given up (the first plan's as written, less the kept one's), the
rounds and the loop's wall time, and whether the target was met.  Then one JSON line.

    .venv/bin/python benchmarks/bench_target.py                       # flagship + two zoo missions
    .venv/bin/python benchmarks/bench_target.py --cases flagship --check-runs 2000
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gcs.assess import AssessOptions, assess, ray_session
from gcs.assess.target import TargetOptions, plan_to_probability
from planner.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
CASES = {
    "flagship": (ROOT / "configs" / "powerline_inspection.yaml", "uniform(0, 6)"),
    "line4_order": (ROOT / "benchmarks/scenarios/powerline_line4_2drones_order.yaml", "uniform(0, 6)"),
    "u_revisits": (ROOT / "benchmarks/scenarios/patrol_u_revisits_1drone.yaml", "uniform(0, 6)"),
}  # fmt: skip


def run_case(name: str, args: argparse.Namespace) -> dict[str, object]:
    path, wind = CASES[name]
    problem = load_scenario(path)
    dist = {"wind_m_s": wind}
    opts = TargetOptions(
        probability=args.target,
        assess=AssessOptions(
            runs=args.assess_runs, seed=0, disturbances=dist, workers=args.workers
        ),
        final_runs=args.final_runs,
        rounds=args.rounds,
        time_limit_s=120.0,
    )
    t0 = time.perf_counter()
    r = plan_to_probability(
        problem, opts, say=lambda line: print(f"  {name}: {line}", file=sys.stderr, flush=True)
    )
    loop_s = time.perf_counter() - t0
    check = assess(
        r.plan,
        AssessOptions(runs=args.check_runs, seed=987_654, disturbances=dist, workers=args.workers),
    )
    margins = list(r.margins.values())
    return {
        "case": name,
        "wind": wind,
        "target": args.target,
        "met": r.met,
        "p_first": r.rounds[0].p,
        "ci_first": list(r.rounds[0].ci),
        "p_fresh": r.final.p,
        "ci_fresh": list(r.final.ci),
        "p_check": check.p,
        "ci_check": list(check.ci),
        "check_runs": check.runs,
        "tightened": len(margins),
        "max_margin_m": max(margins, default=0.0),
        "robustness_first": r.first,
        "robustness_kept": r.result.robustness,
        "given_up_m": r.first - r.result.robustness,
        "rounds": len(r.rounds),
        "loop_s": loop_s,
        "limiting": r.limiting,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES), help=f"of {', '.join(CASES)}")
    ap.add_argument("--target", type=float, default=0.99)
    ap.add_argument("--assess-runs", type=int, default=2000)
    ap.add_argument("--final-runs", type=int, default=4000)
    ap.add_argument("--check-runs", type=int, default=10_000)
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--workers", type=int, default=None, help="Ray CPUs (default all)")
    args = ap.parse_args(argv)
    head = (
        f"{'case':<12} {'P first':>16} {'P fresh':>16} {'P check':>16} {'tight':>5} "
        f"{'max m':>6} {'rob first':>9} {'rob kept':>8} {'rounds':>6} {'loop s':>7} {'met':>4}"
    )
    print(head)
    print("-" * len(head))
    rows = []
    with ray_session(None, args.workers):  # one Ray for every case and check
        for name in args.cases.split(","):
            row = run_case(name, args)
            rows.append(row)

            def pc(p: object, ci: object) -> str:
                return f"{p:.4f} [{ci[0]:.3f}]"  # type: ignore[index]

            print(
                f"{name:<12} {pc(row['p_first'], row['ci_first']):>16} "
                f"{pc(row['p_fresh'], row['ci_fresh']):>16} {pc(row['p_check'], row['ci_check']):>16} "
                f"{row['tightened']:>5} {row['max_margin_m']:>6.2f} {row['robustness_first']:>+9.3f} "
                f"{row['robustness_kept']:>+8.3f} {row['rounds']:>6} {row['loop_s']:>7.1f} "
                f"{'y' if row['met'] else 'n':>4}",
                flush=True,
            )
            if row["limiting"]:
                print(f"  limited by {row['limiting']}")
    print(json.dumps({"bench": "target", "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
