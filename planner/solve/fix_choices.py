"""The spec with its discrete choices fixed: what the NLP refines after the combinatorial stage.

A spec's ``or``, ``eventually``, ``until`` and ``implies`` are choices: which option, which
time, which side.  The NLP's smooth robustness keeps every option alive (log-sum-exp), which
is what lets it choose, and also what makes it slow and easy to pull away from a good plan.
Once the combinatorial stage has chosen (:mod:`planner.solve.coarse_start`), :func:`fixed_clauses`
reads its choices off a trajectory with the exact semantics and writes the spec as a
conjunction of ``always[a, b] atom`` clauses: the option an ``or`` takes there, the step where
an ``eventually`` peaks, the witness of an ``until``, the side of an ``implies`` that decides
it (negations pushed to the atoms first, which keeps every value: ``rho(not phi) =
-rho(phi)``, min and max swap).  Every clause of the result is one the NLP encodes exactly,
without smoothing, and

    robustness(fixed, x) <= robustness(spec, x)   for every trajectory x,

with equality at the trajectory the choices were read from (each choice is the operand or step
that attains the max there).  So a plan that meets the fixed spec meets the spec.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from planner.problem import Clause, Problem
from planner.stl import (
    Always,
    And,
    BoolConst,
    Eventually,
    Formula,
    Implies,
    Not,
    Or,
    Until,
)

__all__ = ["choices_problem", "fixed_clauses", "negated"]


def negated(node: Formula) -> Formula:
    """``not node`` with the negation pushed towards the atoms (the same robustness)."""
    if isinstance(node, Not):
        return node.child
    if isinstance(node, And):
        return Or(tuple(negated(c) for c in node.operands))
    if isinstance(node, Or):
        return And(tuple(negated(c) for c in node.operands))
    if isinstance(node, Always):
        return Eventually(negated(node.child), node.start_s, node.end_s)
    if isinstance(node, Eventually):
        return Always(negated(node.child), node.start_s, node.end_s)
    if isinstance(node, Implies):
        return And((node.lhs, negated(node.rhs)))
    if isinstance(node, BoolConst):
        return BoolConst(not node.value)
    return Not(node)  # an atom, or an until (kept whole)


def _choice_free(node: Formula) -> bool:
    """No choice below: only ``and``, ``always`` and atoms (or negated atoms)."""
    if isinstance(node, And):
        return all(_choice_free(c) for c in node.operands)
    if isinstance(node, Always):
        return _choice_free(node.child)
    if isinstance(node, Not):
        return not node.child.children
    return not isinstance(node, Or | Eventually | Until | Implies)


class _Fixer:
    def __init__(self, signals: Mapping[str, Any], dt: float) -> None:
        self.signals, self.dt = signals, dt
        self._traces: dict[int, tuple[Formula, np.ndarray]] = {}
        #: (atom formula, first step, last step), absolute steps from the plan's start
        self.out: list[tuple[Formula, int, int]] = []

    def trace(self, node: Formula) -> np.ndarray:
        got = self._traces.get(id(node))
        if got is None:
            got = (node, node.robustness_trace(self.signals, self.dt))
            self._traces[id(node)] = got  # the node kept alive with its trace (its id)
        return got[1]

    def fix(self, node: Formula, t: int) -> None:
        if isinstance(node, BoolConst):
            if not node.value:
                self.out.append((node, t, t))
        elif isinstance(node, And):
            for c in node.operands:
                self.fix(c, t)
        elif isinstance(node, Or):
            values = [self.trace(c)[t] for c in node.operands]
            self.fix(node.operands[int(np.argmax(values))], t)
        elif isinstance(node, Always):
            ta, tb = node.steps(self.dt)
            if _choice_free(node.child):
                self.out.append((node.child, t + ta, t + tb))
            else:
                for s in range(t + ta, t + tb + 1):
                    self.fix(node.child, s)
        elif isinstance(node, Eventually):
            ta, tb = node.steps(self.dt)
            window = self.trace(node.child)[t + ta : t + tb + 1]
            self.fix(node.child, t + ta + int(np.argmax(window)))
        elif isinstance(node, Implies):
            if -self.trace(node.lhs)[t] >= self.trace(node.rhs)[t]:
                self.fix(negated(node.lhs), t)
            else:
                self.fix(node.rhs, t)
        elif isinstance(node, Not) and node.child.children and not isinstance(node.child, Until):
            self.fix(negated(node.child), t)
        elif isinstance(node, Until):
            ta, tb = node.steps(self.dt)
            p, q = self.trace(node.lhs), self.trace(node.rhs)
            prefix = np.concatenate(([np.inf], np.minimum.accumulate(p[t : t + tb])))
            inner = np.minimum(q[t + ta : t + tb + 1], prefix[ta : tb + 1])
            best = t + ta + int(np.argmax(inner))
            self.fix(node.rhs, best)
            if best > t:
                if _choice_free(node.lhs):
                    self.out.append((node.lhs, t, best - 1))
                else:
                    for s in range(t, best):
                        self.fix(node.lhs, s)
        else:  # an atom, a negated atom, a negated until: held where it stands
            self.out.append((node, t, t))


def fixed_clauses(
    formula: Formula, signals: Mapping[str, Any], dt: float
) -> list[tuple[Formula, float, float]] | None:
    """The spec with the choices the trajectory ``signals`` makes, as ``always[a, b] f``
    clauses (module docstring): ``(f, a_s, b_s)`` each, ``f`` free of choices, steps of
    one formula merged where they touch.  None when the spec has no choice to fix.

    Args:
        formula: the whole spec (evaluated at t = 0).
        signals: the trajectory's samples every ``dt`` (the exact semantics' signals).
        dt: the sample step (s).
    """
    if _choice_free(formula):
        return None
    fixer = _Fixer(signals, dt)
    fixer.fix(formula, 0)
    spans: dict[str, tuple[Formula, list[tuple[int, int]]]] = {}
    for f, lo, hi in fixer.out:
        spans.setdefault(str(f), (f, []))[1].append((lo, hi))
    out: list[tuple[Formula, float, float]] = []
    for f, steps in spans.values():
        steps.sort()
        merged = [list(steps[0])]
        for lo, hi in steps[1:]:
            if lo <= merged[-1][1] + 1:
                merged[-1][1] = max(merged[-1][1], hi)
            else:
                merged.append([lo, hi])
        out.extend((f, lo * dt, hi * dt) for lo, hi in merged)
    return out


def choices_problem(
    problem: Problem, formula: Formula, signals: Mapping[str, np.ndarray]
) -> Problem | None:
    """``problem`` with its spec ``formula``'s choices fixed where ``signals`` (sampled every
    ``sample_dt_s``) take them (:func:`fixed_clauses`): clauses ``choices[i]``, one start, no
    combinatorial stage; None when the spec has no choice to fix."""
    fixed = fixed_clauses(formula, signals, problem.timing.sample_dt_s)
    if fixed is None:
        return None
    clauses = tuple(
        Clause(f"choices[{i}]", str(Always(f, a, b))) for i, (f, a, b) in enumerate(fixed)
    )
    return dataclasses.replace(
        problem,
        clauses=clauses,
        solver=dataclasses.replace(problem.solver, starts=1, coarse_s=0.0),
    )
