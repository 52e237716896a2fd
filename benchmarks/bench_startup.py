"""Start-up and plan-file reading: what a user waits for before a command does anything.

Each command is run ``--repeat`` times (default 5) as a fresh ``python -m gcs.cli`` process in
the current directory (so a checkout of another version, run from its own root, measures that
version), and the median wall time is printed:

* ``gcs --help`` (imports every command's module), ``gcs plan --help``, ``gcs verify --help``;
* ``gcs verify`` of the stored 4-vehicle plan (``tests/mavlink/data/reach_avoid_4.plan.json``);
* reading a long plan file in this process: that plan's vehicles twice over, each with 40
  times its samples (8 vehicles, 38,720 samples; ``planner.planfile.load_plan``), median of
  ``--repeat``.

Printed: a table, then one JSON line.

    .venv/bin/python benchmarks/bench_startup.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path.cwd()
PLAN = ROOT / "tests" / "mavlink" / "data" / "reach_avoid_4.plan.json"


def _wall(argv: list[str], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "gcs.cli", *argv], cwd=ROOT, check=False,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _long_plan(path: Path) -> int:
    data = json.loads(PLAN.read_text(encoding="utf-8"))
    for v in data["vehicles"]:
        for key in ("t", "pos", "vel", "acc", "yaw"):
            v[key] = v[key] * 40
    data["vehicles"] = data["vehicles"] * 2
    path.write_text(json.dumps(data), encoding="utf-8")
    return sum(len(v["t"]) for v in data["vehicles"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    rows = {
        "gcs --help": _wall(["--help"], args.repeat),
        "gcs plan --help": _wall(["plan", "--help"], args.repeat),
        "gcs verify --help": _wall(["verify", "--help"], args.repeat),
        "gcs verify (4 vehicles)": _wall(["verify", str(PLAN)], args.repeat),
    }
    sys.path.insert(0, str(ROOT))
    from planner.planfile import load_plan

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "long.plan.json"
        samples = _long_plan(path)
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            load_plan(path)
            times.append(time.perf_counter() - t0)
    rows[f"load_plan, 8 vehicles, {samples:,} samples"] = statistics.median(times)
    width = max(len(k) for k in rows)
    print(f"{'what':{width}}  median (s)")
    for k, v in rows.items():
        print(f"{k:{width}}  {v:8.3f}")
    print(json.dumps({"bench": "startup", "root": str(ROOT), "repeat": args.repeat,
                      "median_s": {k: round(v, 4) for k, v in rows.items()}}))  # fmt: skip


if __name__ == "__main__":
    main()
