"""The row-wise leaves' Jacobian and Hessian differentiated at one sample and mapped over the
steps (:mod:`planner.solve.rowwise`) equal CasADi's derivatives of the whole block, on every kind of
row-wise leaf the planner writes: box faces, obstacle boxes, polygons, cylinders, comparisons
of coordinates and separations between vehicles."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from planner.optimize import make_model
from planner.scenario import parse_scenario
from planner.solve.leaf_templates import local_hessian
from planner.solve.nlp import NlpBuilder, is_separation
from planner.solve.nlp_solvers import derivatives
from planner.solve.rowwise import block_hessian, block_jacobian, sample_leaf
from planner.stl import conjunction

SCENARIO = {
    "name": "rowwise",
    "origin": {"lat": 47.397742, "lon": 8.545594, "alt": 488.0},
    "workspace": {"min": [-10, -10, 0.5], "max": [20, 20, 10]},
    "regions": {
        "goal": {"kind": "goal", "min": [15, 7, 1], "max": [16, 8, 2]},
        "block": {"kind": "obstacle", "min": [5, 0, 0], "max": [7, 3, 6]},
        "mast": {"kind": "pole", "center": [10, 10], "radius": 0.5, "z": [0, 8]},
        "yard": {"kind": "obstacle", "polygon": [[0, 12], [4, 12], [4, 16], [2, 18], [0, 16]],
                 "z": [0, 6]},
    },
    "limits": {"v_max_m_s": 2, "a_max_m_s2": 1},
    "vehicles": [
        {"name": "d1", "start": [1, 1, 1]},
        {"name": "d2", "start": [1, 3, 1]},
        {"name": "d3", "start": [1, 5, 1]},
    ],
    "timing": {"horizon_s": 12, "segment_s": 2, "Ts_s": 0.5, "check_dt_s": 0.25},
    "separation_m": 0.8,
    "epsilon": 0.01,
    "model": "minimum_jerk",
    "spec": [
        {"formula": "eventually[0, 10] always[0, 1] inside(d1, goal)"},
        {"each": "d in all",
         "formula": "always[0, 12] (inside(d, workspace) and outside(d, block) and "
                    "outside(d, mast) and outside(d, yard))"},
        {"formula": "always[2, 9] (z(d2) >= 2 and x(d3) - y(d3) <= 4)"},
        {"formula": "always[0, 12] inside(d3, workspace)"},
        {"each": "(a, b) in pairs(all)", "formula": "always[0, 12] dist(a, b) >= $separation"},
    ],
}  # fmt: skip


@pytest.fixture(scope="module")
def builder() -> NlpBuilder:
    problem = parse_scenario(SCENARIO)
    b = NlpBuilder(problem, make_model(problem), conjunction(list(problem.formulas)))
    return b.add_spec_constraints().add_dynamics_constraints().add_robustness_cost().add_bounds()


def _random(fn: ca.Function, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.normal(scale=4.0, size=fn.size_in(i)) for i in range(fn.n_in())]


@pytest.mark.slow
def test_each_blocks_derivatives_equal_casadis_of_the_whole_block(builder) -> None:
    w = builder.w
    lam_all = ca.SX.sym("lam", int(builder.direct.shape[0]))
    row, kinds = 0, set()
    for (leaf, steps), part in zip(builder.direct_steps.items(), builder.nonlinear, strict=True):
        m = int(part.shape[0])
        lam = lam_all[row : row + m]
        got = builder.sample_leaf(leaf, steps)
        assert got is not None, str(leaf)
        rows = part + builder.r * builder.a_direct[row : row + m]  # the leaf's own rows
        reference = [local_hessian(ca.dot(lam, rows), w), ca.jacobian(rows, w)]
        mine = [block_hessian(got[0], w, got[1], lam), block_jacobian(got[0], w, got[1])]
        ref_fn = ca.Function("ref", [w, builder.p, lam_all], reference)
        mine_fn = ca.Function("mine", [w, builder.p, lam_all], mine)
        for seed in range(3):
            args = _random(ref_fn, seed)
            for a, b in zip(ref_fn.call(args), mine_fn.call(args), strict=True):
                assert np.allclose(np.asarray(a), np.asarray(b), rtol=1e-10, atol=1e-10), leaf
        kinds.add(type(leaf).__name__ + (" separation" if is_separation(leaf) else ""))
        row += m
    # the scenario exercises predicates, comparisons and separations
    assert {"Predicate", "Comparison", "Comparison separation"} <= kinds


@pytest.mark.slow
def test_the_constraint_jacobian_and_lagrangian_hessian_are_unchanged(builder) -> None:
    """The assembled ``jac_g`` and ``hess_lag`` with per-sample blocks equal the ones
    differentiated block by block, separations' flat rows included."""
    w, p = builder.w, builder.p
    flat = [is_separation(leaf) for leaf in builder.direct_steps]
    rowwise = [builder.sample_leaf(leaf, st) for leaf, st in builder.direct_steps.items()]
    assert any(r is not None for r in rowwise)
    args = (w, p, builder.f, builder.linear, builder.nonlinear, True, flat)
    ref, mine = derivatives(*args), derivatives(*args, rowwise)
    for name in ("jac_g", "hess_lag"):
        assert mine[name].sparsity_out(mine[name].n_out() - 1).nnz() > 0
        for seed in range(3):
            vals = _random(ref[name], seed)
            for a, b in zip(ref[name].call(vals), mine[name].call(vals), strict=True):
                assert np.allclose(np.asarray(a), np.asarray(b), atol=1e-9), name


def test_a_leaf_of_constants_has_no_sample_leaf() -> None:
    assert sample_leaf(lambda xs: ca.DM([1.0, 2.0]), ["d1"]) is None
    one = sample_leaf(lambda xs: xs["d2"][0] ** 2 + xs["d2"][1] * xs["d2"][2], ["d1", "d2"])
    assert one is not None and one.vehicles == (1,) and one.rows == 1
    h = np.asarray(one.hess([1.0, 2.0, 3.0], [2.0]))
    assert np.allclose(h, 2.0 * np.array([[2, 0, 0], [0, 0, 1], [0, 1, 0]]))
    assert np.allclose(np.asarray(one.jac([1.0, 2.0, 3.0])), [[2.0, 3.0, 2.0]])
