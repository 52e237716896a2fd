"""What the link puts on the wire, read by an independent pymavlink endpoint."""

from __future__ import annotations

import asyncio
import socket
import threading
import time

import numpy as np
import pymap3d
import pytest
from pymavlink.dialects.v20 import common as mav

from mavlink.link.fleet import Fleet
from mavlink.link.vehicle_status import VehicleSpec
from mavlink.offboard.setpoints import offboard_sender
from mavlink.offboard.stream import SetpointStreamer, StreamTarget
from mavlink.plan_setpoints import plan_setpoints_ned
from planner.frames import GeodeticPoint
from planner.trajectory import Trajectory, YawMode, YawPolicy
from tests.mavlink.linkutil import free_udp_ports

MISSION_ORIGIN = GeodeticPoint(47.397742, 8.545594, 488.0)
VEHICLE_ORIGIN = GeodeticPoint(47.398100, 8.546300, 491.5)  # ~70 m away, 3.5 m higher


class PymavlinkVehicle:
    """A bare PX4-looking endpoint: heartbeats, ACKs every command, keeps every setpoint."""

    def __init__(self, gcs_port: int, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.05)
        self.gcs = ("127.0.0.1", gcs_port)
        self.mav = mav.MAVLink(None, srcSystem=1, srcComponent=1)
        self.setpoints: list[mav.MAVLink_set_position_target_local_ned_message] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)

    def run(self) -> None:
        next_hb = 0.0
        while not self.stop.is_set():
            if time.monotonic() >= next_hb:
                next_hb = time.monotonic() + 0.2
                hb = self.mav.heartbeat_encode(
                    mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, 0, 0, mav.MAV_STATE_STANDBY
                )
                self.sock.sendto(hb.pack(self.mav), self.gcs)
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            for msg in self.mav.parse_buffer(data) or ():
                if msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
                    self.setpoints.append(msg)
                elif msg.get_type() in ("COMMAND_LONG", "COMMAND_INT"):
                    ack = self.mav.command_ack_encode(
                        msg.command, mav.MAV_RESULT_ACCEPTED, 0, 0, 245, 190
                    )
                    self.sock.sendto(ack.pack(self.mav), self.gcs)

    def __enter__(self) -> PymavlinkVehicle:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join()
        self.sock.close()


def curve() -> Trajectory:
    """One 2 s segment with non-zero velocity and acceleration along all axes, yaw 0.7 rad (ENU)."""
    c = np.zeros((1, 3, 4))
    c[0, :, 0] = (3.0, -2.0, 5.0)
    c[0, :, 1] = (0.5, 1.0, -0.2)
    c[0, :, 2] = (0.3, -0.1, 0.05)
    c[0, :, 3] = (-0.05, 0.02, 0.01)
    return Trajectory(
        [0.0], [2.0], c, name="d1", yaw_policy=YawPolicy(YawMode.CONSTANT, yaw_rad=0.7)
    )


def test_setpoints_in_the_vehicles_own_ned_frame_match_pymap3d() -> None:
    traj = curve()
    sp = plan_setpoints_ned(traj, 10.0, MISSION_ORIGIN, VEHICLE_ORIGIN)
    t = np.arange(21) / 10.0
    p = traj.position(t)
    lat, lon, alt = pymap3d.enu2geodetic(p[:, 0], p[:, 1], p[:, 2], *_lla(MISSION_ORIGIN))
    n, e, d = pymap3d.geodetic2ned(lat, lon, alt, *_lla(VEHICLE_ORIGIN))
    np.testing.assert_allclose(sp.pos_ned_m, np.column_stack([n, e, d]), atol=1e-6)
    # Velocity: finite differences of the exact position transform.
    h = 1e-4
    p2 = traj.position(t + h)
    lat2, lon2, alt2 = pymap3d.enu2geodetic(p2[:, 0], p2[:, 1], p2[:, 2], *_lla(MISSION_ORIGIN))
    n2, e2, d2 = pymap3d.geodetic2ned(lat2, lon2, alt2, *_lla(VEHICLE_ORIGIN))
    fd = (np.column_stack([n2, e2, d2]) - np.column_stack([n, e, d])) / h
    np.testing.assert_allclose(sp.vel_ned_m_s[:-1], fd[:-1], atol=2e-3)
    # With a send offset the samples are taken at the vehicle's own send times.
    shifted = plan_setpoints_ned(traj, 10.0, MISSION_ORIGIN, VEHICLE_ORIGIN, t_offset_s=0.025)
    np.testing.assert_allclose(shifted.t_s, t + 0.025)
    q = traj.position(t + 0.025)
    lat3, lon3, alt3 = pymap3d.enu2geodetic(q[:, 0], q[:, 1], q[:, 2], *_lla(MISSION_ORIGIN))
    np.testing.assert_allclose(
        shifted.pos_ned_m,
        np.column_stack(pymap3d.geodetic2ned(lat3, lon3, alt3, *_lla(VEHICLE_ORIGIN))),
        atol=1e-6,
    )
    # ENU yaw 0.7 rad (from east, counter-clockwise) is NED heading pi/2 - 0.7 (from north,
    # clockwise); the tangent planes 70 m apart differ by ~1e-5 rad.
    np.testing.assert_allclose(sp.yaw_ned_rad, np.pi / 2 - 0.7, atol=1e-4)
    # The drag feed-forward: acceleration + c * velocity, same frame; nothing else changes.
    dragged = plan_setpoints_ned(traj, 10.0, MISSION_ORIGIN, VEHICLE_ORIGIN, drag_per_s=0.8)
    np.testing.assert_allclose(
        dragged.acc_ned_m_s2, sp.acc_ned_m_s2 + 0.8 * sp.vel_ned_m_s, atol=1e-9
    )
    np.testing.assert_array_equal(dragged.pos_ned_m, sp.pos_ned_m)
    np.testing.assert_array_equal(dragged.vel_ned_m_s, sp.vel_ned_m_s)


def _lla(g: GeodeticPoint) -> tuple[float, float, float]:
    return g.lat_deg, g.lon_deg, g.alt_m


@pytest.mark.slow
def test_stream_arrives_as_local_ned_position_velocity_acceleration_targets() -> None:
    gcs_port, port = free_udp_ports(2)
    sp = plan_setpoints_ned(curve(), 20.0, MISSION_ORIGIN, VEHICLE_ORIGIN)

    async def run() -> None:
        fleet = Fleet(
            [VehicleSpec("d1", f"udpin://127.0.0.1:{gcs_port}", 1)], telemetry_rate_hz=None
        )
        async with fleet:
            v = fleet["d1"]
            streamer = SetpointStreamer([StreamTarget("d1", offboard_sender(v.offboard), sp)], 20.0)
            stats = await streamer.run(time.monotonic() + 0.05)
            assert stats["d1"].sent == len(sp)
            await asyncio.sleep(0.2)

    with PymavlinkVehicle(gcs_port, port) as vehicle:
        asyncio.run(run())
    # MAVSDK re-sends the last setpoint by itself every 50 ms unless a new one came in the
    # meantime, so at 20 Hz a setpoint may arrive twice in a row: compare the distinct ones.
    got = [
        m
        for i, m in enumerate(vehicle.setpoints)
        if i == 0
        or (m.x, m.y, m.z)
        != (vehicle.setpoints[i - 1].x, vehicle.setpoints[i - 1].y, vehicle.setpoints[i - 1].z)
    ]
    assert len(got) == len(sp)
    f32 = np.float32
    for k, m in enumerate(got):
        assert (m.target_system, m.target_component) == (1, 1)
        assert m.get_srcSystem() == 245  # MAVSDK's ground-station system id
        assert m.coordinate_frame == mav.MAV_FRAME_LOCAL_NED
        # Only yaw rate ignored: position, velocity, acceleration and yaw are all used.
        assert m.type_mask == 0b0000_1000_0000_0000
        assert (f32(m.x), f32(m.y), f32(m.z)) == tuple(f32(sp.pos_ned_m[k]))
        assert (f32(m.vx), f32(m.vy), f32(m.vz)) == tuple(f32(sp.vel_ned_m_s[k]))
        assert (f32(m.afx), f32(m.afy), f32(m.afz)) == tuple(f32(sp.acc_ned_m_s2[k]))
        assert m.yaw == pytest.approx(sp.yaw_ned_rad[k], abs=1e-5)
