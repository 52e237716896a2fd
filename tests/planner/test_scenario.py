"""Scenario files: the shipped configs load, repetition expands, mistakes name the key path."""

from __future__ import annotations

import copy
import itertools
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from planner.problem import DynamicsModel
from planner.scenario import load_scenario, parse_scenario
from planner.scenario.checks import reach_m
from planner.scenario.sections import ScenarioError
from planner.spec.predicates import build_registry
from planner.stl import parse

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _yaml(name: str) -> dict[str, Any]:
    return yaml.safe_load((CONFIGS / name).read_text())


@pytest.mark.parametrize("n", [1, 2, 4, 16])
def test_reach_avoid_vehicle_count_expands_clauses_per_vehicle_and_pair(n: int) -> None:
    p = load_scenario(CONFIGS / "reach_avoid.yaml", vehicles=n)
    assert [v.name for v in p.vehicles] == [f"d{i}" for i in range(1, n + 1)]
    assert [v.sysid for v in p.vehicles] == list(range(1, n + 1))
    # 2 clauses per drone, 1 per unordered pair.
    assert len(p.clauses) == 2 * n + n * (n - 1) // 2
    dist_clauses = [c.text for c in p.clauses if "dist(" in c.text]
    pairs = {tuple(re.search(r"dist\((\w+), (\w+)\)", t).groups()) for t in dist_clauses}
    assert pairs == {(f"d{i}", f"d{j}") for i in range(1, n + 1) for j in range(i + 1, n + 1)}
    starts = np.array([v.start_enu_m for v in p.vehicles])
    # In the far bands (west or south of the obstacle), >= 3 m from the goal along an axis.
    assert np.all(starts[:, :2].min(axis=1) <= -1.5 + 1e-12)
    goal = p.region("goal").center_enu_m
    assert np.all(np.abs(starts - goal).max(axis=1) >= 3.0 - 1e-12)
    if n > 1:
        d = np.linalg.norm(starts[:, None] - starts[None], axis=-1)[np.triu_indices(n, 1)]
        assert d.min() >= p.separation_m
    assert p.model is DynamicsModel.MINIMUM_JERK
    assert p.timing.n_samples == 121


def test_starts_are_deterministic() -> None:
    a = load_scenario(CONFIGS / "reach_avoid.yaml", vehicles=8)
    b = load_scenario(CONFIGS / "reach_avoid.yaml", vehicles=8)
    assert a.vehicles == b.vehicles


def test_expanded_spec_text_parses_back_to_the_same_clauses() -> None:
    p = load_scenario(CONFIGS / "powerline_inspection.yaml", vehicles=4)
    reg = build_registry(p)
    whole = parse(p.spec_text, reg)
    each = [parse(c.text, reg) for c in p.clauses]
    assert whole.clauses == tuple(each)
    assert "$" not in p.spec_text


def test_powerline_groups_split_halves_and_until_clause() -> None:
    p = load_scenario(CONFIGS / "powerline_inspection.yaml", vehicles=4)
    assert p.groups["west"] == ("d1", "d2")
    assert p.groups["east"] == ("d3", "d4")
    assert p.groups["all"] == ("d1", "d2", "d3", "d4")
    texts = [c.text for c in p.clauses]
    assert "eventually[0, 29] always[0, 1] inside(d1, insp4)" in texts
    assert any(t.startswith("(not inside(d3, insp3)) until[0, 15]") for t in texts)
    # Realistic geometry: poles tens of metres apart, 10-15 m tall.
    poles = [p.region(f"pole{i}") for i in range(1, 5)]
    xs = [r.center_enu_m[0] for r in poles]
    assert all(20 <= b - a <= 60 for a, b in itertools.pairwise(xs))
    assert all(10 <= r.hi_enu_m[2] <= 15 for r in poles)
    assert p.vehicles[0].thrust_max_m_s2 == 20


def test_double_integrator_config_loads() -> None:
    p = load_scenario(CONFIGS / "narrow_passage_di.yaml")
    assert p.model is DynamicsModel.DOUBLE_INTEGRATOR
    assert len(p.vehicles) == 2


def _mutate(base: dict[str, Any], path: list[Any], value: Any) -> dict[str, Any]:
    data = copy.deepcopy(base)
    node = data
    for key in path[:-1]:
        node = node[key]
    if value is _DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return data


_DELETE = object()


@pytest.mark.parametrize(
    ("path", "value", "key_path", "words"),
    [
        (["spec", 0, "formula"], "eventually[0, 6] inside(d, gaol)", "spec[0].formula", "gaol"),
        (["limits", "v_max_m_s"], -1.0, "limits.v_max_m_s", "> 0"),
        (["limits", "a_max_m_s2"], [1, 0, 1], "limits.a_max_m_s2[1]", "> 0"),
        (
            ["vehicles", "starts", "positions", 0],
            [-3, 1.5, 0.75],
            "vehicles.starts.positions[0]",
            "outside the workspace: east -3 is below its minimum -2",
        ),
        (
            ["vehicles", "starts", "positions", 1],
            [1.5, -1.5, 2.5],
            "vehicles.starts.positions[1]",
            "up 2.5 is above its maximum 2",
        ),
        (
            ["vehicles", "starts", "positions", 0],
            [0.5, 0.0, 1.0],
            "vehicles.starts.positions[0]",
            "inside obstacle 'obstacle' ([-1, -1, 0] to [1, 1, 1.5])",
        ),
        (
            ["spec", 2, "formula"],
            "always[0, $horizon] dist(a, b) >= 5",
            "spec[2].formula",
            "dist(d1, d2) >= 5 is -0.757 with d1, d2 at their starts",
        ),
        (
            ["spec", 0, "formula"],
            "eventually[0, 1] inside(d, goal)",
            "spec[0].formula",
            "inside(d1, goal) cannot hold by t = 1 s: goal is 3 m east of d1's start and d1 "
            "covers at most 0.469 m that way in 1 s from rest (limits 0.751 m/s, 1 m/s^2)",
        ),
        (
            ["spec", 0, "formula"],
            "always[0, 3] eventually[0, 2] always[0, 2] inside(d, goal)",
            "spec[0].formula",
            "looks 3 + 2 + 2 = 7 s ahead, more than the plan's horizon 6 s",
        ),
        (["regions", "goal", "half_size"], 0, "regions.goal.half_size", "> 0"),
        (["regions", "obstacle", "kind"], "wall", "regions.obstacle.kind", "unknown kind"),
        (["timing", "segment_s"], 0.7, "timing.segment_s", "whole number of segments of 0.7 s"),
        (["timing", "Ts_s"], 0.7, "timing.Ts_s", "make timing.horizon_s 5.6 or 6.3 s"),
        (["timing"], _DELETE, "timing", "missing"),
        (["spec", 0, "each"], "d in drones", "spec[0].each", "unknown group"),
        (
            ["spec", 0, "formula"],
            "eventually[0, $horizn] inside(d, goal)",
            "spec[0].formula",
            "$horizn",
        ),
        (["spec", 0, "formula"], "eventually[0, 6] inside(d, goal", "spec[0].formula", "line 1"),
        (["spec", 0, "formula"], "eventually[0, 9] inside(d, goal)", "spec[0].formula", "horizon"),
        (["spec", 0, "formula"], "always[0, 6] d >= 0", "spec[0].formula", "x(d1)"),
        (["spec", 0, "formula"], "always[0, 6] inside(d, d)", "spec[0].formula", "unknown region"),
        (
            ["spec", 0, "formula"],
            "always[0, 6] near(d, goal)",
            "spec[0].formula",
            "unknown function",
        ),
        (["spec", 2, "each"], "(a, b) in all", "spec[2].each", "pairs(GROUP)"),
        (["vehicles", "count"], 0, "vehicles.count", ">= 1"),
        (["separation_m"], -0.2, "separation_m", ">= 0"),
        (["solver"], {"method": "snopt"}, "solver.method", "unknown method"),
        (["solver"], {"separation_curvature": "yes"}, "solver.separation_curvature", "true"),
        (["solver"], {"qpsol": "gurobi"}, "solver.qpsol", "unknown QP solver"),
        (["colour"], "red", "colour", "unknown key"),
        (["origin", "lat"], 123.0, "origin.lat", "latitude"),
        (["model"], "bicycle", "model", "unknown model"),
    ],
)
def test_bad_scenario_names_file_and_key_path(
    path: list[Any], value: Any, key_path: str, words: str
) -> None:
    data = _mutate(_yaml("reach_avoid.yaml"), path, value)
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(data, "configs/x.yaml")
    assert exc.value.key_path == key_path
    assert str(exc.value).startswith(f"configs/x.yaml: {key_path}: ")
    assert words in str(exc.value)


def test_vehicle_override_outside_range_is_an_error() -> None:
    with pytest.raises(ScenarioError, match=r"vehicles: --vehicles 17 is outside 1\.\.16"):
        load_scenario(CONFIGS / "reach_avoid.yaml", vehicles=17)
    with pytest.raises(ScenarioError, match=r"--vehicles 1 is outside 2\.\.8 .*\(2 groups\)"):
        load_scenario(CONFIGS / "powerline_inspection.yaml", vehicles=1)
    with pytest.raises(ScenarioError, match="lists its vehicles"):
        load_scenario(CONFIGS / "narrow_passage_di.yaml", vehicles=3)


def test_starts_closer_than_separation_are_rejected() -> None:
    data = _yaml("narrow_passage_di.yaml")
    data["vehicles"][1]["start"] = [1.2, 1, 1]
    with pytest.raises(ScenarioError, match=r"vehicles: starts of d1 and d2 are 0\.2 m apart"):
        parse_scenario(data, "np.yaml")


def test_duplicate_vehicle_names_are_rejected() -> None:
    data = _yaml("narrow_passage_di.yaml")
    data["vehicles"][1]["name"] = "d1"
    with pytest.raises(ScenarioError, match=r"vehicles\[1\]\.name: duplicate"):
        parse_scenario(data, "np.yaml")


def test_yaml_syntax_error_names_line(tmp_path: Path) -> None:
    f = tmp_path / "broken.yaml"
    f.write_text("name: x\norigin: {lat: 1, lon: [2\n")
    with pytest.raises(ScenarioError, match=r"broken\.yaml: line \d+, column \d+: invalid YAML"):
        load_scenario(f)


def test_missing_file_is_a_scenario_error(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="cannot read"):
        load_scenario(tmp_path / "nope.yaml")


def test_product_binding_and_literal_lists() -> None:
    data = _yaml("reach_avoid.yaml")
    data["spec"] = [
        {"each": ["d in all", "r in [goal, obstacle]"], "formula": "eventually[0, 6] inside(d, r)"}
    ]
    p = parse_scenario(data, "x.yaml", vehicles=2)
    assert [c.text for c in p.clauses] == [
        "eventually[0, 6] inside(d1, goal)",
        "eventually[0, 6] inside(d1, obstacle)",
        "eventually[0, 6] inside(d2, goal)",
        "eventually[0, 6] inside(d2, obstacle)",
    ]


def test_sqpmethod_defaults_to_bfgs_and_a_shipped_qp_solver() -> None:
    data = _yaml("reach_avoid.yaml")
    data["solver"] = {"method": "sqpmethod"}
    solver = parse_scenario(data, "x.yaml").solver
    assert (solver.hessian, solver.qpsol) == ("limited-memory", "piqp")
    data["solver"] = {"method": "sqpmethod", "hessian": "exact", "qpsol": "osqp"}
    solver = parse_scenario(data, "x.yaml").solver
    assert (solver.hessian, solver.qpsol) == ("exact", "osqp")


@pytest.mark.parametrize(("v_max", "a_max", "t_s"), [(0.751, 1.0, 1.0), (5.0, 2.0, 38.0), (3.0, 4.0, 0.5), (2.0, 1.0, 2.0)])  # fmt: skip
def test_the_reach_bound_is_what_full_acceleration_then_full_speed_covers(
    v_max: float, a_max: float, t_s: float
) -> None:
    # The fastest way along one axis from rest within |v| <= V and |a| <= A: accelerate at A
    # until V, then hold V. Integrated step by step, independently of the closed form.
    dt, x, v = 1e-4, 0.0, 0.0
    for _ in range(round(t_s / dt)):
        a = a_max if v < v_max else 0.0
        v_next = min(v + a * dt, v_max)
        x += 0.5 * (v + v_next) * dt
        v = v_next
    assert reach_m(t_s, v_max, a_max) == pytest.approx(x, abs=1e-3)


def test_load_checks_stop_at_what_the_spec_requires_not_at_what_it_allows() -> None:
    data = _yaml("reach_avoid.yaml")
    # a choice (or) and a negation are not obligations: these load
    for text in (
        "eventually[0, 1] inside(d, goal) or eventually[0, 6] inside(d, goal)",
        "not always[0, 6] dist(a, b) >= 5",
    ):
        ok = _mutate(data, ["spec", 2 if "dist" in text else 0, "formula"], text)
        parse_scenario(ok, "configs/x.yaml")
    # an obligation under always is one: at t = 0 (always[0, ...]) and by its deadline
    nested = _mutate(data, ["spec", 0, "formula"], "always[0, 2] eventually[0, 1] inside(d, goal)")
    with pytest.raises(ScenarioError, match=r"cannot hold by t = 1 s"):
        parse_scenario(nested, "configs/x.yaml")
    late = _mutate(data, ["spec", 0, "formula"], "always[5, 6] inside(d, goal)")
    parse_scenario(late, "configs/x.yaml")  # by 5 s: 3 m is within reach
    # the shipped scenarios all load
    for name in ("reach_avoid.yaml", "powerline_inspection.yaml", "narrow_passage_di.yaml"):
        load_scenario(CONFIGS / name)
