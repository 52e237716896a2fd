"""MAVSDK's own log lines: the user sees only errors they can act on, the flight's log keeps
every line; and a vehicle reads what it only looks at now and then instead of subscribing.

The routing is checked on lines given to the forwarding callback MAVSDK calls, and end to end
on a real MAVSDK callback backlog (a deliberately slow subscriber against a mock vehicle).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from mavsdk import LogLevel

from mavlink.link.mavsdk_glue import (
    MAVSDK_LOG,
    calls_settled,
    calls_under_way,
    forward_mavsdk_line,
    mavsdk_call,
    mavsdk_instance_opened,
    mavsdk_log_file,
    route_mavsdk_logs,
)
from mavlink.link.vehicle import Vehicle
from mavlink.link.vehicle_status import VehicleStatus
from mavlink.mission.items import MissionItem
from mavlink.mission.transfer import upload
from mavlink.px4_modes import Px4Mode
from planner.frames import GeodeticPoint, geodetic_to_enu
from tests.mavlink.linkutil import mock_and_fleet

ORIGIN = GeodeticPoint(47.397742, 8.545594, 488.0)
DROPPING = (
    "Dropping subscription callbacks (1 so far): a subscriber is not keeping up.\n"
    "See: https://mavsdk.mavlink.io/main/en/cpp/troubleshooting.html#user_callbacks"
)


def test_only_actionable_mavsdk_errors_reach_stderr_and_the_flight_log_keeps_every_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "mavsdk.log"
    level, propagate = MAVSDK_LOG.level, MAVSDK_LOG.propagate
    with mavsdk_log_file(path) as written:
        assert written == path
        mavsdk_instance_opened(True)  # as Fleet.connect does
        try:
            # as MAVSDK 4.1 says them: its full callback queue is an error, nothing to act on
            forward_mavsdk_line(LogLevel.ERROR, DROPPING, "mavsdk_impl.cpp", 1862)
            forward_mavsdk_line(LogLevel.WARN, "Heartbeats from system 3 timed out", "s.cpp", 1)
            forward_mavsdk_line(LogLevel.INFO, "New system on: 127.0.0.1:1", "udp.cpp", 2)
            forward_mavsdk_line(LogLevel.DEBUG, "Component Autopilot added.", "s.cpp", 3)
            forward_mavsdk_line(LogLevel.ERROR, "bind error: Address in use", "udp.cpp", 4)
            # a send to a silent vehicle, on every heartbeat: the flight reports the lost link
            forward_mavsdk_line(LogLevel.ERROR, "Sending message failed", "mavsdk_impl.cpp", 7)
        finally:
            mavsdk_instance_opened(False)
        # an instance already destroyed (a command's fleet closed) reports a heartbeat it could
        # not send: into the log, not onto whatever command's stderr comes next
        forward_mavsdk_line(LogLevel.ERROR, "Sending message failed", "mavsdk_impl.cpp", 6)
    forward_mavsdk_line(LogLevel.WARN, "Vehicle type changed", "s.cpp", 5)  # after the flight

    err = capsys.readouterr().err
    assert err == "MAVSDK: bind error: Address in use (udp.cpp:4)\n"
    lines = path.read_text(encoding="utf-8").splitlines()
    levels = [line.split()[2] for line in lines if not line.startswith("See:")]
    assert levels == ["ERROR", "WARNING", "INFO", "DEBUG", "ERROR", "ERROR", "ERROR"]
    text = "\n".join(lines)
    for said in (DROPPING, "timed out", "New system", "Autopilot added", "bind", "Sending message"):
        assert said in text
    assert "Vehicle type changed" not in text  # the file is the flight's only
    assert (MAVSDK_LOG.level, MAVSDK_LOG.propagate) == (level, propagate)


def test_mavsdk_lines_still_reach_an_application_handler_outside_a_flight_log(
    caplog: pytest.LogCaptureFixture, capsys: pytest.CaptureFixture[str]
) -> None:
    route_mavsdk_logs()
    with caplog.at_level(logging.WARNING, logger=MAVSDK_LOG.name):
        forward_mavsdk_line(LogLevel.ERROR, DROPPING, "mavsdk_impl.cpp", 1862)
    assert [r.levelname for r in caplog.records] == ["ERROR"]
    assert caplog.records[0].mavsdk_internal  # type: ignore[attr-defined]
    assert capsys.readouterr().err == ""


@pytest.mark.slow  # real-time MAVSDK discovery over UDP
def test_a_real_mavsdk_callback_backlog_goes_to_the_log_file_not_to_stderr(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "mavsdk.log"

    def slow(_msg: object, _ud: object) -> None:
        time.sleep(0.02)  # a subscriber that cannot keep up with ~150 messages a second

    async def run() -> bool:
        async with mock_and_fleet(["d1"], ORIGIN, [(0.0, 0.0, 0.0)]) as (_mock, fleet):
            v = fleet["d1"]
            handle = v.direct.subscribe_message("", slow)
            try:
                deadline = time.monotonic() + 10.0
                while time.monotonic() < deadline:
                    if "Dropping subscription callbacks" in path.read_text(encoding="utf-8"):
                        return True
                    await asyncio.sleep(0.1)
                return False
            finally:
                v.direct.unsubscribe_message(handle)

    with mavsdk_log_file(path):
        dropped = asyncio.run(run())
    assert dropped, path.read_text(encoding="utf-8")
    text = path.read_text(encoding="utf-8")
    assert "ERROR Dropping subscription callbacks" in text and "INFO MAVSDK version" in text
    out, err = capfd.readouterr()
    assert "Dropping" not in err + out and "MAVSDK" not in err + out


@pytest.mark.slow  # a real-time take-off over UDP
def test_heading_position_home_and_battery_are_read_not_subscribed_and_follow_the_vehicle() -> None:
    async def run() -> tuple[Vehicle, VehicleStatus, list[str], np.ndarray, GeodeticPoint]:
        spawn = (3.0, -2.0, 0.0)  # ENU of the mission origin
        async with mock_and_fleet(["d1"], ORIGIN, [spawn], profile="ideal") as (mock, fleet):
            v = fleet["d1"]
            subscribed = list(v.subscriptions)
            on_ground = await v.wait_for(
                lambda s: None not in (s.position, s.home, s.battery_remaining, s.heading_deg),
                "global position, home, battery and heading",
                timeout_s=5.0,
            )
            v.start_track()
            await v.arm()
            assert on_ground.position is not None
            await v.takeoff_to(on_ground.position.alt_m + 2.0)
            up = await v.wait_for(
                lambda s: s.mode is Px4Mode.AUTO_LOITER and (s.relative_alt_m or 0.0) > 1.8,
                "hover at 2 m",
                timeout_s=15.0,
            )
            assert up.position is not None  # then turn east where it is
            await v.goto(up.position.lat_deg, up.position.lon_deg, up.position.alt_m, 90.0)
            await v.wait_for(
                lambda s: s.heading_deg is not None and abs(s.heading_deg - 90.0) < 1.0,
                "heading east",
                timeout_s=15.0,
            )
            rows = v.stop_track()
            origin = GeodeticPoint(*mock.vehicles[0].origin_lla)
            return v, on_ground, subscribed, rows, origin

    v, st, subscribed, rows, origin = asyncio.run(run())
    # subscribed: what is needed as it comes; the rest is MAVSDK's latest value, read. The
    # local position comes whole through mavlink_direct (MAVSDK's telemetry drops its
    # time_boot_ms, which the track's instants are taken from)
    assert "unsubscribe_position_velocity_ned" not in subscribed
    assert "unsubscribe_message" in subscribed
    for read in ("position", "home", "battery", "heading"):
        assert f"unsubscribe_{read}" not in subscribed
    assert st.battery_remaining == pytest.approx(1.0, abs=0.05)
    assert st.heading_deg == pytest.approx(0.0, abs=1.0)
    # The global position is where the local one says, in the frame of the EKF origin.
    assert st.position is not None and st.home is not None and st.pos_ned_m is not None
    pos = st.position
    e, n, u = geodetic_to_enu(pos.lat_deg, pos.lon_deg, pos.alt_m, origin)[0]
    np.testing.assert_allclose((n, e, -u), st.pos_ned_m, atol=0.1)
    # Every track sample carries the heading MAVSDK had by then: north on the ground, east after.
    yaw = rows[:, 7]
    assert np.all(np.isfinite(yaw))
    assert abs(yaw[0]) < math.radians(1.0)
    # (the last sample may precede the status read that ended the turn by one position
    # period: at the end of the turn, up to a degree or two short of it)
    assert yaw[-1] == pytest.approx(math.pi / 2, abs=math.radians(3.0))
    # Closed, the vehicle keeps what it last read.
    assert v.status().heading_deg == pytest.approx(90.0, abs=1.0)


def test_a_mavsdk_call_is_counted_until_its_answer_even_one_nobody_waits_for() -> None:
    assert calls_settled(30.0)  # calls of earlier tests in this process answered
    answer: list[Callable[..., None]] = []

    def start(value: int, callback: Callable[..., None]) -> None:
        answer.append(lambda: callback(value * 2, None))

    async def run() -> tuple[int, int]:
        got = await asyncio.wait_for(_answered_soon(start, answer), 5.0)
        with contextlib.suppress(TimeoutError):  # a call nobody waits for any more
            await mavsdk_call(start, 1, timeout_s=0.01)
        return got, calls_under_way()

    got, left = asyncio.run(run())
    assert (got, left) == (42, 1)
    assert not calls_settled(0.05)
    threading.Thread(target=answer[-1]).start()  # MAVSDK's callback thread, loop closed
    assert calls_settled(5.0) and calls_under_way() == 0


async def _answered_soon(start: Callable[..., None], answer: list[Callable[..., None]]) -> int:
    task = asyncio.ensure_future(mavsdk_call(start, 21))
    while not answer:
        await asyncio.sleep(0.001)
    threading.Thread(target=answer[-1]).start()
    return int(await task)


@pytest.mark.slow  # real MAVSDK over UDP
def test_a_fleet_closed_during_an_upload_waits_for_its_answer_before_destroying_mavsdk() -> None:
    items = [
        MissionItem(i, 6, 16, int(i == 0), 1, 0.0, 0.5, 0.0, math.nan,
                    473977420 + 100 * i, 85455940, 520.0, 0)
        for i in range(40)
    ]  # fmt: skip

    assert calls_settled(30.0)

    async def run() -> int:
        async with mock_and_fleet(["d1"], ORIGIN, [(0.0, 0.0, 0.0)]) as (_mock, fleet):
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(upload(fleet["d1"], items), 0.01)
            return calls_under_way()

    under_way = asyncio.run(run())
    assert under_way == 1  # the upload was still going when the fleet closed
    assert calls_under_way() == 0  # and had its answer before MAVSDK was destroyed
