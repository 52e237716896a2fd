"""Missions on the plan's clock (issue 42): the shipped scenarios converted and flown as PX4 missions.

Plans each shipped scenario, converts it to PX4 missions twice with the px4 mock's parameters
(drag ``SIH_KDV / SIH_MASS`` = 1 /s): the plain conversion (a waypoint per segment, legs at
their average speeds, the chosen radius: ``convert_plan(iterations=1)``, what stl-gcs did
before) and the search (``convert_plan``: waypoints simplified within a fraction of the plan's
margin, PX4's radius and larger, legs and holds re-timed against the prediction), and prints
the predicted robustness, the lateness per vehicle and the time each took. Then flies the
search's missions on the px4 mock (``gcs fly --dry-run --mode mission``, no ``--force``, mock
at ``--speed``) for ``--runs`` seeds: the exit status (1: refused, predicted below epsilon),
the flown robustness beside the predicted, each mission's finish against the plan, and the
pictures per pole where the plan takes any. Prints a table, then one JSON line. Usage::

    .venv/bin/python benchmarks/bench_missions.py [--runs 2] [--speed 4] [--only powerline]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gcs.cli import main as gcs  # noqa: E402

SCENARIOS = {
    "powerline": "powerline_inspection.yaml",
    "reach_avoid": "reach_avoid.yaml",
    "narrow_passage": "narrow_passage_di.yaml",
    "line10_camera": "powerline_line10_camera.yaml",
}
#: The px4 mock's drag (SIH_KDV / SIH_MASS), which gcs fly reads from the vehicles.
MOCK_PARAMS = {"SIH_KDV": 1.0, "SIH_MASS": 1.0}


def run_json(argv: list[str]) -> tuple[int, dict]:  # type: ignore[type-arg]
    """Exit status and the JSON printed; with no JSON, the last line of standard error."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = gcs(argv)
    text = out.getvalue()
    try:
        return rc, json.loads(text)
    except json.JSONDecodeError:
        lines = [x for x in err.getvalue().splitlines() if x.strip()]
        return rc, {"stderr": lines[-1][:160] if lines else ""}


def convert(plan_path: Path) -> dict:  # type: ignore[type-arg]
    from gcs.flight.missions import convert_plan
    from gcs.flight.payload import capture_spans
    from mavlink.mission import MissionEnd
    from planner.planfile import load_plan

    plan = load_plan(plan_path)
    spans = capture_spans(plan)
    out = {"planned": plan.robustness}
    for key, kw in (("plain", {"iterations": 1}), ("search", {})):
        t = time.perf_counter()
        c = convert_plan(plan, end=MissionEnd.HOLD, params=MOCK_PARAMS, captures=spans, **kw)
        out[key] = {
            "predicted": round(c.predicted_robustness, 3),
            "late_s": {k: round(v, 2) for k, v in c.late_s.items()},
            "radius_m": round(c.acceptance_m, 2),
            "simplify_m": round(c.simplify_m, 3),
            "predictions": c.iterations,
            "time_s": round(time.perf_counter() - t, 1),
            "waypoints": sum(len(m.waypoints_enu_m) for m in c.missions.values()),
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=2, help="mock flights per scenario (2)")
    ap.add_argument("--speed", type=float, default=4.0, help="the mock's speed (4)")
    ap.add_argument("--only", default=",".join(SCENARIOS), help="scenarios, comma-separated")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.only.split(","):
            plan = Path(tmp) / f"{name}.json"
            rc, res = run_json(
                ["plan", str(ROOT / "configs" / SCENARIOS[name]), "-o", str(plan), "--json"]
            )
            if rc != 0:
                rows.append({"scenario": name, "error": f"gcs plan exit {rc}"})
                continue
            row = {"scenario": name, **convert(plan), "flights": []}
            print(f"  {name}: converted", file=sys.stderr)
            for seed in range(args.runs):
                t = time.perf_counter()
                argv = ["fly", str(plan), "--dry-run", "--mode", "mission", "--json"]
                rc, res = run_json([*argv, "--seed", str(seed), "--speed", f"{args.speed:g}"])
                pred = res.get("mission_prediction") or {}
                cov = res.get("coverage") or {}
                row["flights"].append(
                    {
                        "seed": seed,
                        "exit": rc,
                        "wall_s": round(time.perf_counter() - t, 1),
                        "predicted": pred.get("predicted_robustness"),
                        "flown": res.get("flown_robustness"),
                        "late_s": {
                            k: m.get("late_s") for k, m in (res.get("missions") or {}).items()
                        },
                        "pictures": {t["target"]: t["images"] for t in cov.get("by_target", [])},
                        "covered": None if not cov else cov["covered"] == cov["targets"],
                        "why": res.get("safety_event") or res.get("stderr") or "",
                    }
                )
                print(f"  {name} seed {seed}: exit {rc}", file=sys.stderr)
            rows.append(row)

    def num(x: float | None, fmt: str = "+.3f") -> str:
        return "-" if x is None else format(x, fmt)

    def lates(d: dict) -> str:  # type: ignore[type-arg]
        vals = [v for v in d.values() if v is not None]
        return f"{min(vals):+.1f}..{max(vals):+.1f}" if vals else "-"

    print(f"px4 mock (drag 1 /s), missions ending in a hold; flights at speed {args.speed:g}")
    print(f"{'scenario':<15} {'planned':>7} | {'plain pred':>10} {'late s':>11} | "
          f"{'search pred':>11} {'late s':>11} {'R m':>4} {'simp m':>6} {'wps':>4} "
          f"{'n':>3} {'time s':>6}")  # fmt: skip
    for r in rows:
        if "error" in r:
            print(f"{r['scenario']:<15} {r['error']}")
            continue
        p, s = r["plain"], r["search"]
        print(
            f"{r['scenario']:<15} {r['planned']:>+7.3f} | {p['predicted']:>+10.3f} "
            f"{lates(p['late_s']):>11} | {s['predicted']:>+11.3f} {lates(s['late_s']):>11} "
            f"{s['radius_m']:>4.1f} {s['simplify_m']:>6.2f} {s['waypoints']:>4} "
            f"{s['predictions']:>3} {s['time_s']:>6}"
        )
    print()
    print(f"{'scenario':<15} {'seed':>4} {'exit':>4} {'predicted':>9} {'flown':>7} "
          f"{'finish vs plan s':>16} {'wall s':>6}  pictures per pole")  # fmt: skip
    for r in rows:
        for f in r.get("flights", []):
            pics = " ".join(str(v) for v in f["pictures"].values()) or "-"
            print(
                f"{r['scenario']:<15} {f['seed']:>4} {f['exit']:>4} {num(f['predicted']):>9} "
                f"{num(f['flown']):>7} {lates(f['late_s']):>16} {f['wall_s']:>6}  {pics}"
                + ("" if f["covered"] is None else f" (all covered: {f['covered']})")
            )
            if f["exit"] != 0 and f["why"]:
                print(f"{'':<15} {'':>4}      {f['why'][:110]}")
    print(json.dumps({"bench": "missions", "speed": args.speed, "rows": rows}))


if __name__ == "__main__":
    main()
