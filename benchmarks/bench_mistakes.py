"""What a new user's mistakes cost to be told (issue 20): the load-time checks, end to end.

For each mistake a scenario file is written (the shipped reach-avoid or power line with one
edit) and ``gcs plan`` is run on it as a user would: the exit status, the one line it
printed, and the wall time to that line (median of ``--repeats``; a fresh interpreter each
time, so CasADi is not loaded: the checks come before any solve).  Then the in-process cost
of the checks on the shipped scenarios (``load_scenario`` with and without them), and of the
landing points of ``--end land``.

Prints a table, then one JSON line.  Usage::

    .venv/bin/python benchmarks/bench_mistakes.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import copy
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[1]
GCS = [sys.executable, "-m", "gcs.cli"]


def _mistakes() -> list[tuple[str, str, list[Any], Any]]:
    """(what, scenario, key path, new value)."""
    return [
        (
            "start inside a pole",
            "powerline_inspection.yaml",
            ["vehicles", "starts"],
            {"grid": {"min": [0, 0, 5], "max": [12, 4, 5], "shape": [4, 2, 1]}},
        ),
        (
            "start above the workspace",
            "reach_avoid.yaml",
            ["vehicles", "starts", "positions", 1],
            [1.5, -1.5, 2.5],
        ),
        (
            "starts break separation at t = 0",
            "reach_avoid.yaml",
            ["spec", 2, "formula"],
            "always[0, $horizon] dist(a, b) >= 5",
        ),
        (
            "target out of reach in time",
            "reach_avoid.yaml",
            ["spec", 0, "formula"],
            "eventually[0, 1] inside(d, goal)",
        ),
        (
            "nested intervals past the horizon",
            "reach_avoid.yaml",
            ["spec", 0, "formula"],
            "always[0, 3] eventually[0, 2] always[0, 2] inside(d, goal)",
        ),
        (
            "horizon not a whole number of segments",
            "reach_avoid.yaml",
            ["timing", "segment_s"],
            0.7,
        ),
    ]


def _edit(data: dict[str, Any], path: list[Any], value: Any) -> dict[str, Any]:
    out = copy.deepcopy(data)
    node = out
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for what, name, path, value in _mistakes():
            data = yaml.safe_load((REPO / "configs" / name).read_text(encoding="utf-8"))
            f = Path(tmp) / f"{len(rows)}.yaml"
            f.write_text(yaml.safe_dump(_edit(data, path, value)), encoding="utf-8")
            times, line, code = [], "", None
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                proc = subprocess.run(
                    [*GCS, "plan", str(f), "-o", str(Path(tmp) / "p.json")],
                    cwd=REPO,
                    capture_output=True,
                    text=True,
                    check=False,
                )
                times.append(time.perf_counter() - t0)
                code = proc.returncode
                lines = proc.stderr.strip().splitlines()
                line = lines[-1] if lines else ""
            rows.append(
                {
                    "mistake": what,
                    "exit": code,
                    "one_line": len(line) > 0 and "Traceback" not in line,
                    "median_s": statistics.median(times),
                    "line": line,
                }
            )
    from gcs.flight.landing import landing_points
    from planner import scenario
    from planner.planfile import load_plan

    cost = []
    for name in ("reach_avoid.yaml", "powerline_inspection.yaml"):
        for n in (2, 16) if name == "reach_avoid.yaml" else (4, 8):
            with_checks, without = [], []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                scenario.load_scenario(REPO / "configs" / name, vehicles=n)
                with_checks.append(time.perf_counter() - t0)
                saved = scenario.clause_findings, scenario.start_findings
                scenario.clause_findings = lambda *a: []  # type: ignore[assignment]
                scenario.start_findings = lambda *a: []  # type: ignore[assignment]
                try:
                    t0 = time.perf_counter()
                    scenario.load_scenario(REPO / "configs" / name, vehicles=n)
                    without.append(time.perf_counter() - t0)
                finally:
                    scenario.clause_findings, scenario.start_findings = saved
            cost.append(
                {
                    "scenario": name,
                    "vehicles": n,
                    "load_ms": 1e3 * statistics.median(with_checks),
                    "checks_ms": 1e3
                    * (statistics.median(with_checks) - statistics.median(without)),
                }
            )
    land_ms = None
    with tempfile.TemporaryDirectory() as tmp:
        plan_path = Path(tmp) / "pl.json"
        subprocess.run(
            [*GCS, "plan", "configs/powerline_inspection.yaml", "-o", str(plan_path)],
            cwd=REPO,
            capture_output=True,
            check=True,
        )
        plan = load_plan(plan_path)
        t0 = time.perf_counter()
        for _ in range(args.repeats):
            landing_points(plan)
        land_ms = 1e3 * (time.perf_counter() - t0) / args.repeats

    print(f"{'mistake':<40} {'exit':>4} {'one line':>8} {'time s':>7}  message")
    for r in rows:
        print(
            f"{r['mistake']:<40} {r['exit']:>4} {r['one_line']!s:>8} {r['median_s']:>7.2f}  {r['line'][:110]}"
        )
    print(f"{'scenario':<28} {'N':>3} {'load ms':>8} {'of it checks ms':>16}")
    for c in cost:
        print(
            f"{c['scenario']:<28} {c['vehicles']:>3} {c['load_ms']:>8.1f} {c['checks_ms']:>16.1f}"
        )
    print(f"landing points of the power-line plan (4 vehicles): {land_ms:.1f} ms")
    print(json.dumps({"bench": "mistakes", "rows": rows, "load_cost": cost, "landing_ms": land_ms}))


if __name__ == "__main__":
    main()
