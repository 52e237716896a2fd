"""Commands of the mock vehicle: COMMAND_LONG/COMMAND_INT, arming and the flight modes.

Mixed into :class:`mavlink.mock.vehicle.MockVehicle`.  Every ``COMMAND_LONG`` or
``COMMAND_INT`` addressed to the autopilot (component 0 or 1) goes to its ``_cmd_*`` handler
by ``MAV_CMD`` (:attr:`CommandsMixin._COMMANDS`, with the gimbal manager's and the ROI's
from :mod:`mavlink.mock.payload`) and is answered with one ``COMMAND_ACK`` (none for a
command PX4 leaves to a module the vehicle lacks: the gimbal manager's without a gimbal); a
handler may leave an action to run after the ACK (a requested message follows its ACK, as
on PX4).  The camera and the gimbal device then see it too (their own component, or a
broadcast) and answer for themselves.  Arming with PX4's pre-arm checks, the mode
switches a client may request and what entering each mode sets up (:meth:`set_mode`)
live here too: they are what commands ask for, and the navigator and the failsafes
enter modes through the same :meth:`set_mode`.  A room of its own because it is the
vehicle's command surface, apart from how the vehicle then flies (navigator, offboard).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, TypeAlias

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock.mission import MISSION
from mavlink.mock.parts import VehicleParts
from mavlink.mock.sim.px4 import Px4Mode
from mavlink.mock.telemetry import DEFAULT_RATES_HZ, Stream

#: A pymavlink message (its fields are per message type: untyped to mypy).
Msg: TypeAlias = Any

ACCEPTED = mavlink2.MAV_RESULT_ACCEPTED
TEMPORARILY_REJECTED = mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
DENIED = mavlink2.MAV_RESULT_DENIED
UNSUPPORTED = mavlink2.MAV_RESULT_UNSUPPORTED
FAILED = mavlink2.MAV_RESULT_FAILED

_FORCE_MAGIC = 21196.0

#: A handler's answer: the ACK's result (None: no ACK, the command is left to a module the
#: vehicle lacks, as PX4's commander does) and what to run after the ACK (or nothing).
_Reply: TypeAlias = tuple[int | None, Callable[[], None] | None]


class CommandsMixin(VehicleParts):
    """Command handlers, arming and mode logic of :class:`~mavlink.mock.vehicle.MockVehicle`."""

    def _on_command_long(self, msg: Msg) -> None:
        if not self._for_me(msg):
            return
        p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        if msg.target_component in (0, 1):
            self._command(msg, msg.command, p, mavlink2.MAV_FRAME_GLOBAL, is_int=False)
        self._payload_command(msg, p)

    def _on_command_int(self, msg: Msg) -> None:
        if not self._for_me(msg):
            return
        p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y, msg.z)
        if msg.target_component in (0, 1):
            self._command(msg, msg.command, p, msg.frame, is_int=True)
        self._payload_command(msg, p)

    def _command(
        self, msg: Msg, command: int, p: tuple[float, ...], frame: int, is_int: bool
    ) -> None:
        handler = self._COMMANDS.get(command)
        self._cmd_partner = (command, msg.get_srcSystem(), msg.get_srcComponent())
        result: int | None
        if handler is None:
            result = UNSUPPORTED
            after = None
        else:
            result, after = handler(self, p, frame, is_int)
        if result is not None:
            self.send(
                mavlink2.MAVLink_command_ack_message(
                    command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
                )
            )
        if after is not None:
            after()

    def _cmd_arm_disarm(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        force = abs(p[1] - _FORCE_MAGIC) < 0.5
        if p[0] >= 0.5:
            return self.arm(force=force), None
        return self.disarm(force=force), None

    def arm(self, force: bool = False) -> int:
        """Arm as PX4 does (pre-arm checks unless forced); returns a MAV_RESULT."""
        if self.armed:
            return ACCEPTED
        if not force:
            reason = self.arming_denied_reason()
            if reason:
                self.statustext(mavlink2.MAV_SEVERITY_CRITICAL, f"Arming denied: {reason}")
                return TEMPORARILY_REJECTED
        self.armed = True
        self.phys.armed[self.index] = True
        # PX4 idles on the ground until a climb is wanted (see _takeoff_gate)
        self.phys.idle[self.index] = self.landed and self.px4_nav
        self._armed_at_s = self._now()
        self.has_flown = not self.landed
        if self.landed:
            self.home_ned_m = self.phys.pos_ned_m[self.index].copy()
        self.failsafe = False
        if self.mode in (Px4Mode.AUTO_LOITER, Px4Mode.AUTO_READY):
            self.phys.hold_here(self.index)
        self.statustext(mavlink2.MAV_SEVERITY_INFO, "Armed by external command")
        return ACCEPTED

    def arming_denied_reason(self) -> str:
        if self._now() < self.config.ready_after_s:
            return "EKF not ready, wait for GPS lock"
        if self.mode is Px4Mode.OFFBOARD and not self._stream_ok():
            return "no offboard signal"
        if self.mode is Px4Mode.AUTO_MISSION and not self.missions.plans[MISSION]:
            return "no valid mission"
        if self._fence_breached:
            return "geofence violation"
        return ""

    def disarm(self, force: bool = False) -> int:
        """Disarm; refused in the air unless forced.  Returns a MAV_RESULT."""
        if not self.armed:
            return ACCEPTED
        if not self.landed and not force:
            self.statustext(mavlink2.MAV_SEVERITY_CRITICAL, "Disarming denied: not landed")
            return DENIED
        self._do_disarm("Disarmed by external command")
        return ACCEPTED

    def _do_disarm(self, why: str) -> None:
        self.armed = False
        self.phys.armed[self.index] = False
        self.statustext(mavlink2.MAV_SEVERITY_INFO, why)

    def _cmd_set_mode(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        if not (int(p[0]) & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED):
            return UNSUPPORTED, None
        mode = Px4Mode.from_main_sub(int(p[1]), int(p[2]))
        if mode is None or mode is Px4Mode.AUTO_READY:
            self.statustext(mavlink2.MAV_SEVERITY_WARNING, "Unsupported mode")
            return DENIED, None
        return self.request_mode(mode), None

    def request_mode(self, mode: Px4Mode) -> int:
        """A mode switch requested by a client; returns a MAV_RESULT."""
        if mode is self.mode and not self.failsafe:
            return ACCEPTED
        if mode.needs_manual_control:
            self.statustext(
                mavlink2.MAV_SEVERITY_CRITICAL,
                f"Switching to {mode.name} is not possible: no manual control",
            )
            return TEMPORARILY_REJECTED
        if mode is Px4Mode.OFFBOARD and not self._stream_ok():
            self.statustext(
                mavlink2.MAV_SEVERITY_CRITICAL, "Switching to Offboard is currently not possible"
            )
            return TEMPORARILY_REJECTED
        if mode is Px4Mode.AUTO_MISSION and not self.missions.plans[MISSION]:
            self.statustext(mavlink2.MAV_SEVERITY_CRITICAL, "Mission rejected: no mission")
            return TEMPORARILY_REJECTED
        if mode is Px4Mode.AUTO_MISSION and self._mission_not_ready():
            return ACCEPTED  # and a late TEMPORARILY_REJECTED, as PX4 (_mission_not_ready)
        self.failsafe = False
        self.set_mode(mode)
        return ACCEPTED

    def _mission_not_ready(self) -> bool:
        """PX4's window after a mission upload in which the commander still flags the mission
        missing (``auto_mission_missing``, ~90 ms on SITL): the mode switch is acknowledged
        ACCEPTED by the MAVLink receiver, then TEMPORARILY_REJECTED ~12 ms later by the
        commander, and the vehicle stays in its mode.  True (and the late ACK scheduled)
        inside that window."""
        window_s = self.params["MOCK_MIS_RDY_T"]
        now = self._now()
        if not (window_s > 0 and now - self._mission_valid_s < window_s):
            return False
        command, sysid, compid = self._cmd_partner

        def reject() -> None:
            self.statustext(mavlink2.MAV_SEVERITY_CRITICAL, "Mission rejected: mission invalid")
            self.send(
                mavlink2.MAVLink_command_ack_message(
                    command, TEMPORARILY_REJECTED, 0, 0, sysid, compid
                )
            )

        self._deferred.append((now + 0.012, reject))
        return True

    def set_mode(self, mode: Px4Mode, takeoff_down_m: float | None = None) -> None:
        """Enter ``mode`` (no checks) and set up its controller targets."""
        i = self.index
        phys = self.phys
        was_mission = self.mode is Px4Mode.AUTO_MISSION
        self._payload_mode_change(self.mode, mode)
        self.mode = mode
        self.traj.active = False
        self._apply_limits()
        pos = phys.pos_ned_m[i]
        if mode is Px4Mode.AUTO_LOITER:
            phys.hold_here(i)
        elif mode is Px4Mode.AUTO_TAKEOFF:
            if takeoff_down_m is None:
                takeoff_down_m = float(self.home_ned_m[2]) - self.params["MIS_TAKEOFF_ALT"]
            self._takeoff_d_m = min(takeoff_down_m, float(pos[2]))
            target = pos.copy()
            target[2] = self._takeoff_d_m
            phys.set_position(i, target)
            phys.sp_yaw_rad[i] = phys.yaw_rad[i]
            phys.m_yaw[i] = True
        elif mode is Px4Mode.AUTO_LAND:
            self._start_descent()
        elif mode is Px4Mode.AUTO_RTL:
            self._rtl_start()
        elif mode is Px4Mode.AUTO_MISSION:
            if not was_mission or self.mission_finished:
                if self.mission_finished:
                    self.mission_seq = 0
                    self._jump_counts.clear()
                self.mission_finished = False
            self._mission_start_item(self.mission_seq)
        elif mode is Px4Mode.OFFBOARD:
            self._apply_setpoint()

    def _land_speed_m_s(self) -> float:
        """PX4's descent speed when landing, from the height above home.

        ``FlightTaskAuto::_prepareLandSetpoints``: MPC_Z_VEL_MAX_DN above MPC_LAND_ALT1,
        MPC_LAND_SPEED below MPC_LAND_ALT2, linear between (``math::interpolate``).  The
        ideal vehicle lands at MPC_LAND_SPEED throughout.
        """
        prm = self.params
        slow, fast = prm["MPC_LAND_SPEED"], prm["MPC_Z_VEL_MAX_DN"]
        if not self.px4_nav:
            return slow
        height = float(self.home_ned_m[2] - self.phys.pos_ned_m[self.index, 2])
        lo, hi = prm["MPC_LAND_ALT2"], prm["MPC_LAND_ALT1"]
        if height <= lo or hi <= lo:
            return slow if height <= lo else fast
        if height >= hi:
            return fast
        return slow + (fast - slow) * (height - lo) / (hi - lo)

    def _start_descent(self) -> None:
        i = self.index
        self.phys.set_axes(
            i,
            self.phys.pos_ned_m[i].copy(),
            np.array([0.0, 0.0, self._land_speed_m_s()]),
            np.zeros(3),
            np.array([1.0, 1.0, 0.0]),
            np.array([0.0, 0.0, 1.0]),
            np.zeros(3),
        )

    def _cmd_takeoff(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        alt = p[6]
        down = None
        if math.isfinite(alt):
            down = self._alt_to_down(frame if is_int else mavlink2.MAV_FRAME_GLOBAL, float(alt))
        if not self.landed and self.mode is not Px4Mode.AUTO_TAKEOFF and down is None:
            return ACCEPTED, None
        self.failsafe = False
        # PX4 v1.17 ignores param4 (yaw) here: navigator_main.cpp sets the take-off's yaw to
        # NaN ("Navigator doesn't handle the yaw reset"), so the vehicle keeps its heading.
        self.set_mode(Px4Mode.AUTO_TAKEOFF, takeoff_down_m=down)
        return ACCEPTED, None

    def _cmd_land(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        self.failsafe = False
        self.set_mode(Px4Mode.AUTO_LAND)
        return ACCEPTED, None

    def _cmd_rtl(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        self.failsafe = False
        self.set_mode(Px4Mode.AUTO_RTL)
        return ACCEPTED, None

    def _cmd_mission_start(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        plan = self.missions.plans[MISSION]
        if not plan:
            self.statustext(mavlink2.MAV_SEVERITY_CRITICAL, "Mission rejected: no mission")
            return DENIED, None
        if self._mission_not_ready():
            return ACCEPTED, None
        first = int(p[0]) if math.isfinite(p[0]) else 0
        if 0 <= first < len(plan) and first != self.mission_seq:
            self.mission_seq = first
            self.mission_finished = False
        if self.mission_finished:
            self.mission_seq = 0
            self.mission_finished = False
        self.failsafe = False
        self.mode = Px4Mode.AUTO_MISSION
        self._apply_limits()
        self._mission_start_item(self.mission_seq)
        return ACCEPTED, None

    def _cmd_set_mission_current(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        seq = int(p[0]) if math.isfinite(p[0]) else -1
        if not self.set_mission_current(seq):
            return DENIED, None
        return ACCEPTED, None

    def set_mission_current(self, seq: int) -> bool:
        """Make ``seq`` the current mission item; False if out of range."""
        if not (0 <= seq < len(self.missions.plans[MISSION])):
            return False
        self.mission_seq = seq
        self.mission_finished = False
        if self.mode is Px4Mode.AUTO_MISSION:
            self._mission_start_item(seq)
        self._announce_current(set_by_client=True)
        return True

    def _on_mission_set_current(self, msg: Msg) -> None:
        if self._for_me(msg):
            self.set_mission_current(msg.seq)

    def _cmd_reposition(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        if not self.armed or self.landed:
            return TEMPORARILY_REJECTED, None
        i = self.index
        pos = self.phys.pos_ned_m[i].copy()
        if is_int:
            x, y = int(p[4]), int(p[5])
        else:
            x = round(p[4] * 1e7) if math.isfinite(p[4]) else 0
            y = round(p[5] * 1e7) if math.isfinite(p[5]) else 0
        target = self._item_target_ned(
            frame if is_int else mavlink2.MAV_FRAME_GLOBAL, x, y, float(p[6]), pos
        )
        if p[0] > 0:
            self.cruise_speed_m_s = float(p[0])
        self.failsafe = False
        self.set_mode(Px4Mode.AUTO_LOITER)
        self.phys.set_position(i, target)
        if math.isfinite(p[3]):
            # radians: PX4 copies param4 into the setpoint's yaw unconverted
            # (navigator_main.cpp), and MAVSDK's goto_location sends radians
            self.phys.sp_yaw_rad[i] = float(p[3])
        return ACCEPTED, None

    def _cmd_change_speed(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        if p[1] > 0:
            self.cruise_speed_m_s = float(p[1])
        elif p[1] == -1:
            self.cruise_speed_m_s = self.params["MPC_XY_CRUISE"]
        self._apply_limits()
        return ACCEPTED, None

    def _cmd_set_home(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        if p[0] >= 0.5:
            self.home_ned_m = self.phys.pos_ned_m[self.index].copy()
        else:
            if is_int:
                x, y = int(p[4]), int(p[5])
            else:
                x, y = round(p[4] * 1e7), round(p[5] * 1e7)
            self.home_ned_m = self._item_target_ned(
                mavlink2.MAV_FRAME_GLOBAL_INT, x, y, float(p[6]), self.home_ned_m
            )
        self.send(self._msg_home_position())
        return ACCEPTED, None

    def _cmd_request_message(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        msg_id = int(p[0])
        build = self._builders.get(msg_id)
        if build is None:
            return DENIED, None

        def send_it() -> None:
            msg = build()
            if msg is not None:
                self.send(msg)

        return ACCEPTED, send_it

    def _cmd_request_capabilities(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        return ACCEPTED, lambda: self.send(self._msg_autopilot_version())

    def _cmd_set_message_interval(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        msg_id = int(p[0])
        build = self._builders.get(msg_id)
        if build is None:
            return DENIED, None
        interval_us = p[1]
        if interval_us == -1:
            self._streams.pop(msg_id, None)
            return ACCEPTED, None
        if interval_us == 0:
            rate = DEFAULT_RATES_HZ.get(msg_id)
            if rate is None:
                self._streams.pop(msg_id, None)
                return ACCEPTED, None
            interval_s = 1.0 / rate
        elif interval_us > 0:
            interval_s = max(interval_us * 1e-6, self.fleet.dt_s)
        else:
            return DENIED, None
        self._streams[msg_id] = Stream(msg_id, interval_s, self._now(), build)
        return ACCEPTED, None

    def _cmd_get_message_interval(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        msg_id = int(p[0])
        stream = self._streams.get(msg_id)
        interval_us = -1 if stream is None else round(stream.interval_s * 1e6)
        if msg_id not in self._builders:
            interval_us = 0
        return ACCEPTED, lambda: self.send(
            mavlink2.MAVLink_message_interval_message(msg_id, interval_us)
        )

    _COMMANDS: ClassVar[dict[int, Callable[..., _Reply]]] = {
        mavlink2.MAV_CMD_COMPONENT_ARM_DISARM: _cmd_arm_disarm,
        mavlink2.MAV_CMD_DO_SET_MODE: _cmd_set_mode,
        mavlink2.MAV_CMD_NAV_TAKEOFF: _cmd_takeoff,
        mavlink2.MAV_CMD_NAV_LAND: _cmd_land,
        mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH: _cmd_rtl,
        mavlink2.MAV_CMD_MISSION_START: _cmd_mission_start,
        mavlink2.MAV_CMD_DO_SET_MISSION_CURRENT: _cmd_set_mission_current,
        mavlink2.MAV_CMD_DO_REPOSITION: _cmd_reposition,
        mavlink2.MAV_CMD_DO_CHANGE_SPEED: _cmd_change_speed,
        mavlink2.MAV_CMD_DO_SET_HOME: _cmd_set_home,
        mavlink2.MAV_CMD_REQUEST_MESSAGE: _cmd_request_message,
        mavlink2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: _cmd_request_capabilities,
        mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL: _cmd_set_message_interval,
        mavlink2.MAV_CMD_GET_MESSAGE_INTERVAL: _cmd_get_message_interval,
    }
