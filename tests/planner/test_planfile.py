"""Plan files: lossless round trip of a real plan, and clear errors for bad files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from planner.optimize import PlanResult, plan
from planner.planfile import FORMAT, PlanFileError, load_plan, save_plan
from planner.scenario import load_scenario

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.fixture(scope="module")
def planned(tmp_path_factory: pytest.TempPathFactory) -> tuple[PlanResult, Path]:
    result = plan(load_scenario(CONFIGS / "reach_avoid.yaml", vehicles=1))
    path = tmp_path_factory.mktemp("plan") / "plan.json"
    save_plan(path, result, scenario_path="configs/reach_avoid.yaml")
    return result, path


@pytest.fixture(scope="module")
def plan_path(planned: tuple[PlanResult, Path]) -> Path:
    return planned[1]


def test_plan_file_has_the_contract_keys(plan_path: Path) -> None:
    data = json.loads(plan_path.read_text())
    assert data["format"] == FORMAT and data["version"] == 1
    assert data["scenario"] == "configs/reach_avoid.yaml"
    assert set(data["origin"]) == {"lat", "lon", "alt"}
    for key in ("spec", "robustness", "smooth_robustness", "status", "solve_time_s"):
        assert key in data
    v = data["vehicles"][0]
    assert v["name"] == "d1" and v["sysid"] == 1
    n = len(v["t"])
    assert np.asarray(v["pos"]).shape == (n, 3) == np.asarray(v["vel"]).shape
    assert np.asarray(v["acc"]).shape == (n, 3) and len(v["yaw"]) == n
    assert v["t"][0] == 0.0 and v["t"][-1] >= data["horizon_s"]


def test_segments_round_trip_exactly(planned: tuple[PlanResult, Path]) -> None:
    result, path = planned
    loaded = load_plan(path)
    original = result.trajectories[0]
    again = loaded.vehicles[0].trajectory
    np.testing.assert_array_equal(again.coeffs, original.coeffs)
    np.testing.assert_array_equal(again.segment_t0_s, original.segment_t0_s)
    data = json.loads(path.read_text())
    t = np.asarray(data["vehicles"][0]["t"])
    np.testing.assert_array_equal(again.position(t), np.asarray(data["vehicles"][0]["pos"]))
    assert loaded.spec == result.problem.spec_text
    assert loaded.robustness == result.robustness
    assert loaded.vehicle("d1").v_max_m_s == (0.751, 0.751, 0.751)
    assert loaded.region("goal").hi_enu_m == (2.0, 2.0, 1.0)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(format="other"), "format: expected 'stl-gcs-plan'"),
        (lambda d: d.update(version=9), "version: unsupported version 9"),
        (lambda d: d.pop("origin"), "origin: missing"),
        (lambda d: d["vehicles"][0].pop("segments"), r"vehicles\[0\]\.segments: missing"),
        (
            lambda d: d["vehicles"][0]["segments"][1].update(t0_s=5.0),
            r"vehicles\[0\]\.segments",
        ),
        (lambda d: d["vehicles"][0].update(sysid=0), r"vehicles\[0\]\.sysid: expected 1\.\.255"),
        (
            lambda d: d["workspace"].update(max=[1, 1]),
            r"workspace\.max: expected a list of 3 numbers \[x, y, z\]",
        ),
    ],
)
def test_bad_plan_files_name_the_key(
    plan_path: Path, tmp_path: Path, edit: object, message: str
) -> None:
    data = json.loads(plan_path.read_text())
    edit(data)  # type: ignore[operator]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(PlanFileError, match=message) as exc:
        load_plan(bad)
    assert str(exc.value).startswith(str(bad))


def test_not_json_and_missing_file(tmp_path: Path) -> None:
    bad = tmp_path / "x.json"
    bad.write_text("{not json")
    with pytest.raises(PlanFileError, match=r"line 1, column 2: not JSON"):
        load_plan(bad)
    with pytest.raises(PlanFileError, match="cannot read"):
        load_plan(tmp_path / "missing.json")
