"""Clauses tightened by a margin (``planner.spec.margins``): the tightened formula's exact
robustness is the original's minus the margin, at every instant, for every kind of node and
region; the split spec is the same spec; a plan made for the tightened spec keeps the spec as
written by the margin; bad margins are refused."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from planner.optimize import plan
from planner.scenario import load_scenario
from planner.solve.plan_check import recheck
from planner.spec.margins import (
    MarginError,
    clause_texts,
    has_dwell,
    lengthened,
    max_margin,
    offset_region,
    shifted,
    split,
    split_clauses,
    tighten,
    tightened_name,
)
from planner.spec.predicates import build_registry
from planner.spec.regions import Cylinder, Prism, Region, RegionKind
from planner.stl import conjunction, parse

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
RNG = np.random.default_rng(52)


class _Regions:
    """A region source that grows: the tightened copies are added as they are made."""

    def __init__(self, regions: list[Region]) -> None:
        self.by_name = {r.name: r for r in regions}

    @property
    def all_regions(self) -> tuple[Region, ...]:
        return tuple(self.by_name.values())

    def region(self, name: str) -> Region:
        return self.by_name[name]

    def moved(self, name: str, m: float) -> str:
        new = tightened_name(name, m)
        self.by_name.setdefault(new, offset_region(self.by_name[name], m, new))
        return new


def _regions() -> _Regions:
    return _Regions(
        [
            Region("workspace", RegionKind.WORKSPACE, (-10, -10, 0), (10, 10, 10)),
            Region("box", RegionKind.INSPECTION, (-1, -2, 1), (3, 2, 4)),
            Region.of_shape(
                "hexa",
                RegionKind.NO_FLY,
                Prism.from_polygon([[0, -3], [3, -2], [4, 1], [2, 3], [-1, 2], [-2, -1]], 0, 5),
            ),
            Region.of_shape(
                "turned", RegionKind.INSPECTION, Prism.oriented_box([1, 0, 3], [2.5, 1.5, 1.5], 0.6)
            ),
            Region.of_shape("pole", RegionKind.POLE, Cylinder((1.0, 0.5), 1.5, 0.0, 6.0)),
        ]
    )


FORMULAS = [
    "always[0,2] dist(a, b) >= 1.5",
    "eventually[0,3] (z(a) <= 4 and x(b) >= 0.5 - y(a))",
    "always[0,4] (inside(a, workspace) and outside(a, pole) and outside(b, hexa))",
    "eventually[0,3] always[0,1] inside(a, box)",
    "not inside(a, turned) until[0,3] always[0,1] inside(b, turned)",
    "always[0,4] (inside(a, hexa) implies z(a) >= 3)",
    "eventually[0,4] (inside(a, pole) or not (dist(a, b) < 2 and inside(b, box)))",
]


@pytest.mark.parametrize("text", FORMULAS)
@pytest.mark.parametrize("m", [0.3, -0.2, 0.75])
def test_a_tightened_formula_loses_exactly_its_margin_at_every_instant(text: str, m: float) -> None:
    src = _regions()
    phi = parse(text, functions=build_registry(src))
    tight = shifted(phi, m, src.moved)
    assert str(tight) != str(phi)
    # reparsed from its text (as a tightened problem is), with the moved regions known
    again = parse(str(tight), functions=build_registry(src))
    dt = 0.1
    for _ in range(5):
        n = 80
        walk = {
            v: np.cumsum(RNG.normal(0, 0.4, (n, 3)), axis=0) + RNG.uniform(-2, 4, 3)
            for v in ("a", "b")
        }
        want = phi.robustness_trace(walk, dt) - m
        np.testing.assert_allclose(tight.robustness_trace(walk, dt), want, atol=1e-9)
        np.testing.assert_allclose(again.robustness_trace(walk, dt), want, atol=1e-9)


@pytest.mark.parametrize("name", ["box", "hexa", "turned", "pole"])
def test_a_moved_region_has_every_face_margin_moved(name: str) -> None:
    src = _regions()
    r = src.region(name)
    p = RNG.uniform(np.asarray(r.lo_enu_m) - 1, np.asarray(r.hi_enu_m) + 1, (500, 3))
    for m in (0.25, -0.6):
        moved = offset_region(r, m, "moved")
        np.testing.assert_allclose(moved.margin(p), r.margin(p) - m, atol=1e-9)
        assert moved.kind is r.kind


def test_a_region_that_would_vanish_is_refused_and_the_largest_margin_found() -> None:
    src = _regions()
    with pytest.raises(MarginError, match=r"'box' cannot shrink by 2\.5 m"):
        offset_region(src.region("box"), 2.5, "x")  # its smallest half-size is 1.5 m
    problem = load_scenario(CONFIGS / "powerline_inspection.yaml")
    text = "eventually[0,29] always[0,1] inside(d1, insp1)"
    assert text in clause_texts(problem)
    half = problem.region("insp1").min_half_m
    assert max_margin(problem, text) == pytest.approx(half, abs=0.011)
    assert max_margin(problem, text) < half
    with pytest.raises(MarginError, match="no clause of the spec reads"):
        tighten(problem, {"always[0,30] dist(d1, d9) >= 1": 0.5})


def test_the_split_spec_is_the_same_spec() -> None:
    src = _regions()
    for text in [*FORMULAS, "always[0,3] (always[0,1] (x(a) >= 0 and y(b) <= 2) and z(a) >= 1)"]:
        phi = parse(text, functions=build_registry(src))
        parts = split(phi)
        walk = {v: RNG.normal(0, 2, (60, 3)) for v in ("a", "b")}
        whole = phi.robustness_trace(walk, 0.1)
        np.testing.assert_allclose(conjunction(parts).robustness_trace(walk, 0.1), whole)
    three = parse(
        "always[0,4] (inside(a, workspace) and outside(a, pole) and outside(b, hexa))",
        functions=build_registry(src),
    )
    assert [str(p) for p in split(three)] == [
        "always[0,4] inside(a, workspace)",
        "always[0,4] outside(a, pole)",
        "always[0,4] outside(b, hexa)",
    ]


@pytest.mark.slow
def test_a_plan_for_the_tightened_spec_keeps_the_spec_as_written_by_the_margins() -> None:
    written = load_scenario(CONFIGS / "powerline_inspection.yaml", vehicles=2)
    problem = split_clauses(written)
    texts = clause_texts(problem)
    margins = {t: 0.4 for t in texts if "dist(" in t or "corridor" in t}
    assert margins
    tight = plan(tighten(problem, margins))
    assert tight.success
    judged = recheck(tight, written, note="margins")
    assert judged.success and "margins" in judged.status
    assert judged.problem is written
    by_text = {c.text: c.robustness for c in recheck(tight, problem).clauses}
    for t, m in margins.items():
        assert by_text[t] >= m + written.epsilon - 1e-9
    # the tightened plan's own robustness is the written one's less the margins (or more)
    assert judged.robustness >= tight.robustness - 1e-9
    assert math.isfinite(judged.robustness_planning_grid)


@pytest.mark.parametrize(
    "text,want",
    [
        (
            "eventually[0,29] always[0,1] inside(a, box)",
            "eventually[0,27] always[0,3] inside(a, box)",
        ),
        (
            "not inside(a, turned) until[0,15] always[0,1] inside(b, turned)",
            "not inside(a, turned) until[0,13] always[0,3] inside(b, turned)",
        ),
        (
            "always[0,4] (eventually[1,2] always[0,1] z(a) >= 1)",
            "always[0,4] eventually[1,1] always[0,2] z(a) >= 1",
        ),
        ("always[0,4] inside(a, workspace)", "always[0,4] inside(a, workspace)"),
        (
            "not eventually[0,3] always[0,1] inside(a, box)",
            "not eventually[0,3] always[0,1] inside(a, box)",
        ),
    ],
)
def test_a_longer_dwell_asks_more_and_looks_no_further(text: str, want: str) -> None:
    src = _regions()
    phi = parse(text, functions=build_registry(src))
    longer = lengthened(phi, 2.0)
    assert str(longer) == str(parse(want, functions=build_registry(src)))
    assert longer.horizon == phi.horizon
    assert has_dwell(phi) == (str(longer) != str(phi))
    # never more robust than the clause as written, for any signal
    for _ in range(20):
        walk = {v: np.cumsum(RNG.normal(0, 0.3, (400, 3)), axis=0) for v in ("a", "b")}
        assert longer.robustness(walk, 0.1) <= phi.robustness(walk, 0.1) + 1e-12
