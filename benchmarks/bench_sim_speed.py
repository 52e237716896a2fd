"""Dry runs faster than real time (issue 41): the same flight at speeds 1, 2, 4, 8.

Plans the power line (``configs/powerline_inspection.yaml``, 4 drones) once, then flies it with
``gcs fly --dry-run --speed K`` on the px4 mock (drag fed forward, as ``gcs fly`` does by
default) for each speed and ``--runs`` seeds. The flight runs on the mock's simulated clock, so
what must not change with the speed is the flight: the tracking rms and the best-fit lag per
vehicle (PX4 SITL's band for this flight: rms 0.26-0.68 m, lag 0.03-0.15 s,
``mavlink.mock.sim.calibration``), the flown robustness and the stream's lateness (simulated time).
What should change is the wall time. A datagram's way through MAVSDK (its own process, on the
wall clock) takes K times longer in simulated time, which is what limits K. Prints a table,
then one JSON line. Usage::

    .venv/bin/python benchmarks/bench_sim_speed.py [--speeds 1,2,4,8] [--runs 2]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gcs.cli import main as gcs  # noqa: E402


def run_json(argv: list[str]) -> tuple[int, dict]:  # type: ignore[type-arg]
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = gcs(argv)
    text = out.getvalue()
    return rc, json.loads(text) if text.strip() else {}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speeds", default="1,2,4,8")
    ap.add_argument("--runs", type=int, default=2, help="seeds per speed (2)")
    args = ap.parse_args()
    speeds = [float(s) for s in args.speeds.split(",")]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        plan = Path(tmp) / "powerline.json"
        rc, _ = run_json(
            ["plan", str(ROOT / "configs" / "powerline_inspection.yaml"), "-o", str(plan), "--json"]
        )
        assert rc == 0, "the power line did not plan"
        for speed in speeds:
            for seed in range(args.runs):
                t = time.perf_counter()
                argv = ["fly", str(plan), "--dry-run", "--json", "--seed", str(seed)]
                rc, res = run_json([*argv, "--speed", f"{speed:g}"])
                wall = time.perf_counter() - t
                tracking = res.get("tracking", [])
                stream = res.get("stream", {})
                row = {
                    "speed": speed,
                    "seed": seed,
                    "exit": rc,
                    "wall_s": round(wall, 1),
                    "flight_s": round(res.get("flight_s", float("nan")), 1),
                    "flown": res.get("flown_robustness"),
                    "rms_m": [round(tr["rms_m"], 3) for tr in tracking],
                    "lag_s": [round(tr["lag_s"], 3) for tr in tracking],
                    "late_max_ms": round(
                        1e3 * max((s["max_lateness_s"] for s in stream.values()), default=0.0), 1
                    ),
                }
                rows.append(row)
                print(f"  speed {speed:g} seed {seed}: {row['wall_s']} s", file=sys.stderr)
    print(
        "power line, 4 drones, px4 mock, drag fed forward; PX4 SITL band: rms 0.26-0.68 m, lag 0.03-0.15 s"
    )
    print(f"{'speed':>5} {'seed':>4} {'exit':>4} {'wall s':>7} {'flight s':>8} {'flown':>7} "
          f"{'rms m (min-max)':>16} {'lag s (min-max)':>16} {'late ms':>7}")  # fmt: skip
    for r in rows:
        flown = "-" if r["flown"] is None else f"{r['flown']:+.3f}"
        rms, lag = r["rms_m"] or [float("nan")], r["lag_s"] or [float("nan")]
        print(
            f"{r['speed']:>5g} {r['seed']:>4} {r['exit']:>4} {r['wall_s']:>7} {r['flight_s']:>8} "
            f"{flown:>7} {min(rms):>7.3f}-{max(rms):<8.3f} {min(lag):>7.3f}-{max(lag):<8.3f} "
            f"{r['late_max_ms']:>7}"
        )
    summary = {}
    for speed in speeds:
        mine = [r for r in rows if r["speed"] == speed]
        summary[f"{speed:g}"] = {
            "wall_s_median": statistics.median(r["wall_s"] for r in mine),
            "rms_m": [min(x for r in mine for x in r["rms_m"]), max(x for r in mine for x in r["rms_m"])],
            "lag_s": [min(x for r in mine for x in r["lag_s"]), max(x for r in mine for x in r["lag_s"])],
        }  # fmt: skip
    print(json.dumps({"bench": "sim_speed", "summary": summary, "runs": rows}))


if __name__ == "__main__":
    main()
