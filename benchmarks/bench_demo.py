"""Wall time of ``gcs demo`` split into its stages, and flown vs planned robustness.

Runs the demo pipeline in-process (:func:`gcs.commands.demo.run_demo`: power-line inspection,
4 drones by default, mock PX4 vehicles, offboard flight at 20 Hz) and prints a table of the
stages (imports, set-up, planning, vehicles = mock start + MAVLink connection, flight =
take-off to end action, report = evaluation + picture + report) and then one JSON line.
The planner's own cache is cleared first, so planning includes building the CasADi problem,
as a fresh ``gcs demo`` process does.

Usage: ``.venv/bin/python benchmarks/bench_demo.py [--vehicles N] [--out DIR]``
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time


def main() -> int:
    """Run the demo once and print the table and the JSON line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=4)
    ap.add_argument("--out", help="output directory (default: a temporary one)")
    ap.add_argument("--scenario", help="scenario file (default: the demo's)")
    args = ap.parse_args()

    t = time.perf_counter()
    import gcs.plot  # noqa: F401  (matplotlib)
    import mavlink.link.fleet  # noqa: F401  (mavsdk)
    import planner.optimize as optimize  # (casadi)
    from gcs.commands.demo import run_demo

    import_s = time.perf_counter() - t
    optimize.clear_cache()
    out = args.out or tempfile.mkdtemp(prefix="bench-demo-")
    t = time.perf_counter()
    demo = run_demo(out, vehicles=args.vehicles, scenario=args.scenario)
    wall_s = time.perf_counter() - t

    stages = {"imports": import_s, **demo.timings_s}
    total = sum(stages.values())
    print(f"gcs demo, {args.vehicles} vehicles, output {out}")
    print(f"{'stage':<10} {'s':>8} {'share':>7}")
    for name, s in stages.items():
        print(f"{name:<10} {s:8.2f} {100 * s / total:6.1f}%")
    print(f"{'total':<10} {total:8.2f}   (run_demo wall {wall_s:.2f} s)")
    oc = demo.outcome
    ev = oc.evaluation if oc is not None else None
    planned = demo.plan.robustness
    flown = ev.flown_robustness if ev is not None else None
    print(f"planned robustness {planned:+.4f}  flown robustness ", end="")
    print("n/a" if flown is None else f"{flown:+.4f}", end="")
    print(
        f"  ({demo.plan.status.split(':')[0]}; {'verification FAILED: ' + demo.verification if demo.verification else 'verifies'})"
    )
    if ev is not None:
        for te in ev.tracking:
            print(
                f"  {te.vehicle}: tracking max {te.max_m:.3f} m rms {te.rms_m:.3f} m, "
                f"best-fit delay {te.lag_s:+.2f} s"
            )
    stream = (
        {
            n: {"sent": s.sent, "late": s.late, "p99_ms": s.p99_lateness_s * 1e3}
            for n, s in oc.stats.items()
        }
        if oc is not None
        else {}
    )
    print(
        json.dumps(
            {
                "bench": "demo",
                "vehicles": args.vehicles,
                "stages_s": {k: round(v, 3) for k, v in stages.items()},
                "total_s": round(total, 3),
                "planned_robustness": planned,
                "flown_robustness": flown,
                "plan_success": demo.plan.success,
                "completed": None if oc is None else oc.completed,
                "max_tracking_error_m": None if ev is None else max(te.max_m for te in ev.tracking),
                "stream": stream,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
