"""The combinatorial stage as the NLP's first start (docs/solver-notes.md, "Two stages").

:func:`coarse_start` runs :func:`planner.milp.solve_coarse` within a budget: the mixed-integer
program on a coarse model of the vehicles chooses the discrete structure of the spec (which
option of each ``or``, which vehicle takes which task, the order and time of each visit,
which side of each keep-out).  Its incumbent, straight lines between the coarse samples fitted
within the vehicles' limits (:func:`planner.solve.coarse_fit.waypoint_guess`), is the start the NLP
refines.  When the coarse program has no plan that meets the spec, a deletion filter names the
clauses that conflict on the coarse model (:func:`planner.milp.find_conflict`), which
:func:`planner.solve.explain.needs` reports.

What the coarse model is: positions every ``dt_c`` seconds with the vehicles' limits as
bounds on first and second differences, the predicates as linear margins (a cylinder as a
polygon, a separation as the largest per-axis distance): close to the primitives' model, but
neither inside nor outside it, so a coarse answer is a guide for the NLP, not a proof about
the smooth plan; the exact check after the NLP decides.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.milp import CoarseResult, CoarseStatus, Conflict, find_conflict, solve_coarse
from planner.problem import Problem
from planner.solve.coarse_fit import waypoint_guess

__all__ = [
    "AUTO_BUDGET_S",
    "BackgroundStage",
    "CoarseOutcome",
    "StageBeside",
    "coarse_budget_s",
    "coarse_start",
]

#: The share of the time limit the combinatorial stage may use at most.
_LIMIT_SHARE = 0.25
#: Beside the NLP the stage's budget is CPU time of its thread; its wall time is capped at
#: this many times the budget (the planner stops it at its own deadlines as well).
_WALL_FACTOR = 3.0
#: How long the end of a search waits for a stopped stage to end (s).
_STOP_WAIT_S = 0.2
#: The stage's budget when ``solver.coarse_s`` is auto (None): 30 s to find a coarse plan
#: (issue 40's mission of every class: none in 15 s, its optimum at 8-23 s), and
#: :data:`_BASE_S` once a plan is in hand.
AUTO_BUDGET_S = 30.0
#: With the auto budget, how long the guess's first NLP runs at least before it yields to the
#: stage's plan, and how long the stage is waited for (s, wall time from its start) once a plan
#: is in hand, the NLP's met plan or the stage's own incumbent (the budget of 5 s it had
#: before). The whole 30 s would have kept an NLP going nowhere, or a stage proving a plan it
#: has optimal, for a quarter of the time limit (the allocation mission 56 s against 18.5 s,
#: the door puzzle 10.7 s against 8.2 s, at --time-limit 60). A budget given is waited for
#: whole, as before.
_BASE_S = 5.0
#: The share of the stage's budget the covering reading gets before the weaker one is tried.
_COVER_SHARE = 0.5
#: The least time (s) the conflict search gets once the spec is proven infeasible on the
#: coarse model (its answer is worth more than a few more seconds of the NLP).
_CONFLICT_MIN_S = 2.0


@dataclass(frozen=True, slots=True)
class CoarseOutcome:
    """What the combinatorial stage did for one plan.

    Attributes:
        result: the coarse program's result.
        decision: the NLP start made from its incumbent (None without one).
        conflict: the clauses that conflict on the coarse model, when it found no coarse
            plan that meets the spec (None otherwise, or when the filter ran out of time).
    """

    result: CoarseResult
    decision: np.ndarray | None
    conflict: Conflict | None = None
    #: the stage was stopped before its end (a start of the initial guess met the mission
    #: first, the time limit, Ctrl-C): its figures are of a program it did not finish
    stopped: bool = False

    def describe(self) -> str:
        """The start's name in the planner's status."""
        r = self.result
        kind = "optimal" if r.status is CoarseStatus.OPTIMAL else "best found"
        return (
            f"the combinatorial stage's plan ({kind} on the coarse model, every "
            f"{r.dt_s:g} s: robustness {r.robustness:+.3g})"
        )

    def summary(self) -> dict[str, Any]:
        """Plain figures for the plan's statistics (``gcs plan --json``)."""
        r = self.result
        return {
            "status": r.status.value,
            "robustness": None if not math.isfinite(r.robustness) else r.robustness,
            "bound": None if not math.isfinite(r.bound) else r.bound,
            "dt_s": r.dt_s,
            "build_s": r.build_s,
            "solve_s": r.solve_s,
            "binaries": r.num_binaries,
            "windows": "covered" if r.cover else "inner samples",
            "message": r.message,
            "stopped": self.stopped,
            "conflict": None
            if self.conflict is None
            else [c.key_path for c in self.conflict.clauses],
        }


def coarse_budget_s(problem: Problem, remaining_s: float) -> float:
    """The combinatorial stage's budget: ``solver.coarse_s`` (:data:`AUTO_BUDGET_S` when
    auto), at most a quarter of the time left (``remaining_s``; inf without a limit); 0 when
    it is off."""
    given = problem.solver.coarse_s
    budget = AUTO_BUDGET_S if given is None else given
    if math.isfinite(remaining_s):
        budget = min(budget, _LIMIT_SHARE * max(remaining_s, 0.0))
    return budget


def coarse_start(
    problem: Problem, model: Any, x0s: list[np.ndarray], budget_s: float
) -> CoarseOutcome:
    """Run the combinatorial stage within ``budget_s`` seconds (the conflict search, if it
    comes to that, within what is left of it) and make its plan a start of the NLP.

    Args:
        problem: the scenario.
        model: the planner's linear model (:func:`planner.optimize.make_model`).
        x0s: each vehicle's start state ``(n_init, 3)``.
        budget_s: seconds for the whole stage (CPU time of the calling thread, and wall
            time).
    """
    result, conflict = _solve_stage(problem, budget_s, None)
    return _outcome(problem, model, x0s, result, conflict)


def _solve_stage(
    problem: Problem,
    budget_s: float,
    stop: threading.Event | None,
    on_incumbent: Callable[[float], None] | None = None,
    wall_s: float | None = None,
) -> tuple[CoarseResult, Conflict | None]:
    """The stage's programs (HiGHS and numpy only: no CasADi, so that it can run in a
    thread beside the NLP's build): the coarse result and, when no coarse plan meets the
    spec, the clauses in conflict.

    ``budget_s`` is CPU time of the calling thread (the stage's work, the same on a busy
    machine as on an idle one), within ``wall_s`` seconds of wall time (default
    ``budget_s``).  ``on_incumbent``: each better coarse plan's robustness, as HiGHS
    finds it."""
    t0, cpu0 = time.perf_counter(), time.thread_time()
    wall = budget_s if wall_s is None else wall_s

    def left() -> float:
        return min(wall - (time.perf_counter() - t0), budget_s - (time.thread_time() - cpu0))

    # The robustness at least epsilon as a constraint: HiGHS prunes every branch below it
    # (the door puzzle: the optimum 0.4 in 8 s, against no incumbent above -1 in 20 s
    # without), and a spec no coarse path meets is proven INFEASIBLE at once.  Capped like
    # the NLP (solver.robustness_cap_m): more margin is not wanted.
    def solve(cover: bool, share: float = 1.0) -> CoarseResult:
        wall_left = wall - (time.perf_counter() - t0)
        cpu_left = budget_s - (time.thread_time() - cpu0)
        return solve_coarse(
            problem,
            time_limit_s=max(share * wall_left, 0.05),
            robustness_cap_m=problem.solver.robustness_cap_m,
            min_robustness=problem.epsilon,
            cover=cover,
            legs=True,  # the weaker reading too: a leg through a U's wall is no guide
            stop=stop,
            on_incumbent=on_incumbent,
            cpu_until=time.thread_time() + share * max(cpu_left, 0.0),
        )

    # Each always over the coarse steps that cover its window first (a plan the smooth
    # model can keep the timing of), with half the budget; when that is proven impossible,
    # or has found no coarse plan by then, the weaker reading (the steps inside the window)
    # with the rest, before any conflict is named. (Issue 40's mission of every class: the
    # covering reading, 6 s steps asking every 1-2 s hover for 6-12 s, found nothing in
    # 110 s; the weaker one its optimum in 8-11 s. Both keep the legs out of polygons:
    # without, the weaker optimum cut through the U's wall and the NLP ended at -4.85.)
    result = solve(True, _COVER_SHARE)
    if result.status in (CoarseStatus.INFEASIBLE, CoarseStatus.NO_SOLUTION) and left() > 0.05:
        weaker = solve(False)  # a relaxation of the covering reading: its proof is one too
        if weaker.success or CoarseStatus.INFEASIBLE in (weaker.status, result.status):
            result = weaker
    conflict = None
    if result.status is CoarseStatus.INFEASIBLE:
        # no coarse plan meets the spec (proven): which clauses conflict there (a deletion
        # filter of small MILPs, each proven in a fraction of a second on the zoo's)
        spare = max(left(), _CONFLICT_MIN_S)
        conflict = find_conflict(
            problem, time_limit_s=spare, per_solve_s=max(0.5, spare / 8), stop=stop
        )
    return result, conflict


def _outcome(
    problem: Problem,
    model: Any,
    x0s: list[np.ndarray],
    result: CoarseResult,
    conflict: Conflict | None,
) -> CoarseOutcome:
    """The stage's answer as the NLP's start: its waypoints fitted within the limits."""
    if not result.success:
        return CoarseOutcome(result, None, conflict)
    times = np.asarray(result.times_s, dtype=float)
    points = [np.asarray(result.waypoints_enu_m[v.name]) for v in problem.vehicles]
    return CoarseOutcome(result, waypoint_guess(problem, model, x0s, times, points))


class BackgroundStage:
    """The combinatorial stage in a thread beside the NLP's build and first start.

    HiGHS releases the GIL while it solves, so on two cores the stage costs the planner
    little wall time: the NLP is built, and the initial guess's start solved, while it runs.
    Only the programs run in the thread (:func:`_solve_stage`); the fit of the plan's
    waypoints (a CasADi QP) is made by :meth:`outcome`, in the caller's thread.

    Args:
        problem, model, x0s: as for :func:`coarse_start`.
        budget_s: CPU seconds of the stage's thread for the whole stage (its wall time at
            most ``_WALL_FACTOR`` times that).
        on_answer: called from the stage's thread when it ends with a coarse plan or with
            clauses in conflict (the planner then lets the running start yield to it; see
            :class:`planner.optimize.PlanSearch`).
    """

    def __init__(
        self,
        problem: Problem,
        model: Any,
        x0s: list[np.ndarray],
        budget_s: float,
        on_answer: Callable[[str], None] | None = None,
    ) -> None:
        self.problem, self.model, self.x0s = problem, model, x0s
        self.budget_s = budget_s
        #: when the stage began (``time.perf_counter()``)
        self.started_at = time.perf_counter()
        self._on_answer = on_answer
        self._stop = threading.Event()
        self._done = threading.Event()
        self._answer: tuple[CoarseResult, Conflict | None] | None = None
        self._error: BaseException | None = None
        self._cut = False  # stopped before its programs ended
        #: the robustness of the best coarse plan HiGHS has found so far (nan: none yet)
        self.incumbent = math.nan
        self._outcome: CoarseOutcome | None = None
        self._thread = threading.Thread(
            target=self._work, name="stl-gcs combinatorial stage", daemon=True
        )
        self._thread.start()

    def _work(self) -> None:
        try:
            self._answer = _solve_stage(
                self.problem, self.budget_s, self._stop, self._improved,
                wall_s=_WALL_FACTOR * self.budget_s,
            )  # fmt: skip
            self._cut = self._stop.is_set()
        except BaseException as exc:  # re-raised in the caller's thread by outcome()
            self._error = exc
        finally:
            self._done.set()
        if (
            self._answer is not None
            and (self._answer[0].success or self._answer[1] is not None)
            and not self._cut
            and self._on_answer is not None
        ):
            self._on_answer("plan" if self._answer[0].success else "conflict")

    def _improved(self, robustness: float) -> None:
        if not robustness <= self.incumbent:  # nan at first
            self.incumbent = robustness

    @property
    def done(self) -> bool:
        """Whether the stage has ended (finished, stopped or failed)."""
        return self._done.is_set()

    def wait(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` seconds for the stage to end; whether it has."""
        return self._done.wait(timeout_s)

    def stop(self) -> None:
        """Ask the stage to end now (HiGHS stops at its next interrupt check)."""
        self._stop.set()

    def _ended(self) -> tuple[CoarseResult, Conflict | None]:
        self._thread.join()
        if self._error is not None:
            raise self._error
        assert self._answer is not None
        return self._answer

    def outcome(self) -> CoarseOutcome:
        """The stage's answer, once it has ended (this waits for it): its plan as a start,
        or why it has none.  Stopped early, it is marked ``stopped``: its incumbent, if it
        had one, is the start (a conflict search it was in names nothing)."""
        if self._outcome is None:
            result, conflict = self._ended()
            got = _outcome(self.problem, self.model, self.x0s, result, conflict)
            # stopped: its incumbent stands (like one at the time limit), no conflict is named
            self._outcome = (
                dataclasses.replace(got, conflict=None, stopped=True) if self._cut else got
            )
        return self._outcome

    def figures(self) -> CoarseOutcome:
        """What the stage did, for the plan's statistics, without making its start (the
        planner did not need it): waits for the stage to end."""
        if self._outcome is not None:
            return self._outcome
        result, conflict = self._ended()
        return CoarseOutcome(result, None, None if self._cut else conflict, stopped=self._cut)


class StageBeside:
    """The combinatorial stage beside a search (:class:`planner.optimize.PlanSearch`): the
    stage in its thread (:class:`BackgroundStage`), the guess's first NLP yielding to its
    plan, and the stage waited for or stopped once that NLP has ended.

    Args:
        problem, model, x0s, budget_s: as for :class:`BackgroundStage`.
        say: the search's progress.
    """

    def __init__(
        self,
        problem: Problem,
        model: Any,
        x0s: list[np.ndarray],
        budget_s: float,
        say: Callable[[str], None],
    ) -> None:
        self.say = say
        self.budget_s = budget_s
        #: how long the guess's NLP runs before it yields, and the stage is waited for with
        #: a plan in hand: :data:`_BASE_S` with the auto budget, else the budget given
        self.in_hand_s = min(budget_s, _BASE_S) if problem.solver.coarse_s is None else budget_s
        #: what the stage did, once the search asked (None before, or when it was stopped
        #: and had not ended in :data:`_STOP_WAIT_S`)
        self.outcome: CoarseOutcome | None = None
        self._lock = threading.Lock()  # the two instants below and the NLP's watch
        self._answer_at: float | None = None  # when the stage ended with a plan or a conflict
        self._answer_kind: str | None = None  # which ("plan", "conflict")
        self._nlp_at: float | None = None  # when the guess's first NLP began, while it runs
        self._watch: Any = None  # that NLP's iteration watch (its ``deadline``)
        self._stopped = False
        self.stage = BackgroundStage(problem, model, x0s, budget_s, on_answer=self._has_answer)

    # ---------------------------------------------------------- the guess's first NLP

    def _yield_at(self) -> float:
        """When the guess's first NLP yields to the stage's answer: once the stage has a plan,
        or has named clauses in conflict, and the NLP has had :attr:`in_hand_s` (an NLP that
        meets the mission in that time is never cut, whatever the stage does)."""
        assert self._nlp_at is not None
        return max(time.perf_counter(), self._nlp_at + self.in_hand_s)

    def nlp_began(self, watch: Any) -> None:
        """The guess's first NLP begins, stopped by ``watch.deadline``: it yields to the
        stage's answer (:meth:`_yield_at`)."""
        with self._lock:
            self._nlp_at, self._watch = time.perf_counter(), watch
            if self._answer_at is not None:
                watch.deadline = min(watch.deadline, self._yield_at())

    def nlp_ended(self) -> None:
        with self._lock:
            self._nlp_at = self._watch = None

    def yielded(self, status: str, watch: Any, until: float) -> str:
        """The guess's first NLP was stopped before ``until`` (``status``: IPOPT's): if the
        stage's answer stopped it, its status says so (not an error inside the solver), and
        what is left of that start (the eq. (1) rounds' plain maximisation) gets as long
        again, :attr:`in_hand_s`, within ``until``."""
        with self._lock:
            kind = self._answer_kind
        if kind is None:
            return status
        watch.deadline = min(until, time.perf_counter() + self.in_hand_s)
        what = "plan" if kind == "plan" else "clauses in conflict"
        return f"{status}; stopped after {self.in_hand_s:g} s for the combinatorial stage's {what}"

    def _has_answer(self, kind: str) -> None:
        """From the stage's thread: it has a plan, or clauses in conflict (proven on the
        coarse model that no plan meets the spec: the NLP's own answer is then wanted
        within seconds, issue 40, not after its iteration limit); the guess's NLP, if it
        runs, yields."""
        with self._lock:
            self._answer_at, self._answer_kind = time.perf_counter(), kind
            if self._nlp_at is not None:
                self._watch.deadline = min(self._watch.deadline, self._yield_at())

    # ------------------------------------------------------------ after the first NLP

    def answer(
        self, met: float | None, until: float, interrupted: Callable[[], bool]
    ) -> CoarseOutcome | None:
        """The stage's plan as the next start, or None (what it did is in :attr:`outcome`).

        ``met``: the robustness of the plan the guess's NLP met the mission with (None: it
        fell short).  The stage is waited for until ``until`` (or Ctrl-C, ``interrupted``);
        stopped then, its best plan so far stands.  After a met plan, its plan is a start
        only if it promises more margin (its coarse robustness above ``met``); a stage still
        running whose best so far does not is not waited for any longer.  With a plan in hand
        (``met``, or the stage's incumbent) the stage is waited for only until it has run
        :attr:`in_hand_s`: the rest of an auto budget is for finding a coarse plan at all."""
        stage = self.stage
        in_hand = stage.started_at + self.in_hand_s
        if not stage.done:
            self.say("waiting for the combinatorial stage")
            while not stage.wait(0.05):
                now = time.perf_counter()
                if interrupted() or now >= until:
                    break
                if now >= in_hand and (met is not None or not math.isnan(stage.incumbent)):
                    break
        if met is not None and not stage.done and not stage.incumbent > met:
            so_far = (
                "it has no plan yet"
                if math.isnan(stage.incumbent)
                else f"its best plan so far ({stage.incumbent:+.4f} on the coarse model) "
                f"promises no more margin than the plan met ({met:+.4f})"
            )
            self.say(f"combinatorial stage: stopped, {so_far}")
            self.settle(quiet=True)
            return None
        stage.stop()  # ended already, or its incumbent stands
        outcome = self.outcome = stage.outcome()
        if outcome.decision is None:
            r = outcome.result
            if outcome.stopped:
                why = "stopped before it had a plan"
            elif r.status is CoarseStatus.NOT_ENCODABLE:
                why = f"the spec is not encodable there: {r.message}"
            else:
                why = (
                    f"{r.status.value} after {r.build_s + r.solve_s:.1f} s, "
                    f"{r.num_binaries} binaries"
                )
            if outcome.conflict is None:
                alone = "the plan met stands" if met is not None else "the initial guess alone"
                self.say(f"combinatorial stage: no coarse plan ({why}); {alone}")
            return None
        rho_c = outcome.result.robustness
        if met is not None and not rho_c > met:
            self.say(
                f"combinatorial stage: its plan ({rho_c:+.4f} on the coarse model) promises "
                f"no more margin than the plan met ({met:+.4f})"
            )
            return None
        return outcome

    def settle(self, quiet: bool = False, met: bool = False) -> None:
        """At the end of the search: a stage still running is stopped (a start met the
        mission first, or the time is up) and what it did is kept in :attr:`outcome`.
        ``quiet``: the progress has said why already; ``met``: a plan met the mission."""
        stage = self.stage
        if self.outcome is not None or (self._stopped and not stage.done):
            return  # kept already, or waited for once already
        if not stage.done:
            if not (quiet or self._stopped):
                self.say(
                    "combinatorial stage: stopped (not needed: the initial guess's start met "
                    "the mission)"
                    if met
                    else "combinatorial stage: stopped"
                )
            stage.stop()
            self._stopped = True
            # HiGHS ends at its next interrupt check (inside a sub-MIP, up to a second on
            # the zoo's); a stage that has not ended by then ends in its thread after the
            # plan is returned, and its figures are not kept
            if not stage.wait(_STOP_WAIT_S):
                return
        self.outcome = stage.figures()
