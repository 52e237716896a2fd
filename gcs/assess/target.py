"""Plans that hold with a stated probability: the assessment in the planner's loop.

``gcs plan SCENARIO --target-probability P`` (docs/guide.md, "Planning to a probability"):

1. plan the scenario as written;
2. assess the plan (:func:`gcs.assess.assess`: ``runs`` flights in the batch simulator under
   the disturbances asked for, each judged with the exact semantics on the true positions);
3. while the lower end of P(spec holds)'s 95 % interval is below ``P``: from the runs, the
   robustness each top-level clause needs on the plan (:func:`needed_margins`), the clauses
   that lack it tightened by that much (:mod:`planner.spec.margins`: a larger separation,
   keep-outs grown, inspection places shrunk), planned again from the last plan's decisions
   (warm), assessed again on new runs;
4. when the tuning runs put the interval at or above ``P``, the plan is judged on runs the
   loop never tuned on (a fresh campaign seed, ``final_runs``): that assessment is the one
   the plan file records (:class:`planner.assurance.Assurance`).  If it falls short, its
   runs tune the next round and the next check takes another fresh seed.

Clauses that still break when their margin is at its cap and that ask for a hover are
planned with a longer one (:func:`longer_dwells`).  It stops when the target is met, when the
margins asked for cannot be planned (a region would vanish, or the tightened spec cannot be
met: the clause that stops it is named), after ``rounds`` plans, or when the next round and
the check after it would not end within ``budget_s``.  The plan kept is the one that met the
target on fresh runs, else the round whose tuning runs gave the highest lower end of the
interval, judged on fresh runs (the first plan, as written, when no margin helped).  Seeds:
round ``k`` tunes on campaign seed ``seed + k`` and checks on ``seed + FRESH_SEED_OFFSET +
k``; an independent assessment should use another.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from gcs.assess import AssessOptions, assess, ray_session
from gcs.errors import UserError
from planner.assurance import Assurance
from planner.optimize import plan
from planner.solve.plan_check import recheck
from planner.spec.margins import (
    MarginError,
    clause_texts,
    conjuncts,
    has_dwell,
    max_margin,
    split_clauses,
    tighten,
)

if TYPE_CHECKING:
    from gcs.assess.stats import AssessResult
    from planner.planfile import Plan
    from planner.problem import Problem
    from planner.results import PlanResult

__all__ = [
    "FRESH_SEED_OFFSET",
    "TargetOptions",
    "TargetResult",
    "TargetRound",
    "longer_dwells",
    "needed_margins",
    "plan_to_probability",
]

#: The fresh seeds' distance from the tuning seeds (campaign seeds hash their runs apart).
FRESH_SEED_OFFSET = 100_000
#: The share of ``1 - target`` the tuning runs may still fail with the new margins (the rest
#: is room for the plan changing under the margins, and for the interval's width).
FAIL_SHARE = 0.3
#: The share of a clause's largest margin (its regions' smallest half-size) it may be given.
CAP_SHARE = 0.8
#: The most a clause's margin grows in one round (m): the next plan flies differently, so
#: its losses are not this one's; small steps let the runs say again.
STEP_M = 0.3
#: Dwell added to a clause at its margin's cap that still breaks (s), and the most in all.
DWELL_STEP_S = 1.0
DWELL_MAX_S = 3.0
#: The share of its cap a hover's margin must have reached for a longer dwell (the power line
#: with 0.75: dwells from round 4, P 0.9665 at round 5 against 0.977 without, and a replan of
#: 40 s instead of 5; so at the cap only).
DWELL_CAP_SHARE = 1.0
#: The share of runs a clause must break first in to be given a longer dwell.
DWELL_AFTER = 0.001
#: The least time (s) left in the budget for which a cold plan or a halved increment is
#: tried (the planner's time limit does not bound its initial guess and build).
MIN_PLAN_S = 10.0
#: Halvings of a round's margin increments tried when they cannot be planned.
BACK_OFFS = 1
#: Every clause is planned with at least this quantile of its losses.
Q_KEEP = 0.999
#: The share of a clause's robustness (up to its :data:`Q_KEEP` loss) every plan keeps.
KEEP_SHARE = 0.5
#: Added to each clause's needed robustness (m).
BUFFER_M = 0.02


@dataclass(frozen=True, slots=True)
class TargetOptions:
    """Settings of the loop.

    Attributes:
        probability: the target, 0 < P < 1.
        assess: the campaign of each tuning round (``runs`` per round; its ``seed`` the
            loop's base seed; the disturbances, profile, Ray settings).
        final_runs: runs of each check on fresh seeds.
        rounds: most plans the loop makes.
        time_limit_s: the first plan's time limit (``None``: none).
        budget_s: the loop's wall time: no round starts that would not end in it with the
            check on fresh runs after it (by the last round's times), and a replan gets at
            most what is left (``None``: none).
        replan_time_limit_s: each tightened plan's (one that does not meet the tightened
            spec in that time is taken as impossible).
    """

    probability: float
    assess: AssessOptions
    final_runs: int = 4000
    rounds: int = 6
    time_limit_s: float | None = None
    replan_time_limit_s: float = 60.0
    budget_s: float | None = 240.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.probability) and 0.0 < self.probability < 1.0):
            raise UserError(
                f"--target-probability: must be a number in (0, 1), got {self.probability:g}"
            )
        if not (isinstance(self.final_runs, int) and self.final_runs > 0):
            raise UserError(f"--final-runs: must be a whole number > 0, got {self.final_runs!r}")
        if self.budget_s is not None and not (math.isfinite(self.budget_s) and self.budget_s > 0):
            raise UserError(f"--budget: must be a number of seconds > 0, got {self.budget_s!r}")
        if not (isinstance(self.rounds, int) and self.rounds > 0):
            raise UserError(f"--rounds: must be a whole number > 0, got {self.rounds!r}")


@dataclass(frozen=True, slots=True)
class TargetRound:
    """One plan of the loop and its assessments.

    Attributes:
        index: 1, 2, ...
        margins: the margins (m) it was planned with, per clause text.
        robustness: its exact robustness on the spec as written; ``planned_s``: plan time.
        p, ci, runs, seed: the tuning assessment.
        fresh: the check on fresh seeds (``None``: not reached).
        dwells: the longer dwells (s) it was planned with, per clause text.
    """

    index: int
    margins: Mapping[str, float]
    robustness: float
    planned_s: float
    p: float
    ci: tuple[float, float]
    runs: int
    seed: int
    fresh: AssessResult | None = None
    dwells: Mapping[str, float] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class TargetResult:
    """The loop's outcome.

    Attributes:
        result: the plan kept, judged against the spec as written (:func:`recheck`).
        plan: it as a plan file, with its :class:`Assurance`.
        final: the assessment on fresh seeds the plan file records (``None``, and no
            assurance, when the scenario as written cannot be planned: nothing was assessed).
        rounds: every round, in order.
        met: the final interval's lower end is at least the target.
        limiting: when not met, the clause that limits it (its text) and why.
        first: the first plan's robustness (before any margin), to show what was given up.
        elapsed_s: the loop's wall time.
    """

    result: PlanResult
    plan: Plan
    final: AssessResult | None
    rounds: tuple[TargetRound, ...]
    met: bool
    limiting: str | None
    first: float
    elapsed_s: float

    @property
    def margins(self) -> Mapping[str, float]:
        """The kept plan's margins (m) per clause text, as its record says ({}: none)."""
        return {} if self.plan.assurance is None else self.plan.assurance.margins


def needed_margins(
    a: AssessResult,
    target: float,
    margins: Mapping[str, float],
    epsilon: float,
    cap: Callable[[str], float] = lambda _text: math.inf,
) -> dict[str, float]:
    """The margins of the next round, from the runs of assessment ``a`` of a plan made with
    ``margins``.

    Each clause ``c`` lost ``planned_c - true_c`` in each run.  If the next plan's clauses
    lose what this one's did, raising clause ``c``'s planned robustness by ``lift_c`` turns
    its robustness in every run to ``true_c + lift_c``.  The lifts are found greedily: while
    more than ``FAIL_SHARE * (1 - target)`` of the runs would still fail some clause, the
    clause that is the weakest in most of those runs is raised by the median of what they
    lack there (plus :data:`BUFFER_M`), so the clauses that break are raised and the ones
    that hold anyway are left alone.  A raised clause is given the margin ``planned_c +
    lift_c - epsilon`` (a tightened plan meeting epsilon then has that robustness), never
    less than it had, and at most :data:`STEP_M` more: margins only grow, a little per round
    (the next plan flies differently, so its runs are asked again).  ``cap(text)`` bounds a clause's margin (how far its
    regions can shrink, :func:`planner.spec.margins.max_margin`); a clause at its cap is
    raised no further, and the next weakest is.  Every clause, raised or not, is then given
    at least :data:`KEEP_SHARE` of the :data:`Q_KEEP` quantile of its losses, or of what the
    plan already gives it if that is less (less ``epsilon``, within its cap), so that a plan
    tightened for one clause does not give another up (a hover turned into a pass); a clause
    that did not break is kept in part, not raised.  The clauses' losses are taken one by
    one: a drift that costs two clauses at once is counted in each, so a margin for each
    of them in full would over-constrain the plan.
    """
    texts = [c.text for c in a.clauses]
    planned = np.array([c.planned for c in a.clauses])
    true = np.asarray(a.clause_true, dtype=float)
    out = dict(margins)
    if true.size == 0:
        return out
    allowed = math.floor(FAIL_SHARE * (1.0 - target) * true.shape[0])
    lift = np.zeros(len(texts))
    room = np.full(len(texts), np.nan)  # the lift each clause's cap allows (nan: not asked)
    for _ in range(20 * len(texts)):
        now = true + lift[None, :]
        failing = (now <= 0.0).any(axis=1)
        if int(failing.sum()) <= allowed:
            break
        fails = now[failing]
        weakest = np.argmin(fails, axis=1)
        counts = np.bincount(weakest, minlength=len(texts))
        step = 0.0
        for c in np.argsort(-counts, kind="stable"):
            if counts[c] == 0:
                break
            if np.isnan(room[c]):
                room[c] = cap(texts[c]) + epsilon - planned[c]
            lacks = -fails[weakest == c, c]
            step = min(float(np.median(lacks)) + BUFFER_M, float(room[c]) - lift[c])
            if step > 1e-3:
                lift[c] += step
                break
        if step <= 1e-3:  # every clause that breaks is at its cap
            break
    # Every clause keeps at least what its losses ask at Q_KEEP, lifted or not: a plan
    # tightened elsewhere must not give up a clause's robustness (a hover turned into a pass).
    keep = np.quantile(planned[None, :] - true, Q_KEEP, axis=0) + BUFFER_M
    for i, text in enumerate(texts):
        kept = KEEP_SHARE * min(float(planned[i]), float(keep[i]))  # kept in part, not raised
        want = max(float(planned[i] + lift[i]) if lift[i] > 0.0 else -math.inf, kept)
        had = out.get(text, 0.0)
        m = min(want - epsilon, cap(text), had + STEP_M)
        if m > had + 1e-3:
            out[text] = m
    return out


def plan_to_probability(
    problem: Problem,
    opts: TargetOptions,
    *,
    scenario_path: str | None = None,
    say: Callable[[str], None] | None = None,
) -> TargetResult:
    """Run the loop (module docstring) on ``problem``, the scenario as written.

    Raises:
        UserError: bad options or disturbances, an unreachable Ray address.
    """
    say = say or (lambda _line: None)
    t0 = time.perf_counter()
    written = problem
    problem = split_clauses(problem)  # the same spec in its finest clauses
    texts = clause_texts(problem)
    caps = _Caps(problem)
    base = opts.assess
    with ray_session(base.ray_address, base.workers) if base.workers != 0 else nullcontext():
        rounds: list[TargetRound] = []
        margins: dict[str, float] = {}
        dwells: dict[str, float] = {}
        dwelling = {t for t, c in conjuncts(problem).items() if has_dwell(c)}
        t_plan = time.perf_counter()
        tight = plan(problem, time_limit_s=opts.time_limit_s)
        result = recheck(tight, problem)
        first = result.robustness
        plans: list[PlanResult] = []  # per round: its plan, judged on the split spec
        met_i: int | None = None  # the round whose fresh check met the target
        limiting: str | None = None
        if not result.success:
            limiting = f"the scenario as written: {result.status}"
        k = 0
        while result.success and k < opts.rounds:
            k += 1
            planned_s = time.perf_counter() - t_plan
            plan_k = result.to_plan(scenario_path)
            plans.append(result)
            tune = dataclasses.replace(base, seed=base.seed + k)
            a = assess(plan_k, tune)
            say(
                f"round {k}: planned {result.robustness:+.3f} in {planned_s:.1f} s; "
                f"{a.runs} runs: P = {a.p:.4f} [{a.ci[0]:.4f}, {a.ci[1]:.4f}]"
            )
            fresh = None
            if a.ci[0] >= opts.probability:
                check = dataclasses.replace(
                    base, runs=opts.final_runs, seed=base.seed + FRESH_SEED_OFFSET + k
                )
                fresh = assess(plan_k, check)
                say(
                    f"round {k}: {fresh.runs} fresh runs (seed {check.seed}): P = "
                    f"{fresh.p:.4f} [{fresh.ci[0]:.4f}, {fresh.ci[1]:.4f}]"
                )
            rounds.append(
                TargetRound(
                    k, dict(margins), result.robustness, planned_s, a.p, a.ci, a.runs,
                    tune.seed, fresh, dict(dwells),
                )
            )  # fmt: skip
            if fresh is not None and fresh.ci[0] >= opts.probability:
                met_i = len(rounds) - 1
                break
            if k == opts.rounds:
                break
            new = needed_margins(
                fresh or a, opts.probability, margins, problem.epsilon, cap=caps.get
            )
            new_dwells = longer_dwells(fresh or a, new, dwells, caps.get, dwelling)
            if new == margins and new_dwells == dwells:
                limiting = _worst_clause(fresh or a, "no margin the runs ask for is left to add")
                break
            now = time.perf_counter()
            # what is left once a check on fresh runs (as long as this round's assessment
            # would take for final_runs) is set aside
            check_s = a.elapsed_s * opts.final_runs / max(1, a.runs)
            left = math.inf if opts.budget_s is None else t0 + opts.budget_s - now - check_s
            round_s = now - t_plan  # this round: its plan and its assessments
            if left < round_s:
                limiting = _worst_clause(
                    fresh or a, f"the loop's budget ({opts.budget_s:g} s) allows no more rounds"
                )
                break
            t_plan = now
            tight_k, new, failed = _replan(
                problem, tight, margins, new, new_dwells, opts, say, k, left - 0.5 * round_s
            )
            if tight_k is None:
                limiting = failed
                say(f"round {k + 1}: {limiting}")
                break
            tight, margins, dwells = tight_k, new, new_dwells
            result = recheck(tight, problem)
        if rounds:
            # met: that round; else the round whose tuning runs did best, on fresh runs
            i = (
                met_i
                if met_i is not None
                else max(range(len(rounds)), key=lambda j: rounds[j].ci[0])
            )
            if rounds[i].fresh is None:
                check = dataclasses.replace(
                    base, runs=opts.final_runs, seed=base.seed + FRESH_SEED_OFFSET + rounds[i].index
                )
                rounds[i] = dataclasses.replace(
                    rounds[i], fresh=assess(plans[i].to_plan(scenario_path), check)
                )
    if not rounds:  # the scenario as written cannot be planned: nothing to assess
        fail = recheck(tight, written)
        return TargetResult(
            result=fail,
            plan=fail.to_plan(scenario_path),
            final=None,
            rounds=(),
            met=False,
            limiting=limiting,
            first=first,
            elapsed_s=time.perf_counter() - t0,
        )
    chosen = rounds[i]
    final = chosen.fresh
    assert final is not None
    kept = recheck(
        plans[i],
        written,
        note="planned with clause margins: see assurance"
        if chosen.margins or chosen.dwells
        else "",
    )
    met = met_i is not None
    if not met and limiting is None:
        limiting = _worst_clause(final, f"{len(rounds)} round(s) reached")
    elapsed = time.perf_counter() - t0
    record = Assurance(
        target=opts.probability,
        met=met,
        p=final.p,
        ci=final.ci,
        runs=final.runs,
        seed=final.seed,
        disturbances=dict(base.disturbances),
        profile=base.profile,
        margins={t: chosen.margins[t] for t in texts if chosen.margins.get(t, 0.0) > 0.0},
        dwells={t: chosen.dwells[t] for t in texts if chosen.dwells.get(t, 0.0) > 0.0},
        rounds=len(rounds),
        elapsed_s=elapsed,
        limiting=None if met else limiting,
    )
    out = dataclasses.replace(kept.to_plan(scenario_path), assurance=record)
    return TargetResult(
        result=kept,
        plan=out,
        final=final,
        rounds=tuple(rounds),
        met=met,
        limiting=record.limiting,
        first=first,
        elapsed_s=elapsed,
    )


def _replan(
    problem: Problem,
    tight: PlanResult,
    margins: Mapping[str, float],
    new: Mapping[str, float],
    dwells: Mapping[str, float],
    opts: TargetOptions,
    say: Callable[[str], None],
    k: int,
    left_s: float = math.inf,
) -> tuple[PlanResult | None, dict[str, float], str]:
    """Plan ``problem`` tightened by ``new`` and ``dwells`` (warm from ``tight``, then cold);
    where that cannot be planned, by the margins half way from ``margins`` to ``new``, once.
    Returns the plan and the margins it was made with, or ``None`` and why not.  The plans
    share ``left_s`` seconds (each at most ``opts.replan_time_limit_s``)."""
    why = ""
    until = time.perf_counter() + left_s
    for attempt in range(1 + BACK_OFFS):
        if attempt and until - time.perf_counter() < MIN_PLAN_S:
            why += " (no time left in the budget to try half the increment)"
            break
        share = 0.5**attempt
        asked = {t: margins.get(t, 0.0) + share * (m - margins.get(t, 0.0)) for t, m in new.items()}
        grown = {t: m for t, m in asked.items() if m > margins.get(t, 0.0) + 1e-3}
        if attempt and not grown:
            break
        longer = ", ".join(f"{t} by {d:g} s" for t, d in dwells.items())
        say(
            f"round {k}: tightening {_describe(grown) or 'no clause'}"
            + (f"; dwelling longer: {longer}" if longer else "")
        )
        try:
            tightened = tighten(problem, asked, dwells)
        except MarginError as exc:
            why = str(exc)
            continue

        def limit() -> float:
            return max(1.0, min(opts.replan_time_limit_s, until - time.perf_counter()))

        tight_k = plan(tightened, initial_guess=tight.decision, time_limit_s=limit())
        if not tight_k.success and until - time.perf_counter() > MIN_PLAN_S:
            tight_k = plan(tightened, time_limit_s=limit())
        if tight_k.success:
            return tight_k, asked, ""
        i = int(np.argmin([c.robustness for c in tight_k.clauses]))
        why = (
            f"{problem.clauses[i].text}: no plan keeps the margins asked for "
            f"(tightened, it reached {tight_k.robustness:+.3f} < epsilon {problem.epsilon:g})"
        )
    return None, dict(margins), why


def longer_dwells(
    a: AssessResult,
    margins: Mapping[str, float],
    dwells: Mapping[str, float],
    cap: Callable[[str], float],
    dwelling: set[str],
) -> dict[str, float]:
    """The dwells of the next round: a clause that asks for a hover, broke first in at least
    :data:`DWELL_AFTER` of the runs and whose margin is near its cap
    (:data:`DWELL_CAP_SHARE` of it) is given :data:`DWELL_STEP_S` more (up to
    :data:`DWELL_MAX_S`): margins in time where the margins in space run out."""
    out = dict(dwells)
    for c in a.clauses:
        t = c.text
        if t not in dwelling or c.first_to_fail < max(1.0, DWELL_AFTER * a.runs):
            continue
        if margins.get(t, 0.0) < DWELL_CAP_SHARE * cap(t) - 1e-3:
            continue
        out[t] = min(out.get(t, 0.0) + DWELL_STEP_S, DWELL_MAX_S)
    return out


def _worst_clause(a: AssessResult, why: str = "") -> str:
    """The clause that broke first in most runs of ``a`` (its text), with ``why``."""
    c = max(a.clauses, key=lambda c: (c.first_to_fail, c.failures))
    return f"{c.text} (broke first in {c.first_to_fail} of {a.runs} runs)" + (
        f": {why}" if why else ""
    )


def _describe(grown: Mapping[str, float]) -> str:
    items = sorted(grown.items(), key=lambda kv: -kv[1])
    shown = ", ".join(f"{t} by {m:.2f} m" for t, m in items[:3])
    return shown + (f" and {len(items) - 3} more" if len(items) > 3 else "")


class _Caps:
    """Each clause's largest margin, 0.8 of what its regions allow, found when first asked."""

    def __init__(self, problem: Problem) -> None:
        self.problem = problem
        self.known: dict[str, float] = {}

    def get(self, text: str) -> float:
        if text not in self.known:
            self.known[text] = CAP_SHARE * max_margin(self.problem, text)
        return self.known[text]
