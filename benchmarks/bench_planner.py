"""Planner figures: planning time, iterations, exact robustness and problem size.

For each case the structure cache is cleared, then the case is planned ``--runs`` times:
the first run builds the CasADi functions and the nlpsol (cold), the later ones reuse them
(warm, as a re-plan with the same scenario structure would).  Printed per case: median
total time over the runs, cold build time, median solver (IPOPT) time and the part of it
spent in CasADi function evaluations, the dense exact check, iterations, exact robustness
(dense samples), decision variables and constraints.  Then one JSON line with everything.

    .venv/bin/python benchmarks/bench_planner.py                 # all cases, 3 runs
    .venv/bin/python benchmarks/bench_planner.py --runs 1 --cases reach_avoid:2,powerline:2
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")  # MUMPS threads only fight on 2 shared cores

from planner.optimize import clear_cache, plan
from planner.scenario import load_scenario

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
FILES = {"reach_avoid": "reach_avoid.yaml", "powerline": "powerline_inspection.yaml"}
DEFAULT_CASES = (
    "reach_avoid:1,reach_avoid:2,reach_avoid:4,reach_avoid:8,reach_avoid:16,"
    "powerline:2,powerline:4,powerline:8"
)


def run_case(name: str, n: int, runs: int) -> dict[str, object]:
    problem = load_scenario(CONFIGS / FILES[name], vehicles=n)
    clear_cache()
    results = []
    for _ in range(runs):
        t0 = time.perf_counter()
        r = plan(problem)
        results.append((time.perf_counter() - t0, r))
    first = results[0][1]
    assert first.stats is not None
    return {
        "case": name,
        "n": n,
        "runs": runs,
        "median_total_s": statistics.median(t for t, _ in results),
        "cold_total_s": results[0][0],
        "build_s": first.stats.build_s,
        "solver_s": statistics.median(r.stats.solver_s for _, r in results),
        "function_eval_s": statistics.median(r.stats.function_eval_s for _, r in results),
        "check_s": statistics.median(r.stats.check_s for _, r in results),
        "iterations": first.iterations,
        "robustness": first.robustness,
        "success": first.success,
        "n_variables": first.stats.n_variables,
        "n_constraints": first.stats.n_constraints,
        "hessian": problem.solver.hessian,
        "status": first.status,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--cases", default=DEFAULT_CASES, help="name:N,... (reach_avoid, powerline)")
    args = ap.parse_args(argv)
    rows = []
    head = (
        f"{'case':<12} {'N':>3} {'median s':>9} {'cold s':>8} {'build s':>8} {'ipopt s':>8} "
        f"{'f-eval s':>8} {'check s':>8} {'iter':>5} {'robust':>8} {'ok':>3} {'vars':>6} {'cons':>7}"
    )
    print(head)
    print("-" * len(head))
    for item in args.cases.split(","):
        name, n = item.split(":")
        row = run_case(name, int(n), args.runs)
        rows.append(row)
        print(
            f"{name:<12} {n:>3} {row['median_total_s']:>9.2f} {row['cold_total_s']:>8.2f} "
            f"{row['build_s']:>8.2f} {row['solver_s']:>8.2f} {row['function_eval_s']:>8.2f} "
            f"{row['check_s']:>8.2f} {row['iterations']:>5} {row['robustness']:>8.4f} "
            f"{'y' if row['success'] else 'n':>3} {row['n_variables']:>6} {row['n_constraints']:>7}",
            flush=True,
        )
    print(json.dumps({"bench": "planner", "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
