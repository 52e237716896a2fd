"""Derivatives of the row-wise leaves, differentiated once per leaf at one sample.

A row-wise leaf of the NLP (:func:`planner.solve.leaves.is_direct`: a predicate or a comparison,
``outside(d, pole7)``, ``dist(d1, d2) >= 1.5``) is the same function of the vehicles'
positions at every constraint step: its rows at step ``j`` depend on the lifted positions of
that step only.  Differentiating the whole block (every step at once) twice, as CasADi's
``hessian`` of ``lam . rows`` does, repeats the symbolic work per step and colours a matrix
of thousands of columns; on the 40-pole line (4 drones, 300 s, 326 such blocks) that was
21 s of the 53 s build (``which_depends`` and ``hessian``), and the Jacobians 5.5 s more.

Here the leaf is written at one sample, ``v(x)`` with ``x`` the positions of the vehicles it
names (3 per vehicle, in the order of ``names``); its Jacobian ``J(x) = dv/dx`` and Hessian
``H(x, lam) = d2 (lam . v) / dx2`` are built once, and the block's derivatives are those
functions mapped over the steps (one ``rows x 3m`` / ``3m x 3m`` block per step) and
scattered into the NLP's rows and variables, in MX: the NLP's derivative functions call the
mapped functions instead of holding every step's expressions
(:func:`planner.solve.nlp_solvers.derivatives`).  The values are the same expressions, so IPOPT
sees the same numbers (checked against CasADi's own ``jacobian`` and ``hessian`` in
``tests/planner/test_rowwise.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

__all__ = ["SampleLeaf", "block_hessian", "block_jacobian", "sample_leaf"]


@dataclass(frozen=True, slots=True)
class SampleLeaf:
    """A row-wise leaf at one sample.

    Attributes:
        vehicles: indices (into the ``names`` it was built with) of the vehicles whose
            positions the leaf depends on; ``x`` is their positions, vehicle after vehicle.
        rows: rows of the leaf per sample (a box's faces, or 1).
        jac: ``x (3m, 1) -> dv/dx (rows, 3m)``.
        hess: ``(x (3m, 1), lam (rows, 1)) -> d2 (lam . v) / dx2 (3m, 3m)``.
    """

    vehicles: tuple[int, ...]
    rows: int
    jac: Any
    hess: Any


def sample_leaf(
    values: Callable[[Mapping[str, Any]], Any], names: Sequence[str]
) -> SampleLeaf | None:
    """The leaf whose rows at one sample are ``values({name: (1, 3) position})`` (a column, or
    a row of faces), as a :class:`SampleLeaf`; None when it depends on no position
    (constant rows)."""
    xs = {nm: ca.SX.sym(f"x_{nm}", 1, 3) for nm in names}
    v = ca.vec(values(xs))
    used = tuple(i for i, nm in enumerate(names) if ca.depends_on(v, xs[nm]))
    if not used:
        return None
    x = ca.vertcat(*[xs[names[i]].T for i in used])
    lam = ca.SX.sym("lam", v.shape[0])
    h = ca.hessian(ca.dot(lam, v), x)[0]
    return SampleLeaf(
        used,
        int(v.shape[0]),
        ca.Function("row_jac", [x], [ca.jacobian(v, x)]),
        ca.Function("row_hess", [x, lam], [h]),
    )


def _positions(w: Any, cols: np.ndarray) -> Any:
    """``(3m, n)``: column j is ``x`` at step j."""
    n, m = cols.shape
    return ca.reshape(w[cols.reshape(-1).tolist()], m, n)


def _selection(cols: np.ndarray, n_w: int) -> Any:
    """``(n 3m, n_w)``: row ``j 3m + k`` picks ``w[cols[j, k]]``."""
    flat = cols.reshape(-1).tolist()
    return ca.DM(ca.Sparsity.triplet(len(flat), n_w, list(range(len(flat))), flat), 1.0)


def block_jacobian(leaf: SampleLeaf, w: Any, cols: np.ndarray) -> Any:
    """``d rows / dw`` of the leaf's block, ``(rows n, n_w)``, of ``w``'s kind (SX or MX), in
    the block's row order
    (the rows of one face for every step, then the next face's: the steps run fastest).

    Args:
        leaf: the leaf at one sample.
        w: the NLP's variables (an SX or MX column; the planner passes MX, so that the mapped
            functions stay calls instead of being expanded step by step).
        cols: ``(n, 3m)`` indices into ``w`` of ``x`` at each of the block's ``n`` steps.
    """
    n, m = cols.shape
    r = leaf.rows
    diag = ca.diagcat(*ca.horzsplit(leaf.jac.map(n)(_positions(w, cols)), m))  # rows (j, f)
    order = np.arange(n * r).reshape(n, r).T.reshape(-1)  # row (f, j) <- row (j, f)
    perm = ca.DM(ca.Sparsity.triplet(n * r, n * r, list(range(n * r)), order.tolist()), 1.0)
    return ca.mtimes(ca.mtimes(perm, diag), _selection(cols, int(w.shape[0])))


def block_hessian(leaf: SampleLeaf, w: Any, cols: np.ndarray, lam: Any) -> Any:
    """``d2 (lam . rows) / dw2`` of the leaf's block, ``(n_w, n_w)``, of ``w``'s kind.

    Args:
        leaf: the leaf at one sample.
        w: the NLP's variables (an SX or MX column, as :func:`block_jacobian`).
        cols: ``(n, 3m)`` indices into ``w`` of ``x`` at each of the block's ``n`` steps.
        lam: the block's ``rows * n`` multipliers, in the block's row order (the rows of
            one face for every step, then the next face's: the steps run fastest).
    """
    n, m = cols.shape
    lam_steps = ca.reshape(lam, n, leaf.rows).T  # column j: the multipliers of step j
    blocks = ca.horzsplit(leaf.hess.map(n)(_positions(w, cols), lam_steps), m)
    sel = _selection(cols, int(w.shape[0]))
    return ca.mtimes(ca.mtimes(sel.T, ca.diagcat(*blocks)), sel)
