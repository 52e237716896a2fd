"""``gcs plan``: writes the plan file, prints the summary or JSON, prints the expanded spec."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from gcs import cli
from tests.planner.test_lexicographic import FLOOR

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def test_plan_writes_a_plan_file_and_a_summary_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "p.json"
    code = cli.main(["plan", str(CONFIGS / "reach_avoid.yaml"), "--vehicles", "1", "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.out + captured.err
    data = json.loads(out.read_text())
    assert data["format"] == "stl-gcs-plan" and len(data["vehicles"]) == 1
    table = captured.out
    assert "max |v| m/s" in table and "d1" in table
    assert "eventually[0, 6] inside(d1, goal)" in table
    assert "OK: " in table and f"plan written to {out}" in table
    assert sorted(tmp_path.iterdir()) == [out]  # the early write check left nothing behind
    assert "solving with ipopt" in captured.err  # progress (non-tty: one line per stage)
    assert "checking on dense samples" in captured.err


def test_plan_json_summary(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "p.json"
    code = cli.main(
        ["plan", str(CONFIGS / "reach_avoid.yaml"), "--vehicles", "1", "-o", str(out), "--json"]
    )
    summary = json.loads(capsys.readouterr().out)
    assert code == 0
    assert summary["success"] is True and summary["robustness"] > 0
    assert summary["output"] == str(out)
    assert {c["key"] for c in summary["clauses"]} == {"spec[0].formula", "spec[1].formula"}
    assert summary["stats"]["n_variables"] > 0


def test_print_spec_prints_the_expanded_formula(capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["plan", str(CONFIGS / "reach_avoid.yaml"), "--vehicles", "3", "--print-spec"])
    text = capsys.readouterr().out
    assert code == 0
    assert "dist(d1, d3) >= 0.2" in text and "dist(d2, d3) >= 0.2" in text
    assert "$" not in text and "each" not in text


def test_bad_scenario_exits_2_with_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        (CONFIGS / "reach_avoid.yaml").read_text().replace("v_max_m_s: 0.751", "v_max_m_s: -1")
    )
    proc = subprocess.run(
        [sys.executable, "-m", "gcs.cli", "plan", str(bad)], capture_output=True, text=True
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1
    assert f"{bad}: limits.v_max_m_s: must be > 0" in lines[0]
    assert "Traceback" not in proc.stderr


def test_vehicle_count_out_of_range_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["plan", str(CONFIGS / "reach_avoid.yaml"), "--vehicles", "40"])
    assert code == 2
    assert "--vehicles 40 is outside 1..16" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("output", "reason"),
    [
        ("missing-dir/p.json", "No such file or directory"),
        (".", "Is a directory"),
        ("a-file/p.json", "Not a directory"),
    ],
)
@pytest.mark.slow
def test_unwritable_output_is_refused_before_solving(
    tmp_path: Path, output: str, reason: str
) -> None:
    (tmp_path / "a-file").write_text("not a directory\n")
    before = sorted(tmp_path.rglob("*"))
    out = tmp_path / output
    argv = ["plan", str(CONFIGS / "reach_avoid.yaml"), "-o", str(out)]
    proc = subprocess.run(
        [sys.executable, "-m", "gcs.cli", *argv],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    # One line, and no progress line: the solve never started.
    assert proc.stderr.splitlines() == [f"gcs plan: error: {out}: cannot write: {reason}"]
    assert "Traceback" not in proc.stderr
    assert sorted(tmp_path.rglob("*")) == before


def test_writable_output_check_leaves_an_existing_file_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from planner.planfile import check_writable

    old = tmp_path / "old.json"
    old.write_text("previous plan\n")
    mtime_ns = old.stat().st_mtime_ns
    check_writable(old)
    check_writable(tmp_path / "new.json")
    assert old.read_text() == "previous plan\n" and old.stat().st_mtime_ns == mtime_ns
    assert sorted(tmp_path.iterdir()) == [old]


@pytest.mark.slow
def test_ctrl_c_during_the_solve_writes_the_best_plan_so_far_and_says_so(tmp_path: Path) -> None:
    import signal
    import time

    from tests.procutil import interruptible

    out = tmp_path / "p.json"
    # 8 drones on the power line: a build of seconds, then an IPOPT solve of seconds more
    argv = [sys.executable, "-m", "gcs.cli", "plan", str(CONFIGS / "powerline_inspection.yaml"),
            "--vehicles", "8", "-o", str(out), "--json"]  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=interruptible)  # fmt: skip
    assert proc.stderr is not None
    for line in proc.stderr:  # progress: one line per stage
        if "solving with ipopt" in line:
            break
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    summary = json.loads(stdout)
    assert summary["status"].startswith("interrupted (Ctrl-C); the best plan so far"), summary
    assert "Traceback" not in stderr
    assert json.loads(out.read_text())["format"] == "stl-gcs-plan"  # written all the same


@pytest.mark.parametrize("value", ["-1", "nan", "inf"])
def test_a_bad_time_limit_is_one_line_exit_2(
    value: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["plan", str(CONFIGS / "reach_avoid.yaml"), "-o", str(tmp_path / "p.json")]
    assert cli.main([*argv, "--time-limit", value]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--time-limit: must be a number of seconds >= 0" in err
    assert not (tmp_path / "p.json").exists()


@pytest.mark.slow
def test_plan_says_when_the_start_sets_the_figure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A drone 1 m up over a 0.5 m floor: 0.5 m at t = 0 whatever the plan; the inspection
    # box (3 m each side) allows up to 1.5 m.
    scenario = tmp_path / "floor.yaml"
    scenario.write_text(yaml.safe_dump(FLOOR))
    out = tmp_path / "p.json"
    assert cli.main(["plan", str(scenario), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "weakest: inside(d1, workspace) = 0.5000 at t = 0 s" in text
    line = next(ln for ln in text.splitlines() if ln.startswith("the start sets this figure"))
    others = float(line.rsplit(" ", 1)[1])
    assert 1.3 <= others <= 1.5
    assert cli.main(["plan", str(scenario), "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["start_bound"]["others_robustness"] == pytest.approx(others, abs=1e-4)
    assert summary["robustness"] == pytest.approx(0.5, abs=1e-9)
