"""Clauses tightened by a margin: a plan that keeps a clause ``m`` metres better than asked.

``gcs plan --target-probability`` (:mod:`gcs.assess.target`) asks the planner for plans whose
clauses hold with room to spare where the flights of the assessment lose robustness.  A clause
``phi`` *tightened by* ``m`` is a formula ``phi_m`` whose exact robustness is that of ``phi``
minus ``m`` at every instant, for every signal:

    rho(phi_m, s, t) = rho(phi, s, t) - m

so a plan that meets ``phi_m`` with robustness ``r`` meets ``phi`` with ``r + m``.  It is
written in the spec's own language, so every part of the planner (the initial guess, the
combinatorial stage, the NLP, the exact check) reads it as it reads any clause:

* ``and``, ``or``, ``always``, ``eventually`` and ``until`` are minima and maxima of their
  operands' robustness, which commute with subtracting a constant: their operands are
  tightened by ``m``;
* ``not psi`` is ``-rho(psi)``: ``psi`` is *loosened* by ``m`` (tightened by ``-m``);
  ``a implies b`` is ``max(-rho(a), rho(b))``: ``a`` loosened, ``b`` tightened;
* a comparison moves its constant: ``dist(d1, d2) >= 1.5`` becomes ``dist(d1, d2) >= 2.1``
  for ``m = 0.6`` (``<=``: the other way);
* ``inside(d, R)`` is the smallest of ``R``'s face margins, ``outside(d, R)`` minus it
  (:mod:`planner.spec.predicates`): ``R`` is replaced by a copy with every face moved ``m``
  inwards (``inside``) or outwards (``outside``): the box's sides, a prism's walls (by
  Shapely's mitred offset, which moves each side of a convex polygon along its normal), its
  floor and roof, a cylinder's radius.  A polygon that is not convex is already the ``or``
  (``and``) of its convex parts, each moved;
* any other function used as an atom (``face``) becomes ``f(...) >= m``.

A clause can also be given a longer dwell (:func:`lengthened`: a hover of ``tau`` seconds
more within the same window), a margin in time: the flight then keeps the clause if any
hover-long part of the dwell holds, which wind gusts shorter than the dwell leave.

Where a region cannot shrink by ``m`` (it would be empty), :func:`tighten` raises
:class:`MarginError` naming it: no plan can keep that clause by that margin.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping

import numpy as np
from shapely.geometry import Polygon

from planner.errors import PlannerError
from planner.problem import Clause, Problem
from planner.scenario.spec import clause_formulas
from planner.spec.regions import Cylinder, Prism, Region, ShapeError
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
    Formula,
    Implies,
    Not,
    Or,
    Predicate,
    Until,
    conjunction,
)

__all__ = [
    "MarginError",
    "clause_texts",
    "conjuncts",
    "has_dwell",
    "lengthened",
    "max_margin",
    "offset_region",
    "shifted",
    "split",
    "split_clauses",
    "tighten",
    "tightened_name",
]

#: Region-valued atoms and the direction their region moves: +1 inwards (its margin falls by
#: the shift), -1 outwards (minus its margin falls).
_REGION_ATOMS = {"inside": 1.0, "outside": -1.0}


class MarginError(PlannerError, ValueError):
    """A clause cannot be tightened by the margin asked (a region would be empty)."""


def tightened_name(name: str, m: float) -> str:
    """The name of region ``name`` with its faces moved ``m`` inwards (``m < 0``: outwards),
    an identifier: ``insp1__in30cm``, ``pole2__out125cm`` (to the millimetre)."""
    mm = round(abs(m) * 1000.0)
    size = f"{mm // 10}cm" if mm % 10 == 0 else f"{mm}mm"
    return f"{name}__{'in' if m > 0 else 'out'}{size}"


def offset_region(region: Region, m: float, name: str) -> Region:
    """``region`` with every face moved ``m`` inwards (``m < 0``: outwards): its margin at any
    point is ``region``'s minus ``m`` (:meth:`Region.margin`).

    Raises:
        MarginError: the region would be empty.
    """
    s = region.shape
    try:
        if s is None:
            lo = np.asarray(region.lo_enu_m) + m
            hi = np.asarray(region.hi_enu_m) - m
            if np.any(hi <= lo):
                raise ShapeError("empty")
            return Region(name, region.kind, tuple(lo.tolist()), tuple(hi.tolist()))
        if isinstance(s, Cylinder):
            shape: Prism | Cylinder = Cylinder(
                s.center_xy, s.radius_m - m, s.z_lo_m + m, s.z_hi_m - m
            )
        else:
            grown = Polygon(s.vertices_xy).buffer(-m, join_style="mitre", mitre_limit=1e6)
            if grown.is_empty or grown.geom_type != "Polygon":
                raise ShapeError("empty")
            corners = np.asarray(grown.exterior.coords)[:-1]
            shape = Prism.from_polygon(corners, s.z_lo_m + m, s.z_hi_m - m)
    except ShapeError:
        raise MarginError(
            f"region {region.name!r} cannot shrink by {m:.3g} m (its smallest half-size is "
            f"{region.min_half_m:.3g} m)"
        ) from None
    return Region.of_shape(name, region.kind, shape)


def shifted(node: Formula, m: float, region: Callable[[str, float], str]) -> Formula:
    """``node`` tightened by ``m`` (module docstring); ``region(name, m)`` names the copy of
    region ``name`` with its faces moved ``m`` inwards (and makes it)."""
    if m == 0.0 or isinstance(node, BoolConst):
        return node
    if isinstance(node, And | Or):
        return type(node)(tuple(shifted(c, m, region) for c in node.operands))
    if isinstance(node, Not):
        return Not(shifted(node.child, -m, region))
    if isinstance(node, Implies):
        return Implies(shifted(node.lhs, -m, region), shifted(node.rhs, m, region))
    if isinstance(node, Always | Eventually):
        return dataclasses.replace(node, child=shifted(node.child, m, region))
    if isinstance(node, Until):
        return dataclasses.replace(
            node, lhs=shifted(node.lhs, m, region), rhs=shifted(node.rhs, m, region)
        )
    if isinstance(node, Comparison):
        up = node.op in (CmpOp.GE, CmpOp.GT)  # robustness lhs - rhs, else rhs - lhs
        delta = m if up else -m
        rhs = node.rhs
        if isinstance(rhs, Const):
            return dataclasses.replace(node, rhs=Const(rhs.value + delta))
        return dataclasses.replace(node, rhs=BinOp(ArithOp.ADD, rhs, Const(delta)))
    if isinstance(node, Predicate):
        call = node.call
        sign = _REGION_ATOMS.get(call.name)
        if sign is not None and len(call.args) == 2:
            moved = region(call.args[1], sign * m)
            return Predicate(Call(call.name, (call.args[0], moved), call.function))
        return Comparison(call, CmpOp.GE, Const(m))
    raise MarginError(f"cannot tighten {type(node).__name__} {node}")


def lengthened(node: Formula, tau: float) -> Formula:
    """``node`` with every dwell lengthened by ``tau`` seconds: an ``always[c, d] psi`` that
    an ``eventually[a, b]`` (or the right side of an ``until[a, b]``) asks for becomes
    ``always[c, d + tau] psi`` within ``[a, b - tau]`` (never below ``a``): the same look
    ahead, a longer hover that must start earlier.  A plan meeting it meets ``node`` with at
    least the same robustness (a longer window contains the shorter one), and a flight
    keeps ``node`` if any one-hover-long part of the longer dwell holds, not only the one
    planned.  ``and``, ``or`` and ``always`` are looked through; ``not`` and ``implies``
    are not (a dwell under a negation is not something to make longer)."""
    if tau <= 0.0:
        return node
    if isinstance(node, And | Or):
        return type(node)(tuple(lengthened(c, tau) for c in node.operands))
    if isinstance(node, Always):
        return dataclasses.replace(node, child=lengthened(node.child, tau))
    if isinstance(node, Eventually) and isinstance(node.child, Always):
        inner = node.child
        end = max(node.start_s, node.end_s - tau)
        longer = dataclasses.replace(inner, end_s=inner.end_s + (node.end_s - end))
        return dataclasses.replace(node, child=longer, end_s=end)
    if isinstance(node, Until) and isinstance(node.rhs, Always):
        inner = node.rhs
        end = max(node.start_s, node.end_s - tau)
        longer = dataclasses.replace(inner, end_s=inner.end_s + (node.end_s - end))
        return dataclasses.replace(node, rhs=longer, end_s=end)
    return node


def has_dwell(node: Formula) -> bool:
    """Whether :func:`lengthened` would change ``node`` (it asks for a hover in a window)."""
    return lengthened(node, 1.0) != node


def tighten(
    problem: Problem,
    margins: Mapping[str, float],
    dwells: Mapping[str, float] | None = None,
) -> Problem:
    """``problem`` with each top-level conjunct whose text is a key of ``margins`` tightened
    by that many metres (conjuncts as :attr:`Formula.clauses` lists them, the units the
    assessment judges), the moved regions added, and each one in ``dwells`` lengthened by
    that many seconds (:func:`lengthened`).  Margins and dwells <= 0 leave their conjunct
    alone.

    Raises:
        MarginError: a region cannot shrink that far.
    """
    dwells = dwells or {}
    regions = {r.name: r for r in problem.all_regions}
    added: dict[str, Region] = {}

    def moved(name: str, m: float) -> str:
        new = tightened_name(name, m)
        if new not in regions and new not in added:
            added[new] = offset_region(regions[name], m, new)
        return new

    clauses = []
    used: set[str] = set()
    for clause, phi in zip(problem.clauses, clause_formulas(problem), strict=True):
        parts = []
        for c in phi.clauses:
            m = float(margins.get(str(c), 0.0))
            if not math.isfinite(m):
                raise MarginError(f"margin of {c} is not a number: {m!r}")
            tau = float(dwells.get(str(c), 0.0))
            if m > 0.0 or tau > 0.0:
                used.add(str(c))
            part = shifted(c, m, moved) if m > 0.0 else c
            parts.append(lengthened(part, tau) if tau > 0.0 else part)
        text = clause.text if all(p is c for p, c in zip(parts, phi.clauses, strict=True)) else None
        clauses.append(Clause(clause.key_path, text or str(conjunction(parts))))
    asked = [*margins.items(), *dwells.items()]
    unknown = sorted(k for k, v in asked if v > 0.0 and k not in used)
    if unknown:
        raise MarginError(f"no clause of the spec reads {unknown[0]!r}")
    return dataclasses.replace(
        problem, regions=(*problem.regions, *added.values()), clauses=tuple(clauses)
    )


def split(node: Formula) -> list[Formula]:
    """``node`` as the finest conjunction the semantics allow without change:
    ``always[a,b] (A and B)`` is ``always[a,b] A and always[a,b] B`` (the min over time and the
    min over the operands commute), so each conjunct of an ``always`` becomes a clause of its
    own, as the NLP's leaves (:func:`planner.solve.leaves.decompose`) already read them."""
    if isinstance(node, And):
        return [part for op in node.operands for part in split(op)]
    if isinstance(node, Always):
        parts = split(node.child)
        if len(parts) > 1:
            return [dataclasses.replace(node, child=part) for part in parts]
    return [node]


def split_clauses(problem: Problem) -> Problem:
    """``problem`` with each clause split (:func:`split`): the same spec, robustness and
    plans, in the finest clauses, so that a margin can tighten one keep-out of an ``always
    (inside(d, workspace) and outside(d, pole1) and ...)`` and not the others."""
    clauses = [
        Clause(c.key_path, str(part))
        for c, phi in zip(problem.clauses, clause_formulas(problem), strict=True)
        for part in split(phi)
    ]
    return dataclasses.replace(problem, clauses=tuple(clauses))


def max_margin(problem: Problem, text: str, hi_m: float = 20.0, tol_m: float = 0.01) -> float:
    """The largest margin (to ``tol_m``, at most ``hi_m``) by which the conjunct ``text`` can
    be tightened before a region it names would vanish (bisection over :func:`tighten`)."""
    lo, hi = 0.0, hi_m
    try:
        tighten(problem, {text: hi})
        return hi
    except MarginError:
        pass
    while hi - lo > tol_m:
        mid = 0.5 * (lo + hi)
        try:
            tighten(problem, {text: mid})
            lo = mid
        except MarginError:
            hi = mid
    return lo


def conjuncts(problem: Problem) -> dict[str, Formula]:
    """The top-level conjuncts of ``problem``'s spec by their text."""
    return {str(c): c for phi in clause_formulas(problem) for c in phi.clauses}


def clause_texts(problem: Problem) -> list[str]:
    """The top-level conjuncts of ``problem``'s spec as text (the keys of ``margins``)."""
    return list(conjuncts(problem))
