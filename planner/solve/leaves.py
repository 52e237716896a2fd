"""The spec's conjunctive leaves for the NLP: the ``and``/``always`` walk that collects them
with their sample steps (:func:`decompose`), the row-wise ones' constraint steps
(:func:`row_steps`), a long ``eventually`` split into chunks
(:func:`chunks_of`), and the log-sum-exp that joins a chunked leaf's values (:func:`lse`).
Why: ``docs/solver-notes.md``, "The formulation".
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from planner.cache import BoundedCache
from planner.problem import Problem
from planner.solve.leaf_templates import canonical_leaf
from planner.stl import Always, And, BoolConst, Comparison, Eventually, Formula, Predicate

__all__ = [
    "CHUNK_ABOVE_SEGMENTS",
    "CHUNK_SEGMENTS",
    "Lse",
    "chunks_of",
    "constraint_stride",
    "decompose",
    "direct_steps_of",
    "is_direct",
    "local_positions",
    "lse",
    "row_steps",
]

#: A smooth ``eventually`` leaf whose window spans more segments than this, divided by the
#: vehicles it names, is split into chunks of ``CHUNK_SEGMENTS`` segments (:func:`chunks_of`).
#: The dense Hessian of a whole window grows with the square of segments x vehicles: the
#: allocation mission's ``eventually[0, 58]`` over three vehicles (19 segments each) took
#: 29 s of CasADi as one template, 3.3 s in chunks.
CHUNK_ABOVE_SEGMENTS = 24


CHUNK_SEGMENTS = 4


def decompose(node: Formula, steps: np.ndarray, dt: float, out: dict[Formula, set[int]]) -> None:
    """Collect conjunctive leaves: walk ``and``/``always`` from the root, track steps."""
    if isinstance(node, And):
        for child in node.operands:
            decompose(child, steps, dt, out)
    elif isinstance(node, Always):
        lo, hi = node.steps(dt)
        shifted = np.unique((steps[:, None] + np.arange(lo, hi + 1)[None, :]).ravel())
        decompose(node.child, shifted, dt, out)
    elif isinstance(node, BoolConst) and node.value:
        return
    else:
        out.setdefault(node, set()).update(int(s) for s in steps)


def chunks_of(leaf: Formula, step: int, dt: float, per_segment: int) -> list[tuple[Formula, int]]:
    """``eventually[a, b] psi`` at ``step``, when its window is long (times the vehicles it
    names: :data:`CHUNK_ABOVE_SEGMENTS`), as chunks
    ``(eventually[0, c] psi, first step)`` of ``CHUNK_SEGMENTS`` segments, their boundaries
    on multiples of that length; ``[]`` for any other leaf.

    The smooth eventually is ``1/k log sum_t exp(k psi(t))`` over the window, and a log-sum-exp
    over the chunks' log-sum-exps is the same number.  The NLP holds each chunk's value in a
    variable ``s_c`` (an equality row that touches only the decisions of the chunk's few
    segments) and the leaf as the log-sum-exp of its ``s_c``: the leaf's Hessian is block
    banded instead of dense over the whole horizon, and every chunk away from the start is
    the same template (:mod:`planner.solve.leaf_templates`), whichever pole it names.
    """
    if not isinstance(leaf, Eventually):
        return []
    a, b = leaf.steps(dt)
    vehicles = max(1, len(canonical_leaf(leaf)[1]))
    if (b - a + 1) * vehicles <= CHUNK_ABOVE_SEGMENTS * per_segment:
        return []
    length = CHUNK_SEGMENTS * per_segment
    out: list[tuple[Formula, int]] = []
    lo, last = step + a, step + b
    while lo <= last:
        hi = min(last, (lo // length + 1) * length - 1)
        out.append((Eventually(leaf.child, 0.0, (hi - lo) * dt), lo))
        lo = hi + 1
    return out


def local_positions(model: Any) -> bool:
    """Whether each sampled position depends on a few decision rows only (a primitive
    chain's segment ends; not a double integrator's accelerations, which every later position
    sums): only then does a chunk touch few decisions, and chunking pays."""
    mp = np.abs(np.asarray(model.Mp)) > 0.0
    return bool(mp.any()) and int(mp.sum(axis=1).max()) * 4 <= mp.shape[1]


@dataclass(frozen=True, slots=True)
class Lse:
    """``(1/k) log sum exp(k s)`` of ``m`` values, its gradient and ``lam`` times its
    Hessian (a chunked leaf's row, :func:`chunks_of`)."""

    value: Any
    value_grad: Any
    hess: Any


#: The log-sum-exp functions by (size, sharpness), oldest forgotten first.
_LSE: BoundedCache[Lse] = BoundedCache(64)


def lse(m: int, k: float) -> Lse:
    def build() -> Lse:
        s = ca.SX.sym("s", m)
        shift = ca.mmax(s)  # the value and its derivatives do not depend on the shift
        value = shift + ca.log(ca.sum1(ca.exp(k * (s - shift)))) / k
        lam = ca.SX.sym("lam")
        return Lse(
            value=ca.Function("lse", [s], [value]),
            value_grad=ca.Function("lse_grad", [s], [value, ca.jacobian(value, s)]),
            hess=ca.Function("lse_hess", [s, lam], [lam * ca.hessian(value, s)[0]]),
        )

    return _LSE.get_or_build((m, k), build)[0]


def is_direct(node: Formula) -> bool:
    """Leaves evaluated directly (vectorised over steps) rather than through the engine."""
    return isinstance(node, Comparison | Predicate)


def constraint_stride(problem: Problem) -> int:
    """Planning samples between two constraint steps of a row-wise leaf
    (``solver.constraint_dt_s``, by default every sample, at most every 0.1 s)."""
    dt = problem.timing.sample_dt_s
    c_dt = problem.solver.constraint_dt_s
    return max(1, round((c_dt if c_dt is not None else max(dt, 0.1)) / dt))


def direct_steps_of(leaves: Mapping[Formula, set[int]], stride: int) -> dict[Formula, list[int]]:
    """The constraint steps of each row-wise leaf of ``leaves`` (:func:`decompose`'s): every
    ``stride``-th of its steps, and its last."""
    out: dict[Formula, list[int]] = {}
    for leaf, steps_set in leaves.items():
        if is_direct(leaf):
            steps = sorted(steps_set)
            out[leaf] = sorted(set(steps[::stride]) | {steps[-1]})
    return out


def row_steps(problem: Problem, formula: Formula) -> dict[Formula, list[int]]:
    """The row-wise leaves of ``formula`` and their constraint steps, as the NLP has them."""
    leaves: dict[Formula, set[int]] = {}
    decompose(formula, np.array([0]), problem.timing.sample_dt_s, leaves)
    return direct_steps_of(leaves, constraint_stride(problem))
