"""MAVSDK (``mavsdk`` 4, the independent client) against the mock vehicle's camera and gimbal.

Its Camera plugin finds the camera at component 100 and takes pictures, its Gimbal plugin
finds the gimbal PX4 manages (manager component 1, device 154), takes control and points it,
and its mission_raw plugin uploads a mission with camera and gimbal items, reads it back
unchanged and flies it on the ``px4`` vehicle: the pictures, as MAVSDK's capture_info
reports them, come during the capture waypoint's hold only.
"""

from __future__ import annotations

import asyncio
import itertools
import math
import time
from collections.abc import Callable
from typing import Any

import pymap3d
import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk, System
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.camera import CameraAsync
from mavsdk.asyncio.plugins.gimbal import ControlMode, GimbalAsync, GimbalMode, SendMode
from mavsdk.asyncio.plugins.mission_raw import MissionItem, MissionRawAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

from gcs.flight.dryrun import sim_speed
from mavlink.mock import MockFleet
from mavlink.mock.testing import free_udp_ports
from tests.mavlink.test_mock_mavsdk import first

pytestmark = pytest.mark.slow  # flights and discovery over UDP (make test-fast skips)

NAN = math.nan
CAMERA = 100


async def with_system(fleet: MockFleet, gcs_port: int, body: Callable[[System], Any]) -> None:
    async with fleet:
        config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        async with Mavsdk(config) as sdk:
            await sdk.add_any_connection(f"udpin://127.0.0.1:{gcs_port}")
            system = await sdk.first_autopilot(timeout_s=10.0)
            assert system is not None
            await body(system)


class Captures:
    """MAVSDK's capture_info, collected in the background."""

    def __init__(self, camera: CameraAsync) -> None:
        self.items: list[Any] = []
        self._task = asyncio.ensure_future(self._run(camera))

    async def _run(self, camera: CameraAsync) -> None:
        async for info in camera.subscribe_capture_info():
            self.items.append(info)

    async def wait(self, n: int, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while len(self.items) < n and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
        assert len(self.items) >= n, f"{len(self.items)} of {n} pictures"

    def stop(self) -> None:
        self._task.cancel()


def test_mavsdk_camera_plugin_finds_the_camera_and_takes_pictures() -> None:
    gcs_port, vehicle_port = free_udp_ports(2)
    fleet = MockFleet(speed=sim_speed(), n=1, gcs_ports=[gcs_port], vehicle_ports=[vehicle_port], seed=2, ready_after_s=0.0)  # fmt: skip

    async def body(system: System) -> None:
        camera = CameraAsync(system)
        found = await first(camera.subscribe_camera_list(), lambda c: bool(c.cameras), 10.0)
        (cam,) = found.cameras
        assert (cam.component_id, cam.vendor_name, cam.model_name) == (CAMERA, "stl-gcs", "mock camera")  # fmt: skip
        assert cam.focal_length_mm == pytest.approx(4.5)
        assert (cam.horizontal_sensor_size_mm, cam.vertical_sensor_size_mm) == pytest.approx((6.17, 4.55))  # fmt: skip
        assert (cam.horizontal_resolution_px, cam.vertical_resolution_px) == (4000, 3000)
        captures = Captures(camera)
        await asyncio.sleep(0.2)
        await camera.take_photo(CAMERA)
        await captures.wait(1, 5.0)
        await camera.start_photo_interval(CAMERA, 0.5)
        await captures.wait(4, 5.0)
        await camera.stop_photo_interval(CAMERA)
        await asyncio.sleep(1.0)
        captures.stop()
        shots = captures.items
        assert len(shots) == 4 and [s.index for s in shots] == [0, 1, 2, 3]
        assert all(s.component_id == CAMERA and s.is_success for s in shots)
        dt = [(b.time_utc_us - a.time_utc_us) / 1e6 for a, b in itertools.pairwise(shots[1:])]
        assert dt == pytest.approx([0.5, 0.5], abs=0.011)
        lat, lon, alt = fleet.vehicles[0].spawn_lla
        for s in shots:  # on the ground at its spawn point, a level camera looking ahead
            n, e, _ = pymap3d.geodetic2ned(
                s.position.latitude_deg, s.position.longitude_deg, s.position.absolute_altitude_m,
                lat, lon, alt,
            )  # fmt: skip
            assert math.hypot(n, e) < 1.0 and abs(s.position.relative_altitude_m) < 0.5
            assert abs(s.attitude_euler_angle.pitch_deg) < 1e-3

    asyncio.run(with_system(fleet, gcs_port, body))


def test_mavsdk_gimbal_plugin_finds_the_gimbal_takes_control_and_points_it() -> None:
    gcs_port, vehicle_port = free_udp_ports(2)
    fleet = MockFleet(speed=sim_speed(), n=1, gcs_ports=[gcs_port], vehicle_ports=[vehicle_port], seed=3, ready_after_s=0.0)  # fmt: skip

    async def body(system: System) -> None:
        gimbal = GimbalAsync(system)
        found = await first(gimbal.subscribe_gimbal_list(), lambda g: bool(g.gimbals), 10.0)
        (item,) = found.gimbals
        assert (item.gimbal_manager_component_id, item.gimbal_device_id) == (1, 154)
        assert (item.vendor_name, item.model_name) == ("stl-gcs", "mock gimbal")
        gid = item.gimbal_id
        await gimbal.take_control(gid, ControlMode.PRIMARY)
        status = await first(
            gimbal.subscribe_control_status(), lambda s: s.control_mode == ControlMode.PRIMARY, 5.0
        )
        assert (status.sysid_primary_control, status.compid_primary_control) == (245, 190)
        await gimbal.set_angles(gid, 0.0, -40.0, 30.0, GimbalMode.YAW_FOLLOW, SendMode.ONCE)
        attitude = await first(
            gimbal.subscribe_attitude(),
            lambda a: abs(a.euler_angle_forward.pitch_deg + 40.0) < 0.1,
            3.0,
        )
        assert attitude.euler_angle_forward.yaw_deg == pytest.approx(30.0, abs=0.5)
        v = fleet.vehicles[0]
        assert v.gimbal is not None and v.gimbal.primary == (245, 190)
        await gimbal.release_control(gid)
        await asyncio.sleep(0.2)
        assert v.gimbal.primary == (0, 0)

    asyncio.run(with_system(fleet, gcs_port, body))


def capture_mission(fleet: MockFleet, hold2_s: float, interval_s: float) -> list[MissionItem]:
    """The ground station's capture template (takeoff, hover at A, capture during a second
    waypoint at A, on to B), as mission_raw items."""
    v = fleet.vehicles[0]

    def e7(north_m: float, east_m: float) -> tuple[int, int]:
        lat, lon, _ = pymap3d.ned2geodetic(north_m, east_m, 0.0, *v.spawn_lla)
        return round(float(lat) * 1e7), round(float(lon) * 1e7)

    rows: list[tuple[Any, ...]] = [
        (6, 22, 0, 0, 0, NAN, *e7(0, 0), 4.0),  # NAV_TAKEOFF
        (6, 16, 1.0, 0.5, 0, NAN, *e7(5, 0), 4.0),  # NAV_WAYPOINT A, hold 1 s
        (2, 1001, -2, -2, -1, -1, 0, 0, 0.0),  # DO_GIMBAL_MANAGER_CONFIGURE: the autopilot
        (2, 1000, -45, 0, NAN, NAN, 0, 0, 0.0),  # DO_GIMBAL_MANAGER_PITCHYAW
        (2, 2000, 0, interval_s, 0, 0, 0, 0, 0.0),  # IMAGE_START_CAPTURE
        (6, 16, hold2_s, 0.5, 0, NAN, *e7(5, 0), 4.0),  # NAV_WAYPOINT A again: the capture
        (2, 2001, 0, 0, 0, 0, 0, 0, 0.0),  # IMAGE_STOP_CAPTURE
        (2, 178, 1, 3, -1, 0, 0, 0, 0.0),  # DO_CHANGE_SPEED
        (6, 16, 0, 0.5, 0, NAN, *e7(5, 3), 4.0),  # NAV_WAYPOINT B: the mission ends there
    ]
    return [
        MissionItem(seq, frame, cmd, int(seq == 0), 1, p1, p2, p3, p4, x, y, z, 0)
        for seq, (frame, cmd, p1, p2, p3, p4, x, y, z) in enumerate(rows)
    ]


def same(a: MissionItem, b: MissionItem) -> bool:
    fields = ("seq", "frame", "command", "autocontinue", "param1", "param2", "param3")
    fields += ("param4", "x", "y", "z", "mission_type")

    def eq(x: Any, y: Any) -> bool:
        if isinstance(x, float) and math.isnan(x):
            return isinstance(y, float) and math.isnan(y)
        return bool(x == pytest.approx(y, rel=1e-6))

    return all(eq(getattr(a, f), getattr(b, f)) for f in fields)


def test_mavsdk_mission_raw_reads_camera_items_back_and_the_flight_pictures_the_hold() -> None:
    gcs_port, vehicle_port = free_udp_ports(2)
    fleet = MockFleet(
        speed=sim_speed(),
        n=1, gcs_ports=[gcs_port], vehicle_ports=[vehicle_port], seed=4, ready_after_s=0.0,
        params={"MPC_LAND_SPEED": 1.5, "COM_DISARM_LAND": 0.5},
    )  # fmt: skip
    hold2_s, interval_s = 3.5, 1.0

    async def body(system: System) -> None:
        v = fleet.vehicles[0]
        mission = MissionRawAsync(system)
        items = capture_mission(fleet, hold2_s, interval_s)
        await mission.upload_mission(items)
        back = await mission.download_mission()
        assert len(back) == len(items)
        assert all(same(a, b) for a, b in zip(items, back, strict=True))
        captures = Captures(CameraAsync(system))
        await first(TelemetryAsync(system).subscribe_health(), lambda h: h.is_armable, 10.0)
        await ActionAsync(system).arm()
        await mission.start_mission()
        # (simulation time of the last look before the change, of the first after, current
        # item): a look comes when the event loop gets to it, late on a busy machine, so a
        # change is known to lie between the two looks, not at the second
        timeline: list[tuple[float, float, int]] = []
        deadline = time.monotonic() + 60.0
        t_look = fleet.time_s
        while time.monotonic() < deadline and not v.mission_finished:
            t_before, t_look = t_look, fleet.time_s
            if not timeline or timeline[-1][2] != v.mission_seq:
                timeline.append((t_before, t_look, v.mission_seq))
            await asyncio.sleep(0.005)
        await asyncio.sleep(0.5)
        captures.stop()
        assert v.mission_finished
        after, start = next((a, b) for a, b, s in timeline if s == 5)
        end = next(b for _, b, s in timeline if s > 5)
        shots = captures.items
        assert len(shots) == math.floor(hold2_s / interval_s) + 1
        t = [(s.time_utc_us / 1e6) - fleet.utc_start_s for s in shots]
        # the first picture when the capture's item began (one simulation step either side)
        assert after - 0.03 <= t[0] <= start + 0.03 and t[-1] <= end + 0.01
        assert [b - a for a, b in itertools.pairwise(t)] == pytest.approx([1.0] * 3, abs=0.011)
        # the gimbal came down at 90 deg/s after the first picture
        assert [s.attitude_euler_angle.pitch_deg for s in shots[1:]] == pytest.approx([-45.0] * 3, abs=0.01)  # fmt: skip

    asyncio.run(with_system(fleet, gcs_port, body))
