"""Row screening (issue 40, scale): each mission planned with every row-wise constraint in
the NLP (``solver.screen: false``) and screened (``true``: rows only where they can bind,
grown by row generation; :mod:`planner.solve.screen`), and which of the two ``auto``, the default,
chooses (from one more run).

Each run is cold (:func:`planner.solve.nlp.clear_cache` first), in this process, off and on
in turn (A B A B ...) so a drift of the machine's speed falls on both. Printed per mission
and setting: the median total, build and IPOPT time, iterations, the exact robustness, met,
the step rows kept of all and the rounds of row generation; then one JSON line.

    .venv/bin/python benchmarks/bench_screen.py                # every case, 1 run
    .venv/bin/python benchmarks/bench_screen.py --runs 3 --cases line6_12drones
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")  # MUMPS threads only fight on 2 shared cores

from planner.optimize import clear_cache, plan
from planner.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
CASES: dict[str, tuple[str, int | None]] = {
    "line8_3drones": ("benchmarks/scenarios/powerline_line8_3drones.yaml", None),
    "line10_3drones": ("benchmarks/scenarios/powerline_line10_east_3drones.yaml", None),
    "line12_4drones": ("benchmarks/scenarios/powerline_line12_4drones.yaml", None),
    "line6_12drones": ("benchmarks/scenarios/powerline_line6_12drones.yaml", None),
    "line20_4drones": ("benchmarks/scenarios/powerline_line20_4drones_300s.yaml", None),
    "line40_4drones": ("benchmarks/scenarios/powerline_line40_4drones_300s.yaml", None),
    "powerline_4": ("configs/powerline_inspection.yaml", 4),
    "powerline_8": ("configs/powerline_inspection.yaml", 8),
    "reach_avoid_16": ("configs/reach_avoid.yaml", 16),
}


def run(name: str, screen: bool | None, time_limit: float) -> dict[str, Any]:
    path, n = CASES[name]
    problem = load_scenario(ROOT / path, vehicles=n) if n else load_scenario(ROOT / path)
    problem = dataclasses.replace(
        problem, solver=dataclasses.replace(problem.solver, screen=screen)
    )
    clear_cache()
    t0 = time.perf_counter()
    r = plan(problem, time_limit_s=time_limit)
    s = r.stats
    assert s is not None
    return {
        "total_s": time.perf_counter() - t0,
        "build_s": s.build_s,
        "solver_s": s.solver_s,
        "iterations": r.iterations,
        "robustness": r.robustness,
        "met": r.success,
        "screen": None if s.screen is None else dict(s.screen),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--time-limit", type=float, default=120.0)
    args = ap.parse_args(argv)
    names = [c for c in args.cases.split(",") if c]
    out: dict[str, Any] = {"bench": "screen", "runs": args.runs, "cases": {}}
    print(f"{'mission':<16} {'screen':<6} {'auto':<5} {'total s':>8} {'build s':>8} "
          f"{'ipopt s':>8} {'iter':>5} {'robustness':>10} {'met':>4} {'kept / all rows':>18} "
          f"{'rounds':>6}", flush=True)  # fmt: skip
    for name in names:
        auto = run(name, None, args.time_limit)["screen"] is not None  # what the default does
        got: dict[bool, list[dict[str, Any]]] = {False: [], True: []}
        for _ in range(args.runs):
            for on in (False, True):
                got[on].append(run(name, on, args.time_limit))
        out["cases"][name] = {"auto_screens": auto}
        for on in (False, True):
            rs = got[on]
            med = {k: statistics.median(r[k] for r in rs) for k in
                   ("total_s", "build_s", "solver_s", "iterations", "robustness")}  # fmt: skip
            last = rs[-1]
            sc = last["screen"]
            kept = "-" if sc is None else f"{sc['kept']:,} / {sc['total']:,}"
            print(f"{name:<16} {'on' if on else 'off':<6} {'yes' if auto == on else '':<5} "
                  f"{med['total_s']:8.2f} {med['build_s']:8.2f} {med['solver_s']:8.2f} "
                  f"{med['iterations']:5.0f} {med['robustness']:+10.4f} "
                  f"{sum(r['met'] for r in rs):>2}/{len(rs)} {kept:>18} "
                  f"{'-' if sc is None else sc['rounds']:>6}", flush=True)  # fmt: skip
            out["cases"][name]["on" if on else "off"] = {**med, "met": [r["met"] for r in rs],
                                                         "screen": sc}  # fmt: skip
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
