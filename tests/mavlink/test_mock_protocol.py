"""Protocol-level tests of the mock PX4 vehicle with a pymavlink GCS (what MAVSDK hides)."""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import FaultConfig, MockFleet, Outage, Px4Mode
from mavlink.mock.mission import FENCE, MISSION, RALLY
from mavlink.mock.px4 import PARAM_SPECS, ParamType, decode_param_value, encode_param_value
from mavlink.mock.testing import GcsEndpoint, free_udp_ports

ORIGIN = (47.397742, 8.545594, 488.0)


@contextmanager
def mock_vehicles(n: int = 1, **kwargs: object) -> Iterator[tuple[MockFleet, list[GcsEndpoint]]]:
    """``n`` vehicles on free ports, each with its own pymavlink GCS endpoint."""
    vports = free_udp_ports(n)
    gcs = [GcsEndpoint(vports[i], target_system=i + 1) for i in range(n)]
    kwargs.setdefault("ready_after_s", 0.0)
    fleet = MockFleet(
        n=n,
        origin=ORIGIN,
        gcs_ports=[g.port for g in gcs],
        vehicle_ports=vports,
        seed=7,
        **kwargs,  # type: ignore[arg-type]
    )
    try:
        with fleet.running_in_thread():
            yield fleet, gcs
    finally:
        for g in gcs:
            g.close()


def wait_for(predicate, timeout_s: float = 10.0, step_s: float = 0.02) -> bool:  # type: ignore[no-untyped-def]
    """Poll ``predicate`` until true or the deadline (a condition wait, not a fixed sleep)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step_s)
    return bool(predicate())


def item_int(
    seq: int, command: int = mavlink2.MAV_CMD_NAV_WAYPOINT, **kw: float
) -> mavlink2.MAVLink_mission_item_int_message:
    """A MISSION_ITEM_INT for vehicle 1 (relative-alt frame unless given)."""
    return mavlink2.MAVLink_mission_item_int_message(
        1, 1, seq,
        int(kw.get("frame", mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)),
        command, int(seq == 0), 1,
        kw.get("p1", 0.0), kw.get("p2", 0.0), kw.get("p3", 0.0), kw.get("p4", math.nan),
        int(kw.get("x", 473977420 + 90 * seq)), int(kw.get("y", 85455940 + 130 * seq)),
        kw.get("z", 5.0 + seq), int(kw.get("mission_type", MISSION)),
    )  # fmt: skip


def upload(
    gcs: GcsEndpoint, items: list, mission_type: int = MISSION, timeout_s: float = 10.0
) -> int | None:  # type: ignore[type-arg]
    """A GCS-side upload like MAVSDK's: answer every request; on silence re-send COUNT (before
    the first request) or the last item (when only the ACK is missing).  Returns the ACK type."""
    gcs.drain()
    gcs.send(mavlink2.MAVLink_mission_count_message(1, 1, len(items), mission_type))
    deadline = time.monotonic() + timeout_s
    last_rx = time.monotonic()
    sent_last = False
    requested = False
    while time.monotonic() < deadline:
        msg = gcs.recv(("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"), 0.2)
        if msg is None:
            if time.monotonic() - last_rx > 0.6:
                if sent_last:
                    gcs.send(items[-1])
                elif not requested:
                    gcs.send(mavlink2.MAVLink_mission_count_message(1, 1, len(items), mission_type))
                last_rx = time.monotonic()
            continue
        if msg.mission_type != mission_type:
            continue
        last_rx = time.monotonic()
        if msg.get_type() == "MISSION_ACK":
            return int(msg.type)
        requested = True
        gcs.send(items[msg.seq])
        sent_last = msg.seq == len(items) - 1
    return None


def download(gcs: GcsEndpoint, mission_type: int = MISSION, legacy: bool = False) -> list:  # type: ignore[type-arg]
    gcs.send(mavlink2.MAVLink_mission_request_list_message(1, 1, mission_type))
    count = gcs.recv("MISSION_COUNT", 3.0, lambda m: m.mission_type == mission_type)
    assert count is not None
    out = []
    kind = "MISSION_ITEM" if legacy else "MISSION_ITEM_INT"
    for seq in range(count.count):
        req_cls = (
            mavlink2.MAVLink_mission_request_message
            if legacy
            else mavlink2.MAVLink_mission_request_int_message
        )
        gcs.send(req_cls(1, 1, seq, mission_type))
        item = gcs.recv(kind, 3.0, lambda m, s=seq: m.seq == s)
        assert item is not None, f"item {seq} not received"
        out.append(item)
    gcs.send(mavlink2.MAVLink_mission_ack_message(1, 1, 0, mission_type))
    return out


def heartbeat_mode(gcs: GcsEndpoint) -> tuple[Px4Mode | None, mavlink2.MAVLink_heartbeat_message]:
    hb = gcs.recv("HEARTBEAT", 3.0)
    assert hb is not None
    return Px4Mode.from_custom_mode(hb.custom_mode), hb


def stream_setpoints(
    gcs: GcsEndpoint, ned: tuple[float, float, float], duration_s: float, rate_hz: float = 20.0
) -> None:
    t_end = time.monotonic() + duration_s
    while time.monotonic() < t_end:
        gcs.position_setpoint(*ned)
        time.sleep(1.0 / rate_hz)


# ---------------------------------------------------------------- identity


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


# ---------------------------------------------------------------- missions


def test_mission_upload_rerequests_out_of_order_items() -> None:
    items = [item_int(s) for s in range(5)]
    with mock_vehicles() as (fleet, (gcs,)):
        gcs.send(mavlink2.MAVLink_mission_count_message(1, 1, 5, MISSION))
        req = gcs.recv("MISSION_REQUEST_INT", 3.0)
        assert req is not None and req.seq == 0
        gcs.send(items[2])  # out of order: dropped and item 0 asked again at once
        req = gcs.recv("MISSION_REQUEST_INT", 3.0)
        assert req is not None and req.seq == 0
        for seq in range(5):
            gcs.send(items[seq])
            if seq < 4:
                req = gcs.recv("MISSION_REQUEST_INT", 3.0, lambda m, s=seq: m.seq == s + 1)
                assert req is not None
        ack = gcs.recv("MISSION_ACK", 3.0)
        assert ack is not None and ack.type == mavlink2.MAV_MISSION_ACCEPTED
        stored = fleet.vehicles[0].mission_items(MISSION)
        assert [(s.seq, s.x, s.y, s.z) for s in stored] == [
            (m.seq, m.x, m.y, pytest.approx(m.z)) for m in items
        ]


def test_unanswered_request_is_repeated_and_lost_ack_is_resent() -> None:
    items = [item_int(s) for s in range(2)]
    with mock_vehicles() as (fleet, (gcs,)):
        gcs.send(mavlink2.MAVLink_mission_count_message(1, 1, 2, MISSION))
        first = gcs.recv("MISSION_REQUEST_INT", 3.0)
        again = gcs.recv("MISSION_REQUEST_INT", 3.0)  # we stay silent: the vehicle retries
        assert first is not None and again is not None and first.seq == again.seq == 0
        gcs.send(items[0])
        assert gcs.recv("MISSION_REQUEST_INT", 3.0, lambda m: m.seq == 1) is not None
        gcs.send(items[1])
        assert gcs.recv("MISSION_ACK", 3.0).type == mavlink2.MAV_MISSION_ACCEPTED
        gcs.send(items[1])  # as if our ACK was lost
        assert gcs.recv("MISSION_ACK", 3.0).type == mavlink2.MAV_MISSION_ACCEPTED
        assert len(fleet.vehicles[0].mission_items()) == 2


def test_legacy_mission_item_upload_and_download() -> None:
    with mock_vehicles() as (fleet, (gcs,)):
        lat, lon = 47.3978001, 8.5457002
        legacy = [
            mavlink2.MAVLink_mission_item_message(
                1,
                1,
                s,
                mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                mavlink2.MAV_CMD_NAV_WAYPOINT,
                int(s == 0),
                1,
                0,
                0,
                0,
                math.nan,
                lat + 1e-5 * s,
                lon,
                10.0 + s,
                MISSION,
            )
            for s in range(3)
        ]
        gcs.send(mavlink2.MAVLink_mission_count_message(1, 1, 3, MISSION))
        req = gcs.recv(("MISSION_REQUEST_INT", "MISSION_REQUEST"), 3.0)
        assert req is not None and req.seq == 0
        gcs.send(legacy[0])
        for seq in (1, 2):
            # having seen a legacy item, the vehicle asks with legacy MISSION_REQUEST
            req = gcs.recv(("MISSION_REQUEST_INT", "MISSION_REQUEST"), 3.0)
            assert req is not None and req.get_type() == "MISSION_REQUEST" and req.seq == seq
            gcs.send(legacy[seq])
        assert gcs.recv("MISSION_ACK", 3.0).type == mavlink2.MAV_MISSION_ACCEPTED
        stored = fleet.vehicles[0].mission_items()
        assert stored[1].frame == mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
        # legacy lat/lon travel as float32: the stored degE7 value is that float's
        assert stored[1].x == round(float(np.float32(lat + 1e-5)) * 1e7)
        back = download(gcs, legacy=True)
        assert [m.get_type() for m in back] == ["MISSION_ITEM"] * 3
        for b, sent in zip(back, legacy, strict=True):
            assert b.frame == sent.frame
            assert b.x == pytest.approx(sent.x, abs=1e-5) and b.y == pytest.approx(sent.y, abs=1e-5)
        ints = download(gcs)
        assert [m.x for m in ints] == [s.x for s in stored]


@pytest.mark.parametrize(
    ("item", "expected"),
    [
        (item_int(0, frame=mavlink2.MAV_FRAME_LOCAL_NED), mavlink2.MAV_MISSION_UNSUPPORTED_FRAME),
        (item_int(0, command=mavlink2.MAV_CMD_USER_1), mavlink2.MAV_MISSION_UNSUPPORTED),
        (item_int(0, x=950_000_000), mavlink2.MAV_MISSION_INVALID_PARAM5_X),
        (
            item_int(0, command=mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, p1=4),
            mavlink2.MAV_MISSION_UNSUPPORTED,
        ),
    ],
)
def test_bad_items_get_error_acks_and_keep_the_old_plan(item, expected) -> None:  # type: ignore[no-untyped-def]
    with mock_vehicles() as (fleet, (gcs,)):
        good = [item_int(s) for s in range(2)]
        assert upload(gcs, good) == mavlink2.MAV_MISSION_ACCEPTED
        assert upload(gcs, [item, item_int(1)]) == expected
        assert len(fleet.vehicles[0].mission_items()) == 2


def test_mission_protocol_errors_for_counts_sequences_and_fence_items() -> None:
    with mock_vehicles() as (_fleet, (gcs,)):
        gcs.send(mavlink2.MAVLink_mission_count_message(1, 1, 5000, MISSION))
        assert gcs.recv("MISSION_ACK", 3.0).type == mavlink2.MAV_MISSION_NO_SPACE
        gcs.send(mavlink2.MAVLink_mission_request_int_message(1, 1, 3, MISSION))
        assert gcs.recv("MISSION_ACK", 3.0).type == mavlink2.MAV_MISSION_INVALID_SEQUENCE
        bad_polygon = item_int(
            0,
            command=mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
            p1=2,
            mission_type=FENCE,
            frame=mavlink2.MAV_FRAME_GLOBAL_INT,
        )
        assert upload(gcs, [bad_polygon], FENCE) == mavlink2.MAV_MISSION_INVALID_PARAM1


def test_mission_fence_and_rally_plans_are_separate_and_clearable() -> None:
    with mock_vehicles() as (_fleet, (gcs,)):
        mission = [item_int(s) for s in range(3)]
        fence = [
            item_int(s, command=mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, p1=4,
                     mission_type=FENCE, frame=mavlink2.MAV_FRAME_GLOBAL_INT,
                     x=473977420 + (900 if s in (1, 2) else -900), y=85455940 + (1300 if s >= 2 else -1300))
            for s in range(4)
        ]  # fmt: skip
        rally = [
            item_int(s, command=mavlink2.MAV_CMD_NAV_RALLY_POINT, mission_type=RALLY)
            for s in range(2)
        ]
        assert upload(gcs, mission) == 0
        assert upload(gcs, fence, FENCE) == 0
        assert upload(gcs, rally, RALLY) == 0
        assert [len(download(gcs, t)) for t in (MISSION, FENCE, RALLY)] == [3, 4, 2]
        assert [m.y for m in download(gcs, FENCE)] == [f.y for f in fence]
        gcs.send(mavlink2.MAVLink_mission_clear_all_message(1, 1, FENCE))
        assert gcs.recv("MISSION_ACK", 3.0).type == 0
        assert [len(download(gcs, t)) for t in (MISSION, FENCE, RALLY)] == [3, 0, 2]
        assert upload(gcs, [], MISSION) == 0  # count 0 clears
        gcs.send(mavlink2.MAVLink_mission_clear_all_message(1, 1, mavlink2.MAV_MISSION_TYPE_ALL))
        assert gcs.recv("MISSION_ACK", 3.0).type == 0
        assert [len(download(gcs, t)) for t in (MISSION, FENCE, RALLY)] == [0, 0, 0]


def test_mission_upload_completes_under_30_percent_loss_each_way() -> None:
    faults = FaultConfig(loss_to_vehicle=0.3, loss_to_gcs=0.3)
    items = [item_int(s, z=5.0 + 0.25 * s) for s in range(15)]
    with mock_vehicles(faults=faults) as (fleet, (gcs,)):
        assert upload(gcs, items, timeout_s=40.0) == mavlink2.MAV_MISSION_ACCEPTED
        stored = fleet.vehicles[0].mission_items()
        assert [(s.seq, s.command, s.frame, s.x, s.y) for s in stored] == [
            (m.seq, m.command, m.frame, m.x, m.y) for m in items
        ]
        assert [s.z for s in stored] == pytest.approx([m.z for m in items])
        stats = fleet.link_stats()[0]
        assert stats["uplink"].dropped > 0 and stats["downlink"].dropped > 0


def test_mission_runs_in_auto_mission_with_items_reached() -> None:
    params = {"MPC_TKO_SPEED": 3.0, "MPC_LAND_SPEED": 2.5, "MPC_XY_CRUISE": 6.0}
    # the ideal navigator reports every NAV item once (PX4's reports: test_mock_px4.py)
    with mock_vehicles(params=params, profile="ideal") as (fleet, (gcs,)):
        v = fleet.vehicles[0]
        lat0, lon0 = v.origin_lla[0], v.origin_lla[1]
        import pymap3d

        def wp(seq: int, cmd: int, n: float, e: float, alt: float, p1: float = 0.0) -> object:
            lat, lon, _ = pymap3d.ned2geodetic(n, e, 0.0, lat0, lon0, v.origin_lla[2])
            return item_int(seq, command=cmd, x=round(lat * 1e7), y=round(lon * 1e7), z=alt, p1=p1)

        plan = [
            wp(0, mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 2.0),
            wp(1, mavlink2.MAV_CMD_NAV_WAYPOINT, 5, 0, 2.0),
            item_int(2, command=mavlink2.MAV_CMD_DO_CHANGE_SPEED, frame=mavlink2.MAV_FRAME_MISSION, p2=3.0, x=0, y=0, z=0),
            wp(3, mavlink2.MAV_CMD_NAV_WAYPOINT, 5, 5, 3.0, p1=0.5),
            wp(4, mavlink2.MAV_CMD_NAV_LAND, 5, 5, 0.0),
        ]  # fmt: skip
        assert upload(gcs, plan) == 0
        assert gcs.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        assert gcs.command(mavlink2.MAV_CMD_MISSION_START, 0, 0).result == 0
        reached = []
        for msg in gcs.messages(25.0):
            if msg.get_type() == "MISSION_ITEM_REACHED" and msg.seq not in reached:
                reached.append(msg.seq)
                if msg.seq == 4:
                    break
        assert reached == [0, 1, 3, 4]
        assert v.cruise_speed_m_s == pytest.approx(3.0)
        st = v.state
        assert st.landed
        assert st.pos_ned_m[0] == pytest.approx(5.0, abs=0.5) and st.pos_ned_m[1] == pytest.approx(
            5.0, abs=0.5
        )
        current = gcs.recv("MISSION_CURRENT", 3.0)
        assert current is not None and current.total == 5
        assert current.mission_state == mavlink2.MISSION_STATE_COMPLETE


def test_geofence_breach_triggers_hold() -> None:
    # an actual breach (the ideal profile; PX4's predictive fence: test_mock_px4.py)
    with mock_vehicles(profile="ideal") as (fleet, (gcs,)):
        v = fleet.vehicles[0]
        lat0, lon0, _ = v.origin_lla
        circle = item_int(0, command=mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, p1=4.0,
                          mission_type=FENCE, frame=mavlink2.MAV_FRAME_GLOBAL_INT,
                          x=round(lat0 * 1e7), y=round(lon0 * 1e7), z=0.0)  # fmt: skip
        assert upload(gcs, [circle], FENCE) == 0
        stream_setpoints(gcs, (0, 0, -2), 1.2)
        assert gcs.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        assert gcs.set_mode(6).result == 0
        t_end = time.monotonic() + 10.0
        while time.monotonic() < t_end and v.state.mode is Px4Mode.OFFBOARD:
            gcs.position_setpoint(10.0, 0.0, -2.0)
            time.sleep(0.05)
        st = v.state
        assert st.mode is Px4Mode.AUTO_LOITER and st.failsafe
        assert 3.5 < math.hypot(st.pos_ned_m[0], st.pos_ned_m[1]) < 7.0


# ---------------------------------------------------------------- faults


def test_outage_silences_the_link_for_its_window() -> None:
    faults = FaultConfig(outages=(Outage(0.5, 1.5),))
    with mock_vehicles(faults=faults) as (_fleet, (gcs,)):
        stamps = [m.time_boot_ms for m in gcs.messages(2.2) if m.get_type() == "LOCAL_POSITION_NED"]
        assert any(t < 500 for t in stamps) and any(t >= 1500 for t in stamps)
        assert not any(500 <= t < 1500 for t in stamps)


def test_duplication_and_reordering_are_visible_in_sequence_numbers() -> None:
    faults = FaultConfig(duplicate=0.3, reorder=0.3, reorder_delay_s=0.02)
    with mock_vehicles(faults=faults) as (fleet, (gcs,)):
        seqs = [m.get_seq() for m in gcs.messages(1.0)]
        dups = sum(1 for a, b in itertools.pairwise(seqs) if a == b)
        backwards = sum(1 for a, b in itertools.pairwise(seqs) if 0 < (a - b) % 256 < 128)
        assert dups > 0 and backwards > 0
        stats = fleet.link_stats()[0]["downlink"]
        assert stats.duplicated > 0 and stats.reordered > 0


def test_fault_draws_are_reproducible_for_a_seed() -> None:
    import asyncio
    import random

    from mavlink.mock.faults import FaultyChannel

    def pattern(seed: int) -> list[int]:
        loop = asyncio.new_event_loop()
        try:
            out: list[int] = []
            ch = FaultyChannel(
                FaultConfig(loss_to_gcs=0.3),
                0.3,
                random.Random(seed),
                loop,
                lambda d: out.append(d[0]),
                lambda: 0.0,
            )
            for k in range(200):
                ch.push(bytes([k]))
            return out
        finally:
            loop.close()

    a, b, c = pattern(1), pattern(1), pattern(2)
    assert a == b and a != c
    assert 100 < len(a) < 180  # about 70 % survive


def test_latency_jitter_and_reordering_delays_with_a_patched_clock() -> None:
    import random

    from mavlink.mock.faults import FaultyChannel

    class RecordingLoop:
        """Stands in for the event loop: records call_later delays instead of waiting."""

        def __init__(self) -> None:
            self.delays: list[float] = []

        def call_later(self, delay: float, fn, *args):  # type: ignore[no-untyped-def]
            self.delays.append(delay)
            fn(*args)

    loop = RecordingLoop()
    got: list[bytes] = []
    faults = FaultConfig(latency_s=0.2, jitter_s=0.05, reorder=0.25, reorder_delay_s=0.5)
    ch = FaultyChannel(faults, 0.0, random.Random(5), loop, got.append, lambda: 0.0)  # type: ignore[arg-type]
    for k in range(400):
        ch.push(bytes([k % 256]))
    assert len(got) == 400 and len(loop.delays) == 400
    plain = [d for d in loop.delays if d < 0.5]
    held = [d for d in loop.delays if d >= 0.5]
    assert all(0.2 <= d <= 0.25 for d in plain)
    assert all(0.7 <= d <= 0.75 for d in held)
    assert 60 < len(held) < 140  # about a quarter
    assert ch.stats.reordered == len(held) and ch.stats.delayed == 400


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


def test_telemetry_noise_is_reproducible_for_a_seed() -> None:
    def samples(seed: int) -> dict[int, tuple[float, float, float]]:
        vports = free_udp_ports(1)
        with GcsEndpoint(vports[0]) as gcs:
            fleet = MockFleet(
                n=1, gcs_ports=[gcs.port], vehicle_ports=vports, seed=seed, profile="ideal"
            )
            with fleet.running_in_thread():
                return {
                    m.time_boot_ms: (m.x, m.y, m.z)
                    for m in gcs.messages(0.6)
                    if m.get_type() == "LOCAL_POSITION_NED"
                }

    a, b, c = samples(21), samples(21), samples(22)
    common = sorted(set(a) & set(b) & set(c))
    assert len(common) >= 10
    assert [a[t] for t in common] == [b[t] for t in common]  # same seed, same noise per tick
    assert [a[t] for t in common] != [c[t] for t in common]
    assert max(abs(v) for t in common for v in a[t]) < 0.1  # ~1 cm noise on a parked vehicle


def test_faults_can_be_changed_while_running() -> None:
    with mock_vehicles() as (fleet, (gcs,)):
        assert gcs.recv("HEARTBEAT", 3.0) is not None
        fleet.vehicles[0].set_faults(FaultConfig(loss_to_gcs=1.0))
        t_change_ms = fleet.time_s * 1000.0
        stamped = [m.time_boot_ms for m in gcs.messages(0.5) if hasattr(m, "time_boot_ms")]
        # at most a message already on its way when the faults changed gets through
        assert all(t <= t_change_ms + 20 for t in stamped)
        fleet.vehicles[0].set_faults(FaultConfig())
        back = gcs.recv("LOCAL_POSITION_NED", 3.0)
        assert back is not None and back.time_boot_ms > t_change_ms + 400
        assert fleet.link_stats()[0]["downlink"].dropped == 0  # the clean channel drops nothing


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
