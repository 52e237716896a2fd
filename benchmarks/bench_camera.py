"""Pictures per inspection target and coverage on the mock: the 10-pole line along a bearing of
37 degrees, three drones, each facing its poles while it hovers in their inspection boxes
(configs/powerline_line10_camera.yaml; issue 21's figure).

Plans the scenario once (``gcs plan --json``), then flies the plan on mock PX4 vehicles with a
MAVLink camera and gimbal (``gcs fly --dry-run --json --log DIR``), offboard and as PX4
missions (with ``--force``: PX4 is predicted to fly this plan's missions below epsilon, which ``gcs fly``
refuses otherwise; the prediction is printed), with the default ``px4`` profile.  Per flight mode and target: the pictures that count
(taken from within the inspection place, view within face's 15 degrees) against those planned,
their range and largest view angle; per mode the targets covered, the pictures taken and the
flown robustness.  The coverage figures are ``DIR/{offboard,mission}/coverage.png``.  Printed: a
table, then one JSON line.

    .venv/bin/python benchmarks/bench_camera.py [--out DIR] [--modes offboard mission]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
GCS = str(Path(sys.executable).with_name("gcs"))
SCENARIO = ROOT / "configs" / "powerline_line10_camera.yaml"


def _run(argv: list[str]) -> tuple[int, dict[str, Any], float]:
    t0 = time.monotonic()
    proc = subprocess.run(argv, capture_output=True, text=True, check=False)
    wall = time.monotonic() - t0
    try:
        data = json.loads(proc.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        sys.stderr.write(proc.stderr[-2000:])
        raise SystemExit(f"{argv[1]}: no JSON result (exit {proc.returncode})") from None
    return proc.returncode, data, wall


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="directory for the plan and the flights' logs")
    ap.add_argument("--modes", nargs="+", default=["offboard", "mission"])
    ap.add_argument("--seed", type=int, default=0, help="mock vehicles' seed")
    args = ap.parse_args(argv)
    out_dir = args.out or Path(tempfile.mkdtemp(prefix="bench_camera_"))
    out_dir.mkdir(parents=True, exist_ok=True)
    plan = out_dir / "line10_camera.plan.json"
    rc, planned, plan_s = _run([GCS, "plan", str(SCENARIO), "-o", str(plan), "--json"])
    if rc != 0:
        raise SystemExit(f"gcs plan failed (exit {rc})")
    result: dict[str, Any] = {
        "bench": "camera",
        "scenario": SCENARIO.name,
        "plan_s": round(plan_s, 2),
        "planned_robustness": planned.get("robustness"),
        "modes": {},
    }
    print(f"plan: {SCENARIO.name}, robustness {planned.get('robustness'):+.3f}, {plan_s:.1f} s")
    header = (
        f"{'mode':<9} {'target':<8} {'pictures':>8} {'planned':>8} {'range m':>11} "
        f"{'view deg':>9} {'by':>4}"
    )
    print(header)
    ok = True
    for mode in args.modes:
        log = out_dir / mode
        # a mission PX4 is predicted to fly late is refused without --force: flown anyway
        # here, the prediction printed beside the pictures
        force = ["--force"] if mode == "mission" else []
        rc, res, wall = _run(
            [GCS, "fly", str(plan), "--dry-run", "--mode", mode, "--json", "--log", str(log),
             "--seed", str(args.seed), *force]
        )  # fmt: skip
        cov = res.get("coverage") or {}
        for t in cov.get("by_target", []):
            rng = t["range_m"]
            rng_txt = "-" if rng is None else f"{rng[0]:.2f}-{rng[1]:.2f}"
            view = "-" if t["view_deg"] is None else f"{t['view_deg']:.1f}"
            print(
                f"{mode:<9} {t['target']:<8} {t['images']:>8} {t['planned']!s:>8} "
                f"{rng_txt:>11} {view:>9} {','.join(t['vehicles']):>4}"
            )
        covered = cov.get("covered", 0)
        targets = cov.get("targets", 0)
        flown = res.get("flown_robustness")
        pred = (res.get("mission_prediction") or {}).get("predicted_robustness")
        if pred is not None:
            late = max((m.get("late_s") or 0.0) for m in res.get("missions", {}).values())
            print(
                f"{mode:<9} PX4 predicted to fly the missions to {pred:+.3f} (flown with "
                f"--force); the latest finished {late:+.1f} s against the plan"
            )
        print(
            f"{mode:<9} covered {covered}/{targets} targets, {cov.get('images', 0)} pictures "
            f"({cov.get('unmatched', 0)} of no target), flown robustness "
            f"{'n/a' if flown is None else f'{flown:+.3f}'}, exit {rc}, {wall:.0f} s; figure "
            f"{log / 'coverage.png'}"
        )
        result["modes"][mode] = {
            "exit": rc,
            "wall_s": round(wall, 1),
            "flown_robustness": flown,
            "completed": res.get("completed"),
            "coverage": cov,
            "camera_refused": res.get("camera_refused"),
            "predicted_robustness": pred,
        }
        ok &= targets > 0 and covered == targets and res.get("completed") is True
    print(json.dumps(result))
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
