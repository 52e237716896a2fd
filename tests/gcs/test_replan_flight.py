"""``gcs fly --replan`` (issue 43): a vehicle lost in flight, the rest of the power line planned
for the others and flown on, judged on the spec as amended; or, where no new plan can be
flown, the safe stop saying why.

References: the exact STL semantics (the flown robustness of the amended spec), the mock's
PX4 behaviour on a silent link (the offboard-loss failsafe), and the stream itself: the
vehicles that fly on keep their setpoints up to the switch.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gcs.cli import main
from gcs.telemetry import load_telemetry
from planner.optimize import plan
from planner.planfile import load_plan, save_plan
from planner.scenario import load_scenario

pytestmark = pytest.mark.slow  # flights against the mock

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "powerline_inspection.yaml"


@pytest.fixture(scope="module")
def power_line(tmp_path_factory: pytest.TempPathFactory) -> Path:
    result = plan(load_scenario(SCENARIO))
    assert result.success, result.status
    path = tmp_path_factory.mktemp("replan") / "power_line.plan.json"
    save_plan(path, result, str(SCENARIO))
    return path


def _fly(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict[str, Any]]:
    rc = main(["fly", *args, "--dry-run", "--json"])
    out = capsys.readouterr().out.strip().splitlines()
    return rc, json.loads(out[-1])


def test_a_drone_lost_mid_line_is_replanned_around_and_the_others_meet_what_is_left(
    power_line: Path, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    # an area closed in flight (north of the line, where nobody flies), read at the start; on
    # a busy machine its replan may still run when d2 is lost (one replan at a time: d2's then
    # waits for it and starts from its plan), so the flight is in real time
    live = tmp_path / "closed.yaml"
    live.write_text("regions:\n  closed: {min: [60, 5, 0], max: [63, 8, 20]}\n", "utf-8")
    rc, out = _fly(
        capsys, str(power_line), "--speed", "1", "--mock-fault", "d2:lost@10",
        "--replan", "--replan-budget", "12", "--log", str(tmp_path), "--live-regions", str(live),
    )  # fmt: skip
    assert out["safety_event"] is None, out["safety_event"]
    closed, r = out["replans"]
    assert closed["success"] and closed["vehicles"] == []
    assert closed["event"].startswith("closed at t = ") and closed["event"].endswith(": closed")
    assert closed["switch_s"] <= 14.0  # the first poll after the start, 12 s on
    assert r["success"] and r["vehicles"] == ["d2"]
    # lost at 10 s, replanned when seen (COM_OF_LOSS_T later) or once the closed area's replan
    # had ended; the switch on the 2 s waypoint grid 12 s after that
    seen = float(r["event"].split("link lost at t = ")[1].split(" s")[0])
    assert 9.9 <= seen <= 12.0 and r["t_s"] >= seen - 0.05
    assert r["switch_s"] == pytest.approx(2.0 * math.ceil((r["t_s"] + 12.0) / 2.0 - 1e-9))
    assert "eventually[0, 29] always[0, 1] inside(d2, insp4)" in r["dropped"]
    assert "always[0, 30] dist(d1, d2) >= 1.5" in r["discharged"]
    assert r["robustness"] >= 0.01
    judged = out["judged_spec"]
    assert "outside(d1, left_d2)" in judged and "inside(d2" not in judged
    for name in ("d1", "d3", "d4"):  # the closed area kept out of, on the original clock
        assert f"outside({name}, closed)" in judged
    assert out["completed"] and out["flown_robustness"] >= 0.0 and rc == 0
    # the drones that flew on were streamed one plan, the old one up to each switch: judged
    # against the plan as last amended, they tracked it as flights without a loss do (no jump)
    tracking = {t["vehicle"]: t for t in out["tracking"]}
    assert set(tracking) == {"d1", "d3", "d4"}
    assert all(t["max_m"] < 1.5 and t["rms_m"] < 0.8 for t in tracking.values()), tracking
    tracks = load_telemetry(tmp_path / "flight.csv").vehicles
    old = {v.name: v.trajectory for v in load_plan(power_line).vehicles}
    for name in ("d1", "d3", "d4"):  # before the first switch, on the old plan itself
        tr = tracks[name]
        before = (tr.t_s > 1.0) & (tr.t_s < closed["switch_s"])
        off = np.linalg.norm(tr.pos_enu_m[before] - old[name].position(tr.t_s[before]), axis=1)
        assert off.max() < 1.5
    assert tracks["d2"].t_s.max() < 10.5  # nothing heard of d2 after its loss
    report = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "## Replans" in report and "| yes |" in report
    assert (
        "- dropped with the vehicle: `eventually[0, 29] always[0, 1] inside(d2, insp4)`" in report
    )


def test_no_time_left_to_switch_is_the_safe_stop_saying_why(
    power_line: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # lost at 5 s, with a budget that puts the switch past the 30 s plan
    rc, out = _fly(
        capsys, str(power_line), "--mock-fault", "d3:lost@5", "--replan", "--replan-budget", "40"
    )
    assert rc == 1 and not out["completed"]
    [r] = out["replans"]
    assert not r["success"] and "no time is left" in r["reason"]
    assert "d3 left the flight and no new plan was flown" in out["safety_event"]
    assert out["judged_spec"] is None


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (("--replan", "--mode", "mission"), "--replan: only offboard flights"),
        (("--replan", "--replan-budget", "0"), "--replan-budget: must be a number > 0 s"),
        (("--replan-budget", "5"), "--replan-budget: only with --replan"),
        (("--scenario", "x.yaml"), "--scenario: only with --replan"),
        (("--reassign",), "--reassign: only with --replan"),
        (("--live-regions", "x.yaml"), "--live-regions: only with --replan"),
        (
            ("--replan", "--live-regions", "nowhere.yaml"),
            "--live-regions: nowhere.yaml: cannot read",
        ),
        (("--replan", "--scenario", "nowhere.yaml"), "cannot read the plan's scenario"),
        (
            ("--replan", "--scenario", str(ROOT / "configs" / "reach_avoid.yaml")),
            "horizon 6 s, the plan's 30 s",
        ),
    ],
)
def test_a_replan_that_cannot_be_asked_for_is_one_line(
    power_line: Path, capsys: pytest.CaptureFixture[str], extra: tuple[str, ...], says: str
) -> None:
    assert main(["fly", str(power_line), "--dry-run", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err


def test_assess_replans_the_runs_stopped_on_a_lost_link_and_flies_them_again(
    power_line: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(
        ["assess", str(power_line), "--runs", "6", "--workers", "0", "--monitor", "--replan",
         "--reassign", "-d", "lost=0.6", "--seed", "3", "--json"]
    )  # fmt: skip
    assert rc in (0, 1)
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    rp, mon = out["replan"], out["monitor"]
    stops = {r["why"]: r["runs"] for r in mon["reasons"]}
    assert rp["lost_links"] == stops.get("a vehicle lost (its link silent)", 0) > 0
    assert rp["replanned"] <= rp["lost_links"] and rp["flown"] <= rp["replanned"]
    assert rp["flown"] > 0 and rp["solve_s_median"] > 0
    assert 0 <= rp["stopped_flown"] <= rp["flown"] - rp["completed_flown"]
    not_flown = sum(r["runs"] for r in rp["not_flown"])
    assert not_flown == rp["replanned"] - rp["flown"]
    # a run that completes without replanning was never stopped on a lost link: it
    # completes with it too, and replanning can only add runs that complete
    assert rp["completed_with"] == rp["completed_without"] + rp["completed_flown"]


def test_assess_replan_needs_the_monitor(
    power_line: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["assess", str(power_line), "--runs", "2", "--workers", "0"]
    assert main([*args, "--replan"]) == 2
    assert "--replan: with --monitor only" in capsys.readouterr().err
    assert main([*args, "--monitor", "--replan-budget", "4"]) == 2
    assert "--replan-budget: only with --replan" in capsys.readouterr().err


def test_a_closed_area_named_like_a_region_of_the_plan_is_refused_before_the_flight(
    power_line: Path, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    live = tmp_path / "closed.yaml"
    live.write_text("regions:\n  pole1: {min: [60, 5, 0], max: [63, 8, 20]}\n", "utf-8")
    assert main(["fly", str(power_line), "--dry-run", "--replan", "--live-regions", str(live)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "regions.pole1: is the name of a region of the plan" in err[0], err


def test_a_scenario_that_lists_its_vehicles_is_replanned_with_as_it_is(tmp_path: Path) -> None:
    from gcs.flight.replan import replan_problem

    scenario = tmp_path / "hop.yaml"
    scenario.write_text(
        """\
name: hop
origin: {lat: 47.397742, lon: 8.545594, alt: 488.0}
workspace: {min: [-3, -3, 0], max: [8, 3, 6]}
regions:
  goal: {kind: goal, center: [4.0, 0.0, 3.0], half_size: 0.8}
limits: {v_max_m_s: 1.5, a_max_m_s2: 1.5}
vehicles:
  - {name: d1, start: [0.0, 0.0, 3.0]}
timing: {horizon_s: 10, segment_s: 2, Ts_s: 0.1, check_dt_s: 0.02}
separation_m: 1.0
epsilon: 0.05
model: minimum_jerk
spec:
  - formula: eventually[3, 9] always[0, 1] inside(d1, goal)
""",
        "utf-8",
    )
    result = plan(load_scenario(scenario))
    path = tmp_path / "hop.json"
    save_plan(path, result, str(scenario))
    problem = replan_problem(load_plan(path))
    assert [v.name for v in problem.vehicles] == ["d1"] and problem.timing.segment_s == 2
