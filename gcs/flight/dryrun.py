"""Dry runs: mock PX4 vehicles (:class:`mavlink.mock.MockFleet`) in a background thread of this
process, on free loopback ports, each spawned **on the ground directly below its planned start**
(mission-frame ``z = 0``), as PX4 SITL spawns its vehicles; the flight then arms, takes off to
the start and flies, exactly as against SITL.

A room of its own because it stands in for the vehicles, not for the flight: ``gcs fly --mock``,
``gcs demo``, the benchmarks and the tests start the same mock fleet here and then fly it
through :func:`gcs.flight.fly_plan` like any other.

The mock vehicles may run faster than real time (``speed``; ``--speed`` or the environment's
``STL_GCS_SIM_SPEED``, as PX4 SITL's ``PX4_SIM_SPEED_FACTOR``): the flight then runs on their
simulated clock (:attr:`DryRun.clock`), so its timing holds at any speed, and on a busy machine
where the simulation falls behind its pace. What stays on the wall clock is MAVSDK (its own
process): a datagram's way through it takes ``speed`` times longer in simulated time.
"""

from __future__ import annotations

import contextlib
import math
import os
import socket
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from gcs.errors import UserError
from mavlink.mock import MockFleet

if TYPE_CHECKING:
    from mavlink.clock import Clock
    from mavlink.mock import MockFleet
    from mavlink.mock.sim.config import MockVehicleConfig, WindConfig
    from mavlink.mock.vehicle_faults import VehicleFault
    from planner.planfile import Plan

__all__ = ["SPEED_ENV", "DryRun", "free_udp_ports", "mock_vehicles", "sim_speed"]

#: The environment variable of the dry runs' default speed (times real time).
SPEED_ENV = "STL_GCS_SIM_SPEED"
#: The fastest a dry run may go: MAVSDK's latency, in real time, grows with it in simulated time.
MAX_SPEED = 20.0


def sim_speed(speed: float | None = None) -> float:
    """The dry runs' speed: ``speed`` if given, else ``$STL_GCS_SIM_SPEED``, else 1.

    Raises:
        UserError: outside (0, 20], naming ``--speed`` or the environment variable.
    """
    where = "--speed"
    if speed is None:
        raw = os.environ.get(SPEED_ENV, "").strip()
        if not raw:
            return 1.0
        where = f"${SPEED_ENV}"
        try:
            speed = float(raw)
        except ValueError:
            raise UserError(f"{where}: {raw!r} is not a number (times real time)") from None
    if not (math.isfinite(speed) and 0.0 < speed <= MAX_SPEED):
        raise UserError(f"{where}: must be in (0, {MAX_SPEED:g}] times real time, got {speed:g}")
    return float(speed)


def free_udp_ports(k: int) -> list[int]:
    """``k`` distinct loopback UDP ports that were free a moment ago (bound to port 0)."""
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(k)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [int(s.getsockname()[1]) for s in socks]
    finally:
        for s in socks:
            s.close()


@dataclass(frozen=True, slots=True, eq=False)
class DryRun:
    """Mock vehicles running for a dry run: their fleet, the URL of each (plan order), and
    the clock to fly them on (their simulated time)."""

    mock: MockFleet
    urls: tuple[str, ...]
    sysids: tuple[int, ...]

    @property
    def clock(self) -> Clock:
        """The vehicles' simulated time (:class:`mavlink.mock.sim.clock.SimClock`)."""
        return self.mock.clock


@contextlib.contextmanager
def mock_vehicles(
    plan: Plan,
    *,
    seed: int = 0,
    profile: str = "px4",
    params: Mapping[str, float] | None = None,
    vehicle_configs: Sequence[MockVehicleConfig] | None = None,
    wind: WindConfig | None = None,
    speed: float | None = None,
    faults: Sequence[tuple[int, VehicleFault]] = (),
) -> Iterator[DryRun]:
    """Mock PX4 vehicles on the ground below the plan's starts, in a background thread.

    Vehicle ``i`` has system id ``i + 1`` and sends to a free loopback port, reached at
    ``udpin://127.0.0.1:PORT`` (the URLs yielded, plan order).  ``profile`` and
    ``params`` choose the vehicle (:mod:`mavlink.mock.sim.profiles`: ``px4`` by default);
    ``vehicle_configs`` (one per vehicle, plan order: spawn, link faults, parameters) replace
    them where each vehicle differs (``gcs assess --replay --realtime``), and ``wind`` blows on all.
    ``speed``: simulated seconds per wall second (:func:`sim_speed`: default
    ``$STL_GCS_SIM_SPEED`` or 1); fly them on :attr:`DryRun.clock`. ``faults``: (vehicle
    index, fault) injected on each vehicle's plan clock (:mod:`mavlink.mock.vehicle_faults`).
    """

    n = len(plan.vehicles)
    ports = free_udp_ports(2 * n)
    mock = MockFleet(
        n=n,
        origin=plan.origin,
        spawns_enu_m=plan.ground_spawns(),
        gcs_ports=ports[:n],
        vehicle_ports=ports[n:],
        seed=seed,
        profile=profile,
        params=params,
        vehicle_configs=vehicle_configs,
        wind=wind,
        speed=sim_speed(speed),
        terrain=plan.terrain,
    )
    for i, fault in faults:
        mock.vehicles[i].plan_faults.add(fault)
    with mock.running_in_thread():
        yield DryRun(
            mock=mock,
            urls=tuple(f"udpin://127.0.0.1:{p}" for p in ports[:n]),
            sysids=tuple(range(1, n + 1)),
        )
