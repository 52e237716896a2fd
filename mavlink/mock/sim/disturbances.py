"""What can go differently on the day: the disturbances of a simulated flight, as distributions.

A statistical assessment (``gcs assess``, :mod:`mavlink.mock.sim.batch`) flies a plan many times,
each run under disturbances drawn from distributions the user may set: the wind, the state
estimate's errors, where a vehicle really stands when the plan starts, the setpoint link,
and how much of its speed and acceleration a vehicle has.  Each disturbance has a name, a unit,
a range it must stay in, whether it is drawn once per run or per vehicle, and a default that
stands for a calm day with a PX4 quad-rotor on SIH (``docs/px4-behaviour.md``).

A distribution is written as ``const(X)`` (or just ``X``), ``uniform(A, B)``,
``normal(MEAN, SD)`` (clipped to the disturbance's range) or ``triangular(A, MODE, B)``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from mavlink.mock.sim.errors import MockConfigError

__all__ = [
    "DISTURBANCES",
    "Distribution",
    "Disturbance",
    "draw_disturbances",
    "parse_disturbances",
]

_KINDS = {"const": 1, "uniform": 2, "normal": 2, "triangular": 3}
_CALL = re.compile(r"^\s*([a-z_]+)\s*\(([^()]*)\)\s*$")


@dataclass(frozen=True, slots=True)
class Distribution:
    """A distribution of one disturbance: ``kind`` (const, uniform, normal, triangular) and
    its arguments."""

    kind: str
    args: tuple[float, ...]

    @classmethod
    def parse(cls, text: str, what: str = "distribution") -> Distribution:
        """``"uniform(0, 3)"``, ``"normal(0, 0.1)"``, ``"const(2)"`` or a number.

        Raises:
            MockConfigError: naming ``what``, for an unknown kind, a wrong number of
                arguments, a non-finite value, ``B < A`` or a negative standard deviation.
        """
        text = str(text).strip()
        try:
            number = float(text)
        except ValueError:
            pass
        else:
            return cls("const", (_finite(number, what),))
        m = _CALL.match(text)
        if m is None:
            raise MockConfigError(
                f"{what}: {text!r} is not a distribution (const(X), uniform(A, B), "
                "normal(MEAN, SD), triangular(A, MODE, B) or a number)"
            )
        kind, body = m.group(1), m.group(2)
        if kind not in _KINDS:
            raise MockConfigError(
                f"{what}: unknown distribution {kind!r} (choose from {', '.join(_KINDS)})"
            )
        try:
            numbers = [float(a) for a in body.split(",")]
        except ValueError:
            raise MockConfigError(f"{what}: the arguments of {kind}() must be numbers") from None
        args = tuple(_finite(a, what) for a in numbers)
        if len(args) != _KINDS[kind]:
            raise MockConfigError(f"{what}: {kind}() takes {_KINDS[kind]} argument(s)")
        dist = cls(kind, args)
        dist._check(what)
        return dist

    def _check(self, what: str) -> None:
        a = self.args
        if self.kind == "uniform" and a[1] < a[0]:
            raise MockConfigError(f"{what}: uniform(A, B) needs A <= B, got {self}")
        if self.kind == "normal" and a[1] < 0:
            raise MockConfigError(f"{what}: normal(MEAN, SD) needs SD >= 0, got {self}")
        if self.kind == "triangular" and not a[0] <= a[1] <= a[2]:
            raise MockConfigError(f"{what}: triangular(A, MODE, B) needs A <= MODE <= B")

    def support(self) -> tuple[float, float]:
        """The smallest and largest value it can take (normal: unbounded)."""
        a = self.args
        if self.kind == "const":
            return a[0], a[0]
        if self.kind == "normal":
            return (-math.inf, math.inf) if a[1] > 0 else (a[0], a[0])
        return a[0], a[-1]

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """``size`` draws (always consuming the same amount of ``rng`` for one kind)."""
        a = self.args
        if self.kind == "const":
            return np.full(size, a[0])
        if self.kind == "uniform":
            return rng.uniform(a[0], a[1], size)
        if self.kind == "normal":
            return a[0] + a[1] * rng.standard_normal(size)
        if a[0] == a[2]:
            rng.uniform(size=size)  # the same consumption as a proper triangle
            return np.full(size, a[0])
        return rng.triangular(a[0], a[1], a[2], size)

    def __str__(self) -> str:
        return f"{self.kind}({', '.join(f'{v:g}' for v in self.args)})"


def _finite(value: float, what: str) -> float:
    if not math.isfinite(value):
        raise MockConfigError(f"{what}: {value!r} is not a finite number")
    return value


@dataclass(frozen=True, slots=True)
class Disturbance:
    """One disturbance: its default, the range its draws are clipped to, whether it is
    drawn once per run (shared by the fleet) or per vehicle, its unit and meaning."""

    default: Distribution
    lo: float
    hi: float
    per_vehicle: bool
    unit: str
    meaning: str


def _d(text: str) -> Distribution:
    return Distribution.parse(text)


#: The disturbances, in the order they are drawn for a run (a new one goes at the end, so
#: the draws of the others, and every earlier campaign, stay as they were).
DISTURBANCES: dict[str, Disturbance] = {
    "wind_m_s": Disturbance(
        _d("uniform(0, 3)"), 0.0, 30.0, False, "m/s",
        "mean wind speed (a calm day: up to a light breeze, Beaufort 2)",
    ),
    "wind_from_deg": Disturbance(
        _d("uniform(0, 360)"), -720.0, 720.0, False, "deg",
        "where the wind blows from (compass: 0 north, 90 east)",
    ),
    "gust_m_s": Disturbance(
        _d("uniform(0, 0.5)"), 0.0, 15.0, False, "m/s",
        "gusts: standard deviation per horizontal axis (Ornstein-Uhlenbeck)",
    ),
    "gust_tau_s": Disturbance(
        _d("const(2)"), 0.05, 120.0, False, "s", "the gusts' correlation time",
    ),
    "estimator": Disturbance(
        _d("const(1)"), 0.0, 20.0, False, "x",
        "scale of the estimate's noise and biases (1: the profile's, PX4 SITL's)",
    ),
    "ekf_origin": Disturbance(
        _d("const(1)"), 0.0, 20.0, False, "x",
        "scale of the EKF origin's offset from the true spawn (1: the profile's)",
    ),
    "start_error_m": Disturbance(
        _d("uniform(0, 0.3)"), 0.0, 20.0, True, "m",
        "horizontal distance from its start where a vehicle hovers when its start "
        "setpoint is first streamed",
    ),
    "latency_s": Disturbance(
        _d("uniform(0.005, 0.05)"), 0.0, 5.0, False, "s", "setpoint link latency",
    ),
    "jitter_s": Disturbance(
        _d("uniform(0, 0.02)"), 0.0, 5.0, False, "s",
        "setpoint link jitter: an extra delay uniform in [0, jitter]",
    ),
    "loss": Disturbance(
        _d("uniform(0, 0.02)"), 0.0, 1.0, False, "", "probability a setpoint is lost",
    ),
    "derate": Disturbance(
        _d("const(1)"), 0.05, 1.0, True, "x",
        "fraction of its speed and acceleration limits a vehicle has (battery, payload)",
    ),
    "lost": Disturbance(
        _d("const(0)"), 0.0, 1.0, True, "",
        "probability a vehicle is lost during the plan: its link silent for good from a "
        "time uniform over the horizon",
    ),
}  # fmt: skip


def parse_disturbances(settings: Mapping[str, str]) -> dict[str, Distribution]:
    """Every disturbance's distribution: the defaults, with ``settings`` (name -> text) on top.

    Raises:
        MockConfigError: an unknown name (naming the known ones), a malformed distribution,
            or one whose values lie wholly outside the disturbance's range.
    """
    out = {name: d.default for name, d in DISTURBANCES.items()}
    for name, text in settings.items():
        spec = DISTURBANCES.get(name)
        if spec is None:
            raise MockConfigError(
                f"unknown disturbance {name!r} (choose from {', '.join(DISTURBANCES)})"
            )
        dist = Distribution.parse(text, name)
        lo, hi = dist.support()
        if hi < spec.lo or lo > spec.hi:
            raise MockConfigError(
                f"{name}: {dist} lies outside [{spec.lo:g}, {spec.hi:g}] {spec.unit}".rstrip()
            )
        out[name] = dist
    return out


def draw_disturbances(
    dists: Mapping[str, Distribution], rng: np.random.Generator, n_vehicles: int
) -> dict[str, np.ndarray]:
    """One run's draws: per name an array of one value (per run) or ``n_vehicles`` values,
    clipped to the disturbance's range; always drawn in :data:`DISTURBANCES` order."""
    out = {}
    for name, spec in DISTURBANCES.items():
        size = n_vehicles if spec.per_vehicle else 1
        out[name] = np.clip(dists[name].sample(rng, size), spec.lo, spec.hi)
    return out
