"""Configuration values of the mock fleet: faults, wind, noise, per-vehicle set-up, payload.

All values are frozen dataclasses validated on construction; a bad value raises
:class:`mavlink.mock.sim.errors.MockConfigError` naming the field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mavlink.mock.sim.errors import MockConfigError


def _probability(name: str, value: float) -> None:
    if not (0.0 <= value <= 1.0) or math.isnan(value):
        raise MockConfigError(f"{name} must be a probability in [0, 1], got {value!r}")


def _non_negative(name: str, value: float) -> None:
    if not (value >= 0.0) or math.isinf(value):
        raise MockConfigError(f"{name} must be a finite number >= 0, got {value!r}")


@dataclass(frozen=True, slots=True)
class Outage:
    """A link outage: nothing passes in either direction for ``start_s <= t < end_s``.

    Times are seconds of simulation time since the fleet started.
    """

    start_s: float
    end_s: float

    def __post_init__(self) -> None:
        _non_negative("outage start_s", self.start_s)
        if not (self.end_s > self.start_s):
            raise MockConfigError(
                f"outage end_s must be after start_s, got {self.start_s}..{self.end_s}"
            )

    @classmethod
    def parse(cls, text: str) -> Outage:
        """Parse ``"START:END"`` (seconds), e.g. ``"5:8.5"``."""
        parts = text.split(":")
        if len(parts) != 2:
            raise MockConfigError(f"outage {text!r}: expected START:END in seconds")
        try:
            start, end = float(parts[0]), float(parts[1])
        except ValueError:
            raise MockConfigError(f"outage {text!r}: START and END must be numbers") from None
        return cls(start, end)


@dataclass(frozen=True, slots=True)
class FaultConfig:
    """Link faults of one vehicle.

    ``loss_to_vehicle`` / ``loss_to_gcs``: probability that a datagram in that
    direction is dropped.  ``latency_s`` plus a uniform ``[0, jitter_s]`` delay
    is added to every datagram (both directions).  ``duplicate``: probability a
    datagram is delivered twice.  ``reorder``: probability a datagram is held
    back by ``reorder_delay_s`` so later ones overtake it.  ``outages``: time
    windows with no traffic at all.
    """

    loss_to_vehicle: float = 0.0
    loss_to_gcs: float = 0.0
    latency_s: float = 0.0
    jitter_s: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    reorder_delay_s: float = 0.03
    outages: tuple[Outage, ...] = ()

    def __post_init__(self) -> None:
        _probability("loss_to_vehicle", self.loss_to_vehicle)
        _probability("loss_to_gcs", self.loss_to_gcs)
        _probability("duplicate", self.duplicate)
        _probability("reorder", self.reorder)
        _non_negative("latency_s", self.latency_s)
        _non_negative("jitter_s", self.jitter_s)
        _non_negative("reorder_delay_s", self.reorder_delay_s)
        object.__setattr__(self, "outages", tuple(self.outages))

    @property
    def is_clean(self) -> bool:
        """True when no fault is configured (datagrams take the direct path)."""
        return (
            self.loss_to_vehicle == 0.0
            and self.loss_to_gcs == 0.0
            and self.latency_s == 0.0
            and self.jitter_s == 0.0
            and self.duplicate == 0.0
            and self.reorder == 0.0
            and not self.outages
        )

    def in_outage(self, t_s: float) -> bool:
        """True if simulation time ``t_s`` falls in one of the outages."""
        return any(o.start_s <= t_s < o.end_s for o in self.outages)


@dataclass(frozen=True, slots=True)
class WindConfig:
    """Wind acting on every vehicle: a mean plus a seeded Ornstein-Uhlenbeck gust.

    ``mean_ne_m_s``: (north, east) mean wind in m/s.  ``gust_sigma_m_s``:
    stationary standard deviation of the gust per horizontal axis.
    ``gust_tau_s``: its correlation time.  ``drag_per_s``: linear drag
    coefficient coupling air-relative velocity into acceleration (1/s).
    """

    mean_ne_m_s: tuple[float, float] = (0.0, 0.0)
    gust_sigma_m_s: float = 0.0
    gust_tau_s: float = 2.0
    drag_per_s: float = 0.35

    def __post_init__(self) -> None:
        if len(self.mean_ne_m_s) != 2 or not all(math.isfinite(v) for v in self.mean_ne_m_s):
            raise MockConfigError(
                f"wind mean_ne_m_s must be two finite numbers, got {self.mean_ne_m_s!r}"
            )
        object.__setattr__(
            self, "mean_ne_m_s", (float(self.mean_ne_m_s[0]), float(self.mean_ne_m_s[1]))
        )
        _non_negative("gust_sigma_m_s", self.gust_sigma_m_s)
        if not (self.gust_tau_s > 0.0):
            raise MockConfigError(f"gust_tau_s must be > 0, got {self.gust_tau_s!r}")
        _non_negative("drag_per_s", self.drag_per_s)


@dataclass(frozen=True, slots=True)
class NoiseConfig:
    """White Gaussian noise on reported telemetry (the true state is not affected).

    Standard deviations per axis: ``pos_m`` on positions, ``vel_m_s`` on velocities.
    """

    pos_m: float = 0.01
    vel_m_s: float = 0.02

    def __post_init__(self) -> None:
        _non_negative("noise pos_m", self.pos_m)
        _non_negative("noise vel_m_s", self.vel_m_s)


@dataclass(frozen=True, slots=True)
class CameraSpec:
    """The optics of a vehicle's MAVLink camera, as its CAMERA_INFORMATION reports them.

    ``focal_length_mm``, ``sensor_h_mm`` x ``sensor_v_mm`` (sensor width x height) and
    ``resolution_h_px`` x ``resolution_v_px``; the default is a small inspection camera
    (a 1/2.3" sensor behind a 4.5 mm lens, 12 MP).
    """

    vendor: str = "stl-gcs"
    model: str = "mock camera"
    focal_length_mm: float = 4.5
    sensor_h_mm: float = 6.17
    sensor_v_mm: float = 4.55
    resolution_h_px: int = 4000
    resolution_v_px: int = 3000

    def __post_init__(self) -> None:
        for name in ("vendor", "model"):
            if len(getattr(self, name).encode()) > 32:
                raise MockConfigError(f"camera {name} must fit 32 bytes (CAMERA_INFORMATION)")
        for name in ("focal_length_mm", "sensor_h_mm", "sensor_v_mm"):
            value = getattr(self, name)
            if not (value > 0.0 and math.isfinite(value)):
                raise MockConfigError(f"camera {name} must be a finite number > 0, got {value!r}")
        for name in ("resolution_h_px", "resolution_v_px"):
            value = getattr(self, name)
            if not (isinstance(value, int) and 0 < value <= 0xFFFF):
                raise MockConfigError(
                    f"camera {name} must be an integer in 1..65535, got {value!r}"
                )


@dataclass(frozen=True, slots=True)
class GimbalSpec:
    """The gimbal device under the camera: how fast it turns and how far it tilts.

    ``rate_deg_s``: the largest angular rate of each axis (pitch, yaw), deg/s.
    ``pitch_min_deg`` / ``pitch_max_deg``: the pitch limits (down negative), deg; yaw turns
    without limit.  Roll and pitch are stabilised to the horizon.
    """

    rate_deg_s: float = 90.0
    pitch_min_deg: float = -90.0
    pitch_max_deg: float = 30.0

    def __post_init__(self) -> None:
        if not (self.rate_deg_s > 0.0 and math.isfinite(self.rate_deg_s)):
            raise MockConfigError(
                f"gimbal rate_deg_s must be a finite number > 0, got {self.rate_deg_s!r}"
            )
        if not (-90.0 <= self.pitch_min_deg < self.pitch_max_deg <= 90.0):
            raise MockConfigError(
                "gimbal pitch limits must satisfy -90 <= pitch_min_deg < pitch_max_deg <= 90, "
                f"got {self.pitch_min_deg!r}..{self.pitch_max_deg!r}"
            )


@dataclass(frozen=True, slots=True)
class MockVehicleConfig:
    """Set-up of one mock vehicle.

    ``spawn_enu_m``: spawn point in the mission ENU frame (x east, y north, z up)
    relative to the fleet origin; the vehicle's EKF origin and home are there, and
    so is its ground: a spawn with z > 0 stands on a platform at that height.
    ``params``: PX4 parameter overrides by name (e.g. ``{"COM_OF_LOSS_T": 0.5}``).
    ``ready_after_s``: simulated EKF/GPS convergence time; arming is refused before.
    ``profile``: ``"px4"`` (PX4 v1.17 with SIH, the default) or ``"ideal"``
    (:mod:`mavlink.mock.sim.profiles`); ``params`` apply on top of it.
    ``camera``: the vehicle carries a MAVLink camera (component 100) on a gimbal (device
    154, managed by the autopilot; :mod:`mavlink.mock.payload`) with ``camera_spec`` and
    ``gimbal_spec``; False: neither, as PX4 without a camera or gimbal answers.
    """

    spawn_enu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    faults: FaultConfig = field(default_factory=FaultConfig)
    params: tuple[tuple[str, float], ...] = ()
    ready_after_s: float = 0.5
    profile: str = "px4"
    camera: bool = True
    camera_spec: CameraSpec = field(default_factory=CameraSpec)
    gimbal_spec: GimbalSpec = field(default_factory=GimbalSpec)

    def __post_init__(self) -> None:
        spawn = tuple(float(v) for v in self.spawn_enu_m)
        if len(spawn) != 3 or not all(math.isfinite(v) for v in spawn):
            raise MockConfigError(
                f"spawn_enu_m must be three finite numbers, got {self.spawn_enu_m!r}"
            )
        object.__setattr__(self, "spawn_enu_m", spawn)
        params = self.params.items() if isinstance(self.params, dict) else self.params
        object.__setattr__(self, "params", tuple((str(k), float(v)) for k, v in params))
        _non_negative("ready_after_s", self.ready_after_s)
        from mavlink.mock.sim.profiles import profile_params

        profile_params(self.profile)  # names the choices when unknown
