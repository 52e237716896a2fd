"""The rest of a plan after vehicles left the flight: the spec amended, the flown part kept.

When a vehicle leaves a flight (its link lost, a failsafe took it), the ground station plans
the rest of the mission for the vehicles that fly on (``gcs fly --replan``; issue 43).  This
module is that planning, with no flight in it:

* **The spec as amended** (:func:`amend`).  Each clause that reads a departed vehicle is, in
  this order: *discharged* if it holds on the plan up to the departure whatever comes after
  (every vehicle taken as far away after it: an inspection done, a separation kept while it
  flew); *taken over* if options of an ``or`` in positive position do not read it
  (the allocation "some drone inspects each pole": the others now must); else *dropped with
  the vehicle* (its own inspections, its workspace).  Clauses that read no departed vehicle
  stay as they are, deadlines on the original clock.  Where the vehicle is, or will stop, is
  a keep-out for the others from the switch time on (a column from the ground to above it,
  ``separation_m`` wider than the plan's path over the time PX4 takes to stop it, and one over
  its home when it returns there).
* **The flown part kept** (:class:`planner.dynamics.prefix.Prefix`).  The new plan is a plan
  of the whole horizon whose waypoints up to the switch time are fixed to the current plan's
  (bounds with equal ends in the NLP), so the vehicles fly the same setpoints until the
  switch and the spec's robustness is judged over the whole mission: windows that have passed
  are judged on the part flown, ``eventually`` clauses met already stay met (STL progression
  by fixing the prefix, exact on the planning grid).  It is warm-started from the current
  plan.

Also: a departed vehicle's own dropped clauses handed to another (:func:`reassign`,
``--reassign``), and regions closed in flight kept out of from the switch on (``keep_outs``,
``--live-regions``; then no vehicle need have left).

Only the minimum-jerk model (``model: minimum_jerk``) has waypoints to fix; a problem of the
double integrator is refused (:class:`ReplanError`).
"""

from __future__ import annotations

import dataclasses
import math
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from planner.dynamics.prefix import Prefix, warm_start
from planner.errors import PlannerError
from planner.optimize import plan
from planner.problem import Clause, DynamicsModel, Problem
from planner.results import PlanResult
from planner.scenario.spec import clause_formulas
from planner.solve.plan_check import make_model
from planner.spec.regions import Region, RegionKind
from planner.stl import Always, And, Eventually, Formula, Or, Until
from planner.trajectory import Trajectory

__all__ = [
    "Amendment",
    "Departure",
    "Replan",
    "ReplanError",
    "amend",
    "reassign",
    "reassign_candidates",
    "replan",
    "switch_time",
]

#: How long after its last sample PX4 may still move a vehicle that left the flight (s): the
#: offboard-loss timeout COM_OF_LOSS_T (1 s by default) towards its last setpoint, then
#: braking to a stop (under a second from 5 m/s; docs/px4-behaviour.md); its plan over this
#: time bounds where it stops.
STOP_WITHIN_S = 2.0
#: A far-away position (m) for a departed vehicle's signal after its departure.
_GONE_M = 1.0e6


class ReplanError(PlannerError, ValueError):
    """A replan that cannot be asked for: the model has no waypoints to fix, a vehicle
    unknown, no vehicle left, a switch time outside the horizon."""


@dataclass(frozen=True, slots=True)
class Departure:
    """A vehicle that left the flight.

    Attributes:
        vehicle: its name.
        t_s: plan time of its last sample (when it left).
        position_enu_m: where it was then (mission frame).
        reason: what happened, for the operator ("link lost", "failsafe: AUTO_RTL").
        home_enu_m: where it flies to when it returns (None: it stops where it is).
    """

    vehicle: str
    t_s: float
    position_enu_m: tuple[float, float, float]
    reason: str
    home_enu_m: tuple[float, float, float] | None = None


@dataclass(frozen=True, slots=True)
class Amendment:
    """The spec for the vehicles that fly on (:func:`amend`).

    Attributes:
        problem: the amended problem: the vehicles that fly on, the clauses left (pruned where
            taken over) and the keep-outs of the departed vehicles.
        switch_s: from when the new plan differs from the current one.
        departures: who left.
        discharged, taken_over, dropped: the texts of the clauses that read a departed
            vehicle, by what became of them (module docstring).
        keep_outs: the regions added: around the departed vehicles, and those closed in flight.
        reassigned: the dropped clauses handed to another vehicle (:func:`reassign`), as
            they were, and ``reassigned_to`` that vehicle (None: none).
    """

    problem: Problem
    switch_s: float
    departures: tuple[Departure, ...]
    discharged: tuple[str, ...]
    taken_over: tuple[str, ...]
    dropped: tuple[str, ...]
    keep_outs: tuple[Region, ...]
    reassigned: tuple[str, ...] = ()
    reassigned_to: str | None = None


@dataclass(frozen=True, slots=True)
class Replan:
    """A replan's answer: the amendment and the plan of the vehicles that fly on."""

    amendment: Amendment
    result: PlanResult

    @property
    def trajectories(self) -> dict[str, Trajectory]:
        """The new plan's trajectories by vehicle name."""
        return {tr.name: tr for tr in self.result.trajectories}


def switch_time(problem: Problem, now_s: float, budget_s: float) -> float:
    """The first waypoint time at or after ``now_s + budget_s`` (the new plan may differ
    only after a fixed waypoint); the horizon if none is left."""
    seg = problem.timing.segment_s
    t = math.ceil((now_s + budget_s) / seg - 1e-9) * seg
    return float(min(max(t, 0.0), problem.timing.horizon_s))


# ------------------------------------------------------------------------ the amendment


def _prune(f: Formula, gone: frozenset[str]) -> Formula | None:
    """``f`` without the options that read ``gone`` (``or`` in positive position only);
    None where what is left still reads them."""
    if not (f.signal_names() & gone):
        return f
    if isinstance(f, Or):
        kept = [g for g in (_prune(c, gone) for c in f.operands) if g is not None]
        if not kept:
            return None
        return kept[0] if len(kept) == 1 else Or(tuple(kept))
    if isinstance(f, And):
        parts = [_prune(c, gone) for c in f.operands]
        return None if any(p is None for p in parts) else And(tuple(p for p in parts if p))
    if isinstance(f, (Always, Eventually)):
        child = _prune(f.child, gone)
        return None if child is None else dataclasses.replace(f, child=child)
    if isinstance(f, Until):
        lhs, rhs = _prune(f.lhs, gone), _prune(f.rhs, gone)
        if lhs is None or rhs is None:
            return None
        return dataclasses.replace(f, lhs=lhs, rhs=rhs)
    return None  # an atom, a negation or an implication that reads a departed vehicle


def _signals_until(
    trajectories: Mapping[str, Trajectory], until_s: float, t: np.ndarray
) -> dict[str, np.ndarray]:
    """Every vehicle's planned positions at ``t`` up to ``until_s``, and after it each far away
    from everything (and from each other): a clause that holds on these holds on what was
    flown before ``until_s``, whatever comes after."""
    out = {}
    for k, (name, tr) in enumerate(sorted(trajectories.items())):
        sig = np.array(tr.position(t), dtype=float)
        sig[t > until_s] = (_GONE_M * (k + 1), 0.0, 0.0)
        out[name] = sig
    return out


def _keep_outs(
    problem: Problem,
    trajectories: Mapping[str, Trajectory],
    departures: Sequence[Departure],
) -> list[Region]:
    """A column per departed vehicle over where it may stop (and one over its home when it
    returns), ``separation_m`` wider, from the ground to ``separation_m`` above."""
    sep = max(problem.separation_m, 0.0)
    floor = min(0.0, problem.workspace.lo_enu_m[2])
    out = []
    for d in departures:
        tr = trajectories[d.vehicle]
        t = np.linspace(d.t_s, min(d.t_s + STOP_WITHIN_S, tr.duration_s), 16)
        pts = np.vstack([tr.position(t), np.asarray(d.position_enu_m, dtype=float)[None]])
        places = [pts]
        if d.home_enu_m is not None:
            places.append(np.asarray(d.home_enu_m, dtype=float)[None])
        for j, p in enumerate(places):
            lo, hi = p.min(axis=0) - sep, p.max(axis=0) + sep
            name = f"left_{d.vehicle}" if j == 0 else f"left_{d.vehicle}_home"
            out.append(
                Region(
                    name,
                    RegionKind.OBSTACLE,
                    (float(lo[0]), float(lo[1]), float(floor)),
                    (float(hi[0]), float(hi[1]), float(max(hi[2], pts[:, 2].max() + sep))),
                )
            )
    return out


def amend(
    problem: Problem,
    trajectories: Mapping[str, Trajectory],
    departures: Sequence[Departure],
    switch_s: float,
    keep_outs: Sequence[Region] = (),
) -> Amendment:
    """The spec for the vehicles that fly on after ``departures`` (module docstring), and
    out of ``keep_outs`` (regions closed in flight, ``gcs fly --live-regions``) from the
    switch time on.

    Args:
        problem: the current plan's problem.
        trajectories: the current plan, by vehicle name (every vehicle of ``problem``).
        departures: the vehicles that left.
        switch_s: from when the new plan may differ (the keep-outs hold from then on).

    Raises:
        ReplanError: a departed vehicle unknown, none left to fly on, or ``switch_s`` outside
            the horizon.
    """
    names = {v.name for v in problem.vehicles}
    gone = frozenset(d.vehicle for d in departures)
    if not gone <= names:
        raise ReplanError(f"unknown vehicle(s) {', '.join(sorted(gone - names))}")
    if gone == names:
        raise ReplanError("no vehicle is left to fly on")
    if not gone and not keep_outs:
        raise ReplanError("nothing to replan for: no vehicle left and no region closed")
    taken = {r.name for r in problem.all_regions}
    for r in keep_outs:
        if r.name in taken:
            raise ReplanError(f"region {r.name!r} is already a region of the plan")
    horizon = problem.timing.horizon_s
    if not 0.0 <= switch_s <= horizon:
        raise ReplanError(f"switch time {switch_s:g} s outside the horizon [0, {horizon:g}] s")
    missing = names - set(trajectories)
    if missing:
        raise ReplanError(f"no trajectory for {', '.join(sorted(missing))}")
    formulas = clause_formulas(problem)
    dt = problem.timing.check_dt_s
    t = np.arange(round(horizon / dt) + 1) * dt
    sig = _signals_until(trajectories, min((d.t_s for d in departures), default=0.0), t)
    kept: list[Clause] = []
    discharged, taken_over, dropped = [], [], []
    for clause, f in zip(problem.clauses, formulas, strict=True):
        if not (f.signal_names() & gone):
            kept.append(clause)
            continue
        if f.robustness(sig, dt) > 0.0:
            discharged.append(clause.text)
            continue
        pruned = _prune(f, gone)
        if pruned is None:
            dropped.append(clause.text)
        else:
            taken_over.append(clause.text)
            kept.append(Clause(clause.key_path, str(pruned)))
    regions = [*_keep_outs(problem, trajectories, departures), *keep_outs]
    flying = tuple(v for v in problem.vehicles if v.name not in gone)
    for r in regions:
        for v in flying:
            kept.append(
                Clause(
                    f"replan.keep_out({r.name})",
                    f"always[{switch_s:g}, {horizon:g}] outside({v.name}, {r.name})",
                )
            )
    amended = dataclasses.replace(
        problem,
        vehicles=flying,
        groups={g: tuple(n for n in m if n not in gone) for g, m in problem.groups.items()},
        regions=(*problem.regions, *regions),
        clauses=tuple(kept),
    )
    return Amendment(
        amended,
        float(switch_s),
        tuple(departures),
        tuple(discharged),
        tuple(taken_over),
        tuple(dropped),
        tuple(regions),
    )


def _own_clauses(amendment: Amendment) -> list[str]:
    """The dropped clauses that read one departed vehicle and no other vehicle (its own
    obligations, which another vehicle can take on as they are)."""
    names = {v.name for v in amendment.problem.vehicles} | {d.vehicle for d in amendment.departures}
    out = []
    for text in amendment.dropped:
        read = {n for n in names if re.search(rf"\b{re.escape(n)}\b", text)}
        if len(read) == 1:
            out.append(text)
    return out


def reassign(amendment: Amendment, to: str) -> Amendment:
    """``amendment`` with the departed vehicles' own dropped clauses (:func:`_own_clauses`)
    given to vehicle ``to`` as they are, the departed vehicle's name replaced by ``to``."""
    own = _own_clauses(amendment)
    gone = [d.vehicle for d in amendment.departures]
    have = {c.text for c in amendment.problem.clauses}
    added = []
    for text in own:
        new = text
        for g in gone:
            new = re.sub(rf"\b{re.escape(g)}\b", to, new)
        if new not in have:  # the same obligation ``to`` has already (its workspace)
            have.add(new)
            added.append(Clause(f"replan.reassigned({to})", new))
    problem = dataclasses.replace(amendment.problem, clauses=(*amendment.problem.clauses, *added))
    return dataclasses.replace(
        amendment,
        problem=problem,
        dropped=tuple(t for t in amendment.dropped if t not in own),
        reassigned=tuple(own),
        reassigned_to=to,
    )


def reassign_candidates(amendment: Amendment, trajectories: Mapping[str, Trajectory]) -> list[str]:
    """The vehicles that fly on, nearest first at the switch time to the regions the
    departed vehicles' own dropped clauses name (none: no clause to hand over)."""
    own = _own_clauses(amendment)
    problem = amendment.problem
    boxes = [  # the places of those clauses (not the workspace, which every vehicle is in)
        r for r in problem.regions if any(re.search(rf"\b{re.escape(r.name)}\b", t) for t in own)
    ]
    if not own:
        return []

    def distance(name: str) -> float:
        p = np.ravel(trajectories[name].position(amendment.switch_s))
        if not boxes:
            return 0.0
        return min(
            float(
                np.linalg.norm(
                    np.maximum(
                        0.0, np.maximum(np.subtract(r.lo_enu_m, p), np.subtract(p, r.hi_enu_m))
                    )
                )
            )
            for r in boxes
        )

    return sorted((v.name for v in problem.vehicles), key=distance)


def replan(
    problem: Problem,
    trajectories: Mapping[str, Trajectory],
    departures: Sequence[Departure],
    switch_s: float,
    *,
    time_limit_s: float | None = None,
    progress: Callable[[str], None] | None = None,
    reassign_clauses: bool = False,
    keep_outs: Sequence[Region] = (),
) -> Replan:
    """Plan the rest of the mission for the vehicles that fly on (module docstring): the
    amended spec, every waypoint up to ``switch_s`` fixed to ``trajectories``, warm-started
    from them, within ``time_limit_s``, every vehicle out of ``keep_outs`` from the switch
    on.  The result is checked like any plan (its ``success``).

    With ``reassign_clauses``, the departed vehicles' own dropped clauses are handed to one vehicle
    that flies on (:func:`reassign`): each candidate in turn, nearest first
    (:func:`reassign_candidates`), each within an equal share of the time left; the best plan
    that meets its spec wins; where none does, the plan without the handover is the answer
    (if time is left for it).  A vehicle that has every handed clause already (the power
    line's two drones on one side inspect the same poles) is the only one tried."""
    if problem.model is not DynamicsModel.MINIMUM_JERK:
        raise ReplanError(
            "replanning keeps the flown part's waypoints, which only the minimum-jerk model "
            "has (model: minimum_jerk)"
        )
    t_end = math.inf if time_limit_s is None else time.perf_counter() + time_limit_s
    amendment = amend(problem, trajectories, departures, switch_s, keep_outs)
    names = reassign_candidates(amendment, trajectories) if reassign_clauses else []
    handed = [reassign(amendment, to) for to in names]
    # a vehicle that has every handed clause already takes them at no cost: the only try
    free = [h for h in handed if len(h.problem.clauses) == len(amendment.problem.clauses)]
    candidates = free[:1] or handed
    best: Replan | None = None
    for i, candidate in enumerate(candidates):
        left = t_end - time.perf_counter()
        if left <= 0.2:
            break
        share = None if math.isinf(left) else left / (len(candidates) - i + 1)
        got = _solve(candidate, trajectories, share, progress)
        if got.result.success and (best is None or got.result.robustness > best.result.robustness):
            best = got
    if best is not None:
        return best
    left = t_end - time.perf_counter()
    return _solve(amendment, trajectories, None if math.isinf(left) else max(left, 0.2), progress)


def _solve(
    amendment: Amendment,
    trajectories: Mapping[str, Trajectory],
    time_limit_s: float | None,
    progress: Callable[[str], None] | None,
) -> Replan:
    amended = amendment.problem
    model = make_model(amended)
    names = [v.name for v in amended.vehicles]
    guess = warm_start(model, names, trajectories)
    result = plan(
        amended,
        initial_guess=guess,
        prefix=Prefix(amendment.switch_s, {n: trajectories[n] for n in names}),
        time_limit_s=time_limit_s,
        progress=progress,
    )
    return Replan(amendment, result)
