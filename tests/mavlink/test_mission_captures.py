"""Camera and gimbal items in a mission: where a capture span's items go, and what it leaves
alone (mavlink.mission.conversion, CaptureSpan).

PX4 runs a DO item when the NAV item before it is completed (a waypoint after its hold), so the
items of a span that starts or ends within a hold split the hold; one starting on a leg waits for
the next waypoint, one ending on a leg stops at the last. The flight's path and clock stay the
plan's.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavlink.mission import CaptureSpan, Cmd, MissionEnd, trajectory_to_mission
from tests.mavlink.test_link_mission import ORIGIN, min_jerk

# 1 s segments: hover 2 s at A, 3 m east to B, hover 2 s at B, 4 m north to C.
# Waypoints A (0-2 s), B (arrive 3 s, hold to 5 s), C (arrive 6 s).
_WPS = [(0, 0, 2), (0, 0, 2), (0, 0, 2), (3, 0, 2), (3, 0, 2), (3, 0, 2), (3, 4, 2)]


def _mission(*spans: CaptureSpan):  # type: ignore[no-untyped-def]
    return trajectory_to_mission(
        min_jerk(_WPS, 1.0), ORIGIN, acceptance_radius_m=0.25, end=MissionEnd.HOLD, captures=spans
    )


def _layout(mp) -> list[tuple[int, float]]:  # type: ignore[no-untyped-def]
    """(command, param1) of every item but the take-off."""
    return [(int(i.command), round(float(i.param1), 6)) for i in mp.items[1:]]


def test_a_span_within_a_hold_splits_the_hold_around_its_items() -> None:
    plain = _mission()
    mp = _mission(CaptureSpan(3.5, 5.0, gimbal_pitch_deg=-10.0, interval_s=0.5, target="pole1"))
    W, S, C, G, ST, SP = (
        Cmd.NAV_WAYPOINT,
        Cmd.DO_CHANGE_SPEED,
        Cmd.DO_GIMBAL_MANAGER_CONFIGURE,
        Cmd.DO_GIMBAL_MANAGER_PITCHYAW,
        Cmd.IMAGE_START_CAPTURE,
        Cmd.IMAGE_STOP_CAPTURE,
    )
    assert _layout(mp) == [
        (W, 2.0),  # A, its hold
        (S, 1.0),
        (W, 0.5),  # B: hold until the span starts at 3.5 s
        (C, -2.0),  # the mission takes the gimbal (PX4 ignores its PITCHYAW otherwise)
        (G, -10.0),  # gimbal pitch
        (ST, 0.0),  # start capture (param1: every camera)
        (W, 1.5),  # B again: the rest of the hold
        (SP, 0.0),  # stop at the departure, 5 s
        (S, 1.0),
        (W, 0.0),  # C
    ]
    start = next(i for i in mp.items if i.command == ST)
    assert (start.param2, start.param3) == (0.5, 4.0)  # interval, count: 3.5, 4, 4.5, 5 s
    gimbal = next(i for i in mp.items if i.command == G)
    assert math.isnan(gimbal.param3) and math.isnan(gimbal.param4)  # rates not used
    configure = next(i for i in mp.items if i.command == C)
    assert (configure.param1, configure.param2, configure.param3, configure.param4) == (
        -2.0, -2.0, -1.0, -1.0,
    )  # fmt: skip
    # every camera item is in MAV_FRAME_MISSION, the one frame PX4 accepts them in
    assert {i.frame for i in mp.items if i.command in (C, G, ST, SP)} == {2}
    assert gimbal.param2 == 0.0  # yaw: straight ahead (the vehicle faces the target)
    # both halves of B are at B, on B's heading
    b = mp.items[3]
    b1, b2 = (i for i in mp.items if i.command == W and (i.x, i.y) == (b.x, b.y))
    assert (b1.x, b1.y, b1.z, b1.param4) == (b2.x, b2.y, b2.z, b2.param4)
    # the path, the clock and the legs are the plan's, as without the span
    t = np.linspace(0, 8, 801)
    np.testing.assert_array_equal(mp.path.position(t), plain.path.position(t))
    np.testing.assert_array_equal(mp.hold_s, plain.hold_s)
    np.testing.assert_array_equal(mp.leg_speed_m_s, plain.leg_speed_m_s)
    # the waypoint's seq is the item left at its departure (the second half)
    assert [mp.items[q].param1 for q in mp.waypoint_seq] == [2.0, 1.5, 0.0]
    (cap,) = mp.captures
    assert (cap.start_s, cap.stop_s, cap.images, cap.start_seq) == (3.5, 5.0, 4, start.seq)


def test_a_span_starting_on_a_leg_starts_at_the_next_waypoint_and_stops_within_its_hold() -> None:
    mp = _mission(CaptureSpan(2.4, 4.0, interval_s=1.0))
    W = Cmd.NAV_WAYPOINT
    assert _layout(mp)[1:8] == [
        (Cmd.DO_CHANGE_SPEED, 1.0),
        (W, 0.0),  # B on arrival (3 s): a waypoint PX4 completes at once
        (Cmd.DO_GIMBAL_MANAGER_CONFIGURE, -2.0),
        (Cmd.DO_GIMBAL_MANAGER_PITCHYAW, 0.0),
        (Cmd.IMAGE_START_CAPTURE, 0.0),
        (W, 1.0),  # to 4 s
        (Cmd.IMAGE_STOP_CAPTURE, 0.0),
    ]
    assert _layout(mp)[8] == (W, 1.0)  # the rest of B's hold, 4-5 s
    (cap,) = mp.captures
    assert (cap.start_s, cap.stop_s, cap.images) == (3.0, 4.0, 2)


def test_a_span_with_no_waypoint_in_it_is_dropped_and_says_so() -> None:
    plain = _mission()
    mp = _mission(CaptureSpan(2.2, 2.8))  # on the leg A -> B
    assert _layout(mp) == _layout(plain)
    (cap,) = mp.captures
    assert cap.start_s is None and cap.stop_s is None and cap.images == 0 and cap.start_seq == -1


def test_a_span_over_a_waypoint_flown_through_counts_its_pictures_by_time() -> None:
    # no hovers: waypoints at 0, 1, 2, 3 s; the span's only waypoint is at 2 s
    traj = min_jerk([(0, 0, 2), (2, 0, 2), (4, 0, 2), (6, 0, 2)], 1.0)
    mp = trajectory_to_mission(
        traj,
        ORIGIN,
        end=MissionEnd.HOLD,
        captures=[CaptureSpan(1.5, 2.9, interval_s=0.4)],
    )
    cmds = [int(i.command) for i in mp.items]
    assert Cmd.IMAGE_STOP_CAPTURE not in cmds  # no waypoint after the start within the span
    start = next(i for i in mp.items if i.command == Cmd.IMAGE_START_CAPTURE)
    assert start.param3 == 3.0  # 2.0, 2.4, 2.8 s
    (cap,) = mp.captures
    assert (cap.start_s, cap.stop_s, cap.images) == (2.0, None, 3)


@pytest.mark.parametrize("interval", [0.5, 1.0, 2.0])
def test_two_spans_at_one_waypoint_are_in_time_order(interval: float) -> None:
    mp = _mission(
        CaptureSpan(3.2, 3.8, interval_s=interval, target="a"),
        CaptureSpan(4.0, 5.0, interval_s=interval, target="b"),
    )
    kinds = [
        (int(i.command), float(i.param1))
        for i in mp.items
        if i.command in (Cmd.NAV_WAYPOINT, Cmd.IMAGE_START_CAPTURE, Cmd.IMAGE_STOP_CAPTURE)
    ]
    W, ST, SP = Cmd.NAV_WAYPOINT, Cmd.IMAGE_START_CAPTURE, Cmd.IMAGE_STOP_CAPTURE
    holds_at_b = [p for c, p in kinds[1:] if c == W][:-1]
    assert sum(holds_at_b) == pytest.approx(2.0)  # B's hold, split in four
    order = [c for c, _ in kinds[1:] if c != W]
    assert order == [ST, SP, ST, SP]
    configures = [i for i in mp.items if i.command == Cmd.DO_GIMBAL_MANAGER_CONFIGURE]
    assert len(configures) == 1  # the gimbal is taken once, before the first pitch
    a, b = mp.captures
    assert (a.start_s, a.stop_s, b.start_s, b.stop_s) == (3.2, 3.8, 4.0, 5.0)
