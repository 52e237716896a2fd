"""Shared helpers of the protocol tests of the mock PX4 vehicle (test_mock_protocol_*.py).

Vehicles running in a thread on free loopback ports, each with a pymavlink GCS endpoint
(:class:`mavlink.mock.testing.GcsEndpoint`), a condition wait on them, and an offboard
setpoint stream.  A module of its own because the command, mission and fault tests all
start their vehicles with it.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

from gcs.flight.dryrun import sim_speed
from mavlink.mock import MockFleet
from mavlink.mock.testing import GcsEndpoint, free_udp_ports

ORIGIN = (47.397742, 8.545594, 488.0)


@contextmanager
def mock_vehicles(n: int = 1, **kwargs: object) -> Iterator[tuple[MockFleet, list[GcsEndpoint]]]:
    """``n`` vehicles on free ports, each with its own pymavlink GCS endpoint; the vehicles at
    the suite's speed (``$STL_GCS_SIM_SPEED``: the endpoints wait on the wall clock, which
    only makes their waits longer in the vehicles' time)."""
    vports = free_udp_ports(n)
    gcs = [GcsEndpoint(vports[i], target_system=i + 1) for i in range(n)]
    kwargs.setdefault("ready_after_s", 0.0)
    kwargs.setdefault("speed", sim_speed())
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


def stream_setpoints(
    gcs: GcsEndpoint, ned: tuple[float, float, float], duration_s: float, rate_hz: float = 20.0
) -> None:
    t_end = time.monotonic() + duration_s
    while time.monotonic() < t_end:
        gcs.position_setpoint(*ned)
        time.sleep(1.0 / rate_hz)
