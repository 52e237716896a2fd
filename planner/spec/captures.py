"""When a plan takes pictures: the windows in which a vehicle faces an inspection target.

A *capture window* is a stretch of a plan in which a facing rule of the spec applies
(:func:`planner.spec.heading.facing_rules`: the vehicle is in the place of a conjunction holding
``face(d, T)``, or under a top-level ``always`` of ``face``) and the vehicle does face its
target (``face``'s exact margin >= 0) for at least ``min_s``.  Those are the hovers that
satisfy the spec's inspection clauses; the flight takes its pictures there
(``MAV_CMD_IMAGE_START_CAPTURE`` in a mission, or from the ground station in offboard).

The camera aims at the target's axis at the vehicle's own height (clamped to the target's
height range): the gimbal's pitch is the elevation of that point, usually level beside an
insulator.  Numpy only: plan files and flights use it without CasADi.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.spec.heading import facing_rules
from planner.spec.predicates import face_margin, face_tolerance_deg
from planner.stl import Formula
from planner.trajectory import Trajectory

__all__ = ["CaptureWindow", "aim_point", "capture_windows"]


@dataclass(frozen=True, slots=True)
class CaptureWindow:
    """One stretch of a plan in which ``vehicle`` faces ``target`` (module docstring).

    Attributes:
        vehicle, target: names (a vehicle, a region).
        t_start_s, t_end_s: the stretch, seconds from the plan's start.
        range_m: distance from the vehicle to the aim point, mid-window.
        gimbal_pitch_deg: elevation of the aim point seen from the vehicle, mid-window
            (negative: below the vehicle).
        aim_enu_m: the aim point mid-window, ENU metres.
    """

    vehicle: str
    target: str
    t_start_s: float
    t_end_s: float
    range_m: float
    gimbal_pitch_deg: float
    aim_enu_m: tuple[float, float, float]

    @property
    def duration_s(self) -> float:
        return self.t_end_s - self.t_start_s


def aim_point(target: Any, pos_enu_m: np.ndarray) -> np.ndarray:
    """The point the camera aims at from each position, (n, 3): the target's axis (its
    centre seen from above) at the vehicle's height, clamped to the target's heights."""
    p = np.asarray(pos_enu_m, dtype=float).reshape(-1, 3)
    c = target.center_enu_m
    z = np.clip(p[:, 2], target.lo_enu_m[2], target.hi_enu_m[2])
    return np.column_stack([np.full(len(p), c[0]), np.full(len(p), c[1]), z])


def capture_windows(
    formula: Formula,
    problem: Any,
    trajectories: Sequence[Trajectory],
    dt_s: float,
    horizon_s: float,
    min_s: float = 0.5,
) -> list[CaptureWindow]:
    """Every capture window of the plan, by start time (module docstring).

    Args:
        formula: the plan's whole spec; problem: its regions (``region(name)``).
        trajectories: the vehicles' trajectories, with their headings.
        dt_s: sample step of the search; horizon_s: the plan's length.
        min_s: the shortest stretch that counts.
    """
    rules = facing_rules(formula, problem)
    tol = face_tolerance_deg(problem)
    t = np.arange(math.floor(horizon_s / dt_s + 1e-9) + 1) * dt_s
    out: list[CaptureWindow] = []
    for tr in trajectories:
        mine = [r for r in rules if r.vehicle == tr.name]
        if not mine:
            continue
        pos = tr.position(t)
        sig = np.column_stack([pos, tr.yaw_rad(t)])
        for rule in mine:
            on = np.ones(len(t), dtype=bool)
            if rule.window_s is not None:
                on &= (t >= rule.window_s[0] - 1e-9) & (t <= rule.window_s[1] + 1e-9)
            if rule.where is not None:
                on &= np.all(pos @ rule.where.A.T <= rule.where.b + 1e-9, axis=1)
            target = problem.region(rule.target)
            on &= face_margin(sig, target, tol) >= 0.0
            idx = np.nonzero(on)[0]
            if idx.size == 0:
                continue
            for run in np.split(idx, np.nonzero(np.diff(idx) > 1)[0] + 1):
                t0, t1 = float(t[run[0]]), float(t[run[-1]])
                if t1 - t0 < min_s - 1e-9:
                    continue
                mid = run[len(run) // 2]
                aim = aim_point(target, pos[mid])[0]
                d = aim - pos[mid]
                out.append(
                    CaptureWindow(
                        tr.name,
                        rule.target,
                        t0,
                        t1,
                        float(np.linalg.norm(d)),
                        float(math.degrees(math.atan2(d[2], math.hypot(d[0], d[1])))),
                        (float(aim[0]), float(aim[1]), float(aim[2])),
                    )
                )
    return sorted(out, key=lambda w: (w.t_start_s, w.vehicle))
