"""The mock's ``px4`` profile against PX4 v1.17 SITL (SIH): take-off, missions, geofence.

Row by row of docs/px4-behaviour.md: what PX4's navigator and mission protocol do (take-off,
waypoints and their trajectory, MISSION_ITEM_REACHED and MISSION_CURRENT, landing, the
stored plans, the predictive geofence, reposition).  Control and estimation are in
test_mock_px4.py.

The fleet is stepped offline (:meth:`MockFleet.advance`: simulated time, no sockets), and
the vehicles are spoken to in MAVLink bytes through :meth:`MockVehicle.receive`, so every
figure here is deterministic for its seed.  The references are PX4's own: its source's
formulas (PositionControl, TrajMath, TrajectoryConstraints, mavlink_mission.cpp) and the
figures observed on PX4 SITL.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import MockFleet, Px4Mode, WindConfig
from mavlink.mock.sim.navigation import corner_speed, max_speed_from_distance
from mavlink.mock.vehicle import MockVehicle
from tests.mavlink.mock_px4_helpers import (
    NO_CREEP,
    QUIET,
    cmd,
    fleet,
    offboard_hover,
    stream,
)

MISSION, FENCE, RALLY = 0, 1, 2


def acks(v: MockVehicle, command: int) -> list[int]:
    return [m.result for m in v.sent_messages() if m.get_type() == "COMMAND_ACK" and m.command == command]  # fmt: skip


def set_mode(v: MockVehicle, mode: Px4Mode) -> None:
    main, sub = mode.value
    cmd(v, mavlink2.MAV_CMD_DO_SET_MODE, mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)


def item(seq: int, command: int, lat_e7: int = 0, lon_e7: int = 0, alt: float = 0.0,
         p1: float = 0.0, p2: float = 0.0, p4: float = 0.0, mtype: int = MISSION,
         frame: int = mavlink2.MAV_FRAME_GLOBAL_INT, autocontinue: int = 1):  # type: ignore[no-untyped-def]  # fmt: skip
    return mavlink2.MAVLink_mission_item_int_message(
        1, 1, seq, frame, command, 0, autocontinue, p1, p2, 0.0, p4, lat_e7, lon_e7, alt, mtype
    )


def upload(f: MockFleet, v: MockVehicle, items: list, mtype: int = MISSION) -> None:  # type: ignore[no-untyped-def]
    """The GCS side of an upload, message by message; asserts the final ACK."""
    v.sent_messages()
    v.receive(mavlink2.MAVLink_mission_count_message(v.sysid, 1, len(items), mtype))
    for _ in range(len(items) + 2):
        f.advance(0.01)
        for m in v.sent_messages():
            if m.get_type() == "MISSION_REQUEST_INT":
                v.receive(items[m.seq])
            elif m.get_type() == "MISSION_ACK":
                assert m.type == mavlink2.MAV_MISSION_ACCEPTED
                return
    raise AssertionError("upload did not complete")


def download(f: MockFleet, v: MockVehicle, mtype: int) -> list:  # type: ignore[no-untyped-def]
    v.sent_messages()
    v.receive(mavlink2.MAVLink_mission_request_list_message(v.sysid, 1, mtype))
    (count,) = [m.count for m in v.sent_messages() if m.get_type() == "MISSION_COUNT"]
    out = []
    for seq in range(count):
        v.receive(mavlink2.MAVLink_mission_request_int_message(v.sysid, 1, seq, mtype))
        out += [m for m in v.sent_messages() if m.get_type() == "MISSION_ITEM_INT"]
    return out


def ne_to_e7(v: MockVehicle, north_m: float, east_m: float) -> tuple[int, int]:
    lat, lon, _ = v.ned_to_global(np.array([north_m, east_m, 0.0]))
    return round(lat * 1e7), round(lon * 1e7)


# ------------------------------------------------------------------ take-off


def takeoff(v: MockVehicle, above_home_m: float) -> None:
    alt = v.home_alt_amsl() + above_home_m
    nan = math.nan
    cmd(v, mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, alt)


def airborne(f: MockFleet, v: MockVehicle, above_home_m: float, settle_s: float) -> None:
    """Arm, take off to ``above_home_m`` and let ``settle_s`` pass."""
    v.arm()
    takeoff(v, above_home_m)
    f.advance(settle_s)


def test_takeoff_below_nav_mc_alt_rad_is_reached_at_once_and_creep_keeps_it_on_the_ground() -> None:  # fmt: skip
    f = fleet(seed=4)
    v = f.vehicles[0]
    assert v.arm() == mavlink2.MAV_RESULT_ACCEPTED
    takeoff(v, 0.75)
    assert v.mode is Px4Mode.AUTO_TAKEOFF
    f.advance(0.05)
    # within NAV_MC_ALT_RAD (0.8 m) of the target on the ground: "reached", Hold
    assert v.mode is Px4Mode.AUTO_LOITER and f.physics.true_pos_ned_m[0, 2] > -0.01
    f.advance(12.0)
    st = v.state
    agl = -f.physics.true_pos_ned_m[0, 2]
    est_above_home = float(v.home_ned_m[2]) - st.est_pos_ned_m[2]
    # the ground-effect creep: the estimate says it hovers (>= 0.75 m) while it barely flies
    # (whether PX4's land detector then sees it landed depends on how high the estimate crept)
    assert est_above_home > 0.6 and agl < 0.4
    # without the creep it hovers 0.75 m above home (and the origin's depth above that)
    f = fleet(seed=4, **NO_CREEP)
    v = f.vehicles[0]
    airborne(f, v, 0.75, 12.0)
    agl = -f.physics.true_pos_ned_m[0, 2]
    assert agl == pytest.approx(0.75, abs=0.2)  # above home, which is the ground


def test_takeoff_to_2_5_m_climbs_through_the_creep_and_settles() -> None:
    f = fleet(seed=5)
    v = f.vehicles[0]
    airborne(f, v, 2.5, 15.0)
    est_above_home = float(v.home_ned_m[2]) - v.state.est_pos_ned_m[2]
    assert v.mode is Px4Mode.AUTO_LOITER and est_above_home == pytest.approx(2.5, abs=0.2)
    assert f.physics.estimator.creep_m[0] < 0.05  # out of ground effect the baro is back


# ------------------------------------------------------------------ missions


def mission_items(v: MockVehicle, legs_ne_m, alt_above_home_m: float, radius_m: float,
                  hold_s: float = 0.0, speed_m_s: float | None = None,
                  takeoff_m: float | None = None) -> list:  # type: ignore[no-untyped-def]  # fmt: skip
    home_alt = v.home_alt_amsl()
    items = []
    if takeoff_m is not None:
        items.append(
            item(0, mavlink2.MAV_CMD_NAV_TAKEOFF, *ne_to_e7(v, 0, 0), home_alt + takeoff_m)
        )
    for n, e in legs_ne_m:
        items.append(item(len(items), mavlink2.MAV_CMD_NAV_WAYPOINT, *ne_to_e7(v, n, e),
                          home_alt + alt_above_home_m, p1=hold_s, p2=radius_m))  # fmt: skip
        if speed_m_s is not None:
            items.append(item(len(items), mavlink2.MAV_CMD_DO_CHANGE_SPEED, p1=1, p2=speed_m_s))
    return items


def start_mission(f: MockFleet, v: MockVehicle) -> None:
    f.advance(0.5)  # past PX4's post-upload window
    v.sent_messages()
    set_mode(v, Px4Mode.AUTO_MISSION)
    assert acks(v, mavlink2.MAV_CMD_DO_SET_MODE) == [mavlink2.MAV_RESULT_ACCEPTED]


def fly_until_done(f: MockFleet, v: MockVehicle, limit_s: float) -> tuple[float, list]:  # type: ignore[type-arg]
    t0, msgs = f.time_s, []
    while not v.mission_finished and f.time_s - t0 < limit_s:
        f.advance(0.1)
        msgs += v.sent_messages()
    return f.time_s - t0, msgs


def test_corner_speed_and_braking_follow_px4s_trajectory_law() -> None:
    p = MockFleet(n=1).vehicles[0].params
    o, a = np.zeros(3), np.array([10.0, 0.0, 0.0])

    def turn(deg: float, radius: float) -> float:
        h = math.radians(deg)
        nxt = a + 60.0 * np.array([math.cos(h), math.sin(h), 0.0])  # far: no braking cap
        return corner_speed(o, a, nxt, radius, p)

    # docs/px4-behaviour.md: 90 deg 0.67 / 1.22 / 1.73 m/s, 10 deg 2.3 / 4.1 / 5.9 m/s at R 0.3 / 1 / 2
    assert [round(turn(90, r), 2) for r in (0.3, 1.0, 2.0)] == [0.67, 1.22, 1.73]
    assert [round(turn(10, r), 1) for r in (0.3, 1.0, 2.0)] == [2.3, 4.1, 5.9]
    # stop-at-the-next-waypoint look-ahead: about 3.6 m/s on 7.5 m legs
    assert max_speed_from_distance(4.0, 3.0, 7.5, 0.0) == pytest.approx(3.58, abs=0.01)
    assert corner_speed(o, a, a + np.array([0.5, 0.5, 0.0]), 1.0, p) == 0.0  # next within R


@pytest.mark.parametrize("radius", [0.3, 2.0])
def test_a_vehicle_off_the_leg_by_more_than_the_radius_is_sent_back_to_the_line_first(radius: float) -> None:  # fmt: skip
    # PX4's FlightTaskAuto::_getCurrentState: farther than the acceptance radius from the
    # leg (previous waypoint -> target), the trajectory heads for the closest point on the
    # leg ("offtrack"), not for the target.
    f = fleet(seed=3, **QUIET, **NO_CREEP)
    v = f.vehicles[0]
    airborne(f, v, 5.0, 10.0)
    n0, e0, _ = f.physics.pos_ned_m[0]
    upload(f, v, mission_items(v, [(n0, e0), (n0 + 30.0, e0)], 5.0, radius))
    start_mission(f, v)
    f.advance(4.0)  # on the leg north, at speed
    speed = f.physics.sp_vel_ned_m_s[0, 0]
    assert speed > 1.0 and abs(f.physics.pos_ned_m[0, 1] - e0) < 0.1
    # a gust puts it 1 m east of the line
    f.physics.true_pos_ned_m[0, 1] += 1.0
    f.physics.update_estimate()
    f.advance(1.0)
    after = f.physics.sp_vel_ned_m_s[0, 0]
    if radius < 1.0:
        # the setpoint turns back for the closest point on the line, behind it (braking at
        # MPC_ACC_HOR), while the position loop pulls the vehicle west onto the line
        assert after < speed - 1.0, (speed, after)
    else:
        # within the radius of the line: the setpoint keeps going along the leg
        assert after > speed - 0.2, (speed, after)


def test_the_trajectory_waits_for_a_vehicle_that_trails_it() -> None:
    # PX4's PositionSmoothing: while the vehicle is behind its setpoint, the setpoint's clock
    # runs at 1 - error / MPC_XY_ERR_MAX: a vehicle trailing by 2 m or more holds it still.
    def setpoint_advance(err_max: float) -> float:
        f = fleet(seed=3, **QUIET, **NO_CREEP, MPC_XY_ERR_MAX=err_max)
        v = f.vehicles[0]
        airborne(f, v, 5.0, 10.0)
        n0, e0, _ = f.physics.pos_ned_m[0]
        upload(f, v, mission_items(v, [(n0, e0), (n0 + 40.0, e0)], 5.0, 1.0))
        start_mission(f, v)
        f.advance(5.0)
        f.physics.true_pos_ned_m[0, 0] -= 1.0  # the vehicle 1 m further behind
        f.physics.update_estimate()
        before = f.physics.sp_pos_ned_m[0, 0]
        f.advance(0.05)
        return float(f.physics.sp_pos_ned_m[0, 0] - before)

    free, held = setpoint_advance(10.0), setpoint_advance(1.0)
    assert free > 0.1 and held == pytest.approx(0.0, abs=1e-9)


@pytest.mark.slow
def test_missions_slow_at_every_waypoint_and_a_small_circle_missed_in_wind_costs_seconds() -> None:  # fmt: skip
    legs = [(0.0, 0.0), (15.0, 0.0), (15.0, 15.0), (30.0, 15.0), (30.0, 30.0)]
    straight_s = 4 * 15.0 / 3.4  # the legs flown at the cruise speed

    def fly(radius: float, wind_e_m_s: float) -> list[float]:
        f = MockFleet(n=1, seed=6, params={"MPC_XY_CRUISE": 3.4}, ready_after_s=0.0,
                      wind=WindConfig(mean_ne_m_s=(0.0, wind_e_m_s), gust_sigma_m_s=wind_e_m_s / 2))  # fmt: skip
        f.offline_links()
        v = f.vehicles[0]
        airborne(f, v, 5.0, 10.0)
        upload(f, v, mission_items(v, legs, 5.0, radius))
        start_mission(f, v)
        t0, seq, switches = f.time_s, v.mission_seq, [f.time_s]
        while not v.mission_finished and f.time_s - t0 < 120:
            f.advance(0.05)
            if v.mission_seq != seq:
                seq = v.mission_seq
                switches.append(f.time_s)
        assert v.mission_finished
        return list(np.diff([*switches, f.time_s]))

    # calm, R = 1 m: every corner slows the vehicle (PX4: 5 s of legs took 9.3-15.2 s)
    calm = fly(1.0, 0.0)
    assert sum(calm) > 1.3 * straight_s
    # in a 2 m/s crosswind a 0.3 m circle is missed and hunted for (PX4: 18-35 s lost on one
    # waypoint); the 1 m circle is not
    windy_small, windy_large = fly(0.3, 2.0), fly(1.0, 2.0)
    assert max(windy_small) > 1.8 * max(windy_large)
    assert sum(windy_small) > sum(windy_large) + 8.0


def test_mission_item_reached_is_the_last_item_processed_and_resent_up_to_ten_times() -> None:
    f = fleet(seed=7)
    v = f.vehicles[0]
    airborne(f, v, 4.0, 10.0)
    # wp 0, DO_CHANGE_SPEED 1, wp 2, DO_CHANGE_SPEED 3, wp 4 (last)
    items = mission_items(v, [(0.0, 0.0), (6.0, 0.0)], 4.0, 1.0, speed_m_s=2.0)
    items.append(item(len(items), mavlink2.MAV_CMD_NAV_WAYPOINT, *ne_to_e7(v, 6.0, 6.0),
                      v.home_alt_amsl() + 4.0, p2=1.0))  # fmt: skip
    upload(f, v, items)
    start_mission(f, v)
    _, msgs = fly_until_done(f, v, 60.0)
    f.advance(12.0)
    msgs += v.sent_messages()
    reached = [m.seq for m in msgs if m.get_type() == "MISSION_ITEM_REACHED"]
    # the waypoints followed by a DO item are never reported: the DO item's seq is
    assert 0 not in reached and 2 not in reached
    assert set(reached) == {1, 3, 4}
    # the last one re-sent about once a second, up to 10 times after the first report
    assert reached.count(4) == 11
    current = [m for m in msgs if m.get_type() == "MISSION_CURRENT"]
    assert current and current[-1].mission_state == mavlink2.MISSION_STATE_COMPLETE


@pytest.mark.parametrize("profile", ["px4", "ideal"])
@pytest.mark.slow
def test_a_waypoint_is_reported_reached_when_its_hold_is_over_and_a_loiter_unlim_never(
    profile: str,
) -> None:
    # PX4 (MissionBlock::is_mission_item_reached_or_completed): an item is reached once it is
    # completed, a waypoint after its hold (param1), so its report comes at the end of the
    # hold and the mission's last report is its finish; LOITER_UNLIM never completes. The
    # ideal vehicle reports on arrival.
    f = fleet(seed=3, profile=profile)
    v = f.vehicles[0]
    airborne(f, v, 4.0, 10.0)
    items = mission_items(v, [(0.0, 0.0), (5.0, 0.0)], 4.0, 1.0, hold_s=3.0)
    items.append(item(len(items), mavlink2.MAV_CMD_NAV_LOITER_UNLIM, *ne_to_e7(v, 5.0, 5.0),
                      v.home_alt_amsl() + 4.0))  # fmt: skip
    upload(f, v, items)
    start_mission(f, v)
    arrived, reached, t0 = None, {}, f.time_s
    while f.time_s - t0 < 40.0:
        f.advance(0.01)
        if arrived is None and v.mission_seq == 1 and v.mission_phase == "hold":
            arrived = f.time_s
        for m in v.sent_messages():
            if m.get_type() == "MISSION_ITEM_REACHED":
                reached.setdefault(m.seq, f.time_s)
    assert arrived is not None and 1 in reached
    if profile == "px4":
        assert reached[1] - arrived == pytest.approx(3.0, abs=0.03)
        assert 2 not in reached and v.mission_seq == 2 and not v.mission_finished
    else:
        assert reached[1] - arrived == pytest.approx(0.0, abs=0.03)
        assert 2 in reached


def current_and_reached_times(f: MockFleet, v: MockVehicle, limit_s: float):  # type: ignore[no-untyped-def]
    """Step 10 ms at a time; (time, seq) of every MISSION_CURRENT change and first reached."""
    cur, reached, t0 = [], {}, f.time_s
    while (not v.mission_finished or f.time_s - t0 < 2.5) and f.time_s - t0 < limit_s:
        f.advance(0.01)
        for m in v.sent_messages():
            if m.get_type() == "MISSION_CURRENT" and (not cur or cur[-1][1] != m.seq):
                cur.append((f.time_s, m.seq))
            elif m.get_type() == "MISSION_ITEM_REACHED":
                reached.setdefault(m.seq, f.time_s)
    return cur, reached


@pytest.mark.parametrize("now", [0.0, 1.0])
def test_mission_current_mostly_comes_with_the_once_a_second_report(now: float) -> None:
    # PX4 v1.17 (mavlink_mission.cpp): the current seq is a static shared by all MAVLink
    # instances, so the API link saw 61 of 65 advances only on its 1 Hz report, 0.1-0.9 s
    # after the MISSION_ITEM_REACHED of the item before; MOCK_MC_NOW = 1: all at once.
    f = fleet(seed=9, MOCK_MC_NOW=now)
    v = f.vehicles[0]
    airborne(f, v, 4.0, 10.0)
    legs = [(0.0, 0.0), (4.0, 0.0), (4.0, 4.0), (0.0, 4.0), (0.0, 0.0), (4.0, 0.0)]
    upload(f, v, mission_items(v, legs, 4.0, 1.0, speed_m_s=3.0))
    f.advance(0.5)
    # MISSION_SET_CURRENT: acknowledged by the 1 Hz report, never at once (no ACK exists)
    v.sent_messages()
    v.receive(mavlink2.MAVLink_mission_set_current_message(v.sysid, 1, 2))
    f.advance(0.001)
    assert not [m for m in v.sent_messages() if m.get_type() == "MISSION_CURRENT"] or now == 1.0
    f.advance(1.1)
    assert [m.seq for m in v.sent_messages() if m.get_type() == "MISSION_CURRENT"][-1:] == [2]
    v.receive(mavlink2.MAVLink_mission_set_current_message(v.sysid, 1, 0))
    f.advance(1.1)
    set_mode(v, Px4Mode.AUTO_MISSION)
    cur, reached = current_and_reached_times(f, v, 60.0)
    assert v.mission_finished
    # every DO_CHANGE_SPEED (odd seq) is reached at once when its waypoint is, and the
    # mission moves on to the next waypoint: that MISSION_CURRENT is what is timed
    delays = [t - reached[seq - 1] for t, seq in cur if seq - 1 in reached and seq % 2 == 0]
    assert len(delays) == len(legs) - 1
    assert all(-1e-9 <= d < 1.0 + 0.02 for d in delays)
    at_once = sum(d < 0.02 for d in delays)
    if now == 1.0:
        assert at_once == len(delays)
    else:
        assert at_once <= 1 and max(delays) > 0.3


def test_do_change_speed_sets_the_cruise_speed_of_what_follows() -> None:
    f = fleet(seed=8)
    v = f.vehicles[0]
    airborne(f, v, 4.0, 10.0)
    upload(f, v, mission_items(v, [(0.0, 0.0), (40.0, 0.0)], 4.0, 1.0, speed_m_s=2.0))
    start_mission(f, v)
    top = 0.0
    for _ in range(150):
        f.advance(0.1)
        top = max(top, float(np.hypot(*f.physics.sp_vel_ned_m_s[0, :2])))
    assert top == pytest.approx(2.0, abs=0.05)


@pytest.mark.parametrize("profile", ["px4", "ideal"])
@pytest.mark.slow
def test_a_mission_land_flies_to_its_point_then_descends_at_px4s_graded_land_speed(
    profile: str,
) -> None:
    # PX4 v1.17 SITL, NAV_LAND 20 m from a 12 m hover: level flight to 1.7 m short of the
    # point (Mission::do_need_move_to_land: a rotary wing farther than NAV_ACC_RAD moves to
    # the land point first, a waypoint reported reached on arrival), then the descent while
    # it closes the rest, at 1.5 m/s (MPC_Z_VEL_MAX_DN) above MPC_LAND_ALT1 = 10 m, about
    # 0.7 m/s (MPC_LAND_SPEED) below MPC_LAND_ALT2 = 5 m, linear between
    # (FlightTaskAuto::_prepareLandSetpoints). The ideal vehicle descends at MPC_LAND_SPEED
    # and reports the land when it has landed.
    f = fleet(seed=5, profile=profile)
    v = f.vehicles[0]
    airborne(f, v, 12.0, 14.0)
    home_alt = v.home_alt_amsl()
    items = mission_items(v, [(0.0, 0.0)], 12.0, 1.0)
    items.append(item(1, mavlink2.MAV_CMD_NAV_LAND, *ne_to_e7(v, 20.0, 0.0), home_alt))
    upload(f, v, items)
    start_mission(f, v)
    track, reached = [], {}  # north, height above home (estimate), commanded and true down speed
    while not v.mission_finished and f.time_s < 120.0:
        f.advance(0.05)
        ph = f.physics
        track.append((float(ph.pos_ned_m[0, 0]), float(v.home_ned_m[2] - ph.pos_ned_m[0, 2]),
                      float(ph.sp_vel_ned_m_s[0, 2]), float(ph.true_vel_ned_m_s[0, 2])))  # fmt: skip
        for m in v.sent_messages():
            if m.get_type() == "MISSION_ITEM_REACHED":
                reached.setdefault(m.seq, len(track) - 1)
    assert v.mission_finished and v.state.landed
    north, height, command, down = np.array(track).T
    assert north[-1] == pytest.approx(20.0, abs=1.0)
    halfway = int(np.argmax(north > 10.0))
    assert height[halfway] > 12.0 - 0.5  # level on its way
    descending = height < 11.5
    if profile == "px4":
        k = reached[1]  # on arrival, before the descent
        assert 18.0 - 0.3 < north[k] < 20.5 and height[k] > 11.5
        graded = np.interp(height, [5.0, 10.0], [0.7, 1.5])  # ALT2, ALT1 -> LAND_SPEED, MAX_DN
        assert command[descending] == pytest.approx(graded[descending], abs=0.02)
        assert down.max() == pytest.approx(1.5, abs=0.15)  # the vehicle follows
        # the truth follows within the estimate's error (SITL: 0.6-0.8 m/s there)
        assert down[(height > 1.0) & (height < 4.0)].mean() == pytest.approx(0.7, abs=0.1)
    else:
        assert reached[1] >= len(track) - 2  # when it has landed
        assert command[descending] == pytest.approx(0.7, abs=0.02)
        assert down.max() == pytest.approx(0.7, abs=0.1)


def test_a_mission_land_over_its_point_is_reported_when_landed() -> None:
    # PX4 v1.17 SITL, a waypoint at the land point then the NAV_LAND: no move to land, and
    # the land item is reached when the land detector says landed (17 s after the waypoint,
    # from 12 m); gcs missions end this way (mavlink.mission)
    f = fleet(seed=6)
    v = f.vehicles[0]
    airborne(f, v, 12.0, 14.0)
    items = mission_items(v, [(0.0, 0.0), (20.0, 0.0)], 12.0, 1.0)
    items.append(item(2, mavlink2.MAV_CMD_NAV_LAND, *ne_to_e7(v, 20.0, 0.0), v.home_alt_amsl()))
    upload(f, v, items)
    start_mission(f, v)
    first: dict[int, float] = {}
    landed_at = None
    while f.time_s < 120.0 and 2 not in first:
        f.advance(0.05)
        if landed_at is None and v.state.landed:
            landed_at = f.time_s
        for m in v.sent_messages():
            if m.get_type() == "MISSION_ITEM_REACHED":
                first.setdefault(m.seq, f.time_s)
    assert landed_at is not None and first[2] == pytest.approx(landed_at, abs=0.1)
    assert 13.0 < first[2] - first[1] < 20.0  # SITL: 17.0 s


def test_mission_takeoff_within_nav_mc_alt_rad_is_skipped_and_the_vehicle_auto_disarms() -> None:
    f = fleet(seed=9, COM_DISARM_PRFLT=4.0)
    v = f.vehicles[0]
    upload(f, v, mission_items(v, [(0.0, 0.0), (5.0, 0.0)], 0.32, 1.0, takeoff_m=0.32))
    v.arm()
    start_mission(f, v)
    msgs = []
    for _ in range(60):
        f.advance(0.1)
        msgs += v.sent_messages()
    texts = [m.text for m in msgs if m.get_type() == "STATUSTEXT"]
    assert not v.armed and "Disarmed by auto preflight disarming" in texts
    assert -f.physics.true_pos_ned_m[0, 2] < 0.05  # never left the ground
    # 2.5 m above the vehicle (more than NAV_MC_ALT_RAD): the take-off is flown
    f = fleet(seed=9, COM_DISARM_PRFLT=4.0)
    v = f.vehicles[0]
    upload(f, v, mission_items(v, [(0.0, 0.0), (5.0, 0.0)], 2.5, 1.0, takeoff_m=2.5))
    v.arm()
    start_mission(f, v)
    f.advance(6.0)
    assert v.armed and -f.physics.true_pos_ned_m[0, 2] > 1.5


def test_mission_mode_right_after_an_upload_is_acknowledged_twice_and_refused() -> None:
    f = fleet(seed=10)
    v = f.vehicles[0]
    upload(f, v, mission_items(v, [(0.0, 0.0), (5.0, 0.0)], 3.0, 1.0))
    v.arm()
    set_mode(v, Px4Mode.AUTO_MISSION)  # 10 ms after the mission became valid
    f.advance(0.05)
    assert acks(v, mavlink2.MAV_CMD_DO_SET_MODE) == [
        mavlink2.MAV_RESULT_ACCEPTED,
        mavlink2.MAV_RESULT_TEMPORARILY_REJECTED,
    ]
    assert v.mode is Px4Mode.AUTO_LOITER
    f.advance(0.1)  # past the ~90 ms window
    set_mode(v, Px4Mode.AUTO_MISSION)
    f.advance(0.05)
    assert acks(v, mavlink2.MAV_CMD_DO_SET_MODE) == [mavlink2.MAV_RESULT_ACCEPTED]
    assert v.mode is Px4Mode.AUTO_MISSION


# ------------------------------------------------------------------ storage


def test_download_returns_what_px4_stores_yaw_fence_and_rally() -> None:
    f = fleet()
    v = f.vehicles[0]
    lat, lon = ne_to_e7(v, 3.0, 4.0)
    upload(f, v, [
        item(0, mavlink2.MAV_CMD_NAV_WAYPOINT, lat, lon, 500.0, p2=1.0, p4=-81.887),
        item(1, mavlink2.MAV_CMD_NAV_WAYPOINT, lat, lon, 500.0, p2=1.0, p4=90.67021),
    ])  # fmt: skip
    back = download(f, v, MISSION)
    assert [np.float32(m.param4) for m in back] == [np.float32(278.113), np.float32(90.670204)]
    assert back[0].param2 == 1.0 and back[0].autocontinue == 1
    rel = mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    fence = [
        item(k, mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, *ne_to_e7(v, *ne), 0.0,
             p1=4.2, p2=7.0, mtype=FENCE, frame=rel)
        for k, ne in enumerate([(-9, -9), (-9, 9), (9, 9), (9, -9)])
    ] + [item(4, mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, lat, lon, 0.0, p1=2.5, mtype=FENCE)]  # fmt: skip
    upload(f, v, fence, FENCE)
    back = download(f, v, FENCE)
    assert all(m.autocontinue == 0 and m.frame == mavlink2.MAV_FRAME_GLOBAL_INT for m in back)
    assert [m.param1 for m in back] == [4.0, 4.0, 4.0, 4.0, 2.5]
    assert all(m.param2 == m.param3 == m.param4 == 0.0 for m in back)
    assert [m.current for m in back] == [1, 0, 0, 0, 0]  # the mission's current item (0)
    upload(f, v, [item(0, mavlink2.MAV_CMD_NAV_RALLY_POINT, lat, lon, 20.0, p1=3.0, p4=45.0,
                       mtype=RALLY)], RALLY)  # fmt: skip
    (rally,) = download(f, v, RALLY)
    assert rally.autocontinue == 1 and rally.param1 == rally.param4 == 0.0
    # the ideal profile returns items exactly as sent
    f = MockFleet(n=1, profile="ideal")
    v = f.vehicles[0]
    upload(f, v, fence, FENCE)
    first = download(f, v, FENCE)[0]
    assert (first.autocontinue, first.param1, first.param2, first.frame) == (
        1, pytest.approx(4.2, rel=1e-6), 7.0, rel,
    )  # fmt: skip


# ------------------------------------------------------------------ geofence


@pytest.mark.slow
def test_geofence_is_predictive_and_fires_before_a_goal_near_the_wall() -> None:
    def approach(**params: float) -> tuple[Px4Mode, list[str], float]:
        # the fence logic alone: a quiet estimator (its noise near a wall is another matter)
        f = fleet(seed=11, **QUIET, **params)
        v = f.vehicles[0]
        square = [(-2.0, -2.0), (-2.0, 2.0), (2.0, 2.0), (2.0, -2.0)]
        upload(f, v, [
            item(k, mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, *ne_to_e7(v, *ne), 0.0,
                 p1=4, mtype=FENCE)
            for k, ne in enumerate(square)
        ], FENCE)  # fmt: skip
        offboard_hover(f, v, down_m=-1.5)
        v.sent_messages()
        y0 = float(f.physics.pos_ned_m[0, 1])
        goal = 2.0 - 0.25  # a goal 0.25 m from the wall, reached at 0.75 m/s
        texts: list[str] = []
        y = y0
        for _ in range(800):
            y = min(goal, y + 0.75 * 0.01)
            stream(v, (0.0, y, -1.5), (0.0, 0.75 if y < goal else 0.0, 0.0))
            f.advance(0.01)
            texts += [m.text for m in v.sent_messages() if m.get_type() == "STATUSTEXT"]
        return v.mode, texts, float(f.physics.pos_ned_m[0, 1])

    mode, texts, y = approach()
    assert mode is Px4Mode.AUTO_LOITER and y < 2.0
    assert "Geofence: approaching or outside geofence" in texts and "Failsafe activated" in texts
    mode, texts, _ = approach(GF_PREDICT=0)  # only an actual breach counts
    assert mode is Px4Mode.OFFBOARD and not any("eofence" in t for t in texts)


def test_takeoff_ignores_its_yaw_and_reposition_takes_its_yaw_in_radians() -> None:
    # PX4 v1.17 navigator_main.cpp: the take-off's yaw is set to NaN ("Navigator doesn't
    # handle the yaw reset"); DO_REPOSITION copies param4 into the setpoint's yaw unconverted
    # (radians; MAVSDK's goto_location sends radians).
    f = fleet(seed=2, **QUIET)
    v = f.vehicles[0]
    v.arm()
    alt = v.home_alt_amsl() + 3.0
    cmd(v, mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 90.0, math.nan, math.nan, alt)
    f.advance(12.0)
    assert v.mode is Px4Mode.AUTO_LOITER
    assert abs(math.degrees(f.physics.yaw_rad[0])) < 6.0  # still facing north, as booted
    lat, lon, alt = v.ned_to_global(np.array([2.0, 1.0, -3.0]))
    v.receive(
        mavlink2.MAVLink_command_int_message(
            v.sysid, 1, mavlink2.MAV_FRAME_GLOBAL_INT, mavlink2.MAV_CMD_DO_REPOSITION, 0, 0,
            -1.0, 1.0, 0.0, math.pi / 2, round(lat * 1e7), round(lon * 1e7), alt,
        )
    )  # fmt: skip
    f.advance(6.0)
    assert acks(v, mavlink2.MAV_CMD_DO_REPOSITION) == [mavlink2.MAV_RESULT_ACCEPTED]
    assert abs(math.degrees(f.physics.yaw_rad[0]) - 90.0) < 3.0
    assert math.dist(v.state.est_pos_ned_m, (2.0, 1.0, -3.0)) < 0.2


@pytest.mark.parametrize("profile", ["px4", "ideal"])
@pytest.mark.slow
def test_a_waypoints_yaw_is_flown_from_when_it_is_current_turning_at_mpc_yawrauto_max(
    profile: str,
) -> None:
    # PX4 (MissionBlock::mission_item_to_position_setpoint, FlightTaskAuto): the current
    # item's yaw (param4, degrees) is the yaw setpoint from the moment the item is current,
    # rate-limited to MPC_YAWRAUTO_MAX (45 deg/s); a NaN yaw heads toward the waypoint
    # (MPC_YAW_MODE 0). ATTITUDE reports the heading flown.
    f = fleet(seed=5, profile=profile, **QUIET)
    v = f.vehicles[0]
    airborne(f, v, 4.0, 10.0)
    home = v.home_alt_amsl() + 4.0
    items = [
        item(0, mavlink2.MAV_CMD_NAV_WAYPOINT, *ne_to_e7(v, 0.0, 0.0), home, p2=1.0, p4=0.0),
        item(1, mavlink2.MAV_CMD_NAV_WAYPOINT, *ne_to_e7(v, 0.0, 25.0), home, p2=1.0, p4=200.0),
        item(2, mavlink2.MAV_CMD_NAV_WAYPOINT, *ne_to_e7(v, 25.0, 25.0), home, p2=1.0,
             p4=math.nan),
    ]  # fmt: skip
    upload(f, v, items)
    start_mission(f, v)
    yaw, seq, attitude = [], [], []
    while not v.mission_finished and len(yaw) < 1200:
        f.advance(0.05)
        yaw.append(float(f.physics.yaw_rad[0]))
        seq.append(v.mission_seq)
        attitude += [m.yaw for m in v.sent_messages() if m.get_type() == "ATTITUDE"]
    assert v.mission_finished
    deg = np.degrees(np.unwrap(np.asarray(yaw)))
    s = np.asarray(seq)
    on_1 = np.flatnonzero(s == 1)
    # toward 200 deg (not toward the waypoint, due east) and turned the shorter way, through
    # 180, at no more than MPC_YAWRAUTO_MAX
    rate = np.abs(np.diff(deg)) / 0.05
    assert rate.max() <= v.params["MPC_YAWRAUTO_MAX"] + 1e-6
    assert abs(deg[on_1[-1]] % 360 - 200.0) < 2.0
    assert np.all(deg[on_1] <= 0.5)  # 0 -> -160 (= 200): the shorter turn, counter-clockwise
    # the last waypoint has no yaw: the vehicle turns toward it, due north (0 deg)
    assert abs((deg[-1] + 180.0) % 360.0 - 180.0) < 5.0
    # ATTITUDE carries the vehicle's heading
    assert attitude and abs(math.degrees(attitude[-1]) - ((deg[-1] + 180) % 360 - 180)) < 1.0
