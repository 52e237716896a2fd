"""``gcs upload PLAN.json``: the plan's PX4 missions (and geofence) to each vehicle, read back.

Each vehicle's trajectory becomes global ``*_INT`` mission items
(:func:`mavlink.mission.trajectory_to_mission`: take-off to the start, timed straight legs,
land / return / hold), the same items ``gcs export --format qgc`` writes. They are uploaded
with the MAVLink mission protocol (MAVSDK ``mission_raw``), downloaded again and compared
field by field at the wire's precision. With ``--fence`` the geofence goes too (the
workspace's footprint as inclusion polygon, full-height stay-out regions as exclusions,
polygons for boxes and prisms, circles for cylinders: :func:`mavlink.mission.fence_zones`, as
``gcs export`` writes it), also read back. ``--start`` (after checking, before anything is
sent, that each vehicle is within ``--tolerance`` of its planned start, horizontally) then
starts the missions as ``gcs fly --mode mission`` does, with the flight engine's start
(:func:`mavlink.flight.start_together`): every vehicle takes off to its start's altitude, is
brought onto its start through the arrival gate, and all are switched into AUTO.MISSION from
the start waypoint at one instant, each start confirmed. That instant is the plan's t = 0 for
every vehicle (printed; ``t0_unix_s`` in the JSON), so the missions keep the plan's clock as
predicted; they then fly on board, and the ground station leaves them (``gcs fly --mode
mission`` stays, watches and judges).

Interlocks (before anything is sent): a plan that fails ``gcs verify``'s checks is refused, and
with ``--start`` so are missions PX4 is predicted to fly below the plan's epsilon, and missions
with a clause that tolerates less timing error than PX4 keeps between vehicles
(:data:`gcs.flight.missions.KEEPS_CLOCK_S`, 0.5 s): released missions fly without the
ground station's safety monitor, so nothing would stop them where the clock slips (on PX4
SITL the power line's d1-d2 separation, which tolerates 0.14 s, broke by 1.3 m in one of three
released flights); ``--force`` overrides them.

The table gives per vehicle the items sent, the times of upload and read-back, the verdict,
and how far the mission's straight legs stray from the planned trajectory; below it, the
spec's exact robustness if every vehicle flew its mission's path exactly (the price of the
mission conversion against the plan's own robustness).

On a bad radio link each transfer is retried as a whole
(:func:`mavlink.mission.upload_with_retries`: upload, read back, compare; exponential back-off
with jitter between attempts) until it reads back as sent or the vehicle's ``--timeout``
budget (60 s, shared by its mission and fence) runs out; each vehicle's progress goes to
standard error, one line per step (attempt, items, elapsed time). ``--connect-timeout``
bounds the wait for the vehicles to answer (10 s).

Read-back compares each item as PX4 stores it (fence items come back without autocontinue,
yaw wrapped to [0, 360): :func:`mavlink.mission.compare_items`); a position, command or count
that differs is a failure. A start is reported only when it happened: PX4 in AUTO.MISSION
(a start PX4 rejects 12 ms after accepting it is retried); a start too low for PX4's take-off
(NAV_MC_ALT_RAD) is refused before anything is sent; a start that fails on one vehicle holds
them all.

Exit status: 0 every upload read back as sent (and, with ``--start``, every mission started),
1 refused by an interlock (a plan or prediction that fails its checks, a vehicle away from
its start), 2 bad input (plan file, URL, option value, unreachable vehicle), 3 a vehicle
failed it (a read-back differs, a transfer gave up, a start did not happen).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import sys
import time
from dataclasses import asdict, dataclass, replace
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from gcs.commands import add_link_arguments, add_photo_argument, photo_interval
from gcs.errors import EXIT_CHECK_FAILED, EXIT_OK, EXIT_VEHICLE_FAILED, UserError
from gcs.flight import FlightRefused, preflight_interlock, signed_links, vehicle_specs
from gcs.flight.landing import landing_lines
from gcs.flight.mission import (
    MissionRefused,
    mission_gate,
    missions_driver,
    prediction_params,
    read_nav_params,
)
from gcs.flight.missions import (
    KEEPS_CLOCK_S,
    convert_plan_apart,
    fence_plan,
    timing_summary,
)
from gcs.flight.payload import capture_spans
from gcs.flight.tuning import read_tuning
from mavlink.errors import LinkError, MissionError, PreflightError, TransferGaveUpError
from mavlink.flight import check_starts, start_together
from mavlink.link.fleet import Fleet
from mavlink.mission import (
    MissionEnd,
    MissionType,
    RetryPolicy,
    path_deviation,
    upload_with_retries,
)
from planner.planfile import load_plan

if TYPE_CHECKING:
    from collections.abc import Callable

    from gcs.flight.missions import FencePlan, MissionConversion
    from mavlink.link.fleet import Fleet
    from mavlink.link.vehicle import Vehicle
    from mavlink.link.vehicle_status import VehicleSpec
    from mavlink.mission import MissionItem, MissionPlan, MissionStart, TransferProgress
    from mavlink.mission.flight import MissionDriver
    from planner.planfile import Plan

#: GF_ACTION values (PX4 v1.17 geofence breach action).
FENCE_ACTIONS = {"none": 0, "warn": 1, "hold": 2, "return": 3, "terminate": 4, "land": 5}

HELP = "upload each vehicle's mission (and geofence) converted from a plan, read back and compare"

#: Default time budget per vehicle for its transfers, retries included (s).
DEFAULT_BUDGET_S = 60.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``gcs upload``."""
    p.add_argument("plan", help="plan file written by gcs plan")
    p.add_argument("--fence", action="store_true", help="upload the geofence too")
    p.add_argument(
        "--fence-action",
        choices=list(FENCE_ACTIONS),
        help="with --fence: set the vehicles' breach action GF_ACTION (default: leave it)",
    )
    p.add_argument("--start", action="store_true", help="arm and start the missions afterwards")
    p.add_argument("--end", choices=["land", "return", "hold"], default="land")
    p.add_argument(
        "--acceptance",
        type=float,
        metavar="M",
        help="waypoint acceptance radius (default: from the plan's speeds, at most the "
        "vehicle's NAV_ACC_RAD; pass-through waypoints widened by the drag lag)",
    )
    p.add_argument(
        "--drag",
        type=float,
        metavar="C",
        help="the vehicles' drag per unit mass (1/s) for the mission prediction (default: "
        "SIH_KDV / SIH_MASS where the vehicle has them, else 0)",
    )
    p.add_argument(
        "--tolerance",
        type=float,
        default=1.0,
        metavar="M",
        help="with --start: refuse a vehicle farther than M m from its start (1.0)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="upload (and start) a plan or mission path that fails its checks",
    )
    p.add_argument(
        "--timeout",
        default=f"{DEFAULT_BUDGET_S:g}",
        metavar="S",
        help="time budget per vehicle for its transfers, every retry and read-back included "
        f"({DEFAULT_BUDGET_S:g} s)",
    )
    add_link_arguments(
        p,
        plan_order=True,
        timeout_s=10.0,
        timeout_help="connection timeout (10 s)",
        timeout_flag="--connect-timeout",
    )
    add_photo_argument(p)
    p.add_argument("--json", action="store_true", help="print the results as JSON")


@dataclass(frozen=True, slots=True)
class UploadRow:
    """One vehicle's upload.

    Attributes:
        vehicle, sysid, url: the vehicle.
        mission_items, fence_items: items sent (0 fence items without ``--fence``).
        upload_s, readback_s: transfer times (mission + fence), seconds.
        verified: every upload read back identical.
        error: what failed (empty when verified).
        max_deviation_m, rms_deviation_m: mission path vs planned trajectory.
        started: the mission was started: PX4 reported AUTO.MISSION, armed, and the vehicle
            climbed (``--start``).
        start_detail: what the start confirmation saw (or why it failed).
        start_attempts: start commands sent (a TEMPORARILY_REJECTED start is retried).
        mission_attempts, fence_attempts: uploads it took (more than 1: retried on a bad
            link; 0: not tried).
        transfer_s: wall time of the vehicle's transfers, retries and waits included.
    """

    vehicle: str
    sysid: int
    url: str
    mission_items: int
    fence_items: int
    upload_s: float
    readback_s: float
    verified: bool
    error: str
    max_deviation_m: float
    rms_deviation_m: float
    started: bool = False
    start_detail: str = ""
    start_attempts: int = 0
    mission_attempts: int = 0
    fence_attempts: int = 0
    transfer_s: float = 0.0


async def _upload_one(
    v: Vehicle,
    mission: MissionPlan,
    fence: tuple[MissionItem, ...],
    plan: Plan,
    budget_s: float,
    progress: Callable[[TransferProgress], None] | None,
) -> UploadRow:
    """Mission, then fence, each retried until read back as sent, within ``budget_s`` for
    both (:func:`mavlink.mission.upload_with_retries`)."""

    pv = plan.vehicle(v.name)
    dev = path_deviation(pv.trajectory, mission.path)
    up = back = 0.0
    error = ""
    tries = {MissionType.MISSION: 0, MissionType.FENCE: 0}
    t0 = time.monotonic()
    try:
        for items, mtype in ((mission.items, MissionType.MISSION), (fence, MissionType.FENCE)):
            if not items:
                continue
            left = max(budget_s - (time.monotonic() - t0), 1e-3)
            try:
                rep = await upload_with_retries(
                    v, items, mtype, policy=RetryPolicy(budget_s=left), progress=progress
                )
            except MissionError as exc:
                tries[mtype] = exc.attempts if isinstance(exc, TransferGaveUpError) else 1
                raise
            up, back = up + rep.upload_s, back + rep.download_s
            tries[mtype] = rep.attempts
    except LinkError as exc:
        error = exc.detail
    return UploadRow(
        vehicle=v.name,
        sysid=v.spec.sysid,
        url=v.url,
        mission_items=len(mission.items),
        fence_items=len(fence),
        upload_s=up,
        readback_s=back,
        verified=not error,
        error=error,
        max_deviation_m=dev.max_m,
        rms_deviation_m=dev.rms_m,
        mission_attempts=tries[MissionType.MISSION],
        fence_attempts=tries[MissionType.FENCE],
        transfer_s=time.monotonic() - t0,
    )


async def _start(fleet: Fleet, driver: MissionDriver, plan: Plan) -> tuple[float | None, str]:
    """The flight engine's start (:func:`mavlink.flight.start_together`): every vehicle takes
    off, is brought onto its start through the arrival gate, and all are released into
    AUTO.MISSION at one instant, each start confirmed; the missions then fly on board.

    Returns:
        The shared start (Unix time; ``None`` if it did not happen) and, if it did not, why
        (every vehicle was commanded to hold).
    """

    try:
        started = await start_together(fleet, driver, plan.origin)
    except LinkError as exc:
        return None, str(exc).splitlines()[0]
    finally:
        # nothing follows the missions from here: the driver's mission follower lets go of
        # its MAVSDK subscriptions before the link closes under them
        await driver.abort()
    return started.t0_unix_s, ""


async def upload_plan(
    plan: Plan,
    specs: tuple[VehicleSpec, ...],
    *,
    fence: bool,
    start: bool,
    end: str,
    acceptance_m: float | None,
    tolerance_m: float,
    connect_timeout_s: float,
    drag_per_s: float | None = None,
    force: bool = False,
    fence_action: str | None = None,
    budget_s: float = DEFAULT_BUDGET_S,
    progress: Callable[[TransferProgress], None] | None = None,
    photo_interval_s: float = 1.0,
) -> tuple[list[UploadRow], MissionConversion, FencePlan | None, float | None]:
    """Convert (with the vehicles' parameters), upload, read back (and start) every
    vehicle's mission; a row per vehicle, and the conversion with its predicted flight.

    Each vehicle's transfers are retried on a bad link within ``budget_s`` for all of them
    (mission and fence); ``progress`` gets every step (:class:`TransferProgress`). Where the
    plan faces an inspection target the missions take pictures every ``photo_interval_s``
    (:mod:`gcs.flight.payload`; 0: none).

    Raises:
        mavlink.errors.ConnectTimeoutError: a vehicle never answered.
        mavlink.errors.PreflightError: with ``start``, a vehicle too far from its start.
        gcs.flight.mission.MissionRefused: with ``start``, the predicted mission robustness
            is below epsilon (and not ``force``); nothing was uploaded.
    """

    names = [pv.name for pv in plan.vehicles]
    # the start follows the vehicles' positions (the gate): ask for them at the flight's rate
    rate = 20.0 if start else None
    t0_unix: float | None = None
    async with Fleet(specs, connect_timeout_s=connect_timeout_s, telemetry_rate_hz=rate) as fleet:
        # with --start the missions are sent (and read back) below, with the transfers' report
        driver = missions_driver(plan, mission_gate(plan, tolerance_m)) if start else None
        if driver is not None:
            # before anything is sent: each vehicle near its start, high enough to take off
            await check_starts(fleet, driver, plan.origin)
        tuning = await read_tuning(fleet, names, drag_per_s)
        known = await read_nav_params(fleet, names[0])
        fp = fence_plan(plan, acc_hor_m_s2=known.get("MPC_ACC_HOR", 3.0)) if fence else None
        fence_items = fp.items if fp is not None else ()
        conv = await convert_plan_apart(
            plan,
            end=MissionEnd(end),
            acceptance_m=acceptance_m,
            params=prediction_params(tuning, known),
            captures=capture_spans(plan, photo_interval_s),
        )
        if start and not force and not conv.predicted_robustness >= plan.epsilon:
            raise MissionRefused(
                f"refused to start: PX4 is predicted to fly these missions with robustness "
                f"{conv.predicted_robustness:+.4f} < epsilon {plan.epsilon:g} (the plan's own "
                f"{plan.robustness:+.4f}; straight legs {conv.straight_leg_robustness:+.4f}; "
                f"weakest: {conv.weakest}; {timing_summary(conv.late_s)}); fly the plan in "
                "offboard mode (gcs fly), or --force; nothing was uploaded"
            )
        least = conv.least_tolerant()
        if start and not force and least is not None and least[1] < KEEPS_CLOCK_S:
            # released missions fly without the ground station's monitor: nothing would stop
            # them where the clock slips further than the clause tolerates
            raise MissionRefused(
                f"refused to start: on PX4's predicted flight {least[0]} tolerates only "
                f"{least[1]:.2f} s of timing error, and PX4 keeps missions' clocks to about "
                f"{KEEPS_CLOCK_S:g} s between vehicles; released missions fly without the "
                "safety monitor: fly them with gcs fly --mode mission (monitored), offboard "
                "(gcs fly), or --force; nothing was uploaded"
            )
        rows = list(
            await asyncio.gather(
                *(
                    _upload_one(v, conv.missions[v.name], fence_items, plan, budget_s, progress)
                    for v in fleet
                )
            )
        )
        if fence and fence_action is not None and all(r.verified for r in rows):
            await asyncio.gather(
                *(v.set_param_int("GF_ACTION", FENCE_ACTIONS[fence_action]) for v in fleet)
            )
        if driver is not None and all(r.verified for r in rows):
            t0_unix, failure = await _start(fleet, driver, plan)
            rows = [_started_row(r, driver.confirmed.get(r.vehicle), failure) for r in rows]
    return rows, conv, fp, t0_unix


def _started_row(row: UploadRow, confirmed: MissionStart | None, failure: str) -> UploadRow:
    """``row`` with what its vehicle's start did: confirmed (and the whole fleet released),
    or why not."""

    if confirmed is None:
        return replace(row, started=False, start_detail=failure or "not started")
    return replace(
        row,
        started=confirmed.started and not failure,
        start_detail=confirmed.detail if not failure else f"{confirmed.detail}; {failure}",
        start_attempts=confirmed.attempts,
    )


def table(rows: list[UploadRow]) -> str:
    """The text table."""
    lines = [
        f"{'vehicle':<8} {'sysid':>5} {'url':<26} {'items':>5} {'fence':>5} {'up s':>6} "
        f"{'back s':>6} {'tries':>5} {'read-back':<9} {'max dev m':>9} {'rms dev m':>9}"
    ]
    for r in rows:
        verdict = "identical" if r.verified else "FAILED"
        lines.append(
            f"{r.vehicle:<8} {r.sysid:>5} {r.url:<26} {r.mission_items:>5} {r.fence_items:>5} "
            f"{r.upload_s:>6.2f} {r.readback_s:>6.2f} {r.mission_attempts + r.fence_attempts:>5} "
            f"{verdict:<9} {r.max_deviation_m:>9.3f} {r.rms_deviation_m:>9.3f}"
        )
        if r.error:
            lines.append(f"  {r.vehicle}: {r.error}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Upload; 0 when every read-back is as sent (and, with --start, every start happened),
    1 when a check refused it, 3 when a vehicle failed it."""

    budget_s = parse_budget_s(args.timeout)
    for name in ("tolerance", "connect_timeout"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            flag = "--" + name.replace("_", "-")
            raise UserError(f"{flag}: must be a number > 0, got {value:g}")
    if args.acceptance is not None and not (math.isfinite(args.acceptance) and args.acceptance > 0):
        raise UserError(f"--acceptance: must be a number > 0, got {args.acceptance:g}")
    if args.drag is not None and not (math.isfinite(args.drag) and 0 <= args.drag <= 10):
        raise UserError(f"--drag: must be a number in [0, 10] 1/s, got {args.drag:g}")
    plan = load_plan(args.plan)
    specs = vehicle_specs(plan, args.connection, args.base_port)
    try:
        preflight_interlock(plan, force=args.force)
    except FlightRefused as exc:
        print(f"gcs upload: {exc}", file=sys.stderr)
        return EXIT_CHECK_FAILED

    if args.fence_action is not None and not args.fence:
        raise UserError("--fence-action: applies with --fence only")
    if args.end == "land":
        # the missions land clear of the keep-outs (gcs.flight.landing), or the upload is refused

        for line in landing_lines(plan):
            print(line, file=sys.stderr)

    interval = photo_interval(args)

    async def signed_upload() -> tuple[
        list[UploadRow], MissionConversion, FencePlan | None, float | None
    ]:
        async with signed_links(specs, args.signing_key) as links:
            return await upload_plan(
                plan,
                links,
                fence=args.fence,
                start=args.start,
                end=args.end,
                acceptance_m=args.acceptance,
                tolerance_m=args.tolerance,
                connect_timeout_s=args.connect_timeout,
                drag_per_s=args.drag,
                force=args.force,
                fence_action=args.fence_action,
                budget_s=budget_s,
                progress=print_progress,
                photo_interval_s=interval,
            )

    try:
        rows, conv, fp, t0_unix = asyncio.run(signed_upload())
    except (PreflightError, MissionRefused) as exc:  # refused before anything was stored
        print(f"gcs upload: {exc}", file=sys.stderr)
        return EXIT_CHECK_FAILED
    ok = all(r.verified for r in rows) and (not args.start or all(r.started for r in rows))
    if args.json:
        out: dict[str, Any] = {
            "ok": ok,
            "planned_robustness": plan.robustness,
            "mission_path_robustness": conv.straight_leg_robustness,
            "predicted_mission_robustness": conv.predicted_robustness,
            # inf (never seen finishing in the prediction) is not JSON: null
            "predicted_late_s": {
                k: (v if math.isfinite(v) else None) for k, v in conv.late_s.items()
            },
            "acceptance_m": conv.acceptance_m,
            "acceptance_auto": conv.acceptance_auto,
            "retimed": conv.retimed,
            "simplify_m": conv.simplify_m,
            "weakest": conv.weakest,
            "tolerance_s": conv.tolerance_s,
            "fence_inflate_m": None if fp is None else fp.inflate_m,
            "fence_notes": [] if fp is None else list(fp.notes),
            "fence_action": args.fence_action,
            # --start: the plan's t = 0, when every vehicle was released into its mission
            "t0_unix_s": t0_unix,
            "vehicles": [_row_json(r) for r in rows],
        }
        print(json.dumps(out))
    else:
        print(table(rows))
        how = "chosen" if conv.acceptance_auto else "given"
        print(
            f"acceptance radius {conv.acceptance_m:.2f} m ({how}); PX4 is predicted to fly "
            f"these missions with robustness {conv.predicted_robustness:+.4f}, "
            f"{timing_summary(conv.late_s)} (plan {plan.robustness:+.4f}; along the "
            f"straight legs on time {conv.straight_leg_robustness:+.4f}; weakest: "
            f"{conv.weakest})"
        )
        if conv.tolerance_warning():
            print(conv.tolerance_warning())
        for note in fp.notes if fp is not None else ():
            print(note)
        if args.fence_action is not None:
            print(f"fence: GF_ACTION set to {args.fence_action} on every vehicle")
        for r in rows:
            if args.start and r.start_detail:
                verdict = "started" if r.started else "NOT started"
                print(f"  {r.vehicle}: mission {verdict}: {r.start_detail}")
        if t0_unix is not None:
            when = datetime.fromtimestamp(t0_unix, UTC).isoformat(timespec="milliseconds")
            print(f"released together at {when}: the plan's t = 0 for every vehicle")
        if ok:
            print(
                "OK: every upload read back as sent"
                + (", every mission started" if args.start else "")
            )
        else:
            failed = [r.vehicle for r in rows if not r.verified or (args.start and not r.started)]
            print(f"FAILED: {len(failed)} vehicle(s): {', '.join(failed)}")
    # a transfer that gave up or read back wrong, a start PX4 refused: the vehicles failed
    return EXIT_OK if ok else EXIT_VEHICLE_FAILED


def parse_budget_s(text: str) -> float:
    """``--timeout``'s value in seconds: a finite number > 0, else one-line bad input."""

    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise UserError(f"--timeout: must be a number of seconds > 0, got {text!r}")
    return value


def progress_line(p: TransferProgress) -> str:
    """One line of a vehicle's transfer progress: vehicle, plan, attempt, step, elapsed."""
    what = {0: "mission", 1: "fence", 2: "rally"}.get(int(p.mission_type), str(p.mission_type))
    if p.step == "upload":
        body = f"uploading {p.items} items"
    elif p.step == "read-back":
        body = "reading back"
    elif p.step == "retry":
        body = f"{p.detail}; next step in {p.wait_s:.1f} s"
    elif p.step == "verified":
        body = f"{p.items} items read back as sent"
    else:
        body = f"FAILED: {p.detail}"
    return f"{p.vehicle}: {what} attempt {p.attempt}: {body} ({p.elapsed_s:.1f} s)"


def print_progress(p: TransferProgress) -> None:
    """:func:`progress_line` on standard error (standard output keeps the table or JSON)."""
    print(f"gcs upload: {progress_line(p)}", file=sys.stderr, flush=True)


def _row_json(r: UploadRow) -> dict[str, Any]:

    return asdict(r)
