"""What ``gcs plan`` prints, read as a user reads it (issue 39): the workspace reported as
the workspace with the tolerance ``gcs verify`` uses, long clauses that stay
distinguishable, a failing negation explained in its own sign, and a duplicated key refused
before anything is planned."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from gcs import cli
from gcs.checks import verify_plan, weakest_detail
from gcs.commands.plan import clause_cell, plan_table
from planner.checks import WORKSPACE_TOL_M, LimitReport
from planner.planfile import load_plan
from planner.stl import parse

ROOT = Path(__file__).resolve().parents[2]
PLAN = ROOT / "tests" / "mavlink" / "data" / "reach_avoid_2.plan.json"


def _limit(name: str, margin_m: float, v_ratio: float = 0.5) -> LimitReport:
    return LimitReport(
        name=name,
        max_speed_m_s=1.0,
        max_acc_m_s2=1.0,
        path_length_m=10.0,
        v_ratio=v_ratio,
        a_ratio=0.5,
        workspace_margin_m=margin_m,
        feasibility=None,
    )


def _result(limits: list[LimitReport], clauses: list[str]) -> SimpleNamespace:
    return SimpleNamespace(
        limits=limits,
        clauses=[SimpleNamespace(text=t, robustness=1.0 + i, key_path="") for i, t in
                 enumerate(clauses)],
        weakest=None,
        start_bound=None,
        needs=(),
        stats=None,
        robustness=1.0,
        robustness_planning_grid=1.0,
        smooth_robustness=1.0,
        iterations=3,
        solve_time_s=0.1,
        success=True,
        status="ok",
    )  # fmt: skip


def test_a_workspace_breach_is_reported_as_the_workspace_not_as_limits() -> None:
    # issue 39: 3 micrometres out said "limits VIOL" with speed and acceleration well
    # inside; 0.56 micrometres out said "ok" here and FAIL in gcs verify.
    out = _limit("d1", -3e-6)
    hair = _limit("d2", -0.56e-6)
    fast = _limit("d3", 0.2, v_ratio=1.2)
    table = plan_table(_result([out, hair, fast], ["always dist(d1, d2) >= 1"]))
    rows = {ln.split()[0]: ln.split() for ln in table.splitlines() if ln[:2] in ("d1", "d2", "d3")}
    assert "workspace" in table.splitlines()[0]
    # columns: vehicle, path, |v|, |a|, limits, workspace
    assert rows["d1"][4] == "ok" and rows["d1"][5:] == ["out", "by", "3e-06", "m"]
    assert rows["d2"][4:] == ["ok", "in"]
    assert rows["d3"][4:] == ["VIOL", "in"]
    assert out.limits_ok and not out.in_workspace and not out.ok
    assert hair.ok and -hair.workspace_margin_m < WORKSPACE_TOL_M


def test_verify_judges_the_workspace_with_the_tolerance_plan_uses(tmp_path: Path) -> None:
    # the plan's workspace moved onto its own path's edge, a hair inside and a hair outside
    plan = json.loads(PLAN.read_text())
    loaded = load_plan(PLAN)
    t = np.arange(round(loaded.horizon_s / 0.01) + 1) * 0.01
    top = max(float(v.trajectory.position(t)[:, 2].max()) for v in loaded.vehicles)
    for shift, holds in ((-0.5 * WORKSPACE_TOL_M, True), (-3.0 * WORKSPACE_TOL_M, False)):
        plan["workspace"]["max"][2] = top + shift
        path = tmp_path / f"w{shift}.plan.json"
        path.write_text(json.dumps(plan))
        checks = {c.name: c for c in verify_plan(load_plan(path), dt_s=0.01)}
        ws = [c for name, c in checks.items() if name.endswith("workspace margin m")]
        assert ws and all(c.ok for c in ws) == holds, [(c.name, c.value) for c in ws]
        if not holds:
            assert any("outside by" in c.detail for c in ws)


def test_long_clauses_that_differ_in_their_names_stay_distinguishable() -> None:
    texts = [
        f"eventually[0, 58] (always[0, 2] inside(d1, p{i}) or always[0, 2] inside(d2, p{i}) "
        f"or always[0, 2] inside(d3, p{i}))"
        for i in range(1, 7)
    ]
    cells = [clause_cell(t, {"d1", "d2", "d3"}) for t in texts]
    assert len(set(cells)) == 6  # six rows, six different cells
    assert all(len(c) <= 70 for c in cells)
    assert cells[3].endswith("[d1, d2, d3 | p4]")
    short = "always[0, 60] dist(d1, d2) >= 2"
    assert clause_cell(short, {"d1", "d2"}) == short  # what fits is shown whole


def test_a_failing_negation_in_verify_names_both_vehicles_in_its_own_sign() -> None:
    phi = parse("always[0,1] not (a >= 0 and b >= 0)")
    x = {"a": np.array([0.5, -1.0]), "b": np.array([0.2, -1.0])}
    detail = weakest_detail(phi.weakest(x, 1.0))
    assert detail.startswith("weakest not (a >= 0 and b >= 0) = -0.2 at t = 0 s"), detail


def test_a_duplicated_region_is_refused_naming_the_key_and_both_lines(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = (ROOT / "configs" / "reach_avoid.yaml").read_text()
    first = "  goal: {kind: goal, center: [1.75, 1.75, 0.75], half_size: 0.25}\n"
    assert first in text
    pasted = text.replace(first, first + first.replace("1.75, 1.75", "-1.25, 1.75"))
    line_1 = pasted.splitlines().index(first.rstrip("\n")) + 1
    scenario = tmp_path / "dup.yaml"
    scenario.write_text(pasted)
    out = tmp_path / "p.json"
    assert cli.main(["plan", str(scenario), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0]
    assert f"{scenario}: regions: duplicate key 'goal' (lines {line_1} and {line_1 + 1})" in err[0]
    assert not out.exists()


def test_a_duplicated_key_in_a_plan_file_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = json.loads(PLAN.read_text())
    text = json.dumps(data, indent=1)
    # the second vehicle's name written twice, as a hand edit might leave it
    marker = '"name": "d2"'
    assert marker in text
    path = tmp_path / "dup.plan.json"
    path.write_text(text.replace(marker, marker + ',\n   "name": "d1"', 1))
    assert cli.main(["verify", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "duplicate key 'name' (lines" in err[0]
    assert "vehicles[1]" in err[0]
