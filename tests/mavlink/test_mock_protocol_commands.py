"""Protocol-level tests of the mock PX4 vehicle with a pymavlink GCS (what MAVSDK hides):
identity, commands, parameters, telemetry streams and offboard control.

Missions are in test_mock_protocol_missions.py, link faults in test_mock_protocol_faults.py.
"""

from __future__ import annotations

import itertools
import math
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import Px4Mode
from mavlink.mock.px4 import decode_param_value, encode_param_value
from mavlink.mock.sim.px4 import PARAM_SPECS, ParamType
from mavlink.mock.testing import GcsEndpoint
from tests.mavlink.mock_protocol_helpers import ORIGIN, mock_vehicles, stream_setpoints, wait_for


def heartbeat_mode(gcs: GcsEndpoint) -> tuple[Px4Mode | None, mavlink2.MAVLink_heartbeat_message]:
    hb = gcs.recv("HEARTBEAT", 3.0)
    assert hb is not None
    return Px4Mode.from_custom_mode(hb.custom_mode), hb


# ---------------------------------------------------------------- identity


def test_the_simulations_parameter_types_are_mavlinks_numbers() -> None:
    assert int(ParamType.INT32) == mavlink2.MAV_PARAM_TYPE_INT32
    assert int(ParamType.REAL32) == mavlink2.MAV_PARAM_TYPE_REAL32


def test_heartbeats_identify_px4_quadrotors_with_own_sysids() -> None:
    with mock_vehicles(2) as (_fleet, gcs):
        for i, g in enumerate(gcs):
            mode, hb = heartbeat_mode(g)
            assert hb.get_srcSystem() == i + 1 and hb.get_srcComponent() == 1
            assert hb.type == mavlink2.MAV_TYPE_QUADROTOR
            assert hb.autopilot == mavlink2.MAV_AUTOPILOT_PX4
            assert hb.base_mode & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            assert not hb.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
            assert mode is Px4Mode.AUTO_LOITER
            assert hb.custom_mode == (4 << 16) | (3 << 24)
            assert hb.get_header().mlen > 0 and hb.get_msgbuf()[0] == 0xFD  # MAVLink 2


def test_autopilot_version_on_request_has_capabilities_and_unique_uid() -> None:
    with mock_vehicles(2) as (_fleet, gcs):
        uids = []
        for g in gcs:
            ack = g.command(
                mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION
            )
            assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
            av = g.recv("AUTOPILOT_VERSION", 3.0)
            assert av is not None
            need = (
                mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
                | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
            )
            assert av.capabilities & need == need
            uids.append(av.uid)
        assert uids[0] != uids[1] and all(uids)


def test_every_command_is_acknowledged_and_unknown_ones_are_unsupported() -> None:
    with mock_vehicles() as (_fleet, (gcs,)):
        ack = gcs.command(mavlink2.MAV_CMD_DO_FENCE_ENABLE, 1)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_UNSUPPORTED
        assert ack.target_system == 255 and ack.target_component == 190
        gcs.send(
            mavlink2.MAVLink_command_int_message(
                1, 1, 0, mavlink2.MAV_CMD_USER_1, 0, 0, 0, 0, 0, 0, 0, 0, 0
            )
        )
        ack = gcs.recv("COMMAND_ACK", 3.0, lambda m: m.command == mavlink2.MAV_CMD_USER_1)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_UNSUPPORTED
        # a mode PX4 does not have
        ack = gcs.set_mode(9, 0)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_DENIED
        # manual modes need an RC link the mock does not have
        ack = gcs.set_mode(3, 0)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_TEMPORARILY_REJECTED


def test_arming_is_refused_until_ready_then_accepted() -> None:
    with mock_vehicles(ready_after_s=1.0) as (fleet, (gcs,)):
        ack = gcs.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
        assert any(m.get_type() == "STATUSTEXT" and "Arming denied" in m.text for m in gcs.received)
        status = gcs.recv(
            "SYS_STATUS",
            5.0,
            lambda m: m.onboard_control_sensors_health & mavlink2.MAV_SYS_STATUS_PREARM_CHECK,
        )
        assert status is not None
        ack = gcs.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
        hb = gcs.recv("HEARTBEAT", 3.0, lambda m: m.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)
        assert hb is not None and hb.system_status == mavlink2.MAV_STATE_ACTIVE
        assert fleet.vehicles[0].state.armed


def test_timesync_is_answered() -> None:
    with mock_vehicles() as (_fleet, (gcs,)):
        gcs.send(mavlink2.MAVLink_timesync_message(0, 123456789))
        reply = gcs.recv("TIMESYNC", 3.0)
        assert reply is not None and reply.ts1 == 123456789 and reply.tc1 > 0


# ---------------------------------------------------------------- parameters


def test_parameters_list_read_and_set_with_px4_bytewise_ints() -> None:
    with mock_vehicles() as (fleet, (gcs,)):
        gcs.send(mavlink2.MAVLink_param_request_list_message(1, 1))
        names = {}
        for msg in gcs.messages(2.0):
            if msg.get_type() == "PARAM_VALUE":
                names[msg.param_id] = msg
                if len(names) == len(PARAM_SPECS):
                    break
        assert set(names) == {p.name for p in PARAM_SPECS}
        assert all(m.param_count == len(PARAM_SPECS) for m in names.values())
        assert sorted(m.param_index for m in names.values()) == list(range(len(PARAM_SPECS)))
        # an int parameter travels byte-wise
        gcs.send(
            mavlink2.MAVLink_param_set_message(
                1,
                1,
                b"COM_OBL_RC_ACT",
                encode_param_value(4, ParamType.INT32),
                mavlink2.MAV_PARAM_TYPE_INT32,
            )
        )
        echo = gcs.recv("PARAM_VALUE", 3.0, lambda m: m.param_id == "COM_OBL_RC_ACT")
        assert echo is not None and decode_param_value(echo.param_value, ParamType.INT32) == 4
        assert fleet.vehicles[0].params["COM_OBL_RC_ACT"] == 4
        gcs.send(
            mavlink2.MAVLink_param_set_message(
                1, 1, b"MPC_XY_VEL_MAX", 3.5, mavlink2.MAV_PARAM_TYPE_REAL32
            )
        )
        assert gcs.recv("PARAM_VALUE", 3.0, lambda m: m.param_id == "MPC_XY_VEL_MAX") is not None
        assert fleet.physics.vel_xy_max_m_s[0] == pytest.approx(3.5)
        gcs.send(mavlink2.MAVLink_param_request_read_message(1, 1, b"NAV_ACC_RAD", -1))
        read = gcs.recv("PARAM_VALUE", 3.0, lambda m: m.param_id == "NAV_ACC_RAD")
        assert read is not None and read.param_value == pytest.approx(2.0)


# ---------------------------------------------------------------- telemetry


@pytest.mark.slow
def test_set_message_interval_changes_and_disables_streams() -> None:
    with mock_vehicles() as (_fleet, (gcs,)):
        lpn = mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED
        ack = gcs.command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, lpn, 200_000)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
        ack = gcs.command(
            mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAVLINK_MSG_ID_ATTITUDE, -1
        )
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
        gcs.drain()
        stamps = []
        kinds = set()
        for msg in gcs.messages(1.3):
            kinds.add(msg.get_type())
            if msg.get_type() == "LOCAL_POSITION_NED":
                stamps.append(msg.time_boot_ms)
        assert "ATTITUDE" not in kinds
        # consecutive samples are 200 ms apart in the vehicle's own clock
        gaps = [b - a for a, b in itertools.pairwise(stamps)]
        assert len(gaps) >= 3 and all(190 <= g <= 210 for g in gaps), gaps
        ack = gcs.command(mavlink2.MAV_CMD_GET_MESSAGE_INTERVAL, lpn)
        reply = gcs.recv("MESSAGE_INTERVAL", 3.0)
        assert reply is not None and reply.interval_us == 200_000
        ack = gcs.command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1000)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_DENIED


def test_global_position_is_spawn_origin_plus_local_offset() -> None:
    spawn = (30.0, -20.0, 0.0)
    # the ideal profile: the EKF origin exactly at the spawn (px4 scatters it per boot)
    with mock_vehicles(spawns_enu_m=[spawn], profile="ideal") as (_fleet, (gcs,)):
        import pymap3d

        lat0, lon0, alt0 = pymap3d.enu2geodetic(*spawn, *ORIGIN)
        origin = gcs.recv("GPS_GLOBAL_ORIGIN", 3.0)
        home = gcs.recv("HOME_POSITION", 3.0)
        gpi = gcs.recv("GLOBAL_POSITION_INT", 3.0)
        assert origin is not None and home is not None and gpi is not None
        assert origin.latitude == pytest.approx(lat0 * 1e7, abs=1)
        assert origin.longitude == pytest.approx(lon0 * 1e7, abs=1)
        assert home.latitude == origin.latitude and (home.x, home.y, home.z) == (0.0, 0.0, 0.0)
        # on the ground at the spawn point: 1 cm noise is ~1 degE7 unit
        assert gpi.lat == pytest.approx(lat0 * 1e7, abs=10)
        assert gpi.lon == pytest.approx(lon0 * 1e7, abs=10)
        assert gpi.alt == pytest.approx(alt0 * 1000, abs=60)


# ---------------------------------------------------------------- offboard


@pytest.mark.slow
def test_offboard_is_refused_without_a_setpoint_stream() -> None:
    with mock_vehicles() as (fleet, (gcs,)):
        ack = gcs.set_mode(6)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
        # a single setpoint is not a stream
        gcs.position_setpoint(0, 0, -2)
        ack = gcs.set_mode(6)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
        # 1 Hz is below the 2 Hz PX4 requires
        stream_setpoints(gcs, (0, 0, -2), 1.1, rate_hz=1.0)
        ack = gcs.set_mode(6)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
        assert fleet.vehicles[0].state.mode is Px4Mode.AUTO_LOITER
        stream_setpoints(gcs, (0, 0, -2), 1.2, rate_hz=20.0)
        ack = gcs.set_mode(6)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
        assert fleet.vehicles[0].state.mode is Px4Mode.OFFBOARD


def _offboard_flight_then_silence(gcs: GcsEndpoint) -> None:
    stream_setpoints(gcs, (0, 0, -2), 1.2)
    ack = gcs.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
    gcs.position_setpoint(0, 0, -2)
    ack = gcs.set_mode(6)
    assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
    stream_setpoints(gcs, (0, 0, -2), 1.5)


@pytest.mark.slow
def test_offboard_stream_loss_triggers_hold_failsafe() -> None:
    with mock_vehicles(params={"COM_OF_LOSS_T": 0.3}, profile="ideal") as (fleet, (gcs,)):
        _offboard_flight_then_silence(gcs)
        v = fleet.vehicles[0]
        assert v.state.mode is Px4Mode.OFFBOARD and not v.state.landed
        gcs.drain()
        # stream stops here
        hb = gcs.recv(
            "HEARTBEAT",
            3.0,
            lambda m: Px4Mode.from_custom_mode(m.custom_mode) is Px4Mode.AUTO_LOITER,
        )
        assert hb is not None and hb.system_status == mavlink2.MAV_STATE_CRITICAL
        assert any(m.get_type() == "STATUSTEXT" and "Failsafe" in m.text for m in gcs.received)
        st = v.state
        assert st.failsafe and st.armed and not st.landed
        assert st.pos_ned_m[2] == pytest.approx(-2.0, abs=0.5)


@pytest.mark.slow
def test_offboard_loss_action_land_from_parameter() -> None:
    with mock_vehicles(
        params={"COM_OF_LOSS_T": 0.3, "MPC_LAND_SPEED": 2.0, "COM_DISARM_LAND": 0.5}
    ) as (fleet, (gcs,)):
        gcs.send(
            mavlink2.MAVLink_param_set_message(
                1,
                1,
                b"COM_OBL_RC_ACT",
                encode_param_value(4, ParamType.INT32),
                mavlink2.MAV_PARAM_TYPE_INT32,
            )
        )
        assert gcs.recv("PARAM_VALUE", 3.0, lambda m: m.param_id == "COM_OBL_RC_ACT") is not None
        _offboard_flight_then_silence(gcs)
        v = fleet.vehicles[0]
        assert wait_for(lambda: v.state.mode is Px4Mode.AUTO_LAND, 3.0)
        assert wait_for(lambda: not v.state.armed, 8.0)  # landed, then auto-disarmed
        assert v.state.landed


@pytest.mark.slow
def test_offboard_tracks_position_velocity_and_acceleration_setpoints() -> None:
    with mock_vehicles(profile="ideal") as (fleet, (gcs,)):
        v = fleet.vehicles[0]

        # velocity-only setpoint (type mask ignores position and acceleration)
        def vel_sp() -> None:
            gcs.send(mavlink2.MAVLink_set_position_target_local_ned_message(
                0, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, 0b0000_1100_0111,
                0, 0, 0, 1.0, 0.0, -1.0, 0, 0, 0, 0, 0))  # fmt: skip

        t_end = time.monotonic() + 1.2
        while time.monotonic() < t_end:
            vel_sp()
            time.sleep(0.05)
        assert gcs.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        assert gcs.set_mode(6).result == 0
        t_end = time.monotonic() + 2.5
        while time.monotonic() < t_end:
            vel_sp()
            time.sleep(0.05)
        vn, _ve, vd = v.state.vel_ned_m_s
        assert vn == pytest.approx(1.0, abs=0.15) and vd == pytest.approx(-1.0, abs=0.15)
        target = gcs.recv("POSITION_TARGET_LOCAL_NED", 2.0)
        assert target is not None and target.type_mask & 0b111 == 0b111  # position ignored
        assert target.vx == pytest.approx(1.0)


@pytest.mark.slow
def test_attitude_and_thrust_setpoints_fly_in_offboard() -> None:
    with mock_vehicles() as (fleet, (gcs,)):
        v = fleet.vehicles[0]
        pitch = math.radians(-10.0)  # nose down: accelerate north
        q = [math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0]

        def attitude(thrust: float) -> None:
            gcs.send(
                mavlink2.MAVLink_set_attitude_target_message(
                    0, 1, 1, 0b0000_0111, q, 0, 0, 0, thrust
                )
            )

        t_end = time.monotonic() + 1.2
        while time.monotonic() < t_end:
            attitude(0.6)
            time.sleep(0.05)
        assert gcs.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        assert gcs.set_mode(6).result == 0
        t_end = time.monotonic() + 1.5
        while time.monotonic() < t_end:
            attitude(0.6)
            time.sleep(0.05)
        vn, ve, vd = v.state.vel_ned_m_s
        # thrust 0.6 of hover 0.5 tilted 10 deg forward: climbs and accelerates north
        assert vd < -1.0 and vn > 1.0 and abs(ve) < 0.1
        attitude(0.6)
        gcs.drain()
        att = gcs.recv("ATTITUDE", 2.0)
        assert att is not None and att.pitch == pytest.approx(pitch, abs=0.03)


# ---------------------------------------------------------------- reposition and return


@pytest.mark.slow
def test_reposition_then_return_to_launch_lands_at_home() -> None:
    params = {
        "MPC_TKO_SPEED": 3.0,
        "MIS_TAKEOFF_ALT": 2.0,
        "MPC_LAND_SPEED": 2.5,
        "COM_DISARM_LAND": 0.3,
        "RTL_RETURN_ALT": 6.0,
    }
    with mock_vehicles(params=params) as (fleet, (gcs,)):
        v = fleet.vehicles[0]
        assert gcs.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        nan = math.nan
        assert gcs.command(mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, nan).result == 0
        assert wait_for(lambda: v.state.mode is Px4Mode.AUTO_LOITER and not v.state.landed, 5.0)
        lat, lon, alt0 = v.ned_to_global([6.0, 0.0, -2.0])
        gcs.send(
            mavlink2.MAVLink_command_int_message(
                1,
                1,
                mavlink2.MAV_FRAME_GLOBAL_INT,
                mavlink2.MAV_CMD_DO_REPOSITION,
                0,
                0,
                8.0,
                0,
                0,
                nan,
                round(lat * 1e7),
                round(lon * 1e7),
                alt0,
            )
        )
        ack = gcs.recv("COMMAND_ACK", 3.0, lambda m: m.command == mavlink2.MAV_CMD_DO_REPOSITION)
        assert ack is not None and ack.result == 0
        # PX4 navigates on its estimate: that is where the target and home are
        assert wait_for(lambda: math.dist(v.state.est_pos_ned_m, (6.0, 0.0, -2.0)) < 0.3, 12.0)
        assert gcs.command(mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH).result == 0
        top = 0.0
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and v.state.armed:
            top = max(top, -v.state.est_pos_ned_m[2])
            time.sleep(0.02)
        st = v.state
        assert not st.armed and st.landed
        home = st.home_ned_m
        assert math.hypot(st.est_pos_ned_m[0] - home[0], st.est_pos_ned_m[1] - home[1]) < 0.5
        # within RTL_MIN_DIST of home PX4 returns at the current altitude (no climb to 6 m)
        assert top < 2.6
