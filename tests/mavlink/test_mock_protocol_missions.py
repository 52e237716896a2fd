"""Protocol-level tests of the mock PX4 vehicle with a pymavlink GCS (what MAVSDK hides):
the mission protocol (upload, download, errors, the three plan types) and missions flown.

Identity, commands, parameters and offboard are in test_mock_protocol_commands.py.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import FaultConfig, Px4Mode
from mavlink.mock.mission import FENCE, MISSION, RALLY
from mavlink.mock.testing import GcsEndpoint
from tests.mavlink.mock_protocol_helpers import mock_vehicles, stream_setpoints


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


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_a_return_item_completes_the_mission_at_once_and_returns_in_auto_rtl() -> None:
    """As PX4 v1.17 SITL flew ``gcs upload --start --end return``: the return item reported
    reached as soon as it is current, MISSION_CURRENT on it with MISSION_STATE_COMPLETE and
    mission_mode 2 (not in mission mode), HEARTBEAT in AUTO.RTL until it lands at home and
    disarms (PX4: reached 25.9 s, AUTO.RTL 26.4 s, disarmed 39.5 s).  The px4 profile (the
    ideal one runs the same navigator code here)."""
    params = {"MPC_TKO_SPEED": 3.0, "MPC_LAND_SPEED": 2.5, "RTL_RETURN_ALT": 2.0,
              "MPC_XY_CRUISE": 6.0, "COM_DISARM_LAND": 0.5}  # fmt: skip
    with mock_vehicles(params=params, profile="px4") as (fleet, (gcs,)):
        v = fleet.vehicles[0]
        lat0, lon0 = v.origin_lla[0], v.origin_lla[1]
        import pymap3d

        def wp(seq: int, cmd: int, n: float, e: float, alt: float) -> object:
            lat, lon, _ = pymap3d.ned2geodetic(n, e, 0.0, lat0, lon0, v.origin_lla[2])
            return item_int(seq, command=cmd, x=round(lat * 1e7), y=round(lon * 1e7), z=alt)

        plan = [
            wp(0, mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 2.0),
            wp(1, mavlink2.MAV_CMD_NAV_WAYPOINT, 3, 0, 2.0),
            item_int(2, command=mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH, frame=mavlink2.MAV_FRAME_MISSION, x=0, y=0, z=0),
        ]  # fmt: skip
        assert upload(gcs, plan) == 0
        time.sleep(0.5)  # PX4 refuses mission mode for ~90 ms after an upload
        assert gcs.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        assert gcs.command(mavlink2.MAV_CMD_MISSION_START, 0, 0).result == 0
        events: list[tuple[float, str, object]] = []
        t0, mode = time.monotonic(), None
        for msg in gcs.messages(60.0):
            t = time.monotonic() - t0
            kind = msg.get_type()
            if kind == "MISSION_ITEM_REACHED" and msg.seq == 2:
                events.append((t, "reached", 2))
            elif kind == "MISSION_CURRENT" and msg.mission_state == mavlink2.MISSION_STATE_COMPLETE:
                events.append((t, "complete", (msg.seq, msg.mission_mode)))
            elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                now = next((m for m in Px4Mode if m.custom_mode == msg.custom_mode), None)
                armed = bool(msg.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)
                if now is not mode:
                    events.append((t, "mode", now))
                    mode = now
                if not armed and any(e[1] == "reached" for e in events):
                    events.append((t, "disarmed", None))
                    break
        names = [e[1] for e in events]
        assert "disarmed" in names, events
        reached = names.index("reached")
        rtl = next(i for i, e in enumerate(events) if e[1] == "mode" and e[2] is Px4Mode.AUTO_RTL)
        # reached on entering the item, then AUTO.RTL within the second (not after the landing)
        assert events[rtl][0] - events[reached][0] < 1.0, events
        modes_after = [e[2] for e in events[rtl:] if e[1] == "mode"]
        assert Px4Mode.AUTO_MISSION not in modes_after, events
        assert (2, 2) in [e[2] for e in events if e[1] == "complete"], events
        st = v.state
        assert st.landed and math.hypot(st.pos_ned_m[0], st.pos_ned_m[1]) < 1.0


@pytest.mark.slow
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
