"""Configuration errors of the mock fleet name what is wrong; a busy port fails the start."""

from __future__ import annotations

import socket

import pytest

from mavlink.mock import (
    FaultConfig,
    MockConfigError,
    MockFleet,
    MockStartError,
    MockVehicleConfig,
    Outage,
    WindConfig,
)
from mavlink.mock.sim.px4 import Px4Mode
from mavlink.mock.testing import free_udp_ports


@pytest.mark.parametrize(
    ("build", "needle"),
    [
        (lambda: MockFleet(n=0), "n must be"),
        (lambda: MockFleet(n=2, spawns_enu_m=[(0, 0, 0)]), "spawns_enu_m"),
        (lambda: MockFleet(n=2, gcs_ports=[14540]), "gcs_ports"),
        (lambda: MockFleet(n=1, vehicle_ports=[70000]), "out of range"),
        (lambda: MockFleet(n=2, faults={5: FaultConfig()}), "vehicle index 5"),
        (lambda: MockFleet(n=2, faults=[FaultConfig()]), "faults"),
        (lambda: MockFleet(n=1, params={"NO_SUCH": 1.0}), "NO_SUCH"),
        (lambda: MockFleet(n=1, origin=(1.0, 2.0)), "origin"),
        (lambda: MockFleet(n=1, physics_rate_hz=0.0), "physics_rate_hz"),
        (lambda: FaultConfig(duplicate=-0.1), "duplicate"),
        (lambda: FaultConfig(latency_s=float("inf")), "latency_s"),
        (lambda: Outage(3.0, 2.0), "end_s"),
        (lambda: Outage.parse("a:b"), "numbers"),
        (lambda: WindConfig(mean_ne_m_s=(1.0,)), "mean_ne_m_s"),
        (lambda: MockVehicleConfig(spawn_enu_m=(0.0, float("nan"), 0.0)), "spawn_enu_m"),
    ],
)
def test_bad_configuration_is_a_mock_config_error(build, needle) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(MockConfigError, match=needle):
        build()


def test_a_busy_vehicle_port_fails_the_start_in_thread_mode() -> None:
    (gcs_port,) = free_udp_ports(1)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        fleet = MockFleet(n=1, gcs_ports=[gcs_port], vehicle_ports=[port])
        with pytest.raises(MockStartError, match=f"127.0.0.1:{port}"), fleet.running_in_thread():
            pass
        assert not fleet.running


def test_px4_custom_mode_encoding_round_trips() -> None:
    for mode in Px4Mode:
        assert Px4Mode.from_custom_mode(mode.custom_mode) is mode
    assert Px4Mode.OFFBOARD.custom_mode == 6 << 16
    assert Px4Mode.AUTO_MISSION.custom_mode == (4 << 16) | (4 << 24)
    assert Px4Mode.from_main_sub(4, 0) is Px4Mode.AUTO_LOITER
    assert Px4Mode.from_main_sub(9, 0) is None


def test_link_stats_of_offline_links_are_none_not_an_error() -> None:
    # advance() without sockets: in-memory links keep no counters (found by mypy: the
    # offline links have no ``stats``, and link_stats() raised AttributeError)
    from mavlink.mock.fleet import MockFleet

    f = MockFleet(n=2)
    f.offline_links()
    f.advance(0.1)
    assert f.link_stats() == [
        {"sysid": i + 1, "uplink": None, "downlink": None, "send_errors": 0} for i in range(2)
    ]
