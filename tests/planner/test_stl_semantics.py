"""Exact and smooth STL robustness against a naive reference written from docs/stl.md, "Semantics".

The reference below loops over t, t' and t'' exactly as the definitions read; it shares no code
with planner.stl (it walks the node classes only).
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from planner.stl import (
    Always,
    And,
    ArithOp,
    BinOp,
    BoolConst,
    CmpOp,
    Comparison,
    Const,
    EvaluationError,
    Eventually,
    Formula,
    Implies,
    Neg,
    Not,
    Or,
    SamplingError,
    Signal,
    SignalShapeError,
    TraceLengthError,
    UnknownSignalError,
    Until,
    explanation,
    interval_steps,
    parse,
)
from planner.stl.exact import until_unbounded

SIGNALS = ("a", "b", "c")
INF = math.inf

# --------------------------------------------------------------------------- naive reference


def ref_steps(start_s: float, end_s: float, dt: float) -> tuple[int, int]:
    # The strategies only draw bounds and dt that are exact binary fractions, so plain
    # ceil/floor are exact here.
    return math.ceil(start_s / dt), math.floor(end_s / dt)


def ref_horizon(node: Formula, dt: float) -> int:
    if isinstance(node, Always | Eventually):
        return ref_steps(node.start_s, node.end_s, dt)[1] + ref_horizon(node.child, dt)
    if isinstance(node, Until):
        tb = ref_steps(node.start_s, node.end_s, dt)[1]
        return tb + max(ref_horizon(node.lhs, dt), ref_horizon(node.rhs, dt))
    return max((ref_horizon(child, dt) for child in node.children), default=0)


def ref_expr(node, x: dict[str, np.ndarray], t: int) -> float:
    if isinstance(node, Const):
        return node.value
    if isinstance(node, Signal):
        return float(x[node.name][t])
    if isinstance(node, Neg):
        return -ref_expr(node.operand, x, t)
    lhs, rhs = ref_expr(node.lhs, x, t), ref_expr(node.rhs, x, t)
    if node.op is ArithOp.ADD:
        return lhs + rhs
    if node.op is ArithOp.SUB:
        return lhs - rhs
    if node.op is ArithOp.MUL:
        return lhs * rhs
    return lhs / rhs


def ref_rho(node: Formula, x: dict[str, np.ndarray], dt: float, t: int, memo: dict) -> float:
    key = (id(node), t)
    if key in memo:
        return memo[key]
    if isinstance(node, BoolConst):
        value = INF if node.value else -INF
    elif isinstance(node, Comparison):
        lhs, rhs = ref_expr(node.lhs, x, t), ref_expr(node.rhs, x, t)
        value = lhs - rhs if node.op in (CmpOp.GE, CmpOp.GT) else rhs - lhs
    elif isinstance(node, Not):
        value = -ref_rho(node.child, x, dt, t, memo)
    elif isinstance(node, And):
        value = min(ref_rho(c, x, dt, t, memo) for c in node.operands)
    elif isinstance(node, Or):
        value = max(ref_rho(c, x, dt, t, memo) for c in node.operands)
    elif isinstance(node, Implies):
        value = max(-ref_rho(node.lhs, x, dt, t, memo), ref_rho(node.rhs, x, dt, t, memo))
    elif isinstance(node, Always):
        ta, tb = ref_steps(node.start_s, node.end_s, dt)
        value = INF
        for tp in range(t + ta, t + tb + 1):
            value = min(value, ref_rho(node.child, x, dt, tp, memo))
    elif isinstance(node, Eventually):
        ta, tb = ref_steps(node.start_s, node.end_s, dt)
        value = -INF
        for tp in range(t + ta, t + tb + 1):
            value = max(value, ref_rho(node.child, x, dt, tp, memo))
    elif isinstance(node, Until):
        ta, tb = ref_steps(node.start_s, node.end_s, dt)
        value = -INF
        for tp in range(t + ta, t + tb + 1):
            inner = INF  # min over the empty range [t, t) is +inf
            for tpp in range(t, tp):
                inner = min(inner, ref_rho(node.lhs, x, dt, tpp, memo))
            value = max(value, min(ref_rho(node.rhs, x, dt, tp, memo), inner))
    else:
        raise AssertionError(f"reference does not know {type(node).__name__}")
    memo[key] = value
    return value


def ref_trace(node: Formula, x: dict[str, np.ndarray], dt: float) -> np.ndarray:
    n = len(next(iter(x.values())))
    memo: dict = {}
    return np.array([ref_rho(node, x, dt, t, memo) for t in range(n - ref_horizon(node, dt))])


# --------------------------------------------------------------------------- strategies

DTS = (0.25, 0.5, 1.0)


@st.composite
def exprs(draw, depth: int = 2):
    leaf = st.one_of(
        st.sampled_from(SIGNALS).map(Signal),
        st.integers(-4, 4).map(lambda v: Const(v / 2)),
    )
    if depth == 0:
        return draw(leaf)
    kind = draw(st.sampled_from(["leaf", "leaf", "neg", "add", "sub", "mul", "div"]))
    if kind == "leaf":
        return draw(leaf)
    if kind == "neg":
        return Neg(draw(exprs(depth - 1)))
    if kind == "div":  # divide by a non-zero constant only: the reference must stay finite
        return BinOp(ArithOp.DIV, draw(exprs(depth - 1)), Const(draw(st.sampled_from([2, -4]))))
    op = {"add": ArithOp.ADD, "sub": ArithOp.SUB, "mul": ArithOp.MUL}[kind]
    return BinOp(op, draw(exprs(depth - 1)), draw(exprs(depth - 1)))


@st.composite
def atoms(draw, arithmetic: bool = True):
    if draw(st.integers(0, 9)) == 0:
        return BoolConst(draw(st.booleans()))
    lhs = draw(exprs(1)) if arithmetic else Signal(draw(st.sampled_from(SIGNALS)))
    rhs = Const(draw(st.integers(-4, 4)) / 2)
    return Comparison(lhs, draw(st.sampled_from(list(CmpOp))), rhs)


@st.composite
def intervals(draw, dt: float):
    """(a, b) in seconds covering steps ta..tb; offset bounds (not multiples of dt) included."""
    ta = draw(st.integers(0, 3))
    tb = ta + draw(st.integers(0, 3))
    start_s = ta * dt - (draw(st.sampled_from([0.0, 0.5])) * dt if ta > 0 else 0.0)
    end_s = tb * dt + draw(st.sampled_from([0.0, 0.5])) * dt
    if start_s > end_s:  # only possible when ta == tb with offsets; keep zero width
        start_s = end_s = tb * dt
    return start_s, end_s


@st.composite
def formulas(draw, dt: float, depth: int = 4, arithmetic: bool = True):
    if depth == 0:
        return draw(atoms(arithmetic))
    kind = draw(
        st.sampled_from(["atom", "not", "and", "or", "implies", "always", "eventually", "until"])
    )
    sub = formulas(dt, depth - 1, arithmetic)
    if kind == "atom":
        return draw(atoms(arithmetic))
    if kind == "not":
        return Not(draw(sub))
    if kind in ("and", "or"):
        kids = tuple(draw(st.lists(sub, min_size=2, max_size=3)))
        return And(kids) if kind == "and" else Or(kids)
    if kind == "implies":
        return Implies(draw(sub), draw(sub))
    a, b = draw(intervals(dt))
    if kind == "always":
        return Always(draw(sub), a, b)
    if kind == "eventually":
        return Eventually(draw(sub), a, b)
    return Until(draw(sub), draw(sub), a, b)


@st.composite
def cases(draw, depth: int = 4, arithmetic: bool = True, extra: int = 6):
    """(formula, signals, dt) with a trace at least as long as the horizon needs."""
    dt = draw(st.sampled_from(DTS))
    phi = draw(formulas(dt, depth, arithmetic))
    n = ref_horizon(phi, dt) + 1 + draw(st.integers(0, extra))
    value = st.one_of(st.integers(-3, 3).map(float), st.floats(-5, 5, allow_nan=False))
    x = {name: np.array(draw(st.lists(value, min_size=n, max_size=n))) for name in SIGNALS}
    return phi, x, dt


SETTINGS = settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

# --------------------------------------------------------------------------- exact


@SETTINGS
@given(cases())
@pytest.mark.slow
def test_exact_trace_equals_naive_definition(case):
    phi, x, dt = case
    expected = ref_trace(phi, x, dt)
    got = phi.robustness_trace(x, dt)
    assert got.shape == expected.shape
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    assert phi.robustness(x, dt) == pytest.approx(expected[0], abs=1e-12) or (
        math.isinf(expected[0]) and phi.robustness(x, dt) == expected[0]
    )


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.integers(0, 6),
    st.integers(0, 8),
    st.lists(st.integers(-3, 3), min_size=40, max_size=40),
    st.lists(st.integers(-3, 3), min_size=40, max_size=40),
)
def test_until_with_wide_and_offset_windows_equals_definition(ta, width, p, q):
    phi = Until(Signal("a") >= 0, Signal("b") >= 0, ta * 0.5, (ta + width) * 0.5)
    x = {"a": np.array(p, float), "b": np.array(q, float)}
    np.testing.assert_array_equal(phi.robustness_trace(x, 0.5), ref_trace(phi, x, 0.5))


def test_unbounded_until_scan_matches_backward_recurrence_on_long_traces():
    rng = np.random.default_rng(7)
    for m in (1, 2, 3, 5, 8, 1000, 4097):
        p = rng.integers(-50, 50, m).astype(float)
        q = rng.integers(-50, 50, m).astype(float)
        expected = np.empty(m)
        carry = -INF
        for s in range(m - 1, -1, -1):  # V(s) = max(q(s), min(p(s), V(s+1)))
            carry = max(q[s], min(p[s], carry))
            expected[s] = carry
        np.testing.assert_array_equal(until_unbounded(p, q), expected)


def test_trace_covers_the_steps_where_the_horizon_fits():
    phi = parse("always[0,2] (a >= 0) and eventually[1,3] (b >= 0)")
    x = {"a": np.arange(10.0), "b": np.arange(10.0) - 5}
    trace = phi.robustness_trace(x, 1.0)
    assert phi.horizon_steps(1.0) == 3
    assert trace.shape == (7,)
    # min(a over [t, t+2], b over [t+1, t+3]) = min(t, t - 2)
    np.testing.assert_array_equal(trace, np.arange(7.0) - 2)


def test_interval_steps_tolerate_floating_point():
    assert interval_steps(0.0, 0.3, 0.1) == (0, 3)
    assert interval_steps(0.3, 0.7, 0.1) == (3, 7)
    assert interval_steps(0.15, 0.25, 0.1) == (2, 2)
    assert interval_steps(2.0, 4.0, 0.01) == (200, 400)
    phi = parse("always[0,0.3] (a >= 0)")
    assert phi.horizon_steps(0.1) == 3
    x = {"a": np.array([5.0, 4.0, 3.0, 2.0, 1.0])}
    np.testing.assert_array_equal(phi.robustness_trace(x, 0.1), [2.0, 1.0])


def test_interval_without_sample_is_a_sampling_error():
    phi = parse("eventually[0.15,0.18] (a >= 0)")
    with pytest.raises(SamplingError, match=r"\[0.15,0.18\].*dt=0.1"):
        phi.robustness({"a": np.zeros(10)}, 0.1)
    with pytest.raises(SamplingError, match="dt"):
        phi.robustness({"a": np.zeros(10)}, 0.0)


def test_short_trace_names_both_lengths():
    phi = parse("always[0,5] (a >= 0.3) and eventually[2,4] (b < 1)")
    x = {"a": np.zeros(5), "b": np.zeros(5)}
    with pytest.raises(TraceLengthError, match="needs 6 samples, the trace has 5") as info:
        phi.robustness(x, 1.0)
    assert (info.value.needed, info.value.given) == (6, 5)
    assert isinstance(info.value, ValueError)
    with pytest.raises(TraceLengthError):
        phi.smooth_robustness(x, 1.0, 10.0)


def test_unknown_signal_is_named():
    phi = parse("always[0,1] (speed >= 0.3)")
    with pytest.raises(UnknownSignalError, match="'speed'") as info:
        phi.robustness({"a": np.zeros(5)}, 1.0)
    assert info.value.name == "speed"
    with pytest.raises(UnknownSignalError, match="'speed'"):
        phi.smooth_robustness({"a": np.zeros(5)}, 1.0, 5.0)
    with pytest.raises(UnknownSignalError, match="'speed'"):
        phi.smooth_robustness({"a": ca.SX.sym("a", 5)}, 1.0, 5.0)


def test_bad_signals_are_reported():
    phi = parse("a >= 0")
    with pytest.raises(SignalShapeError, match="'b' has 4 samples but 'a' has 5"):
        phi.robustness({"a": np.zeros(5), "b": np.zeros(4)}, 1.0)
    with pytest.raises(SignalShapeError, match="'a' is not finite at sample 2"):
        phi.robustness({"a": np.array([0.0, 1.0, np.nan])}, 1.0)
    with pytest.raises(SignalShapeError, match="scalar signal"):
        phi.robustness({"a": np.zeros((5, 3))}, 1.0)
    with pytest.raises(SignalShapeError, match="no signals"):
        phi.robustness({}, 1.0)


def test_weakest_follows_the_deciding_operands():
    phi = parse("always[0,4] (a >= 0) and eventually[0,2] (b >= 1) and (c >= 0 until[1,3] b >= 2)")
    x = {
        "a": np.array([3.0, 2.0, 0.5, 2.0, 3.0, 3.0, 3.0, 3.0]),
        "b": np.array([0.0, 1.2, 1.4, 1.0, 0.0, 0.0, 0.0, 0.0]),
        "c": np.array([5.0, 5.0, 5.0, 5.0, 5.0, 5.0, 5.0, 5.0]),
    }
    chain = phi.weakest(x, 1.0)
    assert chain[0].formula == phi and chain[0].robustness == phi.robustness(x, 1.0)
    # clauses: always -> 0.5, eventually -> 0.4, until -> max over t' in 1..3 of b - 2 = -0.6
    assert [round(c.robustness(x, 1.0), 12) for c in phi.clauses] == [0.5, 0.4, -0.6]
    assert chain[1].formula == phi.clauses[2]
    assert chain[-1].formula == parse("b >= 2")
    assert chain[-1].step == 2 and chain[-1].t_s == 2.0
    assert chain[-1].robustness == pytest.approx(-0.6)
    # the phi side of an until decides when it fails first
    psi = parse("a >= 2.5 until[2,3] b >= 1")
    last = psi.weakest(x, 1.0)[-1]
    assert last.formula == parse("a >= 2.5") and last.step == 1
    assert last.robustness == pytest.approx(-0.5) == psi.robustness(x, 1.0)


@SETTINGS
@given(cases(depth=3))
@pytest.mark.slow
def test_weakest_chain_ends_at_an_atom_with_the_root_value(case):
    phi, x, dt = case
    chain = phi.weakest(x, dt)
    root = phi.robustness(x, dt)
    assert chain[0].robustness == root
    assert not chain[-1].formula.children
    for link in chain:
        assert abs(link.robustness) == abs(root)
        expected = ref_rho(link.formula, x, dt, link.step, {})
        assert link.robustness == pytest.approx(expected, abs=1e-12) or link.robustness == expected


@SETTINGS
@given(cases(depth=3))
@pytest.mark.slow
def test_the_explanation_has_the_root_value_in_its_own_sign(case):
    # The reported reason for a value is never one that passes where the formula fails:
    # the explaining witness evaluates (by the brute-force semantics) to the root's value.
    phi, x, dt = case
    chain = phi.weakest(x, dt)
    shown = explanation(chain)
    assert shown and shown == chain[: len(shown)]
    root = phi.robustness(x, dt)
    last = shown[-1]
    expected = ref_rho(last.formula, x, dt, last.step, {})
    assert last.robustness == pytest.approx(root, abs=1e-12) or last.robustness == root
    assert expected == pytest.approx(root, abs=1e-12) or expected == root
    if not any(isinstance(w.formula, Not | Implies) for w in chain):
        assert shown == chain  # nothing flips: the deciding atom itself


def test_a_failing_negation_is_explained_by_itself_not_by_the_atom_that_passes():
    # issue 39: `always not (inside(d1, bay) and inside(d2, bay))` failed at -0.00088 and was
    # explained as `inside(d1, bay) = 0.00088`, a value that passes.
    phi = parse("always[0,2] not ((a >= 0) and (b >= 0))")
    x = {"a": np.array([-1.0, 0.5, -1.0, -1.0]), "b": np.array([1.0, 0.3, -1.0, -1.0])}
    chain = phi.weakest(x, 1.0)
    assert chain[-1].formula == parse("b >= 0") and chain[-1].robustness == pytest.approx(0.3)
    last = explanation(chain)[-1]
    assert last.formula == parse("not (a >= 0 and b >= 0)")  # both signals named
    assert last.robustness == pytest.approx(-0.3) and last.step == 1
    # a negated atom alone: `not (a >= 0)` at its own (negative) value
    neg = explanation(parse("eventually[0,1] not (a >= -2)").weakest(x, 1.0))[-1]
    assert neg.formula == parse("not (a >= -2)") and neg.robustness == pytest.approx(-1.0)
    assert neg.step == 0  # a = -1 there: the least far above -2


# --------------------------------------------------------------------------- smooth


@SETTINGS
@given(cases(depth=3), st.sampled_from([0.5, 2.0, 10.0, 100.0]))
@pytest.mark.slow
def test_smooth_is_within_documented_bound_of_exact(case, k):
    phi, x, dt = case
    exact = phi.robustness(x, dt)
    smooth = phi.smooth_robustness(x, dt, k)
    bound = phi.smooth_error_bound(k, dt)
    if math.isinf(exact):
        assert smooth == exact
    else:
        assert abs(smooth - exact) <= bound + 1e-9 * max(1.0, abs(exact))


def test_smooth_bound_is_attained_order_and_shrinks_with_k():
    # Equal operands make LSE hit its bound exactly: and of m equal values = v - log(m)/k.
    phi = parse("a >= 0 and a >= 0 and b >= 0")
    x = {"a": np.array([1.0]), "b": np.array([1.0])}
    for k in (1.0, 10.0, 100.0):
        assert phi.smooth_robustness(x, 1.0, k) == pytest.approx(1.0 - math.log(3) / k)
        assert phi.smooth_error_bound(k, 1.0) == pytest.approx(math.log(3) / k)
    until = parse("a >= 0 until[1,3] b >= 0")
    assert until.smooth_error_bound(2.0, 1.0) == pytest.approx((math.log(3) + math.log(4)) / 2)


def _symbolic(x: dict[str, np.ndarray], kind=ca.SX):
    syms = {name: kind.sym(name, len(values)) for name, values in x.items()}
    return syms, ca.vertcat(*syms.values()), np.concatenate(list(x.values()))


@SETTINGS
@given(cases(depth=3), st.sampled_from([1.0, 10.0, 100.0]))
@pytest.mark.slow
def test_numpy_and_casadi_smooth_agree(case, k):
    phi, x, dt = case
    syms, flat, values = _symbolic(x)
    expr = phi.smooth_robustness(syms, dt, k)
    got = float(ca.Function("rho", [flat], [expr])(values))
    expected = phi.smooth_robustness(x, dt, k)
    if math.isinf(expected):
        assert got == expected
    else:
        assert got == pytest.approx(expected, rel=1e-9, abs=1e-9)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases(depth=3, extra=2), st.sampled_from([1.0, 4.0]))
def test_casadi_gradient_matches_finite_differences(case, k):
    phi, x, dt = case
    syms, flat, values = _symbolic(x)
    expr = phi.smooth_robustness(syms, dt, k)
    if not isinstance(expr, ca.SX) or not ca.depends_on(expr, flat):
        return  # constant formulas (true/false folded) have no gradient to check
    grad = ca.Function("g", [flat], [ca.gradient(expr, flat)])
    analytic = np.asarray(grad(values)).ravel()
    names = list(x)
    sizes = np.cumsum([0] + [len(x[name]) for name in names])

    def smooth_at(v: np.ndarray) -> float:
        sig = {name: v[sizes[i] : sizes[i + 1]] for i, name in enumerate(names)}
        return phi.smooth_robustness(sig, dt, k)

    h = 1e-6
    numeric = np.empty_like(values)
    for i in range(values.size):
        up, down = values.copy(), values.copy()
        up[i] += h
        down[i] -= h
        numeric[i] = (smooth_at(up) - smooth_at(down)) / (2 * h)
    np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-5)


def test_mx_signals_give_the_same_value_as_sx():
    phi = parse("always[0,2] (a >= 0 until[0,2] b > 1) or eventually[1,3] (a - b < 0.5)")
    rng = np.random.default_rng(3)
    x = {"a": rng.normal(size=9), "b": rng.normal(size=9)}
    for kind in (ca.SX, ca.MX):
        syms, flat, values = _symbolic(x, kind)
        expr = phi.smooth_robustness(syms, 1.0, 8.0)
        assert isinstance(expr, kind)
        got = float(ca.Function("rho", [flat], [expr])(values))
        assert got == pytest.approx(phi.smooth_robustness(x, 1.0, 8.0), rel=1e-12)


def test_smooth_graph_holds_only_the_needed_steps():
    phi = parse("eventually[0,0.05] (always[0.02,0.03] (a >= 0))")
    sizes = []
    for n in (100, 10_000):
        a = ca.SX.sym("a", n)
        expr = phi.smooth_robustness({"a": a}, 0.01, 10.0)
        jac = ca.jacobian(expr, a).sparsity()
        assert set(jac.get_col()) == set(range(2, 9))  # steps 0+2 .. 5+3
        sizes.append(ca.Function("f", [a], [expr]).n_instructions())
    assert sizes[0] == sizes[1]


@pytest.mark.parametrize("rows", [2, 5, 17])
@pytest.mark.parametrize("width", [2, 3, 7, 16])
def test_block_window_lse_equals_direct_lse_in_both_back_ends(rows, width):
    from planner.stl.smooth import CasadiOps, NumpyOps, window_lse

    rng = np.random.default_rng(rows * 100 + width)
    y = 30.0 * rng.normal(size=rows + width - 1)
    direct = np.array([np.log(np.sum(np.exp(y[i : i + width] - 50))) + 50 for i in range(rows)])
    np.testing.assert_allclose(window_lse(NumpyOps(), y, width, rows), direct, rtol=1e-13)
    sym = ca.SX.sym("y", y.size)
    expr = window_lse(CasadiOps(), sym, width, rows)
    got = np.asarray(ca.Function("w", [sym], [expr])(y)).ravel()
    np.testing.assert_allclose(got, direct, rtol=1e-13)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases(depth=3), st.sampled_from([2.0, 20.0]))
@pytest.mark.slow
def test_smooth_trace_matches_per_step_smooth_values_in_both_back_ends(case, k):
    phi, x, dt = case
    horizon = ref_horizon(phi, dt)
    n = len(x["a"])
    trace = phi.smooth_robustness_trace(x, dt, k)
    assert trace.shape == (n - horizon,)
    for step in range(n - horizon):
        shifted = {name: values[step:] for name, values in x.items()}
        expected = phi.smooth_robustness(shifted, dt, k)
        assert trace[step] == pytest.approx(expected, rel=1e-9, abs=1e-9) or trace[step] == expected
    syms, flat, values = _symbolic(x)
    column = phi.smooth_robustness_trace(syms, dt, k, 0, n - horizon - 1)
    assert column.shape == (n - horizon, 1)
    got = np.asarray(ca.Function("tr", [flat], [column])(values)).ravel()
    np.testing.assert_allclose(got, trace, rtol=1e-9, atol=1e-9)


def test_smooth_trace_checks_its_step_range():
    phi = parse("always[0,2] (a >= 0)")
    x = {"a": np.arange(6.0)}
    assert phi.smooth_robustness_trace(x, 1.0, 10.0, 1, 3).shape == (3,)
    with pytest.raises(TraceLengthError, match="needs 7 samples, the trace has 6"):
        phi.smooth_robustness_trace(x, 1.0, 10.0, 0, 4)
    with pytest.raises(EvaluationError, match="first <= last"):
        phi.smooth_robustness_trace(x, 1.0, 10.0, 3, 1)
