"""A power line in any direction: the 10-pole line along a bearing of 37 degrees against the same
line laid along x, both from a ``line:`` section, three drones (issue 21's figure).

Each run plans one scenario in a fresh ``gcs plan --json`` process (cold), the two scenarios in
turn (A B A B ...) so a drift of the machine's speed falls on both; per scenario the median and
range of the wall time, the exact robustness, the iterations and the build time, and the ratio
turned / along x of the medians.  Printed: a table, then one JSON line.

    .venv/bin/python benchmarks/bench_line.py --runs 3
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_zoo import GCS, SCENARIOS, planner_version, run_one

PAIR = ("powerline_line10_bearing37_3drones", "powerline_line10_east_3drones")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="runs of each scenario (default 3)")
    ap.add_argument("--time-limit", type=float, default=120.0, help="gcs plan --time-limit")
    args = ap.parse_args(argv)
    rows: dict[str, list[dict[str, Any]]] = {name: [] for name in PAIR}
    for _ in range(args.runs):
        for name in PAIR:
            rows[name].append(run_one(SCENARIOS / f"{name}.yaml", args.time_limit, GCS))
    out: dict[str, Any] = {"bench": "line", "planner": planner_version(), "runs": args.runs}
    print(f"{'scenario':<38} {'met':>5} {'robustness':>10} {'wall s (median, min-max)':>26} "
          f"{'iterations':>10} {'build s':>8}")  # fmt: skip
    for name, rs in rows.items():
        walls = [r["wall_s"] for r in rs]
        met = sum(bool(r["solved"]) for r in rs)
        rho = [r.get("robustness") for r in rs]
        its = [r.get("iterations") for r in rs]
        builds = [r.get("build_s") for r in rs if r.get("build_s") is not None]
        med = statistics.median(walls)
        span = f"{med:.1f} ({min(walls):.1f}-{max(walls):.1f})"
        rho_txt = "/".join(
            f"{x:+.3f}" if isinstance(x, int | float) else "?" for x in dict.fromkeys(rho)
        )
        print(f"{name:<38} {met:>2}/{len(rs):<2} {rho_txt:>10} {span:>26} "
              f"{'/'.join(str(i) for i in dict.fromkeys(its)):>10} "
              f"{statistics.median(builds) if builds else float('nan'):>8.2f}")  # fmt: skip
        out[name] = {"met": met, "runs": len(rs), "robustness": rho, "wall_s": walls,
                     "wall_median_s": med, "iterations": its, "build_s": builds}  # fmt: skip
    ratio = out[PAIR[0]]["wall_median_s"] / out[PAIR[1]]["wall_median_s"]
    out["turned_over_along_x"] = ratio
    print(f"planning time, turned / along x (medians): {ratio:.2f}")
    print(json.dumps(out))
    return 0 if all(out[n]["met"] == out[n]["runs"] for n in PAIR) else 1


if __name__ == "__main__":
    raise SystemExit(main())
