"""``--signing-key`` on the ground-station commands, against mock vehicles that require it."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from gcs.cli import main
from gcs.flight.dryrun import free_udp_ports, sim_speed
from mavlink.mock import MockFleet
from planner.planfile import load_plan

pytestmark = pytest.mark.slow  # flights or transfers over UDP (make test-fast skips)

PLAN = Path(__file__).resolve().parents[1] / "mavlink" / "data" / "reach_avoid_2.plan.json"
KEY = bytes(range(32))


@pytest.fixture
def signed_mock() -> Iterator[tuple[MockFleet, list[str]]]:
    plan = load_plan(PLAN)
    ports = free_udp_ports(4)
    fleet = MockFleet(
        speed=sim_speed(),
        n=2,
        origin=plan.origin,
        spawns_enu_m=plan.ground_spawns(),
        gcs_ports=ports[:2],
        vehicle_ports=ports[2:],
        signing_key=KEY,
    )
    with fleet.running_in_thread():
        yield fleet, [a for p in ports[:2] for a in ("--connection", f"udpin://127.0.0.1:{p}")]


def test_upload_reaches_signed_vehicles_only_with_the_key(
    signed_mock: tuple[MockFleet, list[str]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fleet, connections = signed_mock
    key_file = tmp_path / "fleet.key"
    key_file.write_text(KEY.hex())
    # Unsigned: the vehicles refuse the transfer (a vehicle failure, exit 3); nothing stored.
    assert main(["upload", str(PLAN), "--timeout", "5", *connections]) == 3
    assert all(not v.mission_items(0) for v in fleet.vehicles)
    assert sum(v.signing_rejected for v in fleet.vehicles) > 0
    capsys.readouterr()
    # The refused transfer's last datagrams may still be on their way to the vehicles (its
    # MAVSDK server stops after the command returns): count once they have stopped coming.
    rejected_before = _settled_rejections(fleet)
    # Signed through the proxies: stored and read back, nothing more rejected.
    assert main(["upload", str(PLAN), "--signing-key", str(key_file), *connections]) == 0
    assert all(v.mission_items(0) for v in fleet.vehicles)
    assert [v.signing_rejected for v in fleet.vehicles] == rejected_before


def _settled_rejections(
    fleet: MockFleet, quiet_s: float = 0.5, within_s: float = 10.0
) -> list[int]:
    """Each vehicle's count of rejected unsigned packets once it has not changed for
    ``quiet_s`` (wall time), or as it is after ``within_s``."""
    last = [v.signing_rejected for v in fleet.vehicles]
    t_end = time.monotonic() + within_s
    t_changed = time.monotonic()
    while time.monotonic() < t_end and time.monotonic() - t_changed < quiet_s:
        time.sleep(0.05)
        now = [v.signing_rejected for v in fleet.vehicles]
        if now != last:
            last, t_changed = now, time.monotonic()
    return last


def test_signing_needs_a_connection_the_vehicle_sends_to(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    key_file = tmp_path / "fleet.key"
    key_file.write_text(KEY.hex())
    argv = ["status", "--signing-key", str(key_file), "--connection", "udpout://127.0.0.1:14580"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "udpin:// connections only" in err
