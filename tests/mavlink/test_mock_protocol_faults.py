"""Protocol-level tests of the mock PX4 vehicle with a pymavlink GCS (what MAVSDK hides):
the link's fault injectors (outages, loss, duplication, reordering, latency) and the
reproducibility of their draws and of the telemetry noise for a seed.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import pytest

from mavlink.mock import FaultConfig, MockFleet, Outage
from mavlink.mock.testing import GcsEndpoint, free_udp_ports
from tests.mavlink.mock_protocol_helpers import mock_vehicles

# ---------------------------------------------------------------- faults


@pytest.mark.slow
def test_outage_silences_the_link_for_its_window() -> None:
    faults = FaultConfig(outages=(Outage(0.5, 1.5),))
    with mock_vehicles(faults=faults) as (_fleet, (gcs,)):
        stamps = [m.time_boot_ms for m in gcs.messages(2.2) if m.get_type() == "LOCAL_POSITION_NED"]
        assert any(t < 500 for t in stamps) and any(t >= 1500 for t in stamps)
        assert not any(500 <= t < 1500 for t in stamps)


@pytest.mark.slow
def test_duplication_and_reordering_are_visible_in_sequence_numbers() -> None:
    faults = FaultConfig(duplicate=0.3, reorder=0.3, reorder_delay_s=0.02)
    with mock_vehicles(faults=faults) as (fleet, (gcs,)):
        seqs = [m.get_seq() for m in gcs.messages(1.0)]
        dups = sum(1 for a, b in itertools.pairwise(seqs) if a == b)
        backwards = sum(1 for a, b in itertools.pairwise(seqs) if 0 < (a - b) % 256 < 128)
        assert dups > 0 and backwards > 0
        stats = fleet.link_stats()[0]["downlink"]
        assert stats.duplicated > 0 and stats.reordered > 0


def test_fault_draws_are_reproducible_for_a_seed() -> None:
    import random

    from mavlink.mock.sim.faults import FaultyChannel

    def pattern(seed: int) -> list[int]:
        out: list[int] = []
        ch = FaultyChannel(
            FaultConfig(loss_to_gcs=0.3),
            0.3,
            random.Random(seed),
            lambda _delay, fn, data: fn(data),
            lambda d: out.append(d[0]),
            lambda: 0.0,
        )
        for k in range(200):
            ch.push(bytes([k]))
        return out

    a, b, c = pattern(1), pattern(1), pattern(2)
    assert a == b and a != c
    assert 100 < len(a) < 180  # about 70 % survive


def test_latency_jitter_and_reordering_delays_with_a_patched_clock() -> None:
    import random

    from mavlink.mock.sim.faults import FaultyChannel

    delays: list[float] = []

    def later(delay_s: float, fn: Callable[[bytes], None], data: bytes) -> None:
        """Stands in for the fleet's simulated timers: records the delays instead of waiting."""
        delays.append(delay_s)
        fn(data)

    got: list[bytes] = []
    faults = FaultConfig(latency_s=0.2, jitter_s=0.05, reorder=0.25, reorder_delay_s=0.5)
    ch = FaultyChannel(faults, 0.0, random.Random(5), later, got.append, lambda: 0.0)
    for k in range(400):
        ch.push(bytes([k % 256]))
    assert len(got) == 400 and len(delays) == 400
    plain = [d for d in delays if d < 0.5]
    held = [d for d in delays if d >= 0.5]
    assert all(0.2 <= d <= 0.25 for d in plain)
    assert all(0.7 <= d <= 0.75 for d in held)
    assert 60 < len(held) < 140  # about a quarter
    assert ch.stats.reordered == len(held) and ch.stats.delayed == 400


@pytest.mark.slow
def test_telemetry_noise_is_reproducible_for_a_seed() -> None:
    def samples(seed: int) -> dict[int, tuple[float, float, float]]:
        vports = free_udp_ports(1)
        with GcsEndpoint(vports[0]) as gcs:
            fleet = MockFleet(
                n=1, gcs_ports=[gcs.port], vehicle_ports=vports, seed=seed, profile="ideal"
            )
            with fleet.running_in_thread():
                return {
                    m.time_boot_ms: (m.x, m.y, m.z)
                    for m in gcs.messages(0.6)
                    if m.get_type() == "LOCAL_POSITION_NED"
                }

    a, b, c = samples(21), samples(21), samples(22)
    common = sorted(set(a) & set(b) & set(c))
    assert len(common) >= 10
    assert [a[t] for t in common] == [b[t] for t in common]  # same seed, same noise per tick
    assert [a[t] for t in common] != [c[t] for t in common]
    assert max(abs(v) for t in common for v in a[t]) < 0.1  # ~1 cm noise on a parked vehicle


def test_faults_can_be_changed_while_running() -> None:
    with mock_vehicles() as (fleet, (gcs,)):
        assert gcs.recv("HEARTBEAT", 3.0) is not None
        fleet.vehicles[0].set_faults(FaultConfig(loss_to_gcs=1.0))
        t_change_ms = fleet.time_s * 1000.0
        stamped = [m.time_boot_ms for m in gcs.messages(0.5) if hasattr(m, "time_boot_ms")]
        # at most a message already on its way when the faults changed gets through
        assert all(t <= t_change_ms + 20 for t in stamped)
        fleet.vehicles[0].set_faults(FaultConfig())
        back = gcs.recv("LOCAL_POSITION_NED", 3.0)
        assert back is not None and back.time_boot_ms > t_change_ms + 400
        assert fleet.link_stats()[0]["downlink"].dropped == 0  # the clean channel drops nothing
