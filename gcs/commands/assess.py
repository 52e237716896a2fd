"""``gcs assess PLAN.json --runs N``: how likely the plan is to hold, under disturbances.

Flies the plan ``N`` times in the batch simulator (the mock PX4 vehicle's own model, stepped
for many runs at once, far faster than real time) under drawn wind, gusts, estimator errors,
start errors, link latency, jitter and loss and derated limits (``--disturbance NAME=DIST``;
``--list-disturbances`` shows them with their calm-day defaults), judges every run with the
exact STL semantics, and reports P(spec holds) with its 95 % Clopper-Pearson interval, the
robustness quantiles, every clause's failures, the worst runs with their seeds and the margin a
plan would need for P >= 0.99.  The runs go to Ray in batches: a local instance started for
the command (all cores), or a cluster (``--ray-address``/``RAY_ADDRESS``); ``--workers 0``
runs them in this process.  ``-o DIR`` writes ``report.json``, ``runs.csv`` and
``assess.png``.  ``--replay SEED`` flies one run again and writes its tracks as CSV;
with ``--realtime`` it flies that run's disturbances on real-time mock vehicles.
``--monitor`` flies every run again under ``gcs fly``'s safety monitor and reports how often
it stops the flight, why, and whether the stops were needed.

Exit 0 when the campaign ran (whatever P is), 2 for bad input (an unknown disturbance or
distribution, N <= 0, an unreachable Ray address, an unreadable plan), 130 when interrupted
(after reporting the runs that finished).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from gcs.assess import AssessOptions, assess, evaluate_batch, replay
from gcs.assess.figure import plot_assessment
from gcs.assess.rerun import fly_realtime, write_replay_csv
from gcs.assess.stats import clopper_pearson
from gcs.checks import verify_plan
from gcs.commands import parse_param_overrides
from gcs.errors import EXIT_INTERRUPTED, UserError
from mavlink.mock.sim.disturbances import DISTURBANCES
from mavlink.mock.sim.profiles import DEFAULT_PROFILE, PROFILES
from planner.planfile import load_plan

if TYPE_CHECKING:
    from gcs.assess import CampaignProgress
    from gcs.assess.stats import AssessResult
    from planner.planfile import Plan

HELP = "fly a plan many times under drawn disturbances: P(spec holds), clauses, worst runs"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``gcs assess``."""

    p.add_argument("plan", nargs="?", help="plan file written by gcs plan")
    p.add_argument("--runs", type=int, default=1000, help="how many runs (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    p.add_argument(
        "-d",
        "--disturbance",
        action="append",
        default=[],
        metavar="NAME=DIST",
        help="a disturbance's distribution, e.g. wind_m_s='uniform(0, 6)' or loss=0.05 "
        "(repeatable; --list-disturbances shows them)",
    )
    p.add_argument("--wind", metavar="DIST", help="short for -d wind_m_s=DIST")
    p.add_argument(
        "--list-disturbances", action="store_true", help="list the disturbances and exit"
    )
    p.add_argument("--profile", choices=list(PROFILES), default=DEFAULT_PROFILE,
                   help="simulated vehicle (default px4: PX4 v1.17 on SIH)")  # fmt: skip
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="vehicle parameter over the profile (repeatable)")  # fmt: skip
    p.add_argument("--rate", type=float, default=20.0, help="setpoint rate in Hz (default 20)")
    p.add_argument("--drag", type=float, help="drag fed forward, 1/s (default: the vehicle's)")
    p.add_argument("--batch-size", type=int, default=250, help="runs per task (default 250)")
    p.add_argument("--workers", type=int, help="CPUs for a local Ray (default all; 0: no Ray)")
    p.add_argument("--ray-address", metavar="ADDRESS",
                   help="an existing Ray cluster (default: RAY_ADDRESS, else a local Ray)")  # fmt: skip
    p.add_argument("--monitor", action="store_true",
                   help="also fly every run under gcs fly's safety monitor: how often it stops "
                   "the flight, why, and whether the stops were needed")  # fmt: skip
    p.add_argument("--max-off-plan", type=float, default=3.0, metavar="M",
                   help="with --monitor: its off-plan bound, as gcs fly (default 3 m; 0: none)")  # fmt: skip
    p.add_argument(
        "--replan",
        action="store_true",
        help="with --monitor: replan the runs stopped on a lost link as gcs fly "
        "--replan would, and fly them again (docs/replanning.md)",
    )
    p.add_argument(
        "--replan-budget",
        type=float,
        default=3.0,
        metavar="S",
        help="--replan: plan seconds from a loss seen to the switch (3)",
    )
    p.add_argument(
        "--reassign",
        action="store_true",
        help="--replan: hand a lost vehicle's own clauses to another, as gcs fly",
    )
    p.add_argument("--scenario", metavar="FILE",
                   help="--replan: the scenario the plan was made from (default: the one it names)")  # fmt: skip
    p.add_argument("-o", "--out", metavar="DIR", help="write report.json, runs.csv, assess.png")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--replay", type=int, metavar="SEED", help="fly the run with this seed again")
    p.add_argument("--realtime", action="store_true",
                   help="with --replay: fly its disturbances on real-time mock vehicles")  # fmt: skip


def _options(args: argparse.Namespace, plan: Plan) -> Any:

    settings = disturbance_settings(args.disturbance, args.wind)
    if not (2.0 < args.rate <= 100.0):
        raise UserError(f"--rate: must be in (2, 100] Hz, got {args.rate:g}")
    if args.drag is not None and not (math.isfinite(args.drag) and 0 <= args.drag <= 10):
        raise UserError(f"--drag: must be a number in [0, 10] 1/s, got {args.drag:g}")
    if args.replay is not None and args.replay < 0:
        raise UserError(f"--replay: a run's seed is a whole number >= 0, got {args.replay}")
    if args.realtime and args.replay is None:
        raise UserError("--realtime needs --replay SEED")
    if not (math.isfinite(args.max_off_plan) and args.max_off_plan >= 0):
        raise UserError(f"--max-off-plan: must be a number >= 0 m, got {args.max_off_plan:g}")
    if not (math.isfinite(args.replan_budget) and args.replan_budget > 0):
        raise UserError(f"--replan-budget: must be a number > 0 s, got {args.replan_budget:g}")
    for flag, given in (("--replan-budget", args.replan_budget != 3.0), ("--scenario", args.scenario), ("--reassign", args.reassign)):  # fmt: skip
        if given and not args.replan:
            raise UserError(f"{flag}: only with --replan")
    if args.replan and not args.monitor:
        raise UserError("--replan: with --monitor only (the monitor hands a lost vehicle over)")
    if args.replan and args.replay is not None:
        raise UserError("--replan: not with --replay (a replayed run is flown without replanning)")
    return AssessOptions(
        runs=args.runs,
        seed=args.seed,
        disturbances=settings,
        profile=args.profile,
        params=parse_param_overrides(args.param, "--param"),
        rate_hz=args.rate,
        drag_per_s=args.drag,
        batch_size=args.batch_size,
        workers=args.workers,
        ray_address=args.ray_address,
        monitor=args.monitor,
        max_off_plan_m=args.max_off_plan or None,
        replan=_replan_settings(args, plan) if args.replan else None,
    )


def _replan_settings(args: argparse.Namespace, plan: Plan) -> Any:
    from gcs.assess.replanned import ReplanSettings
    from gcs.flight.replan import replan_problem

    return ReplanSettings(
        problem=replan_problem(plan, args.scenario),
        budget_s=args.replan_budget,
        profile=args.profile,
        params=parse_param_overrides(args.param, "--param"),
        rate_hz=args.rate,
        drag_per_s=args.drag,
        reassign=args.reassign,
    )


def disturbance_settings(items: list[str], wind: str | None) -> dict[str, str]:
    """``-d NAME=DIST`` options and ``--wind DIST`` as ``{name: distribution text}``."""

    settings: dict[str, str] = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise UserError(f"--disturbance {item!r}: expected NAME=DIST")
        settings[name.strip()] = text
    if wind is not None:
        settings["wind_m_s"] = wind
    return settings


def _list_disturbances(out: TextIO) -> None:

    for name, d in DISTURBANCES.items():
        per = "per vehicle" if d.per_vehicle else "per run"
        unit = f" {d.unit}" if d.unit else ""
        print(f"{name:14s} {d.default!s:22s} [{d.lo:g}, {d.hi:g}]{unit}, {per}: {d.meaning}",
              file=out)  # fmt: skip


class _Progress:
    """runs done, P so far and its interval: one rewritten line on a terminal, else a line
    per tenth of the campaign."""

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.tty = out.isatty()
        self._next = 0.1

    def __call__(self, p: CampaignProgress) -> None:

        lo, hi = clopper_pearson(p.holds, p.done)
        line = (
            f"runs {p.done}/{p.total}  P(holds) {p.holds / p.done:.3f} [{lo:.3f}, {hi:.3f}]  "
            f"{p.elapsed_s:.1f} s"
        )
        if self.tty:
            print("\r" + line, end="", file=self.out, flush=True)
            if p.done == p.total:
                print(file=self.out)
        elif p.done >= self._next * p.total or p.done == p.total:
            print(line, file=self.out, flush=True)
            while self._next * p.total <= p.done:
                self._next += 0.1

    def close(self) -> None:
        if self.tty:
            print(file=self.out, flush=True)


def format_result(plan_name: str, r: AssessResult) -> str:
    """The text report of a campaign."""
    lines = [
        f"assess {plan_name}: {r.runs} of {r.asked} runs (seed {r.seed}) on {r.engine} in "
        f"{r.elapsed_s:.1f} s ({r.runs_per_s:.0f} runs/s)"
        + ("  INTERRUPTED: the runs that finished" if r.interrupted else ""),
        f"P(spec holds) = {r.p:.3f}  [{r.ci[0]:.3f}, {r.ci[1]:.3f}] (95 % Clopper-Pearson; "
        f"{r.holds} of {r.runs} runs, on the true positions)",
        f"  on the reported positions (what gcs fly judges): {r.p_reported:.3f}  "
        f"[{r.ci_reported[0]:.3f}, {r.ci_reported[1]:.3f}]",
    ]
    q = r.quantiles
    if q:
        lines.append(
            f"robustness (m): planned {r.planned:+.3f}; flown min {q['min']:+.3f}  p05 "
            f"{q['p05']:+.3f}  median {q['p50']:+.3f}  p95 {q['p95']:+.3f}"
        )
    if r.margin_needed_m is not None:
        lines.append(
            f"margin needed for P >= 0.99: {r.margin_needed_m:.2f} m of planned robustness "
            f"(this plan has {r.planned:.2f} m)"
        )
    else:
        lines.append("margin needed for P >= 0.99: needs at least 100 runs")
    lines.append(f"offboard-loss failsafes: {r.failsafes} run(s)")
    if r.lost:
        lines.append(f"vehicles lost (disturbance lost): in {r.lost} run(s)")
    if r.monitor is not None:
        lines.extend(_format_monitor(r))
    if r.replan is not None:
        lines.extend(_format_replan(r))
    failing = sorted(
        (c for c in r.clauses if c.failures or c.failures_reported),
        key=lambda c: -c.failures,
    )
    if failing:
        lines.append("clauses that failed (runs failed, broke first, median robustness):")
        for c in failing[:10]:
            lines.append(
                f"  {c.failures:6d} {c.first_to_fail:6d}  {c.quantiles.get('p50', math.nan):+.3f}"
                f"  {c.text}"
            )
    else:
        lines.append("no clause failed in any run")
    if r.worst:
        lines.append("worst runs (gcs assess PLAN --replay SEED flies one again):")
        for w in r.worst:
            weakest = r.clauses[w.weakest_clause].text if r.clauses else ""
            lines.append(
                f"  run {w.index:6d}  seed {w.seed}  {w.true:+.3f} m  wind "
                f"{w.draws.get('wind_m_s', 0.0):.1f} m/s from {w.draws.get('wind_from_deg', 0.0) % 360:.0f} deg"
                f"  weakest: {weakest}"
            )
    return "\n".join(lines)


def _format_replan(r: AssessResult) -> list[str]:
    q = r.replan
    assert q is not None
    solve = (
        f"; replans took {q.solve_s_median:.2f} s (median), {q.solve_s_max:.2f} s at most"
        if math.isfinite(q.solve_s_median)
        else ""
    )
    return [
        f"replanning (--replan): {q.lost_links} run(s) stopped on a lost link, {q.tried} "
        f"replanned, {q.flown} flown on a new plan, {q.completed_flown} of those completed "
        f"({q.stopped_flown} stopped later by the monitor){solve}",
        *(f"  not flown: {k} run(s): {why}" for why, k in q.not_flown),
        f"  P(flight completes and its judged spec holds) = {q.p_with:.3f} "
        f"[{q.ci_with[0]:.3f}, {q.ci_with[1]:.3f}] with replanning, {q.p_without:.3f} "
        f"[{q.ci_without[0]:.3f}, {q.ci_without[1]:.3f}] without",
    ]


def _format_monitor(r: AssessResult) -> list[str]:
    m = r.monitor
    assert m is not None
    n = r.runs
    lines = [
        f"safety monitor (--monitor; every run flown again under it): stopped {m.stops} of {n} "
        f"runs, P(stop) = {m.p_stop:.3f} [{m.ci_stop[0]:.3f}, {m.ci_stop[1]:.3f}]"
        + (f", median at t = {m.stop_s_median:.1f} s" if m.stops else ""),
    ]
    for why, k in m.reasons[:6]:
        lines.append(f"  {k:6d}  {why}")
    lines += [
        f"  P(spec holds) under the monitor = {m.p:.3f} [{m.ci[0]:.3f}, {m.ci[1]:.3f}] "
        f"(without: {r.p:.3f})",
        f"  safety clauses ({len(m.watched)} always-clauses) held in {m.safe_monitored} of {n} "
        f"runs under the monitor, {m.safe} without",
        f"  stops needed (the flight without the monitor broke a safety clause): {m.needed}; "
        f"spurious (it held the whole spec): {m.spurious}; safety broken despite the "
        f"monitor: {m.missed}",
    ]
    return lines


def _verify_first(plan: Plan, path: str, out: TextIO) -> None:

    failed = [c for c in verify_plan(plan, None) if not c.ok]
    if failed:
        print(
            f"warning: {path} fails gcs verify ({failed[0].name}: {failed[0].detail}); "
            "assessing it anyway",
            file=out,
            flush=True,
        )


def _write_reports(out_dir: Path, plan: Plan, opts: Any, result: AssessResult) -> list[Path]:

    out_dir.mkdir(parents=True, exist_ok=True)
    report = out_dir / "report.json"
    report.write_text(json.dumps(result.as_json(), indent=1) + "\n", encoding="utf-8")
    runs = out_dir / "runs.csv"
    table = result.runs_table
    names = table.dtype.names or ()
    np.savetxt(runs, table, delimiter=",", header=",".join(names), comments="",
               fmt=["%d", "%d"] + ["%.6g"] * (len(names) - 2))  # fmt: skip
    worst = replay(plan, opts, result.worst[0].seed) if result.worst else None
    figure = plot_assessment(plan, result, worst, out_dir / "assess.png")
    return [report, runs, figure]


def run(args: argparse.Namespace) -> int:
    """Assess; see the module docstring for the exit statuses."""

    if args.list_disturbances:
        _list_disturbances(sys.stdout)
        return 0
    if not args.plan:
        raise UserError("gcs assess: a plan file is needed (PLAN.json)")
    plan = load_plan(args.plan)
    opts = _options(args, plan)
    out = sys.stderr if args.json else sys.stdout
    _verify_first(plan, args.plan, sys.stderr)
    if args.replay is not None:
        flights = replay(plan, opts, args.replay)

        true, rep, _, _ = evaluate_batch(plan, flights)
        print(
            f"run seed {args.replay}: robustness {float(true[0]):+.3f} m (true), "
            f"{float(rep[0]):+.3f} m (reported)",
            file=out,
        )
        if flights.stop is not None and flights.stop_s is not None:
            verdict = flights.stop.verdict(0)
            print(
                "safety monitor: "
                + ("no stop" if verdict is None
                   else f"stopped the flight at t = {float(flights.stop_s[0]):.2f} s ({verdict.value})"),
                file=out,
            )  # fmt: skip
        for p in write_replay_csv(flights, tuple(v.name for v in plan.vehicles),
                                  Path(args.out or ".")):  # fmt: skip
            print(f"wrote {p}", file=out)
        if args.realtime:
            outcome = fly_realtime(plan, opts, flights, seed=args.replay, out=out)
            ev = outcome.evaluation
            flown = None if ev is None else ev.flown_robustness
            print(
                "real-time mock flight: "
                + ("completed" if outcome.completed else "did not complete")
                + (
                    f", flown robustness {flown:+.3f} m (reported positions)"
                    if flown is not None
                    else ""
                ),
                file=out,
            )
            if args.json:
                print(json.dumps({"seed": args.replay, "true": float(true[0]),
                                  "reported": float(rep[0]), "realtime_flown": flown}))  # fmt: skip
        elif args.json:
            print(
                json.dumps({"seed": args.replay, "true": float(true[0]), "reported": float(rep[0])})
            )
        return 0
    progress = _Progress(sys.stderr)
    result = assess(plan, opts, on_batch=progress)
    if args.out:
        for p in _write_reports(Path(args.out), plan, opts, result):
            print(f"wrote {p}", file=out)
    if args.json:
        print(json.dumps(result.as_json()))
    else:
        print(format_result(Path(args.plan).name, result))
    return EXIT_INTERRUPTED if result.interrupted else 0
