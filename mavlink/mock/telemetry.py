"""Telemetry of the mock vehicle: the MAVLink messages PX4 streams, built from the true state.

Mixed into :class:`mavlink.mock.vehicle.MockVehicle`.  Each ``_msg_*`` method
builds one message for the current tick; positions and velocities carry the
fleet's seeded telemetry noise, global positions are the vehicle's EKF origin
plus its local offset (the fleet converts the whole fleet at once per tick).
The streams that send them at their rates are :class:`Stream` records, run by the
vehicle's tick.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeAlias

import pymap3d
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import px4
from mavlink.mock.mission import MISSION
from mavlink.mock.parts import VehicleParts
from mavlink.mock.sim.px4 import Px4Mode

#: A pymavlink message (its fields are per message type: untyped to mypy).
Msg: TypeAlias = Any

#: Default telemetry rates (Hz) of a PX4 GCS/onboard link, by message id.
DEFAULT_RATES_HZ: dict[int, float] = {
    mavlink2.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mavlink2.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    mavlink2.MAVLINK_MSG_ID_HOME_POSITION: 1.0,
    mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: 1.0,
    mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
    mavlink2.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
    mavlink2.MAVLINK_MSG_ID_VFR_HUD: 4.0,
    mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    mavlink2.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 10.0,
    mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 50.0,
    mavlink2.MAVLINK_MSG_ID_ATTITUDE: 50.0,
    mavlink2.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 1.0,
}


@dataclass(slots=True)
class Stream:
    """One telemetry stream of the vehicle: message ``msg_id``, built by ``build`` every
    ``interval_s`` (s), next due at ``next_s`` (simulation time, s).  Set up at boot from
    :data:`DEFAULT_RATES_HZ` and changed by MAV_CMD_SET_MESSAGE_INTERVAL."""

    msg_id: int
    interval_s: float
    next_s: float
    build: Callable[[], Msg | None]


_EST_FLAGS = (
    mavlink2.ESTIMATOR_ATTITUDE
    | mavlink2.ESTIMATOR_VELOCITY_HORIZ
    | mavlink2.ESTIMATOR_VELOCITY_VERT
    | mavlink2.ESTIMATOR_POS_HORIZ_REL
    | mavlink2.ESTIMATOR_POS_HORIZ_ABS
    | mavlink2.ESTIMATOR_POS_VERT_ABS
    | mavlink2.ESTIMATOR_PRED_POS_HORIZ_REL
    | mavlink2.ESTIMATOR_PRED_POS_HORIZ_ABS
)

_SENSORS = (
    mavlink2.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink2.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink2.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink2.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink2.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink2.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink2.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink2.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | mavlink2.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink2.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mavlink2.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mavlink2.MAV_SYS_STATUS_AHRS
    | mavlink2.MAV_SYS_STATUS_SENSOR_BATTERY
)
_PREARM = mavlink2.MAV_SYS_STATUS_PREARM_CHECK


class LandedState(enum.IntEnum):
    """``MAV_LANDED_STATE`` values reported in EXTENDED_SYS_STATE."""

    ON_GROUND = mavlink2.MAV_LANDED_STATE_ON_GROUND
    IN_AIR = mavlink2.MAV_LANDED_STATE_IN_AIR
    TAKEOFF = mavlink2.MAV_LANDED_STATE_TAKEOFF
    LANDING = mavlink2.MAV_LANDED_STATE_LANDING


class TelemetryMixin(VehicleParts):
    """Message builders of :class:`~mavlink.mock.vehicle.MockVehicle` (one per message type)."""

    def _landed_state(self) -> int:
        if self.landed:
            return LandedState.ON_GROUND
        if self.mode is Px4Mode.AUTO_TAKEOFF:
            return LandedState.TAKEOFF
        if self.mode is Px4Mode.AUTO_LAND or (
            self.mode is Px4Mode.AUTO_RTL and self._rtl_phase == "land"
        ):
            return LandedState.LANDING
        return LandedState.IN_AIR

    def _msg_heartbeat(self) -> Msg:
        base = px4.base_mode_flags(self.mode)
        if self.armed:
            base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        if self.failsafe and self.armed:
            status = mavlink2.MAV_STATE_CRITICAL
        elif self.armed:
            status = mavlink2.MAV_STATE_ACTIVE
        else:
            status = mavlink2.MAV_STATE_STANDBY
        return mavlink2.MAVLink_heartbeat_message(
            mavlink2.MAV_TYPE_QUADROTOR,
            mavlink2.MAV_AUTOPILOT_PX4,
            base,
            self.mode.custom_mode,
            status,
            3,
        )

    def _msg_sys_status(self) -> Msg:
        ready = self._now() >= self.config.ready_after_s
        health = _SENSORS | (_PREARM if ready and not self._fence_breached else 0)
        remaining = self._battery_remaining()
        return mavlink2.MAVLink_sys_status_message(
            _SENSORS | _PREARM, _SENSORS | _PREARM, health,
            250, int(15200 + 1000 * remaining / 100), 1200 if self.armed else 50,
            int(remaining), 0, 0, 0, 0, 0, 0,
        )  # fmt: skip

    def _battery_remaining(self) -> float:
        if self.battery_override_pct is not None:  # a fault's (mavlink.mock.vehicle_faults)
            return self.battery_override_pct
        flown_s = self._now() - self._armed_at_s if self.armed else 0.0
        return max(5.0, 100.0 - 0.05 * flown_s)

    def _msg_battery_status(self) -> Msg:
        remaining = self._battery_remaining()
        volts = [int(15200 + 1000 * remaining / 100)] + [65535] * 9
        return mavlink2.MAVLink_battery_status_message(
            0, mavlink2.MAV_BATTERY_FUNCTION_ALL, mavlink2.MAV_BATTERY_TYPE_LIPO, 2500,
            volts, 1200 if self.armed else 50, -1, -1, int(remaining), -1,
            _charge_state(remaining), [0, 0, 0, 0], 0, 0,
        )  # fmt: skip

    def _msg_extended_sys_state(self) -> Msg:
        return mavlink2.MAVLink_extended_sys_state_message(
            mavlink2.MAV_VTOL_STATE_UNDEFINED, self._landed_state()
        )

    def _msg_home_position(self) -> Msg:
        lat, lon, alt = self.ned_to_global(self.home_ned_m)
        h = self.home_ned_m
        return mavlink2.MAVLink_home_position_message(
            round(lat * 1e7), round(lon * 1e7), round(alt * 1000),
            float(h[0]), float(h[1]), float(h[2]), [1.0, 0.0, 0.0, 0.0],
            0.0, 0.0, 0.0, self._usec(),
        )  # fmt: skip

    def _msg_gps_global_origin(self) -> Msg:
        lat, lon, alt = self.origin_lla
        return mavlink2.MAVLink_gps_global_origin_message(
            round(lat * 1e7), round(lon * 1e7), round(alt * 1000), self._usec()
        )

    def _msg_global_position_int(self) -> Msg:
        i = self.index
        lat, lon, alt = self.fleet.geodetic(i)
        vel = self.phys.vel_ned_m_s[i] + self.phys.noise_vel_m_s[i]
        rel = alt - self.home_alt_amsl()
        hdg = round(math.degrees(self.phys.yaw_rad[i]) * 100) % 36000
        return mavlink2.MAVLink_global_position_int_message(
            self._boot_ms(), round(lat * 1e7), round(lon * 1e7), round(alt * 1000),
            round(rel * 1000), round(vel[0] * 100), round(vel[1] * 100), round(vel[2] * 100),
            hdg,
        )  # fmt: skip

    def _msg_gps_raw_int(self) -> Msg:
        i = self.index
        lat, lon, alt = self.fleet.geodetic(i)
        v = self.phys.vel_ned_m_s[i]
        speed = math.hypot(v[0], v[1])
        cog = round(math.degrees(math.atan2(v[1], v[0])) * 100) % 36000 if speed > 0.2 else 65535
        return mavlink2.MAVLink_gps_raw_int_message(
            self._usec(), mavlink2.GPS_FIX_TYPE_3D_FIX, round(lat * 1e7), round(lon * 1e7),
            round(alt * 1000), 80, 120, round(speed * 100), cog, 12, round(alt * 1000),
            500, 800, 200, 0, 0,
        )  # fmt: skip

    def _msg_local_position_ned(self) -> Msg:
        i = self.index
        p = self.phys.pos_ned_m[i] + self.phys.noise_pos_m[i]
        v = self.phys.vel_ned_m_s[i] + self.phys.noise_vel_m_s[i]
        return mavlink2.MAVLink_local_position_ned_message(
            self._boot_ms(), p[0], p[1], p[2], v[0], v[1], v[2]
        )

    def _msg_attitude(self) -> Msg:
        i, p = self.index, self.phys
        return mavlink2.MAVLink_attitude_message(
            self._boot_ms(), p.roll_rad[i], p.pitch_rad[i], p.yaw_rad[i],
            p.roll_rate_rad_s[i], p.pitch_rate_rad_s[i], p.yaw_rate_rad_s[i],
        )  # fmt: skip

    def _msg_attitude_quaternion(self) -> Msg:
        i, p = self.index, self.phys
        q = euler_to_quaternion(p.roll_rad[i], p.pitch_rad[i], p.yaw_rad[i])
        return mavlink2.MAVLink_attitude_quaternion_message(
            self._boot_ms(), *q,
            p.roll_rate_rad_s[i], p.pitch_rate_rad_s[i], p.yaw_rate_rad_s[i], [0.0] * 4,
        )  # fmt: skip

    def _msg_altitude(self) -> Msg:
        i = self.index
        _, _, alt = self.fleet.geodetic(i)
        rel = alt - self.home_alt_amsl()
        return mavlink2.MAVLink_altitude_message(
            self._usec(), alt, alt, -self.phys.pos_ned_m[i, 2], rel, rel, -1000.0
        )

    def _msg_vfr_hud(self) -> Msg:
        i = self.index
        v = self.phys.vel_ned_m_s[i]
        _, _, alt = self.fleet.geodetic(i)
        speed = math.hypot(v[0], v[1])
        hdg = round(math.degrees(self.phys.yaw_rad[i])) % 360
        throttle = 50 if self.armed and not self.landed else (10 if self.armed else 0)
        return mavlink2.MAVLink_vfr_hud_message(speed, speed, hdg, throttle, alt, -v[2])

    def _msg_mission_current(self) -> Msg:
        plan = self.missions.plans[MISSION]
        if not plan:
            state = mavlink2.MISSION_STATE_NO_MISSION
        elif self.mission_finished:
            state = mavlink2.MISSION_STATE_COMPLETE
        elif self.mode is Px4Mode.AUTO_MISSION and self.armed:
            state = mavlink2.MISSION_STATE_ACTIVE
        elif self.mission_seq == 0:
            state = mavlink2.MISSION_STATE_NOT_STARTED
        else:
            state = mavlink2.MISSION_STATE_PAUSED
        return mavlink2.MAVLink_mission_current_message(
            # mission_mode: 1 in mission mode, 2 not (PX4 v1.17 SITL sends 2, never 0)
            self.mission_seq,
            len(plan),
            state,
            1 if self.mode is Px4Mode.AUTO_MISSION else 2,
        )

    def _msg_position_target(self) -> Msg | None:
        if not self.armed:
            return None
        i, p = self.index, self.phys
        mask = 0
        for k, bit in enumerate((1, 2, 4)):
            if p.m_pos[i, k] == 0:
                mask |= bit
        for k, bit in enumerate((8, 16, 32)):
            if p.m_vel[i, k] == 0:
                mask |= bit
        for k, bit in enumerate((64, 128, 256)):
            if p.m_acc[i, k] == 0:
                mask |= bit
        if not p.m_yaw[i]:
            mask |= 1024
        if not p.m_yaw_rate[i]:
            mask |= 2048
        sp, sv, sa = p.sp_pos_ned_m[i], p.sp_vel_ned_m_s[i], p.sp_acc_ned_m_s2[i]
        return mavlink2.MAVLink_position_target_local_ned_message(
            self._boot_ms(), mavlink2.MAV_FRAME_LOCAL_NED, mask,
            sp[0], sp[1], sp[2], sv[0], sv[1], sv[2], sa[0], sa[1], sa[2],
            p.sp_yaw_rad[i], p.sp_yaw_rate_rad_s[i],
        )  # fmt: skip

    def _msg_estimator_status(self) -> Msg:
        """ESTIMATOR_STATUS: flags and the position accuracy the estimator claims (1 sigma).

        Like EKF2's, the accuracies come from the error model (the configured bias and
        noise magnitudes, the current ground-effect creep), not from the truth.
        """
        prm = self.params
        eph = math.hypot(
            prm["MOCK_ORG_XY_MAX"], math.sqrt(2.0) * prm["MOCK_EST_SLOW_B"], prm["MOCK_EST_P_N"]
        )
        epv = math.hypot(prm["MOCK_ORG_Z_MAX"], prm["MOCK_EST_SLOW_B"]) + float(
            self.phys.estimator.creep_m[self.index]
        )
        return mavlink2.MAVLink_estimator_status_message(
            self._usec(), _EST_FLAGS, 0.1, 0.1, 0.1, 0.0, 0.0, 0.0, max(eph, 0.01),
            max(epv, 0.01),
        )  # fmt: skip

    def _msg_truth(self) -> Msg:
        """HIL_STATE_QUATERNION with the simulator's ground truth (on request only).

        Position and velocity are what really happened, not the estimate: a ``truth``
        track in the telemetry log for comparing estimate and truth (PX4 SIH publishes
        its ground truth the same way).
        """
        i, p = self.index, self.phys
        pos = p.true_pos_ned_m[i]
        lat, lon, alt = pymap3d.ned2geodetic(pos[0], pos[1], pos[2], *self.spawn_lla)
        v = p.true_vel_ned_m_s[i]
        a = p.acc_ned_m_s2[i]
        q = euler_to_quaternion(p.roll_rad[i], p.pitch_rad[i], p.yaw_rad[i])
        mg = 1000.0 / 9.80665
        return mavlink2.MAVLink_hil_state_quaternion_message(
            self._usec(), list(q), p.roll_rate_rad_s[i], p.pitch_rate_rad_s[i],
            p.yaw_rate_rad_s[i], round(float(lat) * 1e7), round(float(lon) * 1e7),
            round(float(alt) * 1000), round(v[0] * 100), round(v[1] * 100), round(v[2] * 100),
            round(math.hypot(v[0], v[1]) * 100), round(math.hypot(v[0], v[1]) * 100),
            round(a[0] * mg), round(a[1] * mg), round((a[2] - 9.80665) * mg),
        )  # fmt: skip

    def _msg_autopilot_version(self) -> Msg:
        caps = px4.CAPABILITIES
        if self.gimbal is not None:  # PX4 with MNT_MODE_IN 4 (mavlink_main.cpp)
            caps |= mavlink2.MAV_PROTOCOL_CAPABILITY_COMPONENT_IMPLEMENTS_GIMBAL_MANAGER
        return mavlink2.MAVLink_autopilot_version_message(
            caps, px4.FLIGHT_SW_VERSION, px4.FLIGHT_SW_VERSION, 0, 0,
            [0] * 8, [0] * 8, [0] * 8, 0x26AC, 0x0011, self.uid,
            list(self.uid.to_bytes(8, "little")) + [0] * 10,
        )  # fmt: skip


def euler_to_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def _charge_state(remaining_pct: float) -> int:
    """MAV_BATTERY_CHARGE_STATE of a charge (%) at PX4 v1.17's default thresholds
    (BAT_LOW_THR 15 %, BAT_CRIT_THR 7 %, BAT_EMERGEN_THR 5 %)."""
    if remaining_pct < 5.0:
        return int(mavlink2.MAV_BATTERY_CHARGE_STATE_EMERGENCY)
    if remaining_pct < 7.0:
        return int(mavlink2.MAV_BATTERY_CHARGE_STATE_CRITICAL)
    if remaining_pct < 15.0:
        return int(mavlink2.MAV_BATTERY_CHARGE_STATE_LOW)
    return int(mavlink2.MAV_BATTERY_CHARGE_STATE_OK)
