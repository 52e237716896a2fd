"""Dry runs: mock PX4 vehicles (:class:`mavlink.mock.MockFleet`) in a background thread of this
process, on free loopback ports, each spawned **on the ground directly below its planned start**
(mission-frame ``z = 0``), as PX4 SITL spawns its vehicles; the flight then arms, takes off to
the start and flies, exactly as against SITL.

A room of its own because it stands in for the vehicles, not for the flight: ``gcs fly --mock``,
``gcs demo``, the benchmarks and the tests start the same mock fleet here and then fly it
through :func:`gcs.flight.fly_plan` like any other.
"""

from __future__ import annotations

import contextlib
import socket
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mavlink.mock import MockFleet
    from mavlink.mock.config import MockVehicleConfig, WindConfig
    from planner.planfile import Plan

__all__ = ["DryRun", "free_udp_ports", "ground_spawns", "mock_vehicles"]


def ground_spawns(plan: Plan) -> list[tuple[float, float, float]]:
    """Spawn points for a dry run: on the ground (mission ``z = 0``) below each planned start."""
    return [(float(v.start_enu_m[0]), float(v.start_enu_m[1]), 0.0) for v in plan.vehicles]


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
    """Mock vehicles running for a dry run: their fleet and the URL of each (plan order)."""

    mock: MockFleet
    urls: tuple[str, ...]
    sysids: tuple[int, ...]


@contextlib.contextmanager
def mock_vehicles(
    plan: Plan,
    *,
    seed: int = 0,
    profile: str = "px4",
    params: Mapping[str, float] | None = None,
    vehicle_configs: Sequence[MockVehicleConfig] | None = None,
    wind: WindConfig | None = None,
) -> Iterator[DryRun]:
    """Mock PX4 vehicles on the ground below the plan's starts, in a background thread.

    Vehicle ``i`` has system id ``i + 1`` and sends to a free loopback port, reached at
    ``udpin://127.0.0.1:PORT`` (the URLs yielded, plan order).  ``profile`` and
    ``params`` choose the vehicle (:mod:`mavlink.mock.profiles`: ``px4`` by default);
    ``vehicle_configs`` (one per vehicle, plan order: spawn, link faults, parameters) replace
    them where each vehicle differs (``gcs assess --replay --realtime``), and ``wind`` blows on all.
    """
    from mavlink.mock import MockFleet

    n = len(plan.vehicles)
    ports = free_udp_ports(2 * n)
    mock = MockFleet(
        n=n,
        origin=plan.origin,
        spawns_enu_m=ground_spawns(plan),
        gcs_ports=ports[:n],
        vehicle_ports=ports[n:],
        seed=seed,
        profile=profile,
        params=params,
        vehicle_configs=vehicle_configs,
        wind=wind,
    )
    with mock.running_in_thread():
        yield DryRun(
            mock=mock,
            urls=tuple(f"udpin://127.0.0.1:{p}" for p in ports[:n]),
            sysids=tuple(range(1, n + 1)),
        )
