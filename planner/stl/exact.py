r"""Exact robustness traces, vectorised, O(n) per operator and independent of interval widths.

Trace convention: a node's trace holds the steps where its whole horizon fits in the signals.
With ``n`` samples and ``H = node.horizon_steps(dt)`` the trace has ``n - H`` entries and entry
``t`` equals the definition of docs/stl.md, "Semantics" at step ``t`` exactly: no window is ever
truncated at the end of the trace. A parent reads a child's trace only at steps inside it.

Operators:

* comparisons and predicates: elementwise numpy over the whole trace;
* ``not``/``and``/``or``/``implies``: elementwise ``-``/min/max on the common prefix;
* ``always[a,b]`` / ``eventually[a,b]``: ``scipy.ndimage.minimum_filter1d`` /
  ``maximum_filter1d`` (O(n), independent of the window width) on the steps ``[ta, tb]``,
  ``ta = ceil(a/dt)``, ``tb = floor(b/dt)``;
* ``phi until[a,b] psi``: the linear-time decomposition below.

Until in linear time
--------------------
Definition (``p = rho(phi)``, ``q = rho(psi)``, ``ta..tb`` the interval's steps)::

    U(t) = max_{t' in [t+ta, t+tb]} min(q(t'), min_{t'' in [t, t')} p(t''))      (inf over {} = +inf)

Claim: with ``s = t + ta`` and ``w = tb - ta``,

    U(t) = min( A(t), F(s), V(s) ),   A(t) = min_{[t, t+ta)} p   (+inf when ta = 0),
                                      F(s) = max_{[s, s+w]} q,
                                      V(s) = max_{t' in [s, m)} min(q(t'), min_{[s, t')} p),

``m`` the common length of the child traces (``V`` is the unbounded until to the end of the
trace, computable for all ``s`` by the recurrence ``V(s) = max(q(s), min(p(s), V(s+1)))``,
``V(m) = -inf``).

Proof. (1) For ``t' >= s`` split ``[t, t') = [t, s) u [s, t')``, so the inner min is
``min(A(t), min_{[s,t')} p)``; since ``min(A, .)`` distributes over ``max``,
``U(t) = min(A(t), W(s))`` with ``W(s) = max_{t' in [s, s+w]} g(t')``,
``g(t') = min(q(t'), P(t'))``, ``P(t') = min_{[s,t')} p`` (non-increasing in ``t'``).
(2) ``W(s) <= F(s)`` (each ``g(t') <= q(t')``) and ``W(s) <= V(s)`` (``V`` maximises ``g`` over a
superset, as ``s + w <= m - 1`` wherever ``U(t)`` is defined). (3) Conversely let
``t* in [s, s+w]`` attain ``F(s) = q(t*)``. If ``V(s)`` is attained in ``[s, s+w]`` then
``V(s) = W(s)``. Otherwise it is attained at some ``t' > s + w`` and
``V(s) <= P(t') <= P(s+w+1) <= P(t*)``, hence
``g(t*) = min(F(s), P(t*)) >= min(F(s), V(s))`` and ``W(s) >= min(F(s), V(s))``.
So ``W = min(F, V)`` and ``U(t) = min(A(t), F(t+ta), V(t+ta))``. Every step only selects
values (min/max), so the result is bit-identical to the definition, including the +inf
empty-range rule (``ta = 0``), zero-width intervals (``w = 0``: ``F = q`` and ``V >= q``) and
offset intervals. ``A`` and ``F`` are window filters.

``V`` is a backward scan of maps ``x -> max(q(s), min(p(s), x))``. Each such map is a clamp
``x -> min(max(x, l), h)`` with ``l = q(s)``, ``h = max(q(s), p(s))`` (if ``p < q`` it is the
constant ``q``), and clamps compose into clamps: applying ``(l1, h1)`` then ``(l2, h2)`` is
``(clamp(l1; l2, h2), clamp(h1; l2, h2))``. The composed prefixes come from a work-efficient
(Blelloch-style) parallel scan: O(n) total work in O(log n) vectorised numpy passes, no
per-sample Python loop. ``V(s)`` is the ``l`` of the composition applied to ``-inf``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.ndimage import maximum_filter1d, minimum_filter1d

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
from planner.stl.functions import RowView
from planner.stl.signals import numpy_signals


@dataclass(frozen=True, slots=True)
class Witness:
    """One link of the chain that decides a robustness value (see :func:`weakest`).

    Attributes:
        formula: the sub-formula.
        step: the sample step at which it is evaluated.
        t_s: the same time in seconds (``step * dt``).
        robustness: its exact robustness there.
    """

    formula: Formula
    step: int
    t_s: float
    robustness: float

    def __str__(self) -> str:
        return f"{self.formula} at t={self.t_s:g} s (step {self.step}): {self.robustness:+.6g}"


# --------------------------------------------------------------------------- windows and until


def window_extreme(x: np.ndarray, lo: int, hi: int, *, minimum: bool) -> np.ndarray:
    """``out[t] = min (or max) of x[t+lo .. t+hi]`` for every ``t`` whose window fits.

    Args:
        x: (m,) float array.
        lo, hi: window steps, ``0 <= lo <= hi``.
        minimum: min when True, else max.

    Returns:
        (m - hi,) float array (empty when the window never fits).
    """
    length = x.shape[0] - hi
    if length <= 0:
        return np.empty(0)
    width = hi - lo + 1
    segment = x[lo : hi + length]
    if width == 1:
        return segment.copy()
    filt = minimum_filter1d if minimum else maximum_filter1d
    filtered = filt(segment, size=width, mode="nearest")
    # scipy centres the window: output j covers segment[j - width//2 : j - width//2 + width].
    half = width // 2
    return filtered[half : half + length]


def _compose_prefix(low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Prefix compositions of clamps ``e_i(x) = min(max(x, low_i), high_i)``, ``low <= high``.

    Returns ``(L, H)`` with ``e_i o e_{i-1} o ... o e_0 = clamp(.; L_i, H_i)``: a work-efficient
    scan (pairs are combined, the half-length problem is solved recursively, then the even
    entries are filled in), O(m) work in O(log m) numpy passes.
    """
    m = low.shape[0]
    if m == 1:
        return low.copy(), high.copy()
    even_l, even_h = low[0::2], high[0::2]
    odd_l, odd_h = low[1::2], high[1::2]
    pairs = m // 2
    # e_{2i+1} o e_{2i}  (in place: fewer temporaries on the 10^6-sample path)
    pair_l = np.maximum(even_l[:pairs], odd_l)
    np.minimum(pair_l, odd_h, out=pair_l)
    pair_h = np.maximum(even_h[:pairs], odd_l)
    np.minimum(pair_h, odd_h, out=pair_h)
    pre_l, pre_h = _compose_prefix(pair_l, pair_h)
    out_l = np.empty(m)
    out_h = np.empty(m)
    out_l[1::2] = pre_l
    out_h[1::2] = pre_h
    out_l[0] = low[0]
    out_h[0] = high[0]
    n_even = even_l.shape[0]
    # e_{2i} o (e_{2i-1} o ... o e_0), i >= 1
    for out, pre in ((out_l, pre_l), (out_h, pre_h)):
        target = out[2::2]
        np.maximum(pre[: n_even - 1], even_l[1:], out=target)
        np.minimum(target, even_h[1:], out=target)
    return out_l, out_h


def until_unbounded(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``V(s) = max_{t' in [s, m)} min(q(t'), min_{[s, t')} p)`` for all s (O(m), vectorised).

    Args:
        p, q: (m,) traces of the left and right operands.
    """
    # V(s) = f_s(V(s+1)), f_s = clamp(.; q_s, max(q_s, p_s)); V(m) = -inf. Reversed, V is the
    # prefix composition applied to -inf, i.e. its lower clamp bound.
    low = q[::-1]
    high = np.maximum(q, p)[::-1]
    composed_low, _ = _compose_prefix(np.ascontiguousarray(low), np.ascontiguousarray(high))
    return composed_low[::-1]


def until_trace(p: np.ndarray, q: np.ndarray, ta: int, tb: int) -> np.ndarray:
    """Exact ``phi until[ta,tb] psi`` trace from the operand traces ``p`` and ``q`` (steps).

    Returns:
        (m - tb,) array, ``m = min(len(p), len(q))``; see the module docstring for the proof.
    """
    m = min(p.shape[0], q.shape[0])
    p = p[:m]
    q = q[:m]
    length = m - tb
    if length <= 0:
        return np.empty(0)
    reach = window_extreme(q[ta:], 0, tb - ta, minimum=False)[:length]
    result = np.minimum(reach, until_unbounded(p, q)[ta : ta + length])
    if ta > 0:  # A(t) = min p[t, t+ta); +inf (no effect) when ta = 0
        np.minimum(result, window_extreme(p, 0, ta - 1, minimum=True)[:length], out=result)
    return result


# --------------------------------------------------------------------------- evaluator


class ExactEvaluator:
    """Exact traces of the nodes of one formula on one set of numpy signals (cached per node)."""

    def __init__(self, signals: Mapping[str, Any], dt: float) -> None:
        self.dt = check_dt(dt)
        self.signals, self.n = numpy_signals(signals)
        self._view = RowView(self.signals, 0, self.n)
        self._traces: dict[int, tuple[Formula, np.ndarray]] = {}

    def check_length(self, formula: Formula) -> None:
        """:class:`TraceLengthError` unless the trace covers the formula's horizon."""
        needed = formula.horizon_steps(self.dt) + 1
        if self.n < needed:
            raise TraceLengthError(needed, self.n, self.dt, formula.horizon)

    def trace(self, node: Formula) -> np.ndarray:
        """(n - H,) exact robustness trace of ``node`` (H its horizon in steps)."""
        hit = self._traces.get(id(node))
        if hit is not None:
            return hit[1]
        value = self._compute(node)
        self._traces[id(node)] = (node, value)  # keeps node alive so its id stays unique
        return value

    def _compute(self, node: Formula) -> np.ndarray:
        n = self.n
        if isinstance(node, BoolConst):
            return np.full(n, np.inf if node.value else -np.inf)
        if isinstance(node, Comparison):
            diff = comparison_margin(node.op, self.expr(node.lhs), self.expr(node.rhs))
            if isinstance(diff, np.ndarray) and diff.shape == (n,):
                return diff  # already a fresh array
            return np.full(n, float(diff))
        if isinstance(node, Predicate):
            return np.asarray(self.expr(node.call), dtype=float)
        if isinstance(node, Not):
            return -self.trace(node.child)
        if isinstance(node, And | Or):
            kids = [self.trace(child) for child in node.operands]
            length = min(kid.shape[0] for kid in kids)
            reduce = np.minimum.reduce if isinstance(node, And) else np.maximum.reduce
            return reduce([kid[:length] for kid in kids])
        if isinstance(node, Implies):
            lhs = self.trace(node.lhs)
            rhs = self.trace(node.rhs)
            length = min(lhs.shape[0], rhs.shape[0])
            return np.maximum(-lhs[:length], rhs[:length])
        if isinstance(node, Always | Eventually):
            ta, tb = node.steps(self.dt)
            return window_extreme(self.trace(node.child), ta, tb, minimum=isinstance(node, Always))
        if isinstance(node, Until):
            ta, tb = node.steps(self.dt)
            return until_trace(self.trace(node.lhs), self.trace(node.rhs), ta, tb)
        raise EvaluationError(f"cannot evaluate node of type {type(node).__name__}")

    def expr(self, node: Expr) -> np.ndarray | float:
        """Values of an expression: (n,) array, or a float for constant sub-expressions."""
        return fold_expr(
            node, self._signal, lambda c: call_numpy(c, self._view, self.n), div=np.divide
        )

    def _signal(self, node: Signal) -> np.ndarray:
        if node.name not in self.signals:
            raise UnknownSignalError(node.name, tuple(self.signals))
        values = self.signals[node.name]
        if values.ndim != 1:
            raise SignalShapeError(
                f"signal {node.name!r} has shape {values.shape}: arithmetic and comparisons "
                f"need a scalar signal (use a function for vector signals)"
            )
        return values


def call_numpy(node: Call, view: Mapping[str, Any], rows: int) -> np.ndarray:
    """Run a function's numpy implementation and check it returned (rows,) finite floats."""
    out = np.asarray(node.function.numpy_impl(node.args, view), dtype=float)
    if out.ndim == 2 and out.shape[1] == 1:
        out = out[:, 0]
    if out.shape != (rows,):
        raise SignalShapeError(
            f"function {node.name!r} (numpy) returned shape {out.shape}, expected ({rows},)"
        )
    if not np.isfinite(out).all():
        raise SignalShapeError(f"function {node.name!r} returned non-finite values for {node}")
    return out


def robustness_trace(formula: Formula, signals: Mapping[str, Any], dt: float) -> np.ndarray:
    """Exact robustness trace (see :meth:`Formula.robustness_trace`)."""
    evaluator = ExactEvaluator(signals, dt)
    evaluator.check_length(formula)
    return evaluator.trace(formula)


def weakest(formula: Formula, signals: Mapping[str, Any], dt: float) -> tuple[Witness, ...]:
    """The chain of (sub-formula, time) that decides the robustness at t = 0.

    From the root at step 0, each step goes to the operand that attains the min/max (the first
    one on ties): the weakest conjunct of an ``and``, the strongest disjunct of an ``or``, the
    step where an ``always`` attains its min, and so on, down to an atom. Every witness's
    robustness equals the root's up to sign (``not`` and ``implies`` flip it).

    Returns:
        witnesses, root first, the deciding atom (comparison, predicate or constant) last.
    """
    evaluator = ExactEvaluator(signals, dt)
    evaluator.check_length(formula)
    chain: list[Witness] = []
    node, step = formula, 0
    while True:
        value = float(evaluator.trace(node)[step])
        chain.append(Witness(node, step, step * evaluator.dt, value))
        nxt = _deciding_child(evaluator, node, step)
        if nxt is None:
            return tuple(chain)
        node, step = nxt


def explanation(chain: tuple[Witness, ...]) -> tuple[Witness, ...]:
    """The part of a :func:`weakest` chain that explains the root in its own sign.

    Below a ``not`` (or the left side of an ``implies``) the chain's values flip sign: for
    ``always not (inside(d1, bay) and inside(d2, bay))`` the deciding atom
    ``inside(d1, bay)`` is *positive* where the clause fails. Reporting it as the reason
    would explain a failure by a value that passes. This cuts the chain after its deepest
    witness with the root's sign (an even number of flips above it): here
    ``not (inside(d1, bay) and inside(d2, bay))``, which names both vehicles, with the
    clause's own (negative) value. A chain without flips is returned whole.

    Returns:
        a non-empty prefix of ``chain`` (``chain`` itself when it is empty).
    """
    keep = len(chain)
    flips = 0
    for i, w in enumerate(chain):
        if flips % 2 == 0:
            keep = i + 1
        node = w.formula
        nxt = chain[i + 1].formula if i + 1 < len(chain) else None
        if isinstance(node, Not) or (isinstance(node, Implies) and nxt is node.lhs):
            flips += 1
    return chain[:keep]


def _deciding_child(ev: ExactEvaluator, node: Formula, t: int) -> tuple[Formula, int] | None:
    if isinstance(node, Not):
        return node.child, t
    if isinstance(node, And | Or):
        values = np.array([ev.trace(child)[t] for child in node.operands])
        pick = np.argmin(values) if isinstance(node, And) else np.argmax(values)
        return node.operands[int(pick)], t
    if isinstance(node, Implies):
        lhs = ev.trace(node.lhs)[t]
        rhs = ev.trace(node.rhs)[t]
        return (node.lhs, t) if -lhs >= rhs else (node.rhs, t)
    if isinstance(node, Always | Eventually):
        ta, tb = node.steps(ev.dt)
        window = ev.trace(node.child)[t + ta : t + tb + 1]
        pick = np.argmin(window) if isinstance(node, Always) else np.argmax(window)
        return node.child, t + ta + int(pick)
    if isinstance(node, Until):
        ta, tb = node.steps(ev.dt)
        p = ev.trace(node.lhs)
        q = ev.trace(node.rhs)
        # prefix[j] = min p[t .. t+j-1] (+inf for j = 0)
        prefix = np.concatenate(([np.inf], np.minimum.accumulate(p[t : t + tb])))
        inner = np.minimum(q[t + ta : t + tb + 1], prefix[ta : tb + 1])
        best = t + ta + int(np.argmax(inner))
        if q[best] <= prefix[best - t]:
            return node.rhs, best
        return node.lhs, t + int(np.argmin(p[t:best]))
    return None
