"""The predicate table: one place declares each function a spec may call, its argument kinds
and its role; the implementations and the scenario reader follow it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planner.scenario import load_scenario
from planner.scenario.spec import FUNCTION_NAMES
from planner.spec.predicates import (
    PREDICATES,
    Role,
    build_registry,
    casadi_functions,
    numpy_functions,
    role_of,
)
from planner.stl import parse

REPO = Path(__file__).resolve().parents[2]


def test_every_declared_predicate_has_both_implementations_and_the_scenario_follows_it() -> None:
    problem = load_scenario(REPO / "configs" / "reach_avoid.yaml", vehicles=2)
    assert set(numpy_functions(problem)) == set(PREDICATES)
    assert set(casadi_functions(problem, 10.0)) == set(PREDICATES)
    assert {name: p.args for name, p in PREDICATES.items()} == FUNCTION_NAMES
    registry = build_registry(problem)
    for name, p in PREDICATES.items():
        f = registry[name]
        assert f.arity == len(p.args)
        assert f.signal_args == tuple(i for i, a in enumerate(p.args) if a == "v")


@pytest.mark.parametrize(
    "text, role",
    [
        ("inside(d1, goal)", Role.TARGET_BOX),
        ("outside(d1, obstacle)", Role.KEEP_OUT),
        ("dist(d1, d2) >= 0.2", Role.KEEP_APART),
        ("x(d1) <= 1", Role.COORDINATE),
    ],
)
def test_the_planner_reads_each_predicates_role_from_the_table(text: str, role: Role) -> None:
    problem = load_scenario(REPO / "configs" / "reach_avoid.yaml", vehicles=2)
    f = parse(text, functions=build_registry(problem))
    atom = f if not hasattr(f, "lhs") else f.lhs  # type: ignore[attr-defined]
    assert role_of(atom) is role
    sig = {"d1": np.zeros((2, 3)), "d2": np.ones((2, 3))}
    assert np.isfinite(f.robustness(sig, 0.1))


def test_the_predicates_do_not_load_the_scenario_reader_or_casadi() -> None:
    code = (
        "import sys\n"
        "import planner.spec.predicates\n"
        "print('planner.scenario' in sys.modules, 'casadi' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False False"


def test_a_scenario_and_a_plan_are_parsed_once(monkeypatch: pytest.MonkeyPatch) -> None:
    import planner.optimize as optimize
    import planner.scenario.spec as scenario_spec
    from planner.planfile import load_plan, plan_formula

    problem = load_scenario(REPO / "configs" / "reach_avoid.yaml", vehicles=1)
    assert len(problem.formulas) == len(problem.clauses)
    assert [str(f) for f in problem.formulas] == [
        str(parse(c.text, functions=build_registry(problem))) for c in problem.clauses
    ]

    def parse_again(*_a: object, **_k: object) -> None:
        raise AssertionError("the planner parsed the spec again")

    monkeypatch.setattr(scenario_spec, "parse_clause", parse_again)  # clause_formulas' parser
    assert optimize.plan(problem).success  # on the formulas parsed at load
    plan = load_plan(REPO / "tests" / "mavlink" / "data" / "reach_avoid_2.plan.json")
    assert plan_formula(plan) is plan_formula(plan)  # checked and parsed on first use only
    # both still travel to other processes (the mission conversion runs in a child): the
    # parsed spec, closures over the regions, stays behind and is parsed again there
    import pickle

    copy = pickle.loads(pickle.dumps(plan))
    assert str(plan_formula(copy)) == str(plan_formula(plan))
    assert pickle.loads(pickle.dumps(problem)).formulas == ()
