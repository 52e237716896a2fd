"""Offboard control of the mock vehicle: setpoint messages, the stream check, its loss.

Mixed into :class:`mavlink.mock.vehicle.MockVehicle`.  SET_POSITION_TARGET_LOCAL_NED
(local and body frames), SET_POSITION_TARGET_GLOBAL_INT and SET_ATTITUDE_TARGET become
one stored setpoint in the local NED frame (:class:`Setpoint`), flown while the
vehicle is in OFFBOARD.  As PX4, offboard may be entered only once setpoints have
come at 2 Hz or more for at least 1 s, and when they stop for COM_OF_LOSS_T (the
vehicle's tick watches) the failsafe COM_OBL_RC_ACT takes over.  A room of its own
because it is the path by which the ground station flies a planned trajectory, apart
from PX4's own navigator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, TypeAlias

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock.parts import VehicleParts
from mavlink.mock.sim import px4
from mavlink.mock.sim.physics import GRAVITY_M_S2
from mavlink.mock.sim.px4 import Px4Mode

#: A pymavlink message (its fields are per message type: untyped to mypy).
Msg: TypeAlias = Any

_STREAM_GAP_S = 0.5  # setpoints at >= 2 Hz
_STREAM_MIN_S = 1.0  # ... for at least 1 s before offboard is allowed


@dataclass(slots=True)
class Setpoint:
    """The last offboard setpoint, already in the local NED frame."""

    pos: np.ndarray
    vel: np.ndarray
    acc: np.ndarray
    m_pos: np.ndarray
    m_vel: np.ndarray
    m_acc: np.ndarray
    yaw_rad: float
    yaw_rate_rad_s: float
    use_yaw: bool
    use_yaw_rate: bool


class OffboardMixin(VehicleParts):
    """Offboard setpoints and their failsafe of :class:`~mavlink.mock.vehicle.MockVehicle`."""

    def _stream_ok(self) -> bool:
        now = self._now()
        return (
            now - self._sp_last_s <= _STREAM_GAP_S
            and now - self._sp_stream_start_s >= _STREAM_MIN_S
        )

    def _keepalive(self) -> None:
        now = self._now()
        if now - self._sp_last_s > _STREAM_GAP_S:
            self._sp_stream_start_s = now
        self._sp_last_s = now

    def _on_set_position_target_local(self, msg: Msg) -> None:
        if not self._for_me(msg):
            return
        frame = msg.coordinate_frame
        i = self.index
        if frame not in (
            mavlink2.MAV_FRAME_LOCAL_NED,
            mavlink2.MAV_FRAME_LOCAL_OFFSET_NED,
            mavlink2.MAV_FRAME_BODY_NED,
            mavlink2.MAV_FRAME_BODY_OFFSET_NED,
        ):
            if frame not in self._frame_warned:
                self._frame_warned.add(frame)
                self.statustext(
                    mavlink2.MAV_SEVERITY_WARNING, f"Offboard: frame {frame} not supported"
                )
            return
        pos = np.array([msg.x, msg.y, msg.z], dtype=float)
        vel = np.array([msg.vx, msg.vy, msg.vz], dtype=float)
        acc = np.array([msg.afx, msg.afy, msg.afz], dtype=float)
        if frame in (mavlink2.MAV_FRAME_BODY_NED, mavlink2.MAV_FRAME_BODY_OFFSET_NED):
            yaw = float(self.phys.yaw_rad[i])
            c, s = math.cos(yaw), math.sin(yaw)
            rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            pos, vel, acc = rot @ pos, rot @ vel, rot @ acc
        if frame != mavlink2.MAV_FRAME_LOCAL_NED:
            pos = pos + self.phys.pos_ned_m[i]
        self._store_setpoint(msg.type_mask, pos, vel, acc, msg.yaw, msg.yaw_rate)

    def _on_set_position_target_global(self, msg: Msg) -> None:
        if not self._for_me(msg):
            return
        frame = msg.coordinate_frame
        if frame not in (
            mavlink2.MAV_FRAME_GLOBAL_INT,
            mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
            mavlink2.MAV_FRAME_GLOBAL,
            mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT,
        ):
            return
        pos = self._item_target_ned(
            frame, msg.lat_int, msg.lon_int, msg.alt, self.phys.pos_ned_m[self.index]
        )
        vel = np.array([msg.vx, msg.vy, msg.vz], dtype=float)
        acc = np.array([msg.afx, msg.afy, msg.afz], dtype=float)
        self._store_setpoint(msg.type_mask, pos, vel, acc, msg.yaw, msg.yaw_rate)

    def _on_set_attitude_target(self, msg: Msg) -> None:
        """Attitude + collective thrust (PX4 offboard): the specific force it implies.

        Thrust ``MPC_THR_HOVER`` with a level attitude hovers; the body z axis of
        ``q`` (body -> NED) tilts the thrust.  Body-rate-only setpoints (attitude
        ignored) keep offboard alive but are not flown.
        """
        if not self._for_me(msg):
            return
        if msg.type_mask & 128 or msg.type_mask & 64 or not math.isfinite(msg.thrust):
            self._keepalive()
            return
        w, x, y, z = (float(c) for c in msg.q)
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        if not (norm > 0.0 and math.isfinite(norm)):
            self._keepalive()
            return
        w, x, y, z = w / norm, x / norm, y / norm, z / norm
        body_z_ned = np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])
        specific_force = max(0.0, float(msg.thrust)) / self.params["MPC_THR_HOVER"] * GRAVITY_M_S2
        acc = np.array([0.0, 0.0, GRAVITY_M_S2]) - specific_force * body_z_ned
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        # type mask of SET_POSITION_TARGET_*: everything but the acceleration ignored
        self._store_setpoint(0b0000_0011_1111, np.zeros(3), np.zeros(3), acc, yaw, 0.0)

    def _store_setpoint(
        self,
        type_mask: int,
        pos: np.ndarray,
        vel: np.ndarray,
        acc: np.ndarray,
        yaw: float,
        yaw_rate: float,
    ) -> None:
        m_pos = np.array([not (type_mask & b) for b in (1, 2, 4)], dtype=float)
        m_vel = np.array([not (type_mask & b) for b in (8, 16, 32)], dtype=float)
        m_acc = np.array([not (type_mask & b) for b in (64, 128, 256)], dtype=float)
        m_pos *= np.isfinite(pos)
        m_vel *= np.isfinite(vel)
        m_acc *= np.isfinite(acc)
        # an axis with a position uses velocity/acceleration as feed-forward; an axis with
        # only a velocity is velocity-controlled; an acceleration alone is applied directly
        pos = np.where(m_pos > 0, pos, 0.0)
        vel = np.where(m_vel > 0, vel, 0.0)
        acc = np.where(m_acc > 0, acc, 0.0)
        use_yaw = not (type_mask & 1024) and math.isfinite(yaw)
        use_rate = not (type_mask & 2048) and math.isfinite(yaw_rate) and not use_yaw
        self._keepalive()
        if not (m_pos.any() or m_vel.any() or m_acc.any()):
            return
        self._sp = Setpoint(
            pos, vel, acc, m_pos, m_vel, m_acc, float(yaw), float(yaw_rate), use_yaw, use_rate
        )
        if self.mode is Px4Mode.OFFBOARD:
            self._apply_setpoint()

    def _apply_setpoint(self) -> None:
        sp = self._sp
        i = self.index
        phys = self.phys
        if sp is None:
            phys.hold_here(i)
            return
        phys.set_axes(i, sp.pos, sp.vel, sp.acc, sp.m_pos, sp.m_vel, sp.m_acc)
        phys.m_yaw[i] = sp.use_yaw
        phys.m_yaw_rate[i] = sp.use_yaw_rate
        if sp.use_yaw:
            phys.sp_yaw_rad[i] = sp.yaw_rad
        if sp.use_yaw_rate:
            phys.sp_yaw_rate_rad_s[i] = sp.yaw_rate_rad_s

    def _offboard_lost(self) -> None:
        action = int(self.params["COM_OBL_RC_ACT"])
        mode = px4.OBL_ACTION_MODES.get(action, Px4Mode.AUTO_LOITER)
        self.failsafe = True
        if mode is None:
            self.statustext(mavlink2.MAV_SEVERITY_CRITICAL, "Failsafe: no offboard, disarming")
            self.mode = Px4Mode.AUTO_LOITER
            self._do_disarm("Disarmed by failsafe")
            return
        self.statustext(
            mavlink2.MAV_SEVERITY_CRITICAL, f"Failsafe: no offboard signal, {mode.name}"
        )
        self.set_mode(mode)
