"""Figures of ``gcs assess`` (issue 22): runs per second, Ray scaling, P(spec holds) against
wind, the safety monitor, and (``--agreement N``) agreement with the real-time mock.

    .venv/bin/python benchmarks/bench_assess.py [--runs 10000] [--wind-runs 500] [--agreement 0]

1. the 4-drone power-line plan (planned here), ``--runs`` runs in one process (``workers=0``)
   and on a local 2-worker Ray cluster started here (two ``ray start`` processes on loopback,
   one CPU each): wall time, runs/s, the real-time ratio (simulated flight seconds per wall
   second) and the overhead per task;
2. P(spec holds) with its 95 % Clopper-Pearson interval at 0, 3, 6, 9 m/s mean wind (any
   direction, the other disturbances at their calm-day defaults) for the power-line and the
   reach-avoid plans;
3. the safety monitor (``--monitor``) on the power-line plan in wind of 0-9 m/s: its cost,
   how often it stops the flight and whether the stops were needed;
4. with ``--agreement N``: N runs with deterministic disturbances (wind, setpoint latency,
   derating; no noise) flown in the simulator and on the real-time mock
   (``--replay --realtime``): median and worst |difference| of the flown (reported)
   robustness.

Prints a table and one JSON line.  Ray's processes are stopped at the end (``ray stop``).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from gcs.assess import AssessOptions, assess, replay
from gcs.assess.rerun import fly_realtime
from planner.optimize import plan as make_plan
from planner.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
RAY = str(Path(sys.executable).with_name("ray"))
QUIET = {"gust_m_s": "0", "estimator": "0", "ekf_origin": "0", "start_error_m": "0",
         "latency_s": "0", "jitter_s": "0", "loss": "0"}  # fmt: skip


def _plan(name: str, vehicles: int):  # type: ignore[no-untyped-def]
    result = make_plan(load_scenario(ROOT / "configs" / name, vehicles=vehicles))
    return result.to_plan()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _cluster() -> str:
    # Ray >= 2.5x starts a head with token authentication: the joining node and the driver
    # find the head's token (~/.ray/auth_token) only in token mode
    os.environ["RAY_AUTH_MODE"] = "token"
    port = _free_port()
    subprocess.run([RAY, "start", "--head", "--node-ip-address=127.0.0.1", f"--port={port}",
                    "--num-cpus=1", "--include-dashboard=false", "--disable-usage-stats"],
                   check=True, capture_output=True)  # fmt: skip
    address = f"127.0.0.1:{port}"
    subprocess.run([RAY, "start", f"--address={address}", "--node-ip-address=127.0.0.1",
                    "--num-cpus=1", "--disable-usage-stats"], check=True, capture_output=True)  # fmt: skip
    return address


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--wind-runs", type=int, default=500)
    ap.add_argument("--agreement", type=int, default=0)
    args = ap.parse_args()
    pl = _plan("powerline_inspection.yaml", 4)
    ra = _plan("reach_avoid.yaml", 2)
    flight_s = pl.horizon_s + 3.0  # the settling before the plan
    rows, out = [], {}

    one = assess(pl, AssessOptions(runs=args.runs, workers=0, batch_size=500))
    rows.append(("one process", one))
    subprocess.run([RAY, "stop", "--force"], capture_output=True)
    address = _cluster()
    try:
        two = assess(pl, AssessOptions(runs=args.runs, ray_address=address, batch_size=500))
        rows.append(("Ray cluster, 2 workers", two))
        print(f"{'power-line, 4 drones':28s} {'runs':>6s} {'wall s':>7s} {'runs/s':>7s} "
              f"{'x real time':>11s} {'P(holds)':>8s}")  # fmt: skip
        for label, r in rows:
            print(f"{label:28s} {r.runs:6d} {r.elapsed_s:7.1f} {r.runs_per_s:7.0f} "
                  f"{r.runs * flight_s / r.elapsed_s:11.0f} {r.p:8.3f}")  # fmt: skip
        tasks = -(-args.runs // 500)
        overhead = (two.elapsed_s * 2 - two.sim_s) / tasks
        print(f"speed-up on 2 workers: {one.elapsed_s / two.elapsed_s:.2f}; overhead per task "
              f"(500 runs): {overhead:.2f} s; identical statistics: "
              f"{one.p == two.p and one.quantiles == two.quantiles}")  # fmt: skip
        out.update(
            runs=args.runs,
            one_process_s=one.elapsed_s,
            ray2_s=two.elapsed_s,
            runs_per_s_one=one.runs_per_s,
            runs_per_s_ray2=two.runs_per_s,
            real_time_ratio_ray2=args.runs * flight_s / two.elapsed_s,
            speedup=one.elapsed_s / two.elapsed_s,
            overhead_per_task_s=overhead,
            identical=bool(one.p == two.p and one.quantiles == two.quantiles),
            p_calm_day=one.p,
        )
        print(f"\n{'plan':12s} {'wind m/s':>8s} {'P(holds)':>9s} {'95 % CI':>16s} "
              f"{'median rho':>10s} {'P reported':>10s}")  # fmt: skip
        table = []
        for name, plan in (("power-line", pl), ("reach-avoid", ra)):
            for wind in (0, 3, 6, 9):
                r = assess(plan, AssessOptions(runs=args.wind_runs, ray_address=address,
                                               batch_size=250,
                                               disturbances={"wind_m_s": str(wind)}))  # fmt: skip
                print(f"{name:12s} {wind:8d} {r.p:9.3f} [{r.ci[0]:.3f}, {r.ci[1]:.3f}] "
                      f"{r.quantiles['p50']:+10.3f} {r.p_reported:10.3f}")  # fmt: skip
                table.append({"plan": name, "wind_m_s": wind, "p": r.p, "ci": r.ci,
                              "median": r.quantiles["p50"], "p_reported": r.p_reported})  # fmt: skip
        out["wind_table"] = table
        # the safety monitor: each run flown again under it (same draws)
        m_runs = max(500, args.runs // 5)
        mon = assess(pl, AssessOptions(runs=m_runs, ray_address=address, batch_size=250,
                                       monitor=True, disturbances={"wind_m_s": "uniform(0, 9)"}))  # fmt: skip
        ref = assess(pl, AssessOptions(runs=m_runs, ray_address=address, batch_size=250,
                                       disturbances={"wind_m_s": "uniform(0, 9)"}))  # fmt: skip
        m = mon.monitor
        assert m is not None
        print(f"\n--monitor, power-line, wind 0-9 m/s, {m_runs} runs: {mon.runs_per_s:.0f} runs/s "
              f"({mon.elapsed_s / ref.elapsed_s:.2f} x the time without)")  # fmt: skip
        print(f"  P(stop) {m.p_stop:.3f} [{m.ci_stop[0]:.3f}, {m.ci_stop[1]:.3f}]; stops needed "
              f"{m.needed}, spurious {m.spurious}; always-clauses held {m.safe_monitored} "
              f"(without: {m.safe}); P(holds) {m.p:.3f} (without: {mon.p:.3f})")  # fmt: skip
        for why, k in m.reasons[:4]:
            print(f"  {k:6d}  {why[:90]}")
        out["monitor"] = {"runs": m_runs, "runs_per_s": mon.runs_per_s,
                          "time_ratio": mon.elapsed_s / ref.elapsed_s, **m.as_json(mon.clauses)}  # fmt: skip
    finally:
        subprocess.run([RAY, "stop", "--force"], capture_output=True)
    if args.agreement:
        diffs = []
        for k in range(args.agreement):
            # the deterministic disturbances (as tests/gcs/test_assess_agreement.py)
            dist = dict(QUIET, wind_m_s="uniform(0, 4)", latency_s="uniform(0.005, 0.05)",
                        derate="uniform(0.8, 1)")  # fmt: skip
            opts = AssessOptions(runs=1, workers=0, disturbances=dist)
            seed = 1000 + k
            flights = replay(pl, opts, seed)
            from gcs.assess import evaluate_batch

            sim = float(evaluate_batch(pl, flights)[1][0])
            outcome = fly_realtime(pl, opts, flights, seed=seed)
            ev = outcome.evaluation
            real = None if ev is None else ev.flown_robustness
            if real is not None:
                diffs.append(abs(sim - real))
            print(f"agreement seed {seed}: simulator {sim:+.3f}, real-time mock {real}")
        if diffs:
            print(f"agreement: median |diff| {np.median(diffs):.3f} m, worst {max(diffs):.3f} m")
            out.update(agreement_median_m=float(np.median(diffs)), agreement_worst_m=max(diffs))
    print(json.dumps({"bench": "assess", **out}))


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"bench time {time.perf_counter() - t0:.0f} s", file=sys.stderr)
