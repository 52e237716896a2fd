"""What the safety monitor (:mod:`mavlink.monitor`) judges and reports: its verdicts and
actions, the spec's always-clauses it watches (:func:`always_clauses`), the events of a flight
it stopped (:class:`SafetyEvent`), a run's findings (:class:`RunFindings`, what the batch
simulator of ``gcs assess`` collects) and the monitor's statistics (:class:`MonitorStats`).
No MAVLink here: the mock's batch simulator uses these as the ground station does.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import ClassVar

import numpy as np

from mavlink.px4_modes import Px4Mode
from planner.stl.ast import Always, Formula

__all__ = [
    "MonitorStats",
    "RunFindings",
    "SafetyAction",
    "SafetyClause",
    "SafetyEvent",
    "VehicleLeft",
    "Verdict",
    "always_clause_indices",
    "always_clauses",
]


class Verdict(Enum):
    """Why the monitor stopped the flight."""

    VIOLATED = "violated"  # the clause is false on the current telemetry
    PREDICTED = "predicted"  # it will be false within the horizon
    LINK_LOST = "link_lost"  # a vehicle went silent (heartbeats, or telemetry for longer
    # than the vehicle's offboard-loss time, after which PX4 has left offboard by itself)
    LEFT_MODE = "left_mode"  # a vehicle left the flight's mode (its own failsafe took over)
    ORIGIN_MOVED = "origin_moved"  # a vehicle's EKF origin moved in flight: its positions and
    # the setpoints streamed to it are in another frame than the flight's
    OFF_PLAN = "off_plan"  # a vehicle is farther from its plan than the flight allows
    NO_REPLAN = "no_replan"  # a vehicle left, and no new plan for the others was flown


@dataclass(frozen=True, slots=True)
class VehicleLeft:
    """A vehicle that left the flight while others fly on (the monitor's ``on_departure``).

    Attributes:
        vehicle: its name.
        verdict: LINK_LOST (silent) or LEFT_MODE (its own failsafe took it).
        t_s: plan time of its last position sample.
        position_enu_m: that position in the mission frame (None: never heard).
        mode: the mode it is in (LEFT_MODE), else None.
    """

    vehicle: str
    verdict: Verdict
    t_s: float
    position_enu_m: tuple[float, float, float] | None
    mode: Px4Mode | None = None


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


def always_clauses(
    spec: Formula,
    vehicle_names: Sequence[str],
    exclude: Callable[[Formula], bool] | None = None,
) -> tuple[SafetyClause, ...]:
    """The top-level conjuncts of ``spec`` of the form ``always[a,b] psi`` with ``psi`` atemporal.

    Args:
        spec: the whole specification.
        vehicle_names: names of the vehicle signals (to list which a clause reads).
        exclude: clauses ``psi`` not to watch (:func:`always_clause_indices`).
    """
    out = []
    names = set(vehicle_names)
    for i in always_clause_indices(spec, exclude):
        clause = spec.clauses[i]
        assert isinstance(clause, Always)
        reads = tuple(sorted(names & set(clause.child.signal_names())))
        out.append(SafetyClause(str(clause), clause.child, clause.start_s, clause.end_s, reads))
    return tuple(out)


def always_clause_indices(
    spec: Formula, exclude: Callable[[Formula], bool] | None = None
) -> tuple[int, ...]:
    """Which top-level conjuncts of ``spec`` :func:`always_clauses` watches (their indices).

    ``exclude(psi)`` true leaves ``always[a,b] psi`` unwatched: the ground station passes the
    clauses that read a vehicle's heading (``face``), since the monitor evaluates and
    predicts positions only (such a clause is judged on the flown tracks afterwards).
    """
    out = []
    for i, clause in enumerate(spec.clauses):
        if isinstance(clause, Always) and clause.child.horizon == 0.0:
            if any(isinstance(node, Always) or node.horizon > 0 for node in clause.child.walk()):
                continue
            if exclude is not None and exclude(clause.child):
                continue
            out.append(i)
    return tuple(out)


@dataclass(frozen=True, slots=True, eq=False)
class RunFindings:
    """What one monitor tick found in each of many simultaneous flights
    (:meth:`SafetyMonitor.evaluate_runs`).

    Attributes:
        code: ``(R,)`` 0 where nothing was found, else ``1 + VERDICTS.index(verdict)``.
        clause: ``(R,)`` the failing clause's index (-1: none, or the tracking alarm).
        value: ``(R,)`` the clause's robustness (now, or its predicted minimum); for the
            tracking alarm the largest distance from the plan (m).
        ahead_s: ``(R,)`` for a prediction, how far ahead the violation is (else 0).
    """

    VERDICTS: ClassVar[tuple[Verdict, ...]] = tuple(Verdict)
    code: np.ndarray
    clause: np.ndarray
    value: np.ndarray
    ahead_s: np.ndarray

    @classmethod
    def none(cls, n: int) -> RunFindings:
        """Nothing found in ``n`` runs."""
        return cls(np.zeros(n, np.int8), np.full(n, -1), np.full(n, np.nan), np.zeros(n))

    @classmethod
    def code_of(cls, verdict: Verdict) -> int:
        """The code of ``verdict``."""
        return 1 + cls.VERDICTS.index(verdict)

    def verdict(self, run: int) -> Verdict | None:
        """The verdict of run ``run`` (``None``: nothing found)."""
        c = int(self.code[run])
        return None if c == 0 else self.VERDICTS[c - 1]


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
        latency_s: from the reception of the oldest telemetry the decision read (for a
            departed vehicle, its heartbeat) to the stop commands being sent.
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
    latency_s: float | None = None

    def describe(self) -> str:
        """One line for the operator."""
        who = ", ".join(self.vehicles)
        if self.verdict is Verdict.LINK_LOST:
            # only a setpoint stream stops on it (a mission monitor rides it out)
            head = (
                f"link lost to {who} at t={self.t_s:.2f} s (without setpoints PX4 leaves "
                "offboard by itself after COM_OF_LOSS_T: its offboard-loss failsafe, "
                "COM_OBL_RC_ACT)"
            )
        elif self.verdict is Verdict.LEFT_MODE:
            head = f"{who} left the flight mode at t={self.t_s:.2f} s ({self.detail})"
        elif self.verdict is Verdict.ORIGIN_MOVED:
            head = (
                f"the EKF origin of {who} moved at t={self.t_s:.2f} s ({self.detail}): its "
                "positions and setpoints are no longer in the flight's frame"
            )
        elif self.verdict is Verdict.NO_REPLAN and who:
            head = f"{who} left the flight and no new plan was flown ({self.detail})"
        elif self.verdict is Verdict.NO_REPLAN:
            head = f"no new plan was flown at t={self.t_s:.2f} s ({self.detail})"
        elif self.verdict is Verdict.OFF_PLAN:
            head = f"{who} off its plan at t={self.t_s:.2f} s ({self.detail})"
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
        if self.latency_s is not None:
            tail += f" {self.latency_s * 1e3:.0f} ms after the telemetry"
        if self.action_failures:
            tail += " (not accepted by " + ", ".join(sorted(self.action_failures)) + ")"
        return head + tail


@dataclass(slots=True)
class MonitorStats:
    """What a monitor run did (for reports and benchmarks).

    Attributes:
        checks: evaluations of the clauses.
        tick_s: CPU wall time of each evaluation (telemetry snapshot to verdict), seconds;
            it runs on the monitor's own thread, never on the event loop.
        stale: per vehicle, evaluations in which its telemetry was older than
            ``stale_after_s`` (but younger than ``offboard_loss_s``), so its clauses were
            checked on its prediction from its last sample and its plan.
        stale_max_age_s: per vehicle, the oldest telemetry so predicted.
        off_plan_max_m: per vehicle with a plan, the largest distance from it seen (m).
        off_plan_max_t_s: when that was (plan time, s).
        warned: per vehicle, when it first went farther from its plan than the warning
            distance and how far it was (plan time s, m).
        unheard: per vehicle, the stretches (plan time s, from its last sample to its next;
            the end ``None`` while it is still unheard) in which its link counted as lost
            and a monitor that rides out link losses (mission mode) left its clauses unchecked.
    """

    checks: int = 0
    tick_s: list[float] = field(default_factory=list)
    stale: dict[str, int] = field(default_factory=dict)
    stale_max_age_s: dict[str, float] = field(default_factory=dict)
    off_plan_max_m: dict[str, float] = field(default_factory=dict)
    off_plan_max_t_s: dict[str, float] = field(default_factory=dict)
    warned: dict[str, tuple[float, float]] = field(default_factory=dict)
    unheard: dict[str, list[tuple[float, float | None]]] = field(default_factory=dict)

    def as_json(self) -> dict[str, object]:
        """The figures as JSON values (tick times in ms)."""
        ticks = np.asarray(self.tick_s) * 1e3
        return {
            "checks": self.checks,
            "tick_ms_p50": float(np.percentile(ticks, 50)) if ticks.size else None,
            "tick_ms_max": float(ticks.max()) if ticks.size else None,
            "predicted_while_late": dict(self.stale),
            "late_max_age_s": dict(self.stale_max_age_s),
            "off_plan_max_m": dict(self.off_plan_max_m),
            "off_plan_max_t_s": dict(self.off_plan_max_t_s),
            "off_plan_warned": {n: {"t_s": t, "off_m": d} for n, (t, d) in self.warned.items()},
            "unheard": {n: [list(g) for g in gaps] for n, gaps in self.unheard.items()},
        }

    def describe_unheard(self) -> str:
        """One line on the vehicles the monitor lost and rode out (empty when none)."""
        if not self.unheard:
            return ""
        parts = []
        for n in sorted(self.unheard):
            for a, b in self.unheard[n]:
                parts.append(
                    f"{n} from t = {a:.1f} s to {b:.1f} s ({b - a:.1f} s)"
                    if b is not None
                    else f"{n} from t = {a:.1f} s to the end"
                )
        return (
            "link lost and ridden out (the missions fly on board; their clauses were not "
            "checked meanwhile): " + "; ".join(parts)
        )

    def describe_stale(self) -> str:
        """One line on the vehicles checked on predictions (empty when none was)."""
        if not self.stale:
            return ""
        parts = [
            f"{n} {self.stale[n]} times (telemetry up to {self.stale_max_age_s[n]:.2f} s old)"
            for n in sorted(self.stale)
        ]
        return "checked on its prediction from its last telemetry and its plan: " + ", ".join(parts)
