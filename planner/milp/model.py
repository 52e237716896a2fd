"""The coarse vehicle model of the combinatorial stage: positions on a time grid, with limits.

Per vehicle ``v`` the program has positions ``p_j`` (3 columns, ENU metres) at the times
``t_j = j dt_c``, ``j = 0..N``, and these linear rows:

* ``p_0`` fixed at the vehicle's start; every ``p_j`` in the workspace (its bounding box as
  column bounds, a prism's walls as rows);
* per axis ``lo_v dt_c <= p_{j+1} - p_j <= hi_v dt_c`` (the velocity limits of
  :func:`planner.dynamics.limits.vehicle_bounds`; a horizontal-norm limit ``v_xy`` as ``|v_x|, |v_y|
  <= v_xy`` and ``|v_x| + |v_y| <= sqrt(2) v_xy``);
* per axis ``lo_a dt_c^2 <= p_{j+1} - 2 p_j + p_{j-1} <= hi_a dt_c^2`` (the acceleration
  limits, the norm likewise);
* the start at rest: ``lo_a dt_c^2 / 2 <= p_1 - p_0 <= hi_a dt_c^2 / 2``; where the plan must
  end at rest (``timing.end: rest``, :attr:`planner.problem.Timing.end_at_rest`),
  ``-hi_a dt_c^2 / 2 <= p_N - p_{N-1} <= -lo_a dt_c^2 / 2``.

Every row is a *sound relaxation* of the continuous limits: any trajectory with
``lo_v <= v(t) <= hi_v`` and ``lo_a <= a(t) <= hi_a`` at every instant (the minimum-jerk
primitives' constraints, or the double integrator's) meets them at its samples, because
``p_{j+1} - p_j`` is the integral of ``v`` over one step and the second difference is the
integral of ``a`` against a hat of area ``dt_c^2``; from rest ``|v(t)| <= a t``. So an
infeasible coarse model means no trajectory within the limits exists (for the spec as the
coarse grid samples it), while a coarse path is only a start for the NLP: it need not be
flyable as it is. Positions are also bounded per step by what the limits can reach from the
start (a box growing with ``t``), which tightens every big-M of the encoding.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.dynamics.limits import Bounds, vehicle_bounds
from planner.milp.builder import MilpBuilder
from planner.problem import Problem, Vehicle
from planner.spec.regions import Prism
from planner.stl import Always, Eventually, Formula, SamplingError, Until, interval_steps

__all__ = ["MIN_SAMPLES", "SAMPLE_BUDGET", "CoarseModel", "choose_dt", "temporal_intervals"]

#: Default size of the coarse model: vehicles x samples at most this (a coarser grid than
#: the planning step ``Ts`` is chosen beyond it), but never fewer than
#: :data:`MIN_SAMPLES` samples per vehicle.  Measured on the zoo (HiGHS, one thread): the
#: power-line missions solve to optimality in 1-4 s at about 10 samples per vehicle and
#: find no positive incumbent in 20 s at 40-80 (keep-out binaries grow with the samples).
SAMPLE_BUDGET = 48
MIN_SAMPLES = 16
_TOL = 1e-9


def temporal_intervals(formulas: Sequence[Formula]) -> set[tuple[float, float]]:
    """The ``[a, b]`` (seconds) of every temporal operator in the formulas."""
    out: set[tuple[float, float]] = set()
    for f in formulas:
        for node in f.walk():
            if isinstance(node, Always | Eventually | Until):
                out.add((node.start_s, node.end_s))
    return out


def _divides(dt: float, value: float) -> bool:
    ratio = value / dt
    return abs(ratio - round(ratio)) <= _TOL * max(1.0, abs(ratio))


def _grid_ok(dt: float, intervals: set[tuple[float, float]]) -> bool:
    try:
        for a, b in intervals:
            interval_steps(a, b, dt)
    except SamplingError:
        return False
    return True


def choose_dt(problem: Problem, formulas: Sequence[Formula], budget: int = SAMPLE_BUDGET) -> float:
    """The coarse step (s): the smallest multiple ``k Ts`` of the sample step that divides
    the horizon, leaves a sample in every temporal interval of the spec (steps
    ``ceil(a/dt) .. floor(b/dt)``, docs/stl.md, "Semantics") and keeps
    ``N + 1 <= max(budget / vehicles, MIN_SAMPLES)``; the largest such multiple when none
    is small enough; ``Ts`` itself when no multiple qualifies."""
    ts, horizon = problem.timing.sample_dt_s, problem.timing.horizon_s
    nv = max(1, len(problem.vehicles))
    intervals = temporal_intervals(formulas)
    valid = [
        k * ts
        for k in range(1, max(1, math.floor(horizon / ts + _TOL)) + 1)
        if _divides(k * ts, horizon) and _grid_ok(k * ts, intervals)
    ]
    if not valid:
        return ts
    per_vehicle = max(budget // nv, MIN_SAMPLES)
    for dt in valid:
        if round(horizon / dt) + 1 <= per_vehicle:
            return dt
    return valid[-1]


def _reach(
    bounds_v: Bounds, bounds_a: Bounds, t: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per-axis displacement range from rest after ``t`` seconds, (n, 3) each: ``a t^2 / 2``
    until the speed limit, then ``v t - v^2 / (2 a)``."""

    def one(v: NDArray[np.float64], a: NDArray[np.float64]) -> NDArray[np.float64]:
        v, a = np.abs(v), np.maximum(np.abs(a), 1e-12)
        tt = t[:, None]
        accel = 0.5 * a * tt**2
        cruise = v * tt - v**2 / (2.0 * a)
        return np.where(tt * a <= v, accel, cruise)

    vlo, vhi = _axis_bounds(bounds_v)
    alo, ahi = _axis_bounds(bounds_a)
    return -one(vlo, alo), one(vhi, ahi)


def _axis_bounds(b: Bounds) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per-axis ``(lo, hi)`` implied by the bounds (a norm bound caps each horizontal axis)."""
    lo, hi = np.array(b.lo, dtype=float), np.array(b.hi, dtype=float)
    if b.has_norm:
        hi[:2] = np.minimum(hi[:2], b.xy)
        lo[:2] = np.maximum(lo[:2], -b.xy)
    return lo, hi


def second_differences(cols: NDArray[np.int64]) -> NDArray[np.int64]:
    """``(3 (N - 1), 3)``: for each inner sample and axis, the columns of ``p_{j+1}``, ``p_j``
    and ``p_{j-1}`` (the stencil ``1, -2, 1`` of an acceleration), from ``(N + 1, 3)``
    position columns."""
    return np.stack([cols[2:], cols[1:-1], cols[:-2]], axis=-1).reshape(-1, 3)


@dataclass(frozen=True, slots=True)
class VehicleColumns:
    """One vehicle's columns and their bounds.

    Attributes:
        name: the vehicle (the spec's signal name).
        cols: (N + 1, 3) column indices of ``p_j``.
        lo, hi: (N + 1, 3) bounds of ``p_j`` (workspace and reach from the start), ENU m.
    """

    name: str
    cols: NDArray[np.int64]
    lo: NDArray[np.float64]
    hi: NDArray[np.float64]


class CoarseModel:
    """Position columns and limit rows of every vehicle, added to a :class:`MilpBuilder`.

    Attributes:
        dt_s: the grid step ``dt_c`` (s); ``n_steps``: ``N`` (samples ``0..N``).
        vehicles: name -> :class:`VehicleColumns`.
    """

    def __init__(self, problem: Problem, builder: MilpBuilder, dt_s: float) -> None:
        if not (math.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_c must be a positive number of seconds, got {dt_s!r}")
        self.problem = problem
        self.dt_s = float(dt_s)
        self.n_steps = math.floor(problem.timing.horizon_s / dt_s + _TOL)
        if self.n_steps < 1:
            raise ValueError(
                f"dt_c {dt_s:g} s leaves no step in the horizon {problem.timing.horizon_s:g} s"
            )
        self.times_s = (np.arange(self.n_steps + 1) * self.dt_s).astype(np.float64)
        self.vehicles: dict[str, VehicleColumns] = {}
        for v in problem.vehicles:
            self.vehicles[v.name] = self._add_vehicle(builder, v)

    def _add_vehicle(self, builder: MilpBuilder, vehicle: Vehicle) -> VehicleColumns:
        n, dt = self.n_steps + 1, self.dt_s
        ws = self.problem.workspace
        start = np.asarray(vehicle.start_enu_m, dtype=float)
        ws_lo = np.minimum(np.asarray(ws.lo_enu_m, dtype=float), start)
        ws_hi = np.maximum(np.asarray(ws.hi_enu_m, dtype=float), start)
        bv, ba = vehicle_bounds(vehicle)
        d_lo, d_hi = _reach(bv, ba, self.times_s)
        lo = np.clip(start + d_lo, ws_lo, ws_hi)
        hi = np.clip(start + d_hi, ws_lo, ws_hi)
        lo[0] = hi[0] = start
        cols = builder.add_vars(3 * n, lo.reshape(-1), hi.reshape(-1)).reshape(n, 3)
        vlo, vhi = _axis_bounds(bv)
        alo, ahi = _axis_bounds(ba)
        # first differences (velocity)
        self._diff_rows(builder, cols[1:], cols[:-1], vlo * dt, vhi * dt, bv, dt)
        # second differences (acceleration)
        if n >= 3:
            c2 = second_differences(cols)
            vals = np.tile([1.0, -2.0, 1.0], (len(c2), 1))
            builder.add_rows(c2, vals, np.tile(alo * dt**2, n - 2), np.tile(ahi * dt**2, n - 2))
            if ba.has_norm:
                self._norm_rows(builder, c2, np.array([1.0, -2.0, 1.0]), ba.xy * dt**2)
        # from rest, and to rest where the plan ends at rest
        half = 0.5 * dt**2
        self._diff_rows(builder, cols[1:2], cols[0:1], alo * half, ahi * half, None, dt)
        if self.problem.timing.end_at_rest:
            self._diff_rows(builder, cols[-1:], cols[-2:-1], -ahi * half, -alo * half, None, dt)
        if isinstance(ws.shape, Prism):
            a, b = ws.half_spaces()
            walls = a[:-2]
            pc = np.repeat(cols[:, None, :2], len(walls), axis=1).reshape(-1, 2)
            pv = np.tile(walls[:, :2], (n, 1))
            builder.add_rows(pc, pv, -math.inf, np.tile(b[:-2], n))
        return VehicleColumns(vehicle.name, cols, lo, hi)

    @staticmethod
    def _diff_rows(
        builder: MilpBuilder,
        later: NDArray[np.int64],
        earlier: NDArray[np.int64],
        lo: NDArray[np.float64],
        hi: NDArray[np.float64],
        bounds: Bounds | None,
        dt: float,
    ) -> None:
        m = len(later)
        c = np.stack([later, earlier], axis=-1).reshape(-1, 2)
        vals = np.tile([1.0, -1.0], (len(c), 1))
        builder.add_rows(c, vals, np.tile(lo, m), np.tile(hi, m))
        if bounds is not None and bounds.has_norm:
            CoarseModel._norm_rows(builder, c, np.array([1.0, -1.0]), bounds.xy * dt)

    @staticmethod
    def _norm_rows(
        builder: MilpBuilder, c: NDArray[np.int64], stencil: NDArray[np.float64], bound: float
    ) -> None:
        """``|dx| + |dy| <= sqrt(2) bound`` (implied by ``|(dx, dy)| <= bound``), for the
        stencil rows ``c`` laid out (x, y, z) per sample: four rows each."""
        k = len(stencil)
        xy = c.reshape(-1, 3, k)[:, :2, :].reshape(-1, 2 * k)
        for sx, sy in ((1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)):
            vals = np.concatenate([sx * stencil, sy * stencil])
            builder.add_rows(xy, np.tile(vals, (len(xy), 1)), -math.inf, math.sqrt(2.0) * bound)

    def positions(self, x: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
        """Each vehicle's positions from a solution vector: name -> (N + 1, 3) ENU m."""
        return {name: x[vc.cols].copy() for name, vc in self.vehicles.items()}
