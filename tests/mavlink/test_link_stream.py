"""Deadline scheduling of the setpoint streamer, on a simulated clock (no sleeping)."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from mavlink.errors import StreamError
from mavlink.offboard.stream import Setpoint, SetpointStreamer, StreamTarget
from mavlink.plan_setpoints import NedSetpoints


class SimClock:
    """A clock that only moves when the streamer sleeps or a send costs time."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t

    async def sleep(self, dt: float) -> None:
        self.t += dt


def ramp(n: int, rate_hz: float, offset: float = 0.0) -> NedSetpoints:
    k = np.arange(n, dtype=float)
    pos = np.column_stack([k, np.full(n, offset), np.full(n, -2.0)])
    return NedSetpoints(k / rate_hz, pos, np.ones((n, 3)), np.zeros((n, 3)), np.zeros(n))


def test_every_setpoint_is_sent_in_order_at_its_absolute_deadline() -> None:
    clock = SimClock()
    rate = 50.0
    log: dict[str, list[tuple[float, float, float]]] = {"a": [], "b": []}
    cost_s = 0.0004  # each send takes 0.4 ms of (simulated) time

    def sender(name: str):
        def send(sp: Setpoint) -> None:
            clock.t += cost_s
            log[name].append((clock.t, sp.n_m, sp.e_m))

        return send

    targets = [
        StreamTarget("a", sender("a"), ramp(20, rate)),
        StreamTarget("b", sender("b"), ramp(15, rate, 1.0)),
    ]
    streamer = SetpointStreamer(targets, rate, clock=clock, sleep=clock.sleep)
    t0 = clock.t + 0.1
    stats = asyncio.run(streamer.run(t0, extra_ticks=3))
    # 20 ticks + 3 extra; "b" holds its last setpoint (index 14) once its own run out.
    assert [row[1] for row in log["a"]] == [*range(20), 19, 19, 19]
    assert [row[1] for row in log["b"]] == [*range(15), *([14] * 8)]
    # Sent times never drift: tick k is sent within two send costs of t0 + k / rate.
    times = np.array([row[0] for row in log["a"]])
    deadlines = t0 + np.arange(23) / rate
    assert np.all(times >= deadlines) and np.all(times - deadlines <= 2 * cost_s + 1e-12)
    for s in stats.values():
        assert (s.sent, s.skipped, s.failed, s.late) == (23, 0, 0, 0)
        assert s.max_lateness_s <= 2 * cost_s + 1e-12


def test_a_stall_skips_stale_setpoints_instead_of_bunching_them() -> None:
    clock = SimClock()
    rate = 20.0
    sent: list[float] = []

    def send(sp: Setpoint) -> None:
        n = sp.n_m
        sent.append(n)
        if n == 5:
            clock.t += 3.5 / rate  # a 175 ms stall after setpoint 5

    streamer = SetpointStreamer(
        [StreamTarget("a", send, ramp(20, rate))], rate, clock=clock, sleep=clock.sleep
    )
    stats = asyncio.run(streamer.run(clock.t))["a"]
    # The loop resumes at 8.5 periods: setpoints 6 and 7 are more than a period overdue and
    # skipped; 8 is the current one and goes out half a period late; 9 is on time again.
    assert sent == [0, 1, 2, 3, 4, 5, *range(8, 20)]
    assert (stats.sent, stats.skipped) == (18, 2)
    # Lateness is measured when the send returns: 5 (whose send stalled) and 8 are late.
    assert stats.late == 2
    assert stats.max_lateness_s == pytest.approx(3.5 / rate)


def test_failing_sends_are_counted_and_the_stream_goes_on() -> None:
    clock = SimClock()

    def send(sp: Setpoint) -> None:
        n = sp.n_m
        if n in (3, 4):
            raise OSError("network unreachable")

    streamer = SetpointStreamer(
        [StreamTarget("a", send, ramp(10, 20.0))], 20.0, clock=clock, sleep=clock.sleep
    )
    stats = asyncio.run(streamer.run(clock.t))["a"]
    assert (stats.sent, stats.failed) == (8, 2)
    assert isinstance(streamer.last_errors["a"], OSError)


def test_stop_event_ends_the_stream_before_the_next_tick() -> None:
    clock = SimClock()
    stop = asyncio.Event()

    def send(sp: Setpoint) -> None:
        n = sp.n_m
        if n == 4:
            stop.set()

    streamer = SetpointStreamer(
        [StreamTarget("a", send, ramp(50, 20.0))], 20.0, clock=clock, sleep=clock.sleep
    )
    assert asyncio.run(streamer.run(clock.t, stop=stop))["a"].sent == 5


@pytest.mark.parametrize("rate", [0.0, 2.0, 100.5, float("nan")])
def test_rates_outside_px4_limits_are_refused(rate: float) -> None:
    with pytest.raises(StreamError, match="stream rate"):
        SetpointStreamer([StreamTarget("a", lambda *_: None, ramp(3, 20.0))], rate)


def test_setpoint_shapes_are_checked() -> None:
    with pytest.raises(StreamError, match=r"vel_ned_m_s has shape \(2, 3\), expected \(3, 3\)"):
        NedSetpoints(np.zeros(3), np.zeros((3, 3)), np.zeros((2, 3)), np.zeros((3, 3)), np.zeros(3))


def test_send_groups_spread_the_fleet_over_the_period() -> None:
    clock = SimClock()
    rate = 20.0
    period = 1.0 / rate
    log: list[tuple[str, float, float]] = []

    def sender(name: str):
        def send(sp: Setpoint) -> None:
            n = sp.n_m
            log.append((name, clock.t, n))

        return send

    names = ["a", "b", "c", "d"]
    targets = [StreamTarget(x, sender(x), ramp(6, rate)) for x in names]
    streamer = SetpointStreamer(targets, rate, groups=2, clock=clock, sleep=clock.sleep)
    np.testing.assert_allclose(streamer.offsets_s, [0.0, period / 2, 0.0, period / 2])
    t0 = clock.t + 0.01
    stats = asyncio.run(streamer.run(t0))
    for i, name in enumerate(names):
        times = np.array([t for who, t, _ in log if who == name])
        np.testing.assert_allclose(times, t0 + np.arange(6) * period + streamer.offsets_s[i])
        assert [n for who, _, n in log if who == name] == list(range(6))
        assert stats[name].sent == 6 and stats[name].skipped == 0
    # Group 0 (a, c) and group 1 (b, d) alternate: never all four in one burst.
    order = [who for who, _, _ in log]
    assert set(order[0:2]) == {"a", "c"} and set(order[2:4]) == {"b", "d"}


def test_send_groups_are_validated() -> None:
    with pytest.raises(StreamError, match=r"send groups 3 outside 1\.\.2"):
        SetpointStreamer(
            [StreamTarget(x, lambda *_: None, ramp(3, 20.0)) for x in "ab"], 20.0, groups=3
        )


def test_a_replan_splices_one_vehicles_setpoints_and_drops_another_between_two_sends() -> None:
    clock = SimClock()
    rate = 20.0
    log: dict[str, list[float]] = {"a": [], "b": []}
    base = ramp(10, rate)
    shifted = base.pos_ned_m + np.array([100.0, 0.0, 0.0])
    new = NedSetpoints(base.t_s, shifted, base.vel_ned_m_s, base.acc_ned_m_s2, base.yaw_ned_rad)
    streamer: SetpointStreamer

    def send_a(sp: Setpoint) -> None:
        log["a"].append(sp.n_m)
        if sp.n_m == 3:  # the replan lands on the event loop between two sends: after tick 3
            assert streamer.next_tick == 4
            streamer.splice("b", new, streamer.next_tick)
            streamer.drop("a")

    streamer = SetpointStreamer(
        [
            StreamTarget("a", send_a, base),
            StreamTarget("b", lambda sp: log["b"].append(sp.n_m), base),
        ],
        rate,
        clock=clock,
        sleep=clock.sleep,
    )
    stats = asyncio.run(streamer.run(clock.t))
    assert log["a"] == [0, 1, 2, 3]  # nothing more once dropped
    assert log["b"] == [0, 1, 2, 3, *(100.0 + k for k in range(4, 10))]  # the new from tick 4
    assert stats["a"].sent == 4 and stats["b"].sent == 10
