"""How planning cost grows with the horizon and with the number of poles (issues 19 and 40).

Power-line missions of the zoo's kind (``benchmarks/scenarios/powerline_line20_4drones_300s``:
poles 30 m apart, an inspection box south of each, the conductor corridor and the poles kept
out, 1.5 m separation, PX4-like limits, 5 s minimum-jerk segments sampled every 1 s), generated
for two sweeps:

* horizon: 8 poles, 2 drones (4 poles each), horizon 100 ... 400 s;
* poles: 4 drones, horizon 300 s, 4 ... 40 poles (a quarter each; at 40 the farthest drone
  needs about 290 s of the 300, so a plan that meets it is not expected in the time limit:
  the build is the figure, issue 40's "40 poles x 4 drones x 300 s builds in under 15 s");
* long (``--sweeps long``): 100 and 200 poles (3 and 6 km), 8 drones, each starting at its own
  section's first pole, 300 s, a time limit of at least 600 s.

Each mission is planned cold in this process (:func:`planner.solve.nlp.clear_cache` first), with a
time limit.  Printed per run: the NLP's size, the build and solver times, the total, the
iterations, the exact robustness and whether the mission was met; then, per sweep, the
growth exponent of the total time and of the build (the slope of log time against log size,
a least-squares fit: 1 is linear), the build time per segment and clause, and one JSON line.

    .venv/bin/python benchmarks/bench_scaling.py
    .venv/bin/python benchmarks/bench_scaling.py --quick        # two points per sweep
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from planner.optimize import plan  # noqa: E402
from planner.scenario import parse_scenario  # noqa: E402
from planner.solve.nlp import clear_cache  # noqa: E402

SPAN_M = 30.0


def line_scenario(
    poles: int, drones: int, horizon_s: float, spread: bool = False
) -> dict[str, Any]:
    """A straight line of ``poles`` poles along x, ``drones`` drones sharing them in runs;
    with ``spread``, each drone starts at its own run's first pole (a crew that drove there),
    else all near pole 1."""
    regions: dict[str, Any] = {}
    for i in range(poles):
        x = SPAN_M * i
        regions[f"pole{i + 1}"] = {
            "kind": "pole",
            "min": [x - 0.4, -0.4, 0],
            "max": [x + 0.4, 0.4, 12],
        }
        regions[f"insp{i + 1}"] = {
            "kind": "inspection",
            "min": [x - 2.5, -5.5, 9.5],
            "max": [x + 2.5, -3.3, 12.5],
        }
    end = SPAN_M * (poles - 1)
    regions["corridor"] = {"kind": "conductor", "min": [-2, -2.8, 8], "max": [end + 2, 2.8, 12.5]}
    per = math.ceil(poles / drones)
    names = [f"d{j + 1}" for j in range(drones)]
    spec: list[dict[str, Any]] = []
    for i in range(poles):
        spec.append(
            {
                "formula": f"eventually[0, {horizon_s - 2:g}] always[0, 2] "
                f"inside({names[min(i // per, drones - 1)]}, insp{i + 1})"
            }
        )
    keep = " and ".join(f"outside(d, pole{i + 1})" for i in range(poles))
    spec.append(
        {
            "each": "d in all",
            "formula": f"always[0, {horizon_s:g}] (inside(d, workspace) and {keep} and "
            "outside(d, corridor))",
        }
    )
    if drones > 1:
        spec.append(
            {
                "each": "(a, b) in pairs(all)",
                "formula": f"always[0, {horizon_s:g}] dist(a, b) >= 1.5",
            }
        )
    return {
        "name": f"line{poles}_{drones}drones_{horizon_s:g}s",
        "origin": {"lat": 47.397742, "lon": 8.545594, "alt": 488.0},
        "workspace": {"min": [-10, -20, 0.5], "max": [end + 10, 10, 20]},
        "regions": regions,
        "limits": {
            "v_xy_max_m_s": 5,
            "v_up_max_m_s": 3,
            "v_down_max_m_s": 1.5,
            "a_xy_max_m_s2": 3,
            "a_up_max_m_s2": 3,
            "a_down_max_m_s2": 2,
        },
        "vehicles": [
            {"name": nm, "start": [(SPAN_M * j * per if spread else 4 * j) - 6, -12, 8]}
            for j, nm in enumerate(names)
        ],
        "timing": {"horizon_s": horizon_s, "segment_s": 5, "Ts_s": 1, "check_dt_s": 0.2},
        "separation_m": 1.5,
        "epsilon": 0.01,
        "model": "minimum_jerk",
        "solver": {
            "hessian": "exact",
            "max_iter": 1000,
            "robustness_cap_m": 0.3,
            "separation_curvature": True,
        },
        "spec": spec,
    }


def run(
    poles: int, drones: int, horizon_s: float, time_limit_s: float, spread: bool = False
) -> dict[str, Any]:
    problem = parse_scenario(line_scenario(poles, drones, horizon_s, spread), "<bench_scaling>")
    clear_cache()
    t0 = time.perf_counter()
    result = plan(problem, time_limit_s=time_limit_s)
    total = time.perf_counter() - t0
    st = result.stats
    assert st is not None
    segments = round(horizon_s / 5)
    return {
        "poles": poles,
        "drones": drones,
        "horizon_s": horizon_s,
        "segments": segments,
        "clauses": len(problem.clauses),
        "n_variables": st.n_variables,
        "n_constraints": st.n_constraints,
        "build_s": round(st.build_s, 3),
        "solver_s": round(st.solver_s, 3),
        "total_s": round(total, 3),
        "iterations": result.iterations,
        "robustness": round(result.robustness, 4),
        "met": bool(result.success),
        "build_ms_per_segment_clause": round(
            1e3 * st.build_s / (segments * len(problem.clauses) * drones), 3
        ),
    }


def slope(xs: list[float], ys: list[float]) -> float:
    """Least-squares slope of log y against log x (the growth exponent)."""
    return float(np.polyfit(np.log(xs), np.log(ys), 1)[0])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two points per sweep")
    ap.add_argument("--time-limit", type=float, default=120.0, help="per plan (s)")
    ap.add_argument(
        "--sweeps",
        default="horizon,poles",
        help="which sweeps: horizon, poles, long (100 and 200 poles, 8 drones starting at their "
        "own sections, 300 s; the time limit 600 s)",
    )
    args = ap.parse_args(argv)
    chosen = set(args.sweeps.split(","))
    horizons = [100.0, 400.0] if args.quick else [100.0, 200.0, 300.0, 400.0]
    poles = [4, 20] if args.quick else [4, 8, 12, 16, 20, 30, 40]
    sweeps: dict[str, list[dict[str, Any]]] = {"horizon": [], "poles": [], "long": []}
    head = (
        f"{'sweep':8} {'poles':>5} {'drones':>6} {'horizon':>7} {'vars':>6} {'cons':>6} "
        f"{'build s':>8} {'solver s':>8} {'total s':>8} {'iter':>5} {'robust':>8} {'met':>4} "
        f"{'ms/seg/clause':>13}"
    )
    print(head)
    print("-" * len(head))
    for name, cases in (
        ("horizon", [(8, 2, h) for h in horizons]),
        ("poles", [(n, 4, 300.0) for n in poles]),
        ("long", [(100, 8, 300.0), (200, 8, 300.0)]),
    ):
        if name not in chosen:
            continue
        for n, d, h in cases:
            long = name == "long"
            row = run(n, d, h, max(args.time_limit, 600.0) if long else args.time_limit, long)
            sweeps[name].append(row)
            print(
                f"{name:8} {n:5d} {d:6d} {h:7.0f} {row['n_variables']:6d} "
                f"{row['n_constraints']:6d} {row['build_s']:8.2f} {row['solver_s']:8.2f} "
                f"{row['total_s']:8.2f} {row['iterations']:5d} {row['robustness']:8.4f} "
                f"{'yes' if row['met'] else 'no':>4} {row['build_ms_per_segment_clause']:13.3f}",
                flush=True,
            )
    growth = {
        name: {
            "total": slope([r[key] for r in sweeps[name]], [r["total_s"] for r in sweeps[name]]),
            "build": slope([r[key] for r in sweeps[name]], [r["build_s"] for r in sweeps[name]]),
        }
        for name, key in (("horizon", "horizon_s"), ("poles", "poles"))
        if len(sweeps[name]) > 1
    }
    print()
    for name, g in growth.items():
        print(
            f"growth with {name}: total time ~ {name}^{g['total']:.2f}, build ~ {name}^{g['build']:.2f}"
        )
    met = sum(r["met"] for rows in sweeps.values() for r in rows)
    runs = sum(len(rows) for rows in sweeps.values())
    print(f"missions met: {met}/{runs}")
    rev = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    print(
        json.dumps(
            {
                "bench": "scaling",
                "planner": rev,
                "sweeps": sweeps,
                "growth": growth,
                "met": met,
                "runs": runs,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
