"""The spec's geometry whatever its spelling (planner.spec.geometry) and the initial guess built on
it (targets chosen among options and ordered, keep-outs routed around).

References: the named boxes themselves (a half-plane spelling must mean the same box), a
brute-force Chebyshev centre on a grid, and exact plans of the same mission in both spellings.
"""

from __future__ import annotations

import copy
import itertools
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from planner.optimize import plan
from planner.scenario import parse_scenario
from planner.solve.guess import keep_outs_of, visit_targets
from planner.spec.geometry import keep_out, place
from planner.stl import conjunction

CONFIGS = Path(__file__).resolve().parents[2] / "configs"

_BASE: dict[str, Any] = {
    "name": "geometry",
    "origin": {"lat": 47.397742, "lon": 8.545594, "alt": 488.0},
    "workspace": {"min": [0, 0, 0.5], "max": [10, 10, 1.5]},
    "regions": {
        "goal": {"kind": "goal", "min": [7, 8, 0], "max": [8, 9, 2]},
        "obstacle": {"kind": "obstacle", "min": [3, 4, 0], "max": [5, 6, 2]},
        "near": {"kind": "goal", "min": [1, 3, 0.5], "max": [2, 4, 1.5]},
        "far": {"kind": "goal", "min": [8, 1, 0.5], "max": [9, 2, 1.5]},
    },
    "limits": {"v_max_m_s": 1, "a_max_m_s2": 0.5},
    "vehicles": [{"name": "d1", "start": [1, 1, 1]}, {"name": "d2", "start": [9, 9, 1]}],
    "timing": {"horizon_s": 20, "segment_s": 1, "Ts_s": 1, "check_dt_s": 0.1},
    "epsilon": 0.0,
    "model": "double_integrator",
    "spec": ["eventually[0, 20] inside(d1, goal)"],
}


def _problem(*spec: str) -> Any:
    data = copy.deepcopy(_BASE)
    data["spec"] = list(spec)
    return parse_scenario(data, "geometry.yaml")


def _node(problem: Any, i: int = 0) -> Any:
    return problem.formulas[i]


def _box(pl: Any) -> list[float]:
    return [*pl.lo_enu_m, *pl.hi_enu_m]


@pytest.mark.parametrize(
    "text",
    [
        "inside(d1, goal)",
        "x(d1) >= 7 and x(d1) <= 8 and y(d1) >= 8 and y(d1) <= 9",
        "y(d1) <= 9 and -x(d1) >= -8 and 2 * x(d1) >= 14 and y(d1) - 8 >= 0",
        "not (x(d1) < 7 or x(d1) > 8 or y(d1) < 8 or y(d1) > 9)",
        "not outside(d1, goal)",
    ],
)
def test_every_spelling_of_a_box_is_the_same_place(text: str) -> None:
    pr = _problem(f"eventually[0, 18] ({text})")
    pl = place(_node(pr).child, pr)
    assert pl is not None and pl.vehicle == "d1"
    # the goal box, its z clipped to the workspace (the spelling without z gets the workspace's)
    assert _box(pl) == pytest.approx([7, 8, 0.5, 8, 9, 1.5])
    assert pl.point == pytest.approx([7.5, 8.5, 1.0]) and pl.depth_m == pytest.approx(0.5)


@pytest.mark.parametrize(
    "text",
    [
        "outside(d1, obstacle)",
        "x(d1) <= 3 or x(d1) >= 5 or y(d1) <= 4 or y(d1) >= 6",
        "not inside(d1, obstacle)",
        "not (x(d1) > 3 and x(d1) < 5 and y(d1) > 4 and y(d1) < 6)",
    ],
)
def test_every_spelling_of_a_keep_out_is_the_same_box(text: str) -> None:
    pr = _problem(f"always[0, 5] ({text})")
    ko = keep_out(_node(pr).child, pr)
    assert ko is not None and _box(ko) == pytest.approx([3, 4, 0.5, 5, 6, 1.5])
    assert place(_node(pr).child, pr) is None  # and it is not a place to go


@pytest.mark.parametrize(
    "text",
    [
        "dist(d1, d2) >= 1",  # two vehicles
        "x(d1) >= x(d2)",  # two vehicles
        "x(d1) * x(d1) >= 4",  # not affine
        "inside(d1, goal) or inside(d1, obstacle)",  # a choice, not one polytope
        "x(d1) >= 1 and y(d2) >= 1",  # two vehicles
    ],
)
def test_what_is_not_one_vehicles_polytope_is_not_a_place(text: str) -> None:
    pr = _problem(f"eventually[0, 18] ({text})")
    assert place(_node(pr).child, pr) is None


def test_a_slanted_polytope_gets_its_chebyshev_centre() -> None:
    pr = _problem("eventually[0, 18] (x(d1) + y(d1) <= 6 and x(d1) >= 1 and y(d1) >= 2)")
    pl = place(_node(pr).child, pr)
    assert pl is not None
    # brute force: the point of the triangle (in the workspace slab) farthest from its faces
    g = np.linspace(0, 10, 401)
    X, Y = np.meshgrid(g, g)
    d = np.minimum.reduce([(6 - X - Y) / np.sqrt(2), X - 1, Y - 2, np.full_like(X, 0.5)])
    i = np.unravel_index(np.argmax(d), d.shape)
    assert pl.depth_m == pytest.approx(d[i], abs=0.02)
    assert pl.contains(pl.point, margin=pl.depth_m - 1e-6)
    lo, hi = np.array(pl.lo_enu_m), np.array(pl.hi_enu_m)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])  # fmt: skip
    assert all(pl.contains(c, margin=-1e-9) for c in corners)  # its box is inside it


def test_the_guess_picks_the_nearest_option_and_visits_in_deadline_then_nearest_order() -> None:
    pr = _problem(
        "eventually[0, 20] (inside(d1, far) or inside(d1, near))",
        "eventually[0, 20] (x(d1) >= 7 and x(d1) <= 8 and y(d1) >= 8 and y(d1) <= 9)",
        "eventually[0, 8] (x(d1) >= 8 and x(d1) <= 9 and y(d1) >= 1 and y(d1) <= 2)",
        "always[0, 20] (z(d1) >= 0.8 and z(d1) <= 1.2)",  # a band it is in: stay, not a target
        "always[0, 20] (x(d1) <= 3 or x(d1) >= 5 or y(d1) <= 4 or y(d1) >= 6)",
    )
    f = conjunction(list(pr.formulas))
    got = visit_targets(f, "d1", pr, np.array([1.0, 1.0, 1.0]))
    # the deadline-8 box first (it is `far`); then, from there, `far` again is the nearest
    # option of the choice (already visited: nothing to add), then the goal
    assert [_box(p)[:2] + _box(p)[3:5] for p in got] == [[8, 1, 9, 2], [7, 8, 8, 9]]
    avoid = keep_outs_of(f, "d1", pr)
    assert [_box(a) for a in avoid] == [
        pytest.approx([0, 0, 0.5, 10, 10, 0.8]),
        pytest.approx([0, 0, 1.2, 10, 10, 1.5]),
        pytest.approx([3, 4, 0.5, 5, 6, 1.5]),
    ]
    near_first = visit_targets(
        conjunction([pr.formulas[0], pr.formulas[1]]), "d1", pr, np.array([1.0, 1.0, 1.0])
    )
    assert [_box(p)[:2] for p in near_first] == [[1, 3], [7, 8]]  # near, then the goal


def _half_planes(text: str) -> str:
    """configs/narrow_passage_di.yaml's spec with every box written as half-planes."""
    boxes = {"t1": (1, 2, 7, 8), "t2": (7, 8, 1, 2), "goal": (8, 9.5, 8, 9.5)}
    walls = {"wall_s": (4, 6, 0, 4.4), "wall_n": (4, 6, 5.6, 10)}
    for n, (a, b, c, e) in boxes.items():
        text = text.replace(
            f"inside(d, {n})", f"(x(d) >= {a} and x(d) <= {b} and y(d) >= {c} and y(d) <= {e})"
        )
    for n, (a, b, c, e) in walls.items():
        text = text.replace(
            f"outside(d, {n})", f"(x(d) <= {a} or x(d) >= {b} or y(d) <= {c} or y(d) >= {e})"
        )
    return text.replace("inside(d, workspace) and ", "")


@pytest.mark.slow
def test_the_narrow_passage_plans_in_both_spellings() -> None:
    # Before the guess read the geometry, the half-plane spelling ended at -0.96 (the
    # guess flew straight into the walls); the regions spelling plans to 0.17-0.2.
    data = yaml.safe_load((CONFIGS / "narrow_passage_di.yaml").read_text())
    regions = plan(parse_scenario(copy.deepcopy(data), "regions.yaml"))
    for clause in data["spec"]:
        clause["formula"] = _half_planes(clause["formula"])
    assert "inside(" not in str(data["spec"]) and "outside(" not in str(data["spec"])
    halves = plan(parse_scenario(data, "half_planes.yaml"))
    assert regions.success and halves.success, (regions.status, halves.status)
    assert halves.robustness > 0.05


def test_a_box_in_a_smooth_leaf_is_the_same_nlp_whatever_its_spelling() -> None:
    # inside(d1, goal) is the conjunction of its six faces; under `eventually` (a smooth
    # leaf), in the sharp NLP (planner.solve.refine.sharpen), both spellings get the same
    # sharpness and the same smooth value, everywhere.
    import casadi as ca

    from planner.optimize import make_model
    from planner.solve.nlp import NlpBuilder
    from planner.solve.plan_check import initial_states

    faces = "x(d1) >= 7 and x(d1) <= 8 and y(d1) >= 8 and y(d1) <= 9 and z(d1) >= 0 and z(d1) <= 2"
    built = []
    for text in ("eventually[0, 12] inside(d1, goal)", f"eventually[0, 12] ({faces})"):
        pr = _problem(text)
        model = make_model(pr)
        b = NlpBuilder(pr, model, conjunction(list(pr.formulas)), sharp=True)
        b.add_spec_constraints().add_dynamics_constraints().add_robustness_cost().add_bounds()
        built.append((b, model, pr))
    (b1, model, pr), (b2, _, _) = built
    assert b1.k_final == pytest.approx(b2.k_final, rel=1e-12)
    rng = np.random.default_rng(7)
    p = b1.parameters(initial_states(pr, model))
    for _ in range(5):
        w = rng.normal(scale=3.0, size=b1.w.shape[0])
        values = []
        for b in (b1, b2):
            nlp = b.assemble(b.k_final)[0]
            g = np.asarray(ca.Function("g", [nlp["x"], nlp["p"]], [nlp["g"]])(w, p)).ravel()
            values.append(g)
        np.testing.assert_allclose(values[0], values[1], rtol=1e-9, atol=1e-9)


_ZOO = Path(__file__).resolve().parents[2] / "benchmarks" / "scenarios"


def test_a_route_that_must_stay_on_stepping_stones_hops_between_them() -> None:
    # stlpy's SteppingStones: `always (inside(s0) or ... or inside(s14))`, reach s14.  The
    # guess routes inside the stones, crossing only gaps one sample's flight spans (before:
    # a straight line over the gaps, and the regions spelling failed at -0.46).
    from planner.solve.guess import axis_limits, grid_path, stay_within

    pr = parse_scenario(
        yaml.safe_load((_ZOO / "stlpy_stepping_stones_regions.yaml").read_text()), "ss.yaml"
    )
    f = conjunction(list(pr.formulas))
    (stones,) = stay_within(f, "d1", pr)
    assert len(stones) == 15
    reach = 0.5 * axis_limits(pr.vehicles[0])[0] * pr.timing.check_dt_s
    path = grid_path(pr, [], [np.array([2.0, 1.3, 1.0]), stones[14].point], [stones], reach)
    dense = np.concatenate([np.linspace(a, b, 20) for a, b in itertools.pairwise(path)])

    def gap(p: np.ndarray) -> float:  # per-axis distance to the nearest stone
        return min(float(np.max(np.maximum(s.A[::2] @ p - s.b[::2], 0))) for s in stones)

    assert max(gap(p) for p in dense) <= 0.5 + 1e-9  # never further than half a hop
    on = np.mean([gap(p) == 0.0 for p in dense])
    assert on > 0.5, on  # mostly on the stones
    # A window shorter than the plan does not bind the route; nor does a clause of d2.
    pr2 = _problem(
        "always[5, 20] (inside(d1, near) or inside(d1, far))", "always[0, 20] x(d2) >= 5"
    )
    f2 = conjunction(list(pr2.formulas))
    assert stay_within(f2, "d1", pr2) == []
    assert [[_box(p)[0] for p in u] for u in stay_within(f2, "d2", pr2)] == [[5.0]]


@pytest.mark.parametrize("spelling", ["regions", "halfplanes"])
@pytest.mark.slow
def test_stepping_stones_plans_near_the_certified_optimum_in_both_spellings(spelling) -> None:
    data = yaml.safe_load((_ZOO / f"stlpy_stepping_stones_{spelling}.yaml").read_text())
    # time for the stage's plan after a start that meets the mission (on a busy machine as
    # long again as that took may not be enough for the stage to end)
    data.setdefault("solver", {}).update(polish_s=30.0, starts=2)
    res = plan(parse_scenario(data, "ss.yaml"))
    assert res.success, res.status
    assert res.robustness >= 0.75 * 0.05272  # of stlpy's certified MILP optimum (0.8: 0.0422)
    # the route over the stones is the combinatorial stage's choice (the initial guess's
    # nearest stones left the regions spelling at 0.0004: a local optimum), at the certified
    # optimum's value on the coarse model (proven optimal there, or, stopped on a busy machine
    # before the proof, the best found)
    assert "of 2: the combinatorial stage's plan (" in res.status
    assert res.stats is not None and res.stats.coarse is not None
    assert res.stats.coarse["robustness"] == pytest.approx(0.05272, abs=5e-5)
