"""Big-M encoding of STL robustness over the coarse samples (Raman et al. 2014).

Every (sub-formula, step) the spec reaches from step 0 gets a linear expression ``r`` that is
a *lower bound* of its true robustness on the coarse samples (``r <= rho``), and the program
maximises the root's. So whatever the solver returns, the exact robustness of its waypoints
is at least the reported one; the best bound is an upper bound of this lower-bounding model
(an upper bound of the true optimum only where every atom is encoded exactly, see below).

Encodings, after negations are pushed to the atoms (negation normal form):

* ``and`` / ``always[a,b]``: ``r <= r_i`` for every operand / step of the window; with
  ``cover`` (the default), the window of an ``always`` is the coarse steps that *cover*
  ``[a, b]`` (``floor(a/dt_c) .. ceil(b/dt_c)``, never past the horizon) instead of those
  inside it, so that the straight legs between samples keep a convex predicate for the whole
  of ``[a, b]``: ``always[0, 2] inside(d, box)`` at 4 s steps asks for two samples in the box
  (a stay the smooth model can fly), not one (a pass through it at full speed);
* ``or`` / ``eventually[a,b]``: binaries ``b_i``, ``r <= r_i + M_i (1 - b_i)``,
  ``sum b_i >= 1``;
* ``phi until[a,b] psi``: prefix minima ``P_k <= P_{k-1}``, ``P_k <= rho(phi, t + k - 1)``,
  then the ``or`` over ``t' in [t+a, t+b]`` of ``min(rho(psi, t'), P_{t'-t})``;
  ``not (phi until psi)`` raises :class:`NotEncodable`;
* comparisons of linear arithmetic of ``x(d)``, ``y(d)``, ``z(d)``, ``alt(d)`` and
  constants: exact (no new column);
* a function term ``w f`` of a comparison is replaced by a column ``delta`` with
  ``w delta <= w f``: ``inside(d, R)`` from below by its face margins (``delta <= m_i``; a
  cylinder by the inscribed polygon, its walls' margins divided by ``cos(pi/n)`` so that they
  stay below the true margin outside too), from above with binaries (``delta >= m_i`` for
  one face, a cylinder by the circumscribed polygon); ``outside = -inside``;
  ``dist(a, b)`` from below by the L-infinity distance (``delta <= +-(p_a - p_b)_i`` for one
  of six choices, binaries), from above by the L1 distance (no binaries);
* ``agl(d)`` (the height above a terrain, bilinear) is *relaxed*, as ``face`` is: ``z`` less
  a plane under the ground where a floor is asked (``agl >= h``), over it where a ceiling is
  (:meth:`~planner.spec.terrain.Terrain.plane_bounds`; no new column), recorded in
  :attr:`Encoder.notes`. Never stricter than the ground, so no coarse infeasibility, and no
  conflict named, comes of it (a plane over the ground would keep every coarse path above the
  highest hill, and claim a ridge the start stands beside impossible); the NLP and the exact
  check keep the floor;
* ``face(d, R)`` (needs the heading, which the coarse model has not): its atom is ``true``
  (recorded in :attr:`Encoder.notes`); the NLP and the exact check decide it.

Big-M constants come from interval bounds of every expression over the position bounds of
the coarse model (the workspace and the reach from the start), never from a guess. A
sub-formula shared by several parents or steps is built once per step: nodes are hashed
structurally (atoms by their linear form) and each node is encoded once, at the union of
the steps its parents need, in vectorised blocks of rows.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from planner.errors import PlannerError
from planner.milp.builder import MilpBuilder
from planner.milp.model import CoarseModel
from planner.spec.regions import Cylinder, Prism, Region
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
    Expr,
    Formula,
    Implies,
    Neg,
    Not,
    Or,
    Predicate,
    Signal,
    Until,
)

__all__ = ["Encoder", "Lin", "MilpError", "NotEncodable"]

Ints = NDArray[np.int64]
Floats = NDArray[np.float64]


class MilpError(PlannerError):
    """Any error of the combinatorial stage (bad arguments, specs it cannot encode)."""


class NotEncodable(MilpError):
    """The spec uses something the MILP cannot encode soundly (a product of signals, a
    negated ``until``, an unknown function): plan without the combinatorial stage."""


# --------------------------------------------------------------------------- affine rows


@dataclass(frozen=True, slots=True)
class Lin:
    """``m`` affine expressions ``sum_k vals[i, k] x[cols[i, k]] + const[i]`` with interval
    bounds ``lo[i] <= value <= hi[i]`` (cols, vals: (m, k); const, lo, hi: (m,))."""

    cols: Ints
    vals: Floats
    const: Floats
    lo: Floats
    hi: Floats

    @staticmethod
    def var(cols: Ints, lo: Floats, hi: Floats) -> Lin:
        """The columns themselves."""
        m = len(cols)
        return Lin(cols.reshape(m, 1), np.ones((m, 1)), np.zeros(m), lo, hi)

    def take(self, idx: Ints) -> Lin:
        """Rows ``idx``."""
        return Lin(self.cols[idx], self.vals[idx], self.const[idx], self.lo[idx], self.hi[idx])

    @staticmethod
    def concat(items: Sequence[Lin]) -> Lin:
        """Rows of all, in order (padded to the widest with zero coefficients)."""
        k = max(it.cols.shape[1] for it in items)

        def pad(a: NDArray[np.generic], fill: float) -> NDArray[np.generic]:
            return np.pad(a, ((0, 0), (0, k - a.shape[1])), constant_values=fill)

        return Lin(
            np.concatenate([pad(it.cols, 0) for it in items]).astype(np.int64),
            np.concatenate([pad(it.vals, 0.0) for it in items]).astype(float),
            np.concatenate([it.const for it in items]),
            np.concatenate([it.lo for it in items]),
            np.concatenate([it.hi for it in items]),
        )


def _le_rows(b: MilpBuilder, r: Ints, lin: Lin, big_m: Floats | None, bins: Ints | None) -> None:
    """Rows ``x[r_i] <= lin_i (+ M_i (1 - x[bins_i]))``."""
    cols = [r[:, None], lin.cols]
    vals = [np.ones((len(r), 1)), -lin.vals]
    hi = lin.const
    if big_m is not None and bins is not None:
        cols.append(bins[:, None])
        vals.append(big_m[:, None])
        hi = hi + big_m
    b.add_rows(np.hstack(cols), np.hstack(vals), -math.inf, hi)


# --------------------------------------------------------------------------- normal form

#: A linear form: (constant, ((key, coefficient), ...)); a key is ("p", vehicle, axis),
#: ("inside", vehicle, region), ("dist", vehicle, vehicle) or ("agl", vehicle, None).
LinForm = tuple[float, tuple[tuple[tuple[str, str, object], float], ...]]


@dataclass(frozen=True, slots=True)
class Node:
    """A node of the negation normal form: ``kind`` is ``atom`` (``r = lin``), ``true``,
    ``false``, ``and``, ``or``, ``always``, ``eventually`` (window ``a..b`` steps) or
    ``until`` (``kids = (lhs, rhs)``)."""

    kind: str
    kids: tuple[Node, ...] = ()
    a: int = 0
    b: int = 0
    lin: LinForm | None = None
    text: str = field(default="", compare=False)


TRUE, FALSE = Node("true"), Node("false")


def _and(kids: Sequence[Node], conj: bool) -> Node:
    """Folded ``and`` (``conj``) or ``or`` of nodes: flattened, constants dropped, repeats
    merged."""
    kind, unit, zero = ("and", TRUE, FALSE) if conj else ("or", FALSE, TRUE)
    out: dict[Node, None] = {}
    for k in kids:
        for kk in k.kids if k.kind == kind else (k,):
            if kk == zero:
                return zero
            if kk != unit:
                out[kk] = None
    items = tuple(out)
    if not items:
        return unit
    return items[0] if len(items) == 1 else Node(kind, items)


#: Relative tolerance of a step on an interval's end (as :func:`planner.stl.interval_steps`).
_STEP_TOL = 1e-9


def covering_steps(start_s: float, end_s: float, dt: float) -> tuple[int, int]:
    """The coarse steps ``(floor(start_s/dt), ceil(end_s/dt))`` whose samples enclose the
    interval (a step within ``1e-9`` of an end counts as on it)."""
    lo_ratio, hi_ratio = start_s / dt, end_s / dt
    lo = math.floor(lo_ratio + _STEP_TOL * max(1.0, abs(lo_ratio)))
    hi = math.ceil(hi_ratio - _STEP_TOL * max(1.0, abs(hi_ratio)))
    return lo, max(lo, hi)


class _Face(MilpError):
    """A ``face`` term: the atom is read as true."""


class Normaliser:
    """Formulas -> :class:`Node` trees at the coarse step, with the atoms linearised."""

    def __init__(self, model: CoarseModel, cover: bool = True) -> None:
        self.model = model
        self.dt = model.dt_s
        self.cover = cover
        self.notes: list[str] = []

    def region(self, name: str) -> Region:
        try:
            return self.model.problem.region(name)
        except KeyError:
            raise NotEncodable(f"unknown region {name!r}") from None

    def vehicle(self, name: str, where: object) -> str:
        if name not in self.model.vehicles:
            raise NotEncodable(f"{where}: {name!r} is not a vehicle")
        return name

    def expr(self, e: Expr) -> tuple[float, dict[tuple[str, str, object], float]]:
        """``(constant, {key: coefficient})`` of a linear expression."""
        if isinstance(e, Const):
            return e.value, {}
        if isinstance(e, Signal):
            raise NotEncodable(f"signal {e.name!r}: only vehicle coordinates are decisions")
        if isinstance(e, Neg):
            c, t = self.expr(e.operand)
            return -c, {k: -v for k, v in t.items()}
        if isinstance(e, BinOp):
            (c1, t1), (c2, t2) = self.expr(e.lhs), self.expr(e.rhs)
            if e.op in (ArithOp.ADD, ArithOp.SUB):
                s = 1.0 if e.op is ArithOp.ADD else -1.0
                t = dict(t1)
                for k, v in t2.items():
                    t[k] = t.get(k, 0.0) + s * v
                return c1 + s * c2, t
            if e.op is ArithOp.MUL:
                if t1 and t2:
                    raise NotEncodable(f"{e}: a product of two signals is not linear")
                (c, t), w = ((c1, t1), c2) if not t2 else ((c2, t2), c1)
                return c * w, {k: v * w for k, v in t.items()}
            if t2 or c2 == 0.0:
                raise NotEncodable(f"{e}: division by a signal or by zero")
            return c1 / c2, {k: v / c2 for k, v in t1.items()}
        if isinstance(e, Call):
            return 0.0, self.call(e)
        raise NotEncodable(f"cannot encode the expression {e}")

    def call(self, c: Call) -> dict[tuple[str, str, object], float]:
        axes = {"x": 0, "y": 1, "z": 2, "alt": 2}
        if c.name in axes:
            return {("p", self.vehicle(c.args[0], c), axes[c.name]): 1.0}
        if c.name in ("inside", "outside"):
            v = self.vehicle(c.args[0], c)
            self.region(c.args[1])
            return {("inside", v, c.args[1]): 1.0 if c.name == "inside" else -1.0}
        if c.name == "dist":
            a, b = sorted((self.vehicle(c.args[0], c), self.vehicle(c.args[1], c)))
            return {} if a == b else {("dist", a, b): 1.0}
        if c.name == "agl":
            terrain = getattr(self.model.problem, "terrain", None)
            if terrain is None:
                raise NotEncodable(f"{c}: no terrain")
            a, b, c_lo, c_hi = terrain.plane_bounds()
            note = (
                f"agl: relaxed to planes under and over the ground ({c_hi - c_lo:.2f} m apart); "
                "the NLP keeps it"
            )
            if note not in self.notes:
                self.notes.append(note)
            return {("agl", self.vehicle(c.args[0], c), None): 1.0}
        if c.name == "face":
            raise _Face
        raise NotEncodable(f"the function {c.name!r} has no linear encoding")

    def atom(self, f: Comparison | Predicate, neg: bool) -> Node:
        try:
            if isinstance(f, Predicate):
                const, terms = 0.0, self.call(f.call)
            else:
                (c1, t1), (c2, t2) = self.expr(f.lhs), self.expr(f.rhs)
                const, terms = c1 - c2, dict(t1)
                for k, v in t2.items():
                    terms[k] = terms.get(k, 0.0) - v
                if f.op in (CmpOp.LE, CmpOp.LT):
                    const, terms = -const, {k: -v for k, v in terms.items()}
        except _Face:
            self.notes.append(f"{f}: the heading is not in the coarse model; read as true")
            return TRUE
        s = -1.0 if neg else 1.0
        items = tuple(sorted(((k, s * v) for k, v in terms.items() if v != 0.0), key=repr))
        return Node("atom", lin=(s * const, items), text=f"not ({f})" if neg else str(f))

    def __call__(self, f: Formula, neg: bool = False) -> Node:
        if isinstance(f, BoolConst):
            return TRUE if f.value != neg else FALSE
        if isinstance(f, Comparison | Predicate):
            return self.atom(f, neg)
        if isinstance(f, Not):
            return self(f.child, not neg)
        if isinstance(f, And | Or):
            return _and([self(k, neg) for k in f.operands], isinstance(f, And) != neg)
        if isinstance(f, Implies):
            return _and([self(f.lhs, not neg), self(f.rhs, neg)], neg)
        if isinstance(f, Always | Eventually):
            kind = "always" if isinstance(f, Always) != neg else "eventually"
            a, b = f.steps(self.dt)
            if self.cover and kind == "always":
                a, b = covering_steps(f.start_s, f.end_s, self.dt)
            child = self(f.child, neg)
            if child in (TRUE, FALSE):
                return child
            return Node(kind, (child,), a, b)
        if isinstance(f, Until):
            if neg:
                raise NotEncodable(f"not ({f}): a negated until is not encoded")
            a, b = f.steps(self.dt)
            lhs, rhs = self(f.lhs), self(f.rhs)
            if rhs == FALSE:
                return FALSE
            if lhs == TRUE:
                return Node("eventually", (rhs,), a, b) if rhs != TRUE else TRUE
            if rhs == TRUE:
                return TRUE if a == 0 else Node("always", (lhs,), 0, a - 1)
            if lhs == FALSE:
                return rhs if a == 0 else FALSE
            return Node("until", (lhs, rhs), a, b)
        raise NotEncodable(f"cannot encode {type(f).__name__} nodes")


# --------------------------------------------------------------------------- encoder


class Encoder:
    """Encodes the conjunction of formulas into a builder over a :class:`CoarseModel`.

    Attributes:
        notes: what was approximated beyond the lower bound (``face`` read as true).
        binaries: how many binaries the STL rows added.
    """

    def __init__(
        self, builder: MilpBuilder, model: CoarseModel, cover: bool = True, legs: bool | None = None
    ) -> None:
        self.b = builder
        self.model = model
        self.n = model.n_steps + 1
        self.norm = Normaliser(model, cover)
        #: a polygon kept out of the straight legs as well as the samples (default: cover)
        self.legs = cover if legs is None else legs
        self.binaries = 0
        self._deltas: dict[tuple[tuple[str, str, object], bool], tuple[Ints, Lin]] = {}

    @property
    def notes(self) -> list[str]:
        """Approximations the encoding made (beyond the sound lower bounds)."""
        return self.norm.notes

    def encode(self, formulas: Sequence[Formula]) -> Lin | bool:
        """The robustness lower bound of ``formulas[0] and formulas[1] ...`` at step 0: a
        one-row :class:`Lin`, or ``True``/``False`` when the spec folds to a constant.

        Raises:
            NotEncodable: see the module docstring.
        """
        root = _and([self.norm(f) for f in formulas], True)
        if root == TRUE:
            return True
        if root == FALSE:
            return False
        order: list[Node] = []
        seen: set[Node] = set()
        stack: list[tuple[Node, bool]] = [(root, False)]
        while stack:  # iterative post-order over the DAG
            node, done = stack.pop()
            if done:
                order.append(node)
                continue
            if node in seen:
                continue
            seen.add(node)
            stack.append((node, True))
            stack.extend((k, False) for k in node.kids)
        need = self._needs(order, root)
        self._make_deltas(order, need)
        enc: dict[Node, tuple[Ints, Lin]] = {}
        for node in order:
            steps = np.flatnonzero(need[node])
            if not len(steps):  # e.g. the left side of an until[0,0]: never read
                z = np.zeros(0)
                enc[node] = (steps, Lin(np.zeros((0, 0), np.int64), np.zeros((0, 0)), z, z, z))
                continue
            enc[node] = (steps, self._node(node, steps, enc))
        return self._at(enc, root, np.zeros(1, dtype=np.int64))

    # ---- which steps each node is needed at

    def _needs(self, order: list[Node], root: Node) -> dict[Node, NDArray[np.bool_]]:
        need = {node: np.zeros(self.n, dtype=bool) for node in order}
        need[root][0] = True
        for node in reversed(order):  # parents before children
            idx = np.flatnonzero(need[node])
            if node.kind in ("and", "or"):
                for k in node.kids:
                    need[k][idx] = True
            elif node.kind in ("always", "eventually"):
                self._mark(need[node.kids[0]], idx, node.a, node.b, node)
            elif node.kind == "until":
                if node.b >= 1:
                    self._mark(need[node.kids[0]], idx, 0, node.b - 1, node)
                self._mark(need[node.kids[1]], idx, node.a, node.b, node)
        return need

    def _mark(self, mask: NDArray[np.bool_], idx: Ints, a: int, b: int, node: Node) -> None:
        if not len(idx):
            return
        last = int(idx[-1]) + b
        if last >= self.n and node.kind == "always":
            # a covering window that reaches past the horizon: its samples up to the end
            mask[np.minimum(idx[:, None] + np.arange(a, b + 1), self.n - 1).ravel()] = True
            return
        if last >= self.n:
            raise NotEncodable(
                f"the spec needs step {last} of a {self.n - 1}-step coarse horizon "
                f"(dt_c {self.model.dt_s:g} s) at a {node.kind}[{a},{b}]"
            )
        mask[(idx[:, None] + np.arange(a, b + 1)).ravel()] = True

    @staticmethod
    def _at(enc: dict[Node, tuple[Ints, Lin]], node: Node, steps: Ints) -> Lin:
        have, lin = enc[node]
        return lin.take(np.searchsorted(have, steps))

    # ---- the nodes

    def _node(self, node: Node, steps: Ints, enc: dict[Node, tuple[Ints, Lin]]) -> Lin:
        m = len(steps)
        if node.kind == "atom":
            return self._atom(node, steps)
        if node.kind in ("and", "or"):
            grid = Lin.concat([self._at(enc, k, steps) for k in node.kids])
            w = len(node.kids)
            order = np.arange(m * w).reshape(w, m).T.ravel()  # rows (step, operand)
            grid = grid.take(order)
            return self._min(grid, m, w) if node.kind == "and" else self._max(grid, m, w)
        if node.kind in ("always", "eventually"):
            w = node.b - node.a + 1
            at = (steps[:, None] + np.arange(node.a, node.b + 1)).ravel()
            if node.kind == "always":  # a covering window clipped at the horizon (_mark)
                at = np.minimum(at, self.n - 1)
            grid = self._at(enc, node.kids[0], at)
            return self._min(grid, m, w) if node.kind == "always" else self._max(grid, m, w)
        return self._until(node, steps, enc)

    def _min(self, grid: Lin, m: int, w: int) -> Lin:
        """``r_s <= grid[s, k]`` for every k: rows of ``grid`` ordered (s, k)."""
        if w == 1:
            return grid
        lo = grid.lo.reshape(m, w).min(axis=1)
        hi = grid.hi.reshape(m, w).min(axis=1)
        r = self.b.add_vars(m, lo, hi)
        keep = grid.lo < np.repeat(hi, w)  # an option never below r's bound is redundant
        _le_rows(self.b, np.repeat(r, w)[keep], grid.take(np.flatnonzero(keep)), None, None)
        return Lin.var(r, lo, hi)

    def _max(self, grid: Lin, m: int, w: int) -> Lin:
        """``r_s <= grid[s, k] + M (1 - b_sk)``, ``sum_k b_sk >= 1``."""
        if w == 1:
            return grid
        glo, ghi = grid.lo.reshape(m, w), grid.hi.reshape(m, w)
        lo, hi = glo.max(axis=1), ghi.max(axis=1)
        keep = ghi >= lo[:, None]  # an option that cannot reach r's lower bound never counts
        count = keep.sum(axis=1)
        r = self.b.add_vars(m, lo, hi)
        single = np.flatnonzero(keep.reshape(-1) & np.repeat(count == 1, w))
        if len(single):
            _le_rows(self.b, np.repeat(r, w)[single], grid.take(single), None, None)
        multi = keep & (count > 1)[:, None]
        rows = np.flatnonzero(multi.reshape(-1))
        if len(rows):
            bins = self.b.add_binaries(len(rows))
            self.binaries += len(rows)
            opt = grid.take(rows)
            big_m = np.maximum(np.repeat(hi, w)[rows] - opt.lo, 0.0)
            _le_rows(self.b, np.repeat(r, w)[rows], opt, big_m, bins)
            # sum_k b_sk >= 1, one row per step with several options (padded to w)
            table = np.zeros((m, w), dtype=np.int64)
            vals = np.zeros((m, w))
            table[multi] = bins
            vals[multi] = 1.0
            has = count > 1
            self.b.add_rows(table[has], vals[has], 1.0, math.inf)
        return Lin.var(r, lo, hi)

    def _until(self, node: Node, steps: Ints, enc: dict[Node, tuple[Ints, Lin]]) -> Lin:
        m, a, b = len(steps), node.a, node.b
        lhs, rhs = node.kids
        w = b - a + 1
        q = self._at(enc, rhs, (steps[:, None] + np.arange(a, b + 1)).ravel())
        if b == 0:
            return q
        # prefix minima P[s, k] <= min lhs(s .. s + k - 1), k = 1..b, columns (m, b)
        p_lin = self._at(enc, lhs, (steps[:, None] + np.arange(b)).ravel())
        plo = np.minimum.accumulate(p_lin.lo.reshape(m, b), axis=1)
        phi = np.minimum.accumulate(p_lin.hi.reshape(m, b), axis=1)
        pv = self.b.add_vars(m * b, plo.ravel(), phi.ravel()).reshape(m, b)
        _le_rows(self.b, pv.ravel(), p_lin, None, None)
        if b >= 2:
            prev = Lin.var(pv[:, :-1].ravel(), plo[:, :-1].ravel(), phi[:, :-1].ravel())
            _le_rows(self.b, pv[:, 1:].ravel(), prev, None, None)
        # option j = a..b: min(q(s + j), P[s, j]) (P[s, 0] = +inf)
        opts = []
        for j in range(a, b + 1):
            qj = q.take(np.arange(m) * w + (j - a))
            if j == 0:
                opts.append(self._min(qj, m, 1))
                continue
            pj = Lin.var(pv[:, j - 1], plo[:, j - 1], phi[:, j - 1])
            both = Lin.concat([qj, pj]).take(np.arange(2 * m).reshape(2, m).T.ravel())
            opts.append(self._min(both, m, 2))
        grid = Lin.concat(opts).take(np.arange(m * w).reshape(w, m).T.ravel())
        return self._max(grid, m, w)

    # ---- atoms and the columns that bound functions

    def _pos(self, vehicle: str, axis: int, steps: Ints) -> tuple[Ints, Floats, Floats]:
        vc = self.model.vehicles[vehicle]
        return vc.cols[steps, axis], vc.lo[steps, axis], vc.hi[steps, axis]

    def _atom(self, node: Node, steps: Ints) -> Lin:
        assert node.lin is not None
        const, items = node.lin
        m = len(steps)
        cols, vals = [], []
        base = np.full(m, const)
        lo, hi = base.copy(), base.copy()
        for key, w in items:
            if key[0] == "p":
                c, clo, chi = self._pos(key[1], int(key[2]), steps)  # type: ignore[call-overload]
                cols.append(c)
                vals.append(np.full(m, w))
            else:  # a function's bound: its column, or (agl) an affine form of positions
                have, d = self._deltas[(key, w > 0)]
                dl = d.take(np.searchsorted(have, steps))
                cols.extend(dl.cols.T)
                vals.extend(w * dl.vals.T)
                base += w * dl.const
                clo, chi = dl.lo, dl.hi
            lo += np.minimum(w * clo, w * chi)
            hi += np.maximum(w * clo, w * chi)
        if not cols:
            return Lin(np.zeros((m, 0), np.int64), np.zeros((m, 0)), base, lo, hi)
        return Lin(np.column_stack(cols), np.column_stack(vals), base, lo, hi)

    def _make_deltas(self, order: list[Node], need: dict[Node, NDArray[np.bool_]]) -> None:
        """One column per (function term, direction, step), at the steps its atoms need."""
        masks: dict[tuple[tuple[str, str, object], bool], NDArray[np.bool_]] = {}
        for node in order:
            if node.kind != "atom" or node.lin is None:
                continue
            for key, w in node.lin[1]:
                if key[0] != "p":
                    mk = masks.setdefault((key, w > 0), np.zeros(self.n, dtype=bool))
                    mk |= need[node]
        for (key, lower), mk in masks.items():
            steps = np.flatnonzero(mk)
            if not len(steps):
                continue
            if key[0] == "inside":
                lin = self._inside(str(key[1]), self.norm.region(str(key[2])), steps, lower)
            elif key[0] == "agl":
                lin = self._agl(str(key[1]), steps, lower)
            else:
                lin = self._dist(str(key[1]), str(key[2]), steps, lower)
            self._deltas[(key, lower)] = (steps, lin)

    def _faces(self, vehicle: str, region: Region, steps: Ints, outer: bool) -> Lin:
        """The region's face margins ``(b_i - A_i p) / s_i`` at the steps, rows (step, face)."""
        a, bb = region.half_spaces(outer=outer)
        scale = np.ones(len(a))
        if isinstance(region.shape, Cylinder) and not outer:
            scale[:-2] = 1.0 / math.cos(math.pi / (len(a) - 2))
        a, bb = a * scale[:, None], bb * scale
        f, m = len(a), len(steps)
        vc = self.model.vehicles[vehicle]
        pc, plo, phi = vc.cols[steps], vc.lo[steps], vc.hi[steps]
        cols = np.repeat(pc, f, axis=0)  # (m f, 3)
        vals = -np.tile(a, (m, 1))
        const = np.tile(bb, m)
        lo = const + np.minimum(vals * np.repeat(plo, f, 0), vals * np.repeat(phi, f, 0)).sum(1)
        hi = const + np.maximum(vals * np.repeat(plo, f, 0), vals * np.repeat(phi, f, 0)).sum(1)
        return Lin(cols, vals, const, lo, hi)

    def _inside(self, vehicle: str, region: Region, steps: Ints, lower: bool) -> Lin:
        m = len(steps)
        if lower:  # delta <= every face margin (inner polygon for a cylinder)
            faces = self._faces(vehicle, region, steps, outer=False)
            return self._min(faces, m, len(faces.lo) // m)
        # delta >= the smallest face margin: delta >= m_i for one face i (outer polygon);
        # for a polygon (a part of a non-convex outline, planner.spec.cover) with ``legs`` (by
        # default with covered windows) also at the next sample, the same face i: the straight leg
        # to it stays beyond that face's plane, so the region is kept out of between samples too (a
        # U-shaped keep-out: 12 m legs jumped its 10 m walls into a pocket the NLP could not leave).
        # Boxes and cylinders are held out at the samples only: a leg that cuts one the NLP slides
        # off its nearest face, and the leg rows made the allocation mission's program too hard for
        # its 5 s (no incumbent, against 3.5 s).
        faces = self._faces(vehicle, region, steps, outer=True)
        f = len(faces.lo) // m
        legs = [faces]
        if self.legs and isinstance(region.shape, Prism):
            legs.append(self._faces(vehicle, region, np.minimum(steps + 1, self.n - 1), True))
        flo = faces.lo.reshape(m, f)
        fhi = np.max([leg.hi.reshape(m, f) for leg in legs], axis=0)
        lo, hi = flo.min(axis=1), fhi.min(axis=1)
        d = self.b.add_vars(m, lo, hi)
        keep = flo <= hi[:, None]  # a face always above another's bound is never the least
        count = keep.sum(axis=1)
        rows = np.flatnonzero(keep.reshape(-1))
        dr = np.repeat(d, f)[rows]
        multi = np.repeat(count > 1, f)[rows]
        bins = np.zeros(len(rows), dtype=np.int64)
        nb = int(multi.sum())
        if nb:
            bins[multi] = self.b.add_binaries(nb)
            self.binaries += nb
        for leg in legs:
            opt = leg.take(rows)
            big_m = np.where(multi, np.maximum(opt.hi - np.repeat(lo, f)[rows], 0.0), 0.0)
            # m_i - M_i (1 - b_i) - delta <= 0  <=>  -delta - A_i p + M_i b_i <= M_i - b_i
            cols = np.hstack([dr[:, None], opt.cols, bins[:, None]])
            vals = np.hstack([-np.ones((len(rows), 1)), opt.vals, big_m[:, None]])
            self.b.add_rows(cols, vals, -math.inf, big_m - opt.const)
        if nb:
            table = np.zeros((m, f), dtype=np.int64)
            tv = np.zeros((m, f))
            mk = keep & (count > 1)[:, None]
            table[mk], tv[mk] = bins[multi], 1.0
            has = count > 1
            self.b.add_rows(table[has], tv[has], 1.0, math.inf)
        return Lin.var(d, lo, hi)

    def _agl(self, vehicle: str, steps: Ints, lower: bool) -> Lin:
        """``z - (a x + b y + c)`` with the plane under the ground where the term is bounded
        from below (``lower``: a floor), over it where from above: a relaxation either way."""
        terrain = self.model.problem.terrain
        assert terrain is not None  # Normaliser.call refuses agl without one
        a, b, c_lo, c_hi = terrain.plane_bounds()
        vals = np.array([-a, -b, 1.0])
        m = len(steps)
        vc = self.model.vehicles[vehicle]
        plo, phi = vc.lo[steps], vc.hi[steps]
        const = np.full(m, -(c_lo if lower else c_hi))
        lo = const + np.minimum(vals * plo, vals * phi).sum(axis=1)
        hi = const + np.maximum(vals * plo, vals * phi).sum(axis=1)
        return Lin(vc.cols[steps], np.tile(vals, (m, 1)), const, lo, hi)

    def _dist(self, va: str, vb: str, steps: Ints, lower: bool) -> Lin:
        m = len(steps)
        ca, cb = self.model.vehicles[va], self.model.vehicles[vb]
        dlo = ca.lo[steps] - cb.hi[steps]  # (m, 3) bounds of p_a - p_b
        dhi = ca.hi[steps] - cb.lo[steps]
        pa, pb = ca.cols[steps], cb.cols[steps]
        absmax = np.maximum(np.abs(dlo), np.abs(dhi))
        absmin = np.where((dlo > 0) | (dhi < 0), np.minimum(np.abs(dlo), np.abs(dhi)), 0.0)
        if not lower:  # delta >= |d|_1 >= |d|_2: t_i >= +-d_i, delta >= sum t_i
            t = self.b.add_vars(3 * m, absmin.ravel(), absmax.ravel()).reshape(m, 3)
            for s in (1.0, -1.0):  # s d_i - t_i <= 0
                c = np.stack([pa, pb, t], axis=-1).reshape(-1, 3)
                self.b.add_rows(c, np.tile([s, -s, -1.0], (3 * m, 1)), -math.inf, 0.0)
            lo, hi = absmin.sum(axis=1), absmax.sum(axis=1)
            d = self.b.add_vars(m, lo, hi)
            self.b.add_rows(
                np.column_stack([t, d]), np.tile([1.0, 1.0, 1.0, -1.0], (m, 1)), -math.inf, 0.0
            )
            return Lin.var(d, lo, hi)
        # delta <= s (p_a - p_b)_i for one (axis, sign): the L-infinity distance <= |d|_2
        opts = []
        for s in (1.0, -1.0):
            for i in range(3):
                olo, ohi = (dlo[:, i], dhi[:, i]) if s > 0 else (-dhi[:, i], -dlo[:, i])
                cols = np.column_stack([pa[:, i], pb[:, i]])
                opts.append(Lin(cols, np.tile([s, -s], (m, 1)), np.zeros(m), olo, ohi))
        grid = Lin.concat(opts).take(np.arange(6 * m).reshape(6, m).T.ravel())
        return self._max(grid, m, 6)
