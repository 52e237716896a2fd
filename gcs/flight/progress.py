"""The live view of a flight: per vehicle its mode, its distance to where the plan is at that
instant, and the robustness of the clauses it takes part in *so far* (exact semantics of the
flown prefix completed by the plan for the rest of the horizon, i.e. what the spec's value
will be if the rest goes as planned).

A room of its own because it is the one part of a flight that runs beside it, on a worker
thread, and writes to the terminal: :func:`gcs.flight.fly_plan` only starts
:meth:`FlightProgress.run` and stops it, and :class:`PlanStarts` is how the flight tells the
view (and mission mode) when each vehicle's plan started.
"""

from __future__ import annotations

import asyncio
import bisect
import math
import shutil
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TextIO

import numpy as np

from gcs.flight.evaluation import heading_readers, plan_formula
from mavlink.tracks import wrap_pi
from planner.frames import NedToEnuMap, yaw_ned_to_enu
from planner.planfile import planned_signals
from planner.stl.batch import ClauseBatch

if TYPE_CHECKING:
    from mavlink.link.fleet import Fleet
    from planner.frames import GeodeticPoint, NedToEnuMap
    from planner.planfile import Plan

__all__ = ["FlightProgress", "PlanStarts"]


@dataclass(slots=True)
class PlanStarts:
    """The plan's start instant (on the fleet's clock, :mod:`mavlink.clock`) per vehicle, once
    the flight has one."""

    t0_monotonic_s: dict[str, float] = field(default_factory=dict)

    def plan_time(self, name: str, now: float) -> float | None:
        """Seconds since ``name``'s plan start, or ``None`` before it."""
        t0 = self.t0_monotonic_s.get(name)
        return None if t0 is None else now - t0


class FlightProgress:
    """Live view of a flight: per vehicle mode, distance to the plan, robustness so far.

    On a terminal one status line is rewritten in place (4 times a second); otherwise a
    plain line is printed every ``plain_interval_s``. "Robustness so far" of a vehicle is
    the minimum over the clauses it appears in of their exact robustness on its flown
    positions up to now followed by the plan for the rest of the horizon; where the spec
    reads the heading (``face``), its flown heading (ATTITUDE) likewise: NaN (shown
    ``n/a``) while a vehicle has flown without one.

    The work per update is bounded: the flown samples are written into the signals
    incrementally (only the grid steps since the last update), the clauses are evaluated
    per template (:class:`planner.stl.batch.ClauseBatch`), and :meth:`run` does that on a
    worker thread, so the setpoint stream on the event loop never waits for it.

    Args:
        plan: the plan being flown.
        stream: where to write (stdout, or stderr under ``--json``).
        tty: rewrite one line (default: ``stream.isatty()``).
        plain_interval_s: seconds between plain lines.
    """

    def __init__(
        self,
        plan: Plan,
        stream: TextIO | None = None,
        *,
        tty: bool | None = None,
        plain_interval_s: float = 2.0,
    ) -> None:
        self.stream = stream if stream is not None else sys.stdout
        self.tty = self.stream.isatty() if tty is None else tty
        self.plain_interval_s = plain_interval_s
        self.dt_s = max(plan.check_dt_s, 0.05)
        n = round(plan.horizon_s / self.dt_s) + 1
        self.t_grid = np.arange(n) * self.dt_s
        #: every vehicle flown, in plan order, and those that left it (``gcs fly --replan``)
        self.order = [v.name for v in plan.vehicles]
        self.left: dict[str, str] = {}
        self._samples: dict[str, list[tuple[float, ...]]] = {n: [] for n in self.order}
        self._headless: set[str] = set()  # flown without a known heading the spec reads
        self._lock = threading.Lock()  # record() and so_far() may run on different threads
        self._maps: dict[GeodeticPoint, NedToEnuMap] = {}  # per EKF origin
        self.lines = 0
        self.last_line = ""
        self._load(plan)

    def _load(self, plan: Plan) -> None:
        """The plan's signals and clauses (the flown samples so far written in again)."""

        phi = plan_formula(plan)
        # with the heading as a fourth column where the spec reads it (face)
        planned = planned_signals(plan, self.t_grid)
        names = [v.name for v in plan.vehicles]
        clauses = list(phi.clauses)
        members = {
            name: np.array([i for i, c in enumerate(clauses) if name in c.signal_names()], int)
            for name in names
        }
        reads_heading = {
            name: np.array([i for i, c in enumerate(clauses) if name in heading_readers(c)], int)
            for name in names
        }
        with self._lock:
            self.plan, self.phi, self.planned = plan, phi, planned
            self._heading = heading_readers(phi)
            self._batch = ClauseBatch(clauses)
            self._members = members
            self._reads_heading = reads_heading
            # the signals: flown up to _filled[name] grid steps, planned after
            self._signals = {name: p.copy() for name, p in planned.items()}
            self._filled = dict.fromkeys(names, 0)

    def replanned(self, plan: Plan, left: Mapping[str, str]) -> None:
        """Show the plan made after vehicles left (``left``: name -> why) from now on: the
        others' distances to it and their clauses of it; the vehicles that left as such."""
        self.left.update(left)
        self._load(plan)

    def _fill(
        self, name: str, t_now_s: float, signals: dict[str, np.ndarray], filled: dict[str, int]
    ) -> None:
        """Write the flown positions into the grid steps up to ``t_now_s`` not yet written
        (steps before the last sample only: a later sample could still move them)."""
        with self._lock:
            rows = self._samples[name]
            if not rows:
                return
            t_last = rows[-1][0]
            k0 = filled[name]
            k1 = int(np.searchsorted(self.t_grid, min(t_now_s, t_last), side="right"))
            if k1 <= k0:
                return
            # the samples around steps k0..k1-1: from the last one at or before step k0
            t_first = self.t_grid[k0]
            j = max(0, bisect.bisect_right(rows, (t_first, math.inf)) - 1)
            a = np.asarray(rows[j:])
        sig = signals[name]
        t = self.t_grid[k0:k1]
        for ax in range(3):
            sig[k0:k1, ax] = np.interp(t, a[:, 0], a[:, ax + 1])
        if sig.shape[1] > 3:
            # the flown heading, the shorter turn between samples; where none is known yet
            # (no ATTITUDE) the clauses reading it are unknown (so_far), never judged on the
            # planned heading the column still holds
            known = np.isfinite(a[:, 4])
            if known.any():
                sig[k0:k1, 3] = wrap_pi(np.interp(t, a[known, 0], np.unwrap(a[known, 4])))
            else:
                self._headless.add(name)
        filled[name] = k1

    def so_far(self, t_now_s: float) -> dict[str, float]:
        """Robustness so far per vehicle (see class docstring) at plan time ``t_now_s``."""
        with self._lock:  # one plan's state throughout (a replan swaps it, :meth:`_load`)
            signals, filled = self._signals, self._filled
            batch, members, reads_heading = self._batch, self._members, self._reads_heading
        for name in signals:
            self._fill(name, t_now_s, signals, filled)
        values = batch.values(signals, self.dt_s)
        for name in self._headless:
            if name in reads_heading:
                values[reads_heading[name]] = math.nan
        return {
            name: float(values[idx].min()) if idx.size else math.nan
            for name, idx in members.items()
        }

    def record(
        self, name: str, t_s: float, pos_enu_m: np.ndarray, yaw_enu_rad: float = math.nan
    ) -> None:
        """Add a position sample of ``name`` at plan time ``t_s`` (with the heading, mission
        ENU yaw in rad, NaN: unknown)."""
        with self._lock:
            rows = self._samples[name]
            if not rows or t_s > rows[-1][0]:
                p = pos_enu_m
                rows.append((t_s, float(p[0]), float(p[1]), float(p[2]), float(yaw_enu_rad)))

    def line(
        self,
        fleet: Fleet,
        starts: PlanStarts,
        origins: Mapping[str, GeodeticPoint],
        *,
        with_robustness: bool = True,
    ) -> str:
        """One status line for the current instant (and record the positions it read).

        ``with_robustness=False`` only records (the robustness is the costly part).
        """

        now = fleet.clock.monotonic()
        parts = []
        t_plan: float | None = None
        plan = self.plan
        for name in self.order:
            if name in self.left:
                parts.append(f"{name} left ({self.left[name]})")
                continue
            v = plan.vehicle(name)
            st = fleet[v.name].status(now)
            mode = st.mode.label if st.mode is not None else str(st.custom_mode)
            t = starts.plan_time(v.name, now)
            where = ""
            if st.pos_ned_m is not None and v.name in origins:
                origin = origins[v.name]
                fmap = self._maps.get(origin)
                if fmap is None:
                    fmap = self._maps[origin] = NedToEnuMap.between(self.plan.origin, origin)
                pos = fmap.position(st.pos_ned_m)
                ref_t = 0.0 if t is None else min(max(t, 0.0), v.trajectory.duration_s)
                ref = v.trajectory.position(np.array([ref_t]))[0]
                where = f" {float(np.linalg.norm(pos - ref)):5.2f} m"
                if t is not None and t >= 0.0:
                    yaw = math.nan
                    if v.name in self._heading and st.yaw_ned_rad is not None:
                        yaw = float(yaw_ned_to_enu(st.yaw_ned_rad, self.plan.origin, origin))
                    self.record(v.name, t, pos, yaw)
                    t_plan = t if t_plan is None else max(t_plan, t)
            parts.append(f"{v.name} {mode}{where}")
        if t_plan is not None and with_robustness:
            rho = self.so_far(t_plan)
            parts = [
                p
                if name not in rho
                else f"{p} rho n/a (no heading)"
                if name in self._headless and math.isnan(rho[name])
                else f"{p} rho {rho[name]:+.3f}"
                for p, name in zip(parts, self.order, strict=True)
            ]
            head = f"t {min(t_plan, self.plan.horizon_s):5.1f}/{self.plan.horizon_s:g} s"
        else:
            head = "preparing (distance to start)"
        return head + " | " + " | ".join(parts)

    def show(self, text: str) -> None:
        """Write ``text``: rewrite the status line on a terminal, else a new line."""
        with self._lock:
            self.lines += 1
            if self.tty:
                width = shutil.get_terminal_size((120, 20)).columns
                self.last_line = text[: width - 1]
                self.stream.write("\r\033[K" + self.last_line)
            else:
                self.last_line = text
                self.stream.write(text + "\n")
            self.stream.flush()

    def note(self, text: str) -> None:
        """Write ``text`` on a line of its own (the status line, if any, is redrawn after it).

        Safe from any thread (the safety monitor's warnings come from its own).
        """
        with self._lock:
            if self.tty and self.lines:
                self.stream.write("\r\033[K" + text + "\n" + self.last_line)
            else:
                self.stream.write(text + "\n")
            self.stream.flush()

    def close(self) -> None:
        """End the status line (terminal)."""
        if self.tty and self.lines:
            self.stream.write("\n")
            self.stream.flush()

    async def run(
        self,
        fleet: Fleet,
        starts: PlanStarts,
        origins: Mapping[str, GeodeticPoint],
        stop: asyncio.Event,
    ) -> None:
        """Sample positions every 0.1 s and show a line every 0.25 s (tty) or interval.

        Sampling and evaluation run on a worker thread (the event loop only waits for it),
        one at a time; only the writing is done here. The view refreshes on the wall clock
        (it is for a person), the plan's time is the fleet's.
        """
        show_every = 0.25 if self.tty else self.plain_interval_s
        next_show = time.monotonic()
        while not stop.is_set():
            due = time.monotonic() >= next_show
            text = await asyncio.to_thread(self.line, fleet, starts, origins, with_robustness=due)
            if due:
                self.show(text)
                next_show += show_every
            await asyncio.sleep(0.1)  # no child task: an interruption cancels those
