"""``gcs export --format csv|json``: setpoints against the closed-form trajectories; bad input."""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from gcs import cli
from gcs.export import CSV_COLUMNS
from tests.gcs.test_export_support import D1, D2, quintic_position, reach_avoid_plan, write_plan


def _read_csv(path: Path) -> tuple[list[str], dict[str, np.ndarray]]:
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    by_vehicle: dict[str, list[list[float]]] = {}
    for row in rows[1:]:
        by_vehicle.setdefault(row[1], []).append([float(row[0]), *map(float, row[2:])])
    return rows[0], {k: np.asarray(v) for k, v in by_vehicle.items()}


@pytest.mark.parametrize("rate", [None, "7.5"])
def test_csv_setpoints_are_the_trajectories_sampled_at_the_rate(
    tmp_path: Path, rate: str | None
) -> None:
    plan_path = write_plan(tmp_path / "ra.json", reach_avoid_plan(velocity_yaw=True))
    args = ["export", str(plan_path), "--format", "csv"]
    if rate is not None:
        args += ["--rate", rate]
    assert cli.main(args) == 0
    header, data = _read_csv(tmp_path / "ra.setpoints.csv")
    assert header == list(CSV_COLUMNS)
    hz = 20.0 if rate is None else float(rate)
    plan = reach_avoid_plan(velocity_yaw=True)
    for (name, (wps, durs)), v in zip((("d1", D1), ("d2", D2)), plan.vehicles, strict=True):
        d = data[name]
        n = math.ceil(6.0 * hz - 1e-9) + 1
        t = np.arange(n) / hz
        assert d.shape == (n, 11)
        np.testing.assert_array_equal(d[:, 0], t)
        # Positions against the closed form; derivatives and yaw against Trajectory evaluation
        # (bit-exact: the CSV keeps every digit).
        np.testing.assert_allclose(d[:, 1:4], quintic_position(wps, durs, t), atol=1e-12)
        np.testing.assert_array_equal(d[:, 4:7], v.trajectory.velocity(t))
        np.testing.assert_array_equal(d[:, 7:10], v.trajectory.acceleration(t))
        np.testing.assert_array_equal(d[:, 10], v.trajectory.yaw_rad(t))
        # Velocity really is the derivative of the written positions: central differences
        # err by at most h^2/6 max|jerk| (Taylor, h = 1/rate).
        mid = (d[2:, 1:4] - d[:-2, 1:4]) * hz / 2.0
        jerk_max = np.abs(v.trajectory.jerk(np.linspace(0.0, 6.0, 6001))).max()
        np.testing.assert_allclose(mid, d[1:-1, 4:7], rtol=0, atol=jerk_max / (6 * hz**2) + 1e-12)


def test_json_setpoints_hold_the_same_samples(tmp_path: Path) -> None:
    plan_path = write_plan(tmp_path / "ra.json")
    out = tmp_path / "sp.json"
    assert cli.main(["export", str(plan_path), "--format", "json", "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["format"] == "stl-gcs-setpoints" and doc["version"] == 1
    assert doc["frame"] == "mission ENU" and doc["rate_hz"] == 20.0
    assert doc["origin"] == {"lat": 47.397742, "lon": 8.545594, "alt": 488.0}
    plan = reach_avoid_plan()
    for v, j in zip(plan.vehicles, doc["vehicles"], strict=True):
        assert (j["name"], j["sysid"]) == (v.name, v.sysid)
        t = np.asarray(j["t"])
        np.testing.assert_array_equal(t, np.arange(121) / 20.0)
        np.testing.assert_array_equal(np.asarray(j["pos"]), v.trajectory.position(t))
        np.testing.assert_array_equal(np.asarray(j["vel"]), v.trajectory.velocity(t))
        np.testing.assert_array_equal(np.asarray(j["acc"]), v.trajectory.acceleration(t))
        np.testing.assert_array_equal(np.asarray(j["yaw"]), v.trajectory.yaw_rad(t))


@pytest.mark.parametrize(
    ("plan", "args", "message"),
    [
        ("missing", ["--format", "csv"], r"missing\.json: cannot read"),
        ("{oops", ["--format", "qgc"], r"bad\.json: line 1, column 2: not JSON"),
        (
            '{"format": "stl-gcs-plan", "version": 1}',
            ["--format", "csv"],
            r"bad\.json: origin: missing",
        ),
        (
            "ok",
            ["--format", "kmz"],
            r"--format: unknown format 'kmz' \(choose qgc, csv, json, homes, kml\)",
        ),
        ("ok", [], r"--format: required"),
        ("ok", ["--format", "csv", "--rate", "0"], r"--rate: must be in \(0, 1000\] Hz"),
        ("ok", ["--format", "csv", "--rate", "nan"], r"--rate: must be in"),
        ("ok", ["--format", "qgc", "--end", "crash"], r"--end: unknown 'crash'"),
        (
            "ok",
            ["--format", "qgc", "--acceptance-radius", "0"],
            r"--acceptance-radius: must be > 0",
        ),
        ("ok", ["--format", "csv", "--end", "land"], r"apply to --format qgc only"),
        (
            "ok",
            ["--format", "qgc", "-o", "afile"],
            r"afile: -o for --format qgc must be a directory",
        ),
        ("ok", ["--format", "csv", "-o", "adir"], r"adir: -o for --format csv must be a file"),
    ],
)
def test_bad_input_exits_2_with_one_line(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    plan: str,
    args: list[str],
    message: str,
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    if plan == "missing":
        path = "missing.json"
    elif plan == "ok":
        path = str(write_plan(tmp_path / "ok.json"))
    else:
        path = "bad.json"
        (tmp_path / path).write_text(plan)
    assert cli.main(["export", path, *args]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith("gcs export: error: ")
    assert re.search(message, err), err
    # Nothing half-written.
    assert not list(tmp_path.glob("*.plan")) and not list(tmp_path.glob("*.setpoints.*"))
