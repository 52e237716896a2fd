"""``gcs verify``: re-checks a plan from its segments; exit 0 / 1 (failing check named) / 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gcs import cli
from planner.optimize import plan
from planner.planfile import save_plan
from planner.scenario import load_scenario

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.fixture(scope="module")
def good_plan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    result = plan(load_scenario(CONFIGS / "reach_avoid.yaml", vehicles=2))
    assert result.success, result.status
    path = tmp_path_factory.mktemp("verify") / "plan.json"
    save_plan(path, result)
    return path


def _edited(src: Path, dst: Path, edit: object) -> Path:
    data = json.loads(src.read_text())
    edit(data)  # type: ignore[operator]
    dst.write_text(json.dumps(data))
    return dst


@pytest.mark.slow
def test_verify_accepts_the_planner_output(
    good_plan: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["verify", str(good_plan)]) == 0
    assert "OK:" in capsys.readouterr().out


def test_verify_json_lists_every_check(good_plan: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["verify", str(good_plan), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    names = [c["name"] for c in report["checks"]]
    assert report["ok"] is True
    assert "separation d1-d2 m" in names
    assert any(n.startswith("spec: eventually[0,6] inside(d1, goal)") for n in names)
    assert "d2 velocity / v_max" in names


def test_verify_names_the_failing_clause_when_the_goal_moves(
    good_plan: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def move_goal(d: dict) -> None:
        d["regions"]["goal"] = {"kind": "goal", "min": [1.5, -2, 0.5], "max": [2, -1.5, 1]}

    bad = _edited(good_plan, tmp_path / "moved.json", move_goal)
    assert cli.main(["verify", str(bad)]) == 1
    out = capsys.readouterr().out
    assert "FAIL spec: eventually[0,6] inside(d1, goal)" in out
    assert "FAILED:" in out


def test_verify_catches_limits_and_separation_from_the_segments(
    good_plan: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def tighten(d: dict) -> None:
        d["vehicles"][0]["limits"]["v_max_m_s"] = [0.3, 0.3, 0.3]
        d["separation_m"] = 5.0
        # The samples are ignored: only the segments count.
        d["vehicles"][0]["pos"] = (np.asarray(d["vehicles"][0]["pos"]) * 0).tolist()

    bad = _edited(good_plan, tmp_path / "tight.json", tighten)
    assert cli.main(["verify", str(bad)]) == 1
    out = capsys.readouterr().out
    assert "FAIL d1 velocity / v_max" in out
    assert "FAIL separation d1-d2 m" in out


def test_bad_plan_file_exits_2_with_one_line(good_plan: Path, tmp_path: Path) -> None:
    bad = _edited(good_plan, tmp_path / "broken.json", lambda d: d["vehicles"][1].pop("segments"))
    proc = subprocess.run(
        [sys.executable, "-m", "gcs.cli", "verify", str(bad)], capture_output=True, text=True
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0
    assert "vehicles[1].segments: missing" in proc.stderr


def _set(key: str, value: object):  # type: ignore[no-untyped-def]
    return lambda d: d.update({key: value})


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            _set("spec", "eventually[0,6] inside(d1, gaol)"),
            "spec: unknown region 'gaol' in 'inside(d1, gaol)' "
            "(regions: workspace, obstacle, goal)",
        ),
        (
            _set("spec", "always[0,6] dist(d1, d9) >= 0.2"),
            "spec: unknown vehicle 'd9' in 'dist(d1, d9)' (vehicles: d1, d2)",
        ),
        (
            _set("spec", "always[0,6] alt >= 0.2"),
            "spec: unknown name 'alt' in 'alt >= 0.2' (vehicles: d1, d2)",
        ),
        (
            _set("horizon_s", 3.0),
            "horizon_s: 3 s is shorter than spec clause 1 (eventually[0,6] inside(d1, goal)), "
            "which looks 6 s ahead",
        ),
        # The spec's own line and column; the file is the plan, not the scenario it came from.
        (
            _set("spec", "always[0,6] dist(d1, d2 >= 0.2"),
            "spec: line 1, column 25: expected ')', found '>='",
        ),
        (_set("check_dt_s", 0), "check_dt_s: must be > 0, got 0"),
        (_set("check_dt_s", float("nan")), "check_dt_s: must be finite, got nan"),
        # Only the check step can tell: an interval without a sample step at dt = 0.01 s.
        (
            _set("spec", "eventually[0.111,0.115] inside(d1, goal)"),
            "spec: interval [0.111,0.115] holds no sample at dt=0.01 s (steps 12..11)",
        ),
    ],
    ids=[
        "unknown-region",
        "unknown-vehicle",
        "unknown-name",
        "short-horizon",
        "syntax",
        "zero-check-dt",
        "nan-check-dt",
        "interval-between-samples",
    ],
)
def test_spec_that_does_not_fit_the_plan_names_the_plan_file(
    good_plan: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    edit: object,
    message: str,
) -> None:
    bad = _edited(good_plan, tmp_path / "p.json", edit)
    assert cli.main(["verify", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [f"gcs verify: error: {bad}: {message}"], err


@pytest.mark.slow
def test_unknown_region_in_a_real_process_is_one_line_without_traceback(
    good_plan: Path, tmp_path: Path
) -> None:
    bad = _edited(good_plan, tmp_path / "p.json", _set("spec", "eventually[0,6] inside(d1, gaol)"))
    proc = subprocess.run(
        [sys.executable, "-m", "gcs.cli", "verify", str(bad)], capture_output=True, text=True
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines() == [
        f"gcs verify: error: {bad}: spec: unknown region 'gaol' in 'inside(d1, gaol)' "
        "(regions: workspace, obstacle, goal)"
    ]
    assert proc.stdout == ""


@pytest.mark.parametrize(
    ("dt", "message"),
    [
        ("0", "--dt: must be a positive number of seconds, got 0"),
        ("inf", "--dt: must be a positive number of seconds, got inf"),
        ("1e-9", "--dt: 1e-09 s gives more than 1e+07 check samples over the plan's 6 s horizon"),
    ],
)
def test_bad_dt_option_names_the_option(
    good_plan: Path, capsys: pytest.CaptureFixture[str], dt: str, message: str
) -> None:
    assert cli.main(["verify", str(good_plan), "--dt", dt]) == 2
    assert capsys.readouterr().err.splitlines() == [f"gcs verify: error: {message}"]


def test_failing_clauses_are_listed_worst_first_and_an_or_by_its_best_option(
    good_plan: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # three clauses appended in file order: a small miss, a large one, and a disjunction
    # whose options both miss (the stored paths stay in x in [-2, 2])
    def edit(d: dict) -> None:  # type: ignore[type-arg]
        d["spec"] += (
            " and (always[0, 6] x(d1) <= 1.5)"
            " and (always[0, 6] x(d1) <= -8)"
            " and (eventually[0, 6] (x(d1) >= 10 or x(d1) >= 30))"
        )

    bad = _edited(good_plan, tmp_path / "bad.json", edit)
    assert cli.main(["verify", str(bad), "--json"]) == 1
    checks = json.loads(capsys.readouterr().out)["checks"]
    spec = [c for c in checks if c["name"].startswith("spec: ")]
    values = [c["value"] for c in spec]
    assert values == sorted(values)  # worst first
    failing = [c for c in spec if not c["ok"]]
    assert [c["name"] for c in failing][:2] == [
        "spec: always[0,6] (x(d1) <= -8)",
        "spec: eventually[0,6] (x(d1) >= 10 or x(d1) >= 30)",
    ]
    either = failing[1]["detail"]
    assert either.startswith("either of x(d1) >= 10 or x(d1) >= 30 = ")
    assert "its best option x(d1) >= 10 = " in either
    # fly refuses naming the worst one
    assert cli.main(["fly", str(bad), "--dry-run"]) == 1
    assert "x(d1) <= -8" in capsys.readouterr().err
