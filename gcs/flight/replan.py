"""``gcs fly --replan``: plan the rest of the mission when a vehicle leaves the flight.

The flight engine (:func:`mavlink.flight.fly`) hands the vehicles that left (a link silent
for longer than PX4's offboard-loss time, or a vehicle its own failsafe took: Return, Land,
Hold) to :class:`FlightReplanner`, which plans the rest for the others with
:func:`planner.replan.replan`: from the switch time (the first waypoint at least
``budget_s`` after the departure was seen), the waypoints before it kept, the spec amended
(clauses discharged, taken over, dropped with the vehicle; a keep-out where it stops), within
the time to the switch.  A plan that meets what is left of the spec is streamed from the
switch time; otherwise the flight stops with the reason.  Each replan is recorded
(:class:`ReplanRecord`: the report's and ``--json``'s ``replans``), and the flight is judged
on the spec as last amended (:attr:`FlightReplanner.judged_plan`).  The same happens, with
no vehicle gone, when ``--live-regions`` names an area not yet kept out of; ``--reassign``
hands a lost vehicle's own clauses to another.  A warm-up replan runs in a thread before the
flight, so that the first real one does not pay for loading IPOPT.

The scenario the plan was made from gives what the plan file does not carry (the timing
grid, the model, the solver's settings); :func:`replan_problem` checks that the plan's
trajectories are on that scenario's waypoint grid, so that the kept part is the plan itself.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from gcs.errors import UserError
from gcs.flight.evaluation import reads_heading
from mavlink.flight import NewPlan
from mavlink.monitor_findings import VehicleLeft, Verdict, always_clauses
from mavlink.px4_modes import Px4Mode
from planner.dynamics.prefix import PrefixError, decisions_of
from planner.planfile import plan_formula
from planner.problem import Clause, Problem
from planner.replan import Departure, ReplanError, replan, switch_time
from planner.scenario import load_live_regions, load_scenario
from planner.scenario.sections import ScenarioError
from planner.solve.plan_check import initial_states, make_model
from planner.spec.regions import Region
from planner.strict_read import load_yaml, read_text

if TYPE_CHECKING:
    from planner.planfile import Plan
    from planner.trajectory import Trajectory

__all__ = ["DEFAULT_BUDGET_S", "FlightReplanner", "ReplanRecord", "replan_problem"]

#: The time (s, the plan's) between seeing a departure and the switch to the new plan.
DEFAULT_BUDGET_S = 3.0
#: What the switch keeps free after the solve (s, the plan's): the new setpoints are sampled
#: and spliced into the stream before the switch time.
SWITCH_MARGIN_S = 0.3
#: A plan's trajectory may differ this much (m) from the chain through its waypoints and
#: still be replanned (the plan file stores coefficients to about 1e-12).
GRID_TOLERANCE_M = 1e-4
#: The warm-up solve's limit (s): it holds the planner while it runs, so a real replan that
#: comes meanwhile waits at most this long (it comes at the earliest at the plan's start).
_WARM_UP_S = 2.0


@dataclass(frozen=True, slots=True)
class ReplanRecord:
    """One replan in a flight.

    Attributes:
        event: what happened, for the operator ("d2: link lost at t = 11.0 s").
        vehicles: the vehicles that left.
        t_s: plan time the replan began: when the departure was seen, or, for one seen
            during another replan, when that one had ended.
        switch_s: plan time the new plan differs from.
        solve_s: the replan's wall time (s).
        robustness: the new plan's exact robustness on the amended spec (None: no plan).
        success: the new plan met what is left of the spec and was flown.
        discharged, taken_over, dropped: the clauses that read a departed vehicle, by what
            became of them (:class:`planner.replan.Amendment`).
        reason: why the flight stopped instead ("" when the new plan was flown).
        reassigned, reassigned_to: the clauses of the vehicle that left handed to another
            (``--reassign``), and to which.
    """

    event: str
    vehicles: tuple[str, ...]
    t_s: float
    switch_s: float
    solve_s: float
    robustness: float | None
    success: bool
    discharged: tuple[str, ...] = ()
    taken_over: tuple[str, ...] = ()
    dropped: tuple[str, ...] = ()
    reason: str = ""
    reassigned: tuple[str, ...] = ()
    reassigned_to: str | None = None

    def fates(self) -> list[tuple[str, tuple[str, ...]]]:
        """What became of the clauses that read the vehicles that left: (what, texts)."""
        return [
            ("dropped with the vehicle", self.dropped),
            ("taken over by the others", self.taken_over),
            ("met before it left", self.discharged),
            (f"handed to {self.reassigned_to}", self.reassigned),
        ]

    def to_json(self) -> dict[str, object]:
        """The record as ``--json`` writes it."""

        def num(x: float | None) -> float | None:
            return None if x is None or not math.isfinite(x) else round(float(x), 6)

        return {
            "event": self.event,
            "vehicles": list(self.vehicles),
            "t_s": num(self.t_s),
            "switch_s": num(self.switch_s),
            "solve_s": num(self.solve_s),
            "robustness": num(self.robustness),
            "success": self.success,
            "discharged": list(self.discharged),
            "taken_over": list(self.taken_over),
            "dropped": list(self.dropped),
            "reason": self.reason,
            "reassigned": list(self.reassigned),
            "reassigned_to": self.reassigned_to,
        }


def replan_problem(plan: Plan, scenario: str | None = None) -> Problem:
    """The problem to replan ``plan`` with: its scenario (``scenario``, else the file the
    plan names) with the plan's vehicles, regions and spec.

    Raises:
        UserError: the scenario cannot be read, is not the plan's (vehicles, horizon), does
            not plan on the minimum-jerk model, or the plan's trajectories are not on its
            waypoint grid (one line naming the file).
    """
    path = scenario or plan.scenario
    if not path:
        raise UserError(f"{plan.input_file}: --replan needs the plan's scenario (--scenario)")
    names = [v.name for v in plan.vehicles]
    try:
        problem = load_scenario(path)
        if [v.name for v in problem.vehicles] != names and "count" in _vehicles_section(path):
            # a generated fleet planned with gcs plan --vehicles N
            problem = load_scenario(path, vehicles=len(plan.vehicles))
    except (OSError, ScenarioError) as exc:
        raise UserError(f"--replan: cannot read the plan's scenario: {exc}") from None
    if [v.name for v in problem.vehicles] != names:
        raise UserError(
            f"{path}: its vehicles ({', '.join(v.name for v in problem.vehicles)}) are not "
            f"the plan's ({', '.join(names)}): --replan needs the scenario the plan was made from"
        )
    if abs(problem.timing.horizon_s - plan.horizon_s) > 1e-9:
        raise UserError(
            f"{path}: horizon {problem.timing.horizon_s:g} s, the plan's {plan.horizon_s:g} s: "
            "--replan needs the scenario the plan was made from"
        )
    # the plan's spec, regions and starts (a plan made to a probability has its margins)
    clauses = problem.clauses
    if problem.spec_text != plan.spec:
        clauses = tuple(
            Clause(f"spec[{i}]", str(c)) for i, c in enumerate(plan_formula(plan).clauses)
        )
    vehicles = tuple(
        dataclasses.replace(
            v,
            start_enu_m=(float(p.start_enu_m[0]), float(p.start_enu_m[1]), float(p.start_enu_m[2])),
        )
        for v, p in zip(problem.vehicles, plan.vehicles, strict=True)
    )
    problem = dataclasses.replace(
        problem,
        workspace=plan.workspace,
        regions=plan.regions,
        clauses=clauses,
        vehicles=vehicles,
        separation_m=plan.separation_m,
        epsilon=plan.epsilon,
    )
    try:
        model = make_model(problem)
        x0s = initial_states(problem, model)
        for pv, x0 in zip(plan.vehicles, x0s, strict=True):
            chain = model.trajectory(decisions_of(model, pv.trajectory), x0, pv.name)
            t = np.linspace(0.0, plan.horizon_s, 601)
            off = float(np.abs(chain.position(t) - pv.trajectory.position(t)).max())
            if off > GRID_TOLERANCE_M:
                raise UserError(
                    f"{plan.input_file}: {pv.name}'s trajectory is {off:.3g} m off the "
                    f"waypoint grid of {path} (segment_s {problem.timing.segment_s:g}): "
                    "--replan needs the scenario the plan was made from"
                )
    except PrefixError as exc:
        raise UserError(f"{path}: --replan: {exc}") from None
    return problem


def _vehicles_section(path: str) -> dict[str, object]:
    """The scenario's ``vehicles`` mapping (empty where it lists its vehicles)."""
    data = load_yaml(read_text(Path(path)))
    got = data.get("vehicles") if isinstance(data, dict) else None
    return got if isinstance(got, dict) else {}


class FlightReplanner:
    """The :class:`mavlink.flight.Replanner` of ``gcs fly --replan`` (module docstring).

    Args:
        problem: :func:`replan_problem` of the plan.
        plan: the plan flown.
        budget_s: plan seconds from a departure to the switch (``--replan-budget``).
        reassign: hand the departed vehicle's own clauses to another (``--reassign``,
            :func:`planner.replan.replan`).
        note: one line for the operator (the flight's progress view).
        on_new_plan: called with the plan as amended and the vehicles that left (name ->
            why) when a new plan is flown (the progress view shows it from then on).
        live_regions: a file of regions closed in flight (``--live-regions``,
            :func:`planner.scenario.load_live_regions`), read at the start and whenever it
            changes: each region it names anew is kept out of from the next switch on.
    """

    def __init__(
        self,
        problem: Problem,
        plan: Plan,
        budget_s: float = DEFAULT_BUDGET_S,
        note: Callable[[str], None] | None = None,
        reassign: bool = False,
        on_new_plan: Callable[[Plan, Mapping[str, str]], None] | None = None,
        live_regions: Path | None = None,
    ) -> None:
        self.problem = problem
        self.plan = plan
        self.budget_s = float(budget_s)
        self.reassign = reassign
        self.note = note or (lambda _line: None)
        self.on_new_plan = on_new_plan
        self.trajectories: dict[str, Trajectory] = {v.name: v.trajectory for v in plan.vehicles}
        self.records: list[ReplanRecord] = []
        #: the plan as last amended (None: no replan was flown)
        self.judged_plan: Plan | None = None
        self._t0_wall: float | None = None
        self.live_regions = live_regions
        #: regions of the live file kept out of, and those read but not yet
        self.closed: dict[str, Region] = {}
        self._pending: dict[str, Region] = {}
        self._live_seen: tuple[float, int] | None = None
        self._request: Callable[[], bool] | None = None
        self._watch: asyncio.Task[None] | None = None
        if live_regions is not None:
            self._read_live()  # a bad file is refused before the flight (ScenarioError)
        self._warm = threading.Thread(target=self._warm_up, name="stl-gcs-replan-warm-up")
        self._warm.daemon = True
        self._warm.start()

    def _warm_up(self) -> None:
        """One replan of no consequence before the flight (a vehicle leaving at its start):
        the first solve of a process loads IPOPT and builds CasADi's functions, which took 2 s
        of the first replan's 3 s budget on PX4 SITL; later ones take a quarter of that.
        Its answer is not used, and a failure here is the real replan's to report."""
        first = self.plan.vehicles[-1]
        x, y, z = (float(c) for c in first.start_enu_m)
        with contextlib.suppress(Exception):
            replan(
                self.problem,
                self.trajectories,
                [Departure(first.name, 0.0, (x, y, z), "warm-up")],
                self.problem.timing.segment_s,
                time_limit_s=_WARM_UP_S,
            )

    def close(self, timeout_s: float = 30.0) -> None:
        """Wait for the warm-up to end (a process should not exit inside a solve)."""
        self._warm.join(timeout_s)

    def plan_started(self, t0_monotonic_s: float) -> None:
        """The flight's start on its clock (to convert the plan's seconds to the wall's:
        a dry run's clock may run faster); the live regions are watched from now on."""
        self._t0_wall = time.perf_counter()
        if self.live_regions is not None and self._watch is None:
            self._watch = asyncio.get_running_loop().create_task(self._watch_live())

    def attach(self, request: Callable[[], bool] | None) -> None:
        """The flight engine's way to begin a replan without a departure (None: the flight
        ended, and the live regions are no longer watched)."""
        self._request = request
        if request is None and self._watch is not None:
            self._watch.cancel()

    def _read_live(self) -> bool:
        """Read the live-regions file if it changed; whether regions not kept out of yet
        are pending."""
        assert self.live_regions is not None
        st = self.live_regions.stat()
        seen = (st.st_mtime, st.st_size)
        if seen != self._live_seen:
            self._live_seen = seen
            got = load_live_regions(self.live_regions)
            taken = {r.name for r in self.problem.all_regions} - set(self.closed)
            for r in got:
                if r.name in taken:
                    raise ScenarioError(
                        str(self.live_regions),
                        f"regions.{r.name}",
                        "is the name of a region of the plan: give a closed area a name of its own",
                    )
            for r in got:
                if r.name not in self.closed:
                    self._pending[r.name] = r
        return bool(self._pending)

    async def _watch_live(self, every_s: float = 0.5) -> None:
        """Poll the live-regions file (wall time: it is for a person to edit); ask for a
        replan while regions are pending.  A file that cannot be read in flight is said once
        per change and otherwise left alone."""
        said = ""
        while True:
            try:
                pending = self._read_live()
                said = ""
            except (OSError, ScenarioError) as exc:
                if str(exc) != said:
                    said = str(exc)
                    self.note(f"live regions: {exc}; the regions read before stand")
                pending = bool(self._pending)
            if pending and self._request is not None:
                self._request()
            await asyncio.sleep(every_s)

    def _wall_per_plan_s(self, now_s: float) -> float:
        if self._t0_wall is None or now_s <= 1.0:
            return 1.0
        return max(0.05, (time.perf_counter() - self._t0_wall) / now_s)

    def _departure(self, d: VehicleLeft) -> Departure:
        tr = self.trajectories[d.vehicle]
        pos = d.position_enu_m
        if pos is None:
            pos = tuple(float(x) for x in np.ravel(tr.position(max(d.t_s, 0.0))))  # type: ignore[assignment]
        home = None
        if d.mode is Px4Mode.AUTO_RTL:
            x, y, _ = (float(v) for v in np.ravel(tr.position(0.0)))
            home = (x, y, 0.0)
        if d.verdict is Verdict.LINK_LOST:
            reason = "link lost"
        else:
            reason = f"left the flight ({d.mode.name if d.mode is not None else 'another mode'})"
        assert pos is not None
        return Departure(d.vehicle, max(d.t_s, 0.0), pos, reason, home)

    async def __call__(self, left: Sequence[VehicleLeft], now_s: float) -> NewPlan | str:
        departures = [self._departure(d) for d in left]
        closing = dict(self._pending)
        events = [f"{d.vehicle}: {d.reason} at t = {d.t_s:.1f} s" for d in departures]
        if closing:
            events.append(f"closed at t = {max(now_s, 0.0):.1f} s: {', '.join(closing)}")
        event = "; ".join(events)
        names = tuple(d.vehicle for d in departures)
        switch = switch_time(self.problem, now_s, self.budget_s)
        horizon = self.problem.timing.horizon_s
        self.note(f"replanning ({event}); switch at t = {switch:g} s")
        if switch >= horizon:
            return self._refused(
                event,
                names,
                now_s,
                switch,
                0.0,
                None,
                "no time is left in the plan to switch to another",
            )
        limit = max(0.2, (switch - now_s - SWITCH_MARGIN_S) * self._wall_per_plan_s(now_s))
        t0 = time.perf_counter()
        try:
            got = await asyncio.to_thread(
                replan,
                self.problem,
                self.trajectories,
                departures,
                switch,
                time_limit_s=limit,
                reassign_clauses=self.reassign,
                keep_outs=tuple(closing.values()),
            )
        except ReplanError as exc:
            return self._refused(
                event, names, now_s, switch, time.perf_counter() - t0, None, str(exc)
            )
        solve_s = time.perf_counter() - t0
        a, result = got.amendment, got.result
        kinds = (a.discharged, a.taken_over, a.dropped)
        if not result.success:
            why = (
                f"no plan meets what is left of the spec: the best found has robustness "
                f"{result.robustness:+.3f} ({result.status})"
            )
            return self._refused(
                event, names, now_s, switch, solve_s, result.robustness, why, kinds
            )
        record = ReplanRecord(event, names, now_s, switch, solve_s, result.robustness, True, *kinds)
        self.records.append(
            dataclasses.replace(record, reassigned=a.reassigned, reassigned_to=a.reassigned_to)
        )
        self.problem = a.problem
        self.closed.update(closing)
        for name in closing:
            self._pending.pop(name, None)
        self.trajectories = {n: tr for n, tr in self.trajectories.items() if n not in names}
        self.trajectories.update(got.trajectories)
        amended = result.to_plan(self.plan.scenario)
        self.judged_plan = amended
        if self.on_new_plan is not None:
            self.on_new_plan(amended, {d.vehicle: d.reason for d in departures})
        self.note(
            f"replanned in {solve_s:.2f} s: robustness {result.robustness:+.3f} on what is left "
            f"({len(a.dropped)} clause(s) dropped with {', '.join(names)}, {len(a.taken_over)} "
            f"taken over, {len(a.discharged)} already met"
            + (f", {len(a.reassigned)} handed to {a.reassigned_to}" if a.reassigned_to else "")
            + f"); flying it from t = {switch:g} s"
        )
        formula = plan_formula(amended)
        flying = [v.name for v in amended.vehicles]
        clauses = always_clauses(formula, flying, exclude=reads_heading)
        return NewPlan(switch, got.trajectories, clauses)

    def _refused(
        self,
        event: str,
        names: tuple[str, ...],
        now_s: float,
        switch: float,
        solve_s: float,
        robustness: float | None,
        why: str,
        kinds: tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]] = ((), (), ()),
    ) -> str:
        self.records.append(
            ReplanRecord(event, names, now_s, switch, solve_s, robustness, False, *kinds, why)
        )
        self.note(f"replanning failed: {why}")
        return why
