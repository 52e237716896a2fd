"""Faults injected on the plan's clock in a dry run (``gcs fly --dry-run --mock-fault
VEHICLE:KIND@T``, issue 43): a vehicle lost, a failsafe, a critical battery.

References: PX4 v1.17's documented and source behaviour (the offboard-loss failsafe after
COM_OF_LOSS_T; COM_LOW_BAT_ACT 0 = warning only by default, 2 Land, 3 Return, after holding
COM_FAIL_ACT_T; "Critical battery" logged below BAT_CRIT_THR 7 %), the ground station's own
safety verdicts, and the flown record (where a lost vehicle's track ends).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from gcs.cli import main
from mavlink.mock.sim.errors import MockConfigError
from mavlink.mock.sim.px4 import Px4Mode
from mavlink.mock.vehicle_faults import CRITICAL_PCT, PlanFaults, VehicleFault

PLAN = Path(__file__).resolve().parents[1] / "mavlink" / "data" / "reach_avoid_2.plan.json"


def _fly(
    capsys: pytest.CaptureFixture[str], *faults: str, extra: tuple[str, ...] = ()
) -> tuple[int, dict[str, Any]]:
    args = ["fly", str(PLAN), "--dry-run", "--json", *extra]
    for f in faults:
        args += ["--mock-fault", f]
    rc = main(args)
    return rc, json.loads(capsys.readouterr().out.strip().splitlines()[-1])


@pytest.mark.parametrize(
    ("value", "says"),
    [
        ("d9:lost@3", "no vehicle 'd9' in the plan (d1, d2)"),
        ("d1:crash@3", "unknown kind 'crash' (choose lost, failsafe, battery)"),
        ("d1:lost", "expected VEHICLE:KIND@T, e.g. d2:lost@10"),
        ("d1:lost@soon", "T must be seconds into the plan, got 'soon'"),
        ("d1:lost@99", "T must be in [0, 6] s (the plan), got 99"),
    ],
)
def test_a_bad_fault_is_one_line_naming_it(
    capsys: pytest.CaptureFixture[str], value: str, says: str
) -> None:
    assert main(["fly", str(PLAN), "--dry-run", "--mock-fault", value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--mock-fault {value!r}: {says}" in err[0]


def test_a_fault_needs_a_dry_run(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fly", str(PLAN), "--mock-fault", "d1:lost@3"]) == 2
    assert "--mock-fault: only for --dry-run" in capsys.readouterr().err


class _Vehicle:
    """What the faults touch of a mock vehicle, recorded."""

    def __init__(self, params: dict[str, float]) -> None:
        self.params = params
        self.armed, self.failsafe, self.mode = True, False, Px4Mode.OFFBOARD
        self.battery_override_pct: float | None = None
        self.said: list[str] = []

    def statustext(self, _severity: int, text: str) -> None:
        self.said.append(text)

    def set_mode(self, mode: Px4Mode) -> None:
        self.mode = mode


@pytest.mark.parametrize(
    ("action", "held", "then"),
    [
        (0, None, Px4Mode.OFFBOARD),
        (2, Px4Mode.AUTO_LOITER, Px4Mode.AUTO_LAND),
        (3, Px4Mode.AUTO_LOITER, Px4Mode.AUTO_RTL),
    ],
)
def test_a_critical_battery_acts_as_com_low_bat_act_says_after_com_fail_act_t(
    action: int, held: Px4Mode | None, then: Px4Mode
) -> None:
    v = _Vehicle({"COM_LOW_BAT_ACT": action, "COM_FAIL_ACT_T": 5.0})
    faults = PlanFaults([VehicleFault("battery", 2.0)])
    faults.tick(v, 100.0)  # type: ignore[arg-type]
    assert v.battery_override_pct is None  # no plan yet: no clock
    faults.start(100.0)
    faults.tick(v, 101.9)  # type: ignore[arg-type]
    assert v.battery_override_pct is None and not faults.fired
    faults.tick(v, 102.0)  # type: ignore[arg-type]
    assert v.battery_override_pct == CRITICAL_PCT and faults.fired[0][1] == pytest.approx(2.0)
    assert v.said[0] == "Critical battery"
    assert v.mode is (held or Px4Mode.OFFBOARD)  # hold first (the pilot's COM_FAIL_ACT_T)
    faults.tick(v, 106.9)  # type: ignore[arg-type]
    assert v.mode is (held or Px4Mode.OFFBOARD)
    faults.tick(v, 107.0)  # type: ignore[arg-type]
    assert v.mode is then


def test_a_fault_kind_and_time_are_checked() -> None:
    with pytest.raises(MockConfigError, match="unknown fault 'crash'"):
        VehicleFault("crash", 1.0)
    with pytest.raises(MockConfigError, match=">= 0"):
        VehicleFault("lost", -1.0)


@pytest.mark.slow  # flights on the mock over UDP
def test_a_vehicle_lost_mid_plan_stops_the_flight_and_its_track_ends_there(
    capsys: pytest.CaptureFixture[str],
) -> None:
    rc, out = _fly(capsys, "d2:lost@3")
    assert rc == 1 and not out["completed"]
    assert "link lost to d2" in out["safety_event"]
    assert out["mock_faults"] == [
        {"vehicle": "d2", "kind": "lost", "at_s": 3.0, "fired_at_s": pytest.approx(3.0, abs=0.05)}
    ]


@pytest.mark.slow
def test_a_failsafe_takes_the_vehicle_home_the_rest_held_and_the_report_says_why(
    capsys: pytest.CaptureFixture[str],
) -> None:
    rc, out = _fly(capsys, "d1:failsafe@2")
    assert rc == 1 and "d1 left the flight mode" in out["safety_event"]
    assert "AUTO_RTL" in out["safety_event"]
    said = out["vehicle_messages"]["d1"]
    assert [m["text"] for m in said] == ["Failsafe activated"]
    assert said[0]["severity"] == "CRITICAL" and said[0]["t_s"] == pytest.approx(2.0, abs=0.1)


@pytest.mark.slow
def test_a_critical_battery_is_only_a_warning_by_default_and_the_flight_says_so(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # PX4 v1.17: COM_LOW_BAT_ACT 0 (warning): the plan is flown to its end.
    rc, out = _fly(capsys, "d2:battery@2")
    assert rc == 0 and out["completed"], out["safety_event"]
    said = out["vehicle_messages"]["d2"]
    assert [m["text"] for m in said] == ["Critical battery"]
    assert said[0]["t_s"] == pytest.approx(2.0, abs=0.1)
    assert "d1" not in out["vehicle_messages"]
