"""``gcs fly PLAN.json``: fly a plan on PX4 vehicles (or mock vehicles with ``--dry-run``).

Vehicle ``i`` of the plan is reached at ``--connection`` number ``i`` (repeat the option, plan
order), by default ``udpin://0.0.0.0:{14540+i}``, the ports PX4 SITL instance ``i`` sends to.
``--dry-run`` starts one mock PX4 vehicle per plan vehicle in this process, on the ground below
its planned start and on free loopback ports, and flies against them exactly as against SITL
(arm, take off to the start, fly).

Before anything is armed the plan goes through ``gcs verify``'s checks and each vehicle's
position is compared with its planned start (``--tolerance``); a failed check refuses the
flight (exit 1, the check named) unless ``--force`` (which overrides the plan checks only).
While flying, a status line shows per vehicle its mode, its distance to the plan and the
robustness of its clauses so far; Ctrl-C commands every vehicle to hold and exits (130).
At the end: flown vs planned robustness (exact semantics), tracking errors, setpoint stream
statistics, and with ``--log DIR`` the telemetry (``flight.tlog``), the tracks (``flight.csv``),
MAVSDK's own log lines (``mavsdk.log``) and a report (``report.md``, :mod:`gcs.report`).
MAVSDK's warnings and its notes on its own machinery are for that log, not the terminal:
only its errors the user can act on show on stderr (:mod:`mavlink.link.mavsdk_glue`).

Exit status: 0 flown and the flown data satisfies the spec, 1 refused / not completed / flown
robustness negative, 2 bad input (plan file, URL, unreachable vehicle), 130 interrupted.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gcs.commands import (
    add_link_arguments,
    add_mock_vehicle_arguments,
    add_photo_argument,
    add_speed_argument,
    parse_param_overrides,
    photo_interval,
)
from gcs.errors import EXIT_INTERRUPTED, UserError
from gcs.flight import (
    FlightRefused,
    FlyOptions,
    fly_plan,
    preflight_interlock,
    signed_links,
    vehicle_specs,
)
from gcs.flight.dryrun import mock_vehicles
from gcs.flight.landing import landing_lines
from gcs.flight.mission import MissionRefused
from gcs.flight.outcome import FlightMode, FlightOutcome, format_outcome, outcome_json
from gcs.flight.progress import FlightProgress
from gcs.report import write_report
from mavlink.clock import WALL, Clock
from mavlink.errors import PreflightError
from mavlink.mock.vehicle_faults import FAULT_KINDS, VehicleFault
from mavlink.offboard.setpoints import EndAction
from planner.planfile import load_plan
from planner.scenario.sections import ScenarioError

if TYPE_CHECKING:
    from mavlink.mock.vehicle_faults import VehicleFault
    from planner.planfile import Plan

HELP = "fly a plan in offboard (or mission) mode on PX4 vehicles, or on mock ones with --dry-run"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``gcs fly``."""
    p.add_argument("plan", help="plan file written by gcs plan")
    p.add_argument("--rate", type=float, default=20.0, metavar="HZ", help="setpoint rate (20)")
    p.add_argument(
        "--dry-run", action="store_true", help="fly against mock vehicles started in-process"
    )
    p.add_argument("--mode", choices=["offboard", "mission"], default="offboard")
    p.add_argument(
        "--log",
        metavar="DIR",
        help="write flight.tlog, flight.csv, report.md and MAVSDK's log (mavsdk.log) to DIR",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="fly a plan that fails verification (or, in mission mode, whose predicted "
        "mission robustness is below epsilon)",
    )
    p.add_argument(
        "--tolerance",
        type=float,
        default=1.0,
        metavar="M",
        help="refuse a vehicle farther than M metres from its planned start (1.0)",
    )
    p.add_argument(
        "--arrive",
        type=float,
        metavar="M",
        help="start the plan when every vehicle is within M m of its start, still and on "
        "heading for 1 s (default: half the plan's margin, 0.1-0.3 m)",
    )
    p.add_argument(
        "--drag",
        type=float,
        metavar="C",
        help="the vehicles' drag per unit mass (1/s), fed forward as c * v (default: "
        "SIH_KDV / SIH_MASS where the vehicle has them, else 0; the report says what to set)",
    )
    p.add_argument(
        "--acceptance",
        type=float,
        metavar="M",
        help="--mode mission: waypoint acceptance radius (default: from the plan's speeds, "
        "at most NAV_ACC_RAD)",
    )
    p.add_argument(
        "--max-off-plan",
        type=float,
        default=3.0,
        metavar="M",
        help="hold every vehicle when one is more than M m from its plan (3; 0: never); "
        "past the plan's margin a vehicle is warned about",
    )
    p.add_argument("--end", choices=["hold", "land", "return"], default="hold")
    add_photo_argument(p)
    add_link_arguments(p, plan_order=True, timeout_s=10.0, timeout_help="connection timeout (10 s)")
    p.add_argument("--json", action="store_true", help="print the outcome as JSON")
    add_mock_vehicle_arguments(p, param_flag="--mock-param")
    p.add_argument(
        "--mock-fault",
        action="append",
        default=[],
        metavar="VEHICLE:KIND@T",
        help="--dry-run: inject a fault T seconds into VEHICLE's plan: lost (its link goes "
        "silent), failsafe (PX4 returns home), battery (falls to critical; PX4 acts as "
        "COM_LOW_BAT_ACT says); repeatable",
    )
    p.add_argument(
        "--replan",
        action="store_true",
        help="offboard: when a vehicle leaves the flight (link lost, its failsafe), plan the "
        "rest for the others and fly it (docs/replanning.md); without it the flight stops",
    )
    p.add_argument(
        "--replan-budget",
        type=float,
        default=3.0,
        metavar="S",
        help="--replan: plan seconds from a departure to the switch to the new plan (3)",
    )
    p.add_argument(
        "--reassign",
        action="store_true",
        help="--replan: hand the lost vehicle's own clauses (its inspections) to the vehicle "
        "that flies on for which a plan meets them best, nearest first",
    )
    p.add_argument(
        "--live-regions",
        metavar="FILE",
        help="--replan: a YAML file of regions (`regions:` in the scenario's syntax) closed in "
        "flight; read at the start and whenever it changes, each new region is kept out of "
        "from the next switch on",
    )
    p.add_argument(
        "--scenario",
        default=None,
        metavar="FILE",
        help="--replan: the scenario the plan was made from (default: the one it names)",
    )
    add_speed_argument(p)


def parse_mock_faults(texts: list[str], plan: Plan) -> list[tuple[int, VehicleFault]]:
    """``--mock-fault VEHICLE:KIND@T`` values: (vehicle index, fault), in plan order of
    vehicles; UserError naming the value otherwise."""

    names = [v.name for v in plan.vehicles]
    horizon = max(v.trajectory.duration_s for v in plan.vehicles)
    out: list[tuple[int, VehicleFault]] = []
    for text in texts:
        where = f"--mock-fault {text!r}"
        vehicle, colon, rest = text.partition(":")
        kind, at, t_text = rest.partition("@")
        if not (colon and at and vehicle and kind):
            raise UserError(f"{where}: expected VEHICLE:KIND@T, e.g. d2:lost@10")
        if vehicle not in names:
            raise UserError(f"{where}: no vehicle {vehicle!r} in the plan ({', '.join(names)})")
        if kind not in FAULT_KINDS:
            raise UserError(f"{where}: unknown kind {kind!r} (choose {', '.join(FAULT_KINDS)})")
        try:
            t = float(t_text)
        except ValueError:
            raise UserError(f"{where}: T must be seconds into the plan, got {t_text!r}") from None
        if not (math.isfinite(t) and 0.0 <= t <= horizon):
            raise UserError(f"{where}: T must be in [0, {horizon:g}] s (the plan), got {t_text}")
        out.append((names.index(vehicle), VehicleFault(kind, t)))
    return out


def run(args: argparse.Namespace) -> int:
    """Fly; see the module docstring for the exit statuses."""

    if not (2.0 < args.rate <= 100.0):
        raise UserError(f"--rate: must be in (2, 100] Hz, got {args.rate:g}")
    if not (args.tolerance > 0):
        raise UserError(f"--tolerance: must be > 0 m, got {args.tolerance:g}")
    if not (args.timeout > 0):
        raise UserError(f"--timeout: must be > 0 s, got {args.timeout:g}")
    for name in ("arrive", "acceptance"):
        value = getattr(args, name)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise UserError(f"--{name}: must be a number > 0 m, got {value:g}")
    if not (math.isfinite(args.max_off_plan) and args.max_off_plan >= 0):
        raise UserError(f"--max-off-plan: must be a number >= 0 m, got {args.max_off_plan:g}")
    if args.drag is not None and not (math.isfinite(args.drag) and 0 <= args.drag <= 10):
        raise UserError(f"--drag: must be a number in [0, 10] 1/s, got {args.drag:g}")
    if args.dry_run and args.connection:
        raise UserError("--dry-run and --connection exclude each other")
    if args.speed is not None and not args.dry_run:
        raise UserError("--speed: only for --dry-run (real vehicles fly in real time)")
    if args.mock_fault and not args.dry_run:
        raise UserError("--mock-fault: only for --dry-run (faults are injected into mock vehicles)")
    if not (math.isfinite(args.replan_budget) and args.replan_budget > 0):
        raise UserError(f"--replan-budget: must be a number > 0 s, got {args.replan_budget:g}")
    if args.replan and args.mode != "offboard":
        raise UserError(
            "--replan: only offboard flights switch to a new plan in flight (missions: not yet)"
        )
    for flag, given in (("--replan-budget", args.replan_budget != 3.0), ("--scenario", args.scenario), ("--reassign", args.reassign), ("--live-regions", args.live_regions)):  # fmt: skip
        if given and not args.replan:
            raise UserError(f"{flag}: only with --replan")
    plan = load_plan(args.plan)
    faults = parse_mock_faults(args.mock_fault, plan)
    replanner = None
    if args.replan:
        from gcs.flight.replan import FlightReplanner, replan_problem

        live = Path(args.live_regions) if args.live_regions else None
        try:
            replanner = FlightReplanner(
                replan_problem(plan, args.scenario),
                plan,
                args.replan_budget,
                reassign=args.reassign,
                live_regions=live,
            )
        except OSError as exc:
            raise UserError(
                f"--live-regions: {args.live_regions}: cannot read: {exc.strerror or exc}"
            ) from None
        except ScenarioError as exc:
            raise UserError(f"--live-regions: {exc}") from None
    out = sys.stderr if args.json else sys.stdout
    if args.end == "land":
        # where landing straight down would meet a keep-out, somewhere clear (or refused)

        for line in landing_lines(plan):
            print(line, file=out)
    try:
        preflight_interlock(plan, force=args.force)
    except FlightRefused as exc:
        print(f"gcs fly: {exc}", file=sys.stderr)
        return 1
    options = FlyOptions(
        mode=FlightMode(args.mode),
        rate_hz=args.rate,
        tolerance_m=args.tolerance,
        end=EndAction(args.end),
        log_dir=Path(args.log) if args.log else None,
        connect_timeout_s=args.timeout,
        drag_per_s=args.drag,
        arrive_m=args.arrive,
        acceptance_m=args.acceptance,
        force=args.force,
        max_off_plan_m=args.max_off_plan or None,
        photo_interval_s=photo_interval(args),
    )
    progress = FlightProgress(plan, out)
    if replanner is not None:
        replanner.note = progress.note
        replanner.on_new_plan = progress.replanned
        options = replace(options, replanner=replanner)

    def fly(urls: list[str] | None, clock: Clock = WALL) -> FlightOutcome:
        specs = vehicle_specs(plan, urls, args.base_port)

        async def signed_flight() -> FlightOutcome:
            async with signed_links(specs, args.signing_key) as links:
                return await fly_plan(plan, links, options, progress=progress, clock=clock)

        return asyncio.run(signed_flight())

    fired: list[dict[str, Any]] = []  # the injected faults (--mock-fault), what they did
    try:
        if args.dry_run:
            with mock_vehicles(
                plan,
                seed=args.seed,
                profile=args.profile,
                params=parse_param_overrides(args.mock_param, "--mock-param"),
                speed=args.speed,
                faults=faults,
            ) as dry:
                print(
                    f"dry run: {len(dry.urls)} mock vehicle(s) ({args.profile} profile) on the "
                    "ground below their starts "
                    f"({', '.join(dry.urls)})",
                    file=out,
                    flush=True,
                )
                for i, f in faults:
                    print(
                        f"dry run: fault to inject (--mock-fault): {plan.vehicles[i].name} "
                        f"{f.kind} at {f.at_s:g} s of the plan",
                        file=out,
                        flush=True,
                    )
                options = replace(options, on_plan_start=dry.mock.plan_started)
                outcome = fly(list(dry.urls), dry.clock)
                fired = [
                    {"vehicle": plan.vehicles[i].name, "kind": f.kind, "at_s": f.at_s,
                     "fired_at_s": next((t for g, t in v.plan_faults.fired if g is f), None)}
                    for i, f in faults
                    for v in [dry.mock.vehicles[i]]
                ]  # fmt: skip
        else:
            outcome = fly(args.connection)
    except (PreflightError, MissionRefused) as exc:
        print(f"gcs fly: {exc}", file=sys.stderr)
        return 1
    finally:
        if replanner is not None:
            replanner.close()  # its warm-up solve, before the process may exit
    if options.log_dir is not None:
        write_report(
            options.log_dir / "report.md",
            plan,
            outcome,
            title=Path(args.plan).name,
            files={"plan": Path(args.plan)},
        )
    if args.json:
        data = outcome_json(plan, outcome)
        if args.dry_run:
            data["mock_faults"] = fired
        print(json.dumps(data))
    else:
        print(format_outcome(plan, outcome))
        for rec in fired:
            when = rec["fired_at_s"]
            print(
                f"injected: {rec['vehicle']} {rec['kind']} at {rec['at_s']:g} s of its plan: "
                + (f"fired at {when:.2f} s" if when is not None else "did not fire (the "
                   "flight ended before)")
            )  # fmt: skip
    if outcome.interrupted:
        return EXIT_INTERRUPTED
    ev = outcome.evaluation
    flown_ok = ev is not None and ev.flown_robustness is not None and ev.flown_robustness >= 0
    return 0 if outcome.completed and flown_ok else 1
