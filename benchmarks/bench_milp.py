"""Figures for the combinatorial stage (issue 40): the coarse MILP on every zoo scenario.

For each scenario of ``benchmarks/scenarios/*.yaml`` and ``configs/*.yaml``: the coarse step,
build and solve seconds, status, the MILP's robustness of its incumbent (a lower bound of
the exact robustness of the coarse waypoints, printed beside it), HiGHS's best bound, and the
program's size. Prints a table, then one JSON line.
Run: ``.venv/bin/python benchmarks/bench_milp.py [--time-limit 20] [scenario.yaml ...]``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from planner.milp import solve_coarse
from planner.milp.solve import problem_formulas
from planner.scenario import load_scenario
from planner.stl import EvaluationError, conjunction

ROOT = Path(__file__).resolve().parents[1]


def _num(x: float) -> float | None:
    return x if math.isfinite(x) else None


def run_one(path: Path, time_limit_s: float) -> dict[str, Any]:
    problem = load_scenario(path)
    res = solve_coarse(problem, time_limit_s=time_limit_s)
    exact: float | None = None
    if res.success:
        try:
            phi = conjunction(list(problem_formulas(problem)))
            exact = phi.robustness(dict(res.waypoints_enu_m), res.dt_s)
        except EvaluationError:  # face needs a heading the coarse path has not
            exact = None
    return {
        "scenario": path.stem,
        "dt_s": res.dt_s,
        "build_s": round(res.build_s, 3),
        "solve_s": round(res.solve_s, 3),
        "status": res.status.name,
        "robustness": _num(res.robustness),
        "bound": _num(res.bound),
        "exact_coarse": _num(exact) if exact is not None else None,
        "vars": res.num_vars,
        "binaries": res.num_binaries,
        "rows": res.num_rows,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--time-limit", type=float, default=20.0, help="per scenario (s)")
    ap.add_argument("paths", nargs="*", type=Path)
    args = ap.parse_args(argv)
    paths = args.paths or sorted((ROOT / "benchmarks" / "scenarios").glob("*.yaml")) + sorted(
        (ROOT / "configs").glob("*.yaml")
    )
    head = (
        f"{'scenario':<42} {'dt_s':>5} {'build_s':>7} {'solve_s':>7} {'status':<12} "
        f"{'milp_rho':>9} {'bound':>8} {'exact':>9} {'binaries':>8}"
    )
    print(head)
    rows = []
    for path in paths:
        r = run_one(path, args.time_limit)
        rows.append(r)

        def f(x: float | None) -> str:
            return "-" if x is None else f"{x:+.4f}"

        print(f"{r['scenario']:<42} {r['dt_s']:>5g} {r['build_s']:>7.2f} {r['solve_s']:>7.2f} "
              f"{r['status']:<12} {f(r['robustness']):>9} {f(r['bound']):>8} "
              f"{f(r['exact_coarse']):>9} {r['binaries']:>8}")  # fmt: skip
    positive = sum(1 for r in rows if (r["robustness"] or -1.0) > 0)
    print(json.dumps({"bench": "milp", "time_limit_s": args.time_limit, "scenarios": len(rows),
                      "positive_robustness": positive, "rows": rows}))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
