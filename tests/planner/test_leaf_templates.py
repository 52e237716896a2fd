"""Leaf templates: one shape per renamed leaf, and the same values and derivatives as the
leaf written out with its own vehicles and boxes (CasADi's full Hessian as reference)."""

from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from planner.optimize import make_model
from planner.scenario import load_scenario
from planner.solve.leaf_templates import canonical_leaf, clear_templates, instance, template
from planner.spec.predicates import build_registry, predicate_sharpness
from planner.stl import parse

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _powerline():
    problem = load_scenario(CONFIGS / "powerline_inspection.yaml", vehicles=4)
    return problem, build_registry(problem), make_model(problem)


@pytest.mark.slow
def test_leaves_naming_other_vehicles_and_boxes_share_one_shape() -> None:
    problem, reg, _ = _powerline()
    a = parse("eventually[0, 29] always[0, 1] inside(d1, insp1)", reg)
    b = parse("eventually[0, 29] always[0, 1] inside(d3, insp4)", reg)
    c = parse("(not inside(d2, insp3)) until[0, 15] (always[0, 1] inside(d2, insp2))", reg)
    assert canonical_leaf(a) == (
        "eventually[0,29] always[0,1] inside(v0, r0)",
        ("d1",),
        ("insp1",),
    )
    assert canonical_leaf(b)[0] == canonical_leaf(a)[0]
    text, vehicles, regions = canonical_leaf(c)
    assert vehicles == ("d2",) and regions == ("insp3", "insp2")
    assert "inside(v0, r0)" in text and "inside(v0, r1)" in text
    d = parse("eventually[0, 5] dist(d2, d1) <= 3", reg)
    assert canonical_leaf(d) == ("eventually[0,5] (dist(v0, v1) <= 3)", ("d2", "d1"), ())
    # Built once, then served from the cache for the other vehicle and box.
    clear_templates()
    dt, k, kp = problem.timing.sample_dt_s, 50.0, predicate_sharpness(problem)
    model = make_model(problem)
    first = template(a, 0, model, dt, k, kp)[0]
    assert template(b, 0, model, dt, k, kp)[0] is first
    near = template(d, 0, model, dt, k, kp)[0]
    assert template(d, 1, model, dt, k, kp)[0] is not near  # another step, another window
    assert template(a, 0, model, dt, 2 * k, kp)[0] is not first  # another sharpness
    assert template(a, 0, model, dt, k, 2 * kp)[0] is not first


@pytest.mark.slow
def test_template_value_gradient_and_hessian_equal_the_leaf_written_out() -> None:
    problem, reg, model = _powerline()
    dt, k, kp = problem.timing.sample_dt_s, 80.0, predicate_sharpness(problem)
    names = [v.name for v in problem.vehicles]
    nd, ni = model.n_dec * 3, model.n_init * 3
    z_all = ca.SX.sym("z", nd * len(names))
    x0_all = ca.SX.sym("x0", ni * len(names))
    rng = np.random.default_rng(7)
    clear_templates()
    for text, built_from, step in (
        (
            "eventually[0, 29] always[0, 1] inside(d3, insp4)",
            "eventually[0, 29] always[0, 1] inside(d1, insp1)",
            0,
        ),
        (
            "(not inside(d2, insp3)) until[0, 15] (always[0, 1] inside(d2, insp2))",
            "(not inside(d4, insp2)) until[0, 15] (always[0, 1] inside(d4, insp3))",
            0,
        ),
        ("eventually[0, 2] dist(d4, d1) <= 3", "eventually[0, 2] dist(d2, d3) <= 3", 6),
    ):
        # The template is built from another leaf of the same shape (other vehicles and
        # boxes, roles swapped), then used for this one.
        first = template(parse(built_from, reg), step, model, dt, k, kp)[0]
        leaf = parse(text, reg)
        # Reference: the leaf over the whole fleet's decisions, boxes as constants.
        pos = {}
        for i, nm in enumerate(names):
            Z = ca.reshape(z_all[i * nd : (i + 1) * nd], model.n_dec, 3)
            X0 = ca.reshape(x0_all[i * ni : (i + 1) * ni], model.n_init, 3)
            P = ca.mtimes(ca.DM(model.Mp), Z) + ca.mtimes(ca.DM(model.Np), X0)
            pos[nm] = P[step : step + leaf.horizon_steps(dt) + 1, :]
        ref = leaf.smooth_robustness(pos, dt, k)
        ref_fn = ca.Function(
            "ref", [z_all, x0_all], [ref, ca.gradient(ref, z_all), ca.hessian(ref, z_all)[0]]
        )
        inst = instance(
            leaf, step, model, dt, k, kp, {nm: i for i, nm in enumerate(names)}, problem.region
        )
        assert inst.template is first
        zi, xi = list(inst.z_index), list(inst.x0_index)
        for _ in range(3):
            z = rng.normal(scale=5.0, size=nd * len(names))
            x0 = rng.normal(scale=5.0, size=ni * len(names))
            v_ref, g_ref, h_ref = (np.asarray(ca.densify(m)) for m in ref_fn(z, x0))
            value, grad = inst.template.value_grad(z[zi], x0[xi], inst.bounds)
            hess = np.asarray(inst.template.hess(z[zi], x0[xi], inst.bounds, 2.0))
            assert float(inst.template.value(z[zi], x0[xi], inst.bounds)) == float(value)
            np.testing.assert_allclose(float(value), v_ref.item(), rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(np.asarray(grad).ravel(), g_ref.ravel()[zi], atol=1e-9)
            np.testing.assert_allclose(hess, 2.0 * h_ref[np.ix_(zi, zi)], rtol=1e-9, atol=1e-7)
            # The leaf depends on nothing outside its vehicles' blocks.
            others = np.setdiff1d(np.arange(z.size), zi)
            assert np.all(g_ref.ravel()[others] == 0)
