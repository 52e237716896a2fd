"""Plans for PX4's missions (issue 42): ``gcs plan --for mission`` against the plan as written.

For each scenario, in this process (cold caches first, one run each):

1. the plan as written (``gcs plan``), and the plan made for missions
   (:func:`planner.for_missions.plan_for_missions`, 0.5 s of timing error, 6 rounds at most);
2. for each: its robustness, the clause that tolerates the least timing error on the plan and
   how much (s), the margins added, the time it took;
3. for each: the mission conversion ``gcs upload`` and ``gcs fly --mode mission`` make
   (:func:`gcs.flight.missions.convert_plan`, PX4's navigator predicted by the px4 mock):
   the predicted robustness and the least tolerance on the predicted flight, and whether
   ``gcs upload --start`` would release it (predicted >= epsilon and every clause tolerating
   0.5 s, ``KEEPS_CLOCK_S``).

Printed: a table, then one JSON line.

    .venv/bin/python benchmarks/bench_for_mission.py [--scenarios reach_avoid powerline_inspection]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from gcs.flight.missions import KEEPS_CLOCK_S, MissionEnd, convert_plan
from planner.for_missions import plan_for_missions, plan_tolerances
from planner.optimize import plan
from planner.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]


def _conversion(p: object) -> dict[str, object]:
    t0 = time.perf_counter()
    conv = convert_plan(p, end=MissionEnd.HOLD)  # type: ignore[arg-type]
    least = conv.least_tolerant()
    released = conv.predicted_robustness >= p.epsilon and (  # type: ignore[attr-defined]
        least is None or least[1] >= KEEPS_CLOCK_S
    )
    return {
        "predicted": round(conv.predicted_robustness, 3),
        "predicted_least_s": None if least is None else least[1],
        "predicted_least": None if least is None else least[0],
        "released": released,
        "convert_s": round(time.perf_counter() - t0, 1),
    }


def run(name: str) -> list[dict[str, object]]:
    problem = load_scenario(ROOT / "configs" / f"{name}.yaml")
    rows = []
    t0 = time.perf_counter()
    written = plan(problem)
    t_written = time.perf_counter() - t0
    tol = plan_tolerances(written, problem)
    first = min(tol.items(), key=lambda kv: kv[1])
    t0 = time.perf_counter()
    r = plan_for_missions(problem, rounds=6)
    t_loop = time.perf_counter() - t0
    rows.append(
        {
            "scenario": name,
            "plan": "as written",
            "robustness": round(written.robustness, 3),
            "least_s": first[1],
            "least": first[0],
            "margins_m": {},
            "rounds": 1,
            "plan_s": round(t_written, 1),
            **_conversion(written.to_plan()),
        }
    )
    least = r.timing.least()
    rows.append(
        {
            "scenario": name,
            "plan": "--for mission",
            "robustness": round(r.result.robustness, 3),
            "least_s": None if least is None else least[1],
            "least": None if least is None else least[0],
            "met": r.timing.met,
            "margins_m": dict(r.timing.margins_m),
            "rounds": r.timing.rounds,
            "plan_s": round(t_loop, 1),
            **_conversion(r.result.to_plan()),
        }
    )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=["reach_avoid", "powerline_inspection"])
    args = ap.parse_args()
    rows = [row for name in args.scenarios for row in run(name)]
    head = (
        f"{'scenario':22} {'plan':14} {'rho':>7} {'tolerates':>9} {'rounds':>6} {'time':>7} "
        f"{'predicted':>9} {'pred. tol.':>10} {'released':>8}"
    )
    print(head)
    print("-" * len(head))
    for row in rows:
        tol = "-" if row["least_s"] is None else f"{row['least_s']:.2f} s"
        ptol = "-" if row["predicted_least_s"] is None else f"{row['predicted_least_s']:.2f} s"
        print(
            f"{row['scenario']:22} {row['plan']:14} {row['robustness']:+7.3f} {tol:>9} "
            f"{row['rounds']:>6} {row['plan_s']:>6.1f}s {row['predicted']:+9.3f} {ptol:>10} "
            f"{'yes' if row['released'] else 'no':>8}"
        )
    for row in rows:
        if row["margins_m"]:
            print(f"{row['scenario']} margins (m): {row['margins_m']}")
        print(f"{row['scenario']} {row['plan']}: least tolerant {row['least']}; "
              f"on the predicted flight {row['predicted_least']}")  # fmt: skip
    print(json.dumps({"bench": "for_mission", "tolerance_s": KEEPS_CLOCK_S, "rows": rows}))


if __name__ == "__main__":
    main()
