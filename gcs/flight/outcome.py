"""What a flight did and how it is told: :class:`FlightOutcome` (returned by
:func:`gcs.flight.fly_plan`), the operator's end-of-flight summary (:func:`format_outcome`) and
the same as JSON (:func:`outcome_json`, ``gcs fly --json``).

A room of its own because the outcome outlives the flight: ``gcs fly`` prints it, ``gcs demo``
and the report (:mod:`gcs.report`) read it, and none of them needs the flight's machinery.
:class:`FlightMode` lives here, with the outcome that records it, so that neither this module
nor its readers import :mod:`gcs.flight`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gcs.flight.tuning import LAG_NOISE_S, drag_from_lag
from gcs.plot.coverage import coverage_json, coverage_lines
from mavlink.offboard.stream import STATS_HEADER

if TYPE_CHECKING:
    from gcs.flight.evaluation import FlownEvaluation
    from gcs.flight.mission import MissionFlight
    from gcs.flight.payload import CameraCommands
    from gcs.flight.replan import ReplanRecord
    from gcs.flight.tuning import VehicleTuning
    from gcs.plot.coverage import CoverageReport
    from mavlink.link.camera import CapturedImage
    from mavlink.mission import MissionRun
    from mavlink.monitor_findings import MonitorStats, SafetyEvent
    from mavlink.offboard.stream import StreamStats
    from mavlink.tlog import TlogStats
    from mavlink.tracks import FlownTrack
    from planner.planfile import Plan

__all__ = ["SEVERITY_NAMES", "FlightMode", "FlightOutcome", "format_outcome", "outcome_json"]


class FlightMode(Enum):
    """How the plan is flown."""

    OFFBOARD = "offboard"  # setpoint streaming of the exact trajectories
    MISSION = "mission"  # the PX4 mission conversion (straight legs, timed by speed changes)


@dataclass(frozen=True, slots=True, eq=False)
class FlightOutcome:
    """What :func:`gcs.flight.fly_plan` did.

    Attributes:
        mode: offboard or mission.
        completed: the whole plan was flown, no safety stop, no failed end action.
        interrupted: Ctrl-C stopped it (every vehicle was commanded to hold).
        connect_s: wall time to connect every vehicle and learn its origin.
        flight_s: wall time from then to the end action (take-off, flight, end).
        t0_unix_s: Unix time of the plan's start (offboard; the earliest vehicle in mission mode).
        tracks: flown tracks in the mission frame, times from each vehicle's plan start.
        evaluation: flown vs planned robustness (``None`` when no track was recorded).
        stats: offboard stream statistics per vehicle (empty in mission mode).
        missions: mission runs per vehicle (mission mode).
        safety_event: what the safety monitor stopped, if it did.
        monitor: what the safety monitor did (``None``: it did not run).
        end_failures: vehicles whose end action (or hold on Ctrl-C) failed, with the reason.
        final_modes: each vehicle's mode label at the end.
        tlog: the recording's statistics (with a log directory).
        files: what was written, by kind (``tlog``, ``csv``).
        mission: mission mode's conversion, prediction, clock skews and lateness.
        tuning: each vehicle's tracking model (drag fed forward, gains, estimator accuracy).
        warnings: margin warnings shown before the flight.
        accuracy_m: per vehicle the worst (horizontal, vertical) position accuracy its
            estimator reported during the flight (ESTIMATOR_STATUS, 1-sigma).
        flown_lower_bound: flown robustness minus twice the worst 3-D accuracy: what the
            spec is worth at least if every estimate was within its reported accuracy of
            the truth (flown robustness is computed on the estimates).
        images: the pictures each vehicle's camera reported (CAMERA_IMAGE_CAPTURED).
        coverage: what they cover of the inspection targets (``None``: the plan has none).
        camera: offboard: the camera and gimbal commands sent and refused (``None``:
            none sent by the ground station; a mission carries them as items).
        vehicle_messages: per vehicle the warnings it sent during the flight (STATUSTEXT of
            severity WARNING or worse: "Critical battery", "Failsafe activated"), as (plan
            time, negative before the start and ``None`` if the plan never started,
            severity name, text).
        replans: the replans of ``gcs fly --replan``, in order (the last may be the one that
            found no plan, and stopped the flight).
        judged_spec: the spec the flight was judged on when a replan amended it (the
            evaluation is of it, on the vehicles that flew on), else None.
    """

    mode: FlightMode
    completed: bool
    interrupted: bool
    connect_s: float
    flight_s: float
    t0_unix_s: float | None
    tracks: dict[str, FlownTrack]
    evaluation: FlownEvaluation | None
    stats: dict[str, StreamStats] = field(default_factory=dict)
    missions: dict[str, MissionRun] = field(default_factory=dict)
    safety_event: SafetyEvent | None = None
    monitor: MonitorStats | None = None
    end_failures: dict[str, str] = field(default_factory=dict)
    final_modes: dict[str, str] = field(default_factory=dict)
    tlog: TlogStats | None = None
    files: dict[str, Path] = field(default_factory=dict)
    mission: MissionFlight | None = None
    tuning: dict[str, VehicleTuning] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    accuracy_m: dict[str, tuple[float, float]] = field(default_factory=dict)
    flown_lower_bound: float | None = None
    images: dict[str, tuple[CapturedImage, ...]] = field(default_factory=dict)
    coverage: CoverageReport | None = None
    camera: CameraCommands | None = None
    vehicle_messages: dict[str, tuple[tuple[float | None, str, str], ...]] = field(
        default_factory=dict
    )
    replans: tuple[ReplanRecord, ...] = ()
    judged_spec: str | None = None


#: MAV_SEVERITY names (0 .. 4: the warnings a flight records).
SEVERITY_NAMES = ("EMERGENCY", "ALERT", "CRITICAL", "ERROR", "WARNING")


def format_outcome(plan: Plan, outcome: FlightOutcome) -> str:
    """The end-of-flight summary for the operator (several lines)."""

    lines = []
    if outcome.interrupted:
        lines.append("interrupted: every vehicle was commanded to hold")
    elif outcome.safety_event is not None:
        lines.append(f"safety stop: {outcome.safety_event.describe()}")
    if outcome.monitor is not None and outcome.monitor.stale:
        lines.append(f"monitor: {outcome.monitor.describe_stale()}")
    if outcome.monitor is not None and outcome.monitor.unheard:
        lines.append(f"monitor: {outcome.monitor.describe_unheard()}")
    verdict = "completed" if outcome.completed else "NOT completed"
    lines.append(
        f"flight {verdict} in {outcome.flight_s:.1f} s ({outcome.mode.value}, "
        f"{len(plan.vehicles)} vehicle(s)); modes now: "
        + ", ".join(f"{k} {m}" for k, m in outcome.final_modes.items())
    )
    for name, why in outcome.end_failures.items():
        lines.append(f"  {name}: end action failed: {why}")
    for name, said in outcome.vehicle_messages.items():
        for t, severity, text in said:
            when = "before the plan started" if t is None else f"at t={t:.2f} s"
            lines.append(f"  {name} said {when}: {text!r} ({severity})")
    lines += _replan_lines(outcome)
    if plan.assurance is not None:
        lines.append(plan.assurance.summary())
    ev = outcome.evaluation
    if ev is not None:
        flown = "n/a" if ev.flown_robustness is None else f"{ev.flown_robustness:+.4f}"
        lines.append(
            f"robustness (exact, dt {ev.dt_s:g} s): planned {ev.planned_robustness:+.4f}, "
            f"flown {flown}" + (f" ({ev.coverage_problem})" if ev.coverage_problem else "")
        )
        if outcome.flown_lower_bound is not None:
            acc = max(outcome.accuracy_m.values(), key=lambda a: math.hypot(*a))
            lines.append(
                f"  flown robustness is on the vehicles' estimates; at least "
                f"{outcome.flown_lower_bound:+.4f} if each was within the accuracy its "
                f"estimator reported (worst {acc[0]:.2f} m horizontal, {acc[1]:.2f} m vertical)"
            )
        lines += [f"  {line}" for line in ev.describe_gaps()]
        w = ev.weakest_flown
        if w is not None:
            lines.append(
                f"  weakest flown clause {w.flown:+.4f} (planned {w.planned:+.4f}): {w.text}"
            )
        for te in ev.tracking:
            over = (
                f" (WARNING: more than the plan's margin {plan.robustness:.3f} m)"
                if plan.robustness > 0 and te.max_m > plan.robustness
                else ""
            )
            lines.append(
                f"  {te.vehicle}: tracking error max {te.max_m:.3f} m at t {te.t_at_max_s:.2f} s"
                f"{over}, rms {te.rms_m:.3f} m; best-fit delay {te.lag_s:+.2f} s (rms "
                f"{te.rms_at_lag_m:.3f} m)"
            )
    if outcome.stats:
        lines.append("setpoint stream (lateness of each send after its deadline):")
        lines.append("  " + STATS_HEADER)
        lines += ["  " + s.row() for s in outcome.stats.values()]
    lines += _tuning_lines(outcome)
    m = outcome.mission
    if m is not None:
        c = m.conversion
        how = "chosen" if c.acceptance_auto else "given"
        lines.append(
            f"missions: acceptance radius {c.acceptance_m:.2f} m ({how}), "
            + (
                f"waypoints within {c.simplify_m:.2f} m of the plan, "
                if c.simplify_m > 0
                else "a waypoint per segment, "
            )
            + f"legs {'and holds re-timed' if c.retimed else 'at their average speeds'}; "
            f"robustness predicted {c.predicted_robustness:+.4f} (straight legs "
            f"{c.straight_leg_robustness:+.4f}; {c.iterations} predictions)"
        )
        least = c.least_tolerant()
        if least is not None:
            lines.append(
                f"  timing error tolerated on the prediction: {least[1]:.2f} s at the least "
                f"({least[0]})"
            )
    for name, run in outcome.missions.items():
        extra = ""
        if m is not None:
            late = m.late_s.get(name, math.inf)
            dep = m.departure_skew_s.get(name)
            extra = (
                f", {'+' if late >= 0 else ''}{late:.1f} s against the plan"
                if math.isfinite(late)
                else ""
            )
            extra += f"; start skew {m.start_skew_s.get(name, 0.0) * 1000:+.0f} ms"
            if dep is not None:
                extra += f", left the start waypoint {dep:+.2f} s off the prediction"
        items = len(m.conversion.missions[name].items) if m is not None else None
        lines.append(
            f"  {name}: mission {'finished' if run.finished else 'NOT finished'} in "
            f"{run.duration_s:.1f} s{extra}; "
            + (f"at item {run.current[-1][0]} of {items}" if run.current and items else "")
        )
    if outcome.camera is not None:
        for name in outcome.camera.no_camera:
            lines.append(f"  {name}: no camera heard: no pictures")
        for refused in outcome.camera.refused.values():
            lines += [f"  camera command refused: {r}" for r in refused]
    if outcome.coverage is not None:
        lines += coverage_lines(outcome.coverage)
    if outcome.tlog is not None:
        lines.append(f"telemetry: {outcome.tlog.path} ({outcome.tlog.messages} messages)")
    if "csv" in outcome.files:
        lines.append(f"tracks: {outcome.files['csv']}")
    if "images" in outcome.files:
        lines.append(f"pictures: {outcome.files['images']}")
    if "coverage" in outcome.files:
        lines.append(f"coverage figure: {outcome.files['coverage']}")
    return "\n".join(lines)


def _replan_lines(outcome: FlightOutcome) -> list[str]:
    """What each replan did, and what the flight is judged on."""
    lines = []
    for r in outcome.replans:
        head = (
            f"replan after {r.event}: switch at t = {r.switch_s:g} s, solved in {r.solve_s:.2f} s"
        )
        if r.success:
            lines.append(f"{head}, robustness {r.robustness:+.4f} on what was left; flown")
        else:
            lines.append(f"{head}; NOT flown: {r.reason}")
        for what, texts in r.fates():
            lines += [f"  {what}: {t}" for t in texts]
    if outcome.judged_spec is not None:
        lines.append("the flight is judged on the spec as amended by the last replan")
    return lines


def _tuning_lines(outcome: FlightOutcome) -> list[str]:
    """Drag fed forward per vehicle, the lag it still showed, and the drag to set."""

    ev = outcome.evaluation
    lags = {t.vehicle: t.lag_s for t in ev.tracking} if ev is not None else {}
    lines = []
    for name, tu in outcome.tuning.items():
        lag = lags.get(name, math.nan)
        acc = f", estimator accuracy {tu.accuracy_m:.2f} m" if tu.accuracy_m is not None else ""
        how = "fed forward" if outcome.mode is FlightMode.OFFBOARD else "in the prediction"
        text = f"  {name}: drag {tu.drag_per_s:.2f} /s {how} ({tu.drag_source}){acc}"
        if math.isfinite(lag) and outcome.mode is FlightMode.OFFBOARD:
            c = drag_from_lag(lag, tu)
            text += f"; flown lag {lag:+.2f} s -> drag {c:.2f} /s"
            if abs(lag) > LAG_NOISE_S:
                text += f" (set --drag {c:.2f})"
        lines.append(text)
    return lines


def outcome_json(plan: Plan, outcome: FlightOutcome) -> dict[str, Any]:
    """The outcome as a JSON-ready dict (``gcs fly --json``)."""
    ev = outcome.evaluation

    def num(x: float | None) -> float | None:
        return None if x is None or not math.isfinite(x) else float(x)

    return {
        "mode": outcome.mode.value,
        "assurance": None if plan.assurance is None else plan.assurance.to_json(),
        "completed": outcome.completed,
        "interrupted": outcome.interrupted,
        "connect_s": outcome.connect_s,
        "flight_s": outcome.flight_s,
        "t0_unix_s": outcome.t0_unix_s,
        "safety_event": None if outcome.safety_event is None else outcome.safety_event.describe(),
        "vehicle_messages": {
            name: [{"t_s": t, "severity": sev, "text": text} for t, sev, text in said]
            for name, said in outcome.vehicle_messages.items()
        },
        "monitor": None if outcome.monitor is None else outcome.monitor.as_json(),
        "replans": [r.to_json() for r in outcome.replans],
        "judged_spec": outcome.judged_spec,
        "decision_latency_s": (
            None if outcome.safety_event is None else outcome.safety_event.latency_s
        ),
        "end_failures": outcome.end_failures,
        "final_modes": outcome.final_modes,
        "planned_robustness": None if ev is None else num(ev.planned_robustness),
        "flown_robustness": None if ev is None else num(ev.flown_robustness),
        "coverage_problem": None if ev is None else ev.coverage_problem or None,
        "telemetry_gaps": {}
        if ev is None
        else {n: [list(g) for g in spans] for n, spans in ev.gaps.items()},
        "clauses": []
        if ev is None
        else [
            {"text": c.text, "planned": num(c.planned), "flown": num(c.flown)} for c in ev.clauses
        ],
        "tracking": []
        if ev is None
        else [
            {
                "vehicle": t.vehicle,
                "samples": t.samples,
                "max_m": num(t.max_m),
                "rms_m": num(t.rms_m),
                "lag_s": num(t.lag_s),
                "rms_at_lag_m": num(t.rms_at_lag_m),
            }
            for t in ev.tracking
        ],
        "stream": {
            name: {
                "sent": s.sent,
                "skipped": s.skipped,
                "failed": s.failed,
                "late": s.late,
                "mean_lateness_s": num(s.mean_lateness_s),
                "p99_lateness_s": num(s.p99_lateness_s),
                "max_lateness_s": num(s.max_lateness_s),
                "rate_hz": s.rate_hz,
            }
            for name, s in outcome.stats.items()
        },
        "missions": {
            name: {
                "finished": r.finished,
                "duration_s": r.duration_s,
                "reached": len(r.reached),
                "late_s": None if outcome.mission is None else num(outcome.mission.late_s[name]),
                "start_skew_s": None
                if outcome.mission is None
                else num(outcome.mission.start_skew_s[name]),
                "departure_skew_s": None
                if outcome.mission is None
                else num(outcome.mission.departure_skew_s[name]),
            }
            for name, r in outcome.missions.items()
        },
        "mission_prediction": None
        if outcome.mission is None
        else {
            "acceptance_m": outcome.mission.conversion.acceptance_m,
            "acceptance_auto": outcome.mission.conversion.acceptance_auto,
            "retimed": outcome.mission.conversion.retimed,
            "simplify_m": outcome.mission.conversion.simplify_m,
            "predictions": outcome.mission.conversion.iterations,
            "weakest": outcome.mission.conversion.weakest,
            "tolerance_s": outcome.mission.conversion.tolerance_s,
            "predicted_robustness": num(outcome.mission.conversion.predicted_robustness),
            "straight_leg_robustness": num(outcome.mission.conversion.straight_leg_robustness),
            "predicted_late_s": {k: num(v) for k, v in outcome.mission.conversion.late_s.items()},
        },
        "tuning": {
            name: {
                "drag_per_s": t.drag_per_s,
                "drag_source": t.drag_source,
                "expected_lag_s": t.expected_lag_s,
                "accuracy_m": t.accuracy_m,
            }
            for name, t in outcome.tuning.items()
        },
        "warnings": list(outcome.warnings),
        "flown_lower_bound": num(outcome.flown_lower_bound),
        "estimator_accuracy_m": {k: list(v) for k, v in outcome.accuracy_m.items()},
        "tlog_messages": None if outcome.tlog is None else outcome.tlog.messages,
        "images": {name: len(ims) for name, ims in outcome.images.items()},
        "coverage": None if outcome.coverage is None else _coverage_json(outcome.coverage),
        "camera_refused": {} if outcome.camera is None else dict(outcome.camera.refused),
        "files": {k: str(p) for k, p in outcome.files.items()},
    }


def _coverage_json(report: CoverageReport) -> dict[str, Any]:

    return coverage_json(report)
