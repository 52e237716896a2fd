"""Sudden changes during an offboard flight, on the mock over loopback UDP with real MAVSDK:
a vehicle that reboots in the air and comes back, an EKF origin reset in flight, and the
ground station's wall clock stepping (NTP)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from typing import Any

import numpy as np
import pytest

from mavlink.link.fleet import Fleet
from mavlink.mock import MockFleet
from mavlink.mock.sim.px4 import Px4Mode as MockMode
from mavlink.monitor import SafetyMonitor
from mavlink.monitor_findings import Verdict, always_clauses
from mavlink.offboard import FlightResult, fly_offboard
from mavlink.offboard.setpoints import OffboardConfig
from tests.mavlink.linkutil import mock_and_fleet, spec_formula, stored_plan
from tests.mavlink.linkutil import scenario as link_scenario

pytestmark = pytest.mark.slow  # flights or transfers over UDP (make test-fast skips)

HANG_S = 90.0

During = Callable[[MockFleet], Awaitable[None]]
After = Callable[[MockFleet, Fleet], Awaitable[dict[str, Any]]]


def fly_with(
    during: During | None, after: After | None = None, *, after_start_s: float = 1.0
) -> tuple[FlightResult, dict[str, Any]]:
    """Fly the 2-vehicle reach-avoid plan on ideal mocks under the spec's monitor; ``during``
    runs ``after_start_s`` into the plan, ``after`` once the flight has returned (its dict is
    returned with the result)."""
    plan = stored_plan(2)
    names = [v.name for v in plan.vehicles]
    trajs = {v.name: v.trajectory for v in plan.vehicles}
    spawns = [(v.start_enu_m[0], v.start_enu_m[1], 0.0) for v in plan.vehicles]
    clauses = always_clauses(spec_formula(link_scenario(2)), names)

    async def run() -> tuple[FlightResult, dict[str, Any]]:
        async with mock_and_fleet(names, plan.origin, spawns, profile="ideal") as (mock, fleet):
            started = asyncio.Event()
            monitor = SafetyMonitor(clauses, horizon_s=0.5, on_start=lambda t0: started.set())

            async def inject() -> None:
                await started.wait()
                await asyncio.sleep(after_start_s)
                if during is not None:
                    await during(mock)

            injector = asyncio.create_task(inject())
            try:
                result = await asyncio.wait_for(
                    fly_offboard(fleet, trajs, plan.origin, OffboardConfig(), monitor=monitor),
                    HANG_S,
                )
            finally:
                injector.cancel()
                await asyncio.gather(injector, return_exceptions=True)
            return result, (await after(mock, fleet) if after is not None else {})

    return asyncio.run(run())


def test_a_vehicle_rebooting_in_the_air_is_lost_the_rest_held_and_never_streamed_to_again() -> None:
    async def reboot(mock: MockFleet) -> None:
        mock.vehicles[1].reboot(1.5, in_air=True)  # a brown-out: 1.5 s silent, back fresh

    async def after(mock: MockFleet, fleet: Fleet) -> dict[str, Any]:
        # it comes back (heartbeats again, disarmed) ...
        t_end = time.monotonic() + 10.0
        while not (fleet["d2"].status().connected and fleet["d2"].status().armed is False):
            assert time.monotonic() < t_end, "d2 did not come back"
            await asyncio.sleep(0.05)
        # ... and is never streamed to again
        last = mock.vehicles[1].last_setpoint_s
        await asyncio.sleep(1.5)
        return {"streamed": mock.vehicles[1].last_setpoint_s != last, "d1": mock.vehicles[0].mode}

    result, seen = fly_with(reboot, after)
    ev = result.safety_event
    assert ev is not None and ev.verdict is Verdict.LINK_LOST and ev.vehicles == ("d2",)
    assert not result.completed and "d1" not in ev.action_failures
    assert seen == {"streamed": False, "d1": MockMode.AUTO_LOITER}  # the other one holds


def test_an_ekf_origin_reset_in_flight_stops_the_flight_naming_the_vehicle_and_the_shift() -> None:
    async def reset(mock: MockFleet) -> None:
        mock.vehicles[0].reset_ekf_origin(3.0, -4.0)  # EKF2 re-initialised its origin: 5 m

    async def after(mock: MockFleet, fleet: Fleet) -> dict[str, Any]:
        await asyncio.sleep(0.5)
        return {"modes": [v.mode for v in mock.vehicles]}

    result, seen = fly_with(reset, after)
    ev = result.safety_event
    assert ev is not None and ev.verdict is Verdict.ORIGIN_MOVED and ev.vehicles == ("d1",)
    assert "d1 by 5.00 m" in ev.detail and "no longer in the flight's frame" in ev.describe()
    assert seen["modes"] == [MockMode.AUTO_LOITER, MockMode.AUTO_LOITER]


def test_the_wall_clock_stepping_during_a_flight_changes_nothing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # NTP steps the host's clock back and forth by an hour during the flight: deadlines,
    # timeouts and the monitor run on the monotonic clock, so the flight is as without it.
    real = time.time
    state = {"step": 0.0}

    def stepping() -> float:
        return real() + state["step"]

    async def step_clock(mock: MockFleet) -> None:
        for k in range(6):
            state["step"] = 3600.0 if k % 2 == 0 else -3600.0
            await asyncio.sleep(0.4)
        state["step"] = 0.0

    monkeypatch.setattr(time, "time", stepping)
    result, _ = fly_with(step_clock, after_start_s=0.5)
    assert result.safety_event is None and result.completed
    # a deadline on the wall clock would have skipped every tick after a step (an hour
    # late) or waited an hour; a busy machine may skip the odd tick, never most of them
    for st in result.stats.values():
        assert st.failed == 0 and st.sent >= 0.9 * (st.sent + st.skipped), st
    assert all(np.all(np.diff(tr.t_s) > 0) for tr in result.tracks.values())


def test_two_autopilots_answering_as_one_system_id_are_refused_naming_both_addresses() -> None:
    from mavlink.errors import DuplicateSystemError
    from mavlink.link.vehicle_status import VehicleSpec
    from mavlink.mock.testing import free_udp_ports

    gcs, first, second = free_udp_ports(3)

    async def run() -> str:
        # two mock autopilots, both system id 1, both sending to the ground station's port;
        # the second boots 1.5 s after the first
        async with MockFleet(n=1, gcs_ports=[gcs], vehicle_ports=[first]):
            await asyncio.sleep(1.5)
            async with MockFleet(n=1, gcs_ports=[gcs], vehicle_ports=[second]):
                fleet = Fleet([VehicleSpec("d1", f"udpin://127.0.0.1:{gcs}", 1)])
                try:
                    with pytest.raises(DuplicateSystemError) as err:
                        await asyncio.wait_for(fleet.connect(), HANG_S)
                finally:
                    fleet.close()
                return str(err.value)

    text = asyncio.run(run())
    assert text.startswith(
        f"vehicle d1 (udpin://127.0.0.1:{gcs}): two vehicles answer as system id 1"
    )
    assert f"127.0.0.1:{first}" in text and f"127.0.0.1:{second}" in text
    assert "booted 1." in text and "MAV_SYS_ID" in text


def test_one_autopilot_heard_over_two_links_is_one_vehicle() -> None:
    from mavlink.link.scan import Heard, Sender, duplicates

    one_clock = Heard({1: {("10.0.0.2", 14580): Sender(("10.0.0.2", 14580), "udpin://:14540", 100.0),
                           ("10.0.0.3", 14580): Sender(("10.0.0.3", 14580), "udpin://:14540", 100.2)}})  # fmt: skip
    assert duplicates(one_clock, [1]) == []
    two_clocks = Heard({1: {("10.0.0.2", 14580): Sender(("10.0.0.2", 14580), "udpin://:14540", 100.0),
                            ("10.0.0.3", 14580): Sender(("10.0.0.3", 14580), "udpin://:14540", 160.0)}})  # fmt: skip
    (dup,) = duplicates(two_clocks, [1, 2])
    assert "booted 60.0 s apart" in dup.describe() and "10.0.0.3:14580" in dup.describe()
    no_clock = Heard({1: {("10.0.0.2", 14580): Sender(("10.0.0.2", 14580), "udpin://:14540", None),
                          ("10.0.0.3", 14580): Sender(("10.0.0.3", 14580), "udpin://:14540", 100.0)}})  # fmt: skip
    (dup,) = duplicates(no_clock, [1])
    assert "no clock" in dup.describe()
    assert duplicates(two_clocks, [2]) == []  # not a fleet vehicle's id: not ours to refuse
