"""ClauseBatch against the clauses evaluated one by one (the exact engine is the reference)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.scenario import load_scenario
from planner.scenario.spec import parse_clause
from planner.spec.predicates import build_registry
from planner.stl import parse
from planner.stl.batch import ClauseBatch, rename_signals, signal_order

REPO = Path(__file__).resolve().parents[2]


def _walks(names: list[str], rows: int, seed: int) -> dict[str, np.ndarray]:
    """Random smooth (rows, 3) tracks around the workspace, one per name."""
    rng = np.random.default_rng(seed)
    return {
        n: np.cumsum(rng.normal(0.0, 0.15, (rows, 3)), axis=0) + rng.uniform(-2, 2, 3)
        for n in names
    }


@pytest.mark.parametrize(
    "config, vehicles", [("reach_avoid.yaml", 8), ("powerline_inspection.yaml", 4)]
)
def test_a_batch_gives_every_clause_its_own_robustness(config: str, vehicles: int) -> None:
    problem = load_scenario(REPO / "configs" / config, vehicles=vehicles)
    registry = build_registry(problem)
    clauses = [parse_clause(problem, c, registry) for c in problem.clauses]
    names = [v.name for v in problem.vehicles]
    dt = 0.1
    rows = round(problem.timing.horizon_s / dt) + 1
    batch = ClauseBatch(clauses)
    assert batch.templates < len(clauses)  # the fleet's clauses share templates
    for seed in range(3):
        sig = _walks(names, rows, seed)
        want = np.array([c.robustness(sig, dt) for c in clauses])
        np.testing.assert_array_equal(batch.values(sig, dt), want)


def test_until_and_nested_windows_stay_inside_each_binding() -> None:
    problem = load_scenario(REPO / "configs" / "reach_avoid.yaml", vehicles=4)
    registry = build_registry(problem)
    texts = [
        f"(outside({a}, obstacle) until[0.5, 2] inside({b}, goal)) and "
        f"always[0, 1] eventually[0, 0.5] dist({a}, {b}) >= 0.3"
        for a, b in [("d1", "d2"), ("d2", "d3"), ("d3", "d4"), ("d4", "d1")]
    ]
    clauses = [parse(t, functions=registry) for t in texts]
    batch = ClauseBatch(clauses)
    assert batch.templates == 1
    rows = 41  # 4 s at 0.1 s, the horizon (2.5 s) fits
    for seed in range(5):
        sig = _walks(["d1", "d2", "d3", "d4"], rows, seed)
        want = np.array([c.robustness(sig, dt=0.1) for c in clauses])
        np.testing.assert_array_equal(batch.values(sig, 0.1), want)
    # a horizon longer than the signals: evaluated clause by clause, with the clause's error
    short = _walks(["d1", "d2", "d3", "d4"], 10, 0)
    with pytest.raises(Exception) as got:
        clauses[0].robustness(short, 0.1)
    with pytest.raises(type(got.value)):
        batch.values(short, 0.1)


def test_traces_of_atemporal_clauses_are_their_robustness_traces() -> None:
    problem = load_scenario(REPO / "configs" / "reach_avoid.yaml", vehicles=6)
    registry = build_registry(problem)
    texts = [f"dist({a}, {b}) >= 0.2" for a in ("d1", "d2", "d3") for b in ("d4", "d5", "d6")]
    texts += [f"outside({d}, obstacle) and inside({d}, workspace)" for d in ("d1", "d5")]
    clauses = [parse(t, functions=registry) for t in texts]
    batch = ClauseBatch(clauses)
    assert batch.templates == 2
    sig = _walks([f"d{i}" for i in range(1, 7)], 6, 11)
    want = np.stack([c.robustness_trace(sig, 0.1) for c in clauses])
    np.testing.assert_array_equal(batch.traces(sig, 0.1), want)
    with pytest.raises(ValueError, match="atemporal"):
        ClauseBatch([parse("always[0, 1] dist(d1, d2) >= 0.2", functions=registry)]).traces(
            sig, 0.1
        )


def test_renaming_touches_signals_only() -> None:
    problem = load_scenario(REPO / "configs" / "reach_avoid.yaml", vehicles=2)
    registry = build_registry(problem)
    f = parse("inside(d2, goal) or dist(d2, d1) >= 0.2", functions=registry)
    assert signal_order(f) == ("d2", "d1")
    g = rename_signals(f, {"d2": "a", "d1": "b", "goal": "x"})
    assert str(g) == "inside(a, goal) or dist(a, b) >= 0.2"
