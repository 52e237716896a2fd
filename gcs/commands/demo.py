"""``gcs demo``: plan the power-line inspection for 4 drones, fly it on mock vehicles, report.

Steps (each timed; ``benchmarks/bench_demo.py`` prints the split):

1. **set-up**: find ``configs/powerline_inspection.yaml`` (next to the installed packages, i.e.
   the repository of an editable install, else ``./configs``), load it for ``--vehicles``
   drones;
2. **planning**: :func:`planner.optimize.plan` (CasADi/IPOPT), written to ``<out>/plan.json``
   and put through ``gcs verify``'s checks: a plan that fails them is drawn and reported but
   not flown, as ``gcs fly`` would refuse it (``--force`` flies it on the mock vehicles anyway);
3. **vehicles**: one mock PX4 vehicle per drone in this process, on the ground below its
   planned start, on free loopback ports; connected over MAVLink/UDP through MAVSDK;
4. **flight**: take-off to the starts and the plan flown in offboard mode
   (:func:`gcs.flight.fly_plan`: shared start time, setpoints at 20 Hz against absolute
   deadlines, the safety monitor), telemetry recorded to ``<out>/flight.tlog`` and
   ``<out>/flight.csv``;
5. **report**: the exact robustness of the flown tracks against the spec, the picture
   (:func:`gcs.plot.plot_plan` with the flown tracks, ``<out>/demo.png``) and the report
   (``<out>/report.md``).

It prints a short summary: planned and flown robustness, planning and flight time, the files.
Exit status 0 when the plan passes verification, the flight completed and the flown data
satisfies the spec, 1 otherwise.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

import planner
from gcs.commands import add_mock_vehicle_arguments, add_speed_argument, parse_param_overrides
from gcs.errors import InputFileError, UserError
from gcs.flight import FlightRefused, FlyOptions, fly_plan, preflight_interlock, vehicle_specs
from gcs.flight.dryrun import mock_vehicles
from gcs.flight.progress import FlightProgress
from gcs.plot import plot_plan
from gcs.report import write_report
from gcs.telemetry import Telemetry
from planner.planfile import load_plan, save_plan
from planner.scenario import load_scenario

if TYPE_CHECKING:
    from gcs.flight.outcome import FlightOutcome
    from planner.planfile import Plan

HELP = "plan the power-line inspection, fly it on 4 mock PX4 vehicles and write a report"

#: The scenario the demo flies.
SCENARIO = "powerline_inspection.yaml"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``gcs demo``."""
    p.add_argument("--out", default="demo-out", metavar="DIR", help="output directory (demo-out)")
    p.add_argument("--vehicles", type=int, default=4, metavar="N", help="number of drones (4)")
    p.add_argument("--rate", type=float, default=20.0, metavar="HZ", help="setpoint rate (20)")
    p.add_argument(
        "--force",
        action="store_true",
        help="fly the plan on the mock vehicles even if it fails verification",
    )
    add_mock_vehicle_arguments(p, param_flag="--mock-param")
    add_speed_argument(p)
    p.add_argument(
        "--scenario",
        metavar="YAML",
        help=f"another scenario to plan and fly the same way (default configs/{SCENARIO})",
    )


def find_config(name: str) -> Path:
    """``configs/<name>`` of the repository next to the installed packages, else ``./configs``.

    Raises:
        UserError: not found in either place (both named).
    """

    here = Path(planner.__file__).resolve().parent.parent / "configs" / name
    candidates = [here, Path.cwd() / "configs" / name]
    for c in candidates:
        if c.is_file():
            return c
    raise UserError(
        f"scenario {name} not found (looked in {', '.join(str(c.parent) for c in candidates)})"
    )


@dataclass(frozen=True, slots=True, eq=False)
class DemoResult:
    """What :func:`run_demo` did.

    Attributes:
        plan: the plan flown (as written to ``plan.json``).
        outcome: the flight (``None``: not flown, the plan failed verification).
        timings_s: wall time by stage: set-up, planning, vehicles (mock start and
            connection), flight, report.
        files: written files by description.
        verification: the first failed ``gcs verify`` check of the plan (empty: all hold).
    """

    plan: Plan
    outcome: FlightOutcome | None
    timings_s: dict[str, float]
    files: dict[str, Path]
    verification: str = ""


def run_demo(
    out_dir: str | Path,
    *,
    vehicles: int | None = 4,
    rate_hz: float = 20.0,
    progress: TextIO | None = None,
    scenario: str | Path | None = None,
    force: bool = False,
    profile: str = "px4",
    seed: int = 0,
    mock_params: dict[str, float] | None = None,
    speed: float | None = None,
) -> DemoResult:
    """Plan, fly on mock vehicles, evaluate and report (module docstring).

    Args:
        out_dir: directory for plan.json, flight.tlog, flight.csv, demo.png, report.md.
        vehicles: number of drones (``None``: the scenario's default).
        rate_hz: offboard setpoint rate.
        progress: where the flight's status line goes (``None``: silent).
        scenario: the scenario file (default ``configs/powerline_inspection.yaml``).
        force: fly a plan that fails verification (mock vehicles only, for inspection).
        profile, seed, mock_params, speed: the mock vehicles
            (:func:`gcs.flight.dryrun.mock_vehicles`).
    """
    from planner.optimize import plan as solve

    timings: dict[str, float] = {}
    t = time.perf_counter()
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputFileError(f"--out {out}: cannot create: {exc.strerror or exc}") from None
    scenario = Path(scenario) if scenario is not None else find_config(SCENARIO)
    problem = load_scenario(scenario, vehicles=vehicles)
    timings["set-up"] = time.perf_counter() - t

    t = time.perf_counter()
    result = solve(problem)
    files = {"plan": save_plan(out / "plan.json", result, scenario_path=str(scenario))}
    plan = load_plan(files["plan"])  # what any other command would read
    timings["planning"] = time.perf_counter() - t
    verification = ""
    try:
        preflight_interlock(plan)
    except FlightRefused as exc:
        verification = exc.summary
        if not force:
            if progress is not None:
                print(f"REFUSED: {verification}; not flown (--force flies it)", file=progress)
            t = time.perf_counter()
            files["picture"] = plot_plan(
                plan, out / "demo.png", None, name=f"{scenario.stem} (demo, not flown)"
            ).path
            timings["report"] = time.perf_counter() - t
            return DemoResult(plan, None, timings, files, verification)
        if progress is not None:
            print(f"WARNING: {verification}; flying it anyway (--force)", file=progress)
    if progress is not None:
        print(
            f"planned in {timings['planning']:.1f} s: robustness {plan.robustness:+.4f}; "
            f"flying it on {len(plan.vehicles)} mock PX4 vehicles (offboard, {rate_hz:g} Hz)",
            file=progress,
            flush=True,
        )

    t = time.perf_counter()
    view = FlightProgress(plan, progress) if progress is not None else None
    options = FlyOptions(rate_hz=rate_hz, log_dir=out)
    with mock_vehicles(plan, seed=seed, profile=profile, params=mock_params, speed=speed) as dry:
        t_mock = time.perf_counter() - t
        specs = vehicle_specs(plan, list(dry.urls))
        outcome = asyncio.run(fly_plan(plan, specs, options, progress=view, clock=dry.clock))
    timings["vehicles"] = t_mock + outcome.connect_s
    timings["flight"] = outcome.flight_s

    t = time.perf_counter()
    telemetry = Telemetry(
        source=str(outcome.files.get("csv", "flight")),
        vehicles=dict(outcome.tracks),
    )
    picture = plot_plan(plan, out / "demo.png", telemetry, name=f"{scenario.stem} (demo)").path
    files["picture"] = picture
    files.update(outcome.files)
    timings["report"] = time.perf_counter() - t
    files["report"] = write_report(
        out / "report.md",
        plan,
        outcome,
        title=f"{scenario.stem}, {len(plan.vehicles)} drone(s) on mock PX4 vehicles",
        timings_s=timings,
        picture=picture,
        files={"plan": files["plan"]},
    )
    return DemoResult(plan, outcome, timings, files, verification)


def summary(demo: DemoResult) -> str:
    """The short summary ``gcs demo`` prints."""
    plan, out = demo.plan, demo.outcome
    lines = [f"planned robustness {plan.robustness:+.4f} ({plan.status.split(':')[0]})"]
    if demo.verification:
        lines.append(f"verification FAILED: {demo.verification}")
    if out is None:
        lines.append("not flown: the plan fails its checks (--force flies it on the mock vehicles)")
    if out is not None:
        ev = out.evaluation
        flown = (
            "n/a" if ev is None or ev.flown_robustness is None else f"{ev.flown_robustness:+.4f}"
        )
        why = f" ({ev.coverage_problem})" if ev is not None and ev.coverage_problem else ""
        lines.append(
            f"flown robustness {flown}{why}; flight {'completed' if out.completed else 'NOT completed'}"
        )
        if out.safety_event is not None:
            lines.append(f"safety stop: {out.safety_event.describe()}")
    t = demo.timings_s
    lines.append(
        f"planning {t.get('planning', 0.0):.1f} s, flight {t.get('flight', 0.0):.1f} s, "
        f"total {sum(t.values()):.1f} s (" + ", ".join(f"{k} {v:.1f}" for k, v in t.items()) + ")"
    )
    lines.append("files: " + ", ".join(str(p) for p in demo.files.values()))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Run the demo; 0 when the plan verifies, the flight completed and the flown data satisfies
    the spec."""

    if not 1 <= args.vehicles <= 8:
        raise UserError(f"--vehicles: must be 1..8, got {args.vehicles}")
    if not (2.0 < args.rate <= 100.0):
        raise UserError(f"--rate: must be in (2, 100] Hz, got {args.rate:g}")
    name = Path(args.scenario).name if args.scenario else SCENARIO
    print(f"gcs demo: planning {name} for {args.vehicles} drones (CasADi/IPOPT) ...", flush=True)
    demo = run_demo(
        args.out,
        vehicles=args.vehicles,
        rate_hz=args.rate,
        progress=sys.stdout,
        scenario=args.scenario,
        force=args.force,
        profile=args.profile,
        seed=args.seed,
        mock_params=parse_param_overrides(args.mock_param, "--mock-param"),
        speed=args.speed,
    )
    print(summary(demo))
    out = demo.outcome
    if demo.verification or out is None or not out.completed or out.evaluation is None:
        return 1
    rho = out.evaluation.flown_robustness
    return 0 if rho is not None and rho > 0 else 1
