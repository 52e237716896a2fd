"""``gcs assess --replan``: the runs that lost a vehicle, replanned as ``gcs fly --replan``
would, and flown again from the same draws.

Under ``--monitor`` a run whose vehicle goes silent is stopped on the lost link (what
``gcs fly`` does without ``--replan``).  With ``--replan`` each such run is taken up where
the monitor saw the loss: the vehicles silent by then leave, the rest of the mission is
planned for the others (:func:`planner.replan.replan`: the switch time ``budget_s`` after the
loss was seen, on the waypoint grid; the time to the switch as the solve's limit, as in
flight at real time; the departure at the vehicle's last reported position), and where that
plan meets what is left of the spec the run is flown again on its own seed (the same wind,
noise and loss) with the new trajectories, which equal the old up to the switch, under the
monitor of the amended spec that no longer stops on the vehicle that left.  The run is then
judged on the amended spec (on the vehicles that flew on), as ``gcs fly --replan`` judges.

Not modelled: a second departure after the replan is a stop (``gcs fly`` would replan again),
and the vehicle that left is taken as silent from its loss on (a failsafe that leaves it
heard is no departure here: the batch simulator's failsafes are its offboard-loss ones).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gcs.assess import MonitorSettings, evaluate_batch
from mavlink.mock.sim.batch import BatchFlights, prepare, simulate
from mavlink.monitor_findings import RunFindings, Verdict
from planner.replan import Departure, ReplanError, replan, switch_time

if TYPE_CHECKING:
    from mavlink.mock.sim.disturbances import Distribution
    from planner.planfile import Plan
    from planner.problem import Problem

__all__ = ["ReplanSettings", "ReplannedRuns", "replan_runs"]

#: As ``gcs fly --replan``: plan seconds kept free between the solve and the switch.
SWITCH_MARGIN_S = 0.3


@dataclass(frozen=True, slots=True)
class ReplanSettings:
    """How a campaign replans (what a task is sent).

    Attributes:
        problem: :func:`gcs.flight.replan.replan_problem` of the plan.
        budget_s: plan seconds from a loss seen to the switch (``--replan-budget``).
        profile, params, rate_hz, drag_per_s: the simulated vehicles, as the campaign's.
        reassign: hand a lost vehicle's own clauses to another (``--reassign``).
    """

    problem: Problem
    budget_s: float
    profile: str
    params: Mapping[str, float]
    rate_hz: float
    drag_per_s: float | None
    reassign: bool = False


@dataclass(frozen=True, slots=True, eq=False)
class ReplannedRuns:
    """A batch's runs with replanning, per run ``(R,)``.

    Attributes:
        tried: the monitor stopped it on a lost link, with a vehicle left to fly on.
        flown: a new plan met what was left of the spec and was flown.
        stopped: the run ended in a stop (no new plan, or a stop of the flight after it).
        true: the judged spec's exact robustness on the true positions: the amended spec
            where a new plan was flown, else the monitored run's.
        solve_s: the replan's wall time (NaN: none).
        why_not: why a tried run was not flown again (codes of
            :data:`gcs.assess.stats.WHY_NOT`, from 1; 0: it was, or it was not tried).
    """

    tried: np.ndarray
    flown: np.ndarray
    stopped: np.ndarray
    true: np.ndarray
    solve_s: np.ndarray
    why_not: np.ndarray


def replan_runs(
    plan: Plan,
    settings: ReplanSettings,
    seeds: Sequence[int],
    dists: Mapping[str, Distribution],
    plain: BatchFlights,
    monitored: BatchFlights,
    max_off_plan_m: float | None,
) -> ReplannedRuns:
    """Replan and fly again the runs of ``monitored`` stopped on a lost link (module
    docstring); ``plain`` is the same batch without the monitor (the loss times)."""

    assert monitored.stop is not None and monitored.stop_s is not None
    n = len(seeds)
    code = monitored.stop.code
    silent = RunFindings.code_of(Verdict.LINK_LOST)
    true = evaluate_batch(plan, monitored)[0].copy()
    out = ReplannedRuns(
        tried=np.zeros(n, dtype=bool),
        flown=np.zeros(n, dtype=bool),
        stopped=code != 0,
        true=true,
        solve_s=np.full(n, np.nan),
        why_not=np.zeros(n, dtype=np.int8),
    )
    names = [v.name for v in plan.vehicles]
    for r in (int(x) for x in np.flatnonzero(code == silent)):
        t_seen = float(monitored.stop_s[r])
        gone = [v for v in range(len(names)) if plain.lost_s[r, v] <= t_seen]
        if not gone or len(gone) == len(names):
            continue
        out.tried[r] = True
        got = _replan_one(plan, settings, plain, r, gone, t_seen)
        if isinstance(got, int):
            out.why_not[r] = got
            continue
        new_plan, solve_s = got
        out.solve_s[r] = solve_s
        again = _fly_again(
            new_plan, settings, seeds[r], dists, [names[v] for v in gone], max_off_plan_m
        )
        assert again.stop is not None
        out.flown[r] = True
        out.stopped[r] = bool(again.stop.code[0] != 0)
        out.true[r] = float(evaluate_batch(new_plan, again)[0][0])
    return out


def _replan_one(
    plan: Plan,
    settings: ReplanSettings,
    plain: BatchFlights,
    r: int,
    gone: Sequence[int],
    t_seen: float,
) -> tuple[Plan, float] | int:
    """The plan flown after the replan of run ``r`` (every vehicle, those that left on their
    old trajectories), and the solve's wall time; else why not (a code of
    :data:`gcs.assess.stats.WHY_NOT`)."""
    problem = settings.problem
    switch = switch_time(problem, t_seen, settings.budget_s)
    if switch >= problem.timing.horizon_s:
        return 1
    trajectories = {v.name: v.trajectory for v in plan.vehicles}
    dt = plain.t_s[1] - plain.t_s[0] if plain.t_s.size > 1 else plan.check_dt_s
    departures = []
    for v in gone:
        t_l = float(plain.lost_s[r, v])
        k = int(min(plain.t_s.size - 1, max(0, math.floor(t_l / dt))))
        p = plain.reported_enu_m[r, v, k]
        pos = (float(p[0]), float(p[1]), float(p[2]))
        departures.append(Departure(plan.vehicles[v].name, t_l, pos, "link lost"))
    t0 = time.perf_counter()
    try:
        got = replan(
            problem,
            trajectories,
            departures,
            switch,
            time_limit_s=max(0.2, switch - t_seen - SWITCH_MARGIN_S),
            reassign_clauses=settings.reassign,
        )
    except ReplanError:
        return 3
    solve_s = time.perf_counter() - t0
    if not got.result.success:
        return 2
    amended = got.result.to_plan(plan.scenario)
    new = {v.name: v for v in amended.vehicles}
    vehicles = tuple(new.get(v.name, v) for v in plan.vehicles)
    flown = dataclasses.replace(
        plan,
        vehicles=vehicles,
        spec=amended.spec,
        regions=amended.regions,
        robustness=amended.robustness,
    )
    return flown, solve_s


def _fly_again(
    plan: Plan,
    settings: ReplanSettings,
    seed: int,
    dists: Mapping[str, Distribution],
    left: Sequence[str],
    max_off_plan_m: float | None,
) -> BatchFlights:
    """Run ``seed`` flown again on ``plan`` under the monitor of its spec, ``left`` excused
    (no stop on their silence, no prediction or off-plan alarm along their old plans)."""
    setup = prepare(
        plan,
        profile=settings.profile,
        params=settings.params,
        rate_hz=settings.rate_hz,
        drag_per_s=settings.drag_per_s,
    )
    setup = dataclasses.replace(
        setup, plans={n: tr for n, tr in setup.plans.items() if n not in left}
    )

    monitor = MonitorSettings(max_off_plan_m).build(plan)[0]  # as the campaign's, of this spec
    return simulate(setup, [seed], dists, monitor=monitor, excused=left)
