"""``gcs demo``: the whole pipeline (plan, mock vehicles, offboard flight, evaluation, picture,
report) in one command.

The default power-line demo plans 4 drones over a 30 s horizon (tens of seconds of IPOPT and
30 s of flight): ``make demo`` and ``benchmarks/bench_demo.py`` run it. The suite runs the same
pipeline on the 6 s reach-avoid scenario (``--scenario``), and checks that the default
scenario is found.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from gcs.cli import main
from gcs.commands.demo import SCENARIO, find_config
from gcs.flight.evaluation import plan_formula
from gcs.telemetry import load_telemetry
from planner.planfile import load_plan

pytestmark = pytest.mark.slow  # flights or transfers over UDP (make test-fast skips)

REPO = Path(__file__).resolve().parents[2]


# The ideal vehicle: the pipeline is under test here.  On the px4 vehicle the same
# reach-avoid dry run fails as on PX4 SITL (tests/gcs/test_fly.py and
# tests/gcs/test_px4_calibration.py fly it), and the default demo (power line) flies well.
@pytest.mark.parametrize("profile", ["ideal"])
def test_demo_pipeline_flies_the_plan_and_reports_the_flown_robustness(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], profile: str
) -> None:
    out = tmp_path / "demo"
    scenario = REPO / "configs" / "reach_avoid.yaml"
    argv = ["demo", "--out", str(out), "--vehicles", "2", "--scenario", str(scenario)]
    rc = main([*argv, "--profile", profile])
    text = capsys.readouterr().out
    assert rc == 0, text
    names = {"plan.json", "flight.tlog", "flight.csv", "demo.png", "report.md"}
    assert names <= {p.name for p in out.iterdir()}
    assert (out / "demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    # The printed flown robustness is the spec's exact value on the recorded tracks.
    flown = float(re.search(r"flown robustness ([+-]\d+\.\d+); flight completed", text)[1])  # type: ignore[index]
    plan = load_plan(out / "plan.json")
    tracks = load_telemetry(out / "flight.csv").vehicles
    dt = plan.check_dt_s
    signals = {n: tr.resample(dt, plan.horizon_s) for n, tr in tracks.items()}
    assert plan_formula(plan).robustness(signals, dt) == pytest.approx(flown, abs=6e-5)
    assert flown > 0
    assert f"planned robustness {plan.robustness:+.4f}" in text
    assert re.search(r"planning \d+\.\d s, flight \d+\.\d s, total \d+\.\d s", text)

    report = (out / "report.md").read_text(encoding="utf-8")
    assert f"| flown robustness (on the vehicles' estimates) | {flown:+.4f} |" in report
    assert "![plan and flown tracks](demo.png)" in report
    for stage in ("set-up", "planning", "vehicles", "flight", "report"):
        assert f"| {stage} |" in report


def test_the_demo_scenario_is_found_next_to_the_packages() -> None:
    assert find_config(SCENARIO) == REPO / "configs" / SCENARIO


UNSATISFIABLE = """\
name: goal_in_obstacle
origin: {lat: 47.3977, lon: 8.5456, alt: 488.0}
workspace: {min: [-2, -2, 0], max: [2, 2, 2]}
regions:
  obstacle: {kind: obstacle, min: [-1, -1, 0], max: [1, 1, 1.5]}
  goal: {kind: goal, center: [0, 0, 0.75], half_size: 0.25}
limits: {v_max_m_s: 0.751, a_max_m_s2: 1.0}
vehicles: {count: 1, name: "d{i}", starts: {grid: {min: [-1.5, -1.5, 0.75], max: [-1.5, -1.5, 0.75], shape: [1, 1, 1]}}}
timing: {horizon_s: 4, segment_s: 1, Ts_s: 0.1}
separation_m: 0.2
epsilon: 0.01
spec:
  - each: d in all
    formula: eventually[0, $horizon] inside(d, goal) and always[0, $horizon] outside(d, obstacle)
"""


def test_demo_does_not_fly_a_plan_that_fails_its_checks(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scenario = tmp_path / "goal_in_obstacle.yaml"
    scenario.write_text(UNSATISFIABLE, encoding="utf-8")
    out = tmp_path / "demo"
    rc = main(["demo", "--out", str(out), "--vehicles", "1", "--scenario", str(scenario)])
    text = capsys.readouterr().out
    assert rc == 1, text
    assert "REFUSED" in text and "not flown" in text
    # The plan and its picture are written for inspection; nothing was flown or recorded.
    names = {p.name for p in out.iterdir()}
    assert {"plan.json", "demo.png"} <= names
    assert not names & {"flight.tlog", "flight.csv", "report.md"}
    assert load_plan(out / "plan.json").robustness < 0
