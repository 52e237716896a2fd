"""Piecewise-polynomial vehicle trajectories and their sampling into timed setpoints.

A :class:`Trajectory` is a chain of contiguous segments; segment ``s`` starts at
``t0_s[s]`` (seconds from the plan's start, the first at 0), lasts ``duration_s[s]`` and
has per-axis power coefficients ``coeffs[s, axis, j]`` of the local time
``tau = t - t0_s[s]`` (ascending: ``p(tau) = sum_j coeffs[s, axis, j] tau^j``), axes ENU
in metres. Evaluation is exact and vectorised over any array of times.

Outside ``[0, duration_s]`` the vehicle holds: position clamped to the start/end
position, velocity, acceleration and jerk zero (a hover), yaw clamped. At exactly
``t = duration_s`` the end state of the last segment is returned.

Yaw (ENU: 0 = east, counter-clockwise positive; NED yaw = pi/2 - ENU yaw) follows a
:class:`YawPolicy`. The default is a constant heading ``yaw_rad``  (``YawMode.CONSTANT``, yaw 0 = facing
east): inspection flights usually keep the camera on one side and a constant heading
never spins the vehicle at low speed. ``YawMode.VELOCITY`` faces the horizontal direction
of travel while the horizontal speed is at least ``min_speed_m_s`` and otherwise keeps
the heading it had the last time it was that fast (``yaw_rad`` before it ever was); it is
evaluated exactly from the roots of ``|v_xy(t)|^2 - min_speed^2``, so the value at any
time does not depend on which other times are queried.  ``YawMode.SCHEDULE`` follows knots
(times and headings, linear in between along the shorter turn): the heading the spec's
``face`` asks for (:mod:`planner.spec.heading`).

Serialisation (the plan file's ``"segments"``, docs/scenario-format.md, "Plan files"):
:meth:`Trajectory.to_segments` gives JSON-ready lists of Python floats, one dict per
segment::

    {"t0_s": 0.0, "duration_s": 1.0, "coeffs": [[c0, c1, ...], [..y..], [..z..]],
     "yaw": {"mode": "constant", "yaw_rad": 0.0, "min_speed_m_s": 0.5}}

and :meth:`Trajectory.from_segments` rebuilds the identical trajectory (floats round-trip
exactly through ``json``).

Error tree::

    TrajectoryError(ValueError)    bad segment data (names the segment and field)
"""

from __future__ import annotations

import enum
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.errors import PlannerError

__all__ = ["Setpoints", "Trajectory", "TrajectoryError", "YawMode", "YawPolicy"]


class TrajectoryError(PlannerError, ValueError):
    """Invalid trajectory data; the message names the segment index and field."""


class YawMode(enum.Enum):
    """How a trajectory's yaw is chosen (see module docstring)."""

    CONSTANT = "constant"
    VELOCITY = "velocity"
    SCHEDULE = "schedule"


@dataclass(frozen=True, slots=True)
class YawPolicy:
    """Yaw rule of a trajectory.

    Attributes:
        mode: constant heading, facing the horizontal velocity, or a schedule.
        yaw_rad: ENU yaw (0 = east, CCW) for ``CONSTANT``; initial heading for ``VELOCITY``.
        min_speed_m_s: horizontal speed below which ``VELOCITY`` keeps its last heading.
        knots_t_s, knots_yaw_rad: ``SCHEDULE``: the heading at these times (increasing),
            linear in between along the shorter turn, held before the first and after the
            last (:mod:`planner.spec.heading` makes them from the spec's ``face``).
    """

    mode: YawMode = YawMode.CONSTANT
    yaw_rad: float = 0.0
    min_speed_m_s: float = 0.5
    knots_t_s: tuple[float, ...] = ()
    knots_yaw_rad: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not math.isfinite(self.yaw_rad):
            raise TrajectoryError("yaw.yaw_rad must be finite")
        if not (math.isfinite(self.min_speed_m_s) and self.min_speed_m_s > 0.0):
            raise TrajectoryError("yaw.min_speed_m_s must be finite and > 0")
        if self.mode is YawMode.SCHEDULE:
            t, y = np.asarray(self.knots_t_s, float), np.asarray(self.knots_yaw_rad, float)
            if t.size == 0 or t.shape != y.shape:
                raise TrajectoryError(
                    "yaw: a schedule needs as many knots_t_s as knots_yaw_rad (>= 1)"
                )
            if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y)) and np.all(np.diff(t) > 0)):
                raise TrajectoryError("yaw: a schedule's knots must be finite, at increasing times")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        out: dict[str, Any] = {
            "mode": self.mode.value,
            "yaw_rad": float(self.yaw_rad),
            "min_speed_m_s": float(self.min_speed_m_s),
        }
        if self.mode is YawMode.SCHEDULE:
            out["knots_t_s"] = [float(x) for x in self.knots_t_s]
            out["knots_yaw_rad"] = [float(x) for x in self.knots_yaw_rad]
        return out

    def schedule_at(self, t_s: NDArray[np.float64]) -> NDArray[np.float64]:
        """The scheduled heading at ``t_s`` (unwrapped: the turns as flown)."""
        t = np.asarray(self.knots_t_s, dtype=float)
        y = np.unwrap(np.asarray(self.knots_yaw_rad, dtype=float))
        return np.interp(t_s, t, y)

    @classmethod
    def from_dict(cls, data: Any, where: str = "yaw") -> YawPolicy:
        """Inverse of :meth:`to_dict`; ``where`` names the field in error messages."""
        if not isinstance(data, Mapping):
            raise TrajectoryError(f"{where}: expected an object, got {type(data).__name__}")
        try:
            mode = YawMode(data.get("mode", "constant"))
        except ValueError:
            raise TrajectoryError(
                f"{where}.mode: unknown yaw mode {data.get('mode')!r} "
                f"(expected one of {[m.value for m in YawMode]})"
            ) from None
        yaw = _number(data.get("yaw_rad", 0.0), f"{where}.yaw_rad")
        speed = _number(data.get("min_speed_m_s", 0.5), f"{where}.min_speed_m_s")
        knots: list[tuple[float, ...]] = [(), ()]
        if mode is YawMode.SCHEDULE:
            for j, key in enumerate(("knots_t_s", "knots_yaw_rad")):
                vals = data.get(key)
                if not isinstance(vals, list):
                    raise TrajectoryError(f"{where}.{key}: expected a list of numbers")
                knots[j] = tuple(_number(v, f"{where}.{key}[{i}]") for i, v in enumerate(vals))
        return cls(mode=mode, yaw_rad=yaw, min_speed_m_s=speed, knots_t_s=knots[0],
                   knots_yaw_rad=knots[1])  # fmt: skip


@dataclass(frozen=True, slots=True, eq=False)
class Setpoints:
    """Timed setpoints sampled from a trajectory (mission ENU frame).

    Attributes:
        t_s: ``(n,)`` seconds from the plan's start.
        pos_enu_m: ``(n, 3)``.
        vel_enu_m_s: ``(n, 3)``.
        acc_enu_m_s2: ``(n, 3)``.
        yaw_rad: ``(n,)`` ENU yaw (0 = east, CCW).
    """

    t_s: NDArray[np.float64]
    pos_enu_m: NDArray[np.float64]
    vel_enu_m_s: NDArray[np.float64]
    acc_enu_m_s2: NDArray[np.float64]
    yaw_rad: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TrajectoryError(f"{where}: expected a number, got {value!r}")
    out = float(value)
    if not math.isfinite(out):
        raise TrajectoryError(f"{where}: must be finite, got {value!r}")
    return out


def _readonly(a: NDArray[np.float64]) -> NDArray[np.float64]:
    a = np.array(a, dtype=float, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, slots=True, eq=False)
class Trajectory:
    """Exact piecewise-polynomial trajectory of one vehicle (see module docstring).

    Attributes:
        segment_t0_s: ``(n_seg,)`` segment start times, the first 0, contiguous.
        segment_duration_s: ``(n_seg,)`` segment durations, > 0.
        coeffs: ``(n_seg, 3, deg + 1)`` ENU power coefficients in local time.
        name: vehicle name.
        yaw_policy: yaw rule.

    ``duration_s`` is the total duration.
    """

    segment_t0_s: NDArray[np.float64]
    segment_duration_s: NDArray[np.float64] = field(repr=False)
    coeffs: NDArray[np.float64] = field(repr=False)
    name: str = ""
    yaw_policy: YawPolicy = field(default_factory=YawPolicy)
    _yaw_events: tuple[NDArray[np.float64], NDArray[np.float64]] | None = field(
        default=None, repr=False
    )

    def __init__(
        self,
        segment_t0_s: ArrayLike,
        segment_duration_s: ArrayLike,
        coeffs: ArrayLike,
        name: str = "",
        yaw_policy: YawPolicy | None = None,
    ) -> None:
        t0 = np.asarray(segment_t0_s, dtype=float)
        dur = np.asarray(segment_duration_s, dtype=float)
        c = np.asarray(coeffs, dtype=float)
        if t0.ndim != 1 or t0.shape != dur.shape or t0.size == 0:
            raise TrajectoryError(
                "segment_t0_s and segment_duration_s must be equal-length non-empty 1-D arrays"
            )
        if c.ndim != 3 or c.shape[0] != t0.size or c.shape[1] != 3 or c.shape[2] < 1:
            raise TrajectoryError(
                f"coeffs must have shape (n_seg={t0.size}, 3, deg+1), got {c.shape}"
            )
        for i in range(t0.size):
            if not (np.isfinite(t0[i]) and np.isfinite(dur[i]) and dur[i] > 0.0):
                raise TrajectoryError(
                    f"segment {i}: t0_s and duration_s must be finite, duration > 0"
                )
            if not np.all(np.isfinite(c[i])):
                raise TrajectoryError(f"segment {i}: coeffs must be finite")
        if t0[0] != 0.0:
            raise TrajectoryError(f"segment 0: t0_s must be 0, got {float(t0[0])!r}")
        ends = t0 + dur
        gaps = np.abs(t0[1:] - ends[:-1])
        bad = np.nonzero(gaps > 1e-9 * np.maximum(1.0, ends[:-1]))[0]
        if bad.size:
            i = int(bad[0]) + 1
            raise TrajectoryError(
                f"segment {i}: t0_s={float(t0[i])!r} does not follow segment {i - 1} "
                f"(which ends at {float(ends[i - 1])!r})"
            )
        object.__setattr__(self, "segment_t0_s", _readonly(t0))
        object.__setattr__(self, "segment_duration_s", _readonly(dur))
        object.__setattr__(self, "coeffs", _readonly(c))
        object.__setattr__(self, "name", str(name))
        object.__setattr__(
            self, "yaw_policy", yaw_policy if yaw_policy is not None else YawPolicy()
        )
        object.__setattr__(self, "_yaw_events", None)

    # ------------------------------------------------------------------ evaluation
    @property
    def duration_s(self) -> float:
        """Total duration in seconds."""
        return float(self.segment_t0_s[-1] + self.segment_duration_s[-1])

    @property
    def n_segments(self) -> int:
        """Number of segments."""
        return int(self.segment_t0_s.size)

    @property
    def degree(self) -> int:
        """Polynomial degree of the segments."""
        return int(self.coeffs.shape[2] - 1)

    def _locate(
        self, t_s: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.intp], NDArray[np.float64], NDArray[np.bool_]]:
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        if t.ndim != 1:
            raise TrajectoryError(f"times must be a scalar or 1-D array, got shape {t.shape}")
        if not np.all(np.isfinite(t)):
            raise TrajectoryError("times must be finite")
        end = self.duration_s
        outside = (t < 0.0) | (t > end)
        tc = np.clip(t, 0.0, end)
        seg = np.clip(
            np.searchsorted(self.segment_t0_s, tc, side="right") - 1, 0, self.n_segments - 1
        )
        tau = np.minimum(tc - self.segment_t0_s[seg], self.segment_duration_s[seg])
        return t, seg, tau, outside

    def derivative(self, t_s: ArrayLike, order: int) -> NDArray[np.float64]:
        """``order``-th time derivative ``(n, 3)`` at times ``t_s`` ``(n,)`` (SI units)."""
        if order < 0:
            raise TrajectoryError("derivative order must be >= 0")
        _, seg, tau, outside = self._locate(t_s)
        deg = self.degree
        out = np.zeros((tau.size, 3))
        if order <= deg:
            c = self.coeffs[seg]  # (n, 3, deg+1)
            # Horner on the derivative's coefficients j!/(j-order)! c_j.
            for j in range(deg, order - 1, -1):
                fac = math.factorial(j) / math.factorial(j - order)
                out = out * tau[:, None] + fac * c[:, :, j]
        if order > 0:
            out[outside] = 0.0
        return out

    def position(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """ENU position ``(n, 3)`` in m."""
        return self.derivative(t_s, 0)

    def velocity(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """ENU velocity ``(n, 3)`` in m/s."""
        return self.derivative(t_s, 1)

    def acceleration(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """ENU acceleration ``(n, 3)`` in m/s^2."""
        return self.derivative(t_s, 2)

    def jerk(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """ENU jerk ``(n, 3)`` in m/s^3."""
        return self.derivative(t_s, 3)

    def yaw_rad(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """ENU yaw ``(n,)`` in rad (0 = east, CCW), wrapped to ``(-pi, pi]``."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        if self.yaw_policy.mode is YawMode.CONSTANT:
            if not np.all(np.isfinite(t)):
                raise TrajectoryError("times must be finite")
            return np.full(t.shape, _wrap(self.yaw_policy.yaw_rad))
        if self.yaw_policy.mode is YawMode.SCHEDULE:
            if not np.all(np.isfinite(t)):
                raise TrajectoryError("times must be finite")
            return _wrap(self.yaw_policy.schedule_at(t))
        tc = np.clip(t, 0.0, self.duration_s)
        v = self.velocity(tc)
        speed2 = v[:, 0] ** 2 + v[:, 1] ** 2
        fast = speed2 >= self.yaw_policy.min_speed_m_s**2
        ev_t, ev_yaw = self._events()
        held = np.full(tc.shape, self.yaw_policy.yaw_rad)
        if ev_t.size:  # before the first slow/fast crossing the policy's yaw holds
            idx = np.searchsorted(ev_t, tc, side="right") - 1
            held = np.where(idx >= 0, ev_yaw[np.maximum(idx, 0)], held)
        return _wrap(np.where(fast, np.arctan2(v[:, 1], v[:, 0]), held))

    def yaw(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """Alias of :meth:`yaw_rad`."""
        return self.yaw_rad(t_s)

    def _events(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Times where ``|v_xy|`` equals ``min_speed_m_s`` and the heading there (sorted)."""
        if self._yaw_events is not None:
            return self._yaw_events
        s2 = self.yaw_policy.min_speed_m_s**2
        deg = self.degree
        times: list[float] = []
        if deg >= 1:
            k = np.arange(1, deg + 1)
            for s in range(self.n_segments):
                T = float(self.segment_duration_s[s])
                vx = self.coeffs[s, 0, 1:] * k  # ascending
                vy = self.coeffs[s, 1, 1:] * k
                poly = np.polynomial.polynomial
                q = poly.polyadd(poly.polymul(vx, vx), poly.polymul(vy, vy))
                q = poly.polysub(q, [s2])
                q = np.trim_zeros(q, "b")
                if q.size <= 1:
                    continue
                r = poly.polyroots(q)
                scale = max(1.0, T)
                real = r[np.abs(r.imag) <= 1e-7 * scale].real
                real = real[(real >= -1e-9) & (real <= T + 1e-9)]
                times.extend((self.segment_t0_s[s] + np.clip(real, 0.0, T)).tolist())
        ev_t = np.unique(np.asarray(times, dtype=float))
        if ev_t.size:
            v = self.velocity(ev_t)
            ev_yaw = np.arctan2(v[:, 1], v[:, 0])
        else:
            ev_yaw = np.zeros(0)
        events = (ev_t, ev_yaw)
        object.__setattr__(self, "_yaw_events", events)
        return events

    # ------------------------------------------------------------------ sampling
    def sample(self, rate_hz: float) -> Setpoints:
        """Setpoints at ``t_k = k / rate_hz`` from 0 until the first time >= the end.

        The last sample is at or after ``duration_s`` (holding the final state), so a
        stream of these setpoints covers the whole trajectory.
        """
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise TrajectoryError(f"rate_hz must be finite and > 0, got {rate_hz!r}")
        n = math.ceil(self.duration_s * rate_hz - 1e-9) + 1
        t = np.arange(n) / rate_hz
        return Setpoints(
            t_s=_readonly(t),
            pos_enu_m=_readonly(self.position(t)),
            vel_enu_m_s=_readonly(self.velocity(t)),
            acc_enu_m_s2=_readonly(self.acceleration(t)),
            yaw_rad=_readonly(self.yaw_rad(t)),
        )

    # ------------------------------------------------------------------ serialisation
    def to_segments(self) -> list[dict[str, Any]]:
        """JSON-ready list of segment dicts (module docstring); lossless."""
        yaw = self.yaw_policy.to_dict()
        return [
            {
                "t0_s": float(self.segment_t0_s[s]),
                "duration_s": float(self.segment_duration_s[s]),
                "coeffs": [[float(x) for x in self.coeffs[s, a]] for a in range(3)],
                "yaw": dict(yaw),
            }
            for s in range(self.n_segments)
        ]

    @classmethod
    def from_segments(cls, segments: Any, name: str = "", where: str = "segments") -> Trajectory:
        """Rebuild a trajectory from :meth:`to_segments` output.

        Raises:
            TrajectoryError: naming ``where[i].field`` for malformed data.
        """
        if not isinstance(segments, Sequence) or isinstance(segments, (str, bytes)):
            raise TrajectoryError(f"{where}: expected a list of segments")
        if len(segments) == 0:
            raise TrajectoryError(f"{where}: must contain at least one segment")
        t0: list[float] = []
        dur: list[float] = []
        coeffs: list[list[list[float]]] = []
        yaw: YawPolicy | None = None
        n_coef: int | None = None
        for i, seg in enumerate(segments):
            w = f"{where}[{i}]"
            if not isinstance(seg, Mapping):
                raise TrajectoryError(f"{w}: expected an object")
            for key in ("t0_s", "duration_s", "coeffs"):
                if key not in seg:
                    raise TrajectoryError(f"{w}: missing field {key!r}")
            t0.append(_number(seg["t0_s"], f"{w}.t0_s"))
            dur.append(_number(seg["duration_s"], f"{w}.duration_s"))
            c = seg["coeffs"]
            if not isinstance(c, Sequence) or len(c) != 3:
                raise TrajectoryError(f"{w}.coeffs: expected 3 lists (east, north, up)")
            rows = []
            for a, row in enumerate(c):
                if not isinstance(row, Sequence) or isinstance(row, (str, bytes)) or not row:
                    raise TrajectoryError(f"{w}.coeffs[{a}]: expected a non-empty list of numbers")
                rows.append([_number(x, f"{w}.coeffs[{a}][{j}]") for j, x in enumerate(row)])
            lens = {len(r) for r in rows}
            if len(lens) != 1 or (n_coef is not None and lens != {n_coef}):
                raise TrajectoryError(f"{w}.coeffs: all axes and segments need the same degree")
            n_coef = lens.pop()
            coeffs.append(rows)
            seg_yaw = YawPolicy.from_dict(seg.get("yaw", {}), f"{w}.yaw")
            if yaw is None:
                yaw = seg_yaw
            elif seg_yaw != yaw:
                raise TrajectoryError(
                    f"{w}.yaw: differs from segment 0 (one policy per trajectory)"
                )
        try:
            return cls(t0, dur, coeffs, name=name, yaw_policy=yaw)
        except TrajectoryError as exc:
            msg = re.sub(r"^segment (\d+): ", lambda m: f"{where}[{m.group(1)}]: ", str(exc))
            raise TrajectoryError(msg if msg != str(exc) else f"{where}: {exc}") from None


def _wrap(angle: ArrayLike) -> Any:
    """Wrap to ``(-pi, pi]``."""
    a = np.asarray(angle, dtype=float)
    w = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    return w if w.ndim else float(w)
