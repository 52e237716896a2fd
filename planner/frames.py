"""Frame conversions between the mission ENU frame, vehicles' local NED frames and geodetic.

docs/architecture.md, "Frames and units": the mission frame is local ENU (m) at the scenario's geodetic
origin; each vehicle flies in its own local NED frame whose origin is its EKF origin
(for PX4 SITL: where it was spawned), which in general differs from the mission origin.
A mission-frame point is therefore taken to geodetic with the mission origin and back
to the vehicle's local frame with the vehicle's origin (pymap3d, WGS84), never by
shifting axes. Directions (velocities, accelerations) are rotated between the two
tangent planes through ECEF (pymap3d ``enu2uvw`` / ``uvw2enu``), without translation.

Altitudes are used as heights above the WGS84 ellipsoid by pymap3d. Origins are AMSL
(what PX4 reports), which differs from the ellipsoidal height by the local geoid
undulation; over a mission area that offset is the same for all origins and points, so
the local conversions are unaffected (to well below a millimetre over kilometres).

Yaw: ENU yaw is 0 = east, counter-clockwise; NED yaw is 0 = north, clockwise;
``yaw_ned = pi/2 - yaw_enu`` (both wrapped to ``(-pi, pi]``). The small rotation of
north between two tangent planes a few hundred metres apart (< 1e-4 rad per km) is
included in :func:`yaw_enu_to_ned` when the two origins are given.

All functions are vectorised over ``(n, 3)`` arrays (a single ``(3,)`` point works too
and keeps its shape).

Error tree::

    FrameError(ValueError)     bad shapes or non-finite coordinates
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pymap3d
from numpy.typing import ArrayLike, NDArray

from planner.errors import PlannerError

__all__ = [
    "FrameError",
    "GeodeticPoint",
    "enu_to_geodetic",
    "enu_to_ned",
    "enu_vector_to_ned",
    "geodetic_to_enu",
    "ned_to_enu",
    "ned_vector_to_enu",
    "yaw_enu_to_ned",
    "yaw_ned_to_enu",
]


class FrameError(PlannerError, ValueError):
    """Invalid input to a frame conversion."""


@dataclass(frozen=True, slots=True)
class GeodeticPoint:
    """A geodetic position: latitude and longitude in degrees (WGS84), altitude AMSL in m."""

    lat_deg: float
    lon_deg: float
    alt_m: float

    def __post_init__(self) -> None:
        for name in ("lat_deg", "lon_deg", "alt_m"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise FrameError(f"GeodeticPoint.{name} must be a finite number, got {v!r}")
        if not -90.0 <= self.lat_deg <= 90.0:
            raise FrameError(f"GeodeticPoint.lat_deg must be in [-90, 90], got {self.lat_deg}")
        if not -180.0 <= self.lon_deg <= 360.0:
            raise FrameError(f"GeodeticPoint.lon_deg must be in [-180, 360], got {self.lon_deg}")


def _points(x: ArrayLike, what: str) -> tuple[NDArray[np.float64], bool]:
    a = np.asarray(x, dtype=float)
    single = a.ndim == 1
    a2 = np.atleast_2d(a)
    if a2.ndim != 2 or a2.shape[1] != 3:
        raise FrameError(f"{what} must have shape (3,) or (n, 3), got {a.shape}")
    if not np.all(np.isfinite(a2)):
        raise FrameError(f"{what} must be finite")
    return a2, single


def _out(a: NDArray[np.float64], single: bool) -> NDArray[np.float64]:
    return a[0] if single else a


def _same(a: GeodeticPoint, b: GeodeticPoint) -> bool:
    return a == b


def _enu_to_ned_axes(e: Any, n: Any, u: Any) -> NDArray[np.float64]:
    return np.column_stack([n, e, -np.asarray(u)])


def enu_to_geodetic(pos_enu_m: ArrayLike, origin: GeodeticPoint) -> tuple[Any, Any, Any]:
    """ENU points ``(n, 3)`` (m) at ``origin`` -> ``(lat_deg, lon_deg, alt_m)``, each ``(n,)``.

    A single ``(3,)`` point gives three floats.
    """
    p, single = _points(pos_enu_m, "pos_enu_m")
    lat, lon, alt = pymap3d.enu2geodetic(
        p[:, 0], p[:, 1], p[:, 2], origin.lat_deg, origin.lon_deg, origin.alt_m
    )
    lat, lon, alt = (np.asarray(v, dtype=float).reshape(-1) for v in (lat, lon, alt))
    if single:
        return float(lat[0]), float(lon[0]), float(alt[0])
    return lat, lon, alt


def geodetic_to_enu(
    lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike, origin: GeodeticPoint
) -> NDArray[np.float64]:
    """Geodetic points (each ``(n,)``) -> ENU ``(n, 3)`` in m at ``origin``."""
    lat, lon, alt = np.broadcast_arrays(
        *(np.atleast_1d(np.asarray(v, dtype=float)) for v in (lat_deg, lon_deg, alt_m))
    )
    if lat.ndim != 1 or not (
        np.all(np.isfinite(lat)) and np.all(np.isfinite(lon)) and np.all(np.isfinite(alt))
    ):
        raise FrameError("lat_deg, lon_deg, alt_m must be finite scalars or 1-D arrays")
    e, n, u = pymap3d.geodetic2enu(lat, lon, alt, origin.lat_deg, origin.lon_deg, origin.alt_m)
    return np.column_stack([np.ravel(e), np.ravel(n), np.ravel(u)])


def enu_to_ned(
    pos_enu_m: ArrayLike, mission_origin: GeodeticPoint, vehicle_origin: GeodeticPoint
) -> NDArray[np.float64]:
    """Mission-frame ENU points -> the vehicle's local NED points (m), ``(n, 3)`` or ``(3,)``.

    Mission ENU -> geodetic (mission origin) -> ENU at the vehicle origin -> NED
    (north = y, east = x, down = -z).
    """
    p, single = _points(pos_enu_m, "pos_enu_m")
    if _same(mission_origin, vehicle_origin):
        return _out(_enu_to_ned_axes(p[:, 0], p[:, 1], p[:, 2]), single)
    lat, lon, alt = pymap3d.enu2geodetic(
        p[:, 0],
        p[:, 1],
        p[:, 2],
        mission_origin.lat_deg,
        mission_origin.lon_deg,
        mission_origin.alt_m,
    )
    e, n, u = pymap3d.geodetic2enu(
        lat, lon, alt, vehicle_origin.lat_deg, vehicle_origin.lon_deg, vehicle_origin.alt_m
    )
    return _out(_enu_to_ned_axes(np.ravel(e), np.ravel(n), np.ravel(u)), single)


def ned_to_enu(
    pos_ned_m: ArrayLike, mission_origin: GeodeticPoint, vehicle_origin: GeodeticPoint
) -> NDArray[np.float64]:
    """Inverse of :func:`enu_to_ned`: vehicle-local NED points -> mission ENU (m)."""
    p, single = _points(pos_ned_m, "pos_ned_m")
    e, n, u = p[:, 1], p[:, 0], -p[:, 2]
    if _same(mission_origin, vehicle_origin):
        return _out(np.column_stack([e, n, u]), single)
    lat, lon, alt = pymap3d.enu2geodetic(
        e, n, u, vehicle_origin.lat_deg, vehicle_origin.lon_deg, vehicle_origin.alt_m
    )
    e2, n2, u2 = pymap3d.geodetic2enu(
        lat, lon, alt, mission_origin.lat_deg, mission_origin.lon_deg, mission_origin.alt_m
    )
    return _out(np.column_stack([np.ravel(e2), np.ravel(n2), np.ravel(u2)]), single)


@dataclass(frozen=True, slots=True, eq=False)
class NedToEnuMap:
    """:func:`ned_to_enu` / :func:`ned_vector_to_enu` of one vehicle as one affine map.

    Vehicle NED -> geodetic -> mission ENU goes through ECEF by two affine maps (pymap3d's
    ``enu2ecef`` and ``ecef2enu``; the geodetic round trip in between is the identity), so
    the whole is affine: ``enu = ned @ a.T + b``, velocities ``ned_v @ a.T``. Computed once
    per flight, it turns the per-sample pymap3d calls of a live flight into one product.

    Attributes:
        a: ``(3, 3)`` the linear part (a rotation, with the NED -> ENU axis swap).
        b: ``(3,)`` where the vehicle's origin lies in the mission frame.
    """

    a: NDArray[np.float64]
    b: NDArray[np.float64]

    @classmethod
    def between(cls, mission_origin: GeodeticPoint, vehicle_origin: GeodeticPoint) -> NedToEnuMap:
        """The map of a vehicle whose local origin is ``vehicle_origin``."""
        step = 1000.0  # long base vectors: the round trip's rounding is relative to them
        pts = np.vstack([np.zeros(3), step * np.eye(3)])
        enu = ned_to_enu(pts, mission_origin, vehicle_origin)
        b = enu[0]
        return cls(a=((enu[1:] - b) / step).T.copy(), b=b.copy())

    def position(self, pos_ned_m: ArrayLike) -> NDArray[np.float64]:
        """Mission-ENU positions of NED points ``(..., 3)``."""
        return np.asarray(pos_ned_m, dtype=float) @ self.a.T + self.b

    def vector(self, vec_ned: ArrayLike) -> NDArray[np.float64]:
        """Mission-ENU vectors (velocity, acceleration) of NED vectors ``(..., 3)``."""
        return np.asarray(vec_ned, dtype=float) @ self.a.T


def _rotate_enu(
    vec: NDArray[np.float64], src: GeodeticPoint, dst: GeodeticPoint
) -> NDArray[np.float64]:
    if _same(src, dst):
        return vec
    u, v, w = pymap3d.enu2uvw(vec[:, 0], vec[:, 1], vec[:, 2], src.lat_deg, src.lon_deg)
    e, n, up = pymap3d.uvw2enu(u, v, w, dst.lat_deg, dst.lon_deg)
    return np.column_stack([np.ravel(e), np.ravel(n), np.ravel(up)])


def enu_vector_to_ned(
    vec_enu: ArrayLike, mission_origin: GeodeticPoint, vehicle_origin: GeodeticPoint
) -> NDArray[np.float64]:
    """Rotate mission-ENU vectors (velocity, acceleration) into the vehicle's NED axes."""
    v, single = _points(vec_enu, "vec_enu")
    r = _rotate_enu(v, mission_origin, vehicle_origin)
    return _out(_enu_to_ned_axes(r[:, 0], r[:, 1], r[:, 2]), single)


def ned_vector_to_enu(
    vec_ned: ArrayLike, mission_origin: GeodeticPoint, vehicle_origin: GeodeticPoint
) -> NDArray[np.float64]:
    """Inverse of :func:`enu_vector_to_ned`."""
    v, single = _points(vec_ned, "vec_ned")
    enu = np.column_stack([v[:, 1], v[:, 0], -v[:, 2]])
    return _out(_rotate_enu(enu, vehicle_origin, mission_origin), single)


def _wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def _north_rotation(
    mission_origin: GeodeticPoint | None, vehicle_origin: GeodeticPoint | None
) -> float:
    """Angle (rad, CCW) of the mission frame's east axis seen in the vehicle's ENU frame."""
    if mission_origin is None or vehicle_origin is None or _same(mission_origin, vehicle_origin):
        return 0.0
    east = _rotate_enu(np.array([[1.0, 0.0, 0.0]]), mission_origin, vehicle_origin)[0]
    return float(math.atan2(east[1], east[0]))


def yaw_enu_to_ned(
    yaw_enu_rad: ArrayLike,
    mission_origin: GeodeticPoint | None = None,
    vehicle_origin: GeodeticPoint | None = None,
) -> NDArray[np.float64]:
    """ENU yaw (0 = east, CCW) -> NED yaw (0 = north, CW): ``pi/2 - yaw``, wrapped.

    With both origins, the yaw is first expressed in the vehicle's ENU axes.
    """
    y = np.asarray(yaw_enu_rad, dtype=float)
    return _wrap(np.pi / 2.0 - (y + _north_rotation(mission_origin, vehicle_origin)))


def yaw_ned_to_enu(
    yaw_ned_rad: ArrayLike,
    mission_origin: GeodeticPoint | None = None,
    vehicle_origin: GeodeticPoint | None = None,
) -> NDArray[np.float64]:
    """Inverse of :func:`yaw_enu_to_ned`."""
    y = np.asarray(yaw_ned_rad, dtype=float)
    return _wrap(np.pi / 2.0 - y - _north_rotation(mission_origin, vehicle_origin))
