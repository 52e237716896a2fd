"""The mock vehicle's payload: a MAVLink camera (component 100) on a gimbal PX4 manages.

Over a real UDP socket (pymavlink, :class:`mavlink.mock.testing.GcsEndpoint`): the camera's
and the gimbal device's heartbeats, the camera's answers to requests, interval captures
(count, spacing, the reported position and the camera attitude decoded independently with
scipy), the gimbal manager's control rules and the device's turn rate, and a vehicle
without a camera.  Offline (:meth:`MockFleet.advance`, the vehicle spoken to in MAVLink
bytes, deterministic for the seed): the gimbal following a ROI as the vehicle moves, and
missions with camera and gimbal items flown as PX4 v1.17's navigator flies them
(``docs/px4-behaviour.md``, "Cameras and gimbals"; PX4's ``MissionBlock::issue_command``,
``Navigator::publish_vehicle_command``, the ``gimbal`` module), in both profiles.  The
MAVSDK clients (mission_raw round trip, Camera and Gimbal plugins) are in
test_mock_camera_mavsdk.py.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pymap3d
import pytest
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation

from gcs.flight.dryrun import sim_speed
from mavlink.mock import MissionItem, MockFleet, MockVehicleConfig, Px4Mode
from mavlink.mock.sim.config import CameraSpec
from mavlink.mock.testing import GcsEndpoint, free_udp_ports
from mavlink.mock.vehicle import MockVehicle

ORIGIN = (47.397742, 8.545594, 488.0)
CAMERA, GIMBAL, AUTOPILOT = 100, 154, 1
NAN = math.nan
Msg = Any


# ================================================================ helpers
@contextmanager
def udp_vehicle(**kwargs: Any) -> Iterator[tuple[MockFleet, GcsEndpoint]]:
    """One mock vehicle running in a thread on free loopback ports, a pymavlink GCS on it."""
    (vport,) = free_udp_ports(1)
    gcs = GcsEndpoint(vport, target_system=1)
    kwargs.setdefault("ready_after_s", 0.0)
    fleet = MockFleet(speed=sim_speed(), n=1, origin=ORIGIN, gcs_ports=[gcs.port], vehicle_ports=[vport], seed=11, **kwargs)  # fmt: skip
    try:
        with fleet.running_in_thread():
            assert gcs.recv("HEARTBEAT", 5.0) is not None  # the vehicle talks to us
            yield fleet, gcs
    finally:
        gcs.close()


def command_to(
    gcs: GcsEndpoint, component: int, command: int, *params: float, timeout_s: float = 2.0
) -> Msg | None:
    """COMMAND_LONG to (1, ``component``); the COMMAND_ACK that ``component`` sends back."""
    p = [float(v) for v in params] + [0.0] * (7 - len(params))
    gcs.drain()
    gcs.send(mavlink2.MAVLink_command_long_message(1, component, command, 0, *p))
    return gcs.recv(
        "COMMAND_ACK",
        timeout_s,
        lambda m: m.command == command and m.get_srcComponent() == component,
    )


def collect(gcs: GcsEndpoint, seconds: float) -> list[Msg]:
    return list(gcs.messages(seconds))


def ypr_deg(q: Any) -> tuple[float, float, float]:
    """(yaw, pitch, roll) in degrees of a MAVLink quaternion (w, x, y, z), by scipy."""
    w, x, y, z = (float(v) for v in q)
    yaw, pitch, roll = Rotation.from_quat([x, y, z, w]).as_euler("ZYX", degrees=True)
    return float(yaw), float(pitch), float(roll)


def wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def offline(profile: str = "px4", camera: bool = True, **params: float) -> MockFleet:
    f = MockFleet(
        n=1, origin=ORIGIN, seed=5, profile=profile, params=params or None, ready_after_s=0.0,
        camera=camera, utc_start_s=1.75e9,
    )  # fmt: skip
    f.offline_links()
    return f


def send_command(
    v: MockVehicle, command: int, *params: float, component: int = AUTOPILOT
) -> list[Msg]:
    """COMMAND_LONG from (255, 190) to (sysid, ``component``); what the vehicle sent back."""
    p = [float(x) for x in params] + [0.0] * (7 - len(params))
    v.sent_messages()
    v.receive(mavlink2.MAVLink_command_long_message(v.sysid, component, command, 0, *p))
    return v.sent_messages()


def acks(msgs: list[Msg], command: int) -> list[tuple[int, int]]:
    """(sender component, result) of the COMMAND_ACKs for ``command``."""
    return [
        (m.get_srcComponent(), m.result)
        for m in msgs
        if m.get_type() == "COMMAND_ACK" and m.command == command
    ]


def e7(v: MockVehicle, north_m: float, east_m: float) -> tuple[int, int]:
    lat, lon, _ = pymap3d.ned2geodetic(north_m, east_m, 0.0, *v.spawn_lla)
    return round(float(lat) * 1e7), round(float(lon) * 1e7)


@dataclass
class Flight:
    """What an offline flight gave: the vehicle's messages, and its current mission item
    tick by tick (``seq_s``: (simulation time, seq) at every change)."""

    msgs: list[Msg] = field(default_factory=list)
    seq_s: list[tuple[float, int]] = field(default_factory=list)

    def of(self, kind: str) -> list[Msg]:
        return [m for m in self.msgs if m.get_type() == kind]

    def window(self, seq: int) -> tuple[float, float]:
        """When item ``seq`` became current and when the mission moved past it (s)."""
        start = next(t for t, s in self.seq_s if s == seq)
        end = next(t for t, s in self.seq_s if s > seq)
        return start, end


def fly(f: MockFleet, v: MockVehicle, items: list[MissionItem], seconds: float) -> Flight:
    """Store ``items``, arm, AUTO.MISSION, and fly ``seconds`` tick by tick."""
    v.store_plan(items)
    f.advance(0.5)  # past PX4's mission-start window after an upload
    assert v.arm() == mavlink2.MAV_RESULT_ACCEPTED
    assert v.request_mode(Px4Mode.AUTO_MISSION) == mavlink2.MAV_RESULT_ACCEPTED
    flight = Flight()
    v.sent_messages()
    last = -1
    for _ in range(round(seconds / f.dt_s)):
        f.advance(f.dt_s)
        if v.mission_seq != last:
            last = v.mission_seq
            flight.seq_s.append((f.time_s, last))
        flight.msgs += v.sent_messages()
        if v.mission_finished and v.landed and not v.armed:
            break
    return flight


def camera_mission(
    v: MockVehicle, *, hold1_s: float, hold2_s: float, interval_s: float,
    pitch_deg: float | None, configure: bool = True, roi: tuple[float, float] | None = None,
) -> tuple[list[MissionItem], dict[str, int]]:  # fmt: skip
    """The ground station's capture template at A = 10 m north, 6 m up: NAV_WAYPOINT(hold1)
    [ROI] [GIMBAL_MANAGER_CONFIGURE] [GIMBAL_MANAGER_PITCHYAW] IMAGE_START_CAPTURE
    NAV_WAYPOINT(same position, hold2) IMAGE_STOP_CAPTURE DO_CHANGE_SPEED, then on to B and
    land; returns the items and the seqs of its waypoints by name."""
    items: list[MissionItem] = []
    seqs: dict[str, int] = {}
    rel = mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    mis = mavlink2.MAV_FRAME_MISSION

    def add(frame: int, command: int, *p: float, x: int = 0, y: int = 0, z: float = 0.0) -> None:
        q = [*p, *([0.0] * (4 - len(p)))]
        items.append(MissionItem(len(items), frame, command, 0, 1, *q, x, y, z, 0))

    home = e7(v, 0.0, 0.0)
    a = e7(v, 10.0, 0.0)
    b = e7(v, 10.0, 12.0)
    add(rel, mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, x=home[0], y=home[1], z=6.0)
    seqs["wp1"] = len(items)
    add(rel, mavlink2.MAV_CMD_NAV_WAYPOINT, hold1_s, 0.5, 0, NAN, x=a[0], y=a[1], z=6.0)
    if roi is not None:
        r = e7(v, *roi)
        add(rel, mavlink2.MAV_CMD_DO_SET_ROI_LOCATION, 0, 0, 0, 0, x=r[0], y=r[1], z=0.0)
    if configure and pitch_deg is not None:
        add(mis, mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, -2, -2, -1, -1)
    if pitch_deg is not None:
        add(mis, mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, pitch_deg, 0.0, NAN, NAN)
    seqs["start"] = len(items)
    add(mis, mavlink2.MAV_CMD_IMAGE_START_CAPTURE, 0, interval_s, 0, 0)
    seqs["wp2"] = len(items)
    add(rel, mavlink2.MAV_CMD_NAV_WAYPOINT, hold2_s, 0.5, 0, NAN, x=a[0], y=a[1], z=6.0)
    add(mis, mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE, 0)
    add(mis, mavlink2.MAV_CMD_DO_CHANGE_SPEED, 1, 3, -1, 0)
    add(rel, mavlink2.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, NAN, x=b[0], y=b[1], z=6.0)
    add(rel, mavlink2.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, x=b[0], y=b[1], z=0.0)
    return items, seqs


# ================================================================ the camera over UDP
@pytest.mark.slow
def test_camera_and_gimbal_device_heartbeat_from_their_own_components() -> None:
    with udp_vehicle() as (fleet, gcs):
        gcs.drain()
        first = gcs.recv("HEARTBEAT", 3.0)
        t0 = fleet.time_s
        beats = [m for m in collect(gcs, 2.6) if m.get_type() == "HEARTBEAT"]
        span_s = fleet.time_s - t0  # of the vehicle's time (it may run faster than real time)
    # a client taking "the next HEARTBEAT" still gets the autopilot's
    assert first is not None and first.get_srcComponent() == AUTOPILOT
    by_comp: dict[int, list[Msg]] = {}
    for b in beats:
        assert b.get_srcSystem() == 1
        by_comp.setdefault(b.get_srcComponent(), []).append(b)
    assert sorted(by_comp) == [AUTOPILOT, CAMERA, GIMBAL]
    assert all(b.autopilot == mavlink2.MAV_AUTOPILOT_PX4 for b in by_comp[AUTOPILOT])
    for comp, mav_type in ((CAMERA, mavlink2.MAV_TYPE_CAMERA), (GIMBAL, mavlink2.MAV_TYPE_GIMBAL)):
        assert abs(len(by_comp[comp]) - span_s) <= 1.01  # 1 Hz
        assert all(b.type == mav_type for b in by_comp[comp])
        assert all(b.autopilot == mavlink2.MAV_AUTOPILOT_INVALID for b in by_comp[comp])
    # each component numbers its own frames: the camera sent nothing else in between
    cam = by_comp[CAMERA]
    assert all((b.get_seq() - a.get_seq()) % 256 == 1 for a, b in itertools.pairwise(cam))


def test_camera_answers_requests_for_its_information_settings_and_status() -> None:
    spec = CameraSpec(vendor="acme", model="inspector 8", focal_length_mm=8.0, resolution_h_px=5472)
    with udp_vehicle(vehicle_configs=[MockVehicleConfig(camera_spec=spec)]) as (_fleet, gcs):
        ack = command_to(gcs, CAMERA, mavlink2.MAV_CMD_REQUEST_MESSAGE, 259)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
        assert (ack.target_system, ack.target_component) == (255, 190)
        info = gcs.recv("CAMERA_INFORMATION", 2.0)
        assert info is not None and info.get_srcComponent() == CAMERA
        assert bytes(info.vendor_name).rstrip(b"\0") == b"acme"
        assert bytes(info.model_name).rstrip(b"\0") == b"inspector 8"
        assert info.focal_length == pytest.approx(8.0)
        assert (info.sensor_size_h, info.sensor_size_v) == pytest.approx((6.17, 4.55))
        assert (info.resolution_h, info.resolution_v) == (5472, 3000)
        assert info.flags == mavlink2.CAMERA_CAP_FLAGS_CAPTURE_IMAGE
        assert info.cam_definition_uri == ""
        # the legacy request MAVSDK falls back to on its retries
        ack = command_to(gcs, CAMERA, mavlink2.MAV_CMD_REQUEST_CAMERA_INFORMATION, 1)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
        assert gcs.recv("CAMERA_INFORMATION", 2.0) is not None
        ack = command_to(gcs, CAMERA, mavlink2.MAV_CMD_REQUEST_MESSAGE, 260)
        settings = gcs.recv("CAMERA_SETTINGS", 2.0)
        assert ack.result == 0 and settings.mode_id == mavlink2.CAMERA_MODE_IMAGE
        ack = command_to(gcs, CAMERA, mavlink2.MAV_CMD_REQUEST_MESSAGE, 262)
        status = gcs.recv("CAMERA_CAPTURE_STATUS", 2.0)
        assert ack.result == 0 and status.image_count == 0 and status.image_status == 0
        # what it has not: a video stream, a zoom
        ack = command_to(gcs, CAMERA, mavlink2.MAV_CMD_REQUEST_MESSAGE, 269)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_DENIED
        ack = command_to(gcs, CAMERA, mavlink2.MAV_CMD_SET_CAMERA_ZOOM, 1, 1)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_UNSUPPORTED
        # the autopilot is no camera (PX4: DENIED, UNSUPPORTED)
        ack = command_to(gcs, AUTOPILOT, mavlink2.MAV_CMD_REQUEST_MESSAGE, 259)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_DENIED
        ack = command_to(gcs, AUTOPILOT, mavlink2.MAV_CMD_IMAGE_START_CAPTURE, 0, 1, 0)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_UNSUPPORTED


@pytest.mark.slow
def test_interval_capture_takes_its_total_at_the_interval_with_position_and_attitude() -> None:
    with udp_vehicle() as (_fleet, gcs):
        # every tick's position and attitude, to compare each picture with
        for msg_id in (33, 30):  # GLOBAL_POSITION_INT, ATTITUDE at 100 Hz
            assert command_to(gcs, 1, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 10000).result == 0  # fmt: skip
        configure = mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE
        assert command_to(gcs, AUTOPILOT, configure, 255, 190, -1, -1).result == 0
        pitchyaw = mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
        assert command_to(gcs, AUTOPILOT, pitchyaw, -30, 40, NAN, NAN, 0).result == 0
        time.sleep(0.8)  # 40 deg at 90 deg/s
        ack = command_to(gcs, CAMERA, mavlink2.MAV_CMD_IMAGE_START_CAPTURE, 0, 0.3, 4, 0)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
        msgs = collect(gcs, 2.0)  # 4 pictures in 0.9 s, then nothing more
    shots = [m for m in msgs if m.get_type() == "CAMERA_IMAGE_CAPTURED"]
    assert [s.image_index for s in shots] == [0, 1, 2, 3]
    assert all(s.get_srcComponent() == CAMERA and s.capture_result == 1 for s in shots)
    assert np.diff([s.time_boot_ms for s in shots]) == pytest.approx([300] * 3, abs=10)
    positions = {m.time_boot_ms: m for m in msgs if m.get_type() == "GLOBAL_POSITION_INT"}
    attitudes = {m.time_boot_ms: m for m in msgs if m.get_type() == "ATTITUDE"}
    for s in shots[1:]:  # (the first came with the command, between two ticks)
        gpi = positions[s.time_boot_ms]
        assert (s.lat, s.lon, s.alt, s.relative_alt) == (gpi.lat, gpi.lon, gpi.alt, gpi.relative_alt)  # fmt: skip
        yaw, pitch, roll = ypr_deg(s.q)
        heading = math.degrees(attitudes[s.time_boot_ms].yaw)
        assert wrap_deg(yaw - heading - 40.0) == pytest.approx(0.0, abs=0.01)
        assert (pitch, roll) == pytest.approx((-30.0, 0.0), abs=0.01)
        assert s.time_utc > 1.6e15 and s.file_url.endswith(".JPG")


@pytest.mark.slow
def test_capture_until_stopped_and_the_checks_of_its_parameters() -> None:
    start, stop = mavlink2.MAV_CMD_IMAGE_START_CAPTURE, mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE
    with udp_vehicle() as (_fleet, gcs):
        for bad in ((0, -1, 0, 0), (0, 0, 0, 0), (0, 0, 3, 0), (0, 1, -1, 0), (0, NAN, 0, 0)):
            ack = command_to(gcs, CAMERA, start, *bad)
            assert ack is not None and ack.result == mavlink2.MAV_RESULT_DENIED, bad
        assert command_to(gcs, CAMERA, start, 0, 0.25, 0, 0).result == 0  # until stopped
        shots = []
        for m in gcs.messages(3.0):
            if m.get_type() == "CAMERA_IMAGE_CAPTURED":
                shots.append(m)
                if len(shots) == 3:
                    break
        assert command_to(gcs, CAMERA, stop).result == 0
        shots += [m for m in collect(gcs, 1.0) if m.get_type() == "CAMERA_IMAGE_CAPTURED"]
        assert [s.image_index for s in shots] == [0, 1, 2]
        # a single picture; its command re-sent with the same sequence number takes no second
        for seq, pictures in ((7, 1), (7, 0), (8, 1)):
            assert command_to(gcs, CAMERA, start, 0, 0, 1, seq).result == 0
            got = [m for m in collect(gcs, 0.4) if m.get_type() == "CAMERA_IMAGE_CAPTURED"]
            assert len(got) == pictures
        assert command_to(gcs, CAMERA, mavlink2.MAV_CMD_REQUEST_MESSAGE, 262).result == 0
        status = gcs.recv("CAMERA_CAPTURE_STATUS", 2.0)
        assert status is not None and status.image_count == 5
        # a picture asked for again (a client that missed it)
        assert command_to(gcs, CAMERA, mavlink2.MAV_CMD_REQUEST_MESSAGE, 263, 1).result == 0
        again = gcs.recv("CAMERA_IMAGE_CAPTURED", 2.0)
        assert again is not None and again.image_index == 1
        assert again.time_boot_ms == shots[1].time_boot_ms
        missing = command_to(gcs, CAMERA, mavlink2.MAV_CMD_REQUEST_MESSAGE, 263, 99)
        assert missing is not None and missing.result == mavlink2.MAV_RESULT_DENIED


def test_a_broadcast_gets_one_ack_from_the_autopilot_and_the_cameras_for_what_is_its() -> None:
    f = offline()
    v = f.vehicles[0]
    msgs = send_command(v, mavlink2.MAV_CMD_REQUEST_MESSAGE, 259, component=0)
    assert acks(msgs, mavlink2.MAV_CMD_REQUEST_MESSAGE) == [(AUTOPILOT, 2), (CAMERA, 0)]
    assert [m.get_srcComponent() for m in msgs if m.get_type() == "CAMERA_INFORMATION"] == [CAMERA]  # fmt: skip
    msgs = send_command(v, mavlink2.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1, component=0)
    assert acks(msgs, mavlink2.MAV_CMD_IMAGE_START_CAPTURE) == [(AUTOPILOT, 3), (CAMERA, 0)]
    # what the camera does not implement: the autopilot's ACK alone
    msgs = send_command(v, mavlink2.MAV_CMD_REQUEST_MESSAGE, 148, component=0)
    assert acks(msgs, mavlink2.MAV_CMD_REQUEST_MESSAGE) == [(AUTOPILOT, 0)]
    msgs = send_command(v, mavlink2.MAV_CMD_DO_SET_HOME, 1, component=0)
    assert acks(msgs, mavlink2.MAV_CMD_DO_SET_HOME) == [(AUTOPILOT, 0)]


# ================================================================ the gimbal over UDP
@pytest.mark.slow
def test_gimbal_manager_takes_pitchyaw_from_its_primary_control_and_turns_at_its_rate() -> None:
    pitchyaw = mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
    configure = mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE
    with udp_vehicle() as (_fleet, gcs):
        # nobody is in control at boot: PX4 denies the command (InputMavlinkGimbalV2)
        ack = command_to(gcs, AUTOPILOT, pitchyaw, -60, 90, NAN, NAN, 0)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_DENIED
        assert command_to(gcs, AUTOPILOT, configure, 255, 190, -1, -1).result == 0
        assert command_to(gcs, AUTOPILOT, mavlink2.MAV_CMD_REQUEST_MESSAGE, 281).result == 0
        status = gcs.recv("GIMBAL_MANAGER_STATUS", 2.0)
        assert status is not None and status.get_srcComponent() == AUTOPILOT
        assert (status.primary_control_sysid, status.primary_control_compid) == (255, 190)
        assert status.gimbal_device_id == GIMBAL
        ack = command_to(gcs, AUTOPILOT, pitchyaw, -60, 60, NAN, NAN, 0)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
        msgs = collect(gcs, 1.0)
        # beyond the device's limits: clamped to [-90, +30]
        assert command_to(gcs, AUTOPILOT, pitchyaw, 60, 0, NAN, NAN, 0).result == 0
        high = collect(gcs, 1.2)
        assert command_to(gcs, AUTOPILOT, mavlink2.MAV_CMD_REQUEST_MESSAGE, 280).result == 0
        info = gcs.recv("GIMBAL_MANAGER_INFORMATION", 2.0)
        assert command_to(gcs, AUTOPILOT, mavlink2.MAV_CMD_REQUEST_MESSAGE, 148).result == 0
        version = gcs.recv("AUTOPILOT_VERSION", 2.0)
        ack = command_to(gcs, GIMBAL, mavlink2.MAV_CMD_REQUEST_MESSAGE, 283)
        device = gcs.recv("GIMBAL_DEVICE_INFORMATION", 2.0)
        # released: the next command is denied again
        assert command_to(gcs, AUTOPILOT, configure, -3, -3, -1, -1).result == 0
        assert command_to(gcs, AUTOPILOT, pitchyaw, 0, 0, NAN, NAN, 0).result == 2
    statuses = [m for m in msgs if m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"]
    assert all(m.get_srcComponent() == GIMBAL for m in statuses)
    t = np.array([m.time_boot_ms for m in statuses]) / 1000.0
    assert np.diff(t) == pytest.approx(0.1, abs=0.011)  # 10 Hz
    ypr = np.array([ypr_deg(m.q) for m in statuses])
    yaw, pitch = ypr[:, 0], ypr[:, 1]
    # 90 deg/s on each axis until there, then there (yaw in the vehicle frame)
    moving = (pitch > -59.9) & (pitch < -0.1)
    assert moving.sum() >= 3
    rate = np.diff(pitch) / np.diff(t)
    assert rate[moving[1:] & moving[:-1]] == pytest.approx(-90.0, abs=1.0)
    assert (pitch[-1], yaw[-1]) == pytest.approx((-60.0, 60.0), abs=1e-3)
    assert all(m.flags & mavlink2.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME for m in statuses)
    assert not statuses[-1].flags & mavlink2.GIMBAL_DEVICE_FLAGS_YAW_LOCK
    last = [m for m in high if m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"][-1]
    assert ypr_deg(last.q)[1] == pytest.approx(30.0, abs=1e-3)
    assert info is not None and info.gimbal_device_id == GIMBAL
    assert (math.degrees(info.pitch_min), math.degrees(info.pitch_max)) == pytest.approx((-90, 30))  # fmt: skip
    cap = mavlink2.MAV_PROTOCOL_CAPABILITY_COMPONENT_IMPLEMENTS_GIMBAL_MANAGER
    assert version is not None and version.capabilities & cap
    assert ack is not None and ack.result == 0 and device is not None
    assert device.get_srcComponent() == GIMBAL


def test_gimbal_yaw_lock_holds_a_bearing_while_the_vehicle_turns() -> None:
    f = offline()
    v = f.vehicles[0]
    airborne(f, v, 5.0)
    # -2 is "the autopilot itself": a client must name itself to send PITCHYAW
    send_command(v, mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, -2, -2, -1, -1)
    assert v.gimbal is not None and v.gimbal.primary == (1, 1)
    send_command(v, mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, 255, 190, -1, -1)
    assert v.gimbal.primary == (255, 190)
    lock = float(mavlink2.GIMBAL_MANAGER_FLAGS_YAW_LOCK)
    msgs = send_command(v, mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, -20, 120, NAN, NAN, lock)
    assert acks(msgs, mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW) == [(AUTOPILOT, 0)]
    f.advance(2.0)
    # the vehicle yaws to 90 deg; the camera keeps looking 120 deg from north
    reposition(v, 0.0, 0.0, 5.0, yaw_deg=90.0)
    for _ in range(10):
        f.advance(0.5)
        yaw, pitch, _ = ypr_deg(v.camera_q())
        assert wrap_deg(yaw - 120.0) == pytest.approx(0.0, abs=0.5)
        assert pitch == pytest.approx(-20.0, abs=1e-6)
    assert math.degrees(float(f.physics.yaw_rad[0])) == pytest.approx(90.0, abs=2.0)


def airborne(f: MockFleet, v: MockVehicle, above_home_m: float) -> None:
    assert v.arm() == mavlink2.MAV_RESULT_ACCEPTED
    alt = v.home_alt_amsl() + above_home_m
    send_command(v, mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, alt)
    f.advance(12.0)
    assert v.mode is Px4Mode.AUTO_LOITER and not v.landed


def reposition(v: MockVehicle, north_m: float, east_m: float, up_m: float, yaw_deg: float = NAN) -> None:  # fmt: skip
    lat, lon = e7(v, north_m, east_m)
    alt = v.home_alt_amsl() + up_m
    v.receive(
        mavlink2.MAVLink_command_int_message(
            v.sysid, 1, mavlink2.MAV_FRAME_GLOBAL_INT, mavlink2.MAV_CMD_DO_REPOSITION, 0, 0,
            -1, 1, 0, math.radians(yaw_deg), lat, lon, alt,
        )
    )  # fmt: skip


def test_gimbal_follows_a_roi_as_the_vehicle_moves_and_goes_neutral_after() -> None:
    f = offline(profile="ideal")
    v = f.vehicles[0]
    airborne(f, v, 10.0)
    home_alt = v.home_alt_amsl()
    roi_lat, roi_lon = e7(v, 40.0, 30.0)  # on the ground, 50 m away
    v.sent_messages()
    v.receive(
        mavlink2.MAVLink_command_int_message(
            v.sysid, 1, mavlink2.MAV_FRAME_GLOBAL, mavlink2.MAV_CMD_DO_SET_ROI_LOCATION, 0, 0,
            0, 0, 0, 0, roi_lat, roi_lon, home_alt,
        )
    )  # fmt: skip
    assert acks(v.sent_messages(), mavlink2.MAV_CMD_DO_SET_ROI_LOCATION) == [(AUTOPILOT, 0)]
    f.advance(2.0)
    reposition(v, -20.0, 15.0, 10.0)  # a leg across the line of sight
    errors = []
    for _ in range(40):
        f.advance(0.25)
        msgs = v.sent_messages()
        gpi = [m for m in msgs if m.get_type() == "GLOBAL_POSITION_INT"][-1]
        status = [m for m in msgs if m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"][-1]
        # the expected pointing, from the reported position (independent geodesy)
        e, n, u = pymap3d.geodetic2enu(
            roi_lat / 1e7, roi_lon / 1e7, home_alt, gpi.lat / 1e7, gpi.lon / 1e7, gpi.alt / 1000
        )
        bearing = math.degrees(math.atan2(e, n))
        depression = math.degrees(math.atan2(u, math.hypot(e, n)))
        yaw_rel, pitch, _ = ypr_deg(status.q)  # the device: yaw to the vehicle's heading
        yaw = yaw_rel + math.degrees(status.delta_yaw)
        assert status.flags & mavlink2.GIMBAL_DEVICE_FLAGS_YAW_LOCK
        errors.append((wrap_deg(yaw - bearing), pitch - depression))
    assert np.abs(np.array(errors)).max() < 1.0
    assert v.state.pos_ned_m[0] == pytest.approx(-20.0, abs=0.5)  # it did move
    msgs = send_command(v, mavlink2.MAV_CMD_DO_SET_ROI_NONE)
    assert acks(msgs, mavlink2.MAV_CMD_DO_SET_ROI_NONE) == [(AUTOPILOT, 0)]
    f.advance(3.0)
    yaw, pitch, _ = ypr_deg(v.camera_q())
    # neutral: level, and (PX4 keeps the ROI's absolute-yaw flag) toward north
    assert (pitch, wrap_deg(yaw)) == pytest.approx((0.0, 0.0), abs=1e-6)


# ================================================================ missions (offline)
@pytest.mark.parametrize("profile", ["px4", "ideal"])
@pytest.mark.parametrize("hold1_s", [2.0, 0.0])
@pytest.mark.slow
def test_mission_takes_its_pictures_during_the_second_waypoints_hold(profile: str, hold1_s: float) -> None:  # fmt: skip
    f = offline(profile)
    v = f.vehicles[0]
    items, seqs = camera_mission(v, hold1_s=hold1_s, hold2_s=3.5, interval_s=1.0, pitch_deg=-45)
    flight = fly(f, v, items, 60.0)
    assert v.mission_finished and v.landed  # flown to the end
    start, end = flight.window(seqs["wp2"])
    # the second waypoint, where the vehicle already is, is reached at once: its hold
    assert end - start == pytest.approx(3.5 + f.dt_s, abs=0.015)
    shots = flight.of("CAMERA_IMAGE_CAPTURED")
    t = np.array([s.time_boot_ms for s in shots]) / 1000.0
    assert len(shots) == math.floor(3.5 / 1.0) + 1  # at once, then every second
    assert t[0] == pytest.approx(start, abs=0.011) and t[-1] <= end
    assert np.diff(t) == pytest.approx([1.0] * 3, abs=0.011)
    # at the waypoint (A: 10 m north, 6 m above home), as the autopilot reports it
    for s in shots:
        n, e, _ = pymap3d.geodetic2ned(s.lat / 1e7, s.lon / 1e7, s.alt / 1000, *v.spawn_lla)
        assert math.hypot(n - 10.0, e) < 0.8 and s.relative_alt / 1000 == pytest.approx(6, abs=0.8)  # fmt: skip
    # the gimbal turns at 90 deg/s from level: the first picture comes before it is there
    pitches = [ypr_deg(s.q)[1] for s in shots]
    assert pitches[0] == pytest.approx(0.0, abs=1.0)
    assert pitches[1:] == pytest.approx([-45.0] * 3, abs=1e-3)
    # the navigator sent each command out too; the camera acknowledged its own
    longs = [(m.command, m.target_component, m.confirmation) for m in flight.of("COMMAND_LONG")]
    assert longs.count((mavlink2.MAV_CMD_IMAGE_START_CAPTURE, CAMERA, 0)) == 1
    assert longs.count((mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE, CAMERA, 0)) == 1
    assert not [c for c in longs if c[0] in (2000, 2001) and c[2] > 0]
    yawcmds = [c for c in longs if c[0] == mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW]
    assert yawcmds[:4] == [(1000, 0, k) for k in range(4)]  # broadcast: nobody acknowledges


@pytest.mark.slow
def test_mission_pitchyaw_without_configure_is_denied_as_on_px4() -> None:
    f = offline()
    v = f.vehicles[0]
    items, _ = camera_mission(v, hold1_s=1.0, hold2_s=2.5, interval_s=1.0, pitch_deg=-45, configure=False)  # fmt: skip
    flight = fly(f, v, items, 60.0)
    shots = flight.of("CAMERA_IMAGE_CAPTURED")
    assert len(shots) == 3
    assert [ypr_deg(s.q)[1] for s in shots] == pytest.approx([0.0] * 3, abs=1e-6)


@pytest.mark.slow
def test_mis_command_tout_lets_the_gimbal_turn_before_the_first_picture() -> None:
    f = offline(MIS_COMMAND_TOUT=1.0)
    v = f.vehicles[0]
    items, seqs = camera_mission(v, hold1_s=1.0, hold2_s=2.5, interval_s=1.0, pitch_deg=-45)
    flight = fly(f, v, items, 60.0)
    pitchyaw_seq = seqs["start"] - 1
    wait_start, wait_end = flight.window(pitchyaw_seq)  # the mission waits at the item
    assert wait_end - wait_start == pytest.approx(1.0, abs=0.011)
    shots = flight.of("CAMERA_IMAGE_CAPTURED")
    assert len(shots) == 3
    assert [ypr_deg(s.q)[1] for s in shots] == pytest.approx([-45.0] * 3, abs=1e-3)


@pytest.mark.slow
def test_roi_in_a_mission_turns_the_vehicle_and_the_camera_toward_it() -> None:
    f = offline()
    v = f.vehicles[0]
    roi_ne = (40.0, -30.0)  # on the ground, 30 m north and 30 m west of A
    # (a PITCHYAW after it would take the gimbal off the ROI: the last command wins)
    items, _ = camera_mission(v, hold1_s=1.0, hold2_s=6.0, interval_s=1.0, pitch_deg=None, roi=roi_ne)  # fmt: skip
    flight = fly(f, v, items, 60.0)
    shots = flight.of("CAMERA_IMAGE_CAPTURED")
    assert len(shots) == 7
    roi_lat, roi_lon = (x / 1e7 for x in e7(v, *roi_ne))
    home_alt = v.spawn_lla[2]
    for s in shots[-3:]:  # the vehicle has turned (MPC_YAWRAUTO_MAX), the gimbal followed
        e, n, u = pymap3d.geodetic2enu(roi_lat, roi_lon, home_alt, s.lat / 1e7, s.lon / 1e7, s.alt / 1000)  # fmt: skip
        yaw, pitch, _ = ypr_deg(s.q)
        assert wrap_deg(yaw - math.degrees(math.atan2(e, n))) == pytest.approx(0.0, abs=1.0)
        assert pitch == pytest.approx(math.degrees(math.atan2(u, math.hypot(e, n))), abs=1.0)
    # the ROI turned the vehicle itself (MissionBase::heading_sp_update), not only the gimbal
    headings = [math.degrees(m.yaw) for m in flight.of("ATTITUDE")]
    assert min(abs(wrap_deg(h + 45.0)) for h in headings) < 3.0  # 30 N, 30 W of A: -45 deg


def test_leaving_the_mission_stops_its_capture_and_levels_the_gimbal() -> None:
    f = offline()
    v = f.vehicles[0]
    items, seqs = camera_mission(v, hold1_s=1.0, hold2_s=20.0, interval_s=1.0, pitch_deg=-45)
    v.store_plan(items)
    f.advance(0.5)
    v.arm()
    v.request_mode(Px4Mode.AUTO_MISSION)
    for _ in range(6000):
        f.advance(f.dt_s)
        if v.mission_seq == seqs["wp2"]:
            break
    f.advance(2.5)
    assert v.camera is not None and v.camera.capturing and v.gimbal is not None
    v.sent_messages()
    assert v.request_mode(Px4Mode.AUTO_LOITER) == mavlink2.MAV_RESULT_ACCEPTED
    f.advance(3.0)
    msgs = v.sent_messages()
    longs = [(m.command, m.target_component, m.confirmation) for m in msgs if m.get_type() == "COMMAND_LONG"]  # fmt: skip
    assert (mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE, CAMERA, 0) in longs
    assert not v.camera.capturing
    assert not [m for m in msgs if m.get_type() == "CAMERA_IMAGE_CAPTURED"]
    # 0.25 s later: take control, neutral, release
    assert ypr_deg(v.camera_q())[1] == pytest.approx(0.0, abs=1e-6)
    assert v.gimbal.primary == (0, 0)


def test_vehicle_without_camera_flies_a_mission_with_camera_items() -> None:
    f = offline(camera=False)
    v = f.vehicles[0]
    items, seqs = camera_mission(v, hold1_s=1.0, hold2_s=2.5, interval_s=1.0, pitch_deg=-45)
    flight = fly(f, v, items, 60.0)
    assert v.mission_finished and v.landed
    start, end = flight.window(seqs["wp2"])
    assert end - start == pytest.approx(2.5 + f.dt_s, abs=0.015)
    assert {m.get_srcComponent() for m in flight.msgs} == {AUTOPILOT}
    assert not flight.of("CAMERA_IMAGE_CAPTURED")
    # PX4 sends the camera commands out all the same, re-sent 3 times as nobody answers
    longs = [(m.command, m.target_component, m.confirmation) for m in flight.of("COMMAND_LONG")]
    assert [c for c in longs if c[0] == 2000] == [(2000, CAMERA, k) for k in range(4)]


# ================================================================ uploads (offline)
def upload(f: MockFleet, v: MockVehicle, items: list[MissionItem]) -> int:
    """The GCS side of an upload, message by message; the MISSION_ACK's result."""
    v.sent_messages()
    v.receive(mavlink2.MAVLink_mission_count_message(v.sysid, 1, len(items), 0))
    for _ in range(len(items) + 2):
        f.advance(0.01)
        for m in v.sent_messages():
            if m.get_type() == "MISSION_REQUEST_INT":
                it = items[m.seq]
                v.receive(
                    mavlink2.MAVLink_mission_item_int_message(
                        v.sysid, 1, it.seq, it.frame, it.command, it.current, it.autocontinue,
                        it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z, 0,
                    )
                )  # fmt: skip
            elif m.get_type() == "MISSION_ACK":
                return int(m.type)
    raise AssertionError("upload did not end")


def test_uploads_take_camera_items_in_the_frames_px4_takes_them_and_read_them_back() -> None:
    f = offline()
    v = f.vehicles[0]
    items, _ = camera_mission(v, hold1_s=1.0, hold2_s=3.0, interval_s=1.0, pitch_deg=-45, roi=(5.0, 5.0))  # fmt: skip
    assert upload(f, v, items) == mavlink2.MAV_MISSION_ACCEPTED
    v.sent_messages()
    v.receive(mavlink2.MAVLink_mission_request_list_message(v.sysid, 1, 0))
    back = []
    for seq in range(len(items)):
        v.receive(mavlink2.MAVLink_mission_request_int_message(v.sysid, 1, seq, 0))
        back += [m for m in v.sent_messages() if m.get_type() == "MISSION_ITEM_INT"]
    for sent, got in zip(items, back, strict=True):
        if sent.command == mavlink2.MAV_CMD_DO_SET_ROI_LOCATION:
            # a position to PX4: param1-4 come back zero (format_mavlink_mission_item)
            assert (got.param1, got.param2, got.param3, got.param4) == (0, 0, 0, 0)
            assert (got.x, got.y, got.z, got.frame) == (sent.x, sent.y, sent.z, sent.frame)
        elif sent.frame == mavlink2.MAV_FRAME_MISSION:
            for name in ("command", "param1", "param2", "param3", "param4", "x", "y", "z"):
                a, b = getattr(sent, name), getattr(got, name)
                assert a == b or (math.isnan(a) and math.isnan(b)), (sent, name)
    # PX4's parser: camera and gimbal items only in MAV_FRAME_MISSION, the ROI location only
    # in a global frame; anything else aborts the upload with MAV_MISSION_UNSUPPORTED
    rel, mis = mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavlink2.MAV_FRAME_MISSION
    lat, lon = e7(v, 1.0, 1.0)
    bad_items = [
        MissionItem(0, rel, mavlink2.MAV_CMD_IMAGE_START_CAPTURE, 0, 1, 0, 1, 0, 0, 0, 0, 0, 0),
        MissionItem(0, rel, 1000, 0, 1, -45, 0, NAN, NAN, 0, 0, 0, 0),  # PITCHYAW
        MissionItem(0, mis, mavlink2.MAV_CMD_DO_SET_ROI_LOCATION, 0, 1, 0, 0, 0, 0, lat, lon, 0, 0),
    ]
    for bad in bad_items:
        assert upload(f, v, [bad]) == mavlink2.MAV_MISSION_UNSUPPORTED
    assert len(v.mission_items()) == len(items)  # the plan before is kept


# ================================================================ no camera (UDP)
@pytest.mark.slow
def test_vehicle_without_camera_is_silent_for_camera_and_gimbal_as_px4_without_them() -> None:
    with udp_vehicle(camera=False) as (_fleet, gcs):
        comps = {m.get_srcComponent() for m in collect(gcs, 1.3)}
        assert comps == {AUTOPILOT}
        for component, command, params in (
            (CAMERA, mavlink2.MAV_CMD_REQUEST_MESSAGE, (259,)),
            (CAMERA, mavlink2.MAV_CMD_IMAGE_START_CAPTURE, (0, 1, 0, 0)),
            (GIMBAL, mavlink2.MAV_CMD_REQUEST_MESSAGE, (283,)),
            (AUTOPILOT, mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, (-45, 0, NAN, NAN, 0)),
            (AUTOPILOT, mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, (-2, -2, -1, -1)),
        ):
            p = [float(x) for x in params] + [0.0] * (7 - len(params))
            gcs.drain()
            gcs.send(mavlink2.MAVLink_command_long_message(1, component, command, 0, *p))
            assert gcs.recv("COMMAND_ACK", 0.4, lambda m, c=command: m.command == c) is None
        ack = command_to(gcs, AUTOPILOT, mavlink2.MAV_CMD_REQUEST_MESSAGE, 280)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_DENIED
        ack = command_to(gcs, AUTOPILOT, mavlink2.MAV_CMD_DO_SET_ROI_NONE)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED  # the navigator
        ack = command_to(gcs, AUTOPILOT, mavlink2.MAV_CMD_REQUEST_MESSAGE, 148)
        version = gcs.recv("AUTOPILOT_VERSION", 2.0)
        cap = mavlink2.MAV_PROTOCOL_CAPABILITY_COMPONENT_IMPLEMENTS_GIMBAL_MANAGER
        assert version is not None and not version.capabilities & cap
