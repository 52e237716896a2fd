"""Hostile MAVLink frames against the mock vehicle and the GCS's receive paths.

~10^4 frames per receiver here (``benchmarks/bench_fuzz.py`` runs 10^5): random
bytes, well-formed frames with random payloads, wrong CRC, truncated,
oversized, unknown ids, MAVLink 1, bogus signatures, mutated commands and valid
state-changing messages addressed to other systems.  No receiver may raise,
hang or change its state on a frame that is not addressed to it.
"""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.fuzz import FrameFuzzer, FrameKind, decoded_target, frame_v2
from mavlink.mock import MockFleet
from mavlink.mock.testing import GcsEndpoint, free_udp_ports
from tests.reliability.fuzzrun import (
    fuzz_fleet,
    fuzz_mock_in_process,
    fuzz_mock_udp,
    fuzz_tlog,
)

N_FRAMES = 10_000


def test_generator_covers_every_kind_and_is_reproducible() -> None:
    a = list(FrameFuzzer(5).frames(2000))
    b = list(FrameFuzzer(5).frames(2000))
    assert a == b
    assert {k for k, _ in a} == set(FrameKind)
    # The wrong-target frames are valid MAVLink for someone else; their decoded target proves it.
    for kind, data in a:
        if kind is FrameKind.WRONG_TARGET:
            assert not decoded_target(data, 1)
            msgs = mavlink2.MAVLink(None).parse_buffer(data)
            assert msgs and msgs[0].get_type() != "BAD_DATA" and msgs[0].target_system not in (0, 1)
        if kind is FrameKind.BAD_CRC:
            parser = mavlink2.MAVLink(None)
            parser.robust_parsing = True
            assert all(m.get_type() == "BAD_DATA" for m in parser.parse_buffer(data) or [])


@pytest.mark.slow
def test_mock_vehicle_survives_hostile_frames_and_ignores_those_for_others() -> None:
    rep = asyncio.run(fuzz_mock_in_process(N_FRAMES, seed=11))
    assert rep.frames == N_FRAMES
    assert rep.errors == {}, rep.errors
    assert rep.changed == {}, rep.changed  # not one frame for someone else changed anything
    assert 0 < rep.addressed < rep.frames  # some random frames do address it (no state rule)


@pytest.mark.slow
def test_mock_vehicle_over_udp_stays_alive_and_serves_its_gcs() -> None:
    rep = fuzz_mock_udp(N_FRAMES, seed=12)
    assert rep.alive, rep.notes


@pytest.mark.slow
def test_truncated_junk_does_not_swallow_the_next_command_or_steal_telemetry() -> None:
    # Regression: the parser kept a truncated frame's bytes and ate the next datagram,
    # and any datagram (even junk) redirected the vehicle's telemetry to its sender.
    with GcsEndpoint() as gcs:
        (veh,) = free_udp_ports(1)
        gcs.vehicle_port = veh
        with MockFleet(n=1, gcs_ports=[gcs.port], vehicle_ports=[veh]).running_in_thread():
            assert gcs.recv("HEARTBEAT", 5.0) is not None
            arm = mavlink2.MAVLink_command_long_message(
                1, 1, mavlink2.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0
            ).pack(mavlink2.MAVLink(None, srcSystem=255, srcComponent=190))
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
                stranger.bind(("127.0.0.1", 0))
                junk = frame_v2(0, bytes(9), sysid=77)[:7]  # a heartbeat cut after its header
                stranger.sendto(junk, ("127.0.0.1", veh))
                gcs.drain()
                gcs.sock.sendto(arm, ("127.0.0.1", veh))
                ack = gcs.recv("COMMAND_ACK", 3.0)
                stranger.sendto(junk + b"\x00" * 40, ("127.0.0.1", veh))
                stranger.settimeout(0.5)
                with pytest.raises(TimeoutError):
                    stranger.recvfrom(65535)  # no telemetry went to the stranger
            assert ack is not None and ack.command == mavlink2.MAV_CMD_REQUEST_MESSAGE
            assert gcs.recv("HEARTBEAT", 3.0) is not None


@pytest.mark.slow
def test_mavsdk_fleet_survives_hostile_frames_and_keeps_its_vehicle_state() -> None:
    rep, before, after = asyncio.run(asyncio.wait_for(fuzz_fleet(N_FRAMES, seed=13), 60.0))
    assert rep.alive
    assert (after.mode, after.armed, after.connected) == (before.mode, before.armed, True)
    assert after.home == before.home and after.origin == before.origin


def test_tlog_reader_turns_hostile_files_into_tracks_or_a_link_error(tmp_path: Path) -> None:
    rep, tracks, valid = fuzz_tlog(tmp_path / "hostile.tlog", N_FRAMES, seed=14)
    assert rep.errors == {}, rep.errors
    # whatever was recovered for d1 is some of the samples system 1 really sent
    if "d1" in tracks:
        sent = {(round(x, 6), round(y, 6)) for _, x, y, _ in valid}
        got = tracks["d1"].pos_ned_m
        assert {(round(n, 6), round(e, 6)) for n, e, _ in got} <= sent
