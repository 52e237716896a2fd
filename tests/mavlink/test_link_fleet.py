"""Fleet connection and status against the mock, cross-checked with MAVSDK's own decoding."""

from __future__ import annotations

import asyncio
import socket

import numpy as np
import pytest
from mavsdk.plugins.telemetry import FlightMode

from mavlink.errors import ConnectTimeoutError, LinkError, UrlError
from mavlink.link.fleet import Fleet, default_specs
from mavlink.link.vehicle_status import VehicleSpec
from mavlink.mock.fleet import MockFleet
from mavlink.px4_modes import Px4Mode
from planner.frames import GeodeticPoint
from tests.mavlink.linkutil import free_udp_ports, mock_and_fleet

ORIGIN = GeodeticPoint(47.397742, 8.545594, 488.0)

#: MAVSDK's independent decoding of PX4 modes, for the ones these tests visit.
MAVSDK_MODE = {
    FlightMode.HOLD: Px4Mode.AUTO_LOITER,
    FlightMode.TAKEOFF: Px4Mode.AUTO_TAKEOFF,
    FlightMode.LAND: Px4Mode.AUTO_LAND,
    FlightMode.OFFBOARD: Px4Mode.OFFBOARD,
    FlightMode.MISSION: Px4Mode.AUTO_MISSION,
}


def test_default_specs_follow_the_px4_sitl_convention() -> None:
    specs = default_specs(["a", "b", "c"], urls=[None, "udpin://0.0.0.0:15000", None])
    assert [(s.name, s.url, s.sysid) for s in specs] == [
        ("a", "udpin://0.0.0.0:14540", 1),
        ("b", "udpin://0.0.0.0:15000", 2),
        ("c", "udpin://0.0.0.0:14542", 3),
    ]


def test_bad_specs_are_refused_before_opening_anything() -> None:
    with pytest.raises(UrlError, match=r"^vehicle d2: bad connection URL 'udp://x:1'"):
        Fleet([VehicleSpec("d1", "udpin://0.0.0.0:1", 1), VehicleSpec("d2", "udp://x:1", 2)])
    with pytest.raises(LinkError, match="system id 1 used by more than one vehicle"):
        Fleet(
            [VehicleSpec("d1", "udpin://0.0.0.0:1", 1), VehicleSpec("d2", "udpin://0.0.0.0:2", 1)]
        )
    with pytest.raises(LinkError, match="system id 245 is the ground station's own"):
        Fleet([VehicleSpec("d1", "udpin://0.0.0.0:1", 245)])
    with pytest.raises(LinkError, match="duplicate vehicle names: d1"):
        Fleet(
            [VehicleSpec("d1", "udpin://0.0.0.0:1", 1), VehicleSpec("d1", "udpin://0.0.0.0:2", 2)]
        )


@pytest.mark.slow
def test_missing_vehicle_is_one_error_naming_it_its_url_and_what_was_seen() -> None:
    ports = free_udp_ports(3)

    async def run() -> ConnectTimeoutError:
        async with MockFleet(n=1, origin=ORIGIN, gcs_ports=ports[:1], vehicle_ports=ports[2:]):
            fleet = Fleet(
                [
                    VehicleSpec("d1", f"udpin://127.0.0.1:{ports[0]}", 1),
                    VehicleSpec("d2", f"udpin://127.0.0.1:{ports[1]}", 2),
                ],
                connect_timeout_s=1.5,
            )
            with pytest.raises(ConnectTimeoutError) as info:
                await fleet.connect()
            return info.value

    err = asyncio.run(run())
    assert err.vehicle == "d2" and err.url == f"udpin://127.0.0.1:{ports[1]}"
    assert str(err) == (
        f"vehicle d2 (udpin://127.0.0.1:{ports[1]}): no heartbeat from system id 2 within 1.5 s "
        "(systems seen: 1)"
    )


def test_a_port_in_use_is_a_link_error_naming_the_vehicle_and_the_way_out() -> None:
    busy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    busy.bind(("127.0.0.1", 0))
    port = busy.getsockname()[1]
    try:
        # found by the scan before MAVSDK opens anything ...
        fleet = Fleet([VehicleSpec("d1", f"udpin://127.0.0.1:{port}", 1)], connect_timeout_s=1.0)
        with pytest.raises(LinkError) as info:
            asyncio.run(fleet.connect())
        assert str(info.value).startswith(
            f"vehicle d1 (udpin://127.0.0.1:{port}): port {port} cannot be opened (Address "
            "already in use): another program"
        )
        assert "--base-port or --connection" in str(info.value)
        # ... and by MAVSDK without the scan
        fleet = Fleet(
            [VehicleSpec("d1", f"udpin://127.0.0.1:{port}", 1)], connect_timeout_s=1.0, scan_s=0.0
        )
        with pytest.raises(LinkError, match=r"^vehicle d1 \(udpin://127.0.0.1:\d+\): cannot open"):
            asyncio.run(fleet.connect())
    finally:
        busy.close()


@pytest.mark.slow
def test_another_system_id_on_the_port_is_named_at_once_not_waited_for() -> None:
    gcs, vport = free_udp_ports(2)

    async def run() -> tuple[LinkError, float]:
        # a mock vehicle with system id 1 sends to the port where the fleet expects id 2
        async with MockFleet(n=1, origin=ORIGIN, gcs_ports=[gcs], vehicle_ports=[vport]):
            fleet = Fleet([VehicleSpec("d2", f"udpin://127.0.0.1:{gcs}", 2)], connect_timeout_s=10)
            t0 = asyncio.get_running_loop().time()
            with pytest.raises(LinkError) as info:
                await fleet.connect()
            return info.value, asyncio.get_running_loop().time() - t0

    err, took = asyncio.run(run())
    assert str(err).startswith(
        f"vehicle d2 (udpin://127.0.0.1:{gcs}): system id(s) 1 answer on port {gcs}, not 2: "
        "another program's vehicle"
    )
    assert took < 2.0  # the scan's second, not the 10 s connection timeout


def test_an_autopilot_that_is_not_px4_is_refused() -> None:
    from pymavlink.dialects.v20 import common as mav

    (gcs,) = free_udp_ports(1)

    async def run() -> LinkError:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        link = mav.MAVLink(None, srcSystem=1, srcComponent=1)

        async def ardupilot() -> None:  # heartbeats and attitude, as ArduPilot sends them
            t = 0
            while True:
                hb = mav.MAVLink_heartbeat_message(
                    mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 3, 3
                )
                att = mav.MAVLink_attitude_message(1000 + t, 0, 0, 0, 0, 0, 0)
                for m in (hb, att):
                    sock.sendto(m.pack(link), ("127.0.0.1", gcs))
                t += 50
                await asyncio.sleep(0.05)

        task = asyncio.create_task(ardupilot())
        try:
            fleet = Fleet([VehicleSpec("d1", f"udpin://127.0.0.1:{gcs}", 1)], connect_timeout_s=5)
            with pytest.raises(LinkError) as info:
                await fleet.connect()
            return info.value
        finally:
            task.cancel()
            sock.close()

    err = asyncio.run(run())
    assert str(err) == (
        f"vehicle d1 (udpin://127.0.0.1:{gcs}): system id 1 on port {gcs} is not PX4 (its "
        "heartbeat says MAV_AUTOPILOT 3, ArduPilot): stl-gcs flies PX4 vehicles"
    )


@pytest.mark.slow
def test_status_matches_the_vehicle_and_mavsdks_own_mode_decoding() -> None:
    spawns = [(0.0, 0.0, 0.0), (3.0, -2.0, 0.0)]

    async def run():
        # the ideal profile: compares with the exact spawn and a take-off to exactly 2 m
        async with mock_and_fleet(["d1", "d2"], ORIGIN, spawns, profile="ideal") as (
            mock,
            fleet,
        ):
            theirs: list[FlightMode] = []
            ours: list[Px4Mode | None] = []
            v = fleet["d2"]
            done = asyncio.Event()

            async def poll() -> None:
                while not done.is_set():
                    ours.append(v.status().mode)
                    await asyncio.sleep(0.01)

            def on_mode(mode: FlightMode, _ud: object) -> None:
                theirs.append(mode)

            poller = asyncio.create_task(poll())
            handle = v.telemetry.subscribe_flight_mode(on_mode)
            await fleet.for_each(
                lambda x: x.wait_for(lambda s: s.home is not None, "home", timeout_s=5)
            )
            first = fleet.statuses()
            truth = [x.state for x in mock.vehicles]
            origins = [x.origin_lla for x in mock.vehicles]
            await v.arm()
            await v.takeoff_to(ORIGIN.alt_m + 2.0)
            await v.wait_for(lambda s: s.mode is Px4Mode.AUTO_TAKEOFF, "takeoff", timeout_s=5)
            await v.wait_for(
                lambda s: s.mode is Px4Mode.AUTO_LOITER and s.relative_alt_m > 1.8,
                "hover at 2 m",
                timeout_s=15,
            )
            await v.land()
            await v.wait_for(lambda s: s.mode is Px4Mode.AUTO_LAND, "land", timeout_s=5)
            await asyncio.sleep(1.2)
            v.telemetry.unsubscribe_flight_mode(handle)
            done.set()
            await poller
            return first, truth, origins, ours, theirs

    first, truth, origins, ours, theirs = asyncio.run(run())
    for st, tr, org in zip(first, truth, origins, strict=True):
        assert st.connected and st.armed is False
        assert st.mode is not None and st.mode.value == tr.mode.value  # the mock's (main, sub)
        np.testing.assert_allclose(st.pos_ned_m, tr.pos_ned_m, atol=0.1)  # telemetry noise
        o = st.origin
        assert o is not None  # GPS_GLOBAL_ORIGIN: degE7 and millimetres on the wire
        assert (o.lat_deg, o.lon_deg) == pytest.approx(org[:2], abs=1.5e-7)
        assert o.alt_m == pytest.approx(org[2], abs=2e-3)
        assert st.home is not None and st.position is not None
        assert st.battery_remaining == pytest.approx(1.0, abs=0.05)
    # d2's origin is its spawn point, 3 m east and 2 m south of the mission origin.
    assert first[1].origin.lon_deg > ORIGIN.lon_deg and first[1].origin.lat_deg < ORIGIN.lat_deg

    # Our decoding of HEARTBEAT.custom_mode went through the same modes as MAVSDK's own.
    def changes(seq: list) -> list:
        return [m for i, m in enumerate(seq) if i == 0 or m != seq[i - 1]]

    mavsdk_seq = changes([MAVSDK_MODE[m] for m in theirs])  # MAVSDK reports changes only
    assert len(mavsdk_seq) >= 3 and changes(ours)[-len(mavsdk_seq) :] == mavsdk_seq
    assert changes(ours) == [
        Px4Mode.AUTO_LOITER,
        Px4Mode.AUTO_TAKEOFF,
        Px4Mode.AUTO_LOITER,
        Px4Mode.AUTO_LAND,
    ]


@pytest.mark.slow
def test_set_mode_sends_px4_custom_modes_and_reports_refusals() -> None:
    from mavlink.errors import CommandError

    async def run():
        async with mock_and_fleet(["d1"], ORIGIN, [(0.0, 0.0, 0.0)]) as (mock, fleet):
            v = fleet["d1"]
            # Offboard without a setpoint stream: PX4 (and the mock) refuse it.
            with pytest.raises(CommandError) as refused:
                await v.set_mode(Px4Mode.OFFBOARD)
            await v.set_mode(Px4Mode.AUTO_RTL)
            return refused.value, mock.vehicles[0].state.mode

    refused, mode_after = asyncio.run(run())
    assert refused.result == "TEMPORARILY_REJECTED"
    assert str(refused).startswith("vehicle d1 (udpin://127.0.0.1:")
    assert "set mode OFFBOARD failed: TEMPORARILY_REJECTED" in str(refused)
    assert mode_after.value == Px4Mode.AUTO_RTL.value  # the mock decoded our custom mode
