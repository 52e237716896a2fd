"""Signal Temporal Logic: formula tree, parser, exact and smooth robustness.

Usage::

    import numpy as np
    from planner.stl import parse

    phi = parse("always[0,5] (a >= 0.3) and eventually[2,4] (b < 1)")
    t_s = np.arange(0.0, 10.0, 0.1)
    signals = {"a": 0.5 + 0.1 * np.sin(t_s), "b": 2.0 - 0.4 * t_s}
    phi.horizon                                    # 5.0 seconds
    phi.robustness(signals, dt=0.1)                # exact robustness at t = 0 (float)
    phi.robustness_trace(signals, dt=0.1)          # (n - H,) exact trace, see below
    phi.smooth_robustness(signals, dt=0.1, k=50)   # log-sum-exp robustness at t = 0
    phi.smooth_error_bound(k=50, dt=0.1)           # |smooth - exact| <= this
    phi.smooth_robustness_trace(signals, 0.1, 50)  # smooth value at every step, one graph
    [c.robustness(signals, 0.1) for c in phi.clauses]   # per conjunct of a top-level "and"
    phi.weakest(signals, dt=0.1)[-1]               # deciding atom and its time (Witness)

With CasADi signals (SX/MX matrices (n, 1) for scalars, (n, 3) for vehicle positions) the same
call ``phi.smooth_robustness(signals, dt, k)`` returns a CasADi scalar expression; CasADi
differentiates it. Only the sample steps the formula reaches from t = 0 are built into the
graph. Functions (``inside(d1, pole1)``, ``dist(d1, d2)``) come from a :class:`FunctionRegistry`
passed to :func:`parse`; see :mod:`planner.stl.functions` for their calling convention.

STL syntax
----------
===========================  ===============================================================
``true``, ``false``          constants (robustness +inf / -inf)
``e >= c``, ``e > c``        comparison of arithmetic expressions; robustness ``e - c``
``e <= c``, ``e < c``        robustness ``c - e``
``+ - * /``, ``-e``, ``( )`` arithmetic over signal names, numbers and function calls
``f(x, y)``                  registered function; alone it means ``f(x, y) >= 0``
``not p``, ``!p``            negation, robustness ``-rho(p)``
``p and q``, ``p & q``       conjunction (min); chains form one n-ary node
``p or q``, ``p | q``        disjunction (max)
``p implies q``, ``p -> q``  ``max(-rho(p), rho(q))``; right associative
``always[a,b] p``, ``G[a,b] p``      min of p over [t+a, t+b]
``eventually[a,b] p``, ``F[a,b] p``  max of p over [t+a, t+b]
``p until[a,b] q``, ``p U[a,b] q``   q at some t' in [t+a, t+b], p on [t, t'); right associative
``# ...``                    comment to the end of the line
===========================  ===============================================================

Precedence, loosest first: ``implies``, ``or``, ``and``, ``until``, unary (``not``, ``always``,
``eventually``); arithmetic binds tighter than comparisons. Interval bounds are seconds
(``a <= b``, both included); with sample step ``dt`` they cover steps
``ceil(a/dt) .. floor(b/dt)`` (tolerance 1e-9, so ``[0,0.3]`` at ``dt = 0.1`` is steps 0..3).
``G``, ``F``, ``U`` are operators only before ``[``; the words in the table are reserved.

Examples::

    always[0,60] (alt >= 2 and alt <= 30)
    eventually[10,20] inside(d1, pole1) and eventually[30,40] inside(d1, pole4)
    always[0,60] (dist(d1, d2) >= 2 and outside(d1, nofly))
    (speed - 0.5 * limit < 0) until[0,15] (x > 100)
    G[0,10] (a > 1 -> F[0,2] b <= -0.5)        # a > 1 implies b <= -0.5 within 2 s

Semantics and conventions
-------------------------
Robustness follows docs/stl.md, "Semantics" exactly (until: ``max over t' in [t+a, t+b] of
min(rho(q, t'), min over [t, t') of rho(p))``, an empty inner range counting as +inf).
``robustness_trace`` returns the ``n - H`` steps where the formula's whole horizon
(``H = phi.horizon_steps(dt)`` steps) fits in the ``n`` samples: entry ``t`` is exact, no window
is truncated at the end of the trace. A trace with fewer than ``H + 1`` samples raises
:class:`TraceLengthError` naming both lengths. Exact robustness is O(n) per operator whatever
the interval widths (scipy window filters; until by a linear-time decomposition proved in
:mod:`planner.stl.exact`). Smooth robustness and its error bound: :mod:`planner.stl.smooth`.

Errors
------
::

    STLError(Exception)
      SpecError(ValueError)          spec text does not parse: .line .column .token .expected
      FormulaError(ValueError)       a node built in Python with invalid fields
      RegistryError(ValueError)      bad function registration
      EvaluationError(ValueError)    a formula cannot be evaluated on these signals
        UnknownSignalError           .name: a signal the formula reads is missing
        TraceLengthError             .needed .given: trace shorter than the horizon
        SignalShapeError             wrong shape/type, non-finite values, bad function output
        SamplingError                dt not positive, or an interval without a sample step
"""

from __future__ import annotations

from planner.stl.ast import (
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
    Expr,
    Formula,
    Implies,
    Neg,
    Not,
    Or,
    Predicate,
    Signal,
    Until,
    comparison_margin,
    conjunction,
    fold_expr,
    interval_steps,
)
from planner.stl.errors import (
    EvaluationError,
    FormulaError,
    RegistryError,
    SamplingError,
    SignalShapeError,
    SpecError,
    STLError,
    TraceLengthError,
    UnknownSignalError,
)
from planner.stl.exact import Witness, explanation
from planner.stl.functions import Function, FunctionRegistry
from planner.stl.parser import parse

__all__ = [
    "Always",
    "And",
    "ArithOp",
    "BinOp",
    "BoolConst",
    "Call",
    "CmpOp",
    "Comparison",
    "Const",
    "EvaluationError",
    "Eventually",
    "Expr",
    "Formula",
    "FormulaError",
    "Function",
    "FunctionRegistry",
    "Implies",
    "Neg",
    "Not",
    "Or",
    "Predicate",
    "RegistryError",
    "STLError",
    "SamplingError",
    "Signal",
    "SignalShapeError",
    "SpecError",
    "TraceLengthError",
    "UnknownSignalError",
    "Until",
    "Witness",
    "comparison_margin",
    "conjunction",
    "explanation",
    "fold_expr",
    "interval_steps",
    "parse",
]
