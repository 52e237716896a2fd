"""``gcs plan SCENARIO.yaml``: plan trajectories and write the plan file (docs/scenario-format.md, "Plan files").

Prints a progress line while solving, then a summary table (per vehicle: path length, max
speed, max acceleration, limits; per top-level clause: robustness), or with ``--json`` one
JSON object.  Exit status 0 when the plan succeeds (exact robustness >= epsilon and all
checks pass), 1 when it does not (the plan file is still written, for inspection), 2 for
bad input (scenario errors, or an output file that cannot be written: checked before solving).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from gcs.assess import AssessOptions
from gcs.commands.assess import disturbance_settings
from gcs.errors import UserError
from gcs.flight.tuning import px4_notes
from mavlink.mock.sim.disturbances import parse_disturbances
from mavlink.mock.sim.errors import MockConfigError
from mavlink.mock.sim.profiles import PROFILES
from planner.assurance import AssuranceGoal
from planner.planfile import check_writable, load_plan, save_plan
from planner.problem import SolverMethod
from planner.scenario import load_scenario

HELP = "plan trajectories for a scenario (STL robustness, CasADi/IPOPT) and write a plan file"

#: Clause rows shown in the table when there are many (the weakest ones).
_MAX_CLAUSE_ROWS = 12


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``gcs plan``."""
    p.add_argument("scenario", help="scenario YAML file (see configs/)")
    p.add_argument("--vehicles", type=int, metavar="N", help="number of vehicles (generators)")
    p.add_argument("-o", "--output", default="plan.json", help="plan file (default plan.json)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--print-spec", action="store_true", help="print the expanded STL spec and exit")
    p.add_argument(
        "--time-limit",
        type=float,
        default=120.0,
        metavar="S",
        help="stop solving after S seconds (build included) and write the best plan so far, "
        "saying so (120; 0: no limit)",
    )
    p.add_argument(
        "--coarse-s",
        type=float,
        metavar="S",
        help="CPU seconds of the combinatorial stage (a MILP that chooses options, allocation, "
        "order and timing, beside the NLP; overrides solver.coarse_s; default 30 to find a "
        "coarse plan, 5 once a plan is in hand; at most a quarter of the time limit; 0: off)",
    )
    p.add_argument(
        "--solver",
        choices=["ipopt", "sqpmethod"],
        help="override the scenario's NLP method (sqpmethod: with BFGS and solver.qpsol)",
    )
    g = p.add_argument_group(
        "planning to a probability",
        "plan, assess the plan as gcs assess does, tighten the clauses that fail and plan "
        "again until P(spec holds) reaches P on runs the loop did not tune on (the scenario's "
        "assurance section sets the same; these options override it)",
    )
    g.add_argument("--target-probability", type=float, metavar="P",
                   help="the probability the plan must hold with (0 < P < 1)")  # fmt: skip
    g.add_argument("-d", "--disturbance", action="append", default=[], metavar="NAME=DIST",
                   help="a disturbance's distribution, as gcs assess (repeatable)")  # fmt: skip
    g.add_argument("--wind", metavar="DIST", help="short for -d wind_m_s=DIST")
    g.add_argument("--profile", help="simulated vehicle, as gcs assess (px4)")
    g.add_argument("--assess-runs", type=int, metavar="N",
                   help="runs of each round's assessment (2000)")  # fmt: skip
    g.add_argument("--final-runs", type=int, metavar="N",
                   help="runs of each check on fresh seeds (4000)")  # fmt: skip
    g.add_argument("--rounds", type=int, metavar="K", help="most plans made (6)")
    g.add_argument("--budget", type=float, metavar="S",
                   help="the loop's wall time: no round starts that would not end in it (240)")  # fmt: skip
    g.add_argument("--seed", type=int, help="base campaign seed: round k tunes on seed+k (0)")
    g.add_argument("--workers", type=int, help="CPUs for a local Ray (default all; 0: no Ray)")
    g.add_argument("--ray-address", metavar="ADDRESS",
                   help="an existing Ray cluster (default: RAY_ADDRESS, else a local Ray)")  # fmt: skip


def summary(result: Any, output: str | None) -> dict[str, Any]:
    """JSON-ready summary of a PlanResult."""
    w = result.weakest
    s = result.stats
    return {
        "success": result.success,
        "status": result.status,
        "robustness": result.robustness,
        "robustness_planning_grid": result.robustness_planning_grid,
        # nan: no NLP was built (the time limit came in its build)
        "smooth_robustness": (
            None if math.isnan(result.smooth_robustness) else result.smooth_robustness
        ),
        "solve_time_s": result.solve_time_s,
        "iterations": result.iterations,
        "weakest": None
        if w is None
        else {
            "formula": w.formula,
            "robustness": w.robustness,
            "t_s": w.t_s,
            "clause": w.clause_key,
        },
        "vehicles": [
            {
                "name": lim.name,
                "path_length_m": lim.path_length_m,
                "max_speed_m_s": lim.max_speed_m_s,
                "max_acc_m_s2": lim.max_acc_m_s2,
                "v_ratio": lim.v_ratio,
                "a_ratio": lim.a_ratio,
                "yaw_ratio": lim.yaw_ratio,
                "limits_ok": lim.limits_ok,
                "workspace_margin_m": lim.workspace_margin_m,
                "in_workspace": lim.in_workspace,
            }
            for lim in result.limits
        ],
        "clauses": [
            {"key": c.key_path, "text": c.text, "robustness": c.robustness} for c in result.clauses
        ],
        "stats": None
        if s is None
        else {
            "build_s": s.build_s,
            "solver_s": s.solver_s,
            "function_eval_s": s.function_eval_s,
            "check_s": s.check_s,
            "n_variables": s.n_variables,
            "n_constraints": s.n_constraints,
            "k": None if math.isnan(s.k) else s.k,
            "solver": s.solver,
            "starts": s.starts,
            "coarse": None if s.coarse is None else dict(s.coarse),
            "screen": None if s.screen is None else dict(s.screen),
        },
        "needs": list(result.needs),
        "start_bound": None
        if result.start_bound is None
        else {"others_robustness": result.start_bound.others},
        "output": output,
    }


def plan_table(result: Any) -> str:
    """The summary table ``gcs plan`` prints: per vehicle its path and limits, per top-level
    clause its robustness (the weakest ones when there are many), the status."""
    lines = []
    lines.append(
        f"{'vehicle':<8} {'path m':>9} {'max |v| m/s':>12} {'max |a| m/s2':>13} {'limits':>7}"
        f"  workspace"
    )
    for lim in result.limits:
        ok = "ok" if lim.limits_ok else "VIOL"
        ws = "in" if lim.in_workspace else f"out by {-lim.workspace_margin_m:.2g} m"
        lines.append(
            f"{lim.name:<8} {lim.path_length_m:>9.2f} {lim.max_speed_m_s:>12.3f} "
            f"{lim.max_acc_m_s2:>13.3f} {ok:>7}  {ws}"
        )
    lines.append("")
    clauses = sorted(result.clauses, key=lambda c: c.robustness)
    shown = clauses[:_MAX_CLAUSE_ROWS]
    vehicles = {lim.name for lim in result.limits}
    lines.append(f"{'robustness':>11}  clause")
    for c in shown:
        lines.append(f"{c.robustness:>11.4f}  {clause_cell(c.text, vehicles)}")
    if len(clauses) > len(shown):
        lines.append(f"{'':>11}  ... {len(clauses) - len(shown)} more clauses, all stronger")
    lines.append("")
    w = result.weakest
    if w is not None:
        lines.append(
            f"weakest: {w.formula} = {w.robustness:.4f} at t = {w.t_s:g} s ({w.clause_key})"
        )
    if result.start_bound is not None:
        others = result.start_bound.others
        lines.append(
            "the start sets this figure (at t = 0 the vehicles are where the scenario puts "
            "them)"
            + ("" if others is None else f"; the clauses the plan sets have at least {others:.4f}")
        )
    lines.extend(f"needs {line}" for line in result.needs)
    s = result.stats
    lines.append(
        f"robustness {result.robustness:.4f} (planning grid {result.robustness_planning_grid:.4f}, "
        + (
            "no NLP built"
            if math.isnan(result.smooth_robustness)
            else f"smooth {result.smooth_robustness:.4f}"
        )
        + f"); {result.iterations} iterations, "
        f"{result.solve_time_s:.2f} s"
        + (f" (build {s.build_s:.2f}, solver {s.solver_s:.2f}, check {s.check_s:.2f})" if s else "")
        + (f", {s.starts} starts" if s and s.starts > 1 else "")
        + (
            f"; rows screened: {s.screen['kept']:,} of {s.screen['total']:,} kept"
            + (f", {s.screen['rounds']} round(s) adding rows" if s.screen["rounds"] else "")
            if s and s.screen
            else ""
        )
    )
    lines.append(("OK: " if result.success else "FAILED: ") + result.status)
    return "\n".join(lines)


#: Characters of a clause shown in the plan table before it is shortened.
_CLAUSE_WIDTH = 70
_CALL_ARGS = re.compile(r"\b[A-Za-z_]\w*\(([^()]*)\)")


def clause_cell(text: str, vehicles: set[str], width: int = _CLAUSE_WIDTH) -> str:
    """A clause for the plan table: whole when it fits in ``width``, else its start and,
    after it, the vehicles and places it names (``[d1, d2, d3 | p4]``): long clauses that
    differ only in those (one per pole, an ``or`` over the drones) stay distinguishable."""
    if len(text) <= width:
        return text
    names: list[str] = []
    for m in _CALL_ARGS.finditer(text):
        for arg in m.group(1).split(","):
            a = arg.strip()
            if a and re.fullmatch(r"[A-Za-z_]\w*", a) and a not in names:
                names.append(a)
    who = [n for n in names if n in vehicles]
    where = [n for n in names if n not in vehicles]
    tag = " | ".join(part for part in (", ".join(who), ", ".join(where)) if part)
    tail = f" [{tag}]" if tag else ""
    head = max(24, width - len(tail) - 3)
    return text[:head].rstrip() + "..." + tail


class _Ticker:
    """A progress line on stderr: the current stage and the elapsed time."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.stage = "loading"
        self.t0 = time.perf_counter()
        self._stop = threading.Event()
        self._tty = sys.stderr.isatty()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> _Ticker:
        if self.enabled and self._tty:
            self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        if self.enabled and self._tty:
            sys.stderr.write("\r\033[K")
            sys.stderr.flush()

    def set(self, stage: str) -> None:
        self.stage = stage
        if self.enabled and not self._tty:
            print(f"gcs plan: {stage} ({time.perf_counter() - self.t0:.1f} s)", file=sys.stderr)

    def _run(self) -> None:
        while not self._stop.wait(0.2):
            sys.stderr.write(f"\r\033[K{self.stage} ... {time.perf_counter() - self.t0:.1f} s")
            sys.stderr.flush()


def run(args: argparse.Namespace) -> int:
    """Plan; 0 on success, 1 when the plan fails its checks."""

    from planner.optimize import plan

    if not (math.isfinite(args.time_limit) and args.time_limit >= 0):
        raise UserError(f"--time-limit: must be a number of seconds >= 0, got {args.time_limit:g}")
    problem = load_scenario(args.scenario, vehicles=args.vehicles)
    if args.print_spec:
        print(problem.spec_text)
        return 0
    out = Path(args.output)
    check_writable(out)  # before the solve, which may take minutes
    if args.coarse_s is not None:
        if not (math.isfinite(args.coarse_s) and args.coarse_s >= 0):
            raise UserError(f"--coarse-s: must be a number of seconds >= 0, got {args.coarse_s:g}")
        problem = replace(problem, solver=replace(problem.solver, coarse_s=args.coarse_s))
    if args.solver:
        method = SolverMethod(args.solver)
        hessian = "limited-memory" if method is SolverMethod.SQP else problem.solver.hessian
        problem = replace(problem, solver=replace(problem.solver, method=method, hessian=hessian))
    if args.target_probability is not None or problem.assurance is not None:
        return _to_probability(args, problem, out)
    _no_target_options(args)
    with _Ticker(enabled=True) as ticker:
        result = plan(
            problem,
            progress=ticker.set,
            time_limit_s=args.time_limit or None,
            progress_every_s=1.0 if sys.stderr.isatty() else 10.0,
        )
    save_plan(out, result, scenario_path=str(args.scenario))

    notes = px4_notes(load_plan(out)) if result.success else []
    if args.json:
        print(json.dumps({**summary(result, str(out)), "px4_notes": notes}))
    else:
        print(plan_table(result))
        for note in notes:
            print(note)
        print(f"plan written to {out}")
    return 0 if result.success else 1


#: Options that only mean something with a target probability (their unset values).
_TARGET_ONLY: dict[str, Any] = {
    "disturbance": [],
    "wind": None,
    "profile": None,
    "assess_runs": None,
    "final_runs": None,
    "rounds": None,
    "budget": None,
    "seed": None,
    "workers": None,
    "ray_address": None,
}


def _no_target_options(args: argparse.Namespace) -> None:

    for name, unset in _TARGET_ONLY.items():
        if getattr(args, name) != unset:
            raise UserError(
                f"--{name.replace('_', '-')} needs --target-probability "
                "(or the scenario's assurance section)"
            )


def _first(*values: Any) -> Any:
    return next(v for v in values if v is not None)


def _to_probability(args: argparse.Namespace, problem: Any, out: Path) -> int:
    """The loop of :mod:`gcs.assess.target`, set by the options over the scenario's
    ``assurance`` section; 0 when met."""
    from gcs.assess.target import TargetOptions, plan_to_probability

    goal = problem.assurance or AssuranceGoal(probability=math.nan)
    if problem.assurance is not None:
        try:
            parse_disturbances(goal.disturbances)
        except MockConfigError as exc:
            raise UserError(f"{problem.source}: assurance.disturbances: {exc}") from None
    profile = _first(args.profile, "px4")
    if profile not in PROFILES:
        raise UserError(f"--profile: unknown {profile!r} (profiles: {', '.join(PROFILES)})")
    opts = TargetOptions(
        probability=_first(args.target_probability, goal.probability),
        assess=AssessOptions(
            runs=_first(args.assess_runs, goal.runs),
            seed=_first(args.seed, goal.seed),
            disturbances={
                **goal.disturbances,
                **disturbance_settings(args.disturbance, args.wind),
            },
            profile=profile,
            workers=args.workers,
            ray_address=args.ray_address,
        ),
        final_runs=_first(args.final_runs, goal.final_runs),
        rounds=_first(args.rounds, goal.rounds),
        time_limit_s=args.time_limit or None,
        budget_s=_first(args.budget, goal.budget_s),
    )
    t0 = time.perf_counter()

    def say(line: str) -> None:
        print(f"gcs plan: {line} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)

    r = plan_to_probability(problem, opts, scenario_path=str(args.scenario), say=say)
    save_plan(out, r.plan)
    if r.final is None:  # the scenario as written cannot be planned: nothing was assessed
        if args.json:
            print(json.dumps({**summary(r.result, str(out)), "assurance": None, "rounds": []}))
        else:
            print(plan_table(r.result))
            print("not assessed: the scenario as written cannot be planned")
            print(f"plan written to {out}")
        return 1

    notes = px4_notes(r.plan) if r.result.success else []
    if args.json:
        print(json.dumps({**summary(r.result, str(out)), **target_json(r), "px4_notes": notes}))
    else:
        print(plan_table(r.result))
        print(target_table(r))
        for note in notes:
            print(note)
        print(f"plan written to {out}")
    return 0 if r.met else 1


def target_json(r: Any) -> dict[str, Any]:
    """The loop's record for ``--json``: the assurance, each round, the first plan's figure."""
    assert r.plan.assurance is not None
    return {
        "assurance": r.plan.assurance.to_json(),
        "first_robustness": r.first,
        "rounds": [
            {
                "round": rd.index,
                "robustness": rd.robustness,
                "plan_s": rd.planned_s,
                "tuning": {"runs": rd.runs, "seed": rd.seed, "p_holds": rd.p, "ci95": list(rd.ci)},
                "fresh": None
                if rd.fresh is None
                else {
                    "runs": rd.fresh.runs,
                    "seed": rd.fresh.seed,
                    "p_holds": rd.fresh.p,
                    "ci95": list(rd.fresh.ci),
                },
                "margins": dict(rd.margins),
                "dwells": dict(rd.dwells),
            }
            for rd in r.rounds
        ],
    }


def target_table(r: Any) -> str:
    """The loop's rounds, the margins of the plan kept and its assurance, as text."""
    lines = ["", f"{'round':>5} {'robust':>8} {'plan s':>7} {'P tuning':>18} {'P fresh':>18}"]
    for rd in r.rounds:
        fresh = "-" if rd.fresh is None else f"{rd.fresh.p:.4f} [{rd.fresh.ci[0]:.4f}]"
        lines.append(
            f"{rd.index:>5} {rd.robustness:>+8.3f} {rd.planned_s:>7.1f} "
            f"{f'{rd.p:.4f} [{rd.ci[0]:.4f}]':>18} {fresh:>18}"
        )
    if r.margins:
        lines.append("clauses tightened (margin, m):")
        for text, m in sorted(r.margins.items(), key=lambda kv: -kv[1]):
            lines.append(f"  {m:6.2f}  {clause_cell(text, set())}")
    dwells = r.plan.assurance.dwells if r.plan.assurance is not None else {}
    if dwells:
        lines.append("hovers planned longer (s):")
        for text, d in sorted(dwells.items(), key=lambda kv: -kv[1]):
            lines.append(f"  {d:6g}  {clause_cell(text, set())}")
    lines.append(
        f"robustness {r.result.robustness:+.3f} as written (first plan {r.first:+.3f}); "
        f"{r.elapsed_s:.0f} s"
    )
    assert r.plan.assurance is not None
    lines.append(r.plan.assurance.summary())
    return "\n".join(lines)
