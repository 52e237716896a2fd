"""What a vehicle is and what it last reported: :class:`VehicleSpec` (how to reach it) and
:class:`VehicleStatus` (a snapshot of its telemetry), kept by :class:`mavlink.link.vehicle.Vehicle`."""

from __future__ import annotations

from dataclasses import dataclass

from mavlink.px4_modes import Px4Mode
from planner.frames import GeodeticPoint

__all__ = ["VehicleSpec", "VehicleStatus"]


@dataclass(frozen=True, slots=True)
class VehicleSpec:
    """How to reach one vehicle.

    Attributes:
        name: the plan's vehicle name (``"d1"``).
        url: connection URL (validated by :func:`mavlink.link.urls.parse_url`).
        sysid: the MAVLink system id the vehicle uses (1..255).
    """

    name: str
    url: str
    sysid: int


@dataclass(frozen=True, slots=True)
class VehicleStatus:
    """A snapshot of one vehicle's state as the GCS last heard it.

    Fields are ``None`` until the corresponding message has arrived.

    Attributes:
        name, sysid, url: the vehicle.
        connected: a heartbeat arrived within the link timeout.
        armed: from HEARTBEAT.base_mode.
        in_air: from EXTENDED_SYS_STATE.landed_state (MAVSDK's in-air flag).
        mode: decoded PX4 mode, ``None`` if unknown (``custom_mode`` keeps the raw value).
        custom_mode: raw HEARTBEAT.custom_mode.
        pos_ned_m: local position (north, east, down), metres, LOCAL_POSITION_NED.
        vel_ned_m_s: local velocity, m/s.
        position: GLOBAL_POSITION_INT (altitude AMSL).
        relative_alt_m: altitude above home, metres.
        home: HOME_POSITION (altitude AMSL).
        origin: GPS_GLOBAL_ORIGIN (the EKF origin of the local frame).
        battery_remaining: 0..1.
        battery_voltage_v: volts.
        heartbeat_age_s: seconds since the last heartbeat.
        position_age_s: seconds since the last local position.
        heading_deg: heading, degrees clockwise from north (GLOBAL_POSITION_INT.hdg);
            ``None`` also while the vehicle reports it unknown.
        yaw_ned_rad: the latest known heading (GLOBAL_POSITION_INT.hdg), radians clockwise
            from north in the vehicle's local NED frame.
    """

    name: str
    sysid: int
    url: str
    connected: bool
    armed: bool | None
    in_air: bool | None
    mode: Px4Mode | None
    custom_mode: int | None
    pos_ned_m: tuple[float, float, float] | None
    vel_ned_m_s: tuple[float, float, float] | None
    position: GeodeticPoint | None
    relative_alt_m: float | None
    home: GeodeticPoint | None
    origin: GeodeticPoint | None
    battery_remaining: float | None
    battery_voltage_v: float | None
    heartbeat_age_s: float | None
    position_age_s: float | None
    heading_deg: float | None = None
    yaw_ned_rad: float | None = None
