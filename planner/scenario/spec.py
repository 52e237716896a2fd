"""The spec of a scenario: clause templates expanded over vehicles, groups and pairs, then parsed.

A clause's ``each`` binds identifiers (``d in GROUP``, ``d in [d1, d3]``, ``(a, b) in
pairs(GROUP)``; a list of bindings takes the product) and ``$name`` stands for a constant;
the expansion is plain STL text, one :class:`planner.problem.Clause` per binding.  Every
call must name one of :data:`FUNCTION_NAMES` with vehicles and regions where its arguments
want them, and :func:`parse_clause` parses a clause with the STL engine, a mistake naming
the clause's key.  A room of its own: the spec language of a scenario file, apart from the
YAML sections (:mod:`planner.scenario.sections`) it binds to.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Mapping, Sequence
from functools import partial
from typing import Any

from planner.mission_model import NAME_RE
from planner.problem import Clause, Problem
from planner.scenario.checks import horizon_sum
from planner.scenario.sections import Reader, ScenarioError, join_key
from planner.spec.predicates import PREDICATES, build_registry
from planner.spec.regions import Region
from planner.stl import (
    BinOp,
    Comparison,
    Expr,
    Formula,
    FunctionRegistry,
    Neg,
    Signal,
    SpecError,
    parse,
)

__all__ = ["FUNCTION_NAMES", "parse_clause"]

#: Function predicates a scenario's spec may call, with the kinds of their arguments
#: (``v`` a vehicle, ``r`` a region): :data:`planner.spec.predicates.PREDICATES`.
FUNCTION_NAMES: dict[str, tuple[str, ...]] = {p.name: p.args for p in PREDICATES.values()}


_BIND_ONE = re.compile(r"^\s*([A-Za-z_]\w*)\s+in\s+(.+?)\s*$")
_BIND_PAIR = re.compile(r"^\s*\(\s*([A-Za-z_]\w*)\s*,\s*([A-Za-z_]\w*)\s*\)\s+in\s+(.+?)\s*$")
_PAIRS = re.compile(r"^pairs\(\s*(.+?)\s*\)$")
_LIST = re.compile(r"^\[(.*)\]$")
_DOLLAR = re.compile(r"\$([A-Za-z_]\w*)")
_CALL = re.compile(r"\b([A-Za-z_]\w*)\s*\(([^()]*)\)")


def _collection(rd: Reader, text: str, path: str, groups: Mapping[str, Sequence[str]]) -> list[str]:
    lm = _LIST.match(text)
    if lm:
        items = [s.strip() for s in lm.group(1).split(",") if s.strip()]
        if not items:
            raise rd.fail(path, "empty list")
        for it in items:
            if not NAME_RE.match(it):
                raise rd.fail(path, f"{it!r} is not a name")
        return items
    if text in groups:
        return list(groups[text])
    raise rd.fail(path, f"unknown group {text!r} (groups: {', '.join(sorted(groups))})")


def _bindings(
    rd: Reader, value: Any, path: str, groups: Mapping[str, Sequence[str]]
) -> list[dict[str, str]]:
    """All assignments of the clause's ``each`` (a string or a list: product of bindings)."""
    items = value if isinstance(value, list) else [value]
    per: list[list[dict[str, str]]] = []
    for j, b in enumerate(items):
        p = f"{path}[{j}]" if isinstance(value, list) else path
        if not isinstance(b, str):
            raise rd.fail(p, "expected 'VAR in GROUP', 'VAR in [a, b]' or '(A, B) in pairs(GROUP)'")
        pm = _BIND_PAIR.match(b)
        if pm:
            a, c, coll = pm.groups()
            pairs_m = _PAIRS.match(coll)
            if not pairs_m:
                raise rd.fail(p, f"a pair binding needs pairs(GROUP), got {coll!r}")
            members = _collection(rd, pairs_m.group(1), p, groups)
            per.append([{a: u, c: v} for u, v in itertools.combinations(members, 2)])
            continue
        om = _BIND_ONE.match(b)
        if not om:
            raise rd.fail(p, f"cannot read binding {b!r}; expected 'VAR in GROUP'")
        var, coll = om.groups()
        if _PAIRS.match(coll):
            raise rd.fail(p, "pairs(...) binds two names: write '(a, b) in pairs(GROUP)'")
        per.append([{var: m} for m in _collection(rd, coll, p, groups)])
    out: list[dict[str, str]] = []
    for combo in itertools.product(*per):
        merged: dict[str, str] = {}
        for d in combo:
            merged.update(d)
        out.append(merged)
    return out


def _substitute(text: str, binding: Mapping[str, str]) -> str:
    if not binding:
        return text
    pattern = re.compile(r"\b(" + "|".join(re.escape(k) for k in binding) + r")\b")
    return pattern.sub(lambda m: binding[m.group(1)], text)


def _fmt(x: float) -> str:
    return f"{x:.12g}"


def expand_spec(
    rd: Reader,
    value: Any,
    groups: Mapping[str, Sequence[str]],
    constants: Mapping[str, float],
) -> list[Clause]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value:
        raise rd.fail("spec", "expected a non-empty list of clauses (or one STL string)")
    clauses: list[Clause] = []
    for i, c in enumerate(value):
        p = f"spec[{i}]"
        if isinstance(c, str):
            formula, each = c, None
        else:
            m = rd.mapping(c, p, {"formula", "each", "name"})
            formula = rd.require(m, "formula", p)
            if not isinstance(formula, str):
                raise rd.fail(join_key(p, "formula"), "expected STL text")
            each = m.get("each")
        fpath = p if isinstance(c, str) else join_key(p, "formula")

        def dollar(mt: re.Match[str], fpath: str = fpath) -> str:
            key = mt.group(1)
            if key not in constants:
                raise rd.fail(
                    fpath, f"unknown constant ${key} (known: {', '.join(sorted(constants))})"
                )
            return _fmt(constants[key])

        formula = _DOLLAR.sub(dollar, formula)
        binds = [{}] if each is None else _bindings(rd, each, join_key(p, "each"), groups)
        for b in binds:
            text = " ".join(_substitute(formula, b).split())
            clauses.append(Clause(fpath, text))
    return clauses


#: How ``inside``/``outside`` of a polygon that is not convex reads: of one of its parts, of
#: all of them.
_PART_JOIN = {"inside": " or ", "outside": " and "}


def spell_parts(rd: Reader, clauses: Sequence[Clause], regions: Sequence[Region]) -> list[Clause]:
    """The clauses with each ``inside``/``outside`` of a polygon that is not convex spelled
    as that of its convex parts (:mod:`planner.spec.cover`): ``inside(d, row)`` is
    ``(inside(d, row_part1) or inside(d, row_part2))``, ``outside`` joins with ``and``; any
    other function of such a polygon is an error naming it."""
    parts: dict[str, list[str]] = {}
    for r in regions:
        if r.part_of is not None:
            parts.setdefault(r.part_of, []).append(r.name)
    if not parts:
        return list(clauses)

    def spell(mt: re.Match[str], cl: Clause) -> str:
        fn, args_text = mt.group(1), mt.group(2)
        args = [a.strip() for a in args_text.split(",")]
        named = [a for a in args if a in parts]
        if not named:
            return mt[0]
        if fn not in _PART_JOIN or len(args) != 2 or args[0] in parts:
            raise rd.fail(
                cl.key_path,
                f"{mt[0]!r}: {named[0]} is a polygon that is not convex (read as its convex "
                f"parts {', '.join(parts[named[0]])}); only inside and outside take it",
            )
        each = (f"{fn}({args[0]}, {p})" for p in parts[args[1]])
        return "(" + _PART_JOIN[fn].join(each) + ")"

    return [Clause(cl.key_path, _CALL.sub(partial(spell, cl=cl), cl.text)) for cl in clauses]


def check_calls(
    rd: Reader,
    clauses: Sequence[Clause],
    vehicles: set[str],
    regions: set[str],
    *,
    ground: bool = False,
) -> None:
    """Every function call names a known predicate with arguments of the right kinds
    (``agl`` only over a ``ground``: a terrain section)."""
    for cl in clauses:
        for mt in _CALL.finditer(cl.text):
            fn, args_text = mt.group(1), mt.group(2)
            if fn not in FUNCTION_NAMES:
                raise rd.fail(
                    cl.key_path,
                    f"unknown function {fn!r} in {cl.text!r} (known: {', '.join(FUNCTION_NAMES)})",
                )
            if fn == "agl" and not ground:
                raise rd.fail(
                    cl.key_path,
                    f"{mt[0]!r} is a height above the ground, and the scenario has none: "
                    "add a terrain section (docs/scenario-format.md, Terrain), or use z(d)",
                )
            args = [a.strip() for a in args_text.split(",")] if args_text.strip() else []
            kinds = FUNCTION_NAMES[fn]
            if len(args) != len(kinds):
                raise rd.fail(
                    cl.key_path,
                    f"{fn} takes {len(kinds)} argument(s), got {len(args)} in {mt[0]!r}",
                )
            for a, k in zip(args, kinds, strict=True):
                if k == "v" and a not in vehicles:
                    raise rd.fail(cl.key_path, f"unknown vehicle {a!r} in {mt[0]!r}")
                if k == "r" and a not in regions:
                    raise rd.fail(
                        cl.key_path,
                        f"unknown region {a!r} in {mt[0]!r} (regions: {', '.join(sorted(regions))})",
                    )


def clause_formulas(problem: Problem) -> list[Formula]:
    """``problem``'s clauses parsed: those parsed at load, or (for a problem made otherwise,
    ``dataclasses.replace``) parsed now with one registry."""
    formulas = list(problem.formulas)
    if len(formulas) != len(problem.clauses):
        registry = build_registry(problem)
        formulas = [parse_clause(problem, c, registry) for c in problem.clauses]
    return formulas


def parse_clause(
    problem: Problem, clause: Clause, registry: FunctionRegistry | None = None
) -> Formula:
    """Parse one expanded clause; a SpecError becomes a ScenarioError naming the clause's key."""
    try:
        phi = parse(clause.text, functions=registry or build_registry(problem))
    except SpecError as exc:
        raise ScenarioError(problem.source, clause.key_path, f"{exc} in {clause.text!r}") from None
    for node in phi.walk():
        if isinstance(node, Comparison):
            bare = _bare_signals(node.lhs) | _bare_signals(node.rhs)
            if bare:
                name = sorted(bare)[0]
                raise ScenarioError(
                    problem.source,
                    clause.key_path,
                    f"{name!r} is used as a number in {str(node)!r}; vehicles are positions: "
                    f"use x({name}), y({name}), z({name}) or a function such as dist",
                )
    horizon = problem.timing.horizon_s
    if phi.horizon > horizon * (1 + 1e-9):
        raise ScenarioError(
            problem.source,
            clause.key_path,
            f"the clause looks {horizon_sum(phi)} ahead, more than the plan's horizon "
            f"{horizon:g} s (timing.horizon_s)",
        )
    return phi


def _bare_signals(e: Expr) -> set[str]:
    if isinstance(e, Signal):
        return {e.name}
    if isinstance(e, Neg):
        return _bare_signals(e.operand)
    if isinstance(e, BinOp):
        return _bare_signals(e.lhs) | _bare_signals(e.rhs)
    return set()
