"""Problem -> PlanResult: maximise STL robustness with CasADi/IPOPT (or sqpmethod).

:func:`plan` (and :class:`PlanSearch`, the search as an object) draws the initial guess, runs
the combinatorial stage beside the NLP (:mod:`planner.solve.coarse_start`), solves the NLP of
:mod:`planner.solve.nlp` (its formulation: ``docs/solver-notes.md``) from its starts, refines the best
(:mod:`planner.solve.refine`) and checks it (:mod:`planner.solve.plan_check`).

The measurements behind each choice (smoothing, solver options, the initial guess, eq. (1),
what was tried and not kept) are in ``docs/solver-notes.md``.

After the solve the trajectories are re-sampled every ``check_dt_s`` and evaluated with
the *exact* semantics of the same formula tree (numpy predicates); the result reports
that robustness, the weakest sub-formula (``Formula.weakest``), limits and workspace
checked on the dense samples, and Mueller's thrust/body-rate test where the scenario
gives those limits.  ``success`` means exact robustness >= epsilon with all of those
checks passing; anything else is a ``success=False`` result with the best trajectories
found, never an exception.

Errors: bad scenarios are :class:`~planner.scenario.sections.ScenarioError` (raised by
:mod:`planner.scenario`); this module raises nothing else for bad input.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import numpy as np

from planner.checks import LimitReport, check_trajectories
from planner.dynamics.prefix import Prefix, fixed_entries
from planner.problem import Problem, SolverMethod
from planner.results import ClauseReport, PlanResult, SolveStats, Weakest
from planner.scenario.spec import clause_formulas
from planner.solve.coarse_start import CoarseOutcome, StageBeside, coarse_budget_s
from planner.solve.fix_choices import choices_problem
from planner.solve.guess import initial_guess, starts
from planner.solve.leaves import row_steps
from planner.solve.nlp import (
    K_MIN,
    STRUCTURES,
    BuildTimeout,
    Structure,
    build_structure,
    clear_cache,
    structure_key,
)
from planner.solve.plan_check import (
    check_plan,
    clause_robustness,
    dense_signals,
    dense_times,
    initial_states,
    make_model,
)
from planner.solve.refine import raise_the_rest, sharpen
from planner.solve.screen import (
    GUARD_M,
    REACH_M,
    Screen,
    chosen_screen,
    near_rows,
)
from planner.solve.solver_runs import (
    Attempt,
    SigintWatch,
    SolverRun,
    lower_r,
    margin_rounds,
    nlp_bounds,
    run_solvers,
    solved,
    start_point,
    watch_sigint,
)
from planner.spec.heading import facing_rules, heading_signals, uses_heading, with_heading
from planner.stl import (
    Formula,
    conjunction,
)
from planner.trajectory import Trajectory

__all__ = [
    "K_MIN",
    "ClauseReport",
    "LimitReport",
    "PlanResult",
    "PlanSearch",
    "SolveStats",
    "Weakest",
    "check_trajectories",
    "clear_cache",
    "make_model",
    "plan",
]


def plan(
    problem: Problem,
    *,
    initial_guess: np.ndarray | None = None,
    progress: Callable[[str], None] | None = None,
    time_limit_s: float | None = None,
    progress_every_s: float = 2.0,
    prefix: Prefix | None = None,
) -> PlanResult:
    """Plan trajectories that maximise the robustness of ``problem``'s spec.

    Args:
        problem: a validated scenario (:func:`planner.scenario.load_scenario`).
        initial_guess: flat decision vector (``PlanResult.decision`` of an earlier solve of
            the same structure) to warm start from; default: the starts of
            :meth:`PlanSearch.candidates`.
        progress: called with a short line at each stage (build, solve, check), and
            during a solve every ``progress_every_s`` with the iteration and the best exact
            robustness so far.
        time_limit_s: a bound on the call's wall time (``None``: no limit), the build and
            the check included: the solver stops early enough for the check to fit (its
            cost is measured on the first start), no new start begins after it, and the
            best plan found by then is returned, its status saying so.
        prefix: the waypoints up to ``prefix.until_s`` fixed to those of its trajectories
            (a replan, :mod:`planner.replan`; minimum-jerk model only).

    Returns:
        :class:`PlanResult`; ``success=False`` (with the best trajectories) when the
        exact robustness is below ``epsilon`` or a check fails.
    """
    search = PlanSearch(
        problem,
        progress=progress,
        time_limit_s=time_limit_s,
        progress_every_s=progress_every_s,
        prefix=prefix,
    )
    return search.run(initial_guess)


class PlanSearch:
    """One plan's search: its stages, starts, budget and best result so far.

    In the shape of python-control's ``OptimalControlProblem``: :meth:`run` draws the
    initial guess, starts the combinatorial stage in its thread (:meth:`_start_stage`),
    builds (or takes from the cache) the NLP of the problem's structure, tries the starts of
    :meth:`candidates` (the guess's first, then the stage's plan where it can help), refines
    the best (:func:`raise_the_rest`, :func:`sharpen`), checks it on dense samples and
    returns a :class:`PlanResult`.  The deadline, the iterations and the best iterate seen
    live here, not in the cached structure; one search runs at a time in a process
    (:data:`_PLAN_LOCK`), so two plans started in two threads take turns.
    """

    def __init__(
        self,
        problem: Problem,
        *,
        progress: Callable[[str], None] | None = None,
        time_limit_s: float | None = None,
        progress_every_s: float = 2.0,
        prefix: Prefix | None = None,
    ) -> None:
        self.problem = problem
        self.say: Callable[[str], None] = progress or (lambda _msg: None)
        self.t_start = time.perf_counter()
        self.time_limit_s = time_limit_s
        self.deadline = math.inf if time_limit_s is None else self.t_start + float(time_limit_s)
        self.progress_every_s = progress_every_s
        formulas = clause_formulas(problem)  # parsed once, at load
        self.formulas = formulas
        self.formula = conjunction(formulas)
        # The heading is derived from the positions (planner.spec.heading): where face(d, T) holds
        self.heading = uses_heading(formulas)
        self.rules = facing_rules(self.formula, problem) if self.heading else []
        self.t_dense = dense_times(problem)
        self.model = make_model(problem)
        self.x0s = initial_states(problem, self.model)
        #: the decisions fixed to a prefix (indices, values; :mod:`planner.dynamics.prefix`)
        self.fixed: tuple[np.ndarray, np.ndarray] | None = (
            None
            if prefix is None
            else fixed_entries(self.model, [v.name for v in problem.vehicles], prefix)
        )
        self.check_s = 0.0
        #: seconds one exact evaluation of the clauses took (the check's cost is a few)
        self.exact_eval_s = 0.0
        self.n_starts = 0
        self.best: Attempt | None = None
        self.best_start = (0, "")
        self.combinatorial: CoarseOutcome | None = None
        #: the combinatorial stage, running in its thread beside the build and the initial
        #: guess's first start (:meth:`_start_stage`; None: it does not run)
        self._stage: StageBeside | None = None
        self._rho_first = -math.inf  # the initial guess's start, exact robustness
        #: once a start meets the mission, the seconds more the search may take for margin
        self._margin_s = problem.solver.polish_s
        self._sigint: SigintWatch | None = None
        #: the combinatorial stage's start (None: it made none)
        self._coarse_z: np.ndarray | None = None
        #: the starts made from the combinatorial stage's plan (it, its choices refined)
        self._coarse_starts: list[np.ndarray] = []
        #: once a start meets the mission, more starts only until then (solver.polish_s)
        self.polish_until = math.inf
        #: the initial guess's starts, its first and its decisions (:meth:`_guess`)
        self._first_guess: tuple[Iterator[Any], Any, np.ndarray] | None = None
        self._build_t0 = self.t_start  # when the NLP's build began (run)
        self._iterate_rho = -math.inf  # the best iterate seen during a solve
        self._iterate_w: np.ndarray | None = None
        self._next_progress = 0.0
        #: the row-wise leaves' constraint steps, when the NLP is screened
        #: (:mod:`planner.solve.screen`; None: every row is in the NLP)
        self.rows: dict[Formula, list[int]] | None = None
        self.screen: Screen | None = None
        #: solves again with rows the screen had left out (row generation)
        self.screen_rounds = 0
        self.build_s = 0.0
        self.cached = False
        #: the structures' locks this search holds (:meth:`run`)
        self._held: contextlib.ExitStack | None = None
        self._held_ids: set[int] = set()

    # ------------------------------------------------------------------ the NLP's pieces

    def _prepare_nlp(self, z_ref: np.ndarray) -> None:
        """The NLP for the first start ``z_ref`` (built, or from the cache): screened
        (:mod:`planner.solve.screen`) to the row-wise steps within reach of binding there,
        where screening is on."""
        self.rows = row_steps(self.problem, self.formula)
        self.screen = chosen_screen(self.problem, self.rows, lambda: self._near(z_ref, REACH_M))
        if self.screen is not None:
            self.say(f"screening the NLP's rows: {self.screen.describe()}")
        self._load_structure(first=True)

    def _load_structure(self, first: bool = False) -> None:
        """``self.struct`` for the problem and the screen, and its bounds.

        Raises:
            BuildTimeout: the time limit came during the build.
        """
        problem, model, screen = self.problem, self.model, self.screen

        def build() -> Structure:
            self.say(f"building the NLP for {len(problem.vehicles)} vehicle(s)")
            return build_structure(
                problem, model, self.formula, deadline=self.solve_deadline(), screen=screen
            )

        self.struct, cached = STRUCTURES.get_or_build(structure_key(problem, screen=screen), build)
        struct = self.struct
        if first:
            self.cached = cached
        if self._held is not None and id(struct) not in self._held_ids:
            self._held.enter_context(struct.lock)
            self._held_ids.add(id(struct))
        # p: the start states, and every leaf row >= r (weight 1; raise_the_rest settles)
        self.p_val = np.concatenate(
            [*[x.reshape(-1, order="F") for x in self.x0s], np.ones(struct.leaf_group.size)]
        )
        self.build_s += struct.build_s if not cached else 0.0
        self.watch = struct.watch
        self.bounds = nlp_bounds(struct, model, problem.vehicles, self.p_val, self.fixed)
        self.lbx, self.ubx = self.bounds["lbx"], self.bounds["ubx"]

    def lifted(self, z0: np.ndarray) -> np.ndarray:
        """The NLP's start point for decisions ``z0`` (:func:`start_point`)."""
        return start_point(self.struct, self.model, self.x0s, self.p_val, z0)

    def trajectories_of(self, w: np.ndarray) -> list[Trajectory]:
        """The vehicles' trajectories at the NLP's point ``w`` (with their heading)."""
        model = self.model
        nd = model.n_dec * 3
        trs = [
            model.trajectory(
                w[i * nd : (i + 1) * nd].reshape((model.n_dec, 3), order="F"), x0, v.name
            )
            for i, (v, x0) in enumerate(zip(self.problem.vehicles, self.x0s, strict=True))
        ]
        return with_heading(self.problem, self.rules, trs, self.t_dense) if self.rules else trs

    def clauses_of(self, w: np.ndarray) -> np.ndarray:
        """Each clause's exact robustness (dense samples) at ``w``."""
        t0 = time.perf_counter()
        sig = dense_signals(self.problem, self.trajectories_of(w), self.heading)
        out = clause_robustness(self.problem, self.formulas, sig)
        self.exact_eval_s = max(self.exact_eval_s, time.perf_counter() - t0)
        return out

    def exact_of(self, w: np.ndarray) -> float:
        """The exact robustness (dense samples) at ``w``."""
        rob = self.clauses_of(w)
        return float(rob.min()) if rob.size else math.inf

    def _timed_exact(self, w: np.ndarray) -> float:
        t0 = time.perf_counter()
        rob = self.exact_of(w)
        self.check_s += time.perf_counter() - t0
        return rob

    def _on_iteration(self, w: np.ndarray, _f: float) -> None:
        """During a solve: every progress_every_s, the iterate's exact robustness (the best
        one kept: a solve stopped by the time limit or Ctrl-C returns the better of it and
        its last iterate)."""
        now = time.perf_counter()
        if now < self._next_progress:
            return
        self._next_progress = now + self.progress_every_s
        rho = self.exact_of(w)
        if rho > self._iterate_rho:
            self._iterate_rho, self._iterate_w = rho, w.copy()
        self.say(
            f"solving: iteration {self.watch.iterations}, best exact robustness so far "
            f"{self._iterate_rho:+.4f}"
        )

    # ------------------------------------------------------------------------ the budget

    def solve_deadline(self) -> float:
        """When the solvers must stop for the check to fit in the time limit: the check
        evaluates the clauses a few times (measured on the first start)."""
        if not math.isfinite(self.deadline):
            return self.deadline
        reserve = _CHECK_EVALUATIONS * self.exact_eval_s
        return self.deadline - reserve

    def out_of_time(self, stop: SigintWatch) -> bool:
        """Whether the search must end now: Ctrl-C, or the solver stopped at its deadline."""
        return stop.hit or self.watch.stopped or time.perf_counter() >= self.solve_deadline()

    # ------------------------------------------------------------------------ the stages

    def candidates(self) -> Iterator[tuple[str, np.ndarray]]:
        """The starts of the multi-start, lazily, ``solver.starts`` in all: the initial
        guess's first start (:func:`planner.solve.guess.starts`), solved while the combinatorial
        stage (:mod:`planner.milp`) runs beside it; unless that start meets the mission, the
        stage's plan and its choices refined (:meth:`_fixed_start`); then the guess's other
        starts."""
        problem, model, formula = self.problem, self.model, self.formula
        limit = problem.solver.starts
        guesses, first, z_first = self._guess()
        given = 1
        yield first.describe(problem, formula), z_first
        met = self._met()
        coarse = self._stage_start(met)
        if self.combinatorial is not None and self.combinatorial.conflict is not None:
            # Proven on the coarse model that no plan meets the spec: the NLP from the
            # guess has said what the smooth model makes of it, no more starts.
            self.say("combinatorial stage: no coarse plan meets the spec (clauses in conflict)")
            return
        if coarse is not None and given < limit:
            given += 1
            yield coarse
            if given < limit and not met:
                # The coarse plan fell short in the NLP: its choices fixed and refined
                # (an NLP without smoothing, :meth:`_fixed_start`), then the spec's again.
                fixed = self._fixed_start()
                if fixed is not None:
                    given += 1
                    yield fixed
        if met and problem.solver.polish_s <= 0.0:
            return  # the stage's plan was the one more start for margin
        for st in guesses:
            if given >= limit:
                return
            given += 1
            yield (
                st.describe(problem, formula),
                initial_guess(problem, model, formula, self.x0s, st),
            )

    def _guess(self) -> tuple[Iterator[Any], Any, np.ndarray]:
        """The initial guess's starts, its first and that first start's decisions, drawn
        once (before the build, so that a time limit that comes in the build still has a
        plan to check: the 40-pole line's first guess takes 6 s)."""
        if self._first_guess is None:
            problem, formula = self.problem, self.formula
            guesses = starts(problem, formula, problem.solver.starts)
            first = next(guesses)
            z_first = initial_guess(problem, self.model, formula, self.x0s, first)
            self._first_guess = (guesses, first, z_first)
        return self._first_guess

    def _met(self) -> bool:
        """Whether the best start so far meets the mission."""
        return self.best is not None and self.best.robustness >= self.problem.epsilon

    def _start_stage(self) -> None:
        """Start the combinatorial stage in its thread (:class:`StageBeside`), unless the
        initial guess's start already meets the mission, the stage is off
        (``solver.coarse_s`` 0) or there is no second start for its plan
        (``solver.starts`` 1).  It runs while the NLP is built and the guess's start solved;
        it costs wall time only where that start falls short and the stage is still running
        when it ends."""
        problem = self.problem
        self._rho_first = self._timed_exact(self._guess()[2])
        if self._rho_first >= problem.epsilon or problem.solver.starts < 2:
            return
        budget = coarse_budget_s(problem, self.deadline - time.perf_counter())
        if budget <= 0.0:
            return
        self.say("choosing options, order and timing (combinatorial stage, beside the NLP)")
        self._stage = StageBeside(problem, self.model, self.x0s, budget, self.say)

    def _stage_start(self, met: bool) -> tuple[str, np.ndarray] | None:
        """After the guess's first start: the stage's plan as the next start, or None
        (:meth:`StageBeside.answer`: waited for if that start fell short; after a met plan
        only within the margin time of :meth:`_multistart`, and only if it promises more)."""
        side = self._stage
        if side is None:
            return None
        sigint = self._sigint
        got = side.answer(
            self.best.robustness if met and self.best is not None else None,
            min(self.solve_deadline(), self.polish_until),
            lambda: sigint is not None and sigint.hit,
        )
        self.combinatorial = side.outcome
        if got is None or got.decision is None:
            return None
        if met:  # as long again as the search had taken to meet the mission, to refine it
            self.polish_until = time.perf_counter() + self._margin_s
        self._coarse_z = got.decision
        self._coarse_starts.append(got.decision)
        rho_coarse = self._timed_exact(got.decision)
        self.say(
            f"combinatorial stage: its plan ({got.result.robustness:+.4f} on the coarse model) "
            f"starts at {rho_coarse:+.4f}, the initial guess at {self._rho_first:+.4f}"
        )
        return got.describe(), got.decision

    def _fixed_start(self) -> tuple[str, np.ndarray] | None:
        """The combinatorial stage's choices fixed (:func:`planner.solve.fix_choices.fixed_clauses`)
        and the NLP of that conjunction (every clause exact, nothing smoothed) solved from its
        plan within half the time left: a start for the spec's own NLP (None when the spec
        has no choice to fix)."""
        problem = self.problem
        if self._coarse_z is None:
            return None
        z_c = self._coarse_z
        times = np.arange(problem.timing.n_samples) * problem.timing.sample_dt_s
        sig = heading_signals(self.trajectories_of(z_c), times, self.heading)
        restricted = choices_problem(problem, self.formula, sig)
        if restricted is None:
            return None
        clauses = restricted.clauses
        left = self.deadline - time.perf_counter()
        self.say(f"refining the combinatorial stage's choices ({len(clauses)} clauses)")
        sub = PlanSearch(
            restricted,
            progress=lambda msg: self.say(f"choices fixed: {msg}"),
            time_limit_s=None if not math.isfinite(left) else max(0.5 * left, 1.0),
            progress_every_s=self.progress_every_s,
        )
        got = sub.run(initial_guess=z_c)
        z = np.asarray(got.decision, dtype=float).reshape(-1)[: z_c.size]
        rho = self._timed_exact(z)
        what = f"the combinatorial stage's choices ({len(clauses)} clauses), refined"
        # The spec's own NLP goes on from there: with the choices free again it keeps or
        # raises the margin (reach-avoid: 0.1945 with them fixed, 0.22 freed).
        self.say(f"choices fixed: {rho:+.4f} on the spec; now with the choices free")
        self._coarse_starts.append(z)
        return what, z

    # --------------------------------------------------------------------- the screen

    def _near(self, w: np.ndarray, below: float) -> dict[Formula, set[int]]:
        """The row-wise steps (of :attr:`rows`) where the leaf's exact value at ``w`` is
        below ``below`` (m), and a segment either side of them."""
        assert self.rows is not None
        dt = self.problem.timing.sample_dt_s
        times = np.arange(len(self.model.times_s)) * dt
        sig = heading_signals(self.trajectories_of(w), times, self.heading)
        spread = max(1, round(self.problem.timing.segment_s / dt))
        return near_rows(self.rows, sig, dt, below, spread)

    def _rescreen(self, more: Mapping[Formula, set[int]]) -> bool:
        """The NLP with the rows ``more`` added to the screen (built within the time
        limit); whether it was (False: the time limit came in the build, the NLP stays)."""
        assert self.screen is not None
        old_screen, old_struct = self.screen, self.struct
        self.screen = old_screen.grown(more)
        old = self.watch
        try:
            self._load_structure()
        except BuildTimeout:
            self.screen, self.struct = old_screen, old_struct
            self.say("screening: the time limit came while adding rows; the NLP stays")
            return False
        self.watch = self.struct.watch
        if self.watch is not old:
            self.watch.take_over(old)
        return True

    def _cover(self, w: np.ndarray) -> None:
        """Before a start at ``w``: the rows within reach of binding there join the NLP."""
        if self.screen is None:
            return
        near = self._near(w, REACH_M)
        if not self.screen.covers(near) and self._rescreen(near):
            self.say(f"screening: for this start, {self.screen.describe()}")

    def _missed(self, w: np.ndarray) -> dict[Formula, set[int]]:
        """The rows the screen left out that come within :data:`GUARD_M` of the NLP's
        robustness at its solution ``w`` (of the mission's epsilon, if more)."""
        assert self.screen is not None
        r = max(float(w[-1]), self.problem.epsilon)
        return self.screen.left_out(self._near(w, r + GUARD_M))

    def _generated(self, got: Attempt, stop: SigintWatch) -> Attempt:
        """Row generation after a start: while rows left out come near binding at the
        solution, they (and every row within reach there) join the NLP, which is solved
        again from the solution; the better plan in exact robustness is kept."""
        for _ in range(_SCREEN_ROUNDS):
            if self.screen is None or self.out_of_time(stop):
                break
            missed = self._missed(got.w)
            if not missed:
                break
            n = sum(len(s) for s in missed.values())
            near = self._near(got.w, REACH_M)
            for leaf, steps in missed.items():
                near[leaf] = near.get(leaf, set()) | steps
            if not self._rescreen(near):
                break
            self.screen_rounds += 1
            self.say(
                f"screening: {n} step rows left out came within {GUARD_M:g} m of binding; "
                f"solving again with them ({self.screen.describe()})"
            )
            self._reset_r()
            again = self.attempt(self.lifted(got.w[: self.struct.n_z]), stop)
            # the better plan, with what both solves cost (the NLP's point has the same
            # layout in every screen: planner.solve.nlp lifts every constraint step)
            best = again if again.robustness > got.robustness else got
            cost = got.run.then(again.run)
            # the multipliers are the rows' of the NLP that found the point: kept only for
            # the new one (the earlier NLP had fewer rows)
            lam_g = best.run.lam_g if best is again else None
            got = dataclasses.replace(
                best,
                run=dataclasses.replace(cost, w=best.run.w, status=best.run.status, lam_g=lam_g),
            )
        return got

    def _reset_r(self) -> None:
        """r's bounds for a start: the structure's, and eq. (1)'s floor if asked for."""
        struct, problem = self.struct, self.problem
        self.lbx[-1], self.ubx[-1] = struct.lbx[-1], struct.ubx[-1]
        if problem.solver.robustness_constraint:
            lower_r(self.lbx, self.ubx, problem.epsilon + struct.margin)

    def attempt(self, w0: np.ndarray, stop: SigintWatch) -> Attempt:
        """One start: the maximisation from ``w0`` (with the eq. (1) rounds if asked for)."""
        problem, struct, bounds = self.problem, self.struct, self.bounds
        say = self.say
        rob_start = self._timed_exact(w0)
        self.watch.deadline = min(self.solve_deadline(), self.polish_until)
        # The guess's first start, the stage beside it: it yields to the stage's plan once
        # that is ready and it has had as long as the stage's budget.
        side = self._stage if self.n_starts == 1 else None
        if side is not None:
            side.nlp_began(self.watch)
        elif self._coarse_z is not None and self.n_starts < problem.solver.starts:
            # With the coarse plan's starts to come, one start may not take all the time
            # left (the allocation mission: the first NLP ran to the limit at -0.70, the
            # fixed choices then met it).
            now = time.perf_counter()
            self.watch.deadline = min(
                self.watch.deadline, now + _START_SHARE * (self.watch.deadline - now)
            )
        refine = rob_start >= problem.epsilon and problem.solver.method is SolverMethod.IPOPT
        run = run_solvers(struct, w0, bounds, say, problem.solver.method.value, stop, refine)
        if side is not None:
            side.nlp_ended()
        by_share = self.watch.stopped and time.perf_counter() < min(
            self.solve_deadline(), self.polish_until
        )
        if by_share:
            self.watch.stopped = False  # stopped by this start's share only: others may run
        w_opt, status = run.w, run.status
        if side is not None and by_share and status == "User_Requested_Stop":
            status = side.yielded(status, self.watch, min(self.solve_deadline(), self.polish_until))
        rob = self._timed_exact(w_opt)
        if rob < problem.epsilon and rob_start > rob:
            # The solver fell short from a start that was better (it met the mission, or
            # fell short by less): keep the start, and say so.  A solved point that meets
            # the mission stands even below its start (the robustness cap says more margin
            # is not wanted; the solved point is the smoother).
            status = f"{status}; kept the start point ({rob_start:.4g}; the solver's {rob:.4g})"
            rob, w_opt = rob_start, w0
        if not problem.solver.robustness_constraint:
            return Attempt(rob, w_opt, status, solved(status), run)
        # the paper's eq. (1), in rounds of a growing margin
        return margin_rounds(
            struct, w0, Attempt(rob, w_opt, status, solved(status), run), bounds, problem.epsilon,
            say, stop, self._timed_exact, lambda: self.out_of_time(stop), _EPS_ROUNDS,
        )  # fmt: skip

    def _multistart(
        self, candidates: Iterator[tuple[str, np.ndarray]], stop: SigintWatch
    ) -> SolverRun:
        """The first start's plan, unless it falls short of the mission; then the next
        starts in turn until one meets it, the limit on starts or time comes, or Ctrl-C;
        once met, more starts only for solver.polish_s seconds (default 0).  The best exact
        robustness wins.  No start is drawn (its guess can take seconds on a long line)
        once the time is up."""
        problem = self.problem
        met_at: float | None = None  # when a start first met the mission
        spent: SolverRun | None = None
        while True:
            if self.n_starts and (
                self.out_of_time(stop) or time.perf_counter() >= self.polish_until
            ):
                break
            nxt = next(candidates, None)
            if nxt is None:
                break
            what, z0 = nxt
            self.n_starts += 1
            if self.n_starts > 1:
                self.say(f"start {self.n_starts}: {what}")
            self._cover(z0)
            self._reset_r()
            got = self._generated(self.attempt(self.lifted(z0), stop), stop)
            spent = got.run if spent is None else spent.then(got.run)
            if self.n_starts > 1 or got.robustness < problem.epsilon:
                self.say(f"start {self.n_starts}: exact robustness {got.robustness:+.4f}")
            if self.best is None or got.robustness > self.best.robustness:
                self.best, self.best_start = got, (self.n_starts, what)
            # A coarse plan the NLP did not converge from (it kept the start, which may sit
            # on the limits) is not the end: the next starts still run (the px4 limits
            # test: +0.61 kept at the start, the solver diverged to -12.3).
            from_coarse = any(z0 is z for z in self._coarse_starts)
            diverged = from_coarse and not got.converged
            if self.best.robustness >= problem.epsilon and met_at is None and not diverged:
                # Met: more starts for a larger margin only within the polish budget (the
                # solver stops at its end like at the time limit; the best plan stands).
                met_at = time.perf_counter()
                self._margin_s = problem.solver.polish_s
                if self._stage is not None and self.n_starts == 1:
                    # the stage beside the guess's start: as long again as the search took
                    # to meet the mission, for the margin its plan may add (_stage_start)
                    self._margin_s = max(self._margin_s, met_at - self.t_start)
                self.polish_until = met_at + self._margin_s
        assert spent is not None
        return spent

    def run(self, initial_guess: np.ndarray | None = None) -> PlanResult:
        """Build, try the starts, refine the best, check it: the :class:`PlanResult`.

        One search runs at a time in a process (:data:`_PLAN_LOCK`): CasADi releases the
        GIL in its calls, and its shared state (the sparsity patterns, a Function's
        memory) is not safe from two threads at once.  Plans in parallel take processes
        (``gcs assess`` on Ray)."""
        with _PLAN_LOCK:
            return self._locked_run(initial_guess)

    def _locked_run(self, initial_guess: np.ndarray | None) -> PlanResult:
        try:
            if initial_guess is None:
                self.say("drawing the initial guess")
                self._guess()
                self._start_stage()
            self._build_t0 = time.perf_counter()
            z_ref = (
                self._guess()[2]
                if initial_guess is None
                else np.asarray(initial_guess, dtype=float).reshape(-1)
            )
            try:
                self._prepare_nlp(z_ref)
            except BuildTimeout as exc:
                return self._unbuilt(initial_guess, str(exc))
            with contextlib.ExitStack() as held, watch_sigint() as stop:
                held.enter_context(self.struct.lock)
                self._held, self._held_ids = held, {id(self.struct)}
                self._sigint = stop
                self.watch.arm(self.deadline, self._on_iteration)
                self._next_progress = time.perf_counter() + self.progress_every_s
                try:
                    return self._run(initial_guess, stop)
                finally:
                    self.watch.on_iteration = None
        finally:
            if self._stage is not None:
                self._stage.stage.stop()  # ended already, unless an error came out of it

    def _run(self, initial_guess: np.ndarray | None, stop: SigintWatch) -> PlanResult:
        problem, formula, say = self.problem, self.formula, self.say
        if initial_guess is not None:
            given = np.asarray(initial_guess, dtype=float).reshape(-1)[: self.struct.n_z]
            candidates: Iterator[tuple[str, np.ndarray]] = iter([("the given guess", given)])
        else:
            candidates = self.candidates()
        run = self._multistart(candidates, stop)
        best = self.best
        assert best is not None
        watch = self.watch
        # the solver stopped by the time limit (not by the polish budget)
        by_time = watch.stopped and time.perf_counter() >= self.solve_deadline()
        watch.stopped = by_time
        if abs(best.robustness) < self.struct.box_bound and not (stop.hit or by_time):
            # The plan's margin is within the boxes' smoothing error: that smoothing decides.
            budget = max(_RAISE_MIN_S, 0.5 * (time.perf_counter() - self.t_start))
            sharp = sharpen(problem, self.model, formula, best, self.bounds, self.p_val,
                             self.exact_of, say, stop,
                             min(self.solve_deadline(), time.perf_counter() + budget),
                             self._on_iteration, self.screen, self.fixed)  # fmt: skip
            if sharp is not None:
                self.struct, best, self.bounds, sharp_build_s = sharp
                self.build_s += sharp_build_s
                run = run.then(best.run)
                self.watch = self.struct.watch
                self.watch.on_iteration = None
            watch = self.watch
            watch.deadline = self.solve_deadline()
            by_time = watch.stopped and time.perf_counter() >= self.solve_deadline()
            watch.stopped = by_time
        w_opt, status, converged = best.w, best.status, best.converged
        if self.n_starts > 1 or self.combinatorial is not None:
            n, what = self.best_start
            status = f"{status}; start {n} of {self.n_starts}: {what}"
        # An iterate the watch saw better than where the search ended is the plan, however
        # the solve ended (issue 40's mission of every class: +0.391 seen, -0.512 kept before)
        ended = self.exact_of(w_opt)
        if self._iterate_w is not None and self._iterate_rho > ended:
            w_opt = self._iterate_w
            status += (
                f"; kept an earlier iterate ({self._iterate_rho:.4g}; where it ended {ended:.4g})"
            )
        if (stop.hit or by_time) and w_opt is self._iterate_w:
            pass  # no time left to raise the rest
        elif problem.solver.lexicographic_rounds and not problem.solver.robustness_constraint:
            # at most half the time spent so far (at least _RAISE_MIN_S)
            budget = max(_RAISE_MIN_S, 0.5 * (time.perf_counter() - self.t_start))
            lam_g = best.run.lam_g if best.run.w is w_opt else None
            raised = raise_the_rest(
                self.struct, w_opt, lam_g, self.bounds, problem, self.clauses_of, say, stop,
                self.solve_deadline(), budget,
            )  # fmt: skip
            run = run if raised.run is None else run.then(raised.run)
            by_time = by_time or (
                self.struct.watch.stopped and time.perf_counter() >= self.solve_deadline()
            )
            if raised.note:
                w_opt, status = raised.w, f"{status}; {raised.note}"
        return self._checked(w_opt, status, converged, run, stop, by_time)

    def _unbuilt(self, initial_guess: np.ndarray | None, why: str) -> PlanResult:
        """The time limit came during the build: the initial guess (or the given one),
        checked like any plan, as the result; no solver ran."""
        self.build_s = time.perf_counter() - self._build_t0
        self.cached = False
        if initial_guess is not None:
            z = np.asarray(initial_guess, dtype=float).reshape(-1)
        else:
            z = self._guess()[2]
        status = f"{why}; the initial guess, not refined"
        run = SolverRun(z, status, 0, 0.0, 0.0)
        with watch_sigint() as stop:
            return self._checked(z, status, False, run, stop, True)

    def _checked(
        self,
        w_opt: np.ndarray,
        status: str,
        converged: bool,
        run: SolverRun,
        stop: SigintWatch,
        by_time: bool,
    ) -> PlanResult:
        """The combinatorial stage settled, the plan at ``w_opt`` checked on dense samples
        (:func:`check_plan`): the :class:`PlanResult`."""
        if self._stage is not None and self.combinatorial is None:
            self._stage.settle(met=self._met())
            self.combinatorial = self._stage.outcome
        return check_plan(self, w_opt, status, converged, run, stop, by_time)


#: Held by a search while it runs (:meth:`PlanSearch.run`; re-entrant: the fixed choices
#: search runs inside its parent's).
_PLAN_LOCK = threading.RLock()
#: The share of the time left one start may take while the coarse plan's starts remain.
_START_SHARE = 0.5
#: Solves again with rows the screen left out, at most, per start (row generation).
_SCREEN_ROUNDS = 3
#: Evaluations of the clauses the final check costs (the result's, the start bound's, and
#: room for the explanation): the solvers stop this many evaluations before the time limit.
_CHECK_EVALUATIONS = 4


#: The least time (s) :func:`raise_the_rest` may take (its budget is half the time the
#: plan took before it, at least this).
_RAISE_MIN_S = 2.0


#: Rounds of margin growth for the eq. (1) constraint (each EPS_MARGIN_STEP_M more).
_EPS_ROUNDS = 3
