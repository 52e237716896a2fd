"""Online safety monitor: the spec's always-clauses checked on live telemetry.

The clauses that must hold at every instant of an interval
(``always[a,b] psi`` with ``psi`` free of temporal operators: separation,
workspace, no-fly zones) are evaluated during the flight on the vehicles'
reported positions, converted into the mission frame. At each tick the
monitor also *predicts* the next ``horizon_s`` seconds: each vehicle is
assumed to keep following its plan with its current tracking error, the
error growing with the current velocity error (without a plan: constant
velocity). If a clause is violated now, or its robustness on the predicted
samples drops below zero inside the clause's interval, or a vehicle's link
times out, the monitor stops the stream and commands every vehicle to hold
(or land), and reports which clause, which vehicles and when
(:class:`SafetyEvent`).

Robustness is the exact STL semantics of :mod:`planner.stl`
(``robustness_trace`` of ``psi`` on the predicted samples), so the monitor and
the offline checker agree on what a violation is.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING

import numpy as np
from mavsdk.plugins.offboard import OffboardResult

from mavlink.errors import CommandError, LinkError
from mavlink.px4_modes import Px4Mode
from planner.frames import GeodeticPoint, ned_to_enu, ned_vector_to_enu
from planner.stl.ast import Always, Formula

if TYPE_CHECKING:
    from mavlink.fleet import Fleet, Vehicle
    from planner.trajectory import Trajectory


class Verdict(Enum):
    """Why the monitor stopped the flight."""

    VIOLATED = "violated"  # the clause is false on the current telemetry
    PREDICTED = "predicted"  # it will be false within the horizon
    LINK_LOST = "link_lost"  # a vehicle went silent (heartbeats, or telemetry for longer
    # than the vehicle's offboard-loss time, after which PX4 has left offboard by itself)
    LEFT_MODE = "left_mode"  # a vehicle left the flight's mode (its own failsafe took over)


class SafetyAction(Enum):
    """What every vehicle is told to do on a stop."""

    HOLD = "hold"
    LAND = "land"


@dataclass(frozen=True, slots=True, eq=False)
class SafetyClause:
    """One invariant: ``psi`` must hold at every time in ``[start_s, end_s]``.

    Attributes:
        name: shown in reports (by default the clause's STL text).
        formula: ``psi``, a formula without temporal operators over vehicle
            position signals (``(n, 3)`` ENU metres per vehicle name).
        start_s, end_s: interval in seconds from the plan's start.
        vehicles: the vehicle signals ``psi`` reads.
    """

    name: str
    formula: Formula
    start_s: float
    end_s: float
    vehicles: tuple[str, ...]


def always_clauses(spec: Formula, vehicle_names: Sequence[str]) -> tuple[SafetyClause, ...]:
    """The top-level conjuncts of ``spec`` of the form ``always[a,b] psi`` with ``psi`` atemporal.

    Args:
        spec: the whole specification.
        vehicle_names: names of the vehicle signals (to list which a clause reads).
    """
    out = []
    names = set(vehicle_names)
    for clause in spec.clauses:
        if isinstance(clause, Always) and clause.child.horizon == 0.0:
            if any(isinstance(node, Always) or node.horizon > 0 for node in clause.child.walk()):
                continue
            reads = tuple(sorted(names & set(clause.child.signal_names())))
            out.append(SafetyClause(str(clause), clause.child, clause.start_s, clause.end_s, reads))
    return tuple(out)


@dataclass(frozen=True, slots=True)
class SafetyEvent:
    """What stopped a flight.

    Attributes:
        verdict: violated, predicted or link lost.
        clause: the clause's name (``None`` for a lost link).
        vehicles: the vehicles concerned (the lost one, or those the clause reads).
        t_s: seconds from the plan's start when the monitor decided.
        robustness: the clause's robustness now (violated) or its minimum
            over the prediction (predicted); ``None`` for a lost link.
        predicted_in_s: for a prediction, how far ahead the violation is.
        action: what every vehicle was told (for a vehicle that left the flight's mode:
            every other vehicle; its own failsafe action is not overridden).
        action_failures: vehicles that did not accept it, with the reason.
        detail: for ``LEFT_MODE``, the mode each departed vehicle reported.
    """

    verdict: Verdict
    clause: str | None
    vehicles: tuple[str, ...]
    t_s: float
    robustness: float | None
    predicted_in_s: float | None
    action: SafetyAction
    action_failures: dict[str, str] = field(default_factory=dict)
    detail: str = ""

    def describe(self) -> str:
        """One line for the operator."""
        who = ", ".join(self.vehicles)
        if self.verdict is Verdict.LINK_LOST:
            head = f"link lost to {who} at t={self.t_s:.2f} s"
        elif self.verdict is Verdict.LEFT_MODE:
            head = f"{who} left the flight mode at t={self.t_s:.2f} s ({self.detail})"
        elif self.verdict is Verdict.VIOLATED:
            head = (
                f"clause {self.clause!r} violated by {who} at t={self.t_s:.2f} s "
                f"(robustness {self.robustness:.3f})"
            )
        else:
            head = (
                f"clause {self.clause!r} predicted to fail for {who} in "
                f"{self.predicted_in_s:.2f} s at t={self.t_s:.2f} s "
                f"(predicted robustness {self.robustness:.3f})"
            )
        tail = f"; commanded {self.action.value} to all vehicles"
        if self.action_failures:
            tail += " (not accepted by " + ", ".join(sorted(self.action_failures)) + ")"
        return head + tail


async def safe_stop(v: Vehicle, action: SafetyAction) -> None:
    """Stop offboard streaming (MAVSDK stops re-sending and commands Hold), then land if asked.

    A vehicle not in offboard gets MAVSDK's plain Hold.
    """
    from mavlink.fleet import mavsdk_call

    if v.offboard.is_active():
        result = await mavsdk_call(v.offboard.stop_async)
        if result != OffboardResult.SUCCESS:
            raise CommandError(
                f"offboard stop failed: {result.name}",
                result=result.name,
                vehicle=v.name,
                url=v.url,
            )
    else:
        await v.hold()
    if action is SafetyAction.LAND:
        await v.land()


class SafetyMonitor:
    """Watch links and always-clauses during a flight (see module docstring).

    Args:
        clauses: the invariants (:func:`always_clauses`); may be empty (links only).
        horizon_s: how far ahead to predict (0: no prediction).
        steps: predicted samples over the horizon (the check step is horizon/steps).
        rate_hz: how often to evaluate.
        action: hold or land on a stop.
        stale_after_s: telemetry older than this is not used for a clause
            (the vehicle's link check covers it).
        offboard_loss_s: a vehicle whose position telemetry is older than this counts as
            lost: PX4 leaves offboard by itself after COM_OF_LOSS_T (default 1 s) without
            setpoints, and an outage that silences telemetry that long has most likely
            starved it of setpoints too, so streaming to it must stop before the link returns.
    """

    def __init__(
        self,
        clauses: Sequence[SafetyClause],
        *,
        horizon_s: float = 0.5,
        steps: int = 5,
        rate_hz: float = 20.0,
        action: SafetyAction = SafetyAction.HOLD,
        stale_after_s: float = 0.5,
        offboard_loss_s: float = 1.0,
    ) -> None:
        if not (math.isfinite(horizon_s) and horizon_s >= 0):
            raise LinkError(f"monitor horizon_s must be >= 0, got {horizon_s!r}")
        if steps < 1:
            raise LinkError(f"monitor steps must be >= 1, got {steps!r}")
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise LinkError(f"monitor rate_hz must be > 0, got {rate_hz!r}")
        self.clauses = tuple(clauses)
        self.horizon_s = float(horizon_s)
        self.steps = int(steps) if horizon_s > 0 else 1
        self.rate_hz = float(rate_hz)
        self.action = action
        self.stale_after_s = stale_after_s
        self.offboard_loss_s = offboard_loss_s
        self.checks = 0  # evaluations done in the last run (for tests and reports)

    def predict(
        self,
        t_s: float,
        pos_enu_m: np.ndarray,
        vel_enu_m_s: np.ndarray,
        plan: Trajectory | None,
    ) -> tuple[np.ndarray, float]:
        """Predicted positions ``(steps + 1, 3)`` at ``t_s + j * dt`` and the step ``dt``."""
        if self.horizon_s == 0:
            return pos_enu_m[None, :], 1.0
        dt = self.horizon_s / self.steps
        tau = np.arange(self.steps + 1) * dt
        if plan is None:
            return pos_enu_m + tau[:, None] * vel_enu_m_s, dt
        ref = plan.position(t_s + tau)
        v_ref = plan.velocity(np.array([t_s]))[0]
        return ref + (pos_enu_m - ref[0]) + tau[:, None] * (vel_enu_m_s - v_ref), dt

    def evaluate(
        self,
        t_s: float,
        states: Mapping[str, tuple[np.ndarray, np.ndarray]],
        plans: Mapping[str, Trajectory] | None = None,
    ) -> tuple[Verdict, SafetyClause, float, float] | None:
        """Check every active clause at plan time ``t_s``.

        Args:
            t_s: seconds from the plan's start.
            states: per vehicle, (position ``(3,)``, velocity ``(3,)``) in mission ENU.
            plans: the vehicles' planned trajectories (for the prediction).

        Returns:
            ``(verdict, clause, robustness, predicted_in_s)`` for the first
            failing clause, or ``None``.
        """
        signals: dict[str, np.ndarray] = {}
        dt = 1.0
        for name, (p, v) in states.items():
            signals[name], dt = self.predict(t_s, p, v, None if plans is None else plans.get(name))
        for clause in self.clauses:
            if not (clause.start_s <= t_s <= clause.end_s):
                continue
            if any(name not in signals for name in clause.vehicles):
                continue
            sub = {name: signals[name] for name in clause.vehicles}
            trace = np.asarray(clause.formula.robustness_trace(sub, dt), dtype=float)
            if trace[0] < 0:
                return Verdict.VIOLATED, clause, float(trace[0]), 0.0
            times = t_s + np.arange(trace.size) * dt
            active = times <= clause.end_s
            bad = np.nonzero((trace < 0) & active)[0]
            if bad.size:
                j = int(bad[0])
                return Verdict.PREDICTED, clause, float(trace[active].min()), j * dt
        return None

    async def run(
        self,
        fleet: Fleet,
        vehicles: Sequence[Vehicle],
        *,
        t0_monotonic_s: float,
        mission_origin: GeodeticPoint,
        origins: Mapping[str, GeodeticPoint],
        stop: asyncio.Event,
        plans: Mapping[str, Trajectory] | None = None,
        expected_mode: Px4Mode | None = None,
        mode_grace_s: float = 0.5,
    ) -> SafetyEvent | None:
        """Monitor until ``stop`` is set; on a finding set ``stop``, command every vehicle, report.

        With ``expected_mode`` (OFFBOARD for a setpoint stream), a heartbeat received more than
        ``mode_grace_s`` after the start that shows another mode stops the flight: the vehicle's
        own failsafe took over, and it must not be streamed to or re-engaged without the
        operator.

        Returns:
            The :class:`SafetyEvent`, or ``None`` if the flight ended without one.
        """
        period = 1.0 / self.rate_hz
        k = 0
        self.checks = 0
        while not stop.is_set():
            # Half a period after the setpoint ticks, so an evaluation never delays a send.
            deadline = t0_monotonic_s + (k + 0.5) * period
            delay = deadline - time.monotonic()
            if delay > 0:
                try:
                    await asyncio.wait_for(stop.wait(), delay)
                    break
                except TimeoutError:
                    pass
            k = max(k + 1, int((time.monotonic() - t0_monotonic_s) / period - 0.5) + 1)
            now = time.monotonic()
            t_s = now - t0_monotonic_s
            statuses = {v.name: v.status(now) for v in vehicles}
            lost = tuple(
                sorted(
                    n
                    for n, st in statuses.items()
                    if not st.connected
                    or (st.position_age_s is not None and st.position_age_s > self.offboard_loss_s)
                )
            )
            if lost:
                return await self._stop(fleet, stop, Verdict.LINK_LOST, None, lost, t_s, None, None)
            if expected_mode is not None:
                left = {
                    n: st.mode
                    for n, st in statuses.items()
                    if st.mode is not None
                    and st.mode is not expected_mode
                    and st.heartbeat_age_s is not None
                    and now - st.heartbeat_age_s > t0_monotonic_s + mode_grace_s
                }
                if left:
                    names = tuple(sorted(left))
                    detail = ", ".join(f"{n} now {left[n].name}" for n in names)
                    return await self._stop(
                        fleet, stop, Verdict.LEFT_MODE, None, names, t_s, None, None,
                        exclude=names, detail=detail,
                    )  # fmt: skip
            states: dict[str, tuple[np.ndarray, np.ndarray]] = {}
            for name, st in statuses.items():
                if (
                    st.pos_ned_m is None
                    or st.vel_ned_m_s is None
                    or st.position_age_s is None
                    or st.position_age_s > self.stale_after_s
                ):
                    continue
                origin = origins[name]
                states[name] = (
                    ned_to_enu(np.asarray(st.pos_ned_m), mission_origin, origin),
                    ned_vector_to_enu(np.asarray(st.vel_ned_m_s), mission_origin, origin),
                )
            self.checks += 1
            found = self.evaluate(t_s, states, plans)
            if found is not None:
                verdict, clause, rho, ahead = found
                return await self._stop(
                    fleet, stop, verdict, clause.name, clause.vehicles, t_s, rho, ahead
                )
        return None

    async def _stop(
        self,
        fleet: Fleet,
        stop: asyncio.Event,
        verdict: Verdict,
        clause: str | None,
        vehicles: tuple[str, ...],
        t_s: float,
        rho: float | None,
        ahead: float | None,
        *,
        exclude: tuple[str, ...] = (),
        detail: str = "",
    ) -> SafetyEvent:
        stop.set()
        others = [v for v in fleet if v.name not in exclude]
        failures = await fleet.for_each(lambda v: safe_stop(v, self.action), others)
        return SafetyEvent(
            verdict=verdict,
            clause=clause,
            vehicles=vehicles,
            t_s=t_s,
            robustness=rho,
            predicted_in_s=None if verdict is not Verdict.PREDICTED else ahead,
            action=self.action,
            action_failures={k: str(e) for k, e in failures.items()},
            detail=detail,
        )
