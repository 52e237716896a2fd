"""Planning for PX4's missions (issue 42): time margins that cover a shifted mission (checked
by brute force on shifted signals), and the loop that plans every clause to tolerate the
timing error asked for (checked on the written plan file, shifting its trajectories)."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from gcs.cli import main
from planner.planfile import load_plan, plan_formula, planned_signals
from planner.spec.timing import widened
from planner.stl import FunctionRegistry, parse

ROOT = Path(__file__).resolve().parents[2]


def _registry() -> FunctionRegistry:
    reg = FunctionRegistry()
    reg.register("x", 1, lambda args, s: s[args[0]][:, 0], lambda args, s: None, signal_args=(0,))
    return reg


def _shifted(x: np.ndarray, k: int) -> np.ndarray:
    """The signal ``k`` samples late (``k`` < 0: early), holding its first and last values
    (the vehicle waits at its start before 0 and holds after its last setpoint)."""
    idx = np.clip(np.arange(x.size) - k, 0, x.size - 1)
    return x[idx]


@pytest.mark.parametrize(
    "text",
    [
        "eventually[2, 6] (x(d) >= 1)",
        "always[1, 4] (x(d) >= 0)",
        "eventually[0, 5] always[0, 1] (x(d) >= 0.5)",
        "always[0, 3] (x(d) >= -0.5) or eventually[3, 8] (x(d) >= 1.5)",
    ],
)
def test_a_widened_clause_holds_under_every_shift_up_to_tau(text: str) -> None:
    reg = _registry()
    phi = parse(text, reg)
    tau, dt, horizon = 0.5, 0.1, 10.0
    wide = parse(str(widened(phi, tau, horizon)), reg)  # it is spec text, and round-trips
    rng = np.random.default_rng(7)
    t = np.arange(0.0, horizon + 1e-9, dt)
    held = 0
    for _ in range(300):
        # smooth random signals: a few sines
        f, ph, amp = rng.uniform(0.1, 1.0, 3), rng.uniform(0, 6.3, 3), rng.uniform(0, 1.5, 3)
        x = (amp[:, None] * np.sin(f[:, None] * t + ph[:, None])).sum(axis=0) + rng.normal()
        sig = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
        if wide.robustness({"d": sig}, dt) < 0.0:
            continue
        held += 1
        for k in range(-round(tau / dt), round(tau / dt) + 1):
            moved = np.column_stack([_shifted(x, k), np.zeros_like(x), np.zeros_like(x)])
            assert phi.robustness({"d": moved}, dt) >= 0.0, (text, k)
    assert held > 10  # the property was put to the test, not vacuous


def test_widening_leaves_what_it_cannot_make_safe_and_never_looks_past_the_horizon() -> None:
    reg = _registry()
    short = parse("eventually[2, 2.5] (x(d) >= 1)", reg)  # a window shorter than 2 tau
    assert widened(short, 0.5, 10.0) == short
    late = widened(parse("always[8, 9.8] (x(d) >= 1)", reg), 0.5, 10.0)
    assert str(late) == "always[7.5,10] (x(d) >= 1)"
    inner = widened(parse("always[8, 9] eventually[0, 1] (x(d) >= 1)", reg), 0.5, 10.0)
    assert inner.horizon == 10.0


@pytest.fixture(scope="module")
def mission_plan(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, dict, Path]:
    out = tmp_path_factory.mktemp("for_mission") / "ra.plan.json"
    argv = ["plan", str(ROOT / "configs" / "reach_avoid.yaml"), "--for", "mission"]
    argv += ["-o", str(out), "--json", "--coarse-s", "0"]
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(argv)
    return rc, json.loads(buf.getvalue()), out


@pytest.mark.slow
def test_a_plan_for_missions_tolerates_the_timing_error_asked_for_on_its_own_trajectories(
    mission_plan: tuple[int, dict, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    rc, res, out = mission_plan
    assert rc == 0 and res["success"] and res["timing"]["met"], res["timing"]
    plan = load_plan(out)
    assert plan.timing is not None and plan.timing.tolerance_s == 0.5
    assert plan.robustness >= plan.epsilon
    # independent of the loop: every clause of the written plan, with each vehicle 0.5 s
    # early or late and each pair off the opposite ways, on the plan's own trajectories
    phi = plan_formula(plan)
    dt = plan.check_dt_s
    t = np.arange(round(plan.horizon_s / dt) + 1) * dt
    names = [v.name for v in plan.vehicles]
    shifts = [{n: s * 0.5} for n in names for s in (-1, 1)] + [
        {names[0]: 0.5, names[1]: -0.5},
        {names[0]: -0.5, names[1]: 0.5},
    ]
    base = planned_signals(plan, t)
    for shift in shifts:
        sig = base | {n: planned_signals(plan, t + d)[n] for n, d in shift.items()}
        for clause in phi.clauses:
            assert clause.robustness(sig, dt) >= plan.epsilon, (str(clause), shift)
    # the record reads back, lists every clause, and the file is valid under the schema
    data = json.loads(out.read_text(encoding="utf-8"))
    schema = json.loads((ROOT / "docs" / "plan-file.schema.json").read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator(schema).validate(data)
    assert min(plan.timing.clauses_s.values()) >= 0.5
    capsys.readouterr()
    assert main(["verify", str(out)]) == 0
    said = capsys.readouterr().out
    assert "planned for missions: every clause to tolerate 0.5 s of timing error (met" in said


def test_for_mission_options_that_do_not_go_together_are_one_line_and_exit_2(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    scenario = str(ROOT / "configs" / "reach_avoid.yaml")
    out = str(tmp_path / "p.json")
    cases = [
        (["--timing-tolerance", "0.5"], "--timing-tolerance needs --for mission"),
        (["--for", "mission", "--target-probability", "0.9"], "--for mission: plans to a"),
        (["--for", "mission", "--timing-tolerance", "0"], "--timing-tolerance: must be in"),
        (["--for", "mission", "--wind", "uniform(0, 3)"], "--wind needs --target-probability"),
    ]
    for extra, says in cases:
        assert main(["plan", scenario, "-o", out, *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0], err
