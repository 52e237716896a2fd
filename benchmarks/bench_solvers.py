"""Solver choices measured on the same problems: the evidence behind the planner's defaults.

For each case (scenario, fleet size) and each variant, the structure cache is cleared and
the case planned once (cold: build + solve + check).  Variants:

    ipopt           the baseline: IPOPT, exact Hessian, k fitted, plain maximisation (every
                    variant but eq1 is the plain maximisation, whatever the scenario says)
    ipopt-lbfgs     IPOPT with L-BFGS (hessian: limited-memory)
    sqp-piqp        CasADi sqpmethod, BFGS, QP solver PIQP (its default here)
    sqp-qpoases     sqpmethod, BFGS, qpOASES
    sqp-exact       sqpmethod, exact Hessian regularised to convexity, PIQP
    k/2, 2k         IPOPT with half / twice the fitted sharpness
    cont-k/3        IPOPT on k/3 first, then the fitted k warm started (continuation)
    eq1             the paper's eq. (1): robustness >= epsilon (+ margin) as a constraint,
                    still maximised (what configs/reach_avoid.yaml sets)

Printed per row: wall time, build time, solver time, iterations, exact robustness (dense
samples), success.  Then one JSON line with everything.  sqpmethod variants stop at
``--sqp-max-iter`` iterations and run only up to ``--sqp-max-n`` vehicles (they are far
slower: reach-avoid N = 4 took 200 s with PIQP; the status says when they stopped).

    .venv/bin/python benchmarks/bench_solvers.py
    .venv/bin/python benchmarks/bench_solvers.py --cases reach_avoid:1 --variants ipopt,sqp-piqp
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

from planner.optimize import clear_cache, make_model, plan
from planner.problem import Problem, SolverMethod
from planner.scenario import load_scenario

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
FILES = {
    "reach_avoid": "reach_avoid.yaml",
    "powerline": "powerline_inspection.yaml",
    "narrow_passage_di": "narrow_passage_di.yaml",
}
DEFAULT_CASES = (
    "reach_avoid:1,reach_avoid:2,reach_avoid:4,reach_avoid:8,reach_avoid:16,"
    "powerline:2,powerline:4,powerline:8,narrow_passage_di:2"
)
#: The variants run on every fleet size; the others only up to ``--all-variants-max-n``.
CORE_VARIANTS = ("ipopt", "eq1")
VARIANTS = (
    "ipopt",
    "ipopt-lbfgs",
    "sqp-piqp",
    "sqp-qpoases",
    "sqp-exact",
    "k/2",
    "2k",
    "cont-k/3",
    "eq1",
)


def fitted_k(problem: Problem) -> float:
    """The sharpness the planner fits for ``problem`` (read off a cold plan's stats)."""
    r = plan(dataclasses.replace(problem, solver=dataclasses.replace(problem.solver, max_iter=1)))
    assert r.stats is not None
    return r.stats.k


def variant(problem: Problem, name: str, k: float, sqp_max_iter: int) -> Problem:
    s = dataclasses.replace(problem.solver, robustness_constraint=False)
    sqp = {"method": SolverMethod.SQP, "max_iter": sqp_max_iter}
    changes: dict[str, Any] = {
        "ipopt": {},
        "ipopt-lbfgs": {"hessian": "limited-memory"},
        "sqp-piqp": {**sqp, "hessian": "limited-memory", "qpsol": "piqp"},
        "sqp-qpoases": {**sqp, "hessian": "limited-memory", "qpsol": "qpoases"},
        "sqp-exact": {**sqp, "hessian": "exact", "qpsol": "piqp"},
        "k/2": {"k": k / 2},
        "2k": {"k": 2 * k},
        "cont-k/3": {"k": k, "continuation": (k / 3,)},
        "eq1": {"robustness_constraint": True},
    }[name]
    return dataclasses.replace(problem, solver=dataclasses.replace(s, **changes))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=DEFAULT_CASES, help="name:N,... (" + ", ".join(FILES) + ")")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--sqp-max-iter", type=int, default=150)
    ap.add_argument(
        "--sqp-max-n", type=int, default=2, help="sqpmethod variants only up to this fleet size"
    )
    ap.add_argument(
        "--all-variants-max-n",
        type=int,
        default=8,
        help="beyond this fleet size only the ipopt and eq1 variants run",
    )
    args = ap.parse_args(argv)
    head = (
        f"{'case':<18} {'N':>2} {'variant':<12} {'wall s':>7} {'build s':>7} {'solve s':>8} "
        f"{'iter':>5} {'robust':>8} {'ok':>3}  status"
    )
    print(head)
    print("-" * len(head))
    rows = []
    for item in args.cases.split(","):
        name, n = item.split(":")
        # The narrow passage lists its two vehicles (no --vehicles generator).
        fleet = None if name == "narrow_passage_di" else int(n)
        base = load_scenario(CONFIGS / FILES[name], vehicles=fleet)
        clear_cache()
        k = fitted_k(base)
        for v in args.variants.split(","):
            if v.startswith("sqp") and int(n) > args.sqp_max_n:
                continue
            if v not in CORE_VARIANTS and int(n) > args.all_variants_max_n:
                continue
            problem = variant(base, v, k, args.sqp_max_iter)
            clear_cache()
            t0 = time.perf_counter()
            r = plan(problem)
            wall = time.perf_counter() - t0
            assert r.stats is not None
            row = {
                "case": name,
                "n": int(n),
                "variant": v,
                "k": problem.solver.k or k,
                "wall_s": wall,
                "build_s": r.stats.build_s,
                "solver_s": r.stats.solver_s,
                "iterations": r.iterations,
                "robustness": r.robustness,
                "success": r.success,
                "status": r.status,
                "n_variables": r.stats.n_variables,
                "model": type(make_model(problem)).__name__,
            }
            rows.append(row)
            print(
                f"{name:<18} {int(n):>2} {v:<12} {wall:>7.2f} {r.stats.build_s:>7.2f} "
                f"{r.stats.solver_s:>8.2f} {r.iterations:>5} {r.robustness:>8.4f} "
                f"{'y' if r.success else 'n':>3}  {r.status.split(' (solver: ')[-1].rstrip(')')[:40]}",
                flush=True,
            )
    print(json.dumps({"bench": "solvers", "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
