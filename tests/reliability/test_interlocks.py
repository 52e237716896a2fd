"""Safety interlocks of ``gcs fly`` not covered by tests/gcs/test_fly.py.

test_fly.py already proves: a plan over its velocity limit is refused before
connecting and ``--force`` passes the interlock; Ctrl-C in offboard holds every
vehicle; and (tests/mavlink/test_link_flight.py) a vehicle 5 m from its start
is refused by the link before anything arms.  Here: every kind of hand-edited
plan (spec below epsilon with the stored robustness left untouched, separation,
workspace, start, lowered limits) is refused, judged on the wire that no
vehicle got a command or a setpoint; and the far-start refusal through the
``gcs fly`` command with vehicles listening.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gcs.cli import main
from mavlink.mock import MockFleet
from mavlink.mock.testing import free_udp_ports
from planner.planfile import load_plan

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT / "tests" / "data" / "malformed"
GOOD_PLAN = ROOT / "tests" / "mavlink" / "data" / "reach_avoid_2.plan.json"
HAND_EDITED = sorted(
    name
    for name, exp in json.loads((CORPUS / "manifest.json").read_text(encoding="utf-8")).items()
    if exp["exit"] == 1
)
UPLINK_ACTIONS = ("COMMAND_LONG", "COMMAND_INT", "SET_POSITION_TARGET_LOCAL_NED", "MISSION_COUNT")


def mock_for(plan_path: Path, shift_d1_m: float = 0.0) -> tuple[MockFleet, list[str]]:
    """Mock vehicles on the ground below the plan's starts (d1 moved east by ``shift_d1_m``)."""
    plan = load_plan(plan_path)
    ports = free_udp_ports(4)
    spawns = [(v.start_enu_m[0], v.start_enu_m[1], 0.0) for v in plan.vehicles]
    spawns[0] = (spawns[0][0] + shift_d1_m, spawns[0][1], 0.0)
    mock = MockFleet(
        n=2, origin=plan.origin, spawns_enu_m=spawns, gcs_ports=ports[:2], vehicle_ports=ports[2:]
    )
    return mock, [f"udpin://127.0.0.1:{p}" for p in ports[:2]]


def test_hand_edited_plans_are_refused_and_nothing_reaches_listening_vehicles(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert len(HAND_EDITED) >= 5
    mock, urls = mock_for(GOOD_PLAN)
    stored = {
        name: json.loads((CORPUS / name).read_text(encoding="utf-8"))["robustness"]
        for name in HAND_EDITED
    }
    with mock.running_in_thread():
        for name in HAND_EDITED:
            argv = ["fly", str(CORPUS / name), "--timeout", "3"]
            rc = main([*argv, "--connection", urls[0], "--connection", urls[1]])
            out, err = capsys.readouterr()
            assert rc == 1, (name, err)
            assert out == "" and err.count("\n") == 1, (name, out, err)
            assert "refused: the plan fails verification:" in err and "--force" in err
        received = [dict(v.received) for v in mock.vehicles]
        states = [v.state for v in mock.vehicles]
    # The files still claim the planner's robustness: the interlock recomputed it.
    assert all(r > 0.5 for r in stored.values())
    for got in received:
        assert not any(kind in got for kind in UPLINK_ACTIONS), got
    assert not any(s.armed for s in states)


@pytest.mark.slow
def test_gcs_fly_refuses_a_vehicle_far_from_its_planned_start_before_arming(
    capsys: pytest.CaptureFixture[str],
) -> None:
    mock, urls = mock_for(GOOD_PLAN, shift_d1_m=5.0)
    with mock.running_in_thread():
        rc = main(["fly", str(GOOD_PLAN), "--connection", urls[0], "--connection", urls[1]])
        out, err = capsys.readouterr()
        received = [dict(v.received) for v in mock.vehicles]
        states = [v.state for v in mock.vehicles]
    assert rc == 1, err
    assert "OFFBOARD" not in out
    assert err.startswith("gcs fly: vehicle d1 (") and err.count("\n") == 1
    assert "m horizontally from its planned start (tolerance 1.00 m)" in err
    # The GCS connected (it asked for telemetry) but neither armed nor streamed to anyone.
    assert not any(s.armed for s in states)
    assert all(s.landed for s in states)
    for got in received:
        assert "SET_POSITION_TARGET_LOCAL_NED" not in got and "MISSION_COUNT" not in got
    assert any(got.get("COMMAND_LONG", 0) > 0 for got in received)
