"""Fault matrix of the GCS link against the mock (issue 8): the whole table.

Rows:

1. Mission upload + read-back (:func:`mavlink.mission.upload_and_verify`,
   MAVSDK mission_raw) of a 15-item plan under each link condition of
   ``tests.reliability.harness.CONDITIONS`` (loss 10/30/50 % up, down and
   both ways, duplication, reordering, 200 ms latency), ``--runs`` seeds each.
   A run is a success when the GCS reports success; every run is also judged
   on the vehicle's own stored copy: ``partial`` counts runs where the vehicle
   holds neither its previous mission nor exactly the plan, ``silent`` runs
   where the GCS said success but the vehicle does not hold the plan.
1b. The same upload retried as a whole (:func:`mavlink.mission.upload_with_retries`,
   60 s budget: upload, read back, compare, exponential back-off with jitter) at 30 %
   loss both ways and 50 % up or down, ``--retry-runs`` seeds each; the same
   ``partial`` and ``silent`` judgement on the vehicle's stored copy; ``tries`` is the
   most uploads a run took.
2. Offboard flight of the two-vehicle reach-avoid plan: 10 % setpoint loss with
   50 ms jitter (success: completed and flown robustness > 0); a 3 s outage
   and a 1.5 s outage (shorter than the 2 s link timeout, longer than PX4's
   1 s offboard-loss time); success: the GCS reports the event and streams
   nothing to a vehicle after its failsafe.
3. A vehicle that reboots on the ground (6 s without traffic) while the GCS is
   connected to it and another: success when the GCS shows it (only it)
   disconnected, a fleet Hold fails for it alone in bounded time, it comes
   back disarmed and answers, and its mission survived.
4. A vehicle that never answers: :class:`mavlink.link.fleet.Fleet` connect (success:
   ``ConnectTimeoutError`` naming it).
5. Connecting two vehicles whose links lose 30 % both ways from the start (discovery,
   first heartbeats, telemetry rates at 20 Hz), ``--retry-runs`` seeds; success: connected.

"worst s" is the worst wall time to complete or fail.  Prints a table, then one
JSON line.  Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_faults.py [--runs 5] [--flights 2]

(``--retry-runs 20``: seeds of the retried uploads and of the connect under loss.)
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from pathlib import Path

from mavlink.errors import ConnectTimeoutError
from mavlink.link.fleet import Fleet
from mavlink.link.vehicle_status import VehicleSpec
from mavlink.mission import RetryPolicy
from mavlink.mock import FaultConfig
from mavlink.mock.testing import free_udp_ports
from planner.planfile import load_plan

# the tests' helpers come from the repository, which need not be on the path
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.reliability.harness import (
    CONDITIONS,
    PLAN_PATH,
    connect_run,
    flight_run,
    mission_run,
    plan_items,
    reboot_run,
)

#: Conditions of the retried uploads (issue 17's targets) and the budget of each transfer.
RETRY_CONDITIONS = ("loss 30% both", "loss 50% up", "loss 50% down")
RETRY_BUDGET_S = 60.0


def mission_rows(runs: int) -> list[dict]:
    plan = load_plan(PLAN_PATH)
    items = plan_items(plan)
    other = plan_items(plan_second(plan))
    rows = []
    for name, faults in CONDITIONS.items():
        results = [
            asyncio.run(mission_run(name, faults, seed, items, plan.origin, previous=other))
            for seed in range(runs)
        ]
        errors = sorted({r.error.split(": ", 1)[-1] for r in results if not r.ok})
        rows.append(
            {
                "kind": "mission",
                "condition": name,
                "runs": runs,
                "successes": sum(r.ok for r in results),
                "partial": sum(r.partial_on_vehicle for r in results),
                "silent": sum(r.silent_partial for r in results),
                "worst_s": max(r.elapsed_s for r in results),
                "errors": errors,
            }
        )
        print_row(rows[-1])
    return rows


def retry_rows(runs: int) -> list[dict]:
    plan = load_plan(PLAN_PATH)
    items = plan_items(plan)
    other = plan_items(plan_second(plan))
    rows = []
    for name in RETRY_CONDITIONS:
        results = []
        for seed in range(runs):
            policy = RetryPolicy(budget_s=RETRY_BUDGET_S, seed=seed)
            results.append(
                asyncio.run(
                    mission_run(
                        name, CONDITIONS[name], seed, items, plan.origin, previous=other,
                        policy=policy,
                    )
                )
            )  # fmt: skip
        errors = sorted({r.error.split(": ", 1)[-1] for r in results if not r.ok})
        rows.append(
            {
                "kind": "mission retried",
                "condition": f"retried ({RETRY_BUDGET_S:g} s): {name}",
                "runs": runs,
                "items": len(items),
                "successes": sum(r.ok for r in results),
                "partial": sum(r.partial_on_vehicle for r in results),
                "silent": sum(r.silent_partial for r in results),
                "worst_s": max(r.elapsed_s for r in results),
                "attempts_max": max(r.attempts for r in results),
                "attempts_mean": sum(r.attempts for r in results) / runs,
                "errors": errors,
            }
        )
        print_row(rows[-1])
    return rows


def connect_rows(runs: int) -> list[dict]:
    name = "loss 30% both"
    results = [asyncio.run(connect_run(name, CONDITIONS[name], seed)) for seed in range(runs)]
    row = {
        "kind": "connect",
        "condition": f"connect 2 vehicles: {name}",
        "runs": runs,
        "successes": sum(r.ok for r in results),
        "worst_s": max(r.elapsed_s for r in results),
        "errors": sorted({r.error for r in results if not r.ok}),
    }
    print_row(row)
    return [row]


def plan_second(plan):  # type: ignore[no-untyped-def]
    """The plan with its vehicles swapped (its first vehicle's mission becomes d2's)."""
    import dataclasses

    return dataclasses.replace(plan, vehicles=plan.vehicles[::-1])


def flight_rows(runs: int) -> list[dict]:
    cases = [
        ("offboard: loss 10% + jitter 50 ms", FaultConfig(loss_to_vehicle=0.1, jitter_s=0.05), {}),
        ("offboard: 3 s outage", FaultConfig(), {"outage_after_start_s": 1.0, "outage_s": 3.0}),
        ("offboard: 1.5 s outage", FaultConfig(), {"outage_after_start_s": 1.0, "outage_s": 1.5}),
    ]
    rows = []
    for name, faults, kw in cases:
        results = [asyncio.run(flight_run(name, faults, seed, **kw)) for seed in range(runs)]
        if "outage" in name:
            ok = [
                (not r.completed) and r.verdict != "" and r.setpoints_after_failsafe[0] == 0
                for r in results
            ]
        else:
            ok = [r.completed and r.rho_flown > 0 for r in results]
        rows.append(
            {
                "kind": "flight",
                "condition": name,
                "runs": runs,
                "successes": sum(ok),
                "worst_s": max(r.elapsed_s for r in results),
                "rho_flown_min": min(r.rho_flown for r in results),
                "completed": sum(r.completed for r in results),
                "verdicts": sorted({r.verdict or "-" for r in results}),
                "failsafe_seen": sum(r.failsafe_seen[0] for r in results),
                "setpoints_after_failsafe_max": max(r.setpoints_after_failsafe[0] for r in results),
            }
        )
        print_row(rows[-1])
    return rows


def silent_rows(runs: int) -> list[dict]:
    times, ok = [], 0
    for _ in range(runs):
        (port,) = free_udp_ports(1)
        t0 = time.perf_counter()
        try:
            asyncio.run(
                Fleet(
                    [VehicleSpec("d1", f"udpin://127.0.0.1:{port}", 1)], connect_timeout_s=3.0
                ).connect()
            )
        except ConnectTimeoutError as exc:
            ok += str(exc).startswith("vehicle d1 (udpin://127.0.0.1:")
        times.append(time.perf_counter() - t0)
    row = {
        "kind": "silent",
        "condition": "never answers (connect, 3 s timeout)",
        "runs": runs,
        "successes": ok,
        "worst_s": max(times),
    }
    print_row(row)
    return [row]


def reboot_rows(runs: int) -> list[dict]:
    results = [asyncio.run(reboot_run(seed)) for seed in range(runs)]
    ok = [
        r.status_during == {"d1": False, "d2": True}
        and r.hold_failures == ("d1",)
        and r.back
        and r.mission_kept
        for r in results
    ]
    row = {
        "kind": "reboot",
        "condition": "reboot d1 (6 s silent) of 2",
        "runs": runs,
        "successes": sum(ok),
        "worst_s": max(r.elapsed_s for r in results),
        "worst_hold_s": max(r.hold_s for r in results),
    }
    print_row(row)
    return [row]


def print_row(r: dict) -> None:
    extra = ""
    if r["kind"] == "mission":
        extra = f"partial={r['partial']} silent={r['silent']} {'; '.join(r['errors'])}"
    elif r["kind"] == "mission retried":
        extra = (
            f"partial={r['partial']} silent={r['silent']} tries<={r['attempts_max']} "
            f"(mean {r['attempts_mean']:.1f}) {'; '.join(r['errors'])}"
        )
    elif r["kind"] == "connect":
        extra = "discovery, heartbeats, telemetry rates " + "; ".join(r["errors"])
    elif r["kind"] == "reboot":
        extra = f"fleet Hold with d1 silent: worst {r['worst_hold_s']:.2f} s (d1 fails, d2 held)"
    elif r["kind"] == "flight":
        extra = (
            f"completed={r['completed']} verdicts={','.join(r['verdicts'])} "
            f"rho_min={r['rho_flown_min']:.3f} failsafe={r['failsafe_seen']} "
            f"sp_after_failsafe={r['setpoints_after_failsafe_max']}"
        )
    print(
        f"{r['condition']:<40} {r['runs']:>4} {r['successes']:>9} {r['worst_s']:>8.2f}  {extra}",
        flush=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="seeds per mission condition")
    ap.add_argument("--flights", type=int, default=2, help="runs per flight condition")
    ap.add_argument(
        "--retry-runs",
        type=int,
        default=20,
        help="seeds per retried-upload condition and of the connect under loss",
    )
    args = ap.parse_args()
    print(f"{'condition':<40} {'runs':>4} {'successes':>9} {'worst s':>8}  notes")
    rows = (
        mission_rows(args.runs)
        + retry_rows(args.retry_runs)
        + flight_rows(args.flights)
        + reboot_rows(args.flights)
        + silent_rows(2)
        + connect_rows(args.retry_runs)
    )
    print(json.dumps({"bench": "faults", "rows": rows}))


if __name__ == "__main__":
    main()
