"""Long ``eventually`` windows in chunks (:func:`planner.solve.leaves.chunks_of`): the chunks partition
the window, the NLP's leaf is the smooth value of the whole window, its derivatives are
CasADi's own, its Hessian is banded instead of dense, and the mission plans."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from planner.optimize import conjunction, make_model, plan
from planner.scenario import parse_scenario
from planner.solve import leaves as leaves_mod
from planner.solve.leaves import CHUNK_ABOVE_SEGMENTS, CHUNK_SEGMENTS, chunks_of
from planner.solve.nlp import NlpBuilder
from planner.solve.nlp_solvers import mumps_order
from planner.solve.plan_check import initial_states
from planner.spec.predicates import build_registry
from planner.stl import Eventually, parse

# Two drones, 40 one-second segments of minimum-jerk primitives: "some time in the first
# 37 s, hover 2 s in the goal" is a window of 38 segments, chunked; "within 10 s, reach the
# start box" is not.
SCENARIO = {
    "name": "chunks",
    "origin": {"lat": 47.397742, "lon": 8.545594, "alt": 488.0},
    "workspace": {"min": [0, 0, 0.5], "max": [20, 10, 3]},
    "regions": {
        "goal1": {"kind": "goal", "min": [15, 7, 1], "max": [16, 8, 2]},
        "goal2": {"kind": "goal", "min": [2, 7, 1], "max": [3, 8, 2]},
        "pad": {"kind": "goal", "min": [0.5, 0.5, 0.5], "max": [2.5, 4, 1.5]},
        "obstacle": {"kind": "obstacle", "min": [8, 0, 0], "max": [10, 6, 3]},
    },
    "limits": {"v_max_m_s": 2, "a_max_m_s2": 1},
    "vehicles": [{"name": "d1", "start": [1, 1, 1]}, {"name": "d2", "start": [1, 3, 1]}],
    "timing": {"horizon_s": 40, "segment_s": 1, "Ts_s": 0.5, "check_dt_s": 0.25},
    "separation_m": 0.5,
    "epsilon": 0.01,
    "model": "minimum_jerk",
    "spec": [
        {"formula": "eventually[0, 37] always[0, 2] inside(d1, goal1)"},
        {"formula": "eventually[0, 37] always[0, 2] inside(d2, goal2)"},
        {"formula": "eventually[0, 10] inside(d2, pad)"},
        {"each": "d in all", "formula": "always[0, 40] outside(d, obstacle)"},
        {"each": "(a, b) in pairs(all)", "formula": "always[0, 40] dist(a, b) >= 0.5"},
    ],
}


def _builder(problem):
    formula = conjunction(list(problem.formulas))
    model = make_model(problem)
    b = NlpBuilder(problem, model, formula)
    b.add_spec_constraints().add_dynamics_constraints().add_robustness_cost().add_bounds()
    return b, model


@pytest.mark.parametrize(
    ("a", "b", "step", "per_segment"),
    [(0, 37, 0, 1), (3, 60, 0, 1), (0, 298, 0, 5), (2, 150, 7, 4), (0, 24, 0, 1)],
)
def test_chunks_partition_the_window_on_chunk_boundaries(a, b, step, per_segment) -> None:
    psi = parse("always[0, 2] (x(d1) >= 1)", build_registry(parse_scenario(SCENARIO)))
    leaf = Eventually(psi, float(a), float(b))
    got = chunks_of(leaf, step, 1.0, per_segment)
    if b - a + 1 <= CHUNK_ABOVE_SEGMENTS * per_segment:  # one vehicle (d1)
        assert got == []  # short windows stay whole
        return
    length = CHUNK_SEGMENTS * per_segment
    covered = []
    for chunk, first in got:
        assert isinstance(chunk, Eventually) and chunk.child == psi and chunk.start_s == 0
        lo, hi = chunk.steps(1.0)
        covered.extend(range(first + lo, first + hi + 1))
        assert hi - lo + 1 <= length
        assert first == step + a or first % length == 0  # inner chunks start on a boundary
    assert covered == list(range(step + a, step + b + 1))  # every window once, in order
    assert chunks_of(psi, step, 1.0, per_segment) == []  # only eventually is chunked


@pytest.mark.parametrize("per_segment", [1, 2])
def test_a_window_over_several_vehicles_is_chunked_sooner(per_segment) -> None:
    """The whole window's Hessian grows with the square of segments x vehicles, so the
    threshold is on their product: a 12-segment window is whole for one vehicle, chunked
    for the ``or`` of three (the allocation pattern, "some drone inspects the pole")."""
    scenario = {**SCENARIO, "vehicles": [*SCENARIO["vehicles"], {"name": "d3", "start": [1, 5, 1]}]}
    registry = build_registry(parse_scenario(scenario))
    one = parse("always[0, 2] inside(d1, goal1)", registry)
    three = parse(
        "always[0, 2] inside(d1, goal1) or always[0, 2] inside(d2, goal1) or "
        "always[0, 2] inside(d3, goal1)",
        registry,
    )
    window = 12 * per_segment - 1  # 12 segments of steps
    assert 12 <= CHUNK_ABOVE_SEGMENTS < 36
    assert chunks_of(Eventually(one, 0.0, float(window)), 0, 1.0, per_segment) == []
    chunks = chunks_of(Eventually(three, 0.0, float(window)), 0, 1.0, per_segment)
    assert len(chunks) == 3 and all(c.child == three for c, _first in chunks)


@pytest.mark.slow
def test_a_chunked_leaf_is_the_smooth_value_of_its_whole_window_with_casadis_derivatives() -> None:
    problem = parse_scenario(SCENARIO)
    b, model = _builder(problem)
    assert [len(c) for c in b.chunks] == [10, 10, 0]  # 75 windows in 4-segment chunks
    k = 40.0
    nlp, derivs, leaf_fn, chunk_fn = b.assemble(k)
    x0s = initial_states(problem, model)
    rng = np.random.default_rng(3)
    # every leaf row's weight on r drawn in [0, 1] (1: ">= r"; 0: settled, planner.optimize)
    p = b.parameters(x0s)
    weights = p[b.n_x0 :]
    assert np.all(weights == 1.0)
    weights[:] = rng.uniform(size=weights.size)
    nd = model.n_dec * 3
    # A point: random decisions, their lifted positions, the chunks' values, some r.
    z = rng.normal(scale=1.0, size=b.n_z)
    pos = []
    for i, x0 in enumerate(x0s):
        Zi = z[i * nd : (i + 1) * nd].reshape((model.n_dec, 3), order="F")
        pos.append(np.asarray(model.Mp) @ Zi + np.asarray(model.Np) @ x0)
    lifted = [q[b.used].reshape(-1, order="F") for q in pos]
    w = np.concatenate([z, *lifted, np.zeros(b.n_s), [0.1]])
    w[-1 - b.n_s : -1] = np.asarray(chunk_fn(w, p)).ravel()
    # Reference: each smooth leaf's robustness on the whole window, written out with the
    # smooth predicates the NLP uses (CasADi symbols, the registry at its sharpness).
    smooth_registry = build_registry(problem, b.k_pred)
    signals = {v.name: q for v, q in zip(problem.vehicles, pos, strict=True)}
    values = np.asarray(leaf_fn(w, p)).ravel()[-len(b.smooth_items) :]
    for (leaf, st), value in zip(b.smooth_items, values, strict=True):
        hz = leaf.horizon_steps(b.dt)
        sym = {nm: ca.SX.sym(nm, hz + 1, 3) for nm in signals}
        written = parse(str(leaf), smooth_registry).smooth_robustness(sym, b.dt, k)
        ref_fn = ca.Function("ref", list(sym.values()), [written])
        ref = float(ref_fn(*[q[st : st + hz + 1] for q in signals.values()]))
        np.testing.assert_allclose(value, ref, rtol=1e-10, atol=1e-10)
    # The chunk rows hold at their values, and the leaf rows equal value - weight * r.
    g = np.asarray(ca.Function("g", [nlp["x"], nlp["p"]], [nlp["g"]])(w, p)).ravel()
    n_items = len(b.smooth_items)
    np.testing.assert_allclose(g[len(g) - b.n_s :], 0.0, atol=1e-12)
    smooth_weights = weights[weights.size - n_items :]
    np.testing.assert_allclose(
        g[b.n_sx : b.n_sx + n_items], values - smooth_weights * w[-1], atol=1e-10
    )
    direct = np.asarray(leaf_fn(w, p)).ravel()[: b.n_sx - b.n_lin]
    assert direct.size  # the row-wise leaves (the workspace box) are weighted too
    np.testing.assert_allclose(
        g[b.n_lin : b.n_sx], direct - weights[: direct.size] * w[-1], atol=1e-10
    )
    # Derivatives against CasADi's AD of the assembled rows.
    wm, pm = nlp["x"], nlp["p"]
    jac_ref = ca.Function("j", [wm, pm], [ca.jacobian(nlp["g"], wm)])
    np.testing.assert_allclose(
        np.asarray(ca.densify(derivs["jac_g"](w, p)[1])),
        np.asarray(ca.densify(jac_ref(w, p))),
        rtol=1e-9,
        atol=1e-9,
    )
    lam_f = ca.MX.sym("lam_f")
    lam_g = ca.MX.sym("lam_g", nlp["g"].shape[0])
    lag = lam_f * nlp["f"] + ca.dot(lam_g, nlp["g"])
    hess_ref = ca.Function("h", [wm, pm, lam_f, lam_g], [ca.triu(ca.hessian(lag, wm)[0])])
    lam = rng.normal(size=nlp["g"].shape[0])
    # The smooth leaves live in Z and S (the lifted positions carry the row-wise leaves,
    # whose separation rows enter the Hessian flat by design: nlp_solvers.derivatives).
    keep = np.r_[0 : b.n_z, b.n_w - 1 - b.n_s : b.n_w]
    got = np.asarray(ca.densify(derivs["hess_lag"](w, p, 1.0, lam)))[np.ix_(keep, keep)]
    ref = np.asarray(ca.densify(hess_ref(w, p, 1.0, lam)))[np.ix_(keep, keep)]
    np.testing.assert_allclose(got, ref, rtol=1e-8, atol=1e-8)
    assert np.count_nonzero(got[-1 - b.n_s : -1, -1 - b.n_s : -1])  # the chunks' LSE


def _z_block_nonzeros(hess_fn, n_vehicle_z: int) -> int:
    sp = hess_fn.sparsity_out(0)
    rows, cols = np.asarray(sp.get_triplet()[0]), np.asarray(sp.get_triplet()[1])
    first = (rows < n_vehicle_z) & (cols < n_vehicle_z)  # d1's decisions
    return int(np.count_nonzero(first))


@pytest.mark.slow
def test_chunks_make_the_leaf_hessian_banded_not_dense(monkeypatch) -> None:
    problem = parse_scenario(SCENARIO)
    b, model = _builder(problem)
    per_vehicle = model.n_dec * 3
    chunked = _z_block_nonzeros(b.assemble(40.0)[1]["hess_lag"], per_vehicle)
    monkeypatch.setattr(leaves_mod, "CHUNK_ABOVE_SEGMENTS", 10**6)
    whole, _ = _builder(problem)
    assert whole.n_s == 0
    dense = _z_block_nonzeros(whole.assemble(40.0)[1]["hess_lag"], per_vehicle)
    # the whole window couples (almost) every pair of d1's decisions
    assert dense > 0.9 * per_vehicle * (per_vehicle + 1) // 2
    assert chunked < dense / 3


def test_a_mission_with_long_windows_plans_in_chunks() -> None:
    problem = parse_scenario(SCENARIO)
    result = plan(problem)
    assert result.success, result.status
    assert result.stats is not None and result.stats.n_variables > result.stats.n_constraints / 50
    # the exact robustness (checked on dense samples) meets epsilon; each goal is visited
    # for the 2 s hover inside its box
    for name, box in (("d1", "goal1"), ("d2", "goal2")):
        reg = problem.region(box)
        tr = next(t for t in result.trajectories if t.name == name)
        t = np.arange(0.0, 40.0 + 1e-9, 0.5)
        pos = np.asarray(tr.position(t)).reshape(-1, 3)
        inside = np.all((pos >= np.asarray(reg.lo_enu_m)) & (pos <= np.asarray(reg.hi_enu_m)), 1)
        runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], inside, [0]]))))[::2]
        assert runs.size and runs.max() >= 5  # 2 s at 0.5 s: 5 samples


def test_chunked_nlps_factorise_with_qamd_whatever_the_fleet() -> None:
    """MUMPS's ordering: QAMD (6) for small fleets and for any NLP with chunked leaves (the
    12-drone line: 140 s for 3 iterations under METIS, 6.4 s for 11 under QAMD); MUMPS's own
    (7, METIS) for a large fleet without (reach-avoid N = 16)."""
    import dataclasses

    problem = parse_scenario(SCENARIO)
    fleet = dataclasses.replace(problem, vehicles=problem.vehicles * 6)  # 12 vehicles
    assert mumps_order(problem) == 6
    assert mumps_order(fleet) == 7
    assert mumps_order(fleet, chunked=True) == 6
    b, _model = _builder(problem)
    assert b.n_s > 0  # this scenario's long window is chunked
