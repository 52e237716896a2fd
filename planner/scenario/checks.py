"""Mistakes a scenario can be caught in before any solve: cheap, sound, and named.

:func:`planner.scenario.parse_scenario` runs these on every scenario it loads, after the
clauses are parsed, and turns the first finding into a ``ScenarioError`` (exit 2, the
file and the key).  Each check is *sound*: it fires only where no plan can exist, never on
a mission that is merely hard.

* :func:`start_findings`: a start outside the workspace (naming the bound it misses) or
  inside a box that is a keep-out by kind (obstacle, no-fly zone, pole, conductor).
* :func:`clause_findings`:

  - *t = 0*: what a clause requires at t = 0 (``always[0, b] p``, or a clause with no
    temporal operator) evaluated with every vehicle at its start; a start that already
    breaks it cannot be planned away;
  - *reach*: what a clause requires by a deadline (``eventually[a, b] inside(d, box)``
    needs ``d`` in ``box`` by ``b``; ``always[a, b] inside(d, box)`` by ``a``; nested
    operators add up) against the farthest the vehicle can get from rest at its per-axis
    limits, ``A t^2 / 2`` while accelerating, then ``V t - V^2 / (2 A)``.  The planner's
    minimum-jerk motion reaches less far, so a target beyond this bound is out of reach.

* :func:`horizon_terms`: the interval ends that make a clause's horizon, for the
  message of a clause that looks beyond the plan's (``60 + 50 + 2 = 112 s > 70 s``).

Only what a clause *must* do is read: the conjuncts of a top-level ``and`` and of
``always`` / ``eventually`` / ``until`` bodies.  An ``or``, ``not`` or ``implies`` leaves
a choice and is skipped.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from planner.dynamics.limits import vehicle_bounds
from planner.spec.predicates import Role, role_of
from planner.spec.regions import KEEP_OUT_KINDS, Cylinder, Prism
from planner.stl import Always, And, Eventually, Formula, Predicate, Until
from planner.stl.ast import format_number

if TYPE_CHECKING:
    from planner.problem import Problem, Vehicle
    from planner.spec.regions import Region

_AXES = ("east", "north", "up")


@dataclass(frozen=True, slots=True)
class Finding:
    """A scenario mistake: the key it is at and what is wrong, in one line."""

    key_path: str
    message: str


def start_findings(problem: Problem, start_keys: Mapping[str, str]) -> list[Finding]:
    """Starts outside the workspace or inside a keep-out box (``start_keys``: name -> key)."""
    out: list[Finding] = []
    ws = problem.workspace
    for v in problem.vehicles:
        s = np.asarray(v.start_enu_m, dtype=float)
        key = start_keys[v.name]
        shown = "[" + ", ".join(format_number(float(x)) for x in s) + "]"
        for i, axis in enumerate(_AXES):
            if s[i] < ws.lo_enu_m[i]:
                out.append(Finding(key, f"start {shown} of {v.name} is outside the workspace: "
                                   f"{axis} {format_number(float(s[i]))} is below its minimum "
                                   f"{format_number(ws.lo_enu_m[i])}"))  # fmt: skip
            elif s[i] > ws.hi_enu_m[i]:
                out.append(Finding(key, f"start {shown} of {v.name} is outside the workspace: "
                                   f"{axis} {format_number(float(s[i]))} is above its maximum "
                                   f"{format_number(ws.hi_enu_m[i])}"))  # fmt: skip
        for r in problem.regions:
            if r.kind in KEEP_OUT_KINDS and bool(r.contains(s)):
                out.append(Finding(key, f"start {shown} of {v.name} is inside {r.kind.value} "
                                   f"{r.name!r} ({_box(r)}): no vehicle can start there"))  # fmt: skip
    return out


def clause_findings(problem: Problem, start_keys: Mapping[str, str]) -> list[Finding]:
    """What the clauses require at t = 0 and by their deadlines, against the starts."""
    out: list[Finding] = []
    vehicles = {v.name: v for v in problem.vehicles}
    signals = {v.name: np.asarray(v.start_enu_m, dtype=float)[None, :] for v in problem.vehicles}
    dt = problem.timing.sample_dt_s
    for clause, phi in zip(problem.clauses, problem.formulas, strict=True):
        for atom in at_t0(phi):
            if not atom.signal_names() <= signals.keys():
                continue
            rho = atom.robustness(signals, dt)
            if rho < 0.0:
                who = sorted(atom.signal_names())
                keys = ", ".join(start_keys[n] for n in who)
                out.append(Finding(clause.key_path, f"the starts break {clause.text!r} at t = 0: "
                                   f"{atom} is {rho:+.3g} with {', '.join(who)} at their starts "
                                   f"({keys})"))  # fmt: skip
        for atom, deadline in deadlines(phi):
            if role_of(atom) is not Role.TARGET_BOX:
                continue
            name, region_name = atom.call.args
            v = vehicles.get(name)
            if v is None or deadline <= 0.0:
                continue
            msg = _out_of_reach(v, problem.region(region_name), deadline)
            if msg is not None:
                out.append(Finding(clause.key_path, f"{atom} cannot hold by t = "
                                   f"{format_number(deadline)} s: {msg}"))  # fmt: skip
    return out


def at_t0(phi: Formula) -> list[Formula]:
    """The temporal-free sub-formulas ``phi`` requires at t = 0 (conjunctively)."""
    temporal = any(isinstance(n, Always | Eventually | Until) for n in phi.walk())
    if phi.horizon == 0.0 and not temporal:
        return [phi]
    if isinstance(phi, And):
        return [a for child in phi.children for a in at_t0(child)]
    if isinstance(phi, Always) and phi.start_s == 0.0:
        return at_t0(phi.child)
    return []


def deadlines(phi: Formula, offset_s: float = 0.0) -> list[tuple[Predicate, float]]:
    """Predicate atoms ``phi`` requires to hold at some time no later than their deadline."""
    if isinstance(phi, Predicate):
        return [(phi, offset_s)]
    if isinstance(phi, And):
        return [d for child in phi.children for d in deadlines(child, offset_s)]
    if isinstance(phi, Always):
        return deadlines(phi.child, offset_s + phi.start_s)
    if isinstance(phi, Eventually):
        return deadlines(phi.child, offset_s + phi.end_s)
    if isinstance(phi, Until):
        return deadlines(phi.rhs, offset_s + phi.end_s)
    return []


def horizon_terms(phi: Formula) -> list[float]:
    """The interval ends along the path that makes ``phi.horizon`` (they sum to it)."""
    if isinstance(phi, Always | Eventually):
        return [phi.end_s, *horizon_terms(phi.child)]
    if isinstance(phi, Until):
        deeper = max((phi.lhs, phi.rhs), key=lambda c: c.horizon)
        return [phi.end_s, *horizon_terms(deeper)]
    kids = phi.children
    if not kids:
        return []
    return horizon_terms(max(kids, key=lambda c: c.horizon))


def horizon_sum(phi: Formula) -> str:
    """``"60 + 50 + 2 = 112 s"`` (or ``"112 s"`` for one term), zero terms left out."""
    terms = [t for t in horizon_terms(phi) if t > 0.0]
    total = format_number(phi.horizon)
    if len(terms) <= 1:
        return f"{total} s"
    return " + ".join(format_number(t) for t in terms) + f" = {total} s"


def reach_m(t_s: float, v_max: float, a_max: float) -> float:
    """The farthest one axis gets from rest in ``t_s`` within ``v_max`` and ``a_max``."""
    if t_s <= v_max / a_max:
        return 0.5 * a_max * t_s * t_s
    return v_max * t_s - v_max * v_max / (2.0 * a_max)


def _out_of_reach(v: Vehicle, region: Region, deadline_s: float) -> str | None:
    """Why ``v`` cannot be in ``region`` by ``deadline_s`` from rest, or None: per axis
    within the bound of the direction it must fly (up and down may differ), and
    horizontally within a norm bound."""
    s = np.asarray(v.start_enu_m, dtype=float)
    # a turned or round region: its bounding box, nearer than the region (a sound test)
    lo, hi = np.asarray(region.lo_enu_m), np.asarray(region.hi_enu_m)
    gap = np.maximum(np.maximum(lo - s, s - hi), 0.0)
    vb, ab = vehicle_bounds(v)
    worst: tuple[float, str] | None = None
    for i in range(3):
        ahead = bool(s[i] < lo[i])
        vm = vb.hi[i] if ahead else -vb.lo[i]
        am = ab.hi[i] if ahead else -ab.lo[i]
        reach = reach_m(deadline_s, vm, am)
        if gap[i] > reach and (worst is None or gap[i] - reach > worst[0]):
            why = (
                f"{region.name} is {gap[i]:.4g} m {_direction(i, ahead)} {v.name}'s start and "
                f"{v.name} covers at most {reach:.4g} m that way in "
                f"{format_number(deadline_s)} s from rest (limits {format_number(vm)} m/s, "
                f"{format_number(am)} m/s^2)"
            )
            worst = (gap[i] - reach, why)
    if vb.has_norm:
        a_xy = ab.xy if ab.has_norm else float(np.hypot(ab.hi[0], ab.hi[1]))
        g = float(np.hypot(gap[0], gap[1]))
        reach = reach_m(deadline_s, vb.xy, a_xy)
        if g > reach and (worst is None or g - reach > worst[0]):
            why = (
                f"{region.name} is {g:.4g} m horizontally from {v.name}'s start and {v.name} "
                f"covers at most {reach:.4g} m horizontally in {format_number(deadline_s)} s "
                f"from rest (limits {format_number(vb.xy)} m/s, {format_number(a_xy)} m/s^2)"
            )
            worst = (g - reach, why)
    return None if worst is None else worst[1]


_DIRECTIONS = (("west of", "east of"), ("south of", "north of"), ("below", "above"))


def _direction(axis: int, positive: bool) -> str:
    return _DIRECTIONS[axis][int(positive)]


def _box(r: Region) -> str:
    def vec(x: Sequence[float]) -> str:
        return "[" + ", ".join(format_number(float(c)) for c in x) + "]"

    if isinstance(r.shape, Prism):
        return (f"a prism over {r.shape.walls} corners, z {format_number(r.shape.z_lo_m)} to "
                f"{format_number(r.shape.z_hi_m)}")  # fmt: skip
    if isinstance(r.shape, Cylinder):
        c = r.shape
        return (f"a cylinder of radius {format_number(c.radius_m)} about "
                f"{vec(c.center_xy)}, z {format_number(c.z_lo_m)} to {format_number(c.z_hi_m)}")  # fmt: skip
    return f"{vec(r.lo_enu_m)} to {vec(r.hi_enu_m)}"
