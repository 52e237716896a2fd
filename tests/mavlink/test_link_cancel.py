"""Ctrl-C (a cancellation) in each phase of an offboard flight inside ``Fleet.flight()``: every
vehicle ends up holding, no task of the flight is left alive, and no setpoint stream outlives
the hold. Real MAVSDK against the in-process mock over loopback UDP."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable

import pytest

from mavlink.mock import FaultConfig, MockFleet
from mavlink.mock.sim.px4 import Px4Mode as MockMode
from mavlink.monitor import SafetyMonitor
from mavlink.offboard import fly_offboard
from mavlink.offboard.setpoints import OffboardConfig
from tests.mavlink.linkutil import mock_and_fleet, stored_plan

pytestmark = pytest.mark.slow  # flights or transfers over UDP (make test-fast skips)

HANG_S = 60.0


def _in_mode(mock: MockFleet, mode: MockMode, *, every: bool = False) -> bool:
    modes = [v.mode is mode for v in mock.vehicles]
    return all(modes) if every else any(modes)


PHASES: dict[str, Callable[[MockFleet, asyncio.Event], bool]] = {
    # climbing to the start altitude (PX4's AUTO.TAKEOFF)
    "take-off": lambda mock, started: _in_mode(mock, MockMode.AUTO_TAKEOFF),
    # the start setpoint streamed, nobody in offboard yet
    "pre-stream": lambda mock, started: (
        any(math.isfinite(v.last_setpoint_s) for v in mock.vehicles)
        and not _in_mode(mock, MockMode.OFFBOARD)
    ),
    # a vehicle has switched; its acknowledgement is still on the (slow) way back
    "switch": lambda mock, started: _in_mode(mock, MockMode.OFFBOARD),
    # the plan's clock is running
    "mid-flight": lambda mock, started: started.is_set(),
}


@pytest.mark.parametrize("phase", list(PHASES))
def test_a_cancelled_flight_holds_every_vehicle_and_leaves_nothing_running(phase: str) -> None:
    plan = stored_plan(2)
    names = [v.name for v in plan.vehicles]
    trajs = {v.name: v.trajectory for v in plan.vehicles}
    spawns = [(v.start_enu_m[0], v.start_enu_m[1], 0.0) for v in plan.vehicles]  # on the ground
    # the switch is caught in the act only if its acknowledgement takes a while to come back
    faults = FaultConfig(latency_s=0.25) if phase == "switch" else None

    async def run() -> None:
        async with mock_and_fleet(names, plan.origin, spawns, profile="ideal", faults=faults) as (
            mock,
            fleet,
        ):
            before = asyncio.all_tasks()
            started = asyncio.Event()
            monitor = SafetyMonitor((), on_start=lambda t0: started.set())
            guards = []

            async def flight() -> None:
                async with fleet.flight() as guard:
                    guards.append(guard)
                    await fly_offboard(
                        fleet, trajs, plan.origin, OffboardConfig(rate_hz=20.0), monitor=monitor
                    )

            task = asyncio.create_task(flight())
            t_end = time.monotonic() + HANG_S
            while not PHASES[phase](mock, started):
                assert not task.done(), "the flight ended before the phase"
                assert time.monotonic() < t_end, f"never reached {phase}"
                await asyncio.sleep(0.01)
            if phase == "mid-flight":
                await asyncio.sleep(1.0)
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await asyncio.wait_for(task, HANG_S)
            (guard,) = guards
            assert guard.stopped and guard.failures == {}
            leftover = asyncio.all_tasks() - before - {asyncio.current_task()}
            assert not leftover, leftover
            # every vehicle holds, and nothing streams to it any more
            t_end = time.monotonic() + 5.0
            while not _in_mode(mock, MockMode.AUTO_LOITER, every=True):
                assert time.monotonic() < t_end, [v.mode for v in mock.vehicles]
                await asyncio.sleep(0.05)
            last = [v.last_setpoint_s for v in mock.vehicles]
            await asyncio.sleep(1.0)
            assert [v.last_setpoint_s for v in mock.vehicles] == last
            assert _in_mode(mock, MockMode.AUTO_LOITER, every=True)

    asyncio.run(run())
