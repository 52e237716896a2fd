"""Flying a plan file: the orchestration shared by ``gcs fly`` and ``gcs demo``.

:func:`fly_plan` does, in order:

1. connects every vehicle of the plan (:class:`mavlink.link.fleet.Fleet`; vehicle ``i`` at the
   URL given for it, by default ``udpin://0.0.0.0:{14540+i}``, the PX4 SITL ports);
2. records everything the vehicles send to ``flight.tlog`` (:class:`mavlink.tlog.TlogRecorder`)
   and MAVSDK's own log lines to ``mavsdk.log`` (:func:`mavlink.link.mavsdk_glue.mavsdk_log_file`)
   when a log directory is given (only MAVSDK's errors the user can act on show on stderr);
3. flies with the flight engine (:func:`mavlink.flight.fly`: checks, take-off, the arrival
   gate, one shared start, the safety monitor of the spec's always-clauses, the flown tracks)
   and the mode's driver: in **offboard** mode a :class:`mavlink.offboard.OffboardDriver`
   (setpoints against absolute deadlines), in **mission** mode a
   :class:`mavlink.mission.flight.MissionDriver` flying the plan's PX4 mission conversion
   (:func:`gcs.flight.mission.mission_driver`: converted against PX4's predicted flight,
   refused below epsilon, uploaded and read back before anything is armed);
4. shows progress while flying (:class:`gcs.flight.progress.FlightProgress`): per vehicle its mode,
   its distance to where the plan is at that instant, and the robustness of the clauses it
   takes part in *so far* (exact semantics of the flown prefix completed by the plan for the
   rest of the horizon, i.e. what the spec's value will be if the rest goes as planned);
5. on Ctrl-C (task cancellation) the flight's tasks end with it (structured in the link layer)
   and :meth:`mavlink.link.fleet.Fleet.flight` commands every vehicle
   to hold where it is (:func:`mavlink.monitor.safe_stop`), and reports the modes it then has;
6. writes the flown tracks (``flight.csv``, mission frame) and evaluates the flown data
   against the spec with the exact semantics (:func:`gcs.flight.evaluation.evaluate_flight`), next
   to the planned value, with per-vehicle tracking errors and the delay that best aligns
   flown and planned positions (the first thing to look at when flown robustness falls short).

It returns a :class:`gcs.flight.outcome.FlightOutcome` (told by :func:`gcs.flight.outcome.format_outcome`).

The pre-flight interlock (:func:`preflight_interlock`) re-runs ``gcs verify``'s checks
(:func:`gcs.commands.verify.verify_plan`) and refuses a plan that fails one.

Dry runs (:func:`gcs.flight.dryrun.mock_vehicles`) fly mock PX4 vehicles spawned on the ground below
the planned starts, exactly as against SITL (:mod:`gcs.flight.dryrun`).

Errors::

    FlightRefused(Exception)   a check before the flight failed (exit status 1): .check names it
    (bad input is gcs.errors.UserError, planner.planfile.PlanFileError or
     mavlink.errors.LinkError, e.g. an unreachable connection: exit status 2)
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import sys
import time
from collections.abc import AsyncIterator, Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from gcs.checks import verify_plan
from gcs.errors import GcsError, InputFileError, UserError
from gcs.flight.dryrun import free_udp_ports
from gcs.flight.evaluation import evaluate_flight, plan_formula, reads_heading
from gcs.flight.landing import landing_targets
from gcs.flight.mission import arrive_gate_m, mission_driver, mission_record
from gcs.flight.outcome import SEVERITY_NAMES, FlightMode, FlightOutcome
from gcs.flight.payload import CameraCommands, capture_spans, run_offboard_captures
from gcs.flight.progress import FlightProgress, PlanStarts
from gcs.flight.tuning import expected_error_m, margin_warnings, read_tuning
from gcs.plot.coverage import compute_coverage, coverage_figure
from mavlink.clock import WALL, Clock
from mavlink.errors import LinkError
from mavlink.flight import fly
from mavlink.link.camera import write_images_csv
from mavlink.link.fleet import Fleet
from mavlink.link.mavsdk_glue import mavsdk_log_file
from mavlink.link.signing import SigningProxy, load_key
from mavlink.link.urls import Scheme, default_url, parse_url
from mavlink.link.vehicle_status import VehicleSpec
from mavlink.monitor import SafetyMonitor
from mavlink.monitor_findings import always_clauses
from mavlink.offboard import OffboardDriver
from mavlink.offboard.setpoints import EndAction, OffboardConfig
from mavlink.tlog import TlogRecorder
from mavlink.tracks import track_from_rows, write_tracks_csv
from planner.frames import enu_to_geodetic

if TYPE_CHECKING:
    from gcs.checks import Check
    from gcs.flight.mission import MissionFlight
    from gcs.flight.missions import MissionConversion
    from gcs.flight.replan import FlightReplanner
    from gcs.flight.tuning import VehicleTuning
    from gcs.plot.coverage import CoverageReport
    from mavlink.flight import FlightDriver, FlightResult
    from mavlink.link.camera import CameraInfo, CapturedImage
    from mavlink.link.vehicle import Vehicle
    from mavlink.link.vehicle_status import VehicleStatus
    from mavlink.mission import CaptureSpan
    from mavlink.tracks import FlownTrack
    from planner.frames import GeodeticPoint
    from planner.planfile import Plan

__all__ = [
    "FlightRefused",
    "FlyOptions",
    "fly_plan",
    "preflight_interlock",
    "vehicle_specs",
]

#: Seconds allowed for every vehicle's first heartbeat.
DEFAULT_CONNECT_TIMEOUT_S = 10.0


class FlightRefused(GcsError):
    """A check before the flight failed; nothing was armed.

    Attributes:
        check: the name of the (first) failed check.
        summary: what failed, without the advice of the message.
    """

    def __init__(self, check: str, detail: str, summary: str = "") -> None:
        self.check = check
        self.summary = summary or detail
        super().__init__(detail)


@dataclass(frozen=True, slots=True)
class FlyOptions:
    """Settings of :func:`fly_plan`.

    Attributes:
        mode: offboard or mission.
        rate_hz: offboard setpoint rate (2 < rate <= 100).
        tolerance_m: refuse a vehicle farther than this from its planned start.
        end: what every vehicle does after the plan (hold, land, return).
        log_dir: write ``flight.tlog`` and ``flight.csv`` here (``None``: no files).
        connect_timeout_s: time allowed for every vehicle's first heartbeat.
        monitor: run the online safety monitor of the always-clauses.
        drag_per_s: the vehicles' drag per unit mass for the feed-forward (1/s); ``None``:
            the simulator's own (SIH_KDV / SIH_MASS) where the vehicle has it, else 0
            (:mod:`gcs.flight.tuning`).
        arrive_m: the arrival gate at the starts (m); ``None``: from the plan's margin
            (:func:`gcs.flight.mission.arrive_gate_m`).
        acceptance_m: mission mode's waypoint acceptance radius; ``None``: chosen
            (:func:`gcs.flight.missions.auto_acceptance_m`).
        force: fly missions whose predicted robustness is below epsilon.
        max_off_plan_m: offboard: hold every vehicle when one is farther than this from
            its plan (the monitor's tracking alarm; ``None``: never). Past the plan's margin
            (its robustness) a vehicle is warned about once, in flight and in the report.
        photo_interval_s: time between pictures where the plan faces an inspection target
            (:mod:`gcs.flight.payload`); 0: the camera is left alone.
        on_plan_start: called once with the plan's start on the fleet's clock (a dry run
            times its injected faults from it, :meth:`mavlink.mock.MockFleet.plan_started`).
        replanner: offboard: plan the rest when a vehicle leaves the flight (``gcs fly
            --replan``, :mod:`gcs.flight.replan`); None: a departure stops the flight.
    """

    mode: FlightMode = FlightMode.OFFBOARD
    rate_hz: float = 20.0
    tolerance_m: float = 1.0
    end: EndAction | None = None
    log_dir: Path | None = None
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S
    monitor: bool = True
    drag_per_s: float | None = None
    arrive_m: float | None = None
    acceptance_m: float | None = None
    force: bool = False
    max_off_plan_m: float | None = 3.0
    photo_interval_s: float = 1.0
    on_plan_start: Callable[[float], None] | None = None
    replanner: FlightReplanner | None = None


# ---------------------------------------------------------------------------- before flight


def preflight_interlock(plan: Plan, *, force: bool = False) -> tuple[Check, ...]:
    """``gcs verify``'s checks of ``plan``; refuse the flight if one fails (unless ``force``).

    Returns:
        Every check (failed ones included when ``force``).

    Raises:
        FlightRefused: naming the first failed check, its value and bound, and how many fail.
    """

    checks = tuple(verify_plan(plan))
    failed = [c for c in checks if not c.ok]
    if failed and not force:
        c = failed[0]
        detail = f" ({c.detail})" if c.detail else ""
        summary = (
            f"the plan fails verification: {c.name}: {c.value:.4g} "
            f"(bound {c.bound:.4g}){detail}; {len(failed)} of {len(checks)} checks fail"
        )
        raise FlightRefused(
            c.name, f"refused: {summary} (gcs verify lists them; --force flies anyway)", summary
        )
    return checks


def vehicle_specs(
    plan: Plan, urls: Sequence[str] | None = None, base_port: int = 14540
) -> tuple[VehicleSpec, ...]:
    """How to reach each vehicle of ``plan``, in plan order.

    Vehicle ``i`` uses ``urls[i]`` or, with no URLs, ``udpin://0.0.0.0:{base_port+i}`` (PX4
    SITL: 14540 + i); its system id is the plan's (``i + 1`` for plans written by ``gcs plan``).

    Raises:
        UserError: a number of URLs other than the number of vehicles.
        mavlink.errors.UrlError: a malformed URL (names it and the vehicle).
    """

    n = len(plan.vehicles)
    if urls and len(urls) != n:
        raise UserError(
            f"--connection: {len(urls)} URL(s) given for {n} vehicle(s) "
            f"({', '.join(v.name for v in plan.vehicles)}); give one per vehicle in plan order, "
            "or none for the PX4 SITL defaults udpin://0.0.0.0:14540+i"
        )
    out = []
    for i, v in enumerate(plan.vehicles):
        url = urls[i] if urls else default_url(i, base_port)
        parse_url(url, vehicle=v.name)
        out.append(VehicleSpec(v.name, url, v.sysid))
    return tuple(out)


@contextlib.asynccontextmanager
async def signed_links(
    specs: Sequence[VehicleSpec], key_file: str | None
) -> AsyncIterator[tuple[VehicleSpec, ...]]:
    """Route every vehicle through a MAVLink 2 signing proxy when ``key_file`` is given.

    MAVSDK has no signing API: for each ``udpin://HOST:PORT`` connection a
    :class:`mavlink.link.signing.SigningProxy` takes the vehicle's traffic on ``HOST:PORT``
    (verifying its signatures), signs what the GCS sends, and MAVSDK is pointed at the proxy on
    a free loopback port. Yields the specs to connect with (the same specs without a key).

    Raises:
        UserError: a connection other than ``udpin://`` (the vehicle must send to the GCS).
        mavlink.link.signing.SigningError: a bad key file.
    """
    if key_file is None:
        yield tuple(specs)
        return

    key = load_key(key_file)
    proxies: list[SigningProxy] = []
    try:
        signed = []
        inner_ports = free_udp_ports(len(specs))
        for spec, inner in zip(specs, inner_ports, strict=True):
            url = parse_url(spec.url, vehicle=spec.name)
            if url.scheme is not Scheme.UDPIN:
                raise UserError(
                    f"--signing-key: vehicle {spec.name}: signing works with udpin:// "
                    f"connections only, got {spec.url}"
                )
            proxy = SigningProxy(key, url.port, inner, host=url.host)
            await proxy.start()
            proxies.append(proxy)
            signed.append(VehicleSpec(spec.name, f"udpin://127.0.0.1:{inner}", spec.sysid))
        yield tuple(signed)
    finally:
        for proxy in proxies:
            proxy.close()


# ---------------------------------------------------------------------------- the flight


def _make_log_dir(log_dir: Path | None) -> None:
    if log_dir is None:
        return
    try:
        log_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputFileError(f"--log {log_dir}: cannot create: {exc.strerror or exc}") from None


#: MAVSDK's own log lines of a flight, in its log directory (:func:`_library_log`).
MAVSDK_LOG_NAME = "mavsdk.log"


@contextlib.asynccontextmanager
async def _library_log(log_dir: Path | None, files: dict[str, Path]) -> AsyncIterator[None]:
    """MAVSDK's log lines to ``log_dir/mavsdk.log`` for the flight (listed in ``files``);
    without a directory they are not shown, but for the errors the user can act on
    (:mod:`mavlink.link.mavsdk_glue`)."""
    if log_dir is None:
        yield
        return

    path = log_dir / MAVSDK_LOG_NAME
    with contextlib.ExitStack() as scope:
        try:
            files["mavsdk_log"] = scope.enter_context(mavsdk_log_file(path))
        except OSError as exc:
            raise InputFileError(
                f"--log {log_dir}: cannot write {path.name}: {exc.strerror or exc}"
            ) from None
        yield


def _tracks_from_rows(
    rows: Mapping[str, np.ndarray],
    t0: Mapping[str, float],
    mission_origin: GeodeticPoint,
    origins: Mapping[str, GeodeticPoint],
) -> dict[str, FlownTrack]:
    """FlownTracks from :meth:`Vehicle.stop_track` rows ``(t, n, e, d, vn, ve, vd, yaw)``."""

    return {
        name: track_from_rows(name, r, t0[name], mission_origin, origins[name])
        for name, r in rows.items()
        if r.shape[0] > 0 and name in t0
    }


#: The PX4 mode each end action leads to.
_END_MODE = {"hold": "AUTO.LOITER", "land": "AUTO.LAND", "return": "AUTO.RTL"}


def cfg_end(opts: FlyOptions) -> str:
    """The end action's name (``hold`` by default)."""
    return "hold" if opts.end is None else str(opts.end.value)


async def _show_mode(
    fleet: Fleet, label: str, skip: Mapping[str, str], timeout_s: float = 3.0
) -> None:
    """Wait (bounded) until the vehicles report ``label``: PX4 heartbeats come at 1 Hz.

    A vehicle that does not get there in time is reported by its final mode, not an error.
    """

    async def one(v: Vehicle) -> None:
        with contextlib.suppress(LinkError):
            await v.wait_for(
                lambda s: s.mode is not None and s.mode.label == label, label, timeout_s=timeout_s
            )

    await asyncio.gather(*(one(v) for v in fleet if v.name not in skip))


def _offboard_driver(
    plan: Plan, opts: FlyOptions, tuning: Mapping[str, VehicleTuning]
) -> OffboardDriver:
    """Offboard mode's driver for the flight engine."""

    cfg = OffboardConfig(
        rate_hz=opts.rate_hz,
        start_tolerance_m=opts.tolerance_m,
        arrive_m=opts.arrive_m or arrive_gate_m(plan),
        end_action=opts.end or EndAction.HOLD,
        drag_per_s={n: t.drag_per_s for n, t in tuning.items()},
    )
    if cfg.end_action is EndAction.LAND:
        land_at = {}
        for name, point in landing_targets(plan).items():
            lat, lon, alt = (float(np.ravel(x)[0]) for x in enu_to_geodetic(point, plan.origin))
            land_at[name] = (lat, lon, alt)
        cfg = dataclasses.replace(cfg, land_at=land_at)
    trajs = {v.name: v.trajectory for v in plan.vehicles}
    return OffboardDriver(trajs, plan.origin, cfg)


def _monitor(
    plan: Plan,
    opts: FlyOptions,
    driver: FlightDriver,
    started: Callable[[float], None],
    note: Callable[[str], None],
) -> SafetyMonitor:
    """The safety monitor of the spec's always-clauses for ``driver``'s flight: where the
    vehicles fly the plan's trajectories (offboard), the tracking alarm too (warn past the
    plan's margin, hold past ``max_off_plan_m``); where the plan runs on board (missions), a
    lost link is ridden out."""

    names = [v.name for v in plan.vehicles]
    on = opts.monitor
    tracked = on and driver.plans is not None
    return SafetyMonitor(
        always_clauses(plan_formula(plan), names, exclude=reads_heading) if on else (),
        horizon_s=0.5 if on else 0.0,
        on_start=started,
        warn_off_plan_m=plan.robustness if tracked and plan.robustness > 0 else None,
        max_off_plan_m=opts.max_off_plan_m if tracked else None,
        ride_out_link_loss=driver.on_board,
        on_warning=note,
    )


async def fly_plan(
    plan: Plan,
    specs: Sequence[VehicleSpec],
    options: FlyOptions | None = None,
    *,
    progress: FlightProgress | None = None,
    clock: Clock = WALL,
) -> FlightOutcome:
    """Connect, fly, record and evaluate (module docstring); Ctrl-C holds every vehicle.

    Args:
        plan: a loaded plan (already through :func:`preflight_interlock`).
        specs: how to reach each vehicle (:func:`vehicle_specs`), plan order.
        options: :class:`FlyOptions`.
        progress: live view to run during the flight (``None``: silent).
        clock: the vehicles' clock (:mod:`mavlink.clock`): the wall clock, or a dry run's
            simulated time (:attr:`gcs.flight.dryrun.DryRun.clock`).

    Returns:
        :class:`FlightOutcome`; a safety stop or an interruption is an outcome, not an error.

    Raises:
        mavlink.errors.ConnectTimeoutError: a vehicle never answered (names its URL).
        mavlink.errors.PreflightError: a vehicle too far from its start / cannot reach it.
        mavlink.errors.LinkError: other link failures before the flight.
    """

    opts = options or FlyOptions()
    _make_log_dir(opts.log_dir)
    t_start = time.monotonic()
    files: dict[str, Path] = {}
    starts = PlanStarts()
    async with (
        _library_log(opts.log_dir, files),
        Fleet(specs, connect_timeout_s=opts.connect_timeout_s, clock=clock) as fleet,
    ):
        origins = await fleet.origins()
        connect_s = time.monotonic() - t_start
        t_connected = clock.monotonic()
        recorder = None
        if opts.log_dir is not None:
            files["tlog"] = opts.log_dir / "flight.tlog"
            recorder = TlogRecorder(fleet, files["tlog"])
            recorder.start()
        stop_view = asyncio.Event()
        view = (
            asyncio.create_task(progress.run(fleet, starts, origins, stop_view))
            if progress is not None
            else None
        )
        interrupted = False
        result: FlightResult | None = None
        conv: MissionConversion | None = None
        end_failures: dict[str, str] = {}
        for v in fleet:
            v.start_track()
        names = [v.name for v in plan.vehicles]
        tuning = await read_tuning(fleet, names, opts.drag_per_s)
        # offboard feeds the drag forward; a mission's timing is judged by its prediction
        warnings = margin_warnings(plan, expected_error_m(plan, tuning, fed_forward=True))
        if progress is not None:
            for w in warnings:
                print(w, file=progress.stream, flush=True)
        guard = None

        def note(line: str) -> None:
            if progress is not None:
                progress.note(line)
            else:
                print(line, file=sys.stderr, flush=True)

        spans = capture_spans(plan, opts.photo_interval_s)
        camera = CameraCommands() if opts.mode is FlightMode.OFFBOARD else None
        infos = await _cameras(fleet, [n for n, s in spans.items() if s], note)
        start: asyncio.Future[float] = asyncio.get_running_loop().create_future()

        def started(t0_monotonic_s: float) -> None:
            """The shared start time, for the progress view and the camera's clock."""
            starts.t0_monotonic_s.update(dict.fromkeys(names, t0_monotonic_s))
            if not start.done():
                if opts.on_plan_start is not None:
                    opts.on_plan_start(t0_monotonic_s)
                if opts.replanner is not None:
                    opts.replanner.plan_started(t0_monotonic_s)
                start.set_result(t0_monotonic_s)

        try:
            # the flight's own tasks end with it; leaving it abnormally holds every vehicle
            async with fleet.flight() as guard:
                driver: FlightDriver
                if opts.mode is FlightMode.OFFBOARD:
                    driver = _offboard_driver(plan, opts, tuning)
                else:
                    driver, conv = await mission_driver(fleet, plan, opts, tuning, spans, note)
                monitor = _monitor(plan, opts, driver, started, note)
                # the ground station's camera commands where no mission carries them
                shots = (
                    asyncio.create_task(run_offboard_captures(fleet, spans, start, note, camera))
                    if camera is not None and any(spans.values())
                    else None
                )
                try:
                    result = await fly(
                        fleet, driver, plan.origin, monitor, replanner=opts.replanner
                    )
                finally:
                    if shots is not None:
                        shots.cancel()
                        with contextlib.suppress(asyncio.CancelledError):
                            await shots
        except asyncio.CancelledError:
            # Ctrl-C: asyncio.run cancelled us, and every vehicle was commanded to hold on the
            # way out of the flight. Take the cancellation back to report.
            task = asyncio.current_task()
            if task is not None:
                task.uncancel()
            interrupted = True
            end_failures = dict(guard.failures) if guard is not None else {}
        finally:
            accuracy = {v.name: v.track_accuracy_m for v in fleet}
            said = _vehicle_messages(fleet, t_connected, starts)
            rows = {v.name: v.stop_track() for v in fleet}
            images = {
                v.name: tuple(v.images(starts.t0_monotonic_s[v.name]))
                for v in fleet
                if v.name in starts.t0_monotonic_s
            }
            stop_view.set()
            if view is not None:
                await view
            if progress is not None:
                progress.close()
            tlog = recorder.stop() if recorder is not None else None
        safety_event = result.safety_event if result is not None else None
        if interrupted or safety_event is not None:
            await _show_mode(fleet, "AUTO.LOITER", end_failures)
        elif result is not None:
            await _show_mode(fleet, _END_MODE[cfg_end(opts)], end_failures)
        final_modes = {s.name: _final_mode(s) for s in fleet.statuses()}
    flight_s = clock.monotonic() - t_connected
    t0 = dict(starts.t0_monotonic_s)
    if result is not None:
        # the engine recorded the tracks itself (from just before the shared start)
        tracks = dict(result.tracks)
    else:
        tracks = _tracks_from_rows(rows, t0, plan.origin, origins)
    if opts.log_dir is not None:
        files["csv"] = write_tracks_csv(opts.log_dir / "flight.csv", tracks)
    judged = plan
    replanner = opts.replanner
    if replanner is not None and replanner.judged_plan is not None:
        # judged on the spec as amended, on the vehicles that flew on
        judged = replanner.judged_plan
        tracks_judged = {v.name: tracks[v.name] for v in judged.vehicles if v.name in tracks}
    else:
        tracks_judged = tracks
    evaluation = evaluate_flight(judged, tracks_judged) if tracks_judged else None
    mission = mission_record(conv, result) if conv is not None and result is not None else None
    coverage = _coverage(plan, images, spans, mission, infos, opts.log_dir, files)
    lower = None
    if evaluation is not None and evaluation.flown_robustness is not None:
        errs = [math.hypot(*a) for a in accuracy.values() if a is not None]
        if len(errs) == len(accuracy):
            # every predicate moves by at most its vehicles' position error (a distance
            # between two vehicles by both): flown - 2 * worst 3-D accuracy
            lower = evaluation.flown_robustness - 2.0 * max(errs)
    t0_unix = min(t0.values()) + clock.unix_offset() if t0 else None
    if result is not None:
        end_failures = dict(result.end_failures)
    return FlightOutcome(
        mode=opts.mode,
        completed=result is not None and result.completed and not interrupted,
        interrupted=interrupted,
        connect_s=connect_s,
        flight_s=flight_s,
        t0_unix_s=t0_unix,
        tracks=tracks,
        evaluation=evaluation,
        stats=dict(result.stats) if result is not None else {},
        missions=dict(result.runs) if result is not None else {},
        safety_event=safety_event,
        monitor=result.monitor if result is not None else None,
        end_failures=end_failures,
        final_modes=final_modes,
        tlog=tlog,
        files=files,
        mission=mission,
        tuning=tuning,
        warnings=tuple(warnings),
        accuracy_m={k: v for k, v in accuracy.items() if v is not None},
        flown_lower_bound=lower,
        images=images,
        coverage=coverage,
        camera=camera if camera is not None and any(spans.values()) else None,
        vehicle_messages=said,
        replans=tuple(replanner.records) if replanner is not None else (),
        judged_spec=judged.spec if judged is not plan else None,
    )


def _vehicle_messages(
    fleet: Fleet, since_s: float, starts: PlanStarts
) -> dict[str, tuple[tuple[float | None, str, str], ...]]:
    """Per vehicle the warnings it sent since ``since_s`` (STATUSTEXT severity WARNING or
    worse), as (plan time, negative before the start and None if the plan never started,
    severity name, text)."""
    out = {}
    for v in fleet:
        said = [
            (starts.plan_time(v.name, t), SEVERITY_NAMES[sev], text)
            for t, sev, text in v.timed_statustexts(since_s)
            if sev < len(SEVERITY_NAMES)
        ]
        if said:
            out[v.name] = tuple(said)
    return out


def _final_mode(st: VehicleStatus) -> str:
    """A vehicle's mode at the end, as last heard; a vehicle not heard for longer than
    :data:`SILENT_S` is reported as such, not by a mode it may have left since."""
    mode = st.mode.label if st.mode is not None else str(st.custom_mode)
    if not st.connected or (st.heartbeat_age_s is not None and st.heartbeat_age_s > SILENT_S):
        age = "" if st.heartbeat_age_s is None else f" {st.heartbeat_age_s:.0f} s ago"
        return f"unknown (link lost; {mode} when last heard{age})"
    return mode


#: A vehicle without a heartbeat for this long (s; PX4 sends one a second) is reported as
#: unheard at the end of a flight.
SILENT_S = 3.0


async def _cameras(
    fleet: Fleet, names: Sequence[str], note: Callable[[str], None], wait_s: float = 2.5
) -> dict[str, CameraInfo]:
    """The optics of the cameras of vehicles ``names`` (those the plan has pictures for):
    waits up to ``wait_s`` for each camera's HEARTBEAT (1 Hz), asks for CAMERA_INFORMATION,
    and says which vehicle has no camera."""
    if not names:
        return {}
    vehicles = [fleet[n] for n in names]
    clock = fleet.clock
    deadline = clock.monotonic() + wait_s
    while clock.monotonic() < deadline and any(v.camera_component is None for v in vehicles):
        await clock.sleep(0.1)
    infos = {}
    for v, info in zip(
        vehicles,
        await asyncio.gather(*(v.request_camera_information() for v in vehicles)),
        strict=True,
    ):
        if v.camera_component is None:
            note(f"{v.name}: no camera heard (no MAVLink camera HEARTBEAT): no pictures")
        elif info is not None:
            infos[v.name] = info
    return infos


def _coverage(
    plan: Plan,
    images: Mapping[str, Sequence[CapturedImage]],
    spans: Mapping[str, Sequence[CaptureSpan]],
    mission: MissionFlight | None,
    infos: Mapping[str, CameraInfo],
    log_dir: Path | None,
    files: dict[str, Path],
) -> CoverageReport | None:
    """The flight's coverage report (``None`` when the plan pictures nothing), with the image
    log and the coverage figure written to ``log_dir``."""

    if log_dir is not None and any(images.values()):
        files["images"] = write_images_csv(
            log_dir / "images.csv",
            sorted((i for ims in images.values() for i in ims), key=lambda i: i.t_s),
        )
    if not any(spans.values()):
        return None
    planned: dict[str, int] = {}
    if mission is not None:
        for m in mission.conversion.missions.values():
            for c in m.captures:
                planned[c.span.target] = planned.get(c.span.target, 0) + c.images
    else:
        for todo in spans.values():
            for span in todo:
                planned[span.target] = planned.get(span.target, 0) + span.pictures()
    report = compute_coverage(plan, images, planned=planned, cameras=infos)
    if log_dir is not None:
        files["coverage"] = coverage_figure(plan, report, images, log_dir / "coverage.png")
    return report
