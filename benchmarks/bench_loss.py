"""Vehicle loss without replanning (issue 43's baseline): what the power line loses with a drone.

1. The shipped power-line plan (4 drones, ``configs/powerline_inspection.yaml``, planned here)
   flown on the px4 mock (``gcs fly --dry-run --json``) with d2 lost at 5, 10 and 15 s of the
   plan (``--mock-fault d2:lost@T``): the exit status, the safety stop and when it came, when
   the fault fired, and which clauses the flown prefix had already met (none of that is
   judged as the mission: the flight ends with the hold).
2. ``gcs assess`` of the same plan with ``-d lost=P`` (each drone lost with probability P at
   a time uniform over the plan), P = 0, 0.02, 0.05, 0.1, ``--runs`` runs each, with the
   safety monitor: P(spec holds) with its interval, the runs that lost a drone, and how often
   the monitor stopped on the lost link.

Replanning (issue 43) is to beat these figures. Printed: two tables, then one JSON line.

    .venv/bin/python benchmarks/bench_loss.py --runs 1000
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

from cli_runs import run_cli

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1000, help="runs per assessment (default 1000)")
    ap.add_argument("--times", default="5,10,15", help="loss times for the flights (s)")
    ap.add_argument("--probabilities", default="0,0.02,0.05,0.1")
    args = ap.parse_args(argv)
    result: dict[str, Any] = {"bench": "loss", "flights": [], "assess": []}
    with tempfile.TemporaryDirectory() as tmp:
        plan = str(Path(tmp) / "powerline.json")
        rc, _, plan_s = run_cli(
            ["plan", str(ROOT / "configs/powerline_inspection.yaml"), "-o", plan]
        )
        assert rc == 0, "the power line did not plan"
        print(f"power line planned in {plan_s:.1f} s")
        print(f"{'lost':<10} {'exit':>4} {'fired s':>8} {'stopped':<60} {'wall s':>7}")
        for t in args.times.split(","):
            rc, out, wall = run_cli(
                ["fly", plan, "--dry-run", "--json", "--mock-fault", f"d2:lost@{t}"]
            )
            fired = (out.get("mock_faults") or [{}])[0].get("fired_at_s")
            stop = out.get("safety_event") or "-"
            print(f"d2 at {t:<4} {rc:>4} {fired if fired is None else round(fired, 2)!s:>8} "
                  f"{stop[:60]:<60} {wall:7.1f}")  # fmt: skip
            result["flights"].append({"lost_at_s": float(t), "exit": rc, "fired_at_s": fired,
                                      "safety_event": out.get("safety_event"),
                                      "completed": out.get("completed"), "wall_s": wall})  # fmt: skip
        print()
        print(f"{'P(lost)':>8} {'P(spec holds) [95 %]':>26} {'runs lost':>10} "
              f"{'stops on lost link':>19} {'wall s':>7}")  # fmt: skip
        for p in args.probabilities.split(","):
            rc, out, wall = run_cli(["assess", plan, "--runs", str(args.runs), "-d", f"lost={p}",
                                     "--monitor", "--json"])  # fmt: skip
            reasons = {r["why"]: r["runs"] for r in (out.get("monitor") or {}).get("reasons", [])}
            on_link = reasons.get("a vehicle lost (its link silent)", 0)
            lo, hi = out["ci95"]
            print(f"{float(p):8.2f} {out['p_holds']:>8.4f} [{lo:.4f}, {hi:.4f}] "
                  f"{out['lost']:>10} {on_link:>19} {wall:7.1f}")  # fmt: skip
            result["assess"].append({"p_lost": float(p), "p_holds": out["p_holds"],
                                     "ci95": out["ci95"], "runs": out["runs"],
                                     "runs_lost": out["lost"], "stops_on_lost_link": on_link,
                                     "wall_s": wall})  # fmt: skip
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
