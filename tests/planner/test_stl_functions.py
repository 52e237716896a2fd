"""Function predicates on vector signals: registry, row convention, numpy vs CasADi."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from planner.stl import (
    FunctionRegistry,
    RegistryError,
    SignalShapeError,
    UnknownSignalError,
    parse,
)

BOXES = {  # axis-aligned boxes (lo, hi), ENU metres
    "pole1": (np.array([4.0, -1.0, 0.0]), np.array([6.0, 1.0, 10.0])),
    "nofly": (np.array([-2.0, 3.0, 0.0]), np.array([2.0, 5.0, 50.0])),
}


def _inside_np(args, signals):
    lo, hi = BOXES[args[1]]
    pos = signals[args[0]]
    return np.minimum(pos - lo, hi - pos).min(axis=1)


def _inside_ca(args, signals):
    lo, hi = BOXES[args[1]]
    pos = signals[args[0]]
    rows = pos.shape[0]
    margins = ca.fmin(pos - ca.repmat(ca.DM(lo).T, rows, 1), ca.repmat(ca.DM(hi).T, rows, 1) - pos)
    return ca.fmin(ca.fmin(margins[:, 0], margins[:, 1]), margins[:, 2])


def _dist_np(args, signals):
    return np.linalg.norm(signals[args[0]] - signals[args[1]], axis=1)


def _dist_ca(args, signals):
    diff = signals[args[0]] - signals[args[1]]
    return ca.sqrt(ca.sum2(diff**2))


def registry(calls: list | None = None) -> FunctionRegistry:
    reg = FunctionRegistry()

    def inside_ca(args, signals):
        if calls is not None:
            calls.append((args, signals[args[0]].shape))
        return _inside_ca(args, signals)

    reg.register("inside", 2, _inside_np, inside_ca, signal_args=(0,))
    reg.register(
        "outside",
        2,
        lambda a, s: -_inside_np(a, s),
        lambda a, s: -_inside_ca(a, s),
        signal_args=(0,),
    )
    reg.register("dist", 2, _dist_np, _dist_ca, signal_args=(0, 1))
    return reg


SPEC = """
eventually[1,3] inside(d1, pole1)
and always[0,4] (outside(d1, nofly) and outside(d2, nofly) and dist(d1, d2) >= 0.5)
and (dist(d1, d2) < 6 until[0,2] inside(d2, pole1))
"""


def _paths(n: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, n)[:, None]
    d1 = np.array([0.0, 0.0, 5.0]) + t * np.array([8.0, 0.0, 0.0]) + 0.3 * rng.normal(size=(n, 3))
    d2 = np.array([6.0, 4.0, 5.0]) + t * np.array([-1.0, -4.0, 0.0]) + 0.3 * rng.normal(size=(n, 3))
    return {"d1": d1, "d2": d2}


def _reference(x: dict[str, np.ndarray], dt: float) -> float:
    """SPEC at t = 0, written out with loops (dt = 0.5: steps [2,6], [0,8], [0,4])."""
    assert dt == 0.5

    def inside(name, box, t):
        lo, hi = BOXES[box]
        p = x[name][t]
        return min(min(p[i] - lo[i], hi[i] - p[i]) for i in range(3))

    def dist(t):
        return float(np.sqrt(sum((x["d1"][t][i] - x["d2"][t][i]) ** 2 for i in range(3))))

    reach = max(inside("d1", "pole1", t) for t in range(2, 7))
    safe = min(
        min(-inside("d1", "nofly", t), -inside("d2", "nofly", t), dist(t) - 0.5) for t in range(9)
    )
    until = max(
        min([inside("d2", "pole1", tp)] + [6 - dist(tpp) for tpp in range(tp)]) for tp in range(5)
    )
    return min(reach, safe, until)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_vector_signal_functions_exact_matches_loops(seed):
    phi = parse(SPEC, registry())
    x = _paths(12, seed)
    assert phi.horizon == 4.0 and phi.signal_names() == {"d1", "d2"}
    assert phi.robustness(x, 0.5) == pytest.approx(_reference(x, 0.5), abs=1e-12)


@pytest.mark.parametrize("kind", [ca.SX, ca.MX])
def test_vector_signal_functions_numpy_and_casadi_smooth_agree_with_gradient(kind):
    phi = parse(SPEC, registry())
    x = _paths(12, 3)
    syms = {name: kind.sym(name, *value.shape) for name, value in x.items()}
    expr = phi.smooth_robustness(syms, 0.5, 5.0)
    flat = ca.vertcat(ca.vec(syms["d1"]), ca.vec(syms["d2"]))
    values = np.concatenate([x["d1"].ravel(order="F"), x["d2"].ravel(order="F")])
    fun = ca.Function("f", [flat], [expr, ca.gradient(expr, flat)])
    value, grad = fun(values)
    expected = phi.smooth_robustness(x, 0.5, 5.0)
    assert float(value) == pytest.approx(expected, rel=1e-9, abs=1e-9)
    assert abs(expected - phi.robustness(x, 0.5)) <= phi.smooth_error_bound(5.0, 0.5)

    def numeric(v):
        d1 = v[:36].reshape(3, 12).T
        d2 = v[36:].reshape(3, 12).T
        return phi.smooth_robustness({"d1": d1, "d2": d2}, 0.5, 5.0)

    h = 1e-6
    fd = np.array(
        [(numeric(values + h * e) - numeric(values - h * e)) / (2 * h) for e in np.eye(values.size)]
    )
    np.testing.assert_allclose(np.asarray(grad).ravel(), fd, rtol=1e-5, atol=1e-6)


def test_functions_get_only_the_needed_rows_and_shared_atoms_run_once():
    calls: list = []
    phi = parse(
        "always[0,2] inside(d1, pole1) and eventually[3,4] inside(d1, pole1)", registry(calls)
    )
    d1 = ca.SX.sym("d1", 400, 3)
    expr = phi.smooth_robustness({"d1": d1}, 1.0, 5.0)
    assert calls == [(("d1", "pole1"), (5, 3))]  # rows 0..4, one call for both clauses
    cols = set(ca.jacobian(expr, ca.vec(d1)).sparsity().get_col())
    assert cols == {row + 400 * axis for row in range(5) for axis in range(3)}


def test_function_errors_name_the_function_or_signal():
    reg = FunctionRegistry()
    reg.register("bad", 1, lambda a, s: np.zeros(3), lambda a, s: ca.DM.zeros(2, 2))
    reg.register("nan", 1, lambda a, s: np.full(len(s[a[0]]), np.nan), lambda a, s: None)
    reg.register("reads", 1, lambda a, s: s["ghost"], lambda a, s: s["ghost"])
    x = {"d1": np.zeros((6, 3))}
    with pytest.raises(
        SignalShapeError, match=r"'bad' \(numpy\) returned shape \(3,\), expected \(6,\)"
    ):
        parse("bad(d1)", reg).robustness(x, 1.0)
    with pytest.raises(
        SignalShapeError, match=r"'bad' \(CasADi\) returned shape \(2, 2\), expected \(1, 1\)"
    ):
        parse("bad(d1)", reg).smooth_robustness({"d1": ca.SX.sym("d1", 6, 3)}, 1.0, 5.0)
    with pytest.raises(SignalShapeError, match="'nan' returned non-finite"):
        parse("nan(d1)", reg).robustness(x, 1.0)
    with pytest.raises(UnknownSignalError, match="'ghost'"):
        parse("reads(d1)", reg).robustness(x, 1.0)
    with pytest.raises(UnknownSignalError, match="'ghost'"):
        parse("reads(d1)", reg).smooth_robustness({"d1": ca.SX.sym("d1", 6, 3)}, 1.0, 5.0)


def test_registry_rejects_bad_registrations():
    reg = registry()
    assert set(reg) == {"inside", "outside", "dist"} and len(reg) == 3 and "dist" in reg
    with pytest.raises(RegistryError, match="already registered"):
        reg.register("dist", 2, _dist_np, _dist_ca)
    with pytest.raises(RegistryError, match="reserved"):
        reg.register("always", 1, _dist_np, _dist_ca)
    with pytest.raises(RegistryError, match="not an identifier"):
        reg.register("2fast", 1, _dist_np, _dist_ca)
    with pytest.raises(RegistryError, match="arity"):
        reg.register("neg", -1, _dist_np, _dist_ca)
    with pytest.raises(RegistryError, match="signal_args"):
        reg.register("odd", 1, _dist_np, _dist_ca, signal_args=(1,))
    with pytest.raises(RegistryError, match="callable"):
        reg.register("nope", 1, _dist_np, None)


def test_weakest_reports_the_violated_function_and_its_time():
    phi = parse(SPEC, registry())
    x = _paths(12, 0)
    x["d2"][5] = x["d1"][5] + np.array([0.1, 0.0, 0.0])  # near miss at t = 2.5 s
    clauses = [clause.robustness(x, 0.5) for clause in phi.clauses]
    chain = phi.weakest(x, 0.5)
    assert chain[0].robustness == min(clauses) == clauses[2]
    assert chain[1].formula == phi.clauses[2]
    assert str(chain[-1].formula) == "inside(d2, pole1)"
    lo, hi = BOXES["pole1"]
    assert chain[-1].robustness == pytest.approx(
        np.minimum(x["d2"] - lo, hi - x["d2"])[chain[-1].step].min()
    )
    safety = phi.clauses[1].weakest(x, 0.5)
    assert str(safety[-1].formula) == "dist(d1, d2) >= 0.5"
    assert safety[-1].t_s == 2.5 and safety[-1].step == 5
    assert safety[-1].robustness == pytest.approx(0.1 - 0.5) == clauses[1]


def _docstring_block(marker: str) -> str:
    import textwrap

    import planner.stl

    doc = planner.stl.__doc__
    assert doc is not None
    lines = doc.split(marker, 1)[1].splitlines()[2:]
    block = []
    for line in lines:
        if line and not line.startswith("    "):
            break
        block.append(line)
    return textwrap.dedent("\n".join(block))


def test_package_docstring_usage_example_runs():
    namespace: dict = {}
    exec(_docstring_block("Usage::"), namespace)
    phi, signals = namespace["phi"], namespace["signals"]
    assert phi.horizon == 5.0
    assert abs(phi.smooth_robustness(signals, 0.1, 50) - phi.robustness(signals, 0.1)) <= (
        phi.smooth_error_bound(50, 0.1)
    )


def test_package_docstring_syntax_examples_parse_and_round_trip():
    reg = registry()
    examples = [line.split("#")[0].strip() for line in _docstring_block("Examples::").splitlines()]
    examples = [text for text in examples if text]
    assert len(examples) == 5
    for text in examples:
        phi = parse(text, reg)
        assert parse(str(phi), reg) == phi
