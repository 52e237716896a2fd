"""Online safety monitor: the spec's always-clauses checked on live telemetry.

The clauses that must hold at every instant of an interval
(``always[a,b] psi`` with ``psi`` free of temporal operators: separation,
workspace, no-fly zones; not the heading, which the ground station leaves to the
judgement after the flight) are evaluated during the flight on the vehicles'
reported positions, converted into the mission frame. At each tick the
monitor also *predicts* the next ``horizon_s`` seconds: each vehicle is
assumed to keep following its plan with its current tracking error, the
error growing with the current velocity error (without a plan: constant
velocity). If a clause is violated now, or its robustness on the predicted
samples drops below zero inside the clause's interval, or a vehicle's link
times out, the monitor stops the stream and commands every vehicle to hold
(or land), and reports which clause, which vehicles, when and how long after
the telemetry it decided on (:class:`SafetyEvent`). Where the vehicles fly a plan it
also watches how far each is from it (the tracking alarm): past ``warn_off_plan_m``
(the plan's robustness margin: beyond it the spec may no longer hold) it warns once per
vehicle, past ``max_off_plan_m`` it stops the flight (:attr:`Verdict.OFF_PLAN`), and the
largest distance per vehicle goes into :class:`MonitorStats`. A vehicle whose telemetry
is late (older than ``stale_after_s``, not yet lost) is predicted from its last
sample and its plan over the time since, never skipped; the run's
:class:`MonitorStats` count such evaluations for the report.

The evaluation runs on the monitor's own thread on a snapshot of the telemetry,
vectorised over vehicles and clause templates, so the setpoint stream on the
event loop never waits for it.

Robustness is the exact STL semantics of :mod:`planner.stl`
(``robustness_trace`` of ``psi`` on the predicted samples), so the monitor and
the offline checker agree on what a violation is.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Awaitable, Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from mavsdk.plugins.offboard import OffboardResult

from mavlink.clock import Clock
from mavlink.errors import CommandError, LinkError
from mavlink.link.mavsdk_glue import mavsdk_call
from mavlink.monitor_findings import (
    MonitorStats,
    RunFindings,
    SafetyAction,
    SafetyClause,
    SafetyEvent,
    VehicleLeft,
    Verdict,
)
from mavlink.px4_modes import Px4Mode
from planner.frames import GeodeticPoint, NedToEnuMap
from planner.stl.batch import ClauseBatch

if TYPE_CHECKING:
    from mavlink.link.fleet import Fleet
    from mavlink.link.vehicle import Vehicle
    from mavlink.link.vehicle_status import VehicleStatus
    from planner.trajectory import Trajectory


#: An EKF origin that moves more than this (m) in flight stops the flight (origins are sent
#: as degE7 / mm: a re-sent origin compares equal; this only absorbs rounding).
_ORIGIN_MOVE_M = 0.01
#: Modes PX4 switches to itself at the end of a mission (a hold, a return, a landing).
_MISSION_END_MODES = frozenset({Px4Mode.AUTO_LOITER, Px4Mode.AUTO_RTL, Px4Mode.AUTO_LAND})


async def safe_stop(v: Vehicle, action: SafetyAction) -> None:
    """Stop offboard streaming (MAVSDK stops re-sending and commands Hold), then land if asked.

    A vehicle not in offboard gets MAVSDK's plain Hold.
    """

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


class _PlanTable:
    """The vehicles' planned positions and velocities at any times, all vehicles at once.

    Plans that share their segment times (the planner's always do) are evaluated by one
    vectorised Horner over the stacked coefficients (exact, as :class:`Trajectory`); others
    one by one. A vehicle without a plan has none (``has[i]`` false).
    """

    def __init__(self, plans: Sequence[Trajectory | None]) -> None:
        self.plans = list(plans)
        self.has = np.array([p is not None for p in self.plans], dtype=bool)
        real = [p for p in self.plans if p is not None]
        self._stacked = bool(real) and all(
            p.degree == real[0].degree
            and np.array_equal(p.segment_t0_s, real[0].segment_t0_s)
            and np.array_equal(p.segment_duration_s, real[0].segment_duration_s)
            for p in real
        )
        if self._stacked:
            ref = real[0]
            self._t0 = np.asarray(ref.segment_t0_s)
            self._dur = np.asarray(ref.segment_duration_s)
            self._end = ref.duration_s
            self._deg = ref.degree
            coeffs = np.zeros((len(self.plans), *np.shape(ref.coeffs)))
            for i, p in enumerate(self.plans):
                if p is not None:
                    coeffs[i] = p.coeffs
            self._coeffs = coeffs  # (N, n_seg, 3, deg + 1)

    def state(self, t_s: np.ndarray, order: int) -> np.ndarray:
        """``(N, M, 3)`` derivative ``order`` (0: position, 1: velocity) at times ``(N, M)``
        (zeros for a vehicle without a plan)."""
        n, m = t_s.shape
        out = np.zeros((n, m, 3))
        if not self.has.any():
            return out
        if not self._stacked:
            for i, p in enumerate(self.plans):
                if p is not None:
                    out[i] = p.derivative(t_s[i], order)
            return out
        tc = np.clip(t_s, 0.0, self._end)
        seg = np.clip(np.searchsorted(self._t0, tc, side="right") - 1, 0, self._t0.size - 1)
        tau = np.minimum(tc - self._t0[seg], self._dur[seg])[..., None]
        c = self._coeffs[np.arange(n)[:, None], seg]  # (N, M, 3, deg + 1)
        for j in range(self._deg, order - 1, -1):
            fac = math.factorial(j) / math.factorial(j - order)
            out = out * tau + fac * c[..., j]
        if order > 0:
            out[(t_s < 0.0) | (t_s > self._end)] = 0.0
        return out


@dataclass(frozen=True, slots=True)
class _Finding:
    verdict: Verdict
    clause: SafetyClause | None
    vehicles: tuple[str, ...]
    t_s: float
    robustness: float | None
    ahead_s: float | None
    sample_monotonic_s: float  # when the oldest telemetry the decision read was received
    exclude: tuple[str, ...] = ()
    detail: str = ""


class SafetyMonitor:
    """Watch links and always-clauses during a flight (see module docstring).

    Per evaluation the work is bounded and vectorised: each vehicle's NED -> mission-ENU map
    is computed once per flight (:class:`planner.frames.NedToEnuMap`), every vehicle's
    prediction is one array expression over the stacked plans, and the clauses are
    evaluated per template (:class:`planner.stl.batch.ClauseBatch`: all separation pairs in
    one step). :meth:`run` evaluates on its own thread on a snapshot of the telemetry, so a
    setpoint stream on the event loop never waits for it; only the stop itself (commanding
    the vehicles) runs on the loop.

    Args:
        clauses: the invariants (:func:`always_clauses`); may be empty (links only).
        horizon_s: how far ahead to predict (0: no prediction).
        steps: predicted samples over the horizon (the check step is horizon/steps).
        rate_hz: how often to evaluate.
        action: hold or land on a stop.
        stale_after_s: telemetry older than this is extrapolated: the vehicle is predicted
            from its last sample and its plan over the time since (counted in
            :attr:`stats`), rather than skipped.
        offboard_loss_s: a vehicle whose position telemetry is older than this counts as
            lost: PX4 leaves offboard by itself after COM_OF_LOSS_T (default 1 s) without
            setpoints, and an outage that silences telemetry that long has most likely
            starved it of setpoints too, so streaming to it must stop before the link returns.
        on_start: called with the flight's start (seconds on the fleet's clock) when
            :meth:`run` begins.
        warn_off_plan_m: warn (``on_warning``, once per vehicle) when a vehicle is farther
            than this from its plan (``None``: never).
        max_off_plan_m: stop the flight when a vehicle is farther than this from its plan
            (``None``: never).
        on_warning: called with one line for the operator (on the monitor's thread).
        ride_out_link_loss: a lost vehicle is not a stop (mission mode: PX4 flies its mission
            on board, and with NAV_DLL_ACT at its default 0 a lost data link is no failsafe):
            its clauses go unchecked until its telemetry returns, and the stretch is recorded
            (:attr:`MonitorStats.unheard`, ``on_warning`` when it is lost and when it is back).
        clock: the monotonic clock (seconds) the ticks and ages are read on (default: the
            fleet's, :attr:`mavlink.link.fleet.Fleet.clock`); tests inject a simulated one
            together with ``wait``.
        wait: ``await wait(stop, delay_s)`` waits until ``stop`` is set or ``delay_s`` has
            passed and returns whether ``stop`` is set (default: on the fleet's clock).
        on_departure: called (on the event loop) with the vehicles that left the flight, a
            link lost or another mode, when others fly on; if it returns True the flight goes
            on without them (a replan has begun: :meth:`replace` or :meth:`halt` follows):
            they are no longer watched, told to hold on a stop or checked in any clause.
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
        on_start: Callable[[float], None] | None = None,
        warn_off_plan_m: float | None = None,
        max_off_plan_m: float | None = None,
        on_warning: Callable[[str], None] | None = None,
        clock: Callable[[], float] | None = None,
        wait: Callable[[asyncio.Event, float], Awaitable[bool]] | None = None,
        ride_out_link_loss: bool = False,
        on_departure: Callable[[Sequence[VehicleLeft]], bool] | None = None,
    ) -> None:
        if not (math.isfinite(horizon_s) and horizon_s >= 0):
            raise LinkError(f"monitor horizon_s must be >= 0, got {horizon_s!r}")
        if steps < 1:
            raise LinkError(f"monitor steps must be >= 1, got {steps!r}")
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise LinkError(f"monitor rate_hz must be > 0, got {rate_hz!r}")
        self.horizon_s = float(horizon_s)
        self.steps = int(steps) if horizon_s > 0 else 1
        self.rate_hz = float(rate_hz)
        self.action = action
        self.stale_after_s = stale_after_s
        self.offboard_loss_s = offboard_loss_s
        self.on_start = on_start
        for what, bound in (("warn_off_plan_m", warn_off_plan_m), ("max_off_plan_m", max_off_plan_m)):  # fmt: skip
            if bound is not None and not (math.isfinite(bound) and bound > 0):
                raise LinkError(f"monitor {what} must be > 0, got {bound!r}")
        self.warn_off_plan_m = warn_off_plan_m
        self.max_off_plan_m = max_off_plan_m
        self.on_warning = on_warning
        self.ride_out_link_loss = ride_out_link_loss
        self._clock = clock  # None: the fleet's, from run()
        self._wait = wait
        self.on_departure = on_departure
        #: vehicles that left the flight and are no longer watched (on_departure)
        self.excused: set[str] = set()
        self._halt: tuple[Verdict, tuple[str, ...], float, str] | None = None
        self._plans: Mapping[str, Trajectory] | None = None
        self._next: tuple[Mapping[str, Trajectory] | None, tuple[SafetyClause, ...]] | None = None
        self.stats = MonitorStats()
        self._table: tuple[tuple[int, ...], tuple[str, ...], _PlanTable] | None = None
        self._set_clauses(clauses)

    def _set_clauses(self, clauses: Sequence[SafetyClause]) -> None:
        """The invariants checked from now on, batched per template."""
        self.clauses = tuple(clauses)
        self._batch = ClauseBatch([c.formula for c in self.clauses])
        # the signals the clauses read, and per clause the rows of its vehicles (padded with
        # the extra last row, always "present")
        self._signals = tuple(sorted({n for c in self.clauses for n in c.formula.signal_names()}))
        self._signal_row = {n: k for k, n in enumerate(self._signals)}
        width = max((len(c.vehicles) for c in self.clauses), default=0)
        self._clause_rows = np.full((len(self.clauses), width), len(self._signals), dtype=int)
        for i, c in enumerate(self.clauses):
            for j, name in enumerate(c.vehicles):
                self._clause_rows[i, j] = self._signal_row.get(name, len(self._signals))
        self._ends = np.array([c.end_s for c in self.clauses])
        self._starts = np.array([c.start_s for c in self.clauses])

    def replace(
        self, plans: Mapping[str, Trajectory] | None, clauses: Sequence[SafetyClause]
    ) -> None:
        """After a replan: predict along ``plans`` and check ``clauses`` from the next tick
        (called on the event loop; taken up between two ticks, never during one on the
        monitor's thread)."""
        self._next = (plans, tuple(clauses))

    def halt(self, verdict: Verdict, vehicles: Sequence[str], t_s: float, detail: str) -> None:
        """Stop the flight at the next tick with this finding (a replan that found no plan);
        called on the event loop."""
        self._halt = (verdict, tuple(vehicles), t_s, detail)

    @property
    def halted(self) -> bool:
        """Whether :meth:`halt` was called."""
        return self._halt is not None

    @property
    def checks(self) -> int:
        """Evaluations done in the last run (for tests and reports)."""
        return self.stats.checks

    def _plan_table(
        self, names: tuple[str, ...], plans: Mapping[str, Trajectory] | None
    ) -> _PlanTable:
        chosen = [None if plans is None else plans.get(n) for n in names]
        # the cached table holds these trajectories, so their ids cannot be reused meanwhile
        key = tuple(id(p) for p in chosen)
        if self._table is None or self._table[0] != key or self._table[1] != names:
            self._table = (key, names, _PlanTable(chosen))
        return self._table[2]

    def predict_all(
        self,
        t_s: float,
        pos_enu_m: np.ndarray,
        vel_enu_m_s: np.ndarray,
        table: _PlanTable,
        age_s: np.ndarray | None = None,
    ) -> tuple[np.ndarray, float]:
        """Predicted positions ``(N, steps + 1, 3)`` at ``t_s + j * dt`` and the step ``dt``.

        Each vehicle keeps following its plan with the tracking error of its last sample
        (taken ``age_s`` before ``t_s``), the error growing with that sample's velocity error;
        without a plan it keeps its velocity.
        """
        n = pos_enu_m.shape[0]
        age = np.zeros(n) if age_s is None else np.asarray(age_s, dtype=float)
        dt = self.horizon_s / self.steps if self.horizon_s > 0 else 1.0
        tau = np.arange(self.steps + 1) * dt if self.horizon_s > 0 else np.zeros(1)
        since = tau[None, :] + age[:, None]  # (N, S): from the sample to each prediction
        out = pos_enu_m[:, None, :] + since[..., None] * vel_enu_m_s[:, None, :]
        if table.has.any():
            t_sample = (t_s - age)[:, None]
            ref = table.state(np.broadcast_to(t_s + tau, (n, tau.size)), 0)
            ref0 = table.state(t_sample, 0)[:, 0]
            vref0 = table.state(t_sample, 1)[:, 0]
            along = (
                ref
                + (pos_enu_m - ref0)[:, None, :]
                + since[..., None] * (vel_enu_m_s - vref0)[:, None, :]
            )
            out[table.has] = along[table.has]
        return out, dt

    def predict(
        self,
        t_s: float,
        pos_enu_m: np.ndarray,
        vel_enu_m_s: np.ndarray,
        plan: Trajectory | None,
    ) -> tuple[np.ndarray, float]:
        """Predicted positions ``(steps + 1, 3)`` of one vehicle (see :meth:`predict_all`)."""
        pred, dt = self.predict_all(
            t_s, np.asarray(pos_enu_m, float)[None], np.asarray(vel_enu_m_s, float)[None],
            _PlanTable([plan]),
        )  # fmt: skip
        return pred[0], dt

    def evaluate(
        self,
        t_s: float,
        states: Mapping[str, tuple[np.ndarray, np.ndarray]],
        plans: Mapping[str, Trajectory] | None = None,
        ages_s: Mapping[str, float] | None = None,
    ) -> tuple[Verdict, SafetyClause, float, float] | None:
        """Check every active clause at plan time ``t_s``.

        A clause is violated if its robustness is negative now; otherwise it is predicted to
        fail if negative at a predicted sample inside its interval. Violations come first,
        then predictions; among each, the clauses in order.

        Args:
            t_s: seconds from the plan's start.
            states: per vehicle, (position ``(3,)``, velocity ``(3,)``) in mission ENU.
            plans: the vehicles' planned trajectories (for the prediction).
            ages_s: per vehicle, how old its state is (s; default 0).

        Returns:
            ``(verdict, clause, robustness, predicted_in_s)`` of the failing clause, or
            ``None``.
        """
        if not self.clauses:
            return None
        names = tuple(states)
        if names:
            pos = np.array([np.asarray(states[n][0], dtype=float) for n in names])
            vel = np.array([np.asarray(states[n][1], dtype=float) for n in names])
            age = np.array([(ages_s or {}).get(n, 0.0) for n in names])
            pred, dt = self.predict_all(t_s, pos, vel, self._plan_table(names, plans), age)
        else:
            pred, dt = np.zeros((0, self.steps + 1, 3)), 1.0
        rows = pred.shape[1]
        # every signal the clauses read, in one array (zeros for a vehicle without a state,
        # whose clauses are inactive)
        stack = np.zeros((len(self._signals) + 1, rows, 3))
        have = np.zeros(len(self._signals) + 1, dtype=bool)
        have[-1] = True  # the padding of one-vehicle clauses
        for k, name in enumerate(names):
            j = self._signal_row.get(name)
            if j is not None:
                stack[j] = pred[k]
                have[j] = True
        present = have[self._clause_rows].all(axis=1)
        active = present & (self._starts <= t_s) & (t_s <= self._ends)
        if not active.any():
            return None
        traces = self._batch.traces_of(stack[:-1], self._signals, dt)  # (C, S)
        now = active & (traces[:, 0] < 0)
        if now.any():
            i = int(np.argmax(now))
            return Verdict.VIOLATED, self.clauses[i], float(traces[i, 0]), 0.0
        inside = (t_s + np.arange(rows) * dt)[None, :] <= self._ends[:, None]
        bad = active[:, None] & inside & (traces < 0)
        if not bad.any():
            return None
        i = int(np.argmax(bad.any(axis=1)))
        j = int(np.argmax(bad[i]))
        return Verdict.PREDICTED, self.clauses[i], float(traces[i][inside[i]].min()), j * dt

    def evaluate_runs(
        self,
        t_s: float,
        names: Sequence[str],
        pos_enu_m: np.ndarray,
        vel_enu_m_s: np.ndarray,
        plans: Mapping[str, Trajectory] | None = None,
    ) -> RunFindings:
        """One tick of many simultaneous flights of the same fleet (the batch simulator).

        Per run, what a :meth:`run` tick would decide on that run's fresh telemetry: the
        tracking alarm past ``max_off_plan_m`` first, then :meth:`evaluate` (a clause
        violated now, then one predicted to fail), vectorised over runs: the runs'
        predicted samples are laid end to end, which is exact because the clauses are
        atemporal (each sample's robustness reads that sample only).

        Args:
            t_s: seconds from the plan's start (the same for every run).
            names: the vehicles, in the order of the arrays' second axis.
            pos_enu_m, vel_enu_m_s: ``(R, V, 3)`` every run's vehicles, mission ENU.
            plans: the vehicles' planned trajectories.
        """
        pos = np.asarray(pos_enu_m, dtype=float)
        vel = np.asarray(vel_enu_m_s, dtype=float)
        n_runs, n_veh, _ = pos.shape
        out = RunFindings.none(n_runs)
        table = self._plan_table(tuple(names), plans)
        dt = self.horizon_s / self.steps if self.horizon_s > 0 else 1.0
        tau = np.arange(self.steps + 1) * dt if self.horizon_s > 0 else np.zeros(1)
        rows = tau.size
        # each vehicle's plan is the same in every run: evaluated once per vehicle
        ref = table.state(np.broadcast_to(t_s + tau, (n_veh, rows)), 0)  # (V, S, 3)
        ref0 = table.state(np.full((n_veh, 1), t_s), 0)[:, 0]
        vref0 = table.state(np.full((n_veh, 1), t_s), 1)[:, 0]
        has = table.has[None, :, None, None]
        pred = np.where(
            has,
            ref[None] + (pos - ref0)[:, :, None] + tau[:, None] * (vel - vref0)[:, :, None],
            pos[:, :, None] + tau[:, None] * vel[:, :, None],
        )  # (R, V, S, 3)
        if self.max_off_plan_m is not None and table.has.any():
            off = np.where(table.has, np.linalg.norm(pos - ref0, axis=2), 0.0)  # (R, V)
            far = (off > self.max_off_plan_m).any(axis=1)
            out.code[far] = RunFindings.code_of(Verdict.OFF_PLAN)
            out.value[far] = off[far].max(axis=1)
        if not self.clauses:
            return out
        active = (self._starts <= t_s) & (t_s <= self._ends)
        if not active.any():
            return out
        row_of = {n: k for k, n in enumerate(names)}
        missing = [s for s in self._signals if s not in row_of]
        if missing:
            raise LinkError(f"evaluate_runs: no state for {', '.join(missing)}")
        stack = np.stack([pred[:, row_of[s]].reshape(n_runs * rows, 3) for s in self._signals])
        traces = self._batch.traces_of(stack, self._signals, dt).reshape(-1, n_runs, rows)
        open_ = out.code == 0
        now = active[:, None] & (traces[:, :, 0] < 0)  # (C, R)
        hit = open_ & now.any(axis=0)
        first = np.argmax(now, axis=0)
        out.code[hit] = RunFindings.code_of(Verdict.VIOLATED)
        out.clause[hit] = first[hit]
        out.value[hit] = traces[first[hit], np.flatnonzero(hit), 0]
        inside = (t_s + tau)[None, :] <= self._ends[:, None]  # (C, S)
        bad = active[:, None, None] & inside[:, None, :] & (traces < 0)  # (C, R, S)
        later = open_ & ~hit & bad.any(axis=(0, 2))
        if later.any():
            runs = np.flatnonzero(later)
            c = np.argmax(bad[:, runs].any(axis=2), axis=0)
            s = np.argmax(bad[c, runs], axis=1)
            masked = np.where(inside[c], traces[c, runs], np.inf)
            out.code[runs] = RunFindings.code_of(Verdict.PREDICTED)
            out.clause[runs] = c
            out.value[runs] = masked.min(axis=1)
            out.ahead_s[runs] = s * dt
        return out

    def _tick(
        self,
        vehicles: Sequence[Vehicle],
        t0_monotonic_s: float,
        maps: Mapping[str, NedToEnuMap],
        origins: Mapping[str, GeodeticPoint],
        plans: Mapping[str, Trajectory] | None,
        expected_mode: Px4Mode | None,
        mode_grace_s: float,
        done: Callable[[str], bool] | None,
        clock: Callable[[], float],
    ) -> _Finding | None:
        """One evaluation on a snapshot of the telemetry, at ``clock()`` (runs on the
        monitor's thread)."""
        t_cpu = time.perf_counter()
        now = clock()
        t_s = now - t0_monotonic_s
        statuses = {v.name: v.status(now) for v in vehicles if v.name not in self.excused}
        try:
            lost = tuple(
                sorted(
                    n
                    for n, st in statuses.items()
                    if not st.connected
                    or (st.position_age_s is not None and st.position_age_s > self.offboard_loss_s)
                )
            )
            if lost and not self.ride_out_link_loss:
                return _Finding(Verdict.LINK_LOST, None, lost, t_s, None, None, now)
            if self.ride_out_link_loss:
                self._note_unheard(statuses, set(lost), t_s)
                statuses = {n: st for n, st in statuses.items() if n not in lost}
            if expected_mode is not None:
                left = {
                    n: st
                    for n, st in statuses.items()
                    if st.mode is not None
                    and st.mode is not expected_mode
                    and st.heartbeat_age_s is not None
                    and now - st.heartbeat_age_s > t0_monotonic_s + mode_grace_s
                    and not (st.mode in _MISSION_END_MODES and done is not None and done(n))
                }
                if left:
                    names = tuple(sorted(left))
                    detail = ", ".join(f"{n} now {left[n].mode.name}" for n in names)  # type: ignore[union-attr]
                    seen = min(now - float(left[n].heartbeat_age_s or 0.0) for n in names)
                    return _Finding(
                        Verdict.LEFT_MODE, None, names, t_s, None, None, seen,
                        exclude=names, detail=detail,
                    )  # fmt: skip
            moved = {
                n: float(np.linalg.norm(NedToEnuMap.between(o, st.origin).b))
                for n, st in statuses.items()
                if st.origin is not None and st.origin != (o := origins[n])
            }
            moved = {n: d for n, d in moved.items() if d > _ORIGIN_MOVE_M}
            if moved:
                names = tuple(sorted(moved))
                detail = ", ".join(f"{n} by {moved[n]:.2f} m" for n in names)
                return _Finding(
                    Verdict.ORIGIN_MOVED, None, names, t_s, None, None, now, detail=detail
                )
            states: dict[str, tuple[np.ndarray, np.ndarray]] = {}
            ages: dict[str, float] = {}
            for name, st in statuses.items():
                if st.pos_ned_m is None or st.vel_ned_m_s is None or st.position_age_s is None:
                    continue
                fmap = maps[name]
                states[name] = (fmap.position(st.pos_ned_m), fmap.vector(st.vel_ned_m_s))
                ages[name] = st.position_age_s
                if st.position_age_s > self.stale_after_s:
                    self.stats.stale[name] = self.stats.stale.get(name, 0) + 1
                    self.stats.stale_max_age_s[name] = max(
                        self.stats.stale_max_age_s.get(name, 0.0), st.position_age_s
                    )
            self.stats.checks += 1
            off = self._off_plan(t_s, states, plans, ages, now)
            if off is not None:
                return off
            found = self.evaluate(t_s, states, plans, ages)
            if found is None:
                return None
            verdict, clause, rho, ahead = found
            sample = now - max(ages[n] for n in clause.vehicles)
            return _Finding(verdict, clause, clause.vehicles, t_s, rho, ahead, sample)
        finally:
            self.stats.tick_s.append(time.perf_counter() - t_cpu)

    def _note_unheard(
        self, statuses: Mapping[str, VehicleStatus], lost: set[str], t_s: float
    ) -> None:
        """Open a stretch for each vehicle newly lost (from its last sample), close it for
        each heard again (at its fresh sample), and say so once each way."""
        for name, st in statuses.items():
            gaps = self.stats.unheard.get(name, [])
            age = st.position_age_s if st.position_age_s is not None else 0.0
            if name in lost and (not gaps or gaps[-1][1] is not None):
                self.stats.unheard.setdefault(name, []).append((t_s - age, None))
                if self.on_warning is not None:
                    self.on_warning(
                        f"{name}: link lost at t = {t_s - age:.1f} s: its mission flies on "
                        "board; waiting for its telemetry"
                    )
            elif name not in lost and gaps and gaps[-1][1] is None:
                gaps[-1] = (gaps[-1][0], t_s - age)
                if self.on_warning is not None:
                    self.on_warning(
                        f"{name}: heard again at t = {t_s - age:.1f} s, after "
                        f"{t_s - age - gaps[-1][0]:.1f} s; monitoring it again"
                    )

    def _off_plan(
        self,
        t_s: float,
        states: Mapping[str, tuple[np.ndarray, np.ndarray]],
        plans: Mapping[str, Trajectory] | None,
        ages: Mapping[str, float],
        now: float,
    ) -> _Finding | None:
        """The tracking alarm: record, warn, and past ``max_off_plan_m`` a stop finding."""
        if plans is None or (self.warn_off_plan_m is None and self.max_off_plan_m is None):
            return None
        names = tuple(states)  # the same table as the clauses' prediction (one cache)
        table = self._plan_table(names, plans)
        if not table.has.any():
            return None
        age = np.array([ages[n] for n in names])
        t_sample = np.clip(t_s - age, 0.0, None)[:, None]  # where the plan was at each sample
        ref = table.state(t_sample, 0)[:, 0]
        pos = np.array([states[n][0] for n in names])
        off = np.where(table.has, np.linalg.norm(pos - ref, axis=1), 0.0)
        st = self.stats
        for k, name in enumerate(names):
            if not table.has[k]:
                continue
            d = float(off[k])
            if d > st.off_plan_max_m.get(name, -1.0):
                st.off_plan_max_m[name] = d
                st.off_plan_max_t_s[name] = float(t_sample[k, 0])
            warn = self.warn_off_plan_m
            if warn is not None and d > warn and name not in st.warned:
                st.warned[name] = (float(t_sample[k, 0]), d)
                if self.on_warning is not None:
                    self.on_warning(
                        f"warning: {name} is {d:.2f} m from its plan at t={t_sample[k, 0]:.2f} s, "
                        f"more than the plan's margin {warn:.2f} m: the spec may not hold"
                    )
        bound = self.max_off_plan_m
        if bound is None or not (off > bound).any():
            return None
        far = tuple(n for n, d in zip(names, off, strict=True) if d > bound)
        detail = ", ".join(f"{n} {off[names.index(n)]:.2f} m" for n in far)
        detail += f" from the plan, more than the bound {bound:g} m"
        sample = now - max(ages[n] for n in far)
        return _Finding(Verdict.OFF_PLAN, None, far, t_s, None, None, sample, detail=detail)

    @property
    def templates(self) -> int:
        """How many distinct clause templates the clauses make (one evaluation each per
        tick: :class:`planner.stl.batch.ClauseBatch`)."""
        return self._batch.templates

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
        done: Callable[[str], bool] | None = None,
    ) -> SafetyEvent | None:
        """Monitor until ``stop`` is set; on a finding set ``stop``, command every vehicle, report.

        With ``expected_mode`` (OFFBOARD for a setpoint stream), a heartbeat received more than
        ``mode_grace_s`` after the start that shows another mode stops the flight: the vehicle's
        own failsafe took over, and it must not be streamed to or re-engaged without the
        operator.  A vehicle for which ``done(name)`` holds (on its mission's last item, or
        past it) may be in AUTO.LOITER, AUTO.RTL or AUTO.LAND: PX4 v1.17 switches there itself
        at a mission's end (a hold where a mission without a landing ends, a return item),
        and that heartbeat can come before the ground station has seen the mission end.

        Returns:
            The :class:`SafetyEvent`, or ``None`` if the flight ended without one.
        """
        clock = self._clock or fleet.clock.monotonic
        wait = self._wait or _waiter(fleet.clock)
        if self.on_start is not None:
            self.on_start(t0_monotonic_s)
        self.stats = MonitorStats()
        self._plans = plans
        maps = {v.name: NedToEnuMap.between(mission_origin, origins[v.name]) for v in vehicles}
        period = 1.0 / self.rate_hz
        loop = asyncio.get_running_loop()
        worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="stl-gcs-monitor")
        k = 0
        try:
            while not stop.is_set():
                # Half a period after the setpoint ticks, so an evaluation never delays a send.
                deadline = t0_monotonic_s + (k + 0.5) * period
                delay = deadline - clock()
                if delay > 0 and await wait(stop, delay):
                    break
                k = max(k + 1, int((clock() - t0_monotonic_s) / period - 0.5) + 1)
                if self._next is not None:  # a replan's plan, between two ticks
                    (self._plans, clauses), self._next = self._next, None
                    self._set_clauses(clauses)
                found = await loop.run_in_executor(
                    worker, self._tick, vehicles, t0_monotonic_s, maps, origins, self._plans,
                    expected_mode, mode_grace_s, done, clock,
                )  # fmt: skip
                if self._halt is not None and not stop.is_set():
                    verdict, names, t_s, detail = self._halt
                    found = _Finding(verdict, None, names, t_s, None, None, clock(), detail=detail)
                    return await self._stop(fleet, stop, found, clock())
                if found is not None and not stop.is_set():
                    if self._departed(found, vehicles, maps, t0_monotonic_s, clock()):
                        continue
                    return await self._stop(fleet, stop, found, clock())
        finally:
            worker.shutdown(wait=False, cancel_futures=True)
        return None

    def _departed(
        self,
        found: _Finding,
        vehicles: Sequence[Vehicle],
        maps: Mapping[str, NedToEnuMap],
        t0_monotonic_s: float,
        now: float,
    ) -> bool:
        """Whether the flight goes on without the vehicles of ``found`` (a lost link or another
        mode, others flying on, and ``on_departure`` accepting them)."""
        if self.on_departure is None or found.verdict not in (Verdict.LINK_LOST, Verdict.LEFT_MODE):
            return False
        names = set(found.vehicles)
        if not any(v.name not in names and v.name not in self.excused for v in vehicles):
            return False
        left = []
        for v in vehicles:
            if v.name not in names:
                continue
            st = v.status(now)
            age = st.position_age_s if st.position_age_s is not None else 0.0
            pos = None
            if st.pos_ned_m is not None:
                pos = tuple(float(x) for x in maps[v.name].position(st.pos_ned_m))
            left.append(
                VehicleLeft(
                    v.name,
                    found.verdict,
                    now - t0_monotonic_s - age,
                    pos,  # type: ignore[arg-type]
                    None if found.verdict is Verdict.LINK_LOST else st.mode,
                )
            )
        if not self.on_departure(left):
            return False
        self.excused |= names
        return True

    async def _stop(
        self, fleet: Fleet, stop: asyncio.Event, found: _Finding, t_command: float
    ) -> SafetyEvent:
        stop.set()
        others = [v for v in fleet if v.name not in found.exclude and v.name not in self.excused]
        failures = await fleet.for_each(lambda v: safe_stop(v, self.action), others)
        return SafetyEvent(
            verdict=found.verdict,
            clause=None if found.clause is None else found.clause.name,
            vehicles=found.vehicles,
            t_s=found.t_s,
            robustness=found.robustness,
            predicted_in_s=None if found.verdict is not Verdict.PREDICTED else found.ahead_s,
            action=self.action,
            action_failures={k: str(e) for k, e in failures.items()},
            detail=found.detail,
            latency_s=t_command - found.sample_monotonic_s,
        )


def _waiter(clock: Clock) -> Callable[[asyncio.Event, float], Awaitable[bool]]:
    """``wait(stop, delay_s)`` on ``clock``: until ``stop`` is set or ``delay_s`` has passed;
    whether it is set."""

    async def wait(stop: asyncio.Event, delay_s: float) -> bool:
        if stop.is_set():
            return True
        timer = asyncio.ensure_future(clock.sleep(delay_s))
        stopped = asyncio.ensure_future(stop.wait())
        try:
            await asyncio.wait((timer, stopped), return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in (timer, stopped):
                task.cancel()
        return stop.is_set()

    return wait
