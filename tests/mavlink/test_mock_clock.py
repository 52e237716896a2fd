"""The mock fleet's simulated time as the ground station's clock (mavlink.mock.sim.clock).

A flight in a dry run waits on the simulation: a sleep ends on the tick that reaches its
instant, whatever the fleet's speed and however busy the machine; delayed datagrams keep their
latency in simulated time; and nothing hangs when the fleet stops under a sleeper.
"""

from __future__ import annotations

import asyncio
import threading

import pytest

from mavlink.clock import WALL, Clock
from mavlink.mock import MockFleet
from mavlink.mock.sim.clock import SimClock
from mavlink.mock.sim.errors import MockConfigError
from mavlink.mock.testing import free_udp_ports


def _fleet(speed: float) -> MockFleet:
    gcs, veh = free_udp_ports(2)
    return MockFleet(
        n=1, gcs_ports=[gcs], vehicle_ports=[veh], profile="ideal", camera=False, speed=speed
    )


def test_both_clocks_are_clocks() -> None:
    fleet = MockFleet(n=1, camera=False)
    assert isinstance(WALL, Clock) and isinstance(fleet.clock, Clock)
    assert fleet.clock.unix_offset() == fleet.utc_start_s


def test_a_sleep_ends_on_the_first_tick_at_or_after_its_instant() -> None:
    class Sim:
        """What the clock reads of its fleet; the test moves time as the fleet's ticks do."""

        time_s = 0.0
        speed = 1.0
        utc_start_s = 0.0

    sim = Sim()
    clock = SimClock(sim)  # type: ignore[arg-type]
    clock.started()
    woke: list[tuple[float, float]] = []

    async def sleeper(wait: float) -> None:
        await clock.sleep(wait)
        woke.append((wait, sim.time_s))

    async def main() -> None:
        sim.time_s = 0.07  # a tick's instant summed in steps: 0.07000000000000001
        tasks = [asyncio.create_task(sleeper(w)) for w in (0.5, 0.013, 0.2, 0.01, 0.03)]
        await asyncio.sleep(0)
        for k in range(8, 80):
            sim.time_s = k * 0.01
            clock.wake_due(sim.time_s)
            for _ in range(3):
                await asyncio.sleep(0)  # the woken sleepers run before the next tick
        await asyncio.gather(*tasks)

    asyncio.run(main())
    expected = {0.01: 0.08, 0.013: 0.09, 0.03: 0.10, 0.2: 0.27, 0.5: 0.57}
    assert [w for w, _ in woke] == [0.01, 0.013, 0.03, 0.2, 0.5]
    for wait, at in woke:
        assert at == pytest.approx(expected[wait], abs=1e-12), (wait, at)


def test_sleepers_in_another_thread_wake_in_the_order_of_their_instants_never_early() -> None:
    fleet = _fleet(speed=8.0)
    woke: list[tuple[str, float, float]] = []

    async def sleeper(name: str, wait: float) -> None:
        due = fleet.clock.monotonic() + wait
        await fleet.clock.sleep(wait)
        woke.append((name, due, fleet.clock.monotonic()))

    async def main() -> None:
        await asyncio.gather(
            sleeper("c", 0.9), sleeper("a", 0.3), sleeper("b", 0.6), sleeper("d", 1.2)
        )

    with fleet.running_in_thread():
        asyncio.run(main())
    assert [w[0] for w in woke] == ["a", "b", "c", "d"]
    assert all(now >= due - 1e-9 for _, due, now in woke)


def test_a_cancelled_sleep_leaves_the_others_alone() -> None:
    fleet = _fleet(speed=8.0)

    async def main() -> float:
        gone = asyncio.create_task(fleet.clock.sleep(0.2))
        t = fleet.clock.monotonic()
        await asyncio.sleep(0)
        gone.cancel()
        await fleet.clock.sleep(0.4)
        with pytest.raises(asyncio.CancelledError):
            await gone
        return fleet.clock.monotonic() - t

    with fleet.running_in_thread():
        assert asyncio.run(main()) >= 0.4 - 1e-9


def test_stopping_the_fleet_wakes_a_sleeper_and_later_sleeps_run_on_the_wall_clock() -> None:
    fleet = _fleet(speed=4.0)
    asleep = threading.Event()

    async def main() -> None:
        task = asyncio.create_task(fleet.clock.sleep(3600.0))
        await asyncio.sleep(0)
        asleep.set()
        await asyncio.wait_for(task, 60.0)  # woken by the stop, not after an hour
        await fleet.clock.sleep(0.01)  # on the wall clock now: returns

    result: list[BaseException | None] = []

    def gcs() -> None:
        try:
            asyncio.run(main())
            result.append(None)
        except BaseException as exc:
            result.append(exc)

    with fleet.running_in_thread():
        thread = threading.Thread(target=gcs)
        thread.start()
        assert asleep.wait(30.0)
    thread.join(60.0)
    assert result == [None]
    assert not fleet.running


def test_delayed_datagrams_and_timers_keep_simulated_time() -> None:
    fleet = MockFleet(n=1, camera=False, profile="ideal", speed=5.0)
    calls: list[float] = []
    fleet.call_later(0.25, lambda: calls.append(fleet.time_s))
    fleet.call_later(0.03, lambda: calls.append(fleet.time_s))
    fleet.advance(1.0)
    assert calls == [pytest.approx(0.03), pytest.approx(0.25)]


@pytest.mark.parametrize("speed", [0.0, -1.0, 101.0, float("nan")])
def test_a_speed_out_of_range_is_refused_naming_it(speed: float) -> None:
    with pytest.raises(MockConfigError, match="speed"):
        MockFleet(n=1, speed=speed)
