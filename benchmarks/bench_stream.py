"""Offboard streaming capacity and mission transfer time of the GCS link.

1. Streaming: the largest fleet one process streams at 50 Hz with p99 lateness
   <= 5 ms and no missed setpoint. Fleets of growing size connect through
   :class:`mavlink.link.fleet.Fleet` (one MAVSDK instance, one UDP connection per
   vehicle) to a sink process (``benchmarks/stream_sink.py``) that answers
   like N PX4 endpoints and counts every SET_POSITION_TARGET_LOCAL_NED it
   receives. Each vehicle streams a ramp of distinct setpoints for
   ``--seconds`` through :class:`mavlink.offboard.stream.SetpointStreamer` and MAVSDK's
   Offboard plugin (the path ``fly_offboard`` uses). A setpoint is missed if
   it was skipped, its send failed, or the sink did not receive it. CPU is
   the GCS process's CPU time (all threads, MAVSDK's included) over the
   stream, per vehicle per setpoint.
   Each size runs twice: all vehicles sent at the tick, and spread over one
   send instant per 16 vehicles (``SetpointStreamer(groups=...)``, each
   vehicle's setpoints sampled at its own send times), the default of
   ``fly_offboard``.
2. The same at 32 vehicles through ``mavsdk.asyncio``'s ``OffboardAsync``
   (every call through the default thread pool), to show why the link calls
   the native binding directly.
3. Mission: upload + read-back + item-by-item comparison of a 100-item
   mission to one mock vehicle (``mavlink.mock``) over loopback, repeated.
4. A real flight's load (``--flight-sizes``, ``--flight-rates``): the sink's vehicles also
   send LOCAL_POSITION_NED at 30 Hz (hovering on a grid), and the stream runs beside the
   safety monitor (:class:`mavlink.monitor.SafetyMonitor`, 20 Hz, 0.5 s prediction, the
   reach-avoid invariants of every vehicle and every pair: 2,080 clauses at N = 64) and the
   progress view (:class:`gcs.flight.progress.FlightProgress`, a terminal's 4 updates a second over
   every clause of the whole horizon), as ``gcs fly`` runs them. The same limits apply
   (p99 lateness <= 5 ms, no missed setpoint).
5. The monitor's decision latency at the largest flight size: mid-flight the sink moves
   one vehicle 5 cm from another; from the first datagram with that position to the
   sink receiving the hold command (``--latency-runs`` flights).

Prints a table, then one JSON line. Bounded: a few seconds per fleet size.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import logging
import math
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from mavsdk.asyncio import System as AsyncSystem
from mavsdk.asyncio.plugins.offboard import OffboardAsync
from mavsdk.plugins.offboard import AccelerationNed, PositionNedYaw, VelocityNedYaw

from gcs.flight.evaluation import plan_formula
from gcs.flight.progress import FlightProgress, PlanStarts
from mavlink.link.fleet import Fleet
from mavlink.link.vehicle_status import VehicleSpec
from mavlink.mission import MissionEnd, trajectory_to_mission, upload_and_verify
from mavlink.mock.fleet import MockFleet
from mavlink.monitor import SafetyMonitor
from mavlink.monitor_findings import always_clauses
from mavlink.offboard.setpoints import offboard_sender
from mavlink.offboard.stream import (
    VEHICLES_PER_GROUP,
    SetpointStreamer,
    StreamTarget,
    auto_send_groups,
)
from mavlink.plan_setpoints import NedSetpoints
from planner.frames import GeodeticPoint
from planner.planfile import Plan, load_plan
from planner.trajectory import Trajectory

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
from stream_sink import grid_ned  # noqa: E402  (the sink's hover grid)

#: Telemetry rate of the sink's vehicles in the monitored flights (PX4's API link: 30 Hz).
TELEMETRY_HZ = 30.0
#: A plan file whose regions, origin and margins the monitored flights borrow.
BASE_PLAN = HERE.parent / "tests" / "mavlink" / "data" / "reach_avoid_4.plan.json"


class _CountWarnings(logging.Handler):
    """Counts MAVSDK's own warnings and errors (forwarded to the ``mavlink.mavsdk`` logger)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.count = 0

    def emit(self, record: logging.LogRecord) -> None:
        self.count += 1


WARNINGS = _CountWarnings()
RATE_HZ = 50.0
P99_LIMIT_S = 0.005
ORIGIN = GeodeticPoint(47.397742, 8.545594, 488.0)


def free_udp_ports(k: int) -> list[int]:
    """``k`` UDP ports the OS just handed out (bound to port 0, then released)."""
    import socket

    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(k)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


class Sink:
    """The counting sink process."""

    def __init__(
        self, gcs_ports: list[int], vehicle_ports: list[int], telemetry_hz: float = 0.0
    ) -> None:
        self.proc = subprocess.Popen(
            [
                sys.executable,
                str(HERE / "stream_sink.py"),
                json.dumps(gcs_ports),
                json.dumps(vehicle_ports),
                str(telemetry_hz),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout is not None and self.proc.stdin is not None
        line = self.proc.stdout.readline().strip()
        if line != "ready":
            raise RuntimeError(f"sink did not start: {line!r}")

    def violate(self, i: int, j: int) -> None:
        """Move vehicle ``i`` 5 cm from vehicle ``j`` (0-based)."""
        assert self.proc.stdin is not None
        self.proc.stdin.write(f"violate {i} {j}\n")
        self.proc.stdin.flush()

    def report(self) -> dict[str, Any]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write("report\n")
        self.proc.stdin.flush()
        return json.loads(self.proc.stdout.readline())

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write("quit\n")
        self.proc.stdin.flush()
        self.proc.wait(timeout=10)


def ramp(i: int, n: int, rate_hz: float = RATE_HZ) -> NedSetpoints:
    """Distinct setpoints (1 mm apart) so the sink can tell them from MAVSDK's re-sends."""
    k = np.arange(n, dtype=float)
    pos = np.column_stack([k * 1e-3, np.full(n, float(i)), np.full(n, -2.0)])
    z = np.zeros((n, 3))
    return NedSetpoints(k / rate_hz, pos, z, z.copy(), np.zeros(n))


async def stream_fleet(
    n: int, seconds: float, use_asyncio_wrapper: bool = False, groups: int = 1
) -> dict:
    """Connect ``n`` sink endpoints, stream for ``seconds`` at 50 Hz, return the figures."""
    ports = free_udp_ports(2 * n)
    sink = Sink(ports[:n], ports[n:])
    try:
        specs = [VehicleSpec(f"v{i + 1}", f"udpin://127.0.0.1:{ports[i]}", i + 1) for i in range(n)]
        fleet = Fleet(specs, telemetry_rate_hz=None, connect_timeout_s=30.0)
        t_connect = time.perf_counter()
        await fleet.connect()
        connect_s = time.perf_counter() - t_connect
        try:
            ticks = round(seconds * RATE_HZ)
            if use_asyncio_wrapper:
                out = await _stream_async_wrapper(fleet, ticks)
            else:
                out = await _stream_native(fleet, ticks, groups)
            await asyncio.sleep(0.3)  # let the last datagrams arrive
            counts = sink.report()
        finally:
            fleet.close()
    finally:
        sink.close()
    sent = out["sent"]
    received_ok = all(d >= s for d, s in zip(counts["distinct"], sent, strict=True))
    out.update(
        n=n,
        connect_s=connect_s,
        ticks=ticks,
        received_min=min(counts["distinct"]),
        missed=int(sum(max(0, ticks - d) for d in counts["distinct"])),
        all_received=received_ok,
    )
    out["ok"] = bool(
        out["missed"] == 0
        and out["skipped"] == 0
        and out["failed"] == 0
        and out["p99_ms"] <= P99_LIMIT_S * 1e3
    )
    return out


async def _stream_native(fleet: Fleet, ticks: int, groups: int) -> dict:
    targets = [
        StreamTarget(v.name, offboard_sender(v.offboard), ramp(i, ticks))
        for i, v in enumerate(fleet.vehicles)
    ]
    streamer = SetpointStreamer(targets, RATE_HZ, groups=groups)
    c0 = time.process_time()
    stats = await streamer.run(time.monotonic() + 0.2)
    cpu_s = time.process_time() - c0
    lat = streamer.last_lateness
    lat = lat[~np.isnan(lat)]
    n = len(fleet)
    return {
        "path": f"native/{groups}" if groups > 1 else "native",
        "sent": [s.sent for s in stats.values()],
        "skipped": max(s.skipped for s in stats.values()),
        "failed": sum(s.failed for s in stats.values()),
        "p99_ms": float(np.percentile(lat, 99) * 1e3),
        "max_ms": float(lat.max() * 1e3),
        "mean_ms": float(lat.mean() * 1e3),
        "worst_vehicle_p99_ms": max(s.p99_lateness_s for s in stats.values()) * 1e3,
        "cpu_us_per_setpoint": cpu_s / (n * ticks) * 1e6,
    }


async def _stream_async_wrapper(fleet: Fleet, ticks: int) -> dict:
    """The same stream through mavsdk.asyncio's OffboardAsync (thread-pool per call)."""
    offs = [OffboardAsync(AsyncSystem(v.system)) for v in fleet.vehicles]
    setpoints = [ramp(i, ticks) for i in range(len(offs))]
    lat = np.full((ticks, len(offs)), np.nan)
    period = 1.0 / RATE_HZ
    t0 = time.monotonic() + 0.2
    skipped = 0
    c0 = time.process_time()

    async def one(j: int, k: int, deadline: float) -> None:
        p = setpoints[j].pos_ned_m[k]
        await offs[j].set_position_velocity_acceleration_ned(
            PositionNedYaw(*p, 0.0),
            VelocityNedYaw(0.0, 0.0, 0.0, 0.0),
            AccelerationNed(0.0, 0.0, 0.0),
        )
        lat[k, j] = time.monotonic() - deadline

    k = 0
    while k < ticks:
        deadline = t0 + k * period
        delay = deadline - time.monotonic()
        if delay > 0:
            await asyncio.sleep(delay)
        behind = int((time.monotonic() - deadline) // period)
        if behind >= 1:
            behind = min(behind, ticks - 1 - k)
            skipped += behind
            k += behind
            deadline = t0 + k * period
        await asyncio.gather(*(one(j, k, deadline) for j in range(len(offs))))
        k += 1
    cpu_s = time.process_time() - c0
    flat = lat[~np.isnan(lat)]
    for o in offs:
        o.destroy()
    return {
        "path": "mavsdk.asyncio",
        "sent": [int(np.count_nonzero(~np.isnan(lat[:, j]))) for j in range(len(offs))],
        "skipped": skipped,
        "failed": 0,
        "p99_ms": float(np.percentile(flat, 99) * 1e3),
        "max_ms": float(flat.max() * 1e3),
        "mean_ms": float(flat.mean() * 1e3),
        "worst_vehicle_p99_ms": float(np.nanmax(np.nanpercentile(lat, 99, axis=0)) * 1e3),
        "cpu_us_per_setpoint": cpu_s / (len(offs) * ticks) * 1e6,
    }


def hover_plan(n: int, horizon_s: float) -> Plan:
    """A plan of ``n`` vehicles hovering on the sink's grid, with the reach-avoid spec of
    every vehicle (reach the goal, avoid the obstacle, stay in the workspace) and pair
    (keep the plan's separation), on the regions of :data:`BASE_PLAN`."""
    base = load_plan(BASE_PLAN)
    h = f"{horizon_s:g}"
    vehicles, clauses = [], []
    for i in range(n):
        name = f"v{i + 1}"
        north, east, down = grid_ned(i, n)
        c = np.zeros((1, 3, 6))
        c[0, :, 0] = (east, north, -down)
        traj = Trajectory([0.0], [horizon_s], c, name=name)
        vehicles.append(
            dataclasses.replace(
                base.vehicles[0], name=name, sysid=i + 1, trajectory=traj,
                start_enu_m=(east, north, -down),
            )
        )  # fmt: skip
        clauses.append(f"eventually[0, {h}] inside({name}, goal)")
        clauses.append(f"always[0, {h}] (outside({name}, obstacle) and inside({name}, workspace))")
    for i in range(n):
        for j in range(i + 1, n):
            clauses.append(f"always[0, {h}] dist(v{i + 1}, v{j + 1}) >= {base.separation_m:g}")
    return dataclasses.replace(
        base, vehicles=tuple(vehicles), spec=" and ".join(f"({c})" for c in clauses),
        horizon_s=horizon_s,
    )  # fmt: skip


async def monitored_flight(
    n: int, rate_hz: float, seconds: float, violate_at_s: float | None = None
) -> dict:
    """Stream ``n`` vehicles at ``rate_hz`` for ``seconds`` with the safety monitor and the
    progress view running, as ``gcs fly`` does; optionally break a separation mid-flight."""
    import io

    ports = free_udp_ports(2 * n)
    sink = Sink(ports[:n], ports[n:], TELEMETRY_HZ)
    try:
        specs = [VehicleSpec(f"v{i + 1}", f"udpin://127.0.0.1:{ports[i]}", i + 1) for i in range(n)]
        fleet = Fleet(specs, telemetry_rate_hz=None, connect_timeout_s=30.0)
        await fleet.connect()
        try:
            plan = hover_plan(n, seconds + 2.0)
            names = [v.name for v in plan.vehicles]
            t_build = time.perf_counter()
            monitor = SafetyMonitor(always_clauses(plan_formula(plan), names), horizon_s=0.5)
            progress = FlightProgress(plan, io.StringIO(), tty=True)
            build_s = time.perf_counter() - t_build
            clock = PlanStarts()
            origins = dict.fromkeys(names, ORIGIN)
            trajs = {v.name: v.trajectory for v in plan.vehicles}
            ticks = round(seconds * rate_hz)
            targets = [
                StreamTarget(v.name, offboard_sender(v.offboard), ramp(i, ticks, rate_hz))
                for i, v in enumerate(fleet.vehicles)
            ]
            streamer = SetpointStreamer(targets, rate_hz, groups=auto_send_groups(n))
            t0 = time.monotonic() + 0.3
            clock.t0_monotonic_s.update(dict.fromkeys(names, t0))
            stop = asyncio.Event()
            mon_task = asyncio.create_task(
                monitor.run(
                    fleet, fleet.vehicles, t0_monotonic_s=t0, mission_origin=ORIGIN,
                    origins=origins, stop=stop, plans=trajs,
                )
            )  # fmt: skip
            view_task = asyncio.create_task(progress.run(fleet, clock, origins, stop))

            async def break_separation() -> None:
                await asyncio.sleep(max(0.0, t0 + float(violate_at_s or 0.0) - time.monotonic()))
                sink.violate(4, 5)

            breaker = asyncio.create_task(break_separation()) if violate_at_s else None
            c0 = time.process_time()
            stats = await streamer.run(t0, stop=stop)
            cpu_s = time.process_time() - c0
            stop.set()
            event = await mon_task
            await view_task
            if breaker is not None:
                await breaker
            await asyncio.sleep(0.3)
            counts = sink.report()
        finally:
            fleet.close()
    finally:
        sink.close()
    lat = streamer.last_lateness
    lat = lat[~np.isnan(lat)]
    ticks_ms = np.asarray(monitor.stats.tick_s) * 1e3
    sent = [s.sent for s in stats.values()]
    out = {
        "n": n,
        "rate_hz": rate_hz,
        "clauses": len(monitor.clauses),
        "templates": monitor._batch.templates,
        "build_s": build_s,
        "ticks": ticks,
        "missed": int(sum(max(0, ticks - d) for d in counts["distinct"])),
        "skipped": max(s.skipped for s in stats.values()),
        "failed": sum(s.failed for s in stats.values()),
        "p99_ms": float(np.percentile(lat, 99) * 1e3),
        "max_ms": float(lat.max() * 1e3),
        "monitor_checks": monitor.checks,
        "monitor_tick_ms_p50": float(np.percentile(ticks_ms, 50)) if ticks_ms.size else None,
        "monitor_tick_ms_max": float(ticks_ms.max()) if ticks_ms.size else None,
        "progress_updates": progress.lines,
        "cpu_us_per_setpoint": cpu_s / max(1, sum(sent)) * 1e6,
        "safety_event": None if event is None else event.describe(),
    }
    if violate_at_s is not None:
        out["stopped"] = event is not None
        v_t, c_t = counts.get("violated_t"), counts.get("command_t")
        out["latency_ms"] = None if v_t is None or c_t is None else (c_t - v_t) * 1e3
        out["decided_ms"] = (
            None if event is None or event.latency_s is None else event.latency_s * 1e3
        )
    else:
        out["ok"] = bool(
            out["missed"] == 0 and out["skipped"] == 0 and out["failed"] == 0
            and out["p99_ms"] <= P99_LIMIT_S * 1e3 and event is None
        )  # fmt: skip
    return out


def zigzag_trajectory(legs: int) -> Trajectory:
    """``legs`` rest-to-rest 1 s legs alternating east/north by 2 m, at 10 m height."""
    w = [np.array([0.0, 0.0, 10.0])]
    for j in range(legs):
        w.append(w[-1] + (np.array([2.0, 0.0, 0.0]) if j % 2 == 0 else np.array([0.0, 2.0, 0.0])))
    c = np.zeros((legs, 3, 6))
    for s in range(legs):
        d = w[s + 1] - w[s]
        c[s, :, 0], c[s, :, 3], c[s, :, 4], c[s, :, 5] = w[s], 10 * d, -15 * d, 6 * d
    return Trajectory(np.arange(legs, dtype=float), np.ones(legs), c, name="m1")


async def mission_transfer(repeats: int) -> dict:
    """Upload + verify a 100-item mission to one mock vehicle ``repeats`` times."""
    mp = trajectory_to_mission(zigzag_trajectory(49), ORIGIN, end=MissionEnd.HOLD)
    assert len(mp.items) == 100
    ports = free_udp_ports(2)
    mock = MockFleet(n=1, origin=ORIGIN, gcs_ports=ports[:1], vehicle_ports=ports[1:])
    fleet = Fleet([VehicleSpec("m1", f"udpin://127.0.0.1:{ports[0]}", 1)])
    async with mock, fleet:
        reports = [await upload_and_verify(fleet["m1"], mp.items) for _ in range(repeats)]
    up = [r.upload_s for r in reports]
    down = [r.download_s for r in reports]
    total = [a + b for a, b in zip(up, down, strict=True)]
    return {
        "items": len(mp.items),
        "repeats": repeats,
        "upload_s_median": statistics.median(up),
        "verify_s_median": statistics.median(down),
        "total_s_median": statistics.median(total),
        "total_s_max": max(total),
    }


async def idle_wakeups(ticks: int) -> dict:
    """Wake-up lateness of the event loop at 50 Hz with nothing to send: the machine's noise."""
    period = 1.0 / RATE_HZ
    t0 = time.monotonic() + 0.05
    lat = np.empty(ticks)
    for k in range(ticks):
        delay = t0 + k * period - time.monotonic()
        if delay > 0:
            await asyncio.sleep(delay)
        lat[k] = time.monotonic() - (t0 + k * period)
    return {"p99_ms": float(np.percentile(lat, 99) * 1e3), "max_ms": float(lat.max() * 1e3)}


async def best_of(attempts: int, n: int, seconds: float, groups: int) -> dict:
    """Run a configuration up to ``attempts`` times; the first passing run, else the best one."""
    runs = []
    for _ in range(attempts):
        r = await stream_fleet(n, seconds, groups=groups)
        runs.append(r)
        if r["ok"]:
            break
    best = min(runs, key=lambda r: (not r["ok"], r["p99_ms"]))
    best["attempts"] = len(runs)
    return best


async def main_async(args: argparse.Namespace) -> dict:
    idle = await idle_wakeups(round(args.seconds * RATE_HZ))
    print(
        f"{'idle loop':>14} {0:5d}   (no vehicles: event-loop wake-up lateness "
        f"p99 {idle['p99_ms']:.3f} ms, max {idle['max_ms']:.3f} ms)"
    )
    rows = []
    largest = {"native": 0, "grouped": 0}
    failing = {"native": 0, "grouped": 0}
    for n in [] if args.flight_only else args.sizes:
        for kind in ("native", "grouped"):
            groups = 1 if kind == "native" else auto_send_groups(n)
            if failing[kind] >= 2 or (kind == "grouped" and groups == 1):
                continue  # two sizes in a row past the limit / identical to the plain run
            r = await best_of(args.attempts, n, args.seconds, groups)
            r["kind"] = kind
            rows.append(r)
            _row(r)
            if r["ok"]:
                largest[kind] = n
                if kind == "native" and groups == 1 and auto_send_groups(n) == 1:
                    largest["grouped"] = n  # the same configuration
                failing[kind] = 0
            else:
                failing[kind] += 1
    wrapper = mission = None
    if not args.flight_only:
        wrapper = await stream_fleet(32, args.seconds, use_asyncio_wrapper=True)
        wrapper["attempts"] = 1
        _row(wrapper)
        mission = await mission_transfer(args.mission_repeats)
    flights, latency = await monitored_flights(args)
    return {
        "idle": idle,
        "streaming": rows,
        "asyncio_wrapper_32": wrapper,
        "largest": largest,
        "mission": mission,
        "flights": flights,
        "latency": latency,
    }


async def monitored_flights(args: argparse.Namespace) -> tuple[list[dict], list[dict]]:
    """Part 4 and 5 of the module docstring: the table rows, then the latency runs."""
    print(
        f"\nwith the safety monitor and the progress view (telemetry {TELEMETRY_HZ:g} Hz per "
        f"vehicle), {args.flight_seconds:g} s each, best of {args.attempts}"
    )
    print(
        f"{'n':>5} {'Hz':>4} {'clauses':>7} {'ticks':>6} {'missed':>6} {'p99 ms':>7} {'max ms':>7} "
        f"{'mon ms p50':>10} {'mon ms max':>10} {'checks':>6} {'views':>5}  result"
    )
    flights = []
    for n in args.flight_sizes:
        for rate in args.flight_rates:
            runs = []
            for _ in range(args.attempts):
                runs.append(await monitored_flight(n, rate, args.flight_seconds))
                if runs[-1]["ok"]:
                    break
            r = min(runs, key=lambda r: (not r["ok"], r["p99_ms"]))
            r["attempts"] = len(runs)
            flights.append(r)
            print(
                f"{n:5d} {rate:4g} {r['clauses']:7d} {r['ticks']:6d} {r['missed']:6d} "
                f"{r['p99_ms']:7.2f} {r['max_ms']:7.2f} {r['monitor_tick_ms_p50']:10.2f} "
                f"{r['monitor_tick_ms_max']:10.2f} {r['monitor_checks']:6d} "
                f"{r['progress_updates']:5d}  {'ok' if r['ok'] else 'FAIL'}"
                + (f" ({r['safety_event']})" if r["safety_event"] else ""),
                flush=True,
            )
    latency = []
    if args.latency_runs:
        n = max(args.flight_sizes)
        rate = max(args.flight_rates)
        for _ in range(args.latency_runs):
            latency.append(await monitored_flight(n, rate, 4.0, violate_at_s=2.0))
        ms = [r["latency_ms"] for r in latency if r["latency_ms"] is not None]
        dec = [r["decided_ms"] for r in latency if r["decided_ms"] is not None]
        print(
            f"decision latency at N = {n}, {rate:g} Hz: a separation broken mid-flight, "
            f"stopped in {sum(r['stopped'] for r in latency)} of {len(latency)}; "
            f"telemetry datagram to hold command {min(ms, default=math.nan):.0f}-"
            f"{max(ms, default=math.nan):.0f} ms (received telemetry to hold sent "
            f"{min(dec, default=math.nan):.0f}-{max(dec, default=math.nan):.0f} ms)"
        )
    return flights, latency


def _row(r: dict) -> None:
    print(
        f"{r['path']:>14} {r['n']:5d} {r['ticks']:6d} {min(r['sent']):6d} {r['received_min']:6d} "
        f"{r['skipped']:5d} {r['missed']:6d} {r['mean_ms']:8.3f} {r['p99_ms']:8.3f} {r['max_ms']:8.3f} "
        f"{r['cpu_us_per_setpoint']:8.1f} {r['connect_s']:7.2f} {r['attempts']:4d}  "
        f"{'ok' if r['ok'] else 'FAIL'}",
        flush=True,
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[8, 16, 32, 64, 96, 128, 160, 192])
    p.add_argument("--seconds", type=float, default=4.0)
    p.add_argument("--mission-repeats", type=int, default=5)
    p.add_argument(
        "--attempts",
        type=int,
        default=3,
        help="runs per configuration until one passes (the machine is shared: a run can be "
        "hit by another process; the table shows how many were needed)",
    )
    p.add_argument("--flight-sizes", type=int, nargs="*", default=[16, 32, 64])
    p.add_argument("--flight-rates", type=float, nargs="+", default=[20.0, 50.0])
    p.add_argument("--flight-seconds", type=float, default=6.0)
    p.add_argument("--latency-runs", type=int, default=5)
    p.add_argument(
        "--flight-only", action="store_true", help="only the monitored flights (parts 4 and 5)"
    )
    args = p.parse_args()
    mlog = logging.getLogger("mavlink.mavsdk")
    mlog.addHandler(WARNINGS)
    mlog.propagate = False
    print(
        f"offboard streaming at {RATE_HZ:g} Hz, criterion p99 lateness <= {P99_LIMIT_S * 1e3:g} ms, nothing missed"
    )
    print(
        f"{'path':>14} {'n':>5} {'ticks':>6} {'sent':>6} {'recv':>6} {'skip':>5} {'missed':>6} "
        f"{'mean ms':>8} {'p99 ms':>8} {'max ms':>8} {'cpu us':>8} {'conn s':>7} {'runs':>4}"
    )
    out = asyncio.run(main_async(args))
    m = out["mission"]
    if not args.flight_only:
        print(
            f"largest fleet streamed at {RATE_HZ:g} Hz within the criterion: "
            f"{out['largest']['native']} (all vehicles at the tick), "
            f"{out['largest']['grouped']} (one send instant per {VEHICLES_PER_GROUP} vehicles)"
        )
    print(f"MAVSDK warnings logged during the runs: {WARNINGS.count}")
    flight_keys = ("n", "rate_hz", "clauses", "missed", "p99_ms", "max_ms",
                   "monitor_tick_ms_p50", "monitor_tick_ms_max", "progress_updates", "ok")  # fmt: skip
    flights = {
        "monitored_flights": [{k: r[k] for k in flight_keys} for r in out["flights"]],
        "decision_latency_ms": [r["latency_ms"] for r in out["latency"]],
        "decision_latency_in_gcs_ms": [r["decided_ms"] for r in out["latency"]],
    }
    if m is None:
        print(json.dumps({"bench": "stream", **flights}))
        return 0
    print(
        f"mission of {m['items']} items, upload + read-back + compare over loopback (mock), "
        f"median of {m['repeats']}: upload {m['upload_s_median']:.3f} s, verify {m['verify_s_median']:.3f} s, "
        f"total {m['total_s_median']:.3f} s (max {m['total_s_max']:.3f} s)"
    )
    summary = {
        **flights,
        "bench": "stream",
        "rate_hz": RATE_HZ,
        "idle_wakeup_p99_ms": out["idle"]["p99_ms"],
        "largest_fleet_ok": out["largest"]["native"],
        "largest_fleet_ok_grouped": out["largest"]["grouped"],
        "mavsdk_warnings": WARNINGS.count,
        "streaming": [
            {
                k: r[k]
                for k in (
                    "path",
                    "n",
                    "ticks",
                    "missed",
                    "skipped",
                    "p99_ms",
                    "max_ms",
                    "cpu_us_per_setpoint",
                    "attempts",
                    "ok",
                )
            }
            for r in out["streaming"]
        ],
        "asyncio_wrapper_32": {
            k: out["asyncio_wrapper_32"][k]
            for k in ("missed", "skipped", "p99_ms", "max_ms", "cpu_us_per_setpoint", "ok")
        },
        "mission_100_items_s": m["total_s_median"],
        "mission_upload_s": m["upload_s_median"],
        "mission_verify_s": m["verify_s_median"],
    }
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
