"""``gcs upload --start`` on the power line (issue 42): missions released together, flown on board.

Plans the shipped power line (4 vehicles), then for ``--runs`` seeds starts px4 mock vehicles on
the ground below the starts (in a thread of this process, at ``--speed``), runs ``gcs upload
--start --json`` against them, and once the command has left, records the
vehicles' *true* positions until the plan's horizon is covered from the release it reported
(the median of the instants the vehicles entered AUTO.MISSION on the mock's clock, printed
beside the command's own ``t0_unix_s``). The spec is judged on those positions with the exact
semantics (:func:`gcs.flight.evaluation.evaluate_flight`): the flown robustness beside the
predicted one, the weakest clause, and each vehicle's entry into AUTO.MISSION against the
median (the release's skew). Without ``--force`` this version refuses the power line's start
(its d1-d2 separation tolerates 0.14 s of timing error, PX4 keeps about 0.5 s): the first
boot shows the refusal, and the flights are made with ``--force`` to measure what the
interlock guards against. Prints a table, then one JSON line. Usage::

    .venv/bin/python benchmarks/bench_upload_start.py [--runs 4] [--speed 4]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gcs.cli import main as gcs  # noqa: E402


def fly_one(plan_path: Path, seed: int, speed: float, force: bool) -> dict:  # type: ignore[type-arg]
    """One boot: upload --start, the truth recorded to the horizon, the spec judged."""
    from gcs.flight.dryrun import free_udp_ports
    from gcs.flight.evaluation import evaluate_flight
    from mavlink.mock.fleet import MockFleet
    from mavlink.mock.sim.px4 import Px4Mode
    from mavlink.tracks import FlownTrack
    from planner.planfile import load_plan

    plan = load_plan(plan_path)
    n = len(plan.vehicles)
    ports = free_udp_ports(2 * n)
    fleet = MockFleet(
        speed=speed, n=n, origin=plan.origin, spawns_enu_m=plan.ground_spawns(),
        gcs_ports=ports[:n], vehicle_ports=ports[n:], profile="px4", seed=seed,
    )  # fmt: skip
    rows: list[tuple[float, np.ndarray, list[Px4Mode]]] = []
    stop = threading.Event()

    def sample() -> None:
        last = -1.0
        while not stop.is_set():
            t = fleet.time_s
            if t > last:
                modes = [v.mode for v in fleet.vehicles]
                rows.append((t, fleet.physics.true_pos_ned_m.copy(), modes))
                last = t
            time.sleep(0.005)

    with fleet.running_in_thread():
        recorder = threading.Thread(target=sample, daemon=True)
        recorder.start()
        argv = ["upload", str(plan_path), "--start", "--json", *(["--force"] if force else [])]
        for p in ports[:n]:
            argv += ["--connection", f"udpin://127.0.0.1:{p}"]
        out, err = io.StringIO(), io.StringIO()
        t_wall = time.perf_counter()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = gcs(argv)
        wall_s = time.perf_counter() - t_wall
        res = json.loads(out.getvalue()) if out.getvalue().strip().startswith("{") else {}
        entered = []
        for j in range(n):
            entered.append(next((t for t, _, m in rows if m[j] is Px4Mode.AUTO_MISSION), None))
        t0 = float(np.median([t for t in entered if t is not None])) if all(entered) else None
        if t0 is not None:
            while fleet.time_s < t0 + plan.horizon_s + 0.5:
                time.sleep(0.05)
        stop.set()
        recorder.join()
    row = {
        "seed": seed,
        "force": force,
        "rc": rc,
        "command_s": round(wall_s, 1),
        "started": [v.get("started") for v in res.get("vehicles", [])],
        "predicted": res.get("predicted_mission_robustness"),
        "flown": None,
        "weakest": None,
        "skew_ms": None,
    }
    if t0 is None:
        row["error"] = [x for x in err.getvalue().splitlines() if x.strip()][-1:]
        return row
    t = np.array([r[0] for r in rows]) - t0
    keep = t >= -0.5
    enu = fleet.spawn_ned_to_enu(np.stack([r[1] for r in rows])[keep])
    tracks = {
        v.name: FlownTrack(v.name, t[keep], enu[:, j], np.zeros_like(enu[:, j]), None, None)
        for j, v in enumerate(plan.vehicles)
    }
    ev = evaluate_flight(plan, tracks)
    worst = min((c for c in ev.clauses if c.flown is not None), key=lambda c: c.flown)
    row.update(
        flown=ev.flown_robustness,
        weakest=worst.text,
        skew_ms=[round(1000 * (e - t0)) for e in entered if e is not None],
    )
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=4)
    ap.add_argument("--speed", type=float, default=4.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        plan_path = Path(tmp) / "powerline.json"
        scenario = ROOT / "configs" / "powerline_inspection.yaml"
        with contextlib.redirect_stdout(io.StringIO()):
            rc = gcs(["plan", str(scenario), "--vehicles", "4", "-o", str(plan_path), "--json"])
        if rc != 0:
            sys.exit(f"planning the power line failed (exit {rc})")
        refused = fly_one(plan_path, 0, args.speed, force=False)
        print(f"  without --force: {refused}", file=sys.stderr, flush=True)
        rows = []
        for seed in range(args.runs):
            row = fly_one(plan_path, seed, args.speed, force=True)
            rows.append(row)
            print(f"  seed {seed}: {row}", file=sys.stderr, flush=True)
    why = (refused.get("error") or [""])[0]
    print(f"without --force: exit {refused['rc']}: {why[:200]}")
    print(
        f"{'seed':>4} {'exit':>4} {'cmd s':>6} {'predicted':>9} {'flown':>8} {'skew ms':>16}  weakest"
    )
    for r in rows:
        pred = "-" if r["predicted"] is None else f"{r['predicted']:+.3f}"
        flown = "-" if r["flown"] is None else f"{r['flown']:+.3f}"
        skew = "-" if r["skew_ms"] is None else ",".join(str(s) for s in r["skew_ms"])
        print(
            f"{r['seed']:>4} {r['rc']:>4} {r['command_s']:>6} {pred:>9} {flown:>8} {skew:>16}  {r['weakest'] or r.get('error')}"
        )
    flown = [r["flown"] for r in rows if r["flown"] is not None]
    print(
        json.dumps(
            {
                "bench": "upload_start",
                "without_force": refused,
                "runs": rows,
                "positive": sum(1 for f in flown if f > 0),
                "flown": len(flown),
                "speed": args.speed,
            }
        )
    )


if __name__ == "__main__":
    main()
