"""Figures of the mock PX4 fleet (mavlink.mock).

0. Calibration of the ``px4`` profile against PX4 v1.17 SITL (SIH): the reach-avoid
   2-vehicle and power-line 4-vehicle plans flown offboard by ``gcs fly --dry-run``
   (``--seeds`` boots each), the best-fit lag and tracking rms side by side with PX4's
   figures (``mavlink.mock.sim.calibration``), flown by the ground station PX4 SITL was flown
   with (``--drag 0 --arrive 1``: no drag feed-forward, a 1 m start gate); reach-avoid's
   tracking with the ground-effect creep off and take-offs reached within 0.3 m (PX4's
   figures are of vehicles that flew), then drag-free, then the whole vehicle with today's
   ground station (refused, or how many flights end in a safety stop or below zero; 5 of 5
   failed on PX4); and ``gcs demo`` (power line, 4 vehicles, its default ``px4`` mock and
   today's ground station): planned against flown robustness.
1. Real-time capacity: N vehicles in this one process, pinned to one CPU core,
   telemetry at the default rates (LOCAL_POSITION_NED and ATTITUDE 50 Hz, ...),
   physics at 100 Hz, each vehicle sending to a bound (never read) GCS socket.
   For growing N it reports the real-time factor (simulated s / wall s), the CPU
   share of the core, and the datagrams sent per second; the capacity is the
   largest N whose real-time factor stays >= 0.99 with the simulation less than
   0.1 s behind its wall-clock deadlines at the end.
2. With a real client: 16 vehicles (``--client-vehicles``) flown by MAVSDK in a
   separate process (on another core when there is one): each armed and in
   offboard with MAVSDK streaming position setpoints at 20 Hz; the mock's
   real-time factor, CPU share and setpoints handled per second.
3. Mission upload: 200 MISSION_ITEM_INT from MAVSDK (mission_raw) to one mock
   vehicle over loopback, and the download back; median and best of repeats.

Prints a table, then one JSON line.  Usage::

    .venv/bin/python benchmarks/bench_mock.py [--seconds 4] [--max-vehicles 254] [--seeds 3]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mavlink.mock import MockFleet
from mavlink.mock.sim import calibration as px4
from mavlink.mock.testing import free_udp_ports

REPO = Path(__file__).resolve().parents[1]
GCS = [sys.executable, "-m", "gcs.cli"]


def _sinks(n: int) -> tuple[list[int], list[socket.socket]]:
    socks = []
    for _ in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.bind(("127.0.0.1", 0))
        socks.append(s)
    return [s.getsockname()[1] for s in socks], socks


async def _run_fleet(n: int, seconds: float, profile: str) -> dict[str, float]:
    gcs_ports, socks = _sinks(n)
    vehicle_ports = free_udp_ports(n)
    try:
        fleet = MockFleet(
            n=n, gcs_ports=gcs_ports, vehicle_ports=vehicle_ports, seed=1, profile=profile
        )
        async with fleet:
            await asyncio.sleep(0.5)  # warm-up
            sim0, wall0, cpu0 = fleet.time_s, time.perf_counter(), time.process_time()
            sent0 = sum(v.downlink.stats.offered for v in fleet.vehicles)
            await asyncio.sleep(seconds)
            sim1, wall1, cpu1 = fleet.time_s, time.perf_counter(), time.process_time()
            lag_s = fleet.wall_elapsed_s - fleet.time_s
            sent1 = sum(v.downlink.stats.offered for v in fleet.vehicles)
    finally:
        for s in socks:
            s.close()
    wall = wall1 - wall0
    return {
        "vehicles": n,
        "rtf": (sim1 - sim0) / wall,
        "cpu_share": (cpu1 - cpu0) / wall,
        "msgs_per_s": (sent1 - sent0) / wall,
        "lag_s": lag_s,
    }


async def _client(ports: list[int], seconds: float) -> None:
    """MAVSDK side of figure 2 (runs in its own process): fly every vehicle in offboard."""
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as sdk:
        for port in ports:
            await sdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        systems: dict[int, object] = {}
        while len(systems) < len(ports):
            systems = {await s.get_system_id(): s for s in await sdk.get_systems()}
            await asyncio.sleep(0.1)

        async def fly(sysid: int, system: object) -> OffboardAsync:
            telemetry, action, offboard = (
                TelemetryAsync(system),
                ActionAsync(system),
                OffboardAsync(system),
            )
            async for health in telemetry.subscribe_health():
                if health.is_armable:
                    break
            await offboard.set_position_ned(PositionNedYaw(2.0, 1.0 * sysid, -3.0, 0.0))
            await asyncio.sleep(1.2)
            await action.arm()
            await offboard.start()
            return offboard

        # keep the plugins alive: MAVSDK stops streaming when an Offboard object is destroyed
        plugins = await asyncio.gather(*(fly(i, s) for i, s in systems.items()))
        print("ready", flush=True)
        await asyncio.sleep(seconds)
        del plugins


async def _with_client(n: int, seconds: float) -> dict[str, float]:
    ports = free_udp_ports(2 * n)
    gcs_ports, vehicle_ports = ports[:n], ports[n:]
    async with MockFleet(n=n, gcs_ports=gcs_ports, vehicle_ports=vehicle_ports, seed=2) as fleet:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, __file__, "--client", ",".join(map(str, gcs_ports)),
            "--seconds", str(seconds + 30.0),
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.DEVNULL,
        )  # fmt: skip
        try:
            assert proc.stdout is not None

            async def ready() -> None:
                assert proc.stdout is not None
                while True:  # MAVSDK logs on stdout too
                    line = await proc.stdout.readline()
                    if not line:
                        raise RuntimeError("the MAVSDK client ended before its vehicles flew")
                    if line.strip() == b"ready":
                        return

            await asyncio.wait_for(ready(), 90.0)
            await asyncio.sleep(1.0)

            def setpoints() -> int:
                return sum(
                    v.received.get("SET_POSITION_TARGET_LOCAL_NED", 0) for v in fleet.vehicles
                )

            sim0, wall0, cpu0 = fleet.time_s, time.perf_counter(), time.process_time()
            sp0 = setpoints()
            sent0 = sum(v.downlink.stats.offered for v in fleet.vehicles)
            await asyncio.sleep(seconds)
            sim1, wall1, cpu1 = fleet.time_s, time.perf_counter(), time.process_time()
            sp1 = setpoints()
            sent1 = sum(v.downlink.stats.offered for v in fleet.vehicles)
            offboard = sum(v.mode.name == "OFFBOARD" and v.armed for v in fleet.vehicles)
            lag_s = fleet.wall_elapsed_s - fleet.time_s
        finally:
            proc.kill()
            await proc.wait()
    wall = wall1 - wall0
    return {
        "vehicles": n,
        "in_offboard": offboard,
        "rtf": (sim1 - sim0) / wall,
        "lag_s": lag_s,
        "cpu_share": (cpu1 - cpu0) / wall,
        "setpoints_per_s": (sp1 - sp0) / wall,
        "msgs_per_s": (sent1 - sent0) / wall,
    }


async def _upload(repeats: int, n_items: int) -> dict[str, float]:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.mission_raw import MissionItem, MissionRawAsync

    gcs_port, vehicle_port = free_udp_ports(2)
    items = [
        MissionItem(
            seq,
            6,
            16,
            int(seq == 0),
            1,
            0.0,
            0.0,
            0.0,
            float("nan"),
            473977420 + 50 * seq,
            85455940 + 70 * seq,
            10.0 + 0.01 * seq,
            0,
        )
        for seq in range(n_items)
    ]
    up, down = [], []
    async with MockFleet(n=1, gcs_ports=[gcs_port], vehicle_ports=[vehicle_port]):
        config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        async with Mavsdk(config) as sdk:
            await sdk.add_any_connection(f"udpin://127.0.0.1:{gcs_port}")
            system = await sdk.first_autopilot(timeout_s=10.0)
            if system is None:
                raise RuntimeError("MAVSDK did not discover the mock vehicle")
            mission = MissionRawAsync(system)
            for _ in range(repeats):
                t0 = time.perf_counter()
                await mission.upload_mission(items)
                up.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                back = await mission.download_mission()
                down.append(time.perf_counter() - t0)
                if len(back) != n_items:
                    raise RuntimeError(f"downloaded {len(back)} items, expected {n_items}")
    return {
        "items": n_items,
        "upload_median_s": statistics.median(up),
        "upload_best_s": min(up),
        "download_median_s": statistics.median(down),
        "download_best_s": min(down),
    }


def _gcs_json(args: list[str]) -> dict:  # type: ignore[type-arg]
    """Run ``gcs ARGS --json`` on every core (the capacity figures pin this process)."""
    cores = os.sched_getaffinity(0) | set(range(os.cpu_count() or 1))
    proc = subprocess.run(
        [*GCS, *args, "--json"], cwd=REPO, capture_output=True, text=True, check=False,
        preexec_fn=lambda: os.sched_setaffinity(0, cores),
    )  # fmt: skip
    if not proc.stdout.strip():  # refused before flying (exit 1 or 2): the reason
        lines = proc.stderr.strip().splitlines()
        return {"refused": lines[-1] if lines else f"exit {proc.returncode}", "tracking": []}
    return json.loads(proc.stdout)


#: the ground station PX4 SITL was flown with (commit 1bdb83b): no drag feed-forward, 1 m gate
THEN = ("--drag", "0", "--arrive", "1.0")


def _calibration(seeds: int) -> dict:  # type: ignore[type-arg]
    """Figure 0: fly the calibration plans on the px4 mock; rows of (what, mock, PX4)."""
    out: dict = {}  # type: ignore[type-arg]
    with tempfile.TemporaryDirectory() as tmp:
        plans = {}
        for name, scenario, n in (
            ("reach_avoid", "configs/reach_avoid.yaml", 2),
            ("powerline", "configs/powerline_inspection.yaml", 4),
        ):
            plans[name] = str(Path(tmp) / f"{name}.json")
            _gcs_json(["plan", scenario, "--vehicles", str(n), "-o", plans[name]])

        def runs(plan: str, *params: str, gcs: tuple[str, ...] = THEN) -> list[dict]:  # type: ignore[type-arg]  # fmt: skip
            res = []
            for seed in range(seeds):
                argv = ["fly", plan, "--dry-run", "--seed", str(seed), *gcs]
                for p in params:
                    argv += ["--mock-param", p]
                res.append(_gcs_json(argv))
            return res

        def spread(results: list[dict], key: str) -> list[float]:  # type: ignore[type-arg]
            return [t[key] for r in results for t in r["tracking"] if t[key] is not None]

        # PX4 SITL was flown by the ground station of then (no drag feed-forward, a 1 m start
        # gate: THEN); reach-avoid's tracking with the creep off and take-offs reached within
        # 0.3 m, so that the 0.75 m starts fly (PX4's figures are of vehicles that flew)
        low = ("MOCK_GE_RATE=0", "NAV_MC_ALT_RAD=0.3")
        ra = runs(plans["reach_avoid"], *low)
        free = runs(plans["reach_avoid"], *low, "SIH_KDV=0")
        whole = runs(plans["reach_avoid"], gcs=())  # today's ground station, whole vehicle
        pl = runs(plans["powerline"])
        pl_now = runs(plans["powerline"], gcs=())  # today's ground station: drag fed forward
        failed = sum(
            1 for r in whole
            if "refused" in r or r["safety_event"] or r["flown_robustness"] is None
            or r["flown_robustness"] < 0
        )  # fmt: skip
        out["rows"] = [
            (px4.REACH_AVOID_LAG, spread(ra, "lag_s")),
            (px4.REACH_AVOID_RMS, spread(ra, "rms_m")),
            (px4.DRAG_FREE_LAG, spread(free, "lag_s")),
            (px4.POWERLINE_LAG, spread(pl, "lag_s")),
            (px4.POWERLINE_RMS, spread(pl, "rms_m")),
            (px4.POWERLINE_FLOWN, [r["flown_robustness"] for r in pl if r.get("flown_robustness")]),
            (px4.POWERLINE_FF_LAG, spread(pl_now, "lag_s")),
            (px4.POWERLINE_FF_RMS, spread(pl_now, "rms_m")),
            (
                px4.POWERLINE_FF_FLOWN,
                [r["flown_robustness"] for r in pl_now if r.get("flown_robustness")],
            ),
        ]
        from gcs.flight.missions import convert_plan
        from mavlink.mission import MissionEnd
        from planner.planfile import load_plan

        pl_plan = load_plan(plans["powerline"])
        late = {
            r: convert_plan(pl_plan, end=MissionEnd.HOLD, iterations=1, acceptance_m=r).late_s
            for r in (1.0, 0.3)
        }
        out["rows"].append((px4.POWERLINE_MISSION_LATE, list(late[1.0].values())))
        out["missions_late_r03"] = list(late[0.3].values())
        out["reach_avoid_failed"] = (failed, len(whole))
        out["safety_stops"] = sum(1 for r in whole if r.get("safety_event"))
        demo_dir = Path(tmp) / "demo"
        proc = subprocess.run(
            [*GCS, "demo", "--out", str(demo_dir)], cwd=REPO, capture_output=True, text=True,
            check=False,
        )  # fmt: skip
        text = proc.stdout
        import re

        planned = re.search(r"planned robustness ([+-]\d+\.\d+)", text)
        flown = re.search(r"flown robustness ([+-]\d+\.\d+)", text)
        out["demo"] = {
            "planned": float(planned[1]) if planned else None,
            "flown": float(flown[1]) if flown else None,
            "exit": proc.returncode,
        }
    return out


def _print_calibration(cal: dict) -> None:  # type: ignore[type-arg]
    print("Calibration: px4 mock (gcs fly --dry-run) against PX4 v1.17 SITL with SIH")
    print(f"{'figure':<32} {'mock px4':>17} {'PX4 SITL':>15} {'band +-25%':>15}  in band")
    for fig, values in cal["rows"]:
        lo, hi = fig.band(px4.TOLERANCE)
        if fig is px4.DRAG_FREE_LAG:
            lo, hi = -0.2, 0.2
        inside = sum(1 for v in values if lo <= v <= hi)
        ok = bool(values) and inside == len(values)
        verdict = "yes" if ok else f"NO: {inside} of {len(values)} in"
        if fig is px4.POWERLINE_FLOWN:
            verdict = "(one PX4 flight: for information)"
        if fig is px4.POWERLINE_FF_FLOWN:
            verdict = "(for information)"
        mock = f"{min(values):+.2f}..{max(values):+.2f}" if values else "n/a"
        print(
            f"{fig.what:<32} {mock:>14} {fig.unit:<2} {fig.lo:+.2f}..{fig.hi:+.2f} "
            f"{lo:+.2f}..{hi:+.2f}  {verdict}"
        )
    r03 = cal["missions_late_r03"]
    print(
        f"power-line missions late with R 0.3 m: mock {min(r03):.1f}..{max(r03):.1f} s "
        "(quiet estimator); PX4 SITL: 18-35 s lost on one waypoint, 3 of 4 unfinished at 90 s"
    )
    failed, total = cal["reach_avoid_failed"]
    print(
        f"reach-avoid with the whole px4 vehicle, today's gcs: {failed} of {total} refused or "
        f"failed ({cal['safety_stops']} safety stops); PX4 SITL with the gcs of then: 5 of 5 "
        "failed (4 safety stops)"
    )
    d = cal["demo"]
    print(f"gcs demo (px4 profile): planned {d['planned']:+.4f}, flown {d['flown']:+.4f} "
          "(PX4 SITL, same plan: flown +0.3989)")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=4.0, help="measuring time per fleet size")
    ap.add_argument("--max-vehicles", type=int, default=254)
    ap.add_argument("--repeats", type=int, default=5, help="mission uploads to time")
    ap.add_argument("--items", type=int, default=200)
    ap.add_argument("--client-vehicles", type=int, default=16, help="vehicles of figure 2")
    ap.add_argument("--client", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--seeds", type=int, default=3, help="boots per calibration flight (0: skip)")
    ap.add_argument("--profiles", default="px4,ideal", help="profiles of the capacity figure")
    args = ap.parse_args()
    if args.client is not None:
        cores = sorted(os.sched_getaffinity(0))
        if len(cores) > 1:
            os.sched_setaffinity(0, set(cores[1:]))  # leave the mock's core to the mock
        asyncio.run(_client([int(p) for p in args.client.split(",")], args.seconds))
        return
    cal = None
    if args.seeds > 0:
        cal = _calibration(args.seeds)
        _print_calibration(cal)
    try:
        core = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {core})
        pinned = f"core {core}"
    except (AttributeError, OSError):
        pinned = "not pinned"

    sizes = [1, 4, 8, 16, 24, 32, 48, 64, 96, 128, 160, 192, 254]
    rows: dict[str, list[dict[str, float]]] = {}
    capacities: dict[str, int] = {}
    for profile in args.profiles.split(","):
        rows[profile] = []
        capacity = 0
        print(
            f"Mock fleet, {profile} profile, in one process ({pinned}), physics 100 Hz, "
            "default telemetry rates"
        )
        print(f"{'vehicles':>8} {'RTF':>7} {'lag s':>7} {'CPU':>6} {'msgs/s':>9}")
        for n in sizes:
            if n > args.max_vehicles:
                break
            row = asyncio.run(_run_fleet(n, args.seconds, profile))
            rows[profile].append(row)
            print(
                f"{n:>8} {row['rtf']:>7.3f} {row['lag_s']:>7.3f} {row['cpu_share']:>6.0%} "
                f"{row['msgs_per_s']:>9.0f}"
            )
            # real time: the window kept pace and the simulation is not behind its deadlines
            if row["rtf"] >= 0.99 and row["lag_s"] < 0.1:
                capacity = n
            else:
                break
        capacities[profile] = capacity
        print(
            f"real-time capacity ({profile}): {capacity} vehicles "
            "(largest N with RTF >= 0.99, lag < 0.1 s)"
        )

    cl = asyncio.run(_with_client(args.client_vehicles, args.seconds))
    print(
        f"{cl['vehicles']} vehicles flown by MAVSDK (separate process), {cl['in_offboard']} in "
        f"offboard: RTF {cl['rtf']:.3f}, lag {cl['lag_s']:.3f} s, CPU {cl['cpu_share']:.0%}, "
        f"{cl['setpoints_per_s']:.0f} setpoints/s in, {cl['msgs_per_s']:.0f} msgs/s out"
    )

    up = asyncio.run(_upload(args.repeats, args.items))
    print(
        f"MAVSDK mission_raw {up['items']} items: upload median {up['upload_median_s'] * 1e3:.0f} ms "
        f"(best {up['upload_best_s'] * 1e3:.0f} ms), download median "
        f"{up['download_median_s'] * 1e3:.0f} ms (best {up['download_best_s'] * 1e3:.0f} ms)"
    )
    print(
        json.dumps(
            {
                "bench": "mock",
                "pinned": pinned,
                "realtime_capacity_vehicles": capacities,
                "rows": {
                    p: [{k: round(v, 4) for k, v in r.items()} for r in rs]
                    for p, rs in rows.items()
                },
                "calibration": None
                if cal is None
                else {
                    "figures": [
                        {
                            "what": f.what,
                            "px4": [f.lo, f.hi],
                            "mock": [min(v), max(v)] if v else None,
                        }
                        for f, v in cal["rows"]
                    ],
                    "reach_avoid_failed": list(cal["reach_avoid_failed"]),
                    "missions_late_r03_s": cal["missions_late_r03"],
                    "demo": cal["demo"],
                },
                "with_mavsdk": {k: round(v, 4) for k, v in cl.items()},
                "mission": {k: round(v, 4) for k, v in up.items()},
            }
        )
    )


if __name__ == "__main__":
    main()
