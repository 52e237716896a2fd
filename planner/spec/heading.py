"""The heading the spec asks for: where ``face(d, target)`` must hold, the vehicle faces it.

The NLP plans positions only (``face`` is a constant in it: :mod:`planner.spec.predicates`); the
heading is derived from the planned positions here, and the exact check then evaluates
``face`` on it, so a plan never claims a view it does not have.

A *facing rule* of vehicle ``d`` is read from the spec: a conjunction holding ``face(d, T)``
and a place of ``d`` (``always[0, 2] (inside(d, insp3) and face(d, pole3))``) asks ``d`` to
face ``T`` whenever it is in that place; a ``face(d, T)`` under ``always[a, b]`` of the
spec's conjunction asks it over ``[a, b]``.  On the dense samples, each vehicle's wanted
heading is the bearing to its target wherever a rule applies (the first rule, in spec
order); the schedule (:class:`planner.trajectory.YawPolicy`, ``SCHEDULE``) follows it there
and turns linearly, along the shorter way, in between: from the end of one facing run to
the start of the next, so the turn happens while the vehicle flies from one target to the
next.  Before its first run a vehicle already faces its first target; after its last it
keeps its heading.  The turn rate this takes is reported against the vehicle's yaw-rate
limit (:func:`yaw_rate_needed`; PX4's MPC_YAWRAUTO_MAX, 45 deg/s by default).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.spec.geometry import Place, place
from planner.spec.predicates import Role, role_of
from planner.stl import Always, And, Call, Expr, Formula, Predicate
from planner.trajectory import Trajectory, YawMode, YawPolicy

__all__ = [
    "YAW_RATE_MAX_DEG_S",
    "FacingRule",
    "facing_rules",
    "heading_readers",
    "heading_signals",
    "uses_heading",
    "with_heading",
    "yaw_rate_needed",
]

#: The yaw rate a schedule may ask for (PX4's MPC_YAWRAUTO_MAX default), deg/s.
YAW_RATE_MAX_DEG_S = 45.0
#: Spacing of a facing run's knots (s): the bearing changes slowly as the vehicle hovers.
_KNOT_DT_S = 0.25


@dataclass(frozen=True, slots=True, eq=False)
class FacingRule:
    """``vehicle`` faces the centre of region ``target`` while in ``where`` (a place;
    ``None``: anywhere) during ``window_s`` (absolute; ``None``: the whole plan)."""

    vehicle: str
    target: str
    where: Place | None
    window_s: tuple[float, float] | None


def _faces(node: Formula) -> list[Predicate]:
    return [
        c
        for c in (node.operands if isinstance(node, And) else (node,))
        if isinstance(c, Predicate) and role_of(c) is Role.HEADING
    ]


def facing_rules(formula: Formula, problem: Any) -> list[FacingRule]:
    """The facing rules of the spec (module docstring), in spec order."""
    rules: list[FacingRule] = []

    def walk(node: Formula, window: tuple[float, float] | None, top: bool) -> None:
        if isinstance(node, And):
            faces = _faces(node)
            others = [c for c in node.operands if c not in faces]
            for f in faces:
                d, target = f.call.args
                where = [
                    pl
                    for pl in (place(c, problem) for c in others)
                    if pl is not None and pl.vehicle == d
                ]
                if where:
                    rules.append(FacingRule(d, target, where[0], None))
                elif top:
                    rules.append(FacingRule(d, target, None, window))
            for c in others:
                walk(c, window, top)
            return
        if isinstance(node, Predicate) and role_of(node) is Role.HEADING and top:
            d, target = node.call.args
            rules.append(FacingRule(d, target, None, window))
            return
        if isinstance(node, Always) and top:
            walk(node.child, (node.start_s, node.end_s), top)
            return
        for child in node.children:
            walk(child, None, False)

    walk(formula, None, True)
    return rules


def _wanted(
    rules: Sequence[FacingRule], problem: Any, t_s: np.ndarray, pos: np.ndarray
) -> np.ndarray:
    """The heading wanted at each sample (NaN: free), ENU rad."""
    want = np.full(len(t_s), np.nan)
    for rule in rules:
        on = np.isnan(want)
        if rule.window_s is not None:
            on &= (t_s >= rule.window_s[0] - 1e-9) & (t_s <= rule.window_s[1] + 1e-9)
        if rule.where is not None:
            on &= np.all(pos @ rule.where.A.T <= rule.where.b + 1e-9, axis=1)
        c = problem.region(rule.target).center_enu_m
        want[on] = np.arctan2(c[1] - pos[on, 1], c[0] - pos[on, 0])
    return want


def _knots(t_s: np.ndarray, want: np.ndarray) -> tuple[list[float], list[float]] | None:
    """Knots following ``want`` on its runs (every ``_KNOT_DT_S`` and at both ends), turning
    linearly between runs; ``None`` when nothing is wanted."""
    idx = np.nonzero(~np.isnan(want))[0]
    if idx.size == 0:
        return None
    breaks = np.nonzero(np.diff(idx) > 1)[0]
    runs = np.split(idx, breaks + 1)
    kt: list[float] = []
    ky: list[float] = []
    for run in runs:
        keep = [run[0]]
        for k in run[1:]:
            if t_s[k] - t_s[keep[-1]] >= _KNOT_DT_S - 1e-9:
                keep.append(k)
        if keep[-1] != run[-1]:
            keep.append(run[-1])
        for k in keep:
            if kt and t_s[k] <= kt[-1]:
                continue
            kt.append(float(t_s[k]))
            ky.append(float(want[k]))
    ky = np.unwrap(np.asarray(ky)).tolist()  # the shorter turn between knots
    return kt, ky


def with_heading(problem: Any, rules: Sequence[FacingRule], trajectories: Sequence[Trajectory],
                 t_s: np.ndarray) -> list[Trajectory]:  # fmt: skip
    """The trajectories with the heading the rules want (a ``SCHEDULE`` yaw policy, from
    the positions at the dense times ``t_s``); those no rule names keep theirs."""
    out = []
    for tr in trajectories:
        mine = [r for r in rules if r.vehicle == tr.name]
        got = _knots(t_s, _wanted(mine, problem, t_s, tr.position(t_s))) if mine else None
        if got is None:
            out.append(tr)
            continue
        policy = YawPolicy(mode=YawMode.SCHEDULE, yaw_rad=got[1][0], knots_t_s=tuple(got[0]),
                           knots_yaw_rad=tuple(got[1]))  # fmt: skip
        out.append(Trajectory(tr.segment_t0_s, tr.segment_duration_s, tr.coeffs, tr.name, policy))
    return out


def yaw_rate_needed(trajectory: Trajectory) -> float:
    """The largest turn rate (deg/s) a trajectory's yaw schedule asks for (0 without one)."""
    pol = trajectory.yaw_policy
    if pol.mode is not YawMode.SCHEDULE or len(pol.knots_t_s) < 2:
        return 0.0
    t = np.asarray(pol.knots_t_s)
    y = np.unwrap(np.asarray(pol.knots_yaw_rad))
    return float(math.degrees(np.max(np.abs(np.diff(y) / np.diff(t)))))


def heading_readers(formula: Formula) -> frozenset[str]:
    """The vehicles whose heading ``formula`` reads: the first argument of each heading call
    (``face(d, target)``) anywhere in it, in arithmetic too (empty: positions only)."""
    found: set[str] = set()

    def walk(node: Formula | Expr) -> None:
        if isinstance(node, Call):
            if role_of(node) is Role.HEADING and node.args:
                found.add(node.args[0])
            return
        for f in dataclasses.fields(node):
            value = getattr(node, f.name)
            for x in value if isinstance(value, tuple) else (value,):
                if isinstance(x, Formula | Expr):
                    walk(x)

    walk(formula)
    return frozenset(found)


def uses_heading(formulas: Sequence[Formula]) -> bool:
    """Whether a formula calls a heading predicate (``face``) anywhere (in arithmetic too)."""
    return any(heading_readers(f) for f in formulas)


def heading_signals(
    trajectories: Sequence[Trajectory], t_s: np.ndarray, heading: bool
) -> dict[str, np.ndarray]:
    """Each vehicle's signal at ``t_s``: positions (n, 3), with ``heading`` also the ENU
    yaw as a fourth column (what ``face`` reads)."""
    if not heading:
        return {tr.name: tr.position(t_s) for tr in trajectories}
    return {tr.name: np.column_stack([tr.position(t_s), tr.yaw_rad(t_s)]) for tr in trajectories}
