"""``gcs status``: one line per vehicle: sysid, autopilot, mode, armed, position, battery.

Vehicle ``i`` is reached at ``--connection`` number ``i`` (repeat the option) and has system id
``i + 1`` (PX4 SITL's convention; ``--sysid`` overrides, one per connection). Without
``--connection`` it looks at ``--vehicles N`` PX4 SITL instances, ``udpin://0.0.0.0:14540+i``.
A connection on which the system id never answers within ``--timeout`` is bad user input:
one line naming the URL (and the system ids that were seen there), exit status 2.

The autopilot and vehicle type come from the HEARTBEAT (MAV_AUTOPILOT / MAV_TYPE names); mode
is PX4's custom mode decoded; position is GLOBAL_POSITION_INT (latitude, longitude, altitude
AMSL and above home) and LOCAL_POSITION_NED; battery is remaining charge and voltage.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import common

from gcs.commands import add_link_arguments
from gcs.errors import UserError
from gcs.flight import signed_links
from mavlink.link.fleet import Fleet
from mavlink.link.urls import default_url, parse_url
from mavlink.link.vehicle_status import VehicleSpec

if TYPE_CHECKING:
    from mavlink.link.vehicle_status import VehicleSpec, VehicleStatus

HELP = "show each vehicle: system id, autopilot, mode, armed, position, battery"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``gcs status``."""
    p.add_argument(
        "--sysid", action="append", type=int, metavar="ID", help="system id per connection (i+1)"
    )
    p.add_argument(
        "--vehicles", type=int, default=1, metavar="N", help="without --connection: N SITL ports"
    )
    add_link_arguments(
        p, plan_order=False, timeout_s=5.0, timeout_help="seconds to wait for each (5)"
    )
    p.add_argument("--json", action="store_true", help="print the vehicles as JSON")


@dataclass(frozen=True, slots=True)
class StatusRow:
    """One vehicle as ``gcs status`` shows it (fields ``None`` when not reported)."""

    status: VehicleStatus
    autopilot: str | None
    vehicle_type: str | None

    def as_json(self) -> dict[str, Any]:
        """JSON-ready dict."""
        s = self.status
        pos = s.position
        return {
            "sysid": s.sysid,
            "url": s.url,
            "autopilot": self.autopilot,
            "type": self.vehicle_type,
            "mode": s.mode.label if s.mode is not None else None,
            "custom_mode": s.custom_mode,
            "armed": s.armed,
            "in_air": s.in_air,
            "lat_deg": None if pos is None else pos.lat_deg,
            "lon_deg": None if pos is None else pos.lon_deg,
            "alt_amsl_m": None if pos is None else pos.alt_m,
            "relative_alt_m": s.relative_alt_m,
            "pos_ned_m": None if s.pos_ned_m is None else list(s.pos_ned_m),
            "battery_remaining": s.battery_remaining,
            "battery_voltage_v": s.battery_voltage_v,
        }


def _enum_name(enum: str, value: Any, prefix: str) -> str | None:

    try:
        entry = common.enums[enum][int(value)]
    except (KeyError, TypeError, ValueError):
        return None if value is None else f"{enum} {value}"
    return str(entry.name).removeprefix(prefix)


def specs_for(
    urls: list[str] | None, sysids: list[int] | None, vehicles: int, base_port: int = 14540
) -> tuple[VehicleSpec, ...]:
    """Vehicle specs from the options (see module docstring).

    Raises:
        UserError: counts that do not match, or a system id outside 1..255.
    """

    if urls:
        n = len(urls)
    else:
        if not 1 <= vehicles <= 254:
            raise UserError(f"--vehicles: must be 1..254, got {vehicles}")
        n = vehicles
        urls = [default_url(i, base_port) for i in range(n)]
    if sysids is not None and len(sysids) != n:
        raise UserError(f"--sysid: {len(sysids)} given for {n} connection(s); give one each")
    ids = sysids if sysids is not None else list(range(1, n + 1))
    out = []
    for url, sid in zip(urls, ids, strict=True):
        if not 1 <= sid <= 255:
            raise UserError(f"--sysid: {sid} is not a MAVLink system id (1..255)")
        name = f"sys{sid}"
        parse_url(url, vehicle=name)
        out.append(VehicleSpec(name, url, sid))
    return tuple(out)


async def read_status(specs: tuple[VehicleSpec, ...], timeout_s: float) -> list[StatusRow]:
    """Connect, wait (at most ``timeout_s``) for position and battery, snapshot every vehicle.

    Raises:
        mavlink.errors.ConnectTimeoutError: a vehicle never answered (names its URL).
    """

    heartbeat: dict[str, tuple[Any, Any]] = {}
    lock = threading.Lock()
    async with Fleet(specs, connect_timeout_s=timeout_s, telemetry_rate_hz=None) as fleet:
        handles = []
        for v in fleet:

            def on_heartbeat(msg: Any, _ud: Any, name: str = v.name) -> None:
                if msg.component_id != 1:
                    return
                f = json.loads(msg.fields_json)
                with lock:
                    heartbeat[name] = (f.get("autopilot"), f.get("type"))

            handles.append((v, v.direct.subscribe_message("HEARTBEAT", on_heartbeat)))
        try:
            # PX4 sends HEARTBEAT at 1 Hz: wait for the next one, and for position and battery.
            deadline = time.monotonic() + max(timeout_s, 1.5)
            while time.monotonic() < deadline:
                with lock:
                    seen = set(heartbeat)
                if all(v.name in seen and _complete(v.status()) for v in fleet):
                    break
                await asyncio.sleep(0.05)
            with lock:
                hb = dict(heartbeat)
            rows = []
            for st in fleet.statuses():
                ap, typ = hb.get(st.name, (None, None))
                rows.append(
                    StatusRow(
                        st,
                        _enum_name("MAV_AUTOPILOT", ap, "MAV_AUTOPILOT_"),
                        _enum_name("MAV_TYPE", typ, "MAV_TYPE_"),
                    )
                )
            return rows
        finally:
            for v, h in handles:
                v.direct.unsubscribe_message(h)


def _complete(s: VehicleStatus) -> bool:
    return (
        s.position is not None
        and s.pos_ned_m is not None
        and s.battery_remaining is not None
        and s.mode is not None
    )


def _fmt(x: float | None, fmt: str) -> str:
    return "-" if x is None else format(x, fmt)


def table(rows: list[StatusRow]) -> str:
    """The text table, one line per vehicle."""
    head = (
        f"{'sysid':>5}  {'url':<26} {'autopilot':<9} {'type':<10} {'mode':<13} {'armed':<5} "
        f"{'lat':>11} {'lon':>11} {'alt m':>8} {'rel m':>6}  {'north,east,down m':<22} battery"
    )
    lines = [head]
    for r in rows:
        s = r.status
        pos = s.position
        ned = "-" if s.pos_ned_m is None else ",".join(f"{x:.2f}" for x in s.pos_ned_m)
        batt = (
            "-"
            if s.battery_remaining is None
            else f"{100 * s.battery_remaining:.0f} % {_fmt(s.battery_voltage_v, '.1f')} V"
        )
        mode = s.mode.label if s.mode is not None else str(s.custom_mode)
        armed = "-" if s.armed is None else ("yes" if s.armed else "no")
        lines.append(
            f"{s.sysid:>5}  {s.url:<26} {r.autopilot or '-':<9} {r.vehicle_type or '-':<10} "
            f"{mode:<13} {armed:<5} {_fmt(pos.lat_deg if pos else None, '.7f'):>11} "
            f"{_fmt(pos.lon_deg if pos else None, '.7f'):>11} {_fmt(pos.alt_m if pos else None, '.2f'):>8} "
            f"{_fmt(s.relative_alt_m, '.2f'):>6}  {ned:<22} {batt}"
        )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Print the vehicles; 2 (via the CLI) when one never answers."""

    if not (args.timeout > 0):
        raise UserError(f"--timeout: must be > 0 s, got {args.timeout:g}")
    specs = specs_for(args.connection, args.sysid, args.vehicles, args.base_port)

    async def signed_status() -> list[Any]:
        async with signed_links(specs, args.signing_key) as links:
            return await read_status(links, args.timeout)

    rows = asyncio.run(signed_status())
    if args.json:
        print(json.dumps({"vehicles": [r.as_json() for r in rows]}))
    else:
        print(table(rows))
    return 0
