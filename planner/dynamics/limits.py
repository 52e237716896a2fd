"""A vehicle's kinematic limits, in the two forms a user states them, and their sound linear
encodings for the planner.

Per axis (the original form): ``|v_x| <= v_max[0]``, ``|v_y| <= v_max[1]``,
``|v_z| <= v_max[2]``. PX4's form (``MPC_XY_VEL_MAX``, ``MPC_Z_VEL_MAX_UP`` /
``MPC_Z_VEL_MAX_DN``; ``MPC_ACC_HOR_MAX``, ``MPC_ACC_UP_MAX`` / ``MPC_ACC_DOWN_MAX``): the
horizontal speed bounded as a norm, ``|(v_x, v_y)| <= v_xy``, and the vertical speed by
different bounds up and down, ``-v_down <= v_z <= v_up``. Both forms can be given at once;
each bound holds. The same for the acceleration. :class:`Bounds` is one derivative's
limits with every bound filled in (``inf`` where there is none); :func:`vehicle_bounds`
reads them from a scenario's or a plan file's vehicle.

The planner's constraints are linear (:mod:`planner.dynamics.linear`: Bernstein control
points bounded per axis). The norm bound becomes the regular ``NORM_SIDES``-gon inscribed
in the disc of radius ``v_xy``: ``n_k . (v_x, v_y) <= v_xy cos(pi / NORM_SIDES)`` for the
outward normals ``n_k``, every ``2 pi / NORM_SIDES``. A polygon inside the disc is a sound
inner approximation (control points in the polygon put the whole curve in it, by the
convex hull); it gives up at most ``1 - cos(pi / NORM_SIDES)`` = 3.4 % of the speed (in the
directions between the polygon's vertices). Two of the normals are the x and y axes (the
per-axis rows, their bounds lowered to the polygon's); the others are
:data:`NORM_DIRECTIONS`, extra rows that couple x and y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "NORM_DIRECTIONS",
    "NORM_SIDES",
    "PX4_LIMIT_KEYS",
    "Bounds",
    "vehicle_bounds",
]

#: The PX4-like limit fields of a vehicle (scenario ``limits:`` keys, plan-file ``limits``
#: keys and :class:`planner.problem.Vehicle` fields alike; optional, > 0).  The last, the
#: turn rate a heading schedule may ask for (PX4's MPC_YAWRAUTO_MAX), is checked by
#: :func:`planner.checks.check_trajectories` (45 deg/s when not given).
PX4_LIMIT_KEYS = (
    "v_xy_max_m_s",
    "v_up_max_m_s",
    "v_down_max_m_s",
    "a_xy_max_m_s2",
    "a_up_max_m_s2",
    "a_down_max_m_s2",
    "yaw_rate_max_deg_s",
)

#: Sides of the polygon inscribed in the horizontal-norm disc (even, a multiple of 4 so
#: that the x and y axes are among its normals).
NORM_SIDES = 12
#: ``(n, 2)`` unit normals ``(cos, sin)`` of the polygon's two-sided rows other than the
#: x and y axes (each row bounds ``n . v`` from both sides, so covers two opposite sides).
NORM_DIRECTIONS: NDArray[np.float64] = np.array(
    [
        (math.cos(th), math.sin(th))
        for k in range(1, NORM_SIDES // 2)
        if 4 * k != NORM_SIDES
        for th in (2.0 * math.pi * k / NORM_SIDES,)
    ]
)
NORM_DIRECTIONS.setflags(write=False)
#: Inradius / circumradius of the polygon.
_INSCRIBED = math.cos(math.pi / NORM_SIDES)


@dataclass(frozen=True, slots=True)
class Bounds:
    """One derivative's limits (velocity in m/s or acceleration in m/s^2).

    ``lo[i] <= x_i <= hi[i]`` per ENU axis (``lo <= 0 <= hi``) and
    ``|(x_0, x_1)| <= xy`` (``inf``: no norm bound).
    """

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    xy: float = math.inf

    def ratio(self, values: NDArray[np.float64]) -> float:
        """The largest ``value / bound`` over samples ``(n, 3)`` (1: at a limit)."""
        x = np.asarray(values, dtype=float).reshape(-1, 3)
        if not len(x):
            return 0.0
        hi, lo = np.asarray(self.hi), np.asarray(self.lo)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(x > 0, x / hi, np.where(x < 0, x / lo, 0.0))
        out = float(np.nanmax(r))
        if math.isfinite(self.xy):
            out = max(out, float(np.max(np.hypot(x[:, 0], x[:, 1]))) / self.xy)
        return out

    @property
    def has_norm(self) -> bool:
        """True when the horizontal norm is bounded."""
        return math.isfinite(self.xy)

    def linear(self) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """The planner's sound linear form: ``(lo (3,), hi (3,), b)``, per-axis bounds and
        ``|n . (x_0, x_1)| <= b`` for every :data:`NORM_DIRECTIONS` row (``b = inf``
        without a norm bound). With one, the axis bounds are at most ``b`` too: together the
        rows are the inscribed polygon."""
        lo, hi = np.array(self.lo, dtype=float), np.array(self.hi, dtype=float)
        if not self.has_norm:
            return lo, hi, math.inf
        b = self.xy * _INSCRIBED
        hi[:2] = np.minimum(hi[:2], b)
        lo[:2] = np.maximum(lo[:2], -b)
        return lo, hi, b

    def box(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """A per-axis box inside these limits (the initial guess's per-axis form): the
        axis bounds, horizontally shrunk into the inscribed polygon."""
        lo, hi, b = self.linear()
        if math.isfinite(b):
            c = b / float(np.max(np.abs(NORM_DIRECTIONS).sum(axis=1)))
            hi[:2] = np.minimum(hi[:2], c)
            lo[:2] = np.maximum(lo[:2], -c)
        return lo, hi


def _opt(vehicle: Any, field: str) -> float:
    value = getattr(vehicle, field, None)
    return math.inf if value is None else float(value)


def vehicle_bounds(vehicle: Any) -> tuple[Bounds, Bounds]:
    """``(velocity, acceleration)`` bounds of a vehicle with the scenario's limit fields:
    ``v_max_m_s``/``a_max_m_s2`` (per axis, both signs) and the optional
    ``v_xy_max_m_s``, ``v_up_max_m_s``, ``v_down_max_m_s``, ``a_xy_max_m_s2``,
    ``a_up_max_m_s2``, ``a_down_max_m_s2`` (each bound holds)."""
    out = []
    for per_axis, xy, up, down in (
        ("v_max_m_s", "v_xy_max_m_s", "v_up_max_m_s", "v_down_max_m_s"),
        ("a_max_m_s2", "a_xy_max_m_s2", "a_up_max_m_s2", "a_down_max_m_s2"),
    ):
        m = [float(c) for c in getattr(vehicle, per_axis)]
        hi = (m[0], m[1], min(m[2], _opt(vehicle, up)))
        lo = (-m[0], -m[1], -min(m[2], _opt(vehicle, down)))
        out.append(Bounds(lo=lo, hi=hi, xy=_opt(vehicle, xy)))
    return out[0], out[1]
