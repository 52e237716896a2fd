"""The mock vehicle's local frame: NED about its EKF origin, and moves of that origin.

Mixed into :class:`mavlink.mock.vehicle.MockVehicle`.  The local NED frame's origin is
the EKF origin (the first, noisy GPS fix at boot); global positions are that origin's
geodetic coordinates plus the local offset (pymap3d, exact, curvature included).
Altitudes are AMSL; "relative" altitudes are above home.  Commands, mission items and
global setpoints are converted here; SET_GPS_GLOBAL_ORIGIN (on the ground) and an
injected EKF2 origin reset move the origin, which shifts the local coordinates of a
vehicle that stays where it is.  A room of its own because every global coordinate
in or out of the vehicle passes through it.
"""

from __future__ import annotations

import math
from typing import Any, TypeAlias

import numpy as np
import pymap3d
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock.parts import VehicleParts

#: A pymavlink message (its fields are per message type: untyped to mypy).
Msg: TypeAlias = Any

_GLOBAL_FRAMES = frozenset(
    {
        mavlink2.MAV_FRAME_GLOBAL,
        mavlink2.MAV_FRAME_GLOBAL_INT,
        mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT,
        mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT,
        mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
    }
)
_MAX_ORIGIN_MOVE_M = 50_000.0  # how far from the vehicle SET_GPS_GLOBAL_ORIGIN may put the origin


class OriginMixin(VehicleParts):
    """Geodesy and EKF origin of :class:`~mavlink.mock.vehicle.MockVehicle`."""

    def ned_to_global(self, pos_ned_m: np.ndarray) -> tuple[float, float, float]:
        """Local NED (m) -> (lat_deg, lon_deg, alt_m AMSL)."""
        lat0, lon0, h0 = self.origin_lla
        lat, lon, alt = pymap3d.ned2geodetic(
            float(pos_ned_m[0]), float(pos_ned_m[1]), float(pos_ned_m[2]), lat0, lon0, h0
        )
        return float(lat), float(lon), float(alt)

    def global_to_ned(self, lat_deg: float, lon_deg: float, alt_m: float) -> np.ndarray:
        """(lat_deg, lon_deg, alt_m AMSL) -> local NED (m), shape (3,)."""
        lat0, lon0, h0 = self.origin_lla
        n, e, d = pymap3d.geodetic2ned(lat_deg, lon_deg, alt_m, lat0, lon0, h0)
        return np.array([float(n), float(e), float(d)])

    def home_alt_amsl(self) -> float:
        return self.origin_lla[2] - float(self.home_ned_m[2])

    def _item_target_ned(
        self, frame: int, x_e7: int, y_e7: int, z_m: float, default: np.ndarray
    ) -> np.ndarray:
        """Position of a global mission item / command in local NED; NaN or 0,0 keep ``default``."""
        target = default.copy()
        has_latlon = (x_e7 != 0 or y_e7 != 0) and frame in _GLOBAL_FRAMES
        if math.isfinite(z_m):
            target[2] = self._alt_to_down(frame, z_m)
        if has_latlon:
            # exact geodetic conversion (curvature included) at the target's altitude
            alt_amsl = self.origin_lla[2] - float(target[2])
            ned = self.global_to_ned(x_e7 / 1e7, y_e7 / 1e7, alt_amsl)
            target[0], target[1] = ned[0], ned[1]
            if math.isfinite(z_m):
                target[2] = ned[2]
        return target

    def _alt_to_down(self, frame: int, alt_m: float) -> float:
        if frame in (mavlink2.MAV_FRAME_GLOBAL, mavlink2.MAV_FRAME_GLOBAL_INT):
            return self.origin_lla[2] - alt_m
        # relative to home (terrain following over flat ground is the same)
        return float(self.home_ned_m[2]) - alt_m

    def _on_set_gps_global_origin(self, msg: Msg) -> None:
        if not self._for_me(msg):
            return
        # PX4 accepts a new EKF origin only while landed; the vehicle stays where it is
        # physically, so its local coordinates shift by the origin change.
        if not self.landed:
            return
        new = (msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1e3)
        shift = self.global_to_ned(*new) if abs(new[0]) <= 90.0 and abs(new[1]) <= 180.0 else None
        if shift is None or not (np.all(np.abs(shift) < _MAX_ORIGIN_MOVE_M)):
            # the mock's local frame is a flat tangent plane: it keeps the EKF origin within
            # 50 km of the vehicle (and degE7 / mm fields from overflowing)
            self.statustext(mavlink2.MAV_SEVERITY_WARNING, "EKF origin rejected: too far")
            return
        self._move_origin(new, shift)

    def reset_ekf_origin(self, north_m: float, east_m: float) -> None:
        """Move the EKF origin by (``north_m``, ``east_m``) now, in the air or not: what
        PX4's EKF2 does when it re-initialises its global origin (a GNSS reset). The vehicle
        stays where it is, its local coordinates (and the setpoint it holds) shift, and the
        new GPS_GLOBAL_ORIGIN is sent."""
        lat0, lon0, h0 = self.origin_lla
        lat, lon, alt = pymap3d.ned2geodetic(north_m, east_m, 0.0, lat0, lon0, h0)
        new = (float(lat), float(lon), float(alt))
        self._move_origin(new, self.global_to_ned(*new))

    def _move_origin(self, new: tuple[float, float, float], shift: np.ndarray) -> None:
        """The EKF origin becomes ``new`` (lat, lon, alt), ``shift`` away in the local frame."""
        self.origin_lla = new
        i = self.index
        lat0, lon0, h0 = self.spawn_lla
        n, e, d = pymap3d.geodetic2ned(*new, lat0, lon0, h0)
        self.phys.estimator.set_origin(i, np.array([float(n), float(e), float(d)]))
        self.phys.update_estimate()
        self.phys.sp_pos_ned_m[i] -= shift
        self.home_ned_m = self.home_ned_m - shift
        self.fleet.origins_changed()
        self.send(self._msg_gps_global_origin())
