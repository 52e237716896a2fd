"""STL parser: round trips, precedence, Python operators and every syntax error class."""

from __future__ import annotations

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
    Call,
    CmpOp,
    Comparison,
    Const,
    Eventually,
    FormulaError,
    FunctionRegistry,
    Implies,
    Neg,
    Not,
    Or,
    Predicate,
    Signal,
    SpecError,
    Until,
    parse,
)
from tests.planner.test_stl_semantics import DTS, exprs, formulas


def _registry() -> FunctionRegistry:
    registry = FunctionRegistry()
    registry.register(
        "dist",
        2,
        lambda args, s: np.linalg.norm(s[args[0]] - s[args[1]], axis=1),
        lambda args, s: None,
        signal_args=(0, 1),
    )
    registry.register("inside", 2, lambda args, s: None, lambda args, s: None, signal_args=(0,))
    registry.register("wind", 0, lambda args, s: None, lambda args, s: None)
    return registry


REGISTRY = _registry()
DIST = REGISTRY["dist"]
INSIDE = REGISTRY["inside"]


def a(name: str = "a") -> Signal:
    return Signal(name)


# --------------------------------------------------------------------------- round trips


@st.composite
def formulas_with_functions(draw):
    phi = draw(formulas(draw(st.sampled_from(DTS)), depth=3))
    extra = draw(
        st.sampled_from(
            [
                Predicate(Call("inside", ("d1", "pole1"), INSIDE)),
                Comparison(Call("dist", ("d1", "d2"), DIST), CmpOp.GE, Const(0.5)),
                Comparison(draw(exprs(3)), CmpOp.LT, draw(exprs(2))),
                Comparison(Neg(Const(1.0)), CmpOp.LE, Const(-1.0)),
                Predicate(Call("wind", (), REGISTRY["wind"])),
            ]
        )
    )
    return draw(
        st.sampled_from([phi, And((phi, extra)), Until(extra, phi, 0.1, 0.30000000000000004)])
    )


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(formulas_with_functions())
@pytest.mark.slow
def test_str_parses_back_to_an_equal_formula(phi):
    text = str(phi)
    again = parse(text, REGISTRY)
    assert again == phi, text
    assert str(again) == text
    assert hash(again) == hash(phi)


def test_design_example_and_aliases():
    phi = parse("always[0,5] (a >= 0.3) and eventually[2,4] (b < 1)")
    assert phi == And(
        (Always(a() >= 0.3, 0, 5), Eventually(Comparison(a("b"), CmpOp.LT, Const(1)), 2, 4))
    )
    assert phi.horizon == 5.0
    assert str(phi) == "always[0,5] (a >= 0.3) and eventually[2,4] (b < 1)"
    words = parse("not (a>0) and (b>0 or c>0) implies G[0,1] F[1,2] (a>0 until[0,3] b>0)")
    symbols = parse("!(a>0) & (b>0 | c>0) -> always[0,1] eventually[1,2] (a>0 U[0,3] b>0)")
    assert words == symbols
    assert parse("true") == BoolConst(True) and parse("false") == BoolConst(False)


def test_numbers_and_constants_round_trip_exactly():
    for text in ("a >= 0.1", "a >= 1e-05", "a >= 1e+20", "a >= 123456.789", "a >= .5", "a >= 2."):
        phi = parse(text)
        assert parse(str(phi)) == phi
    assert parse("a >= -1").rhs == Const(-1.0)
    assert parse("a >= -(1)").rhs == Neg(Const(1.0))
    assert str(Comparison(a(), CmpOp.GE, Neg(Const(1.0)))) == "a >= -(1)"
    assert parse("always[0.1,0.30000000000000004] (a > 0)").end_s == 0.30000000000000004


# --------------------------------------------------------------------------- precedence


def test_precedence_loosest_first_implies_or_and_until_unary():
    p, q, r, s = (Signal(x) > 0 for x in "pqrs")
    text = "p > 0 or q > 0 and r > 0 implies not s > 0"
    assert parse(text) == Implies(Or((p, And((q, r)))), Not(s))
    assert parse("p > 0 and q > 0 until[0,1] r > 0") == And((p, Until(q, r, 0, 1)))
    assert parse("not p > 0 until[0,1] q > 0") == Until(Not(p), q, 0, 1)
    assert parse("always[0,1] p > 0 and q > 0") == And((Always(p, 0, 1), q))
    assert parse("eventually[0,1] not p > 0 or q > 0") == Or((Eventually(Not(p), 0, 1), q))
    assert parse("p > 0 -> q > 0 -> r > 0") == Implies(p, Implies(q, r))
    assert parse("p > 0 U[0,1] q > 0 U[0,2] r > 0") == Until(p, Until(q, r, 0, 2), 0, 1)
    assert parse("p > 0 and q > 0 and r > 0") == And((p, q, r))
    assert parse("(p > 0 and q > 0) and r > 0") == And((And((p, q)), r))


def test_arithmetic_precedence_and_parenthesised_arithmetic():
    assert parse("a + b * c >= 1").lhs == BinOp(
        ArithOp.ADD, a(), BinOp(ArithOp.MUL, a("b"), a("c"))
    )
    assert parse("a - b - c >= 1").lhs == BinOp(
        ArithOp.SUB, BinOp(ArithOp.SUB, a(), a("b")), a("c")
    )
    assert parse("a - (b - c) >= 1").lhs == BinOp(
        ArithOp.SUB, a(), BinOp(ArithOp.SUB, a("b"), a("c"))
    )
    assert parse("-a * b >= 1").lhs == BinOp(ArithOp.MUL, Neg(a()), a("b"))
    assert parse("(a + b) / 2 >= 1").lhs == BinOp(
        ArithOp.DIV, BinOp(ArithOp.ADD, a(), a("b")), Const(2)
    )
    assert parse("((a + b)) >= 1") == parse("a + b >= 1")
    assert parse("((a >= 1))") == (a() >= 1)
    assert parse("(a) + 1 >= (b)").rhs == a("b")


def test_temporal_letters_stay_signal_names():
    assert parse("G >= 1 and F < 2 and U > 0") == And(
        (Signal("G") >= 1, Signal("F") < 2, Signal("U") > 0)
    )
    assert parse("G[0,1] G > 1") == Always(Signal("G") > 1, 0, 1)


def test_functions_as_atoms_and_in_arithmetic():
    phi = parse(
        "eventually[0,10] inside(d1, pole1) and always[0,10] (dist(d1,d2) - 0.5 >= 0)", REGISTRY
    )
    assert phi.clauses[0] == Eventually(Predicate(Call("inside", ("d1", "pole1"), INSIDE)), 0, 10)
    assert phi.signal_names() == {"d1", "d2"}
    assert parse("wind() < 3", REGISTRY).lhs == Call("wind", (), REGISTRY["wind"])
    assert parse("# comment\nalways[0,1] # why\n (a > 0)") == Always(a() > 0, 0, 1)


def test_python_operators_build_the_same_trees():
    p, q = a() >= 0.3, a("b") < 1
    assert (p & q) == parse("a >= 0.3 and b < 1")
    assert (p & q & p) == And((p, q, p))
    assert (p | q | p) == Or((p, q, p))
    assert ~p == Not(p)
    assert p.implies(q) == Implies(p, q)
    assert (2 * a() - 1 / a("b") + 3 >= -a("c")) == parse("2 * a - 1 / b + 3 >= -c")
    with pytest.raises(FormulaError, match=r"lower bound 5\.0 exceeds upper bound 2\.0"):
        Always(p, 5, 2)
    with pytest.raises(FormulaError, match=">= 0"):
        Eventually(p, -1, 2)
    with pytest.raises(FormulaError, match="reserved"):
        Signal("until")
    with pytest.raises(FormulaError, match="finite"):
        Const(float("nan"))
    with pytest.raises(FormulaError, match="takes 2 arguments"):
        Call("dist", ("d1",), DIST)


# --------------------------------------------------------------------------- errors


ERRORS = [
    # text, line, column, token, fragment of the message
    ("", 1, 1, "end of input", "expected a formula"),
    ("a >= ", 1, 6, "end of input", "expected a signal name"),
    ("a >= 1 and", 1, 11, "end of input", "formula"),
    ("a", 1, 2, "end of input", "comparison operator"),
    ("a >= 1 b", 1, 8, "b", "'and', 'or', 'implies', 'until' or end of input"),
    ("a < b < c", 1, 7, "<", "chained comparison"),
    ("a >= 1 and and b > 0", 1, 12, "and", "keyword 'and'"),
    ("a $ b", 1, 3, "$", "unexpected character '$'"),
    ("a == b", 1, 3, "=", "unexpected character '='"),
    ("(a >= 1", 1, 8, "end of input", "expected ')'"),
    ("(a >= 1 and b)", 1, 14, ")", "comparison operator"),
    ("always (a > 0)", 1, 8, "(", "expected '['"),
    ("always[0,1 (a > 0)", 1, 12, "(", "expected ']'"),
    ("always[0 1] (a > 0)", 1, 10, "1", "expected ','"),
    ("always[-1,1] (a > 0)", 1, 8, "-", "lower bound"),
    ("always[2,1] (a > 0)", 1, 8, "2", "lower bound 2 exceeds upper bound 1"),
    ("always[0,x] (a > 0)", 1, 10, "x", "upper bound"),
    ("a > 0 until b > 0", 1, 13, "b", "expected '['"),
    ("a >= 1e999", 1, 6, "1e999", "too large"),
    ("foo(d1) > 0", 1, 1, "foo", "unknown function 'foo'"),
    ("dist(d1) > 0", 1, 1, "dist", "takes 2 arguments, got 1"),
    ("dist(d1, 3) > 0", 1, 10, "3", "identifier argument"),
    ("dist(d1, d2 > 0", 1, 13, ">", "expected ')'"),
    ("a + until > 0", 1, 5, "until", "reserved word 'until'"),
    ("always[0,1] (a >= 0)\n  and\n  eventually[0,1] (b >= )", 3, 25, ")", "signal name"),
    ("a > 0 and\n\n   ?", 3, 4, "?", "unexpected character"),
]


@pytest.mark.parametrize(("text", "line", "column", "token", "fragment"), ERRORS)
def test_syntax_errors_name_line_column_token_and_expectation(text, line, column, token, fragment):
    with pytest.raises(SpecError) as info:
        parse(text, REGISTRY)
    err = info.value
    assert isinstance(err, ValueError)
    assert (err.line, err.column, err.token) == (line, column, token), str(err)
    assert fragment in str(err)
    assert str(err).startswith(f"spec line {line}, column {column}: ")
    assert err.expected


def test_unknown_function_lists_the_known_ones_and_without_registry_none():
    with pytest.raises(SpecError, match=r"unknown function 'inside' \(known: none registered\)"):
        parse("inside(d1, pole1)")
    with pytest.raises(SpecError, match="known: dist, inside, wind"):
        parse("outside(d1, box)", REGISTRY)


def test_absurd_nesting_is_a_spec_error_not_a_crash():
    with pytest.raises(SpecError, match="nested too deeply"):
        parse("not " * 5000 + "a > 0")
    with pytest.raises(SpecError, match="nested too deeply"):
        parse("(" * 5000 + "a > 0" + ")" * 5000)
