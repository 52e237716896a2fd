"""``gcs verify PLAN --telemetry LOG``: the flown data judged against the plan's spec."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gcs.cli import main
from gcs.flight.evaluation import plan_formula
from planner.planfile import load_plan

PLAN = Path(__file__).resolve().parents[1] / "mavlink" / "data" / "reach_avoid_2.plan.json"


def _write_csv(path: Path, rows: list[tuple[float, str, np.ndarray]]) -> Path:
    lines = ["t,vehicle,x,y,z"]
    lines += [
        f"{t!r},{name},{float(p[0])!r},{float(p[1])!r},{float(p[2])!r}" for t, name, p in rows
    ]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _flown_as_planned(plan, rate_hz: float = 20.0, t_end_s: float | None = None):  # type: ignore[no-untyped-def]
    t_end = plan.horizon_s if t_end_s is None else t_end_s
    t = np.arange(round(t_end * rate_hz) + 1) / rate_hz
    return {v.name: (t, v.trajectory.position(t)) for v in plan.vehicles}


def _rows(tracks) -> list[tuple[float, str, np.ndarray]]:  # type: ignore[no-untyped-def]
    return [
        (float(ti), n, p) for n, (t, pos) in tracks.items() for ti, p in zip(t, pos, strict=True)
    ]


def test_telemetry_that_follows_the_plan_has_the_plans_clause_robustness(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = load_plan(PLAN)
    # Sampled on the check grid, so interpolation is exact and the values must agree.
    log = _write_csv(tmp_path / "flown.csv", _rows(_flown_as_planned(plan, 1 / plan.check_dt_s)))
    assert main(["verify", str(PLAN), "--telemetry", str(log), "--json"]) == 0
    checks = {c["name"]: c for c in json.loads(capsys.readouterr().out)["checks"]}
    t = np.arange(round(plan.horizon_s / plan.check_dt_s) + 1) * plan.check_dt_s
    planned = {v.name: v.trajectory.position(t) for v in plan.vehicles}
    clauses = plan_formula(plan).clauses
    for clause in clauses:
        got = checks[f"flown spec: {clause}"]
        assert got["ok"] and got["bound"] == 0.0
        assert got["value"] == pytest.approx(clause.robustness(planned, plan.check_dt_s), abs=1e-9)
    assert sum(n.startswith("flown spec: ") for n in checks) == len(clauses)


def test_a_flown_violation_fails_and_names_the_clause(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = load_plan(PLAN)
    tracks = _flown_as_planned(plan)
    t, pos = tracks["d1"]
    pos = pos.copy()
    pos[(t >= 2.0) & (t <= 3.0)] = [0.0, 0.0, 1.0]  # d1 flew through the obstacle's centre
    tracks["d1"] = (t, pos)
    log = _write_csv(tmp_path / "flown.csv", _rows(tracks))
    assert main(["verify", str(PLAN), "--telemetry", str(log)]) == 1
    out = capsys.readouterr().out
    fails = [line for line in out.splitlines() if line.startswith("FAIL")]
    assert fails and all(
        "flown spec:" in line and "outside(d1, obstacle)" in line for line in fails
    )
    # The obstacle is [-0.6, 0.6]^2 in x, y: 0.6 m deep from its centre.
    assert (
        "FAIL flown spec: always[0,6] (outside(d1, obstacle)" in out and ": -0.6 (bound 0)" in out
    )


def test_telemetry_that_stops_early_or_misses_a_vehicle_fails_coverage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = load_plan(PLAN)
    short = _flown_as_planned(plan, t_end_s=plan.horizon_s - 2.0)
    log = _write_csv(tmp_path / "short.csv", _rows(short))
    assert main(["verify", str(PLAN), "--telemetry", str(log)]) == 1
    out = capsys.readouterr().out
    assert "FAIL flown d1 largest gap s: 2 (bound 1)" in out
    assert "flown spec:" not in out  # never judged on extrapolated positions
    only_d2 = {"d2": _flown_as_planned(plan)["d2"]}
    log = _write_csv(tmp_path / "d2.csv", _rows(only_d2))
    assert main(["verify", str(PLAN), "--telemetry", str(log)]) == 1
    assert "FAIL flown d1 telemetry" in capsys.readouterr().out


def test_an_unreadable_telemetry_file_is_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "nope.csv"
    assert main(["verify", str(PLAN), "--telemetry", str(missing)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(missing) in err and "Traceback" not in err


@pytest.fixture(scope="module")
def face_plan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A plan whose spec asks d1 to face pole1 while it inspects it (``gcs plan``)."""
    from tests.gcs.face_plan import write_face_plan

    return write_face_plan(tmp_path_factory.mktemp("face"))


def _write_csv_with_yaw(path: Path, t: np.ndarray, pos: np.ndarray, yaw: np.ndarray) -> Path:
    lines = ["t,vehicle,x,y,z,yaw"]
    lines += [
        f"{ti!r},d1,{p[0]!r},{p[1]!r},{p[2]!r},{y!r}"
        for ti, p, y in zip(t.tolist(), pos.tolist(), yaw.tolist(), strict=True)
    ]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_a_flown_heading_is_judged_by_the_face_clause(
    face_plan: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from planner.planfile import planned_signals
    from tests.gcs.face_plan import FACE_CLAUSE

    plan = load_plan(face_plan)
    (v,) = plan.vehicles
    dt = plan.check_dt_s
    t = np.arange(round(plan.horizon_s / dt) + 1) * dt  # the check grid: exact interpolation
    pos, yaw = v.trajectory.position(t), v.trajectory.yaw_rad(t)
    capsys.readouterr()
    log = _write_csv_with_yaw(tmp_path / "flown.csv", t, pos, yaw)
    assert main(["verify", str(face_plan), "--telemetry", str(log), "--json"]) == 0
    checks = {c["name"]: c for c in json.loads(capsys.readouterr().out)["checks"]}
    face = checks[f"flown spec: {FACE_CLAUSE}"]
    (clause,) = [c for c in plan_formula(plan).clauses if str(c) == FACE_CLAUSE]
    want = clause.robustness(planned_signals(plan, t), dt)
    assert face["ok"] and face["value"] == pytest.approx(want, abs=1e-9)
    assert checks["flown d1 heading largest gap s"]["ok"]
    # the same flight looking 90 degrees away from the pole fails that clause, and only it
    turned = _write_csv_with_yaw(tmp_path / "turned.csv", t, pos, yaw + np.pi / 2)
    assert main(["verify", str(face_plan), "--telemetry", str(turned)]) == 1
    fails = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("FAIL ")]
    assert len(fails) == 1 and fails[0].startswith(f"FAIL flown spec: {FACE_CLAUSE}: -")


def test_telemetry_without_a_heading_fails_on_a_face_spec_saying_so(
    face_plan: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = load_plan(face_plan)
    capsys.readouterr()
    log = _write_csv(tmp_path / "positions.csv", _rows(_flown_as_planned(plan)))
    assert main(["verify", str(face_plan), "--telemetry", str(log)]) == 1
    out, err = capsys.readouterr()
    fails = [ln for ln in out.splitlines() if ln.startswith("FAIL ")]
    assert fails == [
        "FAIL flown d1 heading: 0 (bound 1) the telemetry has no heading (no yaw_enu_rad or "
        "yaw column, no ATTITUDE); the spec's face() reads it"
    ]
    assert "Traceback" not in out + err
    # the clauses that read positions only are still judged; the face clause is not
    assert main(["verify", str(face_plan), "--telemetry", str(log), "--json"]) == 1
    names = [c["name"] for c in json.loads(capsys.readouterr().out)["checks"]]
    flown = [n for n in names if n.startswith("flown spec: ")]
    assert flown and not any("face(" in n for n in flown)
    assert len(flown) == len(plan_formula(plan).clauses) - 1
