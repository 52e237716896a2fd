r"""Smooth robustness: min/max replaced by log-sum-exp (LSE) with sharpness ``k``.

One evaluator, two array back ends: numpy (floats, for checking and reporting) and CasADi
(SX/MX expressions, for the optimiser; gradients come from CasADi). Both run the same code on
the same formula tree, so the optimiser and the checker cannot disagree on the formula.

Smooth operators (``k > 0``)::

    smax_k(x_1..x_m) = (1/k) log sum_i exp(k x_i)          smin_k(x) = -smax_k(-x)

always evaluated shifted by the running maximum (``c + log sum exp(y - c)``, ``c = max y``;
pairwise ``logaddexp``), so nothing overflows and at least one term is 1. The shift cancels in
the derivative, so CasADi gradients are the exact softmax weights even on ties.

* ``and``/``or`` of m operands: ``smin_k``/``smax_k`` of the m values;
* ``implies``: ``smax_k(-l, r)``; ``not``: ``-x``;
* ``always[a,b]``/``eventually[a,b]``: ``smin_k``/``smax_k`` over the ``w = tb - ta + 1`` window
  steps (``ta = ceil(a/dt)``, ``tb = floor(b/dt)``);
* ``phi until[a,b] psi``: the definition with every min/max smoothed,
  ``smax_k over t' in [t+ta, t+tb] of smin_k({psi(t')} u {phi(t'') : t'' in [t, t')})``
  (an empty inner set contributes nothing, the +inf rule). ``true``/``false`` (+-inf) are
  folded exactly (``x and true = x``, ...).

Error bound. For m values ``max x <= smax_k(x) <= max x + log(m)/k`` (and ``min - log(m)/k <=
smin_k <= min``), and smax_k/smin_k are 1-Lipschitz in the max-norm of their inputs. Hence, by
induction on the tree, ``|smooth - exact| <= E(phi)`` with::

    E(atom) = 0                         E(not x) = E(x)
    E(and/or of m) = log(m)/k + max E(operands)      E(implies) = log(2)/k + max(E(l), E(r))
    E(always/eventually, w steps) = log(w)/k + E(child)
    E(until[ta,tb]) = (log(tb - ta + 1) + log(tb + 1))/k + max(E(phi), E(psi))

For until: the inner set at ``t' = t + j`` has ``j + 1 <= tb + 1`` elements (psi plus j values
of phi), so each smoothed inner value is within ``log(tb+1)/k + max(E(phi), E(psi))`` of the
exact one, and the outer smax over ``tb - ta + 1`` steps adds ``log(tb - ta + 1)/k``.
:func:`smooth_error_bound` computes E.

Only the needed steps are built. The set of steps each node must be evaluated at is propagated
from the root (step 0; steps ``first..last`` for :func:`smooth_robustness_trace`) down the tree
as a contiguous range ``[lo, hi]``: ``always[ta,tb]`` at
``[lo, hi]`` needs its child at ``[lo+ta, hi+tb]``; ``phi until[ta,tb] psi`` needs phi at
``[lo, hi+tb-1]`` and psi at ``[lo+ta, hi+tb]``; Boolean operators pass the range through.
Equal sub-formulas are evaluated once on the union of their ranges. Functions receive the rows
``lo..hi`` of the signals (see :mod:`planner.stl.functions`). A formula on a 400-sample
horizon therefore builds O(steps it reaches) nodes, not O(n) per operator.

Windows of width w over R > 1 output steps use the van Herk/Gil-Werman block decomposition with
``logaddexp`` prefixes and suffixes inside blocks of w steps (``LSE`` is associative exactly),
so a window costs O(R + w) graph nodes, not O(R w). Until costs O(R tb).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import casadi as ca
import numpy as np

from planner.stl.ast import (
    Always,
    And,
    BoolConst,
    Call,
    Comparison,
    Eventually,
    Expr,
    Formula,
    Implies,
    Not,
    Or,
    Predicate,
    Signal,
    Until,
    check_dt,
    comparison_margin,
    fold_expr,
)
from planner.stl.errors import (
    EvaluationError,
    SignalShapeError,
    TraceLengthError,
    UnknownSignalError,
)
from planner.stl.exact import call_numpy
from planner.stl.functions import RowView
from planner.stl.signals import casadi_signals, is_symbolic, numpy_signals

# A node's smooth values: a vector over its needed steps, or +-inf for constant truth values.
Values = Any


class NumpyOps:
    """Array operations on numpy vectors (m,)."""

    symbolic = False

    def full(self, rows: int, value: float) -> np.ndarray:
        return np.full(rows, value)

    def lae(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.logaddexp(a, b)

    def lse_many(self, vectors: Sequence[np.ndarray]) -> np.ndarray:
        shift = np.maximum.reduce(vectors)
        total = sum(np.exp(v - shift) for v in vectors)
        return shift + np.log(total)

    def lse_reduce(self, v: np.ndarray) -> np.ndarray:
        shift = np.max(v)
        return np.array([shift + np.log(np.sum(np.exp(v - shift)))])

    def take(self, v: np.ndarray, index: Sequence[int]) -> np.ndarray:
        return v[np.asarray(index, dtype=np.intp)]

    def concat(self, vectors: Sequence[np.ndarray]) -> np.ndarray:
        return np.concatenate(vectors)

    def sub(self, v: np.ndarray, start: int, stop: int) -> np.ndarray:
        return v[start:stop]

    def signal_rows(self, name: str, value: np.ndarray, lo: int, hi: int) -> np.ndarray:
        if value.ndim != 1:
            raise SignalShapeError(
                f"signal {name!r} has shape {value.shape}: arithmetic and comparisons need a "
                f"scalar signal (use a function for vector signals)"
            )
        return value[lo:hi]

    def call(self, node: Call, view: Mapping[str, Any], rows: int) -> np.ndarray:
        return call_numpy(node, view, rows)


class CasadiOps:
    """Array operations on CasADi columns (m, 1), SX or MX."""

    symbolic = True

    def full(self, rows: int, value: float) -> Any:
        return ca.DM(np.full((rows, 1), value))

    def lae(self, a: Any, b: Any) -> Any:
        shift = ca.fmax(a, b)
        return shift + ca.log(ca.exp(a - shift) + ca.exp(b - shift))

    def lse_many(self, vectors: Sequence[Any]) -> Any:
        shift = vectors[0]
        for v in vectors[1:]:
            shift = ca.fmax(shift, v)
        total = ca.exp(vectors[0] - shift)
        for v in vectors[1:]:
            total = total + ca.exp(v - shift)
        return shift + ca.log(total)

    def lse_reduce(self, v: Any) -> Any:
        shift = ca.mmax(v)
        return shift + ca.log(ca.sum1(ca.exp(v - shift)))

    def take(self, v: Any, index: Sequence[int]) -> Any:
        return v[[int(i) for i in index]]

    def concat(self, vectors: Sequence[Any]) -> Any:
        return ca.vertcat(*vectors)

    def sub(self, v: Any, start: int, stop: int) -> Any:
        return v[start:stop]

    def signal_rows(self, name: str, value: Any, lo: int, hi: int) -> Any:
        if value.shape[1] != 1:
            raise SignalShapeError(
                f"signal {name!r} has shape {value.shape}: arithmetic and comparisons need a "
                f"scalar (n, 1) signal (use a function for vector signals)"
            )
        return value[lo:hi, 0]

    def call(self, node: Call, view: Mapping[str, Any], rows: int) -> Any:
        out = node.function.casadi_impl(node.args, view)
        if isinstance(out, int | float | np.ndarray):
            out = ca.DM(np.broadcast_to(np.asarray(out, dtype=float), (rows,)).reshape(-1, 1))
        shape = getattr(out, "shape", None)
        if shape != (rows, 1):
            raise SignalShapeError(
                f"function {node.name!r} (CasADi) returned shape {shape}, expected ({rows}, 1)"
            )
        return out


def window_lse(ops: Any, y: Any, width: int, rows: int) -> Any:
    """``out[i] = log sum exp(y[i .. i+width-1])`` for ``i < rows``; ``y`` has rows+width-1.

    Block decomposition (van Herk/Gil-Werman) with logaddexp prefixes/suffixes inside blocks of
    ``width`` steps: a window starting at a block boundary is one block prefix, any other
    window is a block suffix plus the next block's prefix. O(rows + width) operations.
    """
    if width == 1:
        return y
    if rows == 1:
        return ops.lse_reduce(y)
    total = rows + width - 1
    counts = [(total - 1 - r) // width + 1 for r in range(width)]  # blocks having offset r
    offsets = np.concatenate(([0], np.cumsum(counts)))

    def flat(position: np.ndarray) -> np.ndarray:
        return offsets[position % width] + position // width

    prefix: list[Any] = []
    for r in range(width):
        column = ops.take(y, [r + width * b for b in range(counts[r])])
        if r > 0:
            column = ops.lae(ops.sub(prefix[-1], 0, counts[r]), column)
        prefix.append(column)
    suffix: list[Any] = [None] * width
    for r in range(width - 1, -1, -1):
        index = [r + width * b for b in range(counts[r])]
        carried = counts[r + 1] if r + 1 < width else 0
        parts = []
        if carried:
            parts.append(ops.lae(ops.sub(suffix[r + 1], 0, carried), ops.take(y, index[:carried])))
        if carried < counts[r]:
            parts.append(ops.take(y, index[carried:]))
        suffix[r] = parts[0] if len(parts) == 1 else ops.concat(parts)
    prefix_flat = ops.concat(prefix)
    suffix_flat = ops.concat(suffix)
    starts = np.arange(rows)
    ends = starts + width - 1
    aligned = starts % width == 0
    pieces = []
    order = []
    if aligned.any():
        pieces.append(ops.take(prefix_flat, flat(ends[aligned])))
        order.append(starts[aligned])
    if (~aligned).any():
        pieces.append(
            ops.lae(
                ops.take(suffix_flat, flat(starts[~aligned])),
                ops.take(prefix_flat, flat(ends[~aligned])),
            )
        )
        order.append(starts[~aligned])
    joined = pieces[0] if len(pieces) == 1 else ops.concat(pieces)
    inverse = np.empty(rows, dtype=np.intp)
    inverse[np.concatenate(order)] = np.arange(rows)
    return ops.take(joined, inverse)


class SmoothEvaluator:
    """Smooth robustness of one formula at t = 0 on numpy or CasADi signals."""

    def __init__(self, signals: Mapping[str, Any], dt: float, k: float) -> None:
        self.dt = check_dt(dt)
        try:
            self.k = float(k)
        except (TypeError, ValueError) as exc:
            raise EvaluationError(f"sharpness k must be a number, got {k!r}") from exc
        if not math.isfinite(self.k) or self.k <= 0.0:
            raise EvaluationError(f"sharpness k must be positive and finite, got {k!r}")
        if isinstance(signals, Mapping) and signals and is_symbolic(signals):
            self.signals, self.n, self.kind = casadi_signals(signals)
            self.ops: Any = CasadiOps()
        else:
            self.signals, self.n = numpy_signals(signals)
            self.kind = float
            self.ops = NumpyOps()

    def evaluate(self, formula: Formula) -> Any:
        """Smooth robustness at step 0: float (numpy) or 1x1 SX/MX (CasADi)."""
        needed = formula.horizon_steps(self.dt) + 1
        if self.n < needed:
            raise TraceLengthError(needed, self.n, self.dt, formula.horizon)
        result = self._evaluate(formula, 0, 0)
        if isinstance(result, float):
            return result if not self.ops.symbolic else self.kind(result)
        if self.ops.symbolic:
            return self.kind(result[0])  # a DM when only constants were compared
        return float(result[0])

    def evaluate_steps(self, formula: Formula, first: int, last: int | None) -> Any:
        """Smooth robustness at steps ``first..last``: (R,) numpy or (R, 1) SX/MX column."""
        horizon = formula.horizon_steps(self.dt)
        if self.n < horizon + 1:
            raise TraceLengthError(horizon + 1, self.n, self.dt, formula.horizon)
        top = self.n - 1 - horizon
        last = top if last is None else int(last)
        first = int(first)
        if not 0 <= first <= last:
            raise EvaluationError(f"steps {first}..{last}: need 0 <= first <= last")
        if last > top:
            raise TraceLengthError(last + horizon + 1, self.n, self.dt, formula.horizon)
        rows = last - first + 1
        result = self._evaluate(formula, first, last)
        if isinstance(result, float):
            result = self.ops.full(rows, result)
        return self.kind(result) if self.ops.symbolic else np.asarray(result, dtype=float)

    def _evaluate(self, formula: Formula, first: int, last: int) -> Values:
        ranges = self._ranges(formula, first, last)
        values: dict[Formula, Values] = {}
        for node in _postorder(formula):
            if node in ranges and node not in values:
                values[node] = self._node(node, ranges[node], values, ranges)
        return values[formula]

    # ---- needed steps

    def _ranges(self, formula: Formula, first: int, last: int) -> dict[Formula, tuple[int, int]]:
        ranges: dict[Formula, tuple[int, int]] = {formula: (first, last)}
        for node in reversed(_postorder(formula)):
            if node not in ranges:
                continue
            lo, hi = ranges[node]
            for child, (c_lo, c_hi) in self._child_ranges(node, lo, hi):
                if c_lo > c_hi:
                    continue
                old = ranges.get(child)
                ranges[child] = (
                    (c_lo, c_hi) if old is None else (min(old[0], c_lo), max(old[1], c_hi))
                )
        return ranges

    def _child_ranges(
        self, node: Formula, lo: int, hi: int
    ) -> list[tuple[Formula, tuple[int, int]]]:
        if isinstance(node, Always | Eventually):
            ta, tb = node.steps(self.dt)
            return [(node.child, (lo + ta, hi + tb))]
        if isinstance(node, Until):
            ta, tb = node.steps(self.dt)
            rhs = (node.rhs, (lo + ta, hi + tb))
            # until[., 0] never reads its left operand.
            return [(node.lhs, (lo, hi + tb - 1)), rhs] if tb >= 1 else [rhs]
        return [(child, (lo, hi)) for child in node.children]

    # ---- node values

    def _get(self, values: dict, ranges: dict, child: Formula, lo: int, hi: int) -> Values:
        value = values[child]
        if isinstance(value, float):
            return value
        base = ranges[child][0]
        return self.ops.sub(value, lo - base, hi - base + 1)

    def _node(self, node: Formula, rng: tuple[int, int], values: dict, ranges: dict) -> Values:
        lo, hi = rng
        rows = hi - lo + 1
        ops, k = self.ops, self.k
        if isinstance(node, BoolConst):
            return math.inf if node.value else -math.inf
        if isinstance(node, Comparison):
            diff = comparison_margin(
                node.op, self._expr(node.lhs, lo, hi), self._expr(node.rhs, lo, hi)
            )
            if isinstance(diff, float):
                return ops.full(rows, diff)
            return diff
        if isinstance(node, Predicate):
            return self._expr(node.call, lo, hi)
        if isinstance(node, Not):
            value = self._get(values, ranges, node.child, lo, hi)
            return -value
        if isinstance(node, And | Or | Implies):
            kids = [self._get(values, ranges, child, lo, hi) for child in node.children]
            if isinstance(node, Implies):
                kids[0] = -kids[0]
            return self._smooth_extreme(kids, maximum=not isinstance(node, And))
        if isinstance(node, Always | Eventually):
            ta, tb = node.steps(self.dt)
            child = self._get(values, ranges, node.child, lo + ta, hi + tb)
            if isinstance(child, float):
                return child
            sign = -1.0 if isinstance(node, Always) else 1.0
            return sign * window_lse(ops, sign * k * child, tb - ta + 1, rows) / k
        if isinstance(node, Until):
            return self._until(node, lo, hi, values, ranges)
        raise EvaluationError(f"cannot evaluate node of type {type(node).__name__}")

    def _smooth_extreme(self, kids: list[Values], *, maximum: bool) -> Values:
        # +-inf operands fold exactly: x and true = x, x and false = false, ...
        absorbing = math.inf if maximum else -math.inf
        vectors = []
        for kid in kids:
            if isinstance(kid, float):
                if kid == absorbing:
                    return absorbing
                continue
            vectors.append(kid)
        if not vectors:
            return -absorbing
        if len(vectors) == 1:
            return vectors[0]
        sign = 1.0 if maximum else -1.0
        return sign * self.ops.lse_many([sign * self.k * v for v in vectors]) / self.k

    def _until(self, node: Until, lo: int, hi: int, values: dict, ranges: dict) -> Values:
        ops, k = self.ops, self.k
        ta, tb = node.steps(self.dt)
        rows = hi - lo + 1
        q = self._get(values, ranges, node.rhs, lo + ta, hi + tb)
        p = self._get(values, ranges, node.lhs, lo, hi + tb - 1) if tb >= 1 else math.inf
        if isinstance(q, float) and q == -math.inf:
            return -math.inf
        if isinstance(p, float) and p == math.inf:
            if isinstance(q, float):
                return q
            return window_lse(ops, k * q, tb - ta + 1, rows) / k  # eventually[ta,tb] psi
        if isinstance(p, float):  # p == -inf: only t' = t counts
            if ta > 0:
                return -math.inf
            return q if isinstance(q, float) else ops.sub(q, 0, rows)
        if isinstance(q, float):  # q == +inf: the best t' is t + ta
            if ta == 0:
                return math.inf
            return -window_lse(ops, -k * ops.sub(p, 0, rows + ta - 1), ta, rows) / k
        neg_prefix = None  # LSE of -k p over [t, t+j)
        outer = None  # LSE over j of k * inner(t + j)
        for j in range(tb + 1):
            if j >= 1:
                term = -k * ops.sub(p, j - 1, j - 1 + rows)
                neg_prefix = term if neg_prefix is None else ops.lae(neg_prefix, term)
            if j >= ta:
                neg_q = -k * ops.sub(q, j - ta, j - ta + rows)
                neg_inner = neg_q if neg_prefix is None else ops.lae(neg_prefix, neg_q)
                outer = -neg_inner if outer is None else ops.lae(outer, -neg_inner)
        assert outer is not None  # j = ta <= tb is in the loop
        return outer / k

    def _expr(self, node: Expr, lo: int, hi: int) -> Any:
        def signal(s: Signal) -> Any:
            if s.name not in self.signals:
                raise UnknownSignalError(s.name, tuple(self.signals))
            return self.ops.signal_rows(s.name, self.signals[s.name], lo, hi + 1)

        def call(c: Call) -> Any:
            return self.ops.call(c, RowView(self.signals, lo, hi + 1), hi - lo + 1)

        return fold_expr(node, signal, call)


def _postorder(formula: Formula) -> list[Formula]:
    """Distinct sub-formulas (by equality), every node after all of its descendants."""
    seen: set[Formula] = set()
    order: list[Formula] = []

    def visit(node: Formula) -> None:
        if node in seen:
            return
        seen.add(node)
        for child in node.children:
            visit(child)
        order.append(node)

    visit(formula)
    return order


def smooth_robustness(formula: Formula, signals: Mapping[str, Any], dt: float, k: float) -> Any:
    """Smooth robustness at t = 0 (see :meth:`Formula.smooth_robustness`)."""
    return SmoothEvaluator(signals, dt, k).evaluate(formula)


def smooth_robustness_trace(
    formula: Formula,
    signals: Mapping[str, Any],
    dt: float,
    k: float,
    first_step: int = 0,
    last_step: int | None = None,
) -> Any:
    """Smooth robustness at steps ``first_step..last_step`` (see Formula.smooth_robustness_trace)."""
    return SmoothEvaluator(signals, dt, k).evaluate_steps(formula, first_step, last_step)


def smooth_error_bound(formula: Formula, k: float, dt: float) -> float:
    """``E(formula)``: bound on ``|smooth - exact|`` at sharpness ``k`` (module docstring)."""
    dt = check_dt(dt)
    if not (math.isfinite(k) and k > 0):
        raise EvaluationError(f"sharpness k must be positive and finite, got {k!r}")

    def bound(node: Formula) -> float:
        kids = [bound(child) for child in node.children]
        worst = max(kids, default=0.0)
        if isinstance(node, And | Or):
            return math.log(len(node.operands)) / k + worst
        if isinstance(node, Implies):
            return math.log(2.0) / k + worst
        if isinstance(node, Always | Eventually):
            ta, tb = node.steps(dt)
            return math.log(tb - ta + 1) / k + worst
        if isinstance(node, Until):
            ta, tb = node.steps(dt)
            return (math.log(tb - ta + 1) + math.log(tb + 1)) / k + worst
        return worst

    return bound(formula)
