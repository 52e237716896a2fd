"""Judging a flown flight against its spec: the exact robustness of the flown tracks next to
the plan's, per top-level clause and overall, and per vehicle how far it flew from its plan
and with what delay (the first thing to look at when flown robustness falls short).

A room of its own because it is pure computation on recorded tracks (numpy and the exact STL
semantics; no link, no printing): :func:`gcs.flight.fly_plan` calls :func:`evaluate_flight`
once the flight is over, the live view (:mod:`gcs.flight.progress`) and mission mode evaluate the
same :func:`plan_formula`, and the outcome (:mod:`gcs.flight.outcome`) reports what was found.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from mavlink.errors import LinkError
from mavlink.tracks import NO_HEADING
from planner.planfile import plan_formula as checked_formula
from planner.planfile import planned_signals
from planner.spec.heading import heading_readers

if TYPE_CHECKING:
    from mavlink.tracks import FlownTrack
    from planner.planfile import Plan
    from planner.stl import Formula

__all__ = [
    "GAP_S",
    "ClauseOutcome",
    "FlownEvaluation",
    "TrackingError",
    "evaluate_flight",
    "heading_readers",
    "plan_formula",
    "reads_heading",
]

#: A stretch without telemetry longer than this (s) is a gap in the flown record (PX4 sends
#: positions at 10-50 Hz; MAVSDK counts a link lost after 3 s without heartbeats).
GAP_S = 1.0


def reads_heading(formula: Formula) -> bool:
    """Whether ``formula`` reads a vehicle's heading (:func:`heading_readers`): the live safety
    monitor leaves such clauses out (``exclude`` of :func:`mavlink.monitor.always_clauses`)."""
    return bool(heading_readers(formula))


def plan_formula(plan: Plan) -> Formula:
    """The plan's whole spec with the scenario's predicates (exact numpy semantics), checked
    against the plan: :func:`planner.planfile.plan_formula` (PlanFileError naming the plan file).
    """

    return checked_formula(plan)


@dataclass(frozen=True, slots=True)
class ClauseOutcome:
    """One top-level clause: its text and its exact robustness planned and flown (m)."""

    text: str
    vehicles: tuple[str, ...]
    planned: float
    flown: float | None


@dataclass(frozen=True, slots=True)
class TrackingError:
    """How far one vehicle's reported positions were from its plan at the same instants.

    Attributes:
        vehicle: name.
        samples: telemetry samples inside the horizon.
        max_m, rms_m: largest and root-mean-square distance flown - planned (m).
        t_at_max_s: when the largest distance occurred (s from the plan's start).
        lag_s: the delay ``tau`` minimising the RMS distance between flown(t) and
            planned(t - tau), searched in [-0.5, 1.0] s (0: flown in step with the plan).
        rms_at_lag_m: that minimal RMS distance.
    """

    vehicle: str
    samples: int
    max_m: float
    rms_m: float
    t_at_max_s: float
    lag_s: float
    rms_at_lag_m: float


@dataclass(frozen=True, slots=True, eq=False)
class FlownEvaluation:
    """The flown data judged against the spec (exact semantics, the plan's check grid).

    Attributes:
        dt_s: grid step (the plan's ``check_dt_s``).
        planned_robustness: the spec's robustness on the planned trajectories.
        flown_robustness: on the flown tracks (``None`` when a track does not cover the
            horizon; ``coverage_problem`` says why).
        clauses: per top-level clause, planned and flown.
        tracking: per vehicle tracking error.
        coverage_problem: why flown robustness could not be evaluated, else ``""``.
        gaps: per vehicle, the stretches of the horizon (plan time s, from one sample to the
            next) longer than :data:`GAP_S` without telemetry: the flown robustness
            interpolates the track across them (a lost link in mission mode).
    """

    dt_s: float
    planned_robustness: float
    flown_robustness: float | None
    clauses: tuple[ClauseOutcome, ...]
    tracking: tuple[TrackingError, ...]
    coverage_problem: str = ""
    gaps: dict[str, tuple[tuple[float, float], ...]] = field(default_factory=dict)

    def describe_gaps(self) -> list[str]:
        """One line per vehicle with gaps (none without)."""
        return [
            f"{name}: no telemetry "
            + ", ".join(f"from t = {a:.1f} to {b:.1f} s ({b - a:.1f} s)" for a, b in spans)
            + ": the flown robustness interpolates its track across "
            + ("it" if len(spans) == 1 else "them")
            + " (PX4's own log has what it flew)"
            for name, spans in self.gaps.items()
        ]

    @property
    def weakest_flown(self) -> ClauseOutcome | None:
        """The flown clause with the smallest robustness."""
        flown = [c for c in self.clauses if c.flown is not None]
        return min(flown, key=lambda c: c.flown or 0.0) if flown else None


def _tracking(
    name: str, track: FlownTrack, plan_pos: Any, horizon_s: float, lags_s: np.ndarray
) -> TrackingError:
    inside = (track.t_s >= 0.0) & (track.t_s <= horizon_s)
    t = track.t_s[inside]
    p = track.pos_enu_m[inside]
    if t.size == 0:
        nan = math.nan
        return TrackingError(name, 0, nan, nan, nan, nan, nan)
    d = np.linalg.norm(p - plan_pos(t), axis=1)
    i = int(np.argmax(d))
    # planned(t - tau) for every candidate delay at once: (lags, samples, 3).
    shifted = plan_pos(np.clip((t[None, :] - lags_s[:, None]).ravel(), 0.0, horizon_s))
    err = np.linalg.norm(shifted.reshape(lags_s.size, t.size, 3) - p[None], axis=2)
    rms = np.sqrt(np.mean(err**2, axis=1))
    j = int(np.argmin(rms))
    return TrackingError(
        vehicle=name,
        samples=int(t.size),
        max_m=float(d[i]),
        rms_m=float(np.sqrt(np.mean(d**2))),
        t_at_max_s=float(t[i]),
        lag_s=float(lags_s[j]),
        rms_at_lag_m=float(rms[j]),
    )


def evaluate_flight(plan: Plan, tracks: Mapping[str, FlownTrack]) -> FlownEvaluation:
    """Exact robustness of the flown tracks next to the plan's, per clause and overall.

    Flown positions are resampled on the plan's check grid ``t = 0, dt, ..., horizon`` by
    linear interpolation of the telemetry (:meth:`mavlink.tracks.FlownTrack.resample`, which
    refuses a track that does not cover the horizon); a vehicle whose heading the spec reads
    (``face``, :func:`heading_readers`) with its flown heading as a fourth column. A track
    without a heading leaves the clauses that read it unjudged (``flown`` None) and the
    overall flown robustness None, ``coverage_problem`` naming the vehicle.
    """

    phi = plan_formula(plan)
    dt = plan.check_dt_s
    n = round(plan.horizon_s / dt) + 1
    t = np.arange(n) * dt

    planned = planned_signals(plan, t)
    readers = heading_readers(phi)
    flown: dict[str, np.ndarray] | None = {}
    headless: set[str] = set()
    problem = ""
    for v in plan.vehicles:
        tr = tracks.get(v.name)
        if tr is None:
            flown, problem = None, f"no telemetry from {v.name}"
            break
        heading = v.name in readers and tr.has_heading
        try:
            flown[v.name] = tr.resample(dt, plan.horizon_s, heading=heading)  # type: ignore[index]
        except LinkError as exc:
            flown, problem = None, str(exc)
            break
        if v.name in readers and not heading:
            headless.add(v.name)
            problem = problem or f"vehicle {v.name}: {NO_HEADING}, which the spec's face() reads"
    clauses = []
    for c in phi.clauses:
        judged = flown is not None and not headless & heading_readers(c)
        clauses.append(
            ClauseOutcome(
                text=str(c),
                vehicles=tuple(sorted(c.signal_names() & planned.keys())),
                planned=float(c.robustness(planned, dt)),
                flown=float(c.robustness(flown, dt)) if judged and flown is not None else None,
            )
        )
    lags = np.round(np.arange(-0.5, 1.0 + 1e-9, 0.01), 6)
    tracking = tuple(
        _tracking(v.name, tracks[v.name], v.trajectory.position, plan.horizon_s, lags)
        for v in plan.vehicles
        if v.name in tracks
    )
    whole = flown is not None and not headless
    gaps = {}
    for v in plan.vehicles:
        tr = tracks.get(v.name)
        if tr is None:
            continue
        ts = tr.t_s[(tr.t_s >= -GAP_S) & (tr.t_s <= plan.horizon_s + GAP_S)]
        jumps = np.flatnonzero(np.diff(ts) > GAP_S)
        spans = tuple(
            (float(ts[k]), float(ts[k + 1]))
            for k in jumps
            if ts[k + 1] > 0.0 and ts[k] < plan.horizon_s
        )
        if spans:
            gaps[v.name] = spans
    return FlownEvaluation(
        dt_s=dt,
        planned_robustness=float(phi.robustness(planned, dt)),
        flown_robustness=float(phi.robustness(flown, dt)) if whole and flown is not None else None,
        clauses=tuple(clauses),
        tracking=tracking,
        coverage_problem=problem,
        gaps=gaps,
    )
