"""The objective after its first bottleneck (issue 19, item 4): what the lexicographic rounds
(``solver.lexicographic_rounds``, :func:`planner.solve.refine.raise_the_rest`) buy and cost.

Each zoo scenario below is planned cold in this process twice: with the rounds off (the
max-min alone) and with the default.  Printed per run: the exact robustness (the headline),
the weakest clause the plan itself sets (for a plan whose headline the start sets: the other
clauses' least; for a failing plan: the least robustness among the clauses other than the
weakest), how many clauses meet epsilon, iterations and wall time; then one JSON line.

* ``powerline_ground_start_uncapped_2drones``: the drones start 1 m up over a 0.5 m floor, so
  the headline is 0.5 m whatever the plan does;
* ``two_drones_one_unreachable_hover``: d1's hover is out of reach, d2's is easy;
* ``powerline_ground_start_2drones``: the same line with a robustness cap (0.3 m), where the
  start sets nothing: the rounds must not run (same plan, same cost).

    .venv/bin/python benchmarks/bench_objective.py
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from planner.optimize import plan  # noqa: E402
from planner.problem import SolverOptions  # noqa: E402
from planner.scenario import load_scenario  # noqa: E402
from planner.solve.nlp import clear_cache  # noqa: E402

SCENARIOS = (
    "powerline_ground_start_uncapped_2drones",
    "two_drones_one_unreachable_hover",
    "powerline_ground_start_2drones",
)


def run(name: str, rounds: int) -> dict[str, Any]:
    """One cold plan of zoo scenario ``name`` with ``rounds`` lexicographic rounds."""
    problem = load_scenario(ROOT / "benchmarks" / "scenarios" / f"{name}.yaml")
    problem = dataclasses.replace(
        problem, solver=dataclasses.replace(problem.solver, lexicographic_rounds=rounds)
    )
    clear_cache()
    t0 = time.perf_counter()
    result = plan(problem)
    wall = time.perf_counter() - t0
    rob = sorted(c.robustness for c in result.clauses)
    if result.start_bound is not None:
        second = result.start_bound.others
    else:
        second = rob[1] if len(rob) > 1 else None
    return {
        "scenario": name,
        "rounds": rounds,
        "robustness": result.robustness,
        "second": second,
        "start_sets_headline": result.start_bound is not None,
        "clauses_met": sum(r >= problem.epsilon for r in rob),
        "clauses": len(rob),
        "success": result.success,
        "iterations": result.iterations,
        "wall_s": wall,
        "raised": "then raised the other clauses" in result.status,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", metavar="SUBSTRING", help="scenario filter")
    args = parser.parse_args(argv)
    names = [n for n in SCENARIOS if not args.only or any(s in n for s in args.only)]
    default = SolverOptions().lexicographic_rounds
    rows = [run(name, rounds) for name in names for rounds in (0, default)]
    print(
        f"{'scenario':<42} {'rounds':>6} {'robust':>8} {'second':>8} {'met':>5} "
        f"{'iter':>5} {'wall s':>7}  note"
    )
    for r in rows:
        second = "-" if r["second"] is None else f"{r['second']:.4f}"
        note = ("start sets headline" if r["start_sets_headline"] else "") + (
            "; raised" if r["raised"] else ""
        )
        print(
            f"{r['scenario']:<42} {r['rounds']:>6} {r['robustness']:>8.4f} {second:>8} "
            f"{r['clauses_met']:>2}/{r['clauses']:<2} {r['iterations']:>5} {r['wall_s']:>7.1f}"
            f"  {note.strip('; ')}"
        )
    print(json.dumps({"bench": "objective", "rows": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
