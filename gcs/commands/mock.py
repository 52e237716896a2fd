"""``gcs mock``: run N mock PX4 vehicles (mavlink.mock) until Ctrl-C.

Vehicle ``i`` has system id ``i + 1``, listens on ``--vehicle-base-port + i``
(default ``--base-port + 40``, i.e. 14580 + i) and sends to ``--base-port + i``
on ``--gcs-host`` (14540 + i), as PX4 SITL does.  Spawn points come from
``--spawn`` (mission ENU metres relative to ``--origin``) or from the vehicle
starts and origin of ``--scenario``.  ``--profile`` chooses the vehicle: ``px4``
(the default: PX4 v1.17 SITL with SIH, whose EKF origin and home are a noisy first
GPS fix near the spawn, different for every ``--seed``) or ``ideal`` (origin and home
exactly at the spawn); ``--param NAME=VALUE`` overrides any of its parameters.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import signal
import sys
from collections.abc import Sequence
from typing import Any

from gcs.commands import add_mock_vehicle_arguments, parse_param_overrides
from gcs.errors import UserError
from mavlink.link.signing import load_key
from mavlink.mock import (
    DEFAULT_ORIGIN,
    FaultConfig,
    MockError,
    MockFleet,
    NoiseConfig,
    Outage,
    WindConfig,
)
from planner.frames import FrameError, GeodeticPoint
from planner.scenario import load_scenario
from planner.spec.terrain import Terrain, ground_below

HELP = "run mock PX4 vehicles (MAVLink over UDP, PX4 SITL ports) until Ctrl-C"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``gcs mock``."""
    p.add_argument(
        "--vehicles",
        "-n",
        type=int,
        default=None,
        help="number of vehicles (default 1, or the scenario's)",
    )
    p.add_argument(
        "--base-port",
        type=int,
        default=14540,
        help="GCS port of vehicle 0 (vehicle i sends to base+i)",
    )
    p.add_argument(
        "--vehicle-base-port",
        type=int,
        default=None,
        help="UDP port vehicle 0 listens on (default base-port+40)",
    )
    p.add_argument(
        "--gcs-host", default="127.0.0.1", help="host the vehicles send to (default 127.0.0.1)"
    )
    p.add_argument(
        "--bind", default="127.0.0.1", help="address the vehicles bind (default loopback)"
    )
    p.add_argument(
        "--origin",
        default=None,
        metavar="LAT,LON,ALT",
        help="mission origin (deg, deg, m AMSL); default PX4 SITL home",
    )
    p.add_argument(
        "--spawn",
        action="append",
        default=None,
        metavar="X,Y,Z",
        help="spawn point in mission ENU metres, once per vehicle",
    )
    p.add_argument(
        "--scenario",
        default=None,
        metavar="FILE",
        help="take origin and vehicle starts from a scenario YAML",
    )
    p.add_argument(
        "--ground-spawn",
        action="store_true",
        help="spawn on the ground below the given points (z = 0, or a --scenario's terrain), e.g. under a scenario's airborne starts",
    )
    add_mock_vehicle_arguments(p, param_flag="--param")
    g = p.add_argument_group("link faults (all vehicles, or those in --fault-vehicles)")
    g.add_argument(
        "--loss-in",
        type=float,
        default=0.0,
        metavar="P",
        help="probability a GCS->vehicle datagram is lost",
    )
    g.add_argument(
        "--loss-out",
        type=float,
        default=0.0,
        metavar="P",
        help="probability a vehicle->GCS datagram is lost",
    )
    g.add_argument(
        "--latency-ms",
        type=float,
        default=0.0,
        help="latency added to each datagram, both directions",
    )
    g.add_argument(
        "--jitter-ms", type=float, default=0.0, help="added uniform random latency [0, jitter]"
    )
    g.add_argument(
        "--duplicate",
        type=float,
        default=0.0,
        metavar="P",
        help="probability a datagram is duplicated",
    )
    g.add_argument(
        "--reorder",
        type=float,
        default=0.0,
        metavar="P",
        help="probability a datagram is held back 30 ms",
    )
    g.add_argument(
        "--outage",
        action="append",
        default=[],
        metavar="START:END",
        help="link outage, seconds after start (repeatable)",
    )
    g.add_argument(
        "--fault-vehicles",
        default=None,
        metavar="I,J,...",
        help="0-based vehicle indices the faults apply to",
    )
    e = p.add_argument_group("environment")
    e.add_argument("--wind", default=None, metavar="N,E", help="mean wind north,east in m/s")
    e.add_argument(
        "--gust", type=float, default=0.0, metavar="SIGMA", help="gust standard deviation (m/s)"
    )
    e.add_argument(
        "--pos-noise-m", type=float, default=0.01, help="telemetry position noise (m, 1 sigma)"
    )
    e.add_argument(
        "--vel-noise-m-s", type=float, default=0.02, help="telemetry velocity noise (m/s, 1 sigma)"
    )
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="stop after S seconds (default: run until Ctrl-C)",
    )
    p.add_argument("--json", action="store_true", help="print the vehicle table and the final summary as JSON lines")  # fmt: skip
    p.add_argument(
        "--signing-key",
        default=None,
        metavar="FILE",
        help="MAVLink 2 signing key (64 hex characters or 32 raw bytes): vehicles sign what "
        "they send and refuse unsigned, wrongly signed or replayed frames",
    )


def _floats(text: str, n: int, flag: str) -> tuple[float, ...]:
    parts = [s.strip() for s in text.split(",")]
    try:
        values = tuple(float(s) for s in parts)
    except ValueError:
        raise UserError(f"{flag} {text!r}: expected {n} comma-separated numbers") from None
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise UserError(f"{flag} {text!r}: expected {n} comma-separated finite numbers")
    return values


def _scenario(
    path: str, n: int | None
) -> tuple[GeodeticPoint, list[tuple[float, float, float]], Terrain | None]:
    """Origin, vehicle starts and terrain of a scenario file (planner.scenario's loader)."""

    problem = load_scenario(path, vehicles=n)
    starts = [tuple(float(c) for c in v.start_enu_m) for v in problem.vehicles]
    return problem.origin, starts, problem.terrain  # type: ignore[return-value]


def build_fleet(args: argparse.Namespace) -> MockFleet:
    """The :class:`MockFleet` the options describe (raises UserError on bad options)."""
    n = args.vehicles
    if n is not None and not (1 <= n <= 254):
        raise UserError(f"--vehicles {n}: must be in 1..254")
    origin: GeodeticPoint = DEFAULT_ORIGIN
    spawns: list[tuple[float, float, float]] | None = None
    terrain: Terrain | None = None
    if args.scenario is not None:
        origin, spawns, terrain = _scenario(args.scenario, n)
        n = len(spawns) if n is None else n
    if args.origin is not None:
        try:
            origin = GeodeticPoint(*_floats(args.origin, 3, "--origin"))
        except FrameError as exc:
            raise UserError(f"--origin {args.origin!r}: {exc}") from None
    if args.spawn is not None:
        spawns = [_floats(s, 3, "--spawn") for s in args.spawn]  # type: ignore[misc]
        if n is None:
            n = len(spawns)
        elif len(spawns) != n:
            raise UserError(f"--spawn given {len(spawns)} times for {n} vehicles")
    n = 1 if n is None else n
    if spawns is not None and args.ground_spawn:  # on z = 0, or the scenario's terrain
        spawns = ground_below(terrain, spawns)
    if spawns is not None and len(spawns) != n:
        raise UserError(
            f"--scenario {args.scenario}: has {len(spawns)} vehicles, --vehicles is {n}"
        )
    vbase = args.vehicle_base_port if args.vehicle_base_port is not None else args.base_port + 40
    for flag, base in (("--base-port", args.base_port), ("--vehicle-base-port", vbase)):
        if not (base >= 1 and base + n - 1 <= 65535):
            raise UserError(f"{flag} {base}: ports {base}..{base + n - 1} out of range")
    try:
        faults = FaultConfig(
            loss_to_vehicle=args.loss_in,
            loss_to_gcs=args.loss_out,
            latency_s=args.latency_ms / 1000.0,
            jitter_s=args.jitter_ms / 1000.0,
            duplicate=args.duplicate,
            reorder=args.reorder,
            outages=tuple(Outage.parse(o) for o in args.outage),
        )
        per_vehicle: dict[int, FaultConfig] | FaultConfig = faults
        if args.fault_vehicles is not None:
            try:
                idx = [int(s) for s in args.fault_vehicles.split(",") if s.strip()]
            except ValueError:
                raise UserError(
                    f"--fault-vehicles {args.fault_vehicles!r}: expected indices like 0,2"
                ) from None
            bad = [i for i in idx if not 0 <= i < n]
            if bad:
                raise UserError(f"--fault-vehicles: index {bad[0]} not in 0..{n - 1}")
            per_vehicle = dict.fromkeys(idx, faults)
        wind = WindConfig(
            mean_ne_m_s=_floats(args.wind, 2, "--wind") if args.wind else (0.0, 0.0),  # type: ignore[arg-type]
            gust_sigma_m_s=args.gust,
        )
        noise = NoiseConfig(pos_m=args.pos_noise_m, vel_m_s=args.vel_noise_m_s)
        params = parse_param_overrides(args.param, "--param")
        key = None if args.signing_key is None else load_key(args.signing_key)
        return MockFleet(
            n=n,
            origin=origin,
            spawns_enu_m=spawns,
            gcs_host=args.gcs_host,
            gcs_ports=[args.base_port + i for i in range(n)],
            vehicle_ports=[vbase + i for i in range(n)],
            bind_host=args.bind,
            seed=args.seed,
            faults=per_vehicle,
            params=params,
            wind=wind,
            noise=noise,
            signing_key=key,
            profile=args.profile,
            terrain=terrain,
        )
    except MockError as exc:
        raise UserError(str(exc)) from None


def vehicle_table(fleet: MockFleet) -> list[dict[str, Any]]:
    """One row per vehicle: ids, ports, spawn (mission ENU and geodetic) and EKF origin.

    With the px4 profile the EKF origin is the vehicle's first noisy GPS fix, a few
    tenths of a metre from its spawn (different every boot, as on PX4).
    """
    rows = []
    for v in fleet.vehicles:
        lat, lon, alt = v.origin_lla
        slat, slon, salt = v.spawn_lla
        rows.append(
            {
                "sysid": v.sysid,
                "listen": f"{fleet.bind_host}:{fleet.vehicle_ports[v.index]}",
                "gcs": f"{fleet.gcs_host}:{fleet.gcs_ports[v.index]}",
                "spawn_enu_m": list(v.config.spawn_enu_m),
                "spawn": {"lat": slat, "lon": slon, "alt": salt},
                "origin": {"lat": lat, "lon": lon, "alt": alt},
            }
        )
    return rows


async def serve(fleet: MockFleet, duration_s: float | None, out: Any = None, as_json: bool = False) -> dict[str, Any]:  # fmt: skip
    """Run ``fleet`` until SIGINT/SIGTERM or ``duration_s``; return a summary."""
    out = sys.stdout if out is None else out
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    installed = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(sig, stop.set)
            installed.append(sig)
    try:
        try:
            await fleet.start()
        except MockError as exc:
            raise UserError(str(exc)) from None
        try:
            rows = vehicle_table(fleet)
            if as_json:
                print(json.dumps({"vehicles": rows}), file=out, flush=True)
            else:
                for r in rows:
                    o = r["origin"]
                    print(
                        f"vehicle sysid {r['sysid']}: listening {r['listen']}, sending to {r['gcs']}, "
                        f"spawn ENU {tuple(r['spawn_enu_m'])} m, origin {o['lat']:.7f},{o['lon']:.7f},{o['alt']:.2f}",
                        file=out,
                    )
                print("mock vehicles running; Ctrl-C to stop", file=out, flush=True)
            if duration_s is None:
                await stop.wait()
            else:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), duration_s)
        finally:
            summary = {
                "sim_time_s": round(fleet.time_s, 3),
                "wall_time_s": round(fleet.wall_elapsed_s, 3),
                "real_time_factor": round(fleet.real_time_factor, 4),
            }
            await fleet.stop()
    finally:
        for sig in installed:
            loop.remove_signal_handler(sig)
    if as_json:
        print(json.dumps({"summary": summary}), file=out, flush=True)
    else:
        print(
            f"stopped after {summary['sim_time_s']} s simulated "
            f"(real-time factor {summary['real_time_factor']})",
            file=out,
            flush=True,
        )
    return summary


def run(args: argparse.Namespace) -> int:
    """Entry point of ``gcs mock``."""
    fleet = build_fleet(args)
    asyncio.run(serve(fleet, args.duration, as_json=args.json))
    return 0


def main(argv: Sequence[str] | None = None) -> int:  # pragma: no cover - convenience
    """``python -m gcs.commands.mock`` without the gcs front end."""
    p = argparse.ArgumentParser(prog="gcs mock", description=HELP)
    add_arguments(p)
    return run(p.parse_args(argv))
