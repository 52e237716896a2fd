"""MAVLink 2 signing: the mock refuses what is not signed with its key; the GCS signs via a proxy.

References are independent of the code under test: pymavlink's own signing
(``MAVLink.signing``) signs and checks frames, and MAVSDK (which has no signing
API in 4.1) is the real client behind :class:`mavlink.link.signing.SigningProxy`.
"""

from __future__ import annotations

import asyncio
import socket
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from gcs.cli import main
from mavlink.errors import CommandError
from mavlink.link.fleet import Fleet
from mavlink.link.signing import (
    SigningError,
    SigningProxy,
    load_key,
    sign_frame,
    signing_timestamp,
    verifier,
)
from mavlink.link.vehicle_status import VehicleSpec
from mavlink.mock import MockFleet
from mavlink.mock.testing import GcsEndpoint, free_udp_ports

pytestmark = pytest.mark.slow  # flights or transfers over UDP (make test-fast skips)

KEY = bytes(range(32))
WRONG = bytes(range(1, 33))
ARM = mavlink2.MAV_CMD_COMPONENT_ARM_DISARM


def signer(key: bytes | None, link_id: int = 0, ts: int | None = None) -> mavlink2.MAVLink:
    """A pymavlink encoder of system 255 that signs with ``key`` (``None``: unsigned)."""
    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.link_id = link_id
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = signing_timestamp() if ts is None else ts
    return mav


def packed(mav: mavlink2.MAVLink, msg: mavlink2.MAVLink_message) -> bytes:
    buf = bytes(msg.pack(mav))
    mav.seq = (mav.seq + 1) & 0xFF
    return buf


def arm_msg(arm: bool) -> mavlink2.MAVLink_message:
    return mavlink2.MAVLink_command_long_message(1, 1, ARM, 0, float(arm), 0, 0, 0, 0, 0, 0)


def test_key_files_hex_or_raw_and_bad_ones_name_the_file(tmp_path: Path) -> None:
    (tmp_path / "hex.key").write_text(KEY.hex() + "\n")
    (tmp_path / "raw.key").write_bytes(KEY)
    (tmp_path / "short.key").write_text("abcd")
    assert load_key(tmp_path / "hex.key") == KEY == load_key(tmp_path / "raw.key")
    for name in ("short.key", "missing.key"):
        with pytest.raises(SigningError) as info:
            load_key(tmp_path / name)
        assert str(tmp_path / name) in str(info.value) and "\n" not in str(info.value)


def test_sign_frame_equals_pymavlinks_own_signature() -> None:
    ts = signing_timestamp()
    for msg in (arm_msg(True), mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)):
        ref = signer(KEY, link_id=3, ts=ts)
        plain = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        expected = packed(ref, msg)
        got = sign_frame(packed(plain, msg), KEY, 3, ts)
        assert got == expected
    # and pymavlink's verifier accepts it while refusing the unsigned original
    check = verifier(KEY)
    assert check.parse_buffer(got)[0].get_type() == "HEARTBEAT"
    unsigned = packed(mavlink2.MAVLink(None, srcSystem=255, srcComponent=190), msg)
    assert verifier(KEY).parse_buffer(unsigned)[0].get_type() == "BAD_DATA"


def test_signed_mock_accepts_only_frames_signed_with_its_key_and_refuses_replays() -> None:
    with GcsEndpoint() as gcs:
        (veh,) = free_udp_ports(1)
        gcs.vehicle_port = veh
        mock = MockFleet(n=1, gcs_ports=[gcs.port], vehicle_ports=[veh], signing_key=KEY)
        with mock.running_in_thread():
            v = mock.vehicles[0]
            # the vehicle's own frames are signed with the key (checked by pymavlink)
            data, _ = gcs.sock.recvfrom(65535)
            assert verifier(KEY).parse_buffer(data)[0].get_type() != "BAD_DATA"
            assert verifier(WRONG).parse_buffer(data)[0].get_type() == "BAD_DATA"

            def send(frame: bytes) -> mavlink2.MAVLink_message | None:
                gcs.drain()
                gcs.sock.sendto(frame, ("127.0.0.1", veh))
                return gcs.recv("COMMAND_ACK", 0.6, lambda m: m.command == ARM)

            time.sleep(0.6)  # past the mock's EKF-ready time: a signed arm is accepted
            assert send(packed(signer(None), arm_msg(True))) is None  # unsigned
            assert send(packed(signer(WRONG), arm_msg(True))) is None  # wrong key
            old = signing_timestamp() - 120 * 100_000  # two minutes ago, fresh stream
            assert send(packed(signer(KEY, link_id=7, ts=old), arm_msg(True))) is None
            sp = mavlink2.MAVLink_set_position_target_local_ned_message(
                0, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, 0xDF8, 0, 0, -5, 0, 0, 0, 0, 0, 0, 0, 0
            )
            gcs.sock.sendto(packed(signer(None), sp), ("127.0.0.1", veh))
            gcs.sock.sendto(packed(signer(WRONG), sp), ("127.0.0.1", veh))
            time.sleep(0.2)
            assert not v.state.armed and "SET_POSITION_TARGET_LOCAL_NED" not in v.received
            assert v.signing_rejected == 5

            good = signer(KEY)
            arm_frame = packed(good, arm_msg(True))
            ack = send(arm_frame)
            assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
            ack = send(packed(good, arm_msg(False)))
            assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
            assert send(arm_frame) is None  # the recorded arm, replayed
            time.sleep(0.1)
            assert not v.state.armed and v.signing_rejected == 6


def test_proxy_passes_only_validly_signed_vehicle_frames_to_the_gcs() -> None:
    listen, veh = free_udp_ports(2)

    async def run():
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as inner:
            inner.bind(("127.0.0.1", 0))
            inner.settimeout(0.3)
            async with SigningProxy(KEY, listen, inner.getsockname()[1]) as proxy:
                with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as vehicle:
                    vehicle.bind(("127.0.0.1", veh))
                    hb = mavlink2.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3)
                    good = packed(signer(KEY), hb)
                    frames = {
                        "signed": good,
                        "unsigned": packed(signer(None), hb),
                        "wrong key": packed(signer(WRONG), hb),
                        "replay": good,
                    }
                    got = {}
                    for name, frame in frames.items():
                        vehicle.sendto(frame, ("127.0.0.1", listen))
                        await asyncio.sleep(0.05)
                        try:
                            got[name] = inner.recvfrom(65535)[0]
                        except TimeoutError:
                            got[name] = None
                    # the GCS's reply is signed and goes to the vehicle's address
                    inner.sendto(packed(signer(None), hb), ("127.0.0.1", proxy_inner_port(proxy)))
                    await asyncio.sleep(0.05)
                    vehicle.settimeout(0.3)
                    reply = vehicle.recvfrom(65535)[0]
            return got, reply, proxy.stats

    got, reply, stats = asyncio.run(run())
    assert got == {"signed": got["signed"], "unsigned": None, "wrong key": None, "replay": None}
    assert got["signed"] is not None
    assert verifier(KEY).parse_buffer(reply)[0].get_type() == "HEARTBEAT"
    assert stats.down_accepted == 1 and stats.down_rejected == 3 and stats.up_signed == 1


def proxy_inner_port(proxy: SigningProxy) -> int:
    """The proxy's MAVSDK-side socket port (where the GCS's frames arrive)."""
    port = proxy.own_inner_port
    assert port is not None
    return port


def test_mavsdk_fleet_commands_a_signed_vehicle_only_through_the_signing_proxy() -> None:
    gcs, veh, inner = free_udp_ports(3)

    async def run():
        async with MockFleet(n=1, gcs_ports=[gcs], vehicle_ports=[veh], signing_key=KEY) as mock:
            # Without the proxy MAVSDK hears the vehicle but its unsigned commands are refused.
            spec = VehicleSpec("d1", f"udpin://127.0.0.1:{gcs}", 1)
            async with Fleet([spec], telemetry_rate_hz=None) as fleet:
                with pytest.raises(CommandError) as info:
                    await fleet["d1"].arm()
            refused = mock.vehicles[0].signing_rejected
            armed_without = mock.vehicles[0].state.armed
            await asyncio.sleep(0.3)
            async with SigningProxy(KEY, gcs, inner, vehicle_addr=("127.0.0.1", veh)) as proxy:
                spec = VehicleSpec("d1", f"udpin://127.0.0.1:{inner}", 1)
                async with Fleet([spec], telemetry_rate_hz=None) as fleet:
                    await fleet["d1"].arm()
                    return info.value, refused, armed_without, mock.vehicles[0].state, proxy.stats

    err, refused, armed_without, state, stats = asyncio.run(asyncio.wait_for(run(), 60.0))
    assert "arm failed" in str(err) and refused > 0 and not armed_without
    assert state.armed
    assert stats.up_signed > 0 and stats.down_accepted > 0 and stats.down_rejected == 0


def test_gcs_mock_signing_key_option(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from gcs.cli import build_parser
    from gcs.commands.mock import build_fleet

    key_file = tmp_path / "fleet.key"
    key_file.write_text(KEY.hex())
    args = build_parser().parse_args(["mock", "--signing-key", str(key_file)])
    assert build_fleet(args).signing_key == KEY
    bad = tmp_path / "bad.key"
    bad.write_text("not a key")
    assert main(["mock", "--signing-key", str(bad), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gcs mock: error:") and str(bad) in err and "\n" not in err


def test_signing_proxy_process_lets_a_mavsdk_fleet_command_a_signed_vehicle(tmp_path: Path) -> None:
    """The documented route: ``python -m mavlink.link.signing`` between MAVSDK and the vehicles."""
    import signal
    import subprocess
    import sys

    from tests.procutil import interruptible

    key_file = tmp_path / "fleet.key"
    key_file.write_text(KEY.hex())
    gcs, veh, inner = free_udp_ports(3)
    proc = subprocess.Popen(
        [sys.executable, "-m", "mavlink.link.signing", "--key", str(key_file), "-n", "1",
         "--listen-base", str(gcs), "--inner-base", str(inner), "--vehicle-base", str(veh)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=interruptible,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        assert f"udpin://127.0.0.1:{inner}" in proc.stdout.readline()

        async def run():
            async with MockFleet(
                n=1, gcs_ports=[gcs], vehicle_ports=[veh], signing_key=KEY
            ) as mock:
                spec = VehicleSpec("d1", f"udpin://127.0.0.1:{inner}", 1)
                async with Fleet([spec], telemetry_rate_hz=None) as fleet:
                    await fleet["d1"].arm()
                    return mock.vehicles[0].state.armed, mock.vehicles[0].signing_rejected

        armed, rejected = asyncio.run(asyncio.wait_for(run(), 60.0))
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
    assert armed and rejected == 0
    assert proc.returncode == 0 and "up_signed=" in out and err == ""
    bad = tmp_path / "bad.key"
    bad.write_text("x")
    done = subprocess.run(
        [sys.executable, "-m", "mavlink.link.signing", "--key", str(bad)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and str(bad) in done.stderr
