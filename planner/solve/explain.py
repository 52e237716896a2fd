"""What a plan that falls short of its mission would need (issue 19, "anytime, bounded,
explained"): a few lines a user at a terminal can act on.

* **Time.** Each vehicle's route (the first start's, :func:`planner.solve.guess.visit_targets`) is timed
  at the vehicle's own limits: every leg flown straight from rest to rest on the fastest
  trapezoid the per-axis limits allow, every place held for the spec's hover there.  A
  clause whose place is reached later than the clause allows is named with the time it
  would need: the route's time is optimistic (no detour around keep-outs, full speed), so a
  shortfall it shows is real.  A route longer than the horizon asks for a longer horizon.
* **Solver.** A solve stopped by the time limit or IPOPT's iteration limit asks for more of
  them; one that converged after every start asks for more starts (a local optimum).

Nothing here changes the plan; :func:`planner.optimize.plan` adds the lines to a failed
result (``PlanResult.needs``) and ``gcs plan`` prints them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.problem import Problem
from planner.solve.coarse_start import CoarseOutcome
from planner.solve.guess import (
    Choices,
    axis_limits,
    hover_times,
    leg_profile,
    places_in,
    start_of,
    visit_targets,
)
from planner.spec.geometry import Place
from planner.stl import And, Formula

__all__ = ["needs"]

#: A clause reached this much (s) after its deadline is reported late (the timing is rough).
_LATE_S = 0.5


def _arrivals(
    problem: Problem, formula: Formula, vehicle: Any, start: np.ndarray, hovers: dict[str, float]
) -> tuple[list[Place], dict[Any, float], float]:
    """The vehicle's route, the time it first gets to each place on it (by place key), and
    when the route ends (s), at its limits."""
    route = visit_targets(formula, vehicle.name, problem, start)
    v_lim, a_lim = axis_limits(vehicle)
    at: dict[Any, float] = {}
    t, here = 0.0, start
    for pl in route:
        t += leg_profile(np.asarray(pl.point) - here, v_lim, a_lim)[0]
        at.setdefault(pl.key, t)
        t += hovers.get(pl.name, 0.0)
        here = np.asarray(pl.point)
    return route, at, t


def needs(
    problem: Problem,
    formula: Formula,
    *,
    solver_status: str,
    stopped_by_time: bool,
    starts: int,
    combinatorial: CoarseOutcome | None = None,
) -> list[str]:
    """Lines saying what the plan would need to meet the mission (empty if nothing is
    found to say).  ``combinatorial``: what the combinatorial stage found; clauses it found
    in conflict lead, and no other advice follows them (more time or starts cannot mend a
    conflict)."""
    out: list[str] = []
    if combinatorial is not None and combinatorial.conflict is not None:
        conflict = combinatorial.conflict
        names = "; ".join(f"{c.key_path} `{c.text}`" for c in conflict.clauses)
        return [
            f"conflict: no plan on the coarse model (positions every "
            f"{combinatorial.result.dt_s:g} s) meets these "
            f"{len(conflict.clauses)} clauses together"
            + ("" if conflict.irreducible else " (perhaps not all of them are needed)")
            + f": {names}; change one of them"
        ]
    clauses = list(formula.operands) if isinstance(formula, And) else [formula]
    horizon = problem.timing.horizon_s
    for v in problem.vehicles:
        start = start_of(problem, v.name)
        hovers = hover_times(formula, v.name, problem)
        route, at, end = _arrivals(problem, formula, v, start, hovers)
        if not route:
            continue
        names = " -> ".join(pl.name for pl in route)
        late: list[tuple[float, str, Formula]] = []  # (deadline, place, clause) missed
        for clause in clauses:
            places = places_in(clause, v.name, start, [], problem, Choices())
            if not places or places[-1].key not in at:
                continue
            last = places[-1]
            deadline = clause.horizon - hovers.get(last.name, 0.0)
            arrive = at[last.key]
            if arrive > deadline + _LATE_S:
                late.append((deadline, last.name, clause))
                out.append(
                    f"time: {v.name} reaches {last.name} at about {arrive:.1f} s at its limits "
                    f"(route {names}; straight legs, hovers included), and `{clause}` asks "
                    f"for it by {deadline:g} s: about {arrive - deadline:.1f} s more (a later "
                    "deadline or another order), or a faster vehicle"
                )
        if end > horizon + _LATE_S and late:
            # A longer horizon cannot help a vehicle late for a clause's own deadline.
            deadline, place, clause = min(late, key=lambda d: d[0])
            out.append(
                f"horizon: {v.name}'s route ({names}) takes about {end:.1f} s at its limits, "
                f"but a longer horizon would not help: the binding deadline is {place} by "
                f"{deadline:g} s (`{clause}`)"
            )
        elif end > horizon + _LATE_S:
            out.append(
                f"horizon: {v.name}'s route ({names}) takes about {end:.1f} s at its limits, "
                f"the horizon is {horizon:g} s: timing.horizon_s of at least {end:.0f} s"
            )
    if stopped_by_time:
        out.append("solver: stopped at the time limit: more time (--time-limit)")
    elif solver_status.startswith("Maximum_Iterations_Exceeded"):
        out.append(
            f"solver: stopped at IPOPT's iteration limit ({problem.solver.max_iter}): "
            "more iterations (solver.max_iter)"
        )
    elif not out and starts < problem.solver.starts:
        # every distinct start the guess could make was tried: more would not be different
        out.append(
            f"solver: converged short of the mission from each of the {starts} different "
            f"start(s) the initial guess has (solver.starts allows {problem.solver.starts}): "
            "more room around the weakest clause"
        )
    elif not out:
        out.append(
            f"solver: converged short of the mission from {starts} start(s) (a local "
            f"optimum): more starts (solver.starts, now {problem.solver.starts}), or "
            "more room around the weakest clause"
        )
    return out
