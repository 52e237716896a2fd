"""Fuzz runs shared by ``tests/reliability/test_fuzz.py`` and ``benchmarks/bench_fuzz.py``.

Each run feeds :class:`mavlink.fuzz.FrameFuzzer` datagrams to one receiver and
reports what happened: frames, frames addressed to the receiver, exceptions
raised by the receiving code (by kind and message), state changes caused by
frames *not* addressed to it, and the wall time.
"""

from __future__ import annotations

import asyncio
import socket
import struct
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from mavlink.errors import LinkError
from mavlink.fuzz import FrameFuzzer, decoded_target
from mavlink.link.fleet import Fleet
from mavlink.link.vehicle_status import VehicleSpec
from mavlink.mock import MockFleet, MockVehicle
from mavlink.mock.testing import GcsEndpoint, free_udp_ports
from planner.frames import GeodeticPoint


@dataclass(slots=True)
class FuzzReport:
    """What one fuzz run saw (counters by frame kind)."""

    frames: int = 0
    addressed: int = 0
    elapsed_s: float = 0.0
    errors: Counter[str] = field(default_factory=Counter)
    changed: Counter[str] = field(default_factory=Counter)
    alive: bool = True
    notes: list[str] = field(default_factory=list)

    @property
    def frames_per_s(self) -> float:
        """Frames handled per second of wall time."""
        return self.frames / self.elapsed_s if self.elapsed_s > 0 else 0.0


def vehicle_snapshot(v: MockVehicle) -> tuple[Any, ...]:
    """Everything a command could change on a mock vehicle (not the clock-driven motion)."""
    s = v.state
    sp = v.offboard_setpoint
    return (
        s.armed,
        s.mode,
        s.failsafe,
        s.mission_seq,
        s.home_ned_m,
        tuple(sorted(v.params.items())),
        tuple(v.mission_items(t) for t in (0, 1, 2)),
        None if sp is None else (tuple(sp.pos), tuple(sp.vel), tuple(sp.acc)),
        v.origin_lla,
        v.remote_addr,
        v.cruise_speed_m_s,
    )


async def fuzz_mock_in_process(n: int, seed: int) -> FuzzReport:
    """``n`` datagrams into a running mock vehicle's receive path (same loop, no ticks between).

    Frames not addressed to the vehicle must leave :func:`vehicle_snapshot`
    unchanged; after a frame that is addressed to it the telemetry destination
    is put back, so a later hijack would show.
    """
    gcs, veh = free_udp_ports(2)
    rep = FuzzReport()
    async with MockFleet(n=1, gcs_ports=[gcs], vehicle_ports=[veh], seed=seed) as mock:
        v = mock.vehicles[0]
        home = v.remote_addr
        fuzzer = FrameFuzzer(seed, own_sysid=1)
        t0 = time.perf_counter()
        for kind, data in fuzzer.frames(n):
            mine = decoded_target(data, 1)
            before = None if mine else vehicle_snapshot(v)
            try:
                v.datagram_received(data, ("127.0.0.2", 40000))
            except Exception as exc:  # a fuzz finding: counted and reported, never hidden
                rep.errors[f"{kind.value}: {type(exc).__name__}: {exc}"[:160]] += 1
            rep.frames += 1
            if mine:
                rep.addressed += 1
                v.remote_addr = home
            elif vehicle_snapshot(v) != before:
                rep.changed[kind.value] += 1
        rep.elapsed_s = time.perf_counter() - t0
    return rep


def fuzz_mock_udp(n: int, seed: int) -> FuzzReport:
    """``n`` datagrams over real UDP from a stranger's socket, then the real GCS is served.

    Alive: afterwards the vehicle still sends its telemetry to the GCS
    endpoint and answers its command.
    """
    rep = FuzzReport()
    with GcsEndpoint() as gcs:
        (veh,) = free_udp_ports(1)
        gcs.vehicle_port = veh
        fleet = MockFleet(n=1, gcs_ports=[gcs.port], vehicle_ports=[veh], seed=seed)
        with fleet.running_in_thread() as mock:
            if gcs.recv("HEARTBEAT", 5.0) is None:
                raise RuntimeError("mock vehicle sent no heartbeat")
            gcs.command(mavlink2.MAV_CMD_REQUEST_MESSAGE, 148)  # the GCS talks first
            stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            stranger.bind(("127.0.0.1", 0))
            try:
                fuzzer = FrameFuzzer(seed, own_sysid=1)
                t0 = time.perf_counter()
                for i, (_, data) in enumerate(fuzzer.frames(n)):
                    if data:
                        stranger.sendto(data, ("127.0.0.1", veh))
                    rep.frames += 1
                    if i % 200 == 199:
                        time.sleep(0.002)  # let the vehicle's loop drain its socket
                rep.elapsed_s = time.perf_counter() - t0
            finally:
                stranger.close()
            time.sleep(0.2)
            # Valid frames for the vehicle from the stranger made it the telemetry
            # destination (PX4 follows the last sender); the GCS's next message takes it back.
            ack = gcs.command(mavlink2.MAV_CMD_REQUEST_MESSAGE, 148)
            hb = gcs.recv("HEARTBEAT", 3.0)
            rep.alive = hb is not None and ack is not None and mock.running
            rep.notes.append(
                f"uplink messages counted by the vehicle: {sum(mock.vehicles[0].received.values())}"
            )
    return rep


def write_hostile_tlog(path: Path, n: int, seed: int) -> list[tuple[float, float, float, float]]:
    """A ``.tlog`` of ``n`` hostile frames with valid vehicle-1 records mixed in.

    Every tenth record is a valid LOCAL_POSITION_NED from system 1 (after one
    GPS_GLOBAL_ORIGIN); returns those samples as ``(time_boot_s, x, y, z)``.
    """
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    fuzzer = FrameFuzzer(seed, own_sysid=1)
    t_us = 1_700_000_000_000_000
    valid: list[tuple[float, float, float, float]] = []
    with path.open("wb") as f:
        origin = mavlink2.MAVLink_gps_global_origin_message(473977420, 85455940, 488000, 0)
        f.write(struct.pack(">Q", t_us) + origin.pack(mav))
        for i, (_, data) in enumerate(fuzzer.frames(n)):
            t_us += 10_000
            if i % 10 == 0:
                k = len(valid)
                msg = mavlink2.MAVLink_local_position_ned_message(
                    k * 10, k * 0.1, -k * 0.1, -1.0, 0, 0, 0
                )
                f.write(struct.pack(">Q", t_us) + msg.pack(mav))
                valid.append((k * 0.01, k * 0.1, -k * 0.1, -1.0))
            f.write(struct.pack(">Q", t_us) + data)
    return valid


def fuzz_tlog(path: Path, n: int, seed: int) -> tuple[FuzzReport, dict[str, Any], list[Any]]:
    """Read a hostile ``.tlog`` with :func:`mavlink.tlog.tracks_from_tlog` (the GCS's reader)."""
    from mavlink.tlog import tracks_from_tlog

    valid = write_hostile_tlog(path, n, seed)
    rep = FuzzReport(frames=n)
    tracks: dict[str, Any] = {}
    t0 = time.perf_counter()
    try:
        tracks = tracks_from_tlog(
            path, {1: "d1"}, GeodeticPoint(47.397742, 8.545594, 488.0), 1_700_000_000.0
        )
    except LinkError as exc:
        rep.notes.append(f"LinkError: {exc}")
    except Exception as exc:  # a fuzz finding
        rep.errors[f"{type(exc).__name__}: {exc}"[:160]] += 1
    rep.elapsed_s = time.perf_counter() - t0
    return rep, tracks, valid


async def fuzz_fleet(n: int, seed: int) -> tuple[FuzzReport, Any, Any]:
    """Hostile datagrams at a MAVSDK :class:`Fleet`'s port while it is connected to a mock.

    Frames claim system ids other than the vehicle's (random per run).  Returns
    the report and the vehicle's status before and after; ``alive``: the fleet
    still has its one vehicle connected and a command round trip works.
    """
    gcs, veh = free_udp_ports(2)
    rep = FuzzReport()
    async with MockFleet(n=1, gcs_ports=[gcs], vehicle_ports=[veh], seed=seed) as mock:
        spec = VehicleSpec("d1", f"udpin://127.0.0.1:{gcs}", 1)
        # on the mock's clock: the burst shares the mock's event loop, and on a busy machine
        # the vehicle's heartbeats fall behind the wall clock with it, not behind its own time
        async with Fleet([spec], telemetry_rate_hz=None, clock=mock.clock) as fleet:
            v = fleet["d1"]
            # the snapshot the burst must not change: mode, armed, and the home and origin,
            # which come a moment after the first heartbeat (on a loaded machine, after the
            # mode: the snapshot once had no home yet, and the comparison failed)
            await v.wait_for(
                lambda s: None not in (s.mode, s.armed, s.home, s.origin),
                "mode, home and origin",
                timeout_s=10.0,
            )
            before = v.status()
            stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            stranger.bind(("127.0.0.1", 0))
            src = 2 + seed % 200
            try:
                fuzzer = FrameFuzzer(seed, own_sysid=245, src_sysid=src)
                t0 = time.perf_counter()
                for i, (_, data) in enumerate(fuzzer.frames(n)):
                    if data:
                        stranger.sendto(data, ("127.0.0.1", gcs))
                    rep.frames += 1
                    if i % 200 == 199:
                        await asyncio.sleep(0.002)
                rep.elapsed_s = time.perf_counter() - t0
            finally:
                stranger.close()
            await mock.clock.sleep(1.2)  # a fresh heartbeat after the burst
            await v.hold()  # a command round trip still works
            after = v.status()
            rep.alive = after.connected and len(fleet) == 1 and mock.running
    return rep, before, after
