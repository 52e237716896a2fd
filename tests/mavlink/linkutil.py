"""Shared set-up of the GCS link tests: mock fleet + MAVSDK fleet on free loopback ports."""

from __future__ import annotations

import contextlib
import socket
from collections.abc import AsyncIterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from gcs.flight.dryrun import sim_speed
from mavlink.clock import WALL
from mavlink.link.fleet import Fleet
from mavlink.link.vehicle_status import VehicleSpec
from mavlink.mock.fleet import MockFleet
from mavlink.tracks import FlownTrack
from planner.planfile import Plan, load_plan
from planner.problem import Problem
from planner.scenario import parse_scenario
from planner.scenario.spec import parse_clause
from planner.spec.predicates import build_registry
from planner.stl.ast import Formula, conjunction

DATA = Path(__file__).parent / "data"
SCENARIO = DATA / "link_reach_avoid.yaml"


def free_udp_ports(k: int) -> list[int]:
    """``k`` distinct UDP ports that were free a moment ago (bound to port 0 by the OS)."""
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(k)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def scenario(n: int) -> Problem:
    """The link test scenario with its first ``n`` vehicles."""
    data = yaml.safe_load(SCENARIO.read_text(encoding="utf-8"))
    data["vehicles"] = data["vehicles"][:n]
    return parse_scenario(data, str(SCENARIO))


def stored_plan(n: int) -> Plan:
    """The planner's plan for ``n`` vehicles (tests/mavlink/data/make_plans.py)."""
    return load_plan(DATA / f"reach_avoid_{n}.plan.json")


def spec_formula(problem: Problem) -> Formula:
    """The scenario's whole spec with its predicates (exact numpy semantics)."""
    registry = build_registry(problem)
    return conjunction([parse_clause(problem, c, registry) for c in problem.clauses])


def flown_robustness(
    spec: Formula, tracks: Mapping[str, FlownTrack], dt_s: float, horizon_s: float
) -> float:
    """Exact robustness of the flown tracks, resampled every ``dt_s`` over the horizon."""
    signals = {name: tr.resample(dt_s, horizon_s) for name, tr in tracks.items()}
    return spec.robustness(signals, dt_s)


def true_robustness(spec: Formula, samples: Mapping[str, np.ndarray], dt_s: float) -> float:
    """Robustness of positions given directly as ``(n, 3)`` arrays."""
    return spec.robustness(dict(samples), dt_s)


@contextlib.asynccontextmanager
async def mock_and_fleet(
    names: Sequence[str],
    origin: Any,
    spawns_enu_m: Sequence[Sequence[float]],
    *,
    link_timeout_s: float = 2.0,
    real_time: bool = False,
    **mock_kwargs: Any,
) -> AsyncIterator[tuple[MockFleet, Fleet]]:
    """A running :class:`MockFleet` and a connected :class:`Fleet` (same event loop), the
    fleet on the mock's simulated clock at the suite's speed (``$STL_GCS_SIM_SPEED``); with
    ``real_time`` the mock at speed 1 and the fleet on the wall clock, as against PX4 (the
    tests of the link's own timing: faults, outages, MAVSDK's timeouts)."""
    n = len(names)
    ports = free_udp_ports(2 * n)
    gcs, veh = ports[:n], ports[n:]
    async with MockFleet(
        n=n,
        origin=origin,
        spawns_enu_m=spawns_enu_m,
        gcs_ports=gcs,
        vehicle_ports=veh,
        speed=1.0 if real_time else sim_speed(),
        **mock_kwargs,
    ) as mock:
        specs = [
            VehicleSpec(name, f"udpin://127.0.0.1:{gcs[i]}", i + 1) for i, name in enumerate(names)
        ]
        async with Fleet(
            specs,
            link_timeout_s=link_timeout_s,
            connect_timeout_s=10.0,
            clock=WALL if real_time else mock.clock,
        ) as fleet:
            yield mock, fleet
