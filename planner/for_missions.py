"""Plans that PX4's missions can keep: every clause tolerating the timing error PX4 keeps.

``gcs plan SCENARIO --for mission`` (docs/guide.md, "Planning for missions"). A plan flown as
PX4 missions keeps its path but not exactly its clock: on SITL PX4 kept the power line's
missions within about half a second of each other (docs/px4-sitl.md), so a clause that
tolerates less timing error than that (the power line's d1-d2 separation: 0.14 s, d1 3.3 m
behind d2 at up to 5 m/s) breaks in flight, and ``gcs upload --start`` refuses such a plan.
This loop plans for ``tolerance_s`` of timing error instead (Donzé and Maler's temporal
robustness, per vehicle: :mod:`planner.spec.timing`):

1. the spec in its finest clauses (:func:`planner.spec.margins.split_clauses`), each given
   *time margins* (:func:`planner.spec.timing.widened`: an ``eventually`` window narrowed by
   ``tolerance_s`` at each end, an ``always`` window grown): what a mission late or early as
   a whole needs;
2. planned; then each clause is judged on the plan with its vehicles off by ``tolerance_s``
   (:func:`planner.spec.timing.worst_shifted`: one early or late, two the opposite ways),
   what vehicles off against each other need;
3. a clause that falls below ``epsilon`` there is tightened (:mod:`planner.spec.margins`: a
   larger separation, a keep-out grown, an inspection place shrunk) by what the shift cost it
   plus :data:`PAD_M`, added to its margin so far, and the problem planned again, warm from
   the last plan;
4. until every clause tolerates ``tolerance_s`` on the plan, or ``rounds`` plans (a round whose
   margins cost the plan the spec is planned again half way back, once).

Every plan is judged against the spec as written (:func:`planner.solve.plan_check.recheck`);
the one kept is the first that meets it and tolerates ``tolerance_s`` everywhere, else the one
that meets it whose least tolerant clause tolerates most (the plan as written when none
meets it). What it tolerates is measured on the plan's own clock; PX4's mission flight adds
its lateness on top, which the mission conversion predicts (``gcs upload``, ``gcs fly
--mode mission``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from planner.assurance import MissionTiming
from planner.optimize import plan
from planner.problem import Clause, Problem
from planner.results import PlanResult
from planner.scenario.spec import clause_formulas
from planner.solve.plan_check import recheck
from planner.spec.heading import heading_signals, uses_heading
from planner.spec.margins import MarginError, split_clauses, tighten
from planner.spec.timing import time_tolerance, widened, worst_shifted
from planner.stl import Formula

__all__ = [
    "KEEPS_CLOCK_S",
    "PAD_M",
    "ForMissions",
    "MissionRound",
    "plan_for_missions",
    "plan_tolerances",
]

#: PX4 SITL kept the power line's missions' clocks to about this between two vehicles (s).
KEEPS_CLOCK_S = 0.5
#: Added to the robustness a shift cost a clause when its margin grows (m): the next plan
#: moves, and what it loses to the shift moves with it.
PAD_M = 0.05
#: A margin grows by at most this many times its last step (:func:`_next_margin`).
STEP_CAP = 3.0
#: Most plans made by default.
ROUNDS = 6


@dataclass(frozen=True, slots=True)
class MissionRound:
    """One plan of the loop: what it met and tolerated, and the margins it was made with."""

    robustness: float
    success: bool
    least_clause: str
    least_s: float
    margins_m: dict[str, float]
    elapsed_s: float


@dataclass(frozen=True, slots=True)
class ForMissions:
    """The loop's outcome: the plan kept (judged on the spec as written), its timing record
    for the plan file, and every round."""

    result: PlanResult
    timing: MissionTiming
    rounds: tuple[MissionRound, ...]


def _signals(
    result: PlanResult, formulas: Sequence[Formula]
) -> Callable[[str, np.ndarray], np.ndarray]:
    heading = uses_heading(formulas)

    def at(name: str, t: np.ndarray) -> np.ndarray:
        return heading_signals(result.trajectories, t, heading)[name]

    return at


def _tolerances(
    result: PlanResult, problem: Problem, clauses: Sequence[Formula], up_to_s: float
) -> dict[str, float]:
    """Per clause of ``problem`` (split), the seconds of timing error it tolerates on the plan."""
    t = problem.timing
    grid = np.arange(0.0, t.horizon_s + 0.5 * t.check_dt_s, t.check_dt_s)
    signal = _signals(result, clauses)
    names = [v.name for v in problem.vehicles]
    return {
        str(c): time_tolerance(
            c, signal, names, grid, t.check_dt_s, epsilon=problem.epsilon, up_to_s=up_to_s
        )
        for c in clauses
    }


def _costs(
    result: PlanResult, problem: Problem, clauses: Sequence[Formula], tau: float
) -> dict[str, float]:
    """Per clause below ``epsilon`` with its vehicles off by ``tau``: what the shift cost it
    against ``epsilon`` (m), the margin it lacks."""
    t = problem.timing
    grid = np.arange(0.0, t.horizon_s + 0.5 * t.check_dt_s, t.check_dt_s)
    signal = _signals(result, clauses)
    names = [v.name for v in problem.vehicles]
    out = {}
    for c in clauses:
        worst = worst_shifted(c, signal, names, grid, t.check_dt_s, tau)
        if worst < problem.epsilon:
            out[str(c)] = problem.epsilon - worst
    return out


def _next_margin(seen: Sequence[tuple[float, float]], cost: float, tau: float) -> float:
    """A clause's next margin (m) from its rounds so far, ``(margin, seconds tolerated)``:
    the last margin plus what the shift cost it and :data:`PAD_M` (the plan moves with the
    margin, so this alone gains the tolerance a step at a time), or, once two rounds show how
    the tolerance grows with the margin, the secant's margin for ``tau`` (at least the
    first, at most :data:`STEP_CAP` times the last step further)."""
    m, tol = seen[-1]
    step = cost + PAD_M
    if len(seen) >= 2:
        m0, tol0 = seen[-2]
        if tol > tol0 + 1e-3 and m > m0:
            secant = (tau - tol) * (m - m0) / (tol - tol0)
            step = min(max(step, secant), STEP_CAP * (m - m0))
    return m + step


def _with_time_margins(problem: Problem, tau: float) -> tuple[Problem, dict[str, str]]:
    """``problem`` (split) with every clause widened by ``tau`` (:func:`widened`), and each
    widened clause's text by the text of the clause it came from."""
    horizon = problem.timing.horizon_s
    clauses, by_text = [], {}
    for clause, phi in zip(problem.clauses, clause_formulas(problem), strict=True):
        wide = widened(phi, tau, horizon)
        clauses.append(Clause(clause.key_path, str(wide)))
        by_text[str(phi)] = str(wide)
    return dataclasses.replace(problem, clauses=tuple(clauses)), by_text


def plan_tolerances(result: PlanResult, problem: Problem, up_to_s: float = 3.0) -> dict[str, float]:
    """Per clause of ``problem``'s split spec, the seconds of timing error it tolerates on the
    plan ``result`` (:func:`planner.spec.timing.time_tolerance`)."""
    split = split_clauses(problem)
    clauses = [c for phi in clause_formulas(split) for c in phi.clauses]
    return _tolerances(result, split, clauses, up_to_s)


def plan_for_missions(
    problem: Problem,
    *,
    tolerance_s: float = KEEPS_CLOCK_S,
    rounds: int = ROUNDS,
    time_limit_s: float | None = None,
    say: Callable[[str], None] | None = None,
) -> ForMissions:
    """Run the loop (module docstring) on ``problem``, the scenario as written."""
    say = say or (lambda _line: None)
    if not (math.isfinite(tolerance_s) and tolerance_s > 0.0):
        raise ValueError(f"tolerance_s must be > 0, got {tolerance_s!r}")
    t0 = time.perf_counter()
    split = split_clauses(problem)
    clauses = [c for phi in clause_formulas(split) for c in phi.clauses]
    timed, wide_text = _with_time_margins(split, tolerance_s)
    margins: dict[str, float] = {}
    seen: dict[str, list[tuple[float, float]]] = {}  # per clause: (margin, tolerated s) so far
    backed_off = False
    kept: tuple[PlanResult, dict[str, float], dict[str, float]] | None = None
    history: list[MissionRound] = []
    tight: PlanResult | None = None
    for k in range(1, max(1, rounds) + 1):
        try:
            asked = tighten(timed, {wide_text[c]: m for c, m in margins.items()})
        except MarginError as exc:
            say(f"round {k}: {exc}; stopping")
            break
        # warm from the last plan, unless the last round gained nothing: the structure the
        # warm start keeps (who follows whom) may be what limits the tolerance
        stalled = (
            not backed_off
            and len(history) >= 2
            and history[-1].success
            and history[-2].success
            and history[-1].least_s <= history[-2].least_s + 0.01
        )
        warm = None if tight is None or stalled else tight.decision
        tight = plan(asked, initial_guess=warm, time_limit_s=time_limit_s)
        if warm is not None and not tight.success:
            tight = plan(asked, time_limit_s=time_limit_s)
        judged = recheck(tight, split, note=f"planned for missions, round {k}")
        tolerates = _tolerances(judged, split, clauses, up_to_s=max(3.0, 2 * tolerance_s))
        least = min(tolerates.items(), key=lambda kv: kv[1])
        history.append(
            MissionRound(
                robustness=judged.robustness,
                success=judged.success,
                least_clause=least[0],
                least_s=least[1],
                margins_m=dict(margins),
                elapsed_s=time.perf_counter() - t0,
            )
        )
        say(
            f"round {k}: robustness {judged.robustness:+.3f}, least tolerant {least[0]} "
            f"{least[1]:.2f} s (asked {tolerance_s:g} s)"
        )
        if judged.success and (kept is None or least[1] > min(kept[1].values())):
            kept = (judged, tolerates, dict(margins))
        if judged.success and least[1] >= tolerance_s:
            break
        if not judged.success:
            if kept is None or backed_off:
                say(f"round {k}: the margins cost the plan the spec; keeping the best so far")
                break
            # half way back to the margins of the best plan so far, once
            best, _, good = kept
            margins = {c: 0.5 * (good.get(c, 0.0) + m) for c, m in margins.items()}
            tight = best  # warm from the best plan, not the one that failed
            say(f"round {k}: the margins cost the plan the spec; half of the last step")
            backed_off = True
            continue
        backed_off = False
        for c, cost in _costs(judged, split, clauses, tolerance_s).items():
            seen.setdefault(c, []).append((margins.get(c, 0.0), tolerates[c]))
            margins[c] = _next_margin(seen[c], cost, tolerance_s)
    if kept is None:  # no plan met the spec: the first, as it is (its clauses' tolerance)
        assert tight is not None
        first = recheck(tight, split, note="planned for missions")
        kept = (first, _tolerances(first, split, clauses, 3.0), dict(margins))
    result, tolerates, used = kept
    met = result.success and min(tolerates.values()) >= tolerance_s
    timing = MissionTiming(
        tolerance_s=tolerance_s,
        met=met,
        clauses_s=tolerates,
        margins_m={c: round(m, 4) for c, m in used.items() if m > 0.0},
        rounds=len(history),
    )
    return ForMissions(result=recheck(result, problem), timing=timing, rounds=tuple(history))
