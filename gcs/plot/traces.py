"""The robustness over time of every top-level clause of a plan's spec, planned and flown:
what the robustness panel of the plan's picture (:mod:`gcs.plot.figure`) and its HTML table
(:mod:`gcs.plot`) show.

Exact semantics (:mod:`planner.stl`) on the dense grid ``t = 0, dt, ..., horizon`` (``dt`` the
plan's ``check_dt_s``). For a clause ``always[a,b] body`` or ``eventually[a,b] body`` the curve
is the trace of ``body``: the clause's value is its minimum (maximum) over ``[a, b]``, where
the witness dot goes, so the picture shows *when* the margin is small. A top-level until gets
the curve whose maximum over its window is its value; any other clause is its own trace
(defined while its horizon fits in the plan).

Flown robustness is evaluated on the same grid, positions linearly interpolated between
telemetry samples (:mod:`gcs.telemetry`) and held before the first and after the last sample
of each vehicle (the HTML table says how much of the horizon the telemetry covers); where the
spec reads a vehicle's heading (``face``), its flown heading likewise (the shorter turn between
samples). A clause that reads the heading of a vehicle whose telemetry has none gets no flown
value, and says why (``flown_problem``).

A room of its own because it is computation, not drawing: numpy and the STL engine, no
matplotlib, checked by tests against the clauses' own values.

Errors::

    gcs.errors.InputFileError        telemetry without any vehicle of the plan, a bad --dt
    planner.planfile.PlanFileError   a spec that does not parse, or a clause that cannot be
                                     evaluated on the plan (e.g. longer than its horizon)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from gcs.errors import InputFileError
from gcs.flight.evaluation import heading_readers
from mavlink.tracks import NO_HEADING
from planner.planfile import plan_formula, planned_signals, spec_errors
from planner.stl import Always, Eventually, Until

if TYPE_CHECKING:
    from gcs.telemetry import Telemetry
    from planner.planfile import Plan
    from planner.stl import Formula

__all__ = ["ClauseTrace", "clause_traces", "plan_grid"]


@dataclass(frozen=True, slots=True, eq=False)
class ClauseTrace:
    """What the robustness panel draws for one top-level clause.

    Attributes:
        text: the clause as STL text.
        robustness: exact robustness of the clause at t = 0 on the planned paths.
        shown: ``"body"`` when the curve is the body of a top-level always/eventually,
            ``"until"`` for a top-level until (the curve whose maximum over ``[a, b]`` is
            the clause's value, NaN outside), else ``"clause"``.
        operator: ``"always"``, ``"eventually"``, ``"until"`` or ``""`` (``"clause"``).
        window_s: ``(a, b)`` of the top-level operator, else None.
        vehicles: the vehicles the clause reads (its colour: one vehicle's own, several black).
        t_s: ``(m,)`` times of the curve.
        rho: ``(m,)`` planned robustness of what is shown.
        witness_t_s: time where the clause value is attained on the curve (``t_s[0]`` for
            ``shown == "clause"``).
        flown_robustness: the clause on the flown paths (None without telemetry or when the
            telemetry lacks a vehicle the clause reads).
        flown_rho: ``(m,)`` flown counterpart of ``rho`` (or None).
        flown_problem: why the clause has no flown value although telemetry was given
            (a vehicle's telemetry without the heading the clause reads), else ``""``.
    """

    text: str
    robustness: float
    shown: str
    operator: str
    window_s: tuple[float, float] | None
    t_s: NDArray[np.float64]
    rho: NDArray[np.float64]
    witness_t_s: float
    flown_robustness: float | None = None
    flown_rho: NDArray[np.float64] | None = None
    vehicles: tuple[str, ...] = ()
    flown_problem: str = ""


def plan_grid(plan: Plan, dt_s: float | None = None) -> tuple[NDArray[np.float64], float]:
    """The dense grid ``t = 0, dt, ..., horizon`` (s) and its ``dt`` (the plan's check step)."""
    dt = plan.check_dt_s if dt_s is None else float(dt_s)
    if not (math.isfinite(dt) and dt > 0):
        raise InputFileError(f"--dt: must be a positive number of seconds, got {dt_s!r}")
    n = round(plan.horizon_s / dt) + 1
    return np.asarray(np.arange(n) * dt, dtype=np.float64), dt


def _curve(clause: Formula, signals: Mapping[str, Any], dt: float) -> tuple[str, NDArray]:
    """``("body", trace of the body)`` for a top-level always/eventually; for a top-level
    ``p until[a,b] q`` ``("until", c)`` with ``c(t') = min(q(t'), min over [0, t') of p)``
    on ``[a, b]`` (NaN elsewhere), whose maximum is the clause's value at t = 0; else the
    clause's own trace."""

    if isinstance(clause, Always | Eventually):
        return "body", clause.child.robustness_trace(signals, dt)
    if isinstance(clause, Until):
        lo, hi = clause.steps(dt)
        q = clause.rhs.robustness_trace(signals, dt)[: hi + 1]
        p = clause.lhs.robustness_trace(signals, dt)[: hi + 1]
        before = np.concatenate([[np.inf], np.minimum.accumulate(p)[:-1]])  # min over [0, t')
        curve = np.full(hi + 1, np.nan)
        curve[lo:] = np.minimum(q[lo:], before[lo : hi + 1])
        return "until", curve
    return "clause", clause.robustness_trace(signals, dt)


def _witness(
    clause: Formula, rho: NDArray[np.float64], dt: float
) -> tuple[int, str, tuple[float, float] | None]:
    """Step of the curve where the clause value is attained, operator name, window (s).

    Only called once the clause itself evaluated, so its window lies inside ``rho``.
    """

    if isinstance(clause, Always | Eventually):
        lo, hi = clause.steps(dt)
        pick = np.argmin if isinstance(clause, Always) else np.argmax
        k = lo + int(pick(rho[lo : hi + 1]))
        op = "always" if isinstance(clause, Always) else "eventually"
        return k, op, (clause.start_s, clause.end_s)
    if isinstance(clause, Until):
        lo, hi = clause.steps(dt)
        return lo + int(np.nanargmax(rho[lo : hi + 1])), "until", (clause.start_s, clause.end_s)
    return 0, "", None


def clause_traces(
    plan: Plan, telemetry: Telemetry | None = None, dt_s: float | None = None
) -> tuple[ClauseTrace, ...]:
    """Robustness curves of every top-level clause (see :class:`ClauseTrace`).

    The planned curves come from the trajectories' exact positions on :func:`plan_grid`; the
    flown ones from the telemetry on the same grid (module docstring).
    """

    phi = plan_formula(plan)
    t, dt = plan_grid(plan, dt_s)

    planned = planned_signals(plan, t)
    flown: dict[str, NDArray[np.float64]] | None = None
    readers = heading_readers(phi)
    headless: set[str] = set()
    if telemetry is not None:
        known = {v.name for v in plan.vehicles}
        if not known & telemetry.vehicles.keys():
            raise InputFileError(
                f"{telemetry.source}: no vehicle of the plan in the telemetry (it has "
                f"{', '.join(sorted(telemetry.vehicles))}; the plan has {', '.join(sorted(known))})"
            )
        flown = {}
        for name, path in telemetry.vehicles.items():
            heading = name in readers and path.has_heading
            flown[name] = path.signal(t, heading=heading)
            if name in readers and not heading:
                headless.add(name)
    out: list[ClauseTrace] = []
    for i, clause in enumerate(phi.clauses):
        with spec_errors(plan, f"spec clause {i + 1} ({clause})"):
            # The clause's own value (planner.stl), which also rejects a plan too short for it.
            value = float(clause.robustness(planned, dt))
            shown, rho = _curve(clause, planned, dt)
            flown_value: float | None = None
            flown_rho: NDArray[np.float64] | None = None
            missing = sorted(headless & heading_readers(clause))
            problem = f"vehicle {missing[0]}: {NO_HEADING}" if missing else ""
            if flown is not None and clause.signal_names() <= flown.keys() and not missing:
                _, flown_rho = _curve(clause, flown, dt)
                flown_value = float(clause.robustness(flown, dt))
        k, op, window = _witness(clause, rho, dt)
        out.append(
            ClauseTrace(
                text=str(clause),
                robustness=value,
                shown=shown,
                operator=op,
                window_s=window,
                t_s=t[: rho.size],
                rho=rho,
                witness_t_s=float(t[k]),
                flown_robustness=flown_value,
                flown_rho=flown_rho,
                vehicles=tuple(v.name for v in plan.vehicles if v.name in clause.signal_names()),
                flown_problem=problem,
            )
        )
    return tuple(out)
