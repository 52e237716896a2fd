"""The statistics of an assessment campaign: P(spec holds) with its exact interval, the
robustness quantiles, per clause how often it failed, the worst runs, the margin a plan would
need, and the runs table.

A room of its own because it is pure computation on the batches' numbers (no simulation, no
Ray, no printing): :func:`gcs.assess.assess` calls :func:`summarise` once the batches are in,
and the tests check it against independent references (the binomial tails of
``scipy.stats.binom``, numpy's quantiles over the concatenated runs).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.special import betaincinv

from gcs.flight.evaluation import plan_formula
from mavlink.monitor_findings import RunFindings, Verdict, always_clause_indices
from planner.planfile import planned_signals

if TYPE_CHECKING:
    from gcs.assess import AssessOptions, BatchOutcome
    from mavlink.mock.sim.disturbances import Distribution
    from planner.planfile import Plan

__all__ = ["QUANTILES", "AssessResult", "ClauseStats", "RunSummary", "clopper_pearson", "summarise"]

#: The quantiles reported for robustness (fractions).
QUANTILES = (0.01, 0.05, 0.25, 0.5, 0.75, 0.95, 0.99)
#: The probability the needed margin is computed for.
TARGET_P = 0.99


def clopper_pearson(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """The exact (Clopper-Pearson) interval of a binomial proportion ``k / n``; ``(0, 1)`` for
    ``n = 0``. Its ends are the beta distribution's quantiles (Clopper and Pearson, 1934):
    ``B^-1(a/2; k, n-k+1)`` and ``B^-1(1-a/2; k+1, n-k)``, by the inverse of the regularised
    incomplete beta function (:func:`scipy.special.betaincinv`, which ``scipy.stats`` uses
    too, without its second of import)."""

    if n <= 0:
        return (0.0, 1.0)
    alpha = 1.0 - confidence
    lo = 0.0 if k <= 0 else float(betaincinv(k, n - k + 1, 0.5 * alpha))
    hi = 1.0 if k >= n else float(betaincinv(k + 1, n - k, 1.0 - 0.5 * alpha))
    return lo, hi


def _quantiles(x: np.ndarray) -> dict[str, float]:
    if x.size == 0:
        return {}
    q = np.quantile(x, QUANTILES)
    out = {"min": float(x.min())}
    out.update({f"p{round(p * 100):02d}": float(v) for p, v in zip(QUANTILES, q, strict=True)})
    out["max"] = float(x.max())
    return out


@dataclass(frozen=True, slots=True)
class ClauseStats:
    """One top-level clause over the campaign.

    Attributes:
        text: the clause.
        planned: its robustness on the plan.
        failures: runs where it failed (true positions, robustness <= 0).
        failures_reported: runs where it failed on the reported positions.
        first_to_fail: runs where it was the weakest clause and failed (it broke first).
        quantiles: its true robustness's quantiles.
    """

    text: str
    planned: float
    failures: int
    failures_reported: int
    first_to_fail: int
    quantiles: dict[str, float]


@dataclass(frozen=True, slots=True)
class RunSummary:
    """One run: its index and seed (``gcs assess --replay SEED``), robustness, weakest clause
    and what it drew (per-run disturbances; per-vehicle ones as their largest value)."""

    index: int
    seed: int
    true: float
    reported: float
    weakest_clause: int
    failsafe_s: float
    draws: dict[str, float]


#: Why a run replanned under ``--replan`` was not flown again, by code (from 1).
WHY_NOT = ("no time left to switch in the plan", "no plan met what was left", "refused")


@dataclass(frozen=True, slots=True)
class ReplanSummary:
    """``gcs assess --replan``: the runs the monitor stopped on a lost link, replanned.

    A run *completes* when the flight ends without a stop and the spec it is judged on holds
    (true positions): the spec itself without replanning; with it, where a new plan was
    flown, the spec as amended (what ``gcs fly --replan`` judges; its exit status 0).

    Attributes:
        lost_links: runs the monitor stopped on a lost link.
        tried: of these, those with a vehicle left to fly on (replanned).
        flown: replans whose plan met what was left of the spec (flown again).
        completed_flown: of the flown, the runs that completed; ``stopped_flown``: those the
            monitor stopped after the switch (the others ended with the amended spec broken).
        solve_s_median, solve_s_max: the replans' wall time (NaN: none).
        without, p_without, ci_without: runs that complete without replanning.
        with_, p_with, ci_with: with it.
        not_flown: ``(why, runs)`` of the replans not flown.
    """

    lost_links: int
    tried: int
    flown: int
    completed_flown: int
    solve_s_median: float
    solve_s_max: float
    without: int
    p_without: float
    ci_without: tuple[float, float]
    with_: int
    p_with: float
    ci_with: tuple[float, float]
    not_flown: tuple[tuple[str, int], ...] = ()
    stopped_flown: int = 0

    def as_json(self) -> dict[str, Any]:
        """JSON-ready values."""
        return {
            "lost_links": self.lost_links,
            "replanned": self.tried,
            "flown": self.flown,
            "completed_flown": self.completed_flown,
            "stopped_flown": self.stopped_flown,
            "solve_s_median": _finite(self.solve_s_median),
            "solve_s_max": _finite(self.solve_s_max),
            "completed_without": self.without,
            "p_completed_without": self.p_without,
            "ci95_without": list(self.ci_without),
            "completed_with": self.with_,
            "p_completed_with": self.p_with,
            "ci95_with": list(self.ci_with),
            "not_flown": [{"why": w, "runs": k} for w, k in self.not_flown],
        }


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _replan_summary(outcomes: Sequence[BatchOutcome]) -> ReplanSummary | None:

    if not outcomes or any(o.replanned is None or o.monitored is None for o in outcomes):
        return None
    mon = [o.monitored for o in outcomes if o.monitored is not None]
    rep = [o.replanned for o in outcomes if o.replanned is not None]
    code = np.concatenate([m.stop_code for m in mon])
    m_true = np.concatenate([m.true for m in mon])
    tried = np.concatenate([r.tried for r in rep])
    flown = np.concatenate([r.flown for r in rep])
    stopped = np.concatenate([r.stopped for r in rep])
    r_true = np.concatenate([r.true for r in rep])
    solve = np.concatenate([r.solve_s for r in rep])
    why = np.concatenate([r.why_not for r in rep])
    not_flown = tuple(
        (text, int((why == k).sum())) for k, text in enumerate(WHY_NOT, 1) if (why == k).any()
    )
    n = int(code.size)
    without = int(((code == 0) & (m_true > 0)).sum())
    done = ~stopped & (r_true > 0)
    with_ = int(done.sum())
    solved = solve[np.isfinite(solve)]
    return ReplanSummary(
        lost_links=int((code == RunFindings.code_of(Verdict.LINK_LOST)).sum()),
        tried=int(tried.sum()),
        flown=int(flown.sum()),
        completed_flown=int((done & flown).sum()),
        solve_s_median=float(np.median(solved)) if solved.size else math.nan,
        solve_s_max=float(solved.max()) if solved.size else math.nan,
        without=without,
        p_without=without / n if n else math.nan,
        ci_without=clopper_pearson(without, n),
        with_=with_,
        p_with=with_ / n if n else math.nan,
        ci_with=clopper_pearson(with_, n),
        not_flown=not_flown,
        stopped_flown=int((flown & stopped).sum()),
    )


@dataclass(frozen=True, slots=True)
class MonitorSummary:
    """What ``gcs fly``'s safety monitor did over the campaign (``gcs assess --monitor``):
    every run was flown twice on the same draws, without the monitor and under it.

    Attributes:
        watched: the top-level clauses the monitor watches (the always-clauses).
        stops: runs it stopped; ``p_stop`` and ``ci_stop``: the rate and its interval.
        reasons: ``(why, runs)``, most frequent first.
        stop_s_median: the stops' median time (s from the plan's start; NaN: no stop).
        holds, p, ci: runs where the spec held under the monitor (true positions).
        safe, safe_monitored: runs where every watched clause held (true positions),
            without and under the monitor.
        needed: stopped runs whose unmonitored flight broke a watched clause.
        spurious: stopped runs whose unmonitored flight held the whole spec.
        missed: runs under the monitor in which a watched clause still broke.
    """

    watched: tuple[int, ...]
    stops: int
    p_stop: float
    ci_stop: tuple[float, float]
    reasons: tuple[tuple[str, int], ...]
    stop_s_median: float
    holds: int
    p: float
    ci: tuple[float, float]
    safe: int
    safe_monitored: int
    needed: int
    spurious: int
    missed: int

    def as_json(self, clauses: Sequence[ClauseStats]) -> dict[str, Any]:
        """JSON-ready values (``clauses``: the campaign's, to name the watched ones)."""
        return {
            "watched": [clauses[i].text for i in self.watched],
            "stops": self.stops,
            "p_stop": self.p_stop,
            "ci95_stop": list(self.ci_stop),
            "reasons": [{"why": w, "runs": k} for w, k in self.reasons],
            "stop_s_median": None if math.isnan(self.stop_s_median) else self.stop_s_median,
            "holds": self.holds,
            "p_holds": self.p,
            "ci95": list(self.ci),
            "safe_unmonitored": self.safe,
            "safe_monitored": self.safe_monitored,
            "stops_needed": self.needed,
            "stops_spurious": self.spurious,
            "missed": self.missed,
        }


@dataclass(frozen=True, slots=True, eq=False)
class AssessResult:
    """A campaign's result (see :func:`gcs.assess.assess`).

    Attributes:
        runs: runs judged (fewer than asked when interrupted).
        asked: runs asked for.
        holds: runs where the spec held on the true positions (robustness > 0).
        p: ``holds / runs``; ``ci``: its 95 % Clopper-Pearson interval.
        holds_reported, p_reported, ci_reported: the same on the reported positions.
        planned: the plan's own exact robustness.
        quantiles, quantiles_reported: the spec's robustness quantiles (true, reported).
        clauses: per top-level clause.
        clause_true: ``(runs, clauses)`` each clause's robustness in each run (true
            positions), in run order.
        worst: the worst runs (lowest true robustness first).
        margin_needed_m: the planned robustness a plan would need for P(holds) >= 0.99 if it
            lost as much as this one does: the 99th percentile of ``planned - true``
            (``None`` with fewer than 100 runs).
        failsafes: runs where a vehicle met PX4's offboard-loss failsafe.
        runs_table: one row per run (numpy structured array, index order).
        disturbances: per name, the distribution used.
        elapsed_s: wall time; sim_s: time the batches took where they ran (summed).
        engine: where the batches ran; interrupted: the campaign was stopped early.
        seed: the campaign seed.
        monitor: with ``--monitor``, what the safety monitor did.
    """

    runs: int
    asked: int
    holds: int
    p: float
    ci: tuple[float, float]
    holds_reported: int
    p_reported: float
    ci_reported: tuple[float, float]
    planned: float
    quantiles: dict[str, float]
    quantiles_reported: dict[str, float]
    clauses: tuple[ClauseStats, ...]
    clause_true: np.ndarray
    worst: tuple[RunSummary, ...]
    margin_needed_m: float | None
    failsafes: int
    runs_table: np.ndarray
    disturbances: dict[str, str]
    elapsed_s: float
    sim_s: float
    engine: str
    interrupted: bool
    seed: int
    monitor: MonitorSummary | None = None
    #: runs where a vehicle was lost (disturbance ``lost``)
    lost: int = 0
    #: with ``--replan``, what replanning did
    replan: ReplanSummary | None = None

    @property
    def runs_per_s(self) -> float:
        """Runs judged per second of wall time."""
        return self.runs / self.elapsed_s if self.elapsed_s > 0 else math.inf

    def as_json(self) -> dict[str, Any]:
        """Everything but the runs table, as JSON-ready values."""
        return {
            "runs": self.runs,
            "asked": self.asked,
            "seed": self.seed,
            "interrupted": self.interrupted,
            "p_holds": self.p,
            "ci95": list(self.ci),
            "holds": self.holds,
            "p_holds_reported": self.p_reported,
            "ci95_reported": list(self.ci_reported),
            "planned_robustness": self.planned,
            "robustness": self.quantiles,
            "robustness_reported": self.quantiles_reported,
            "margin_needed_m_for_p99": self.margin_needed_m,
            "failsafes": self.failsafes,
            "lost": self.lost,
            "clauses": [
                {
                    "clause": c.text,
                    "planned": c.planned,
                    "failures": c.failures,
                    "failures_reported": c.failures_reported,
                    "first_to_fail": c.first_to_fail,
                    "robustness": c.quantiles,
                }
                for c in self.clauses
            ],
            "worst": [
                {
                    "run": w.index,
                    "seed": w.seed,
                    "robustness": w.true,
                    "reported": w.reported,
                    "weakest": self.clauses[w.weakest_clause].text if self.clauses else "",
                    "failsafe_s": None if math.isnan(w.failsafe_s) else w.failsafe_s,
                    "draws": w.draws,
                }
                for w in self.worst
            ],
            "monitor": None if self.monitor is None else self.monitor.as_json(self.clauses),
            "replan": None if self.replan is None else self.replan.as_json(),
            "disturbances": self.disturbances,
            "engine": self.engine,
            "elapsed_s": self.elapsed_s,
            "sim_s": self.sim_s,
            "runs_per_s": self.runs_per_s,
        }


def _runs_table(
    outcomes: Sequence[BatchOutcome], true: np.ndarray, rep: np.ndarray, weakest: np.ndarray
) -> np.ndarray:
    names = sorted(outcomes[0].draws) if outcomes else []
    dtype = [
        ("run", np.int64),
        ("seed", np.int64),
        ("robustness", np.float64),
        ("reported", np.float64),
        ("weakest_clause", np.int64),
        ("failsafe_s", np.float64),
        ("lost_s", np.float64),
    ]
    if outcomes and outcomes[0].monitored is not None:
        dtype += [("monitored", np.float64), ("stop_s", np.float64), ("stop_code", np.int64)]
    dtype += [(n, np.float64) for n in names]
    table = np.zeros(true.size, dtype=dtype)
    if not outcomes:
        return table
    table["run"] = np.concatenate([o.index + np.arange(len(o.seeds)) for o in outcomes])
    table["seed"] = np.concatenate([o.seeds for o in outcomes])
    table["robustness"] = true
    table["reported"] = rep
    table["weakest_clause"] = weakest
    table["failsafe_s"] = np.concatenate([o.failsafe_s for o in outcomes])
    table["lost_s"] = np.concatenate([o.lost_s for o in outcomes])
    if "stop_s" in (table.dtype.names or ()):
        mon = [o.monitored for o in outcomes]
        assert all(m is not None for m in mon)
        table["monitored"] = np.concatenate([m.true for m in mon if m is not None])
        table["stop_s"] = np.concatenate([m.stop_s for m in mon if m is not None])
        table["stop_code"] = np.concatenate([m.stop_code for m in mon if m is not None])
    for n in names:
        # a per-vehicle draw: its largest value in the run
        cols = [o.draws[n] if o.draws[n].ndim == 1 else o.draws[n].max(axis=1) for o in outcomes]
        table[n] = np.concatenate(cols)
    return table


def summarise(
    plan: Plan,
    outcomes: Sequence[BatchOutcome],
    *,
    opts: AssessOptions,
    dists: Mapping[str, Distribution],
    elapsed_s: float,
    interrupted: bool,
    engine: str,
) -> AssessResult:
    """The campaign's statistics from its batches (in any order: sorted by run index)."""
    outcomes = sorted(outcomes, key=lambda o: o.index)
    phi = plan_formula(plan)
    clauses = phi.clauses
    n_c = len(clauses)
    if outcomes:
        true = np.concatenate([o.true for o in outcomes])
        rep = np.concatenate([o.reported for o in outcomes])
        c_true = np.concatenate([o.clause_true for o in outcomes])
        c_rep = np.concatenate([o.clause_reported for o in outcomes])
    else:
        true = rep = np.zeros(0)
        c_true = c_rep = np.zeros((0, n_c))
    n = int(true.size)
    holds = int((true > 0).sum())
    holds_rep = int((rep > 0).sum())
    weakest = np.argmin(c_true, axis=1) if n and n_c else np.zeros(n, dtype=int)
    table = _runs_table(outcomes, true, rep, weakest)
    t = np.arange(round(plan.horizon_s / plan.check_dt_s) + 1) * plan.check_dt_s

    planned_sig = planned_signals(plan, t)
    clause_stats = []
    for i, c in enumerate(clauses):
        failed = c_true[:, i] <= 0
        clause_stats.append(
            ClauseStats(
                text=str(c),
                planned=float(c.robustness(planned_sig, plan.check_dt_s)),
                failures=int(failed.sum()),
                failures_reported=int((c_rep[:, i] <= 0).sum()),
                first_to_fail=int((failed & (weakest == i)).sum()),
                quantiles=_quantiles(c_true[:, i]),
            )
        )
    planned = float(phi.robustness(planned_sig, plan.check_dt_s))
    order = np.argsort(true, kind="stable")[: max(0, opts.worst)]
    draw_names = [nm for nm in table.dtype.names or () if nm not in _FIXED]
    worst = tuple(
        RunSummary(
            index=int(table["run"][j]),
            seed=int(table["seed"][j]),
            true=float(true[j]),
            reported=float(rep[j]),
            weakest_clause=int(weakest[j]),
            failsafe_s=float(table["failsafe_s"][j]),
            draws={nm: float(table[nm][j]) for nm in draw_names},
        )
        for j in order
    )
    margin = float(np.quantile(planned - true, TARGET_P)) if n >= 100 else None
    return AssessResult(
        runs=n,
        asked=opts.runs,
        holds=holds,
        p=holds / n if n else math.nan,
        ci=clopper_pearson(holds, n),
        holds_reported=holds_rep,
        p_reported=holds_rep / n if n else math.nan,
        ci_reported=clopper_pearson(holds_rep, n),
        planned=planned,
        quantiles=_quantiles(true),
        quantiles_reported=_quantiles(rep),
        clauses=tuple(clause_stats),
        clause_true=c_true,
        worst=worst,
        margin_needed_m=margin,
        failsafes=int(np.isfinite(table["failsafe_s"]).sum()),
        lost=int(np.isfinite(table["lost_s"]).sum()),
        runs_table=table,
        disturbances={k: str(v) for k, v in dists.items()},
        elapsed_s=elapsed_s,
        sim_s=float(sum(o.sim_s for o in outcomes)),
        engine=engine,
        interrupted=interrupted,
        seed=opts.seed,
        monitor=_monitor_summary(phi, outcomes, true, c_true),
        replan=_replan_summary(outcomes),
    )


def _monitor_summary(
    phi: Any, outcomes: Sequence[BatchOutcome], true: np.ndarray, c_true: np.ndarray
) -> MonitorSummary | None:

    mon = [o.monitored for o in outcomes]
    if not mon or any(m is None for m in mon):
        return None
    cat = {
        name: np.concatenate([getattr(m, name) for m in mon if m is not None])
        for name in ("true", "clause_true", "stop_s", "stop_code", "stop_clause")
    }
    n = true.size
    watched = always_clause_indices(phi)
    w = list(watched)
    safe = c_true[:, w].min(axis=1) > 0 if w else np.ones(n, dtype=bool)
    safe_mon = cat["clause_true"][:, w].min(axis=1) > 0 if w else np.ones(n, dtype=bool)
    stopped = cat["stop_code"] != 0
    reasons: dict[str, int] = {}
    labels = {
        Verdict.OFF_PLAN: "off its plan (tracking alarm)",
        Verdict.LEFT_MODE: "a vehicle left offboard (its failsafe)",
        Verdict.LINK_LOST: "a vehicle lost (its link silent)",
    }
    for code, clause in zip(cat["stop_code"][stopped], cat["stop_clause"][stopped], strict=True):
        verdict = RunFindings.VERDICTS[int(code) - 1]
        why = labels.get(verdict) or f"{verdict.value}: {phi.clauses[int(clause)]}"
        reasons[why] = reasons.get(why, 0) + 1
    holds = int((cat["true"] > 0).sum())
    stops = int(stopped.sum())
    return MonitorSummary(
        watched=watched,
        stops=stops,
        p_stop=stops / n if n else math.nan,
        ci_stop=clopper_pearson(stops, n),
        reasons=tuple(sorted(reasons.items(), key=lambda kv: (-kv[1], kv[0]))),
        stop_s_median=float(np.median(cat["stop_s"][stopped])) if stops else math.nan,
        holds=holds,
        p=holds / n if n else math.nan,
        ci=clopper_pearson(holds, n),
        safe=int(safe.sum()),
        safe_monitored=int(safe_mon.sum()),
        needed=int((stopped & ~safe).sum()),
        spurious=int((stopped & (true > 0)).sum()),
        missed=int((~safe_mon).sum()),
    )


_FIXED = (
    "run", "seed", "robustness", "reported", "weakest_clause", "failsafe_s", "lost_s",
    "monitored", "stop_s", "stop_code",
)  # fmt: skip
