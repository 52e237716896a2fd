"""Formula and expression trees of STL as frozen dataclasses.

Two families of nodes:

* expressions (:class:`Expr`): :class:`Const`, :class:`Signal`, :class:`Neg`, :class:`BinOp`,
  :class:`Call` (a registered function) — real-valued signals over time;
* formulas (:class:`Formula`): :class:`BoolConst`, :class:`Comparison`, :class:`Predicate`
  (a function used as an atom, meaning ``f(...) >= 0``), :class:`Not`, :class:`And`, :class:`Or`,
  :class:`Implies`, :class:`Always`, :class:`Eventually`, :class:`Until`.

Nodes compare and hash structurally; ``str(node)`` prints text that :func:`planner.stl.parse`
reads back to an equal node (given the same function registry). Python operators build trees:
``phi & psi``, ``phi | psi``, ``~phi`` for formulas and ``+ - * /``, unary ``-``,
``>= > <= <`` for expressions (``Signal("a") >= 0.3`` is a :class:`Comparison`).

Intervals are in seconds, both ends included. With a sample step ``dt`` they cover the steps
``ceil(a/dt) .. floor(b/dt)`` (with a relative tolerance of 1e-9 on the ratios, so ``[0, 0.3]``
with ``dt = 0.1`` covers 4 samples, steps 0..3).
"""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any

from planner.stl.errors import EvaluationError, FormulaError, SamplingError

if TYPE_CHECKING:
    import numpy as np

    from planner.stl.exact import Witness
    from planner.stl.functions import Function

#: Words that cannot name signals or functions.
RESERVED = frozenset(
    {"true", "false", "not", "and", "or", "implies", "always", "eventually", "until"}
)
IDENTIFIER_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_STEP_TOL = 1e-9


def check_identifier(name: str, what: str) -> None:
    """Raise :class:`FormulaError` unless ``name`` is a usable identifier."""
    if not isinstance(name, str) or not IDENTIFIER_RE.match(name):
        raise FormulaError(f"{what} name {name!r} is not an identifier")
    if name in RESERVED:
        raise FormulaError(f"{what} name {name!r} is a reserved word")


def format_number(value: float) -> str:
    """Shortest text that reads back (``float(text)``) to exactly ``value``."""
    if value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    return repr(value)


def interval_steps(start_s: float, end_s: float, dt: float) -> tuple[int, int]:
    """Sample steps ``(ceil(start_s/dt), floor(end_s/dt))`` of an interval, with tolerance.

    Raises :class:`SamplingError` when the interval holds no step at this ``dt``.
    """
    lo_ratio = start_s / dt
    hi_ratio = end_s / dt
    lo = math.ceil(lo_ratio - _STEP_TOL * max(1.0, abs(lo_ratio)))
    hi = math.floor(hi_ratio + _STEP_TOL * max(1.0, abs(hi_ratio)))
    if lo > hi:
        raise SamplingError(
            f"interval [{format_number(start_s)},{format_number(end_s)}] holds no sample "
            f"at dt={dt:g} s (steps {lo}..{hi})"
        )
    return lo, hi


def check_dt(dt: float) -> float:
    """``dt`` as a float; :class:`SamplingError` unless positive and finite."""
    try:
        value = float(dt)
    except (TypeError, ValueError) as exc:
        raise SamplingError(f"dt must be a number of seconds, got {dt!r}") from exc
    if not math.isfinite(value) or value <= 0.0:
        raise SamplingError(f"dt must be positive and finite, got {dt!r}")
    return value


def _check_interval(start_s: float, end_s: float) -> tuple[float, float]:
    a, b = float(start_s), float(end_s)
    if not (math.isfinite(a) and math.isfinite(b)):
        raise FormulaError(f"interval bounds must be finite, got [{a}, {b}]")
    if a < 0.0:
        raise FormulaError(f"interval lower bound must be >= 0, got {a}")
    if a > b:
        raise FormulaError(f"interval lower bound {a} exceeds upper bound {b}")
    return a, b


# --------------------------------------------------------------------------- expressions


class CmpOp(StrEnum):
    """Comparison operators; robustness is ``lhs - rhs`` for ``>=``/``>``, else ``rhs - lhs``."""

    GE = ">="
    GT = ">"
    LE = "<="
    LT = "<"


class ArithOp(StrEnum):
    """Binary arithmetic operators."""

    ADD = "+"
    SUB = "-"
    MUL = "*"
    DIV = "/"


_ARITH_PREC = {ArithOp.ADD: 1, ArithOp.SUB: 1, ArithOp.MUL: 2, ArithOp.DIV: 2}


def as_expr(value: Expr | float | int) -> Expr:
    """Wrap a number as :class:`Const`; pass expressions through."""
    if isinstance(value, Expr):
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise FormulaError(f"expected an expression or a number, got {value!r}")
    return Const(float(value))


@dataclass(frozen=True, slots=True)
class Expr:
    """Base of real-valued expressions of signals (values per sample step)."""

    def __add__(self, other: Expr | float) -> BinOp:
        return BinOp(ArithOp.ADD, self, as_expr(other))

    def __radd__(self, other: float) -> BinOp:
        return BinOp(ArithOp.ADD, as_expr(other), self)

    def __sub__(self, other: Expr | float) -> BinOp:
        return BinOp(ArithOp.SUB, self, as_expr(other))

    def __rsub__(self, other: float) -> BinOp:
        return BinOp(ArithOp.SUB, as_expr(other), self)

    def __mul__(self, other: Expr | float) -> BinOp:
        return BinOp(ArithOp.MUL, self, as_expr(other))

    def __rmul__(self, other: float) -> BinOp:
        return BinOp(ArithOp.MUL, as_expr(other), self)

    def __truediv__(self, other: Expr | float) -> BinOp:
        return BinOp(ArithOp.DIV, self, as_expr(other))

    def __rtruediv__(self, other: float) -> BinOp:
        return BinOp(ArithOp.DIV, as_expr(other), self)

    def __neg__(self) -> Neg:
        return Neg(self)

    def __ge__(self, other: Expr | float) -> Comparison:
        return Comparison(self, CmpOp.GE, as_expr(other))

    def __gt__(self, other: Expr | float) -> Comparison:
        return Comparison(self, CmpOp.GT, as_expr(other))

    def __le__(self, other: Expr | float) -> Comparison:
        return Comparison(self, CmpOp.LE, as_expr(other))

    def __lt__(self, other: Expr | float) -> Comparison:
        return Comparison(self, CmpOp.LT, as_expr(other))

    @property
    def precedence(self) -> int:
        """Binding strength when printed: 1 ``+ -``, 2 ``* /``, 3 unary minus, 4 atoms."""
        return 4

    def signal_names(self) -> frozenset[str]:
        """Names of the signals this expression reads (function arguments included when known)."""
        return frozenset()


@dataclass(frozen=True, slots=True)
class Const(Expr):
    """A finite real constant."""

    value: float

    def __post_init__(self) -> None:
        value = float(self.value)
        if not math.isfinite(value):
            raise FormulaError(f"constants must be finite, got {self.value!r}")
        object.__setattr__(self, "value", value)

    def __str__(self) -> str:
        return format_number(self.value)


@dataclass(frozen=True, slots=True)
class Signal(Expr):
    """A named scalar signal: ``signals[name]`` of shape (n,) (numpy) or (n, 1) (CasADi)."""

    name: str

    def __post_init__(self) -> None:
        check_identifier(self.name, "signal")

    def __str__(self) -> str:
        return self.name

    def signal_names(self) -> frozenset[str]:
        return frozenset({self.name})


@dataclass(frozen=True, slots=True)
class Neg(Expr):
    """Unary minus."""

    operand: Expr

    @property
    def precedence(self) -> int:
        return 3

    def __str__(self) -> str:
        # "-(1)" keeps Neg(Const(1)) apart from Const(-1), which prints "-1".
        if isinstance(self.operand, Signal | Call | Neg):
            return f"-{self.operand}"
        return f"-({self.operand})"

    def signal_names(self) -> frozenset[str]:
        return self.operand.signal_names()


@dataclass(frozen=True, slots=True)
class BinOp(Expr):
    """Binary arithmetic ``lhs op rhs`` (left associative when printed and parsed)."""

    op: ArithOp
    lhs: Expr
    rhs: Expr

    def __post_init__(self) -> None:
        object.__setattr__(self, "op", ArithOp(self.op))

    @property
    def precedence(self) -> int:
        return _ARITH_PREC[self.op]

    def __str__(self) -> str:
        prec = self.precedence
        left = str(self.lhs)
        if self.lhs.precedence < prec:
            left = f"({left})"
        right = str(self.rhs)
        if self.rhs.precedence <= prec:
            right = f"({right})"
        return f"{left} {self.op.value} {right}"

    def signal_names(self) -> frozenset[str]:
        return self.lhs.signal_names() | self.rhs.signal_names()


@dataclass(frozen=True, slots=True)
class Call(Expr):
    """A registered function applied to identifier arguments, e.g. ``dist(d1, d2)``.

    ``function`` carries the implementations; it takes no part in equality or hashing, so two
    parses of the same text compare equal.
    """

    name: str
    args: tuple[str, ...]
    function: Function = field(compare=False, repr=False)

    def __post_init__(self) -> None:
        check_identifier(self.name, "function")
        object.__setattr__(self, "args", tuple(self.args))
        for arg in self.args:
            check_identifier(arg, "argument")
        if self.function.name != self.name:
            raise FormulaError(f"call of {self.name!r} carries function {self.function.name!r}")
        if len(self.args) != self.function.arity:
            raise FormulaError(
                f"function {self.name!r} takes {self.function.arity} arguments, "
                f"got {len(self.args)}"
            )

    def __str__(self) -> str:
        return f"{self.name}({', '.join(self.args)})"

    def signal_names(self) -> frozenset[str]:
        return frozenset(self.function.signal_names(self.args))


def fold_expr(
    node: Expr,
    signal: Callable[[Signal], Any],
    call: Callable[[Call], Any],
    div: Callable[[Any, Any], Any] = operator.truediv,
) -> Any:
    """The value of an arithmetic expression on one backend: the one evaluator of ``+ - * /``
    that the exact semantics, the smooth semantics and the planner's constraints share.

    Constants are floats; ``signal(node)`` and ``call(node)`` give the backend's leaves
    (numpy arrays, CasADi matrices), and the operators are theirs; ``div`` divides (numpy
    passes ``np.divide``: a division by zero is +-inf there, as the exact semantics say).
    """
    if isinstance(node, Const):
        return node.value
    if isinstance(node, Signal):
        return signal(node)
    if isinstance(node, Call):
        return call(node)
    if isinstance(node, Neg):
        return -fold_expr(node.operand, signal, call, div)
    if isinstance(node, BinOp):
        lhs = fold_expr(node.lhs, signal, call, div)
        rhs = fold_expr(node.rhs, signal, call, div)
        if node.op is ArithOp.ADD:
            return lhs + rhs
        if node.op is ArithOp.SUB:
            return lhs - rhs
        if node.op is ArithOp.MUL:
            return lhs * rhs
        return div(lhs, rhs)
    raise EvaluationError(f"cannot evaluate expression of type {type(node).__name__}")


def comparison_margin(op: CmpOp, lhs: Any, rhs: Any) -> Any:
    """A comparison's robustness from its sides: ``lhs - rhs`` for ``>=``/``>``, else
    ``rhs - lhs`` (any backend)."""
    return lhs - rhs if op in (CmpOp.GE, CmpOp.GT) else rhs - lhs


# --------------------------------------------------------------------------- formulas

# Printing precedence of formulas, loosest first.
_PREC_IMPLIES, _PREC_OR, _PREC_AND, _PREC_UNTIL, _PREC_UNARY, _PREC_ATOM = 1, 2, 3, 4, 5, 6


@dataclass(frozen=True, slots=True)
class Formula:
    """Base of STL formulas.

    Signals: a mapping ``name -> array`` sampled every ``dt`` seconds, all with the same number
    of samples ``n``: numpy arrays of shape (n,) for scalar signals and (n, d) for vector
    signals (vehicle positions, d = 3), or CasADi SX/MX matrices of shape (n, 1) / (n, d) for
    :meth:`smooth_robustness`.
    """

    # ---- structure

    @property
    def children(self) -> tuple[Formula, ...]:
        """Direct sub-formulas (the conjuncts of an :class:`And`, etc.)."""
        return ()

    @property
    def clauses(self) -> tuple[Formula, ...]:
        """Top-level conjuncts: the children of an :class:`And`, else ``(self,)``."""
        return (self,)

    @property
    def precedence(self) -> int:
        return _PREC_ATOM

    @property
    def horizon(self) -> float:
        """Seconds of future the formula needs beyond the evaluation time."""
        return 0.0

    def horizon_steps(self, dt: float) -> int:
        """Sample steps of future the formula needs at step ``dt`` (trace needs this + 1)."""
        return 0

    def signal_names(self) -> frozenset[str]:
        """Signals read by comparisons, plus function arguments the functions declare."""
        names: frozenset[str] = frozenset()
        for child in self.children:
            names |= child.signal_names()
        return names

    def walk(self) -> tuple[Formula, ...]:
        """This node and all sub-formulas, parents before children."""
        out: list[Formula] = [self]
        for child in self.children:
            out.extend(child.walk())
        return tuple(out)

    # ---- operators

    def __and__(self, other: Formula) -> And:
        _check_formula(other)
        return And((*self.clauses, *other.clauses))

    def __or__(self, other: Formula) -> Or:
        _check_formula(other)
        left = self.children if isinstance(self, Or) else (self,)
        right = other.children if isinstance(other, Or) else (other,)
        return Or((*left, *right))

    def __invert__(self) -> Not:
        return Not(self)

    def implies(self, other: Formula) -> Implies:
        """``self implies other``."""
        return Implies(self, other)

    # ---- semantics (docs/stl.md, "Semantics")

    def robustness_trace(self, signals: Mapping[str, Any], dt: float) -> np.ndarray:
        """Exact robustness at every step where the horizon fits in the trace.

        Args:
            signals: numpy signals, ``n`` samples each.
            dt: sample step in seconds.

        Returns:
            (n - H,) float array, ``H = self.horizon_steps(dt)``: entry ``t`` is the robustness
            at time ``t * dt``, computed exactly as the definition (no window is truncated).
        """
        from planner.stl.exact import robustness_trace

        return robustness_trace(self, signals, dt)

    def robustness(self, signals: Mapping[str, Any], dt: float) -> float:
        """Exact robustness at t = 0 (float; +-inf only for ``true``/``false``-like formulas)."""
        return float(self.robustness_trace(signals, dt)[0])

    def smooth_robustness(self, signals: Mapping[str, Any], dt: float, k: float = 10.0) -> Any:
        """Smooth (log-sum-exp, sharpness ``k``) robustness at t = 0.

        Returns a float for numpy signals and a CasADi scalar (SX or MX, as the signals) for
        CasADi signals. Only the sample steps the formula reaches from t = 0 are evaluated.
        ``|smooth - exact| <= self.smooth_error_bound(k, dt)``.
        """
        from planner.stl.smooth import smooth_robustness

        return smooth_robustness(self, signals, dt, k)

    def smooth_robustness_trace(
        self,
        signals: Mapping[str, Any],
        dt: float,
        k: float = 10.0,
        first_step: int = 0,
        last_step: int | None = None,
    ) -> Any:
        """Smooth robustness at every step ``first_step..last_step`` in one graph.

        Same trace convention as :meth:`robustness_trace`: ``last_step`` defaults to the last
        step where the horizon fits (``n - 1 - H``); a later step raises TraceLengthError.
        Sub-formulas shared between steps are built once (windows cost O(steps + width)).

        Returns:
            (R,) float array for numpy signals, (R, 1) SX/MX column for CasADi signals,
            ``R = last_step - first_step + 1``; entry ``i`` equals :meth:`smooth_robustness`
            of the signals shifted by ``first_step + i`` steps.
        """
        from planner.stl.smooth import smooth_robustness_trace

        return smooth_robustness_trace(self, signals, dt, k, first_step, last_step)

    def smooth_error_bound(self, k: float, dt: float) -> float:
        """Bound on ``|smooth_robustness - robustness|`` (robustness units); see smooth.py."""
        from planner.stl.smooth import smooth_error_bound

        return smooth_error_bound(self, k, dt)

    def weakest(self, signals: Mapping[str, Any], dt: float) -> tuple[Witness, ...]:
        """The chain of sub-formulas that decides the robustness at t = 0.

        Returns witnesses from the root (at t = 0) down to the atom (and its time) whose value is
        the robustness, up to sign; for a conjunction the second entry is the weakest clause.
        """
        from planner.stl.exact import weakest

        return weakest(self, signals, dt)


def _check_formula(value: object) -> None:
    if not isinstance(value, Formula):
        raise FormulaError(f"expected a Formula, got {value!r}")


def _wrap(child: Formula, parent_prec: int) -> str:
    text = str(child)
    return f"({text})" if child.precedence <= parent_prec else text


@dataclass(frozen=True, slots=True)
class BoolConst(Formula):
    """``true`` (robustness +inf) or ``false`` (-inf)."""

    value: bool

    def __post_init__(self) -> None:
        if not isinstance(self.value, bool):
            raise FormulaError(f"BoolConst needs a bool, got {self.value!r}")

    def __str__(self) -> str:
        return "true" if self.value else "false"


@dataclass(frozen=True, slots=True)
class Comparison(Formula):
    """``lhs op rhs``; robustness ``lhs - rhs`` for ``>=``/``>``, ``rhs - lhs`` for ``<=``/``<``."""

    lhs: Expr
    op: CmpOp
    rhs: Expr

    def __post_init__(self) -> None:
        object.__setattr__(self, "op", CmpOp(self.op))
        object.__setattr__(self, "lhs", as_expr(self.lhs))
        object.__setattr__(self, "rhs", as_expr(self.rhs))

    def __str__(self) -> str:
        return f"{self.lhs} {self.op.value} {self.rhs}"

    def signal_names(self) -> frozenset[str]:
        return self.lhs.signal_names() | self.rhs.signal_names()


@dataclass(frozen=True, slots=True)
class Predicate(Formula):
    """A function used as an atom: robustness is the function's value (``f(...) >= 0``)."""

    call: Call

    def __str__(self) -> str:
        return str(self.call)

    def signal_names(self) -> frozenset[str]:
        return self.call.signal_names()


@dataclass(frozen=True, slots=True)
class Not(Formula):
    """``not child``; robustness ``-rho(child)``."""

    child: Formula

    def __post_init__(self) -> None:
        _check_formula(self.child)

    @property
    def children(self) -> tuple[Formula, ...]:
        return (self.child,)

    @property
    def precedence(self) -> int:
        return _PREC_UNARY

    @property
    def horizon(self) -> float:
        return self.child.horizon

    def horizon_steps(self, dt: float) -> int:
        return self.child.horizon_steps(dt)

    def __str__(self) -> str:
        return f"not {_unary_operand(self.child)}"


def _unary_operand(child: Formula) -> str:
    # Unary operators print their operand in parentheses unless it is itself unary or a
    # constant/predicate: "always[0,5] (a >= 0.3)", "not eventually[0,1] (b < 0)".
    if isinstance(child, Not | Always | Eventually | BoolConst | Predicate):
        return str(child)
    return f"({child})"


@dataclass(frozen=True, slots=True)
class _NAry(Formula):
    operands: tuple[Formula, ...]

    def __post_init__(self) -> None:
        kids = tuple(self.operands)
        if len(kids) < 2:
            raise FormulaError(f"{type(self).__name__} needs at least two operands")
        for kid in kids:
            _check_formula(kid)
        object.__setattr__(self, "operands", kids)

    @property
    def children(self) -> tuple[Formula, ...]:
        return self.operands

    @property
    def horizon(self) -> float:
        return max(child.horizon for child in self.operands)

    def horizon_steps(self, dt: float) -> int:
        return max(child.horizon_steps(dt) for child in self.operands)


@dataclass(frozen=True, slots=True)
class And(_NAry):
    """Conjunction of two or more formulas; robustness = min."""

    @property
    def clauses(self) -> tuple[Formula, ...]:
        return self.operands

    @property
    def precedence(self) -> int:
        return _PREC_AND

    def __str__(self) -> str:
        return " and ".join(_wrap(child, _PREC_AND) for child in self.operands)


@dataclass(frozen=True, slots=True)
class Or(_NAry):
    """Disjunction of two or more formulas; robustness = max."""

    @property
    def precedence(self) -> int:
        return _PREC_OR

    def __str__(self) -> str:
        return " or ".join(_wrap(child, _PREC_OR) for child in self.operands)


@dataclass(frozen=True, slots=True)
class Implies(Formula):
    """``lhs implies rhs``; robustness ``max(-rho(lhs), rho(rhs))``."""

    lhs: Formula
    rhs: Formula

    def __post_init__(self) -> None:
        _check_formula(self.lhs)
        _check_formula(self.rhs)

    @property
    def children(self) -> tuple[Formula, ...]:
        return (self.lhs, self.rhs)

    @property
    def precedence(self) -> int:
        return _PREC_IMPLIES

    @property
    def horizon(self) -> float:
        return max(self.lhs.horizon, self.rhs.horizon)

    def horizon_steps(self, dt: float) -> int:
        return max(self.lhs.horizon_steps(dt), self.rhs.horizon_steps(dt))

    def __str__(self) -> str:
        return f"{_wrap(self.lhs, _PREC_IMPLIES)} implies {_wrap(self.rhs, _PREC_IMPLIES)}"


@dataclass(frozen=True, slots=True)
class _Temporal(Formula):
    """Unary temporal operator over ``[start_s, end_s]`` seconds (both included)."""

    child: Formula
    start_s: float
    end_s: float

    def __post_init__(self) -> None:
        _check_formula(self.child)
        a, b = _check_interval(self.start_s, self.end_s)
        object.__setattr__(self, "start_s", a)
        object.__setattr__(self, "end_s", b)

    @property
    def children(self) -> tuple[Formula, ...]:
        return (self.child,)

    @property
    def precedence(self) -> int:
        return _PREC_UNARY

    @property
    def horizon(self) -> float:
        return self.end_s + self.child.horizon

    def steps(self, dt: float) -> tuple[int, int]:
        """Interval in sample steps at ``dt``."""
        return interval_steps(self.start_s, self.end_s, dt)

    def horizon_steps(self, dt: float) -> int:
        return self.steps(dt)[1] + self.child.horizon_steps(dt)

    def _interval(self) -> str:
        return f"[{format_number(self.start_s)},{format_number(self.end_s)}]"


@dataclass(frozen=True, slots=True)
class Always(_Temporal):
    """``always[a,b] child``: min of the child over ``[t+a, t+b]``."""

    def __str__(self) -> str:
        return f"always{self._interval()} {_unary_operand(self.child)}"


@dataclass(frozen=True, slots=True)
class Eventually(_Temporal):
    """``eventually[a,b] child``: max of the child over ``[t+a, t+b]``."""

    def __str__(self) -> str:
        return f"eventually{self._interval()} {_unary_operand(self.child)}"


@dataclass(frozen=True, slots=True)
class Until(Formula):
    """``lhs until[a,b] rhs``.

    ``rho(t) = max over t' in [t+a, t+b] of min(rho(rhs, t'), min over t'' in [t, t') of
    rho(lhs, t''))``, the inner min over an empty range being +inf.
    """

    lhs: Formula
    rhs: Formula
    start_s: float
    end_s: float

    def __post_init__(self) -> None:
        _check_formula(self.lhs)
        _check_formula(self.rhs)
        a, b = _check_interval(self.start_s, self.end_s)
        object.__setattr__(self, "start_s", a)
        object.__setattr__(self, "end_s", b)

    @property
    def children(self) -> tuple[Formula, ...]:
        return (self.lhs, self.rhs)

    @property
    def precedence(self) -> int:
        return _PREC_UNTIL

    @property
    def horizon(self) -> float:
        return self.end_s + max(self.lhs.horizon, self.rhs.horizon)

    def steps(self, dt: float) -> tuple[int, int]:
        """Interval in sample steps at ``dt``."""
        return interval_steps(self.start_s, self.end_s, dt)

    def horizon_steps(self, dt: float) -> int:
        return self.steps(dt)[1] + max(self.lhs.horizon_steps(dt), self.rhs.horizon_steps(dt))

    def __str__(self) -> str:
        interval = f"[{format_number(self.start_s)},{format_number(self.end_s)}]"
        return f"{_wrap(self.lhs, _PREC_UNTIL)} until{interval} {_wrap(self.rhs, _PREC_UNTIL)}"


def conjunction(clauses: tuple[Formula, ...] | list[Formula]) -> Formula:
    """``clauses[0] and clauses[1] ...`` (the clause itself when there is one)."""
    items = tuple(clauses)
    if not items:
        return BoolConst(True)
    return items[0] if len(items) == 1 else And(items)
