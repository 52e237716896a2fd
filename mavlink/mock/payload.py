"""The payload of the mock vehicle: a MAVLink camera on a gimbal, as PX4 v1.17 drives them.

Mixed into :class:`mavlink.mock.vehicle.MockVehicle`.  A vehicle with a camera
(``MockVehicleConfig.camera``) is PX4 with its gimbal module as the gimbal manager over a
MAVLink gimbal device (``MNT_MODE_IN`` 4, ``MNT_MODE_OUT`` 2) and a MAVLink camera, the two
devices behind PX4's MAVLink routing: their frames go out the vehicle's own downlink, each
encoded from its own component with its own sequence numbers.

The camera, component 100 (``MAV_COMP_ID_CAMERA``)
    sends HEARTBEAT at 1 Hz (``MAV_TYPE_CAMERA``, ``MAV_AUTOPILOT_INVALID``; in the datagram
    of the autopilot's, after it, as PX4 packs what it forwards) and answers the
    commands addressed to it with a COMMAND_ACK from itself; of a broadcast (component 0)
    it answers only the commands it implements, and says nothing to the rest (the
    autopilot answers those).  REQUEST_MESSAGE gives CAMERA_INFORMATION (optics from
    ``MockVehicleConfig.camera_spec``), CAMERA_SETTINGS, STORAGE_INFORMATION,
    CAMERA_CAPTURE_STATUS and an earlier CAMERA_IMAGE_CAPTURED by index (ACK, then the
    message), as do the legacy requests MAVSDK falls back to on its retries.
    IMAGE_START_CAPTURE (interval param2 s, total param3, 0 until stopped, sequence param4)
    takes the first picture at once and then one per interval on absolute deadlines
    until the total or IMAGE_STOP_CAPTURE; a repeated single capture with the same
    sequence number is acknowledged without a second picture (a re-sent command).  Each
    picture is a CAMERA_IMAGE_CAPTURED with the position the autopilot reports in that
    tick's GLOBAL_POSITION_INT and the camera's attitude in NED: the vehicle's heading
    plus the gimbal's yaw, the gimbal's pitch, roll 0.  DO_DIGICAM_CONTROL with param5 = 1
    (shoot) takes one picture too: PX4's navigator sends a mission's single-picture
    IMAGE_START_CAPTURE (param3 = 1) to the camera as that (``Navigator::
    publish_vehicle_command``).
The gimbal manager, in the autopilot (component 1; PX4's ``gimbal`` module,
    ``InputMavlinkGimbalV2``)
    DO_GIMBAL_MANAGER_PITCHYAW is ACCEPTED only from the primary control, anyone else
    gets DENIED; nobody is in control at boot, a client takes it with
    DO_GIMBAL_MANAGER_CONFIGURE (param1/param2 its sysid/compid; -1 unchanged, -2 the
    autopilot itself, -3 release if in control), which PX4 always ACCEPTs.  Pitch and yaw
    are degrees, yaw relative to the vehicle's heading unless param5 has
    GIMBAL_MANAGER_FLAGS_YAW_LOCK (then to north); a NaN angle (either: PX4 makes one
    quaternion of both) leaves the angles alone and the rates (param3, param4, deg/s) drive
    the gimbal, for 2 s after the last setpoint; GIMBAL_MANAGER_FLAGS_NEUTRAL points it
    level ahead (north if the yaw was locked last).  GIMBAL_MANAGER_SET_ATTITUDE from the
    primary control does the same.  DO_SET_ROI_LOCATION (param5-7 lat, lon, alt
    AMSL: PX4 reads param7 as AMSL whatever the frame) is ACCEPTED by the navigator; the
    gimbal then points at the location, re-aimed from the vehicle's estimate every cycle
    (``OutputBase::_handle_position_update``), yaw locked to north; DO_SET_ROI_NONE returns
    it to neutral.  In missions the vehicle also yaws toward the ROI (the navigator's, not
    the gimbal's: :meth:`NavigatorMixin._roi_heading`).  GIMBAL_MANAGER_INFORMATION on
    request (the device's capabilities and limits, device id 154), GIMBAL_MANAGER_STATUS at
    0.5 Hz; AUTOPILOT_VERSION reports ``COMPONENT_IMPLEMENTS_GIMBAL_MANAGER``.
The gimbal device, component 154 (``MAV_COMP_ID_GIMBAL``)
    turns toward the manager's setpoint at ``GimbalSpec.rate_deg_s`` per axis within its
    pitch limits, yaw free; a stabilised gimbal, it keeps roll level and pitch to the
    horizon whatever the lock flags (PX4 asks for a pitch relative to the vehicle unless
    GIMBAL_MANAGER_FLAGS_PITCH_LOCK is set, which a hovering vehicle hardly tells); sends HEARTBEAT
    (``MAV_TYPE_GIMBAL``) with the camera's, GIMBAL_DEVICE_ATTITUDE_STATUS at 10 Hz (PX4
    forwards it from the device: ``Mavlink::handle_message``), yaw in the vehicle frame,
    and GIMBAL_DEVICE_INFORMATION on request.

The navigator issues a mission's camera and gimbal items as PX4's does
(``MissionBlock::issue_command``, ``Navigator::publish_vehicle_command``): when the item
becomes current, as a vehicle command from the autopilot, camera commands to component 100
(param1 if 1..255), the rest to component 0.  PX4 sends every such command out on its links
as COMMAND_LONG (``MavlinkStreamCommandLong``) and re-sends it 3 times (1.0, 1.5 and 2.0 s
later on SITL) while no COMMAND_ACK comes (``MavlinkCommandSender``): the mock does so on the
vehicle's downlink; the camera's ACK to the autopilot ends the re-sending and is not
forwarded to the ground station.  Leaving the mission, the navigator pauses PX4's camera
trigger (DO_TRIGGER_CONTROL -1, 0, 1), stops an interval capture it started and, in the air,
levels the gimbal 0.25 s later (take control, neutral, release); Land and RTL level it at
once (``MissionBase::on_inactivation``, ``Land::on_activation``, ``RTL::on_activation``).

Without a camera none of this exists: nothing answers for components 100 and 154, the
autopilot ignores DO_GIMBAL_MANAGER_PITCHYAW and _CONFIGURE (PX4's commander leaves them to
the absent gimbal module: no COMMAND_ACK), denies a request for GIMBAL_MANAGER_INFORMATION,
and its navigator still accepts the ROI commands and still issues a mission's payload items.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, TypeAlias

from pymavlink.dialects.v20 import common as mavlink2

from mavlink.link.signing import signing_timestamp
from mavlink.mock.parts import VehicleParts
from mavlink.mock.sim.payload_state import CameraState, GimbalControl, GimbalState
from mavlink.mock.sim.px4 import Px4Mode
from mavlink.mock.telemetry import Stream, euler_to_quaternion

#: A pymavlink message (its fields are per message type: untyped to mypy).
Msg: TypeAlias = Any
#: A command handler's answer: the ACK's result (None: no ACK) and what to run after it.
_Reply: TypeAlias = tuple[int | None, Callable[[], None] | None]

CAMERA_COMPID = mavlink2.MAV_COMP_ID_CAMERA
GIMBAL_COMPID = mavlink2.MAV_COMP_ID_GIMBAL
AUTOPILOT_COMPID = 1

ACCEPTED = mavlink2.MAV_RESULT_ACCEPTED
DENIED = mavlink2.MAV_RESULT_DENIED
UNSUPPORTED = mavlink2.MAV_RESULT_UNSUPPORTED

_DEVICE_STATUS_S = 0.1  # the gimbal device's GIMBAL_DEVICE_ATTITUDE_STATUS, 10 Hz
_MANAGER_STATUS_HZ = 0.5  # PX4's GIMBAL_MANAGER_STATUS stream (mavlink_main.cpp)
_NEUTRAL_DELAY_S = 0.25  # Navigator::neutralize_gimbal_if_control_activated
_RATE_TIMEOUT_S = 2.0  # OutputBase::check_and_handle_setpoint_timeout
#: when PX4 re-sends an unacknowledged command (confirmation 1, 2, 3), s after the first:
#: MavlinkCommandSender (TIMEOUT_US 0.5 s, RETRIES 3), as SITL showed it (the first re-send
#: 1.0 s after; docs/px4-behaviour.md, "Cameras and gimbals")
_RESEND_AFTER_S = (1.0, 1.5, 2.0)
_STORAGE_MIB = 30528.0  # a 32 GB card
_IMAGE_MIB = 6.0  # one 12 MP JPEG

_CAMERA_COMMANDS = frozenset(
    {
        mavlink2.MAV_CMD_REQUEST_MESSAGE,
        mavlink2.MAV_CMD_REQUEST_CAMERA_INFORMATION,
        mavlink2.MAV_CMD_REQUEST_CAMERA_SETTINGS,
        mavlink2.MAV_CMD_REQUEST_STORAGE_INFORMATION,
        mavlink2.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS,
        mavlink2.MAV_CMD_REQUEST_CAMERA_IMAGE_CAPTURE,
        mavlink2.MAV_CMD_IMAGE_START_CAPTURE,
        mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE,
        mavlink2.MAV_CMD_DO_DIGICAM_CONTROL,
    }
)
#: The messages the camera sends on request (REQUEST_MESSAGE param1).
_CAMERA_MESSAGES = frozenset(
    {
        mavlink2.MAVLINK_MSG_ID_CAMERA_INFORMATION,
        mavlink2.MAVLINK_MSG_ID_CAMERA_SETTINGS,
        mavlink2.MAVLINK_MSG_ID_STORAGE_INFORMATION,
        mavlink2.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS,
        mavlink2.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED,
    }
)
#: Mission items the navigator hands on as vehicle commands (MissionBlock::issue_command).
PAYLOAD_MISSION_COMMANDS = frozenset(
    {
        mavlink2.MAV_CMD_IMAGE_START_CAPTURE,
        mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE,
        mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
        mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
        mavlink2.MAV_CMD_DO_SET_ROI_LOCATION,
        mavlink2.MAV_CMD_DO_SET_ROI_NONE,
    }
)
_DEVICE_CAPS = (
    mavlink2.GIMBAL_DEVICE_CAP_FLAGS_HAS_NEUTRAL
    | mavlink2.GIMBAL_DEVICE_CAP_FLAGS_HAS_ROLL_LOCK
    | mavlink2.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_AXIS
    | mavlink2.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_LOCK
    | mavlink2.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_AXIS
    | mavlink2.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_FOLLOW
    | mavlink2.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_LOCK
    | mavlink2.GIMBAL_DEVICE_CAP_FLAGS_SUPPORTS_INFINITE_YAW
)


class PayloadMixin(VehicleParts):
    """Camera, gimbal manager and gimbal device of :class:`~mavlink.mock.vehicle.MockVehicle`."""

    _cam_mav: Any
    _gmb_mav: Any
    _gimbal_status_due_s: float

    # ================================================================ set-up
    def _payload_init(self) -> None:
        """Create the camera and gimbal (``config.camera``) and the autopilot's gimbal
        manager messages; called once by the vehicle's constructor."""
        #: the navigator's ROI (PX4's ``vehicle_roi``) in local NED, or None
        self._roi_ned_m = None
        self._nav_capturing = False
        self._neutral_due_s = math.inf
        self._gimbal_status_due_s = 0.0
        if not self.config.camera:
            self.camera = None
            self.gimbal = None
            return
        self.camera = CameraState()
        self.gimbal = GimbalState()
        self._cam_mav = self._component_codec(CAMERA_COMPID)
        self._gmb_mav = self._component_codec(GIMBAL_COMPID)
        self._builders[mavlink2.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION] = (
            self._msg_gimbal_manager_information
        )
        status_id = mavlink2.MAVLINK_MSG_ID_GIMBAL_MANAGER_STATUS
        self._builders[status_id] = self._msg_gimbal_manager_status
        self._streams[status_id] = Stream(
            status_id, 1.0 / _MANAGER_STATUS_HZ, 0.0, self._msg_gimbal_manager_status
        )

    def _component_codec(self, compid: int) -> Any:
        """A MAVLink 2 encoder for component ``compid`` of this system (signing as the
        autopilot does when the fleet has a key: each component keeps its own timestamp)."""
        mav = mavlink2.MAVLink(None, srcSystem=self.sysid, srcComponent=compid)
        key = self.fleet.signing_key
        if key is not None:
            mav.signing.secret_key = key
            mav.signing.sign_outgoing = True
            mav.signing.link_id = 0
            mav.signing.timestamp = signing_timestamp()
        return mav

    def _send_as(self, mav: Any, msg: Msg) -> None:
        """Encode ``msg`` from the component of ``mav`` and send it down the vehicle's link."""
        buf = msg.pack(mav)
        mav.seq = (mav.seq + 1) & 0xFF
        assert self.downlink is not None, "the fleet sets the links before anything is sent"
        self.downlink.push(buf)

    # ================================================================ tick
    def _payload_tick(self, now: float) -> None:
        """The gimbal's motion, the camera's pictures, the devices' messages, the navigator's
        delayed neutral; run by the vehicle's tick."""
        if now >= self._neutral_due_s:
            self._neutral_due_s = math.inf
            self._level_gimbal()
        cam, gmb = self.camera, self.gimbal
        if cam is None or gmb is None:
            return
        self._gimbal_step(self.fleet.dt_s)
        if cam.capturing and now + 1e-9 >= cam.next_s:
            # on the interval's deadlines (no drift); one picture a tick at most
            cam.next_s += cam.interval_s
            if cam.next_s < now:
                cam.next_s = now + cam.interval_s
            self._take_picture()
        if now + 1e-9 >= self._gimbal_status_due_s:
            self._gimbal_status_due_s = now + _DEVICE_STATUS_S
            self._send_as(self._gmb_mav, self._msg_gimbal_device_attitude_status())

    def _payload_heartbeats(self) -> bytes:
        """The camera's and the gimbal device's HEARTBEAT frames, at the autopilot's 1 Hz
        (sent in the autopilot HEARTBEAT's datagram: :meth:`MockVehicle.send`)."""
        frames = b""
        for mav, mav_type in (
            (self._cam_mav, mavlink2.MAV_TYPE_CAMERA),
            (self._gmb_mav, mavlink2.MAV_TYPE_GIMBAL),
        ):
            frames += _component_heartbeat(mav_type).pack(mav)
            mav.seq = (mav.seq + 1) & 0xFF
        return frames

    # ================================================================ routing
    def _payload_command(self, msg: Msg, p: tuple[float, ...]) -> None:
        """A COMMAND_LONG/INT for this system: the camera and the gimbal device answer what
        is theirs (``target_component`` their own, or 0 for the commands they implement)."""
        target = msg.target_component
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if self.camera is not None and target in (0, CAMERA_COMPID):
            self._camera_command(msg.command, p, src, broadcast=target == 0)
        if self.gimbal is not None and target in (0, GIMBAL_COMPID):
            self._gimbal_device_command(msg.command, p, src, broadcast=target == 0)

    def _ack_as(self, mav: Any, command: int, result: int, to: tuple[int, int]) -> None:
        self._send_as(mav, mavlink2.MAVLink_command_ack_message(command, result, 0, 0, *to))

    # ================================================================ camera
    def _camera_command(
        self, command: int, p: Sequence[float], src: tuple[int, int], *, broadcast: bool
    ) -> bool:
        """Run a command at the camera and acknowledge it to ``src`` (on the link unless
        ``src`` is this autopilot: PX4 does not forward an ACK addressed to itself).
        Returns True if the camera acknowledged it (False: silent)."""
        if command not in _CAMERA_COMMANDS:
            if broadcast:
                return False
            result: int = UNSUPPORTED
            after: Callable[[], None] | None = None
        else:
            result, after = self._camera_reply(command, p)
            if broadcast and result == DENIED and command == mavlink2.MAV_CMD_REQUEST_MESSAGE:
                return False  # a request for some other component's message
        if src != (self.sysid, AUTOPILOT_COMPID):
            self._ack_as(self._cam_mav, command, result, src)
        if after is not None:
            after()
        return True

    def _camera_reply(
        self, command: int, p: Sequence[float]
    ) -> tuple[int, Callable[[], None] | None]:
        cam = self.camera
        assert cam is not None
        if command == mavlink2.MAV_CMD_IMAGE_START_CAPTURE:
            return self._start_capture(interval_s=p[1], total=p[2], sequence=p[3])
        if command == mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE:
            cam.capturing = False
            cam.remaining = 0
            return ACCEPTED, None
        if command == mavlink2.MAV_CMD_DO_DIGICAM_CONTROL:
            if _int(p[4]) != 1:  # param5 = 1: shoot (the rest is lens, zoom, focus)
                return ACCEPTED, None
            return ACCEPTED, self._take_picture
        if command == mavlink2.MAV_CMD_REQUEST_MESSAGE:
            msg_id, index = _int(p[0]), _int(p[1])
        else:  # the requests before REQUEST_MESSAGE (MAVSDK sends them on retries)
            msg_id = _LEGACY_REQUESTS[command]
            index = _int(p[0])
            if (
                command != mavlink2.MAV_CMD_REQUEST_CAMERA_IMAGE_CAPTURE
                and _int(p[1 if command == mavlink2.MAV_CMD_REQUEST_STORAGE_INFORMATION else 0])
                != 1
            ):
                return ACCEPTED, None  # 0: stop sending (nothing streams)
        if msg_id not in _CAMERA_MESSAGES:
            return DENIED, None
        if msg_id == mavlink2.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED:
            if not cam.images:
                return DENIED, None
            shot = cam.images[-1] if index < 0 else None
            if shot is None and 0 <= index < len(cam.images):
                shot = cam.images[index]
            if shot is None:
                return DENIED, None
            return ACCEPTED, lambda: self._send_as(self._cam_mav, shot)
        build = {
            mavlink2.MAVLINK_MSG_ID_CAMERA_INFORMATION: self._msg_camera_information,
            mavlink2.MAVLINK_MSG_ID_CAMERA_SETTINGS: self._msg_camera_settings,
            mavlink2.MAVLINK_MSG_ID_STORAGE_INFORMATION: self._msg_storage_information,
            mavlink2.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS: self._msg_camera_capture_status,
        }[msg_id]
        return ACCEPTED, lambda: self._send_as(self._cam_mav, build())

    def _start_capture(
        self, interval_s: float, total: float, sequence: float
    ) -> tuple[int, Callable[[], None] | None]:
        """IMAGE_START_CAPTURE: DENIED for a negative interval, a negative total, or no
        interval for more than one picture; else ACCEPTED and the first picture at once."""
        cam = self.camera
        assert cam is not None
        if not (math.isfinite(interval_s) and math.isfinite(total) and math.isfinite(sequence)):
            return DENIED, None
        count = round(total)
        if interval_s < 0.0 or count < 0 or (interval_s == 0.0 and count != 1):
            return DENIED, None
        seq = round(sequence)
        if count == 1 and seq > 0 and seq == cam.last_sequence:
            return ACCEPTED, None  # a re-sent single capture: the picture is taken already
        cam.last_sequence = seq if count == 1 else cam.last_sequence
        if count == 1:
            cam.capturing = False
            return ACCEPTED, self._take_picture
        cam.capturing = True
        cam.interval_s = float(interval_s)
        cam.remaining = -1 if count == 0 else count
        cam.next_s = self._now()

        def first() -> None:
            # the first picture right after the ACK, then on the interval's deadlines
            if cam.capturing and cam.next_s <= self._now():
                cam.next_s += cam.interval_s
                self._take_picture()

        return ACCEPTED, first

    def _take_picture(self) -> None:
        """One picture: CAMERA_IMAGE_CAPTURED with the reported position and the camera's
        attitude now; counts down an interval capture."""
        cam = self.camera
        assert cam is not None
        i = self.index
        lat, lon, alt = self.fleet.geodetic(i)  # as this tick's GLOBAL_POSITION_INT
        rel = alt - self.home_alt_amsl()
        index = cam.image_count
        msg = mavlink2.MAVLink_camera_image_captured_message(
            self._boot_ms(), round((self.fleet.utc_start_s + self._now()) * 1e6), 0,
            round(lat * 1e7), round(lon * 1e7), round(alt * 1000), round(rel * 1000),
            list(self.camera_q()), index, 1,
            f"file:///DCIM/100MOCK/S{self.sysid:03d}_{index + 1:05d}.JPG".encode(),
        )  # fmt: skip
        cam.images.append(msg)
        if cam.capturing and cam.remaining > 0:
            cam.remaining -= 1
            if cam.remaining == 0:
                cam.capturing = False
        self._send_as(self._cam_mav, msg)

    def camera_q(self) -> tuple[float, float, float, float]:
        """The camera's attitude in the NED earth frame now, quaternion (w, x, y, z): the
        vehicle's heading plus the gimbal's yaw, the gimbal's pitch, roll 0."""
        gmb = self.gimbal
        assert gmb is not None
        yaw = float(self.phys.yaw_rad[self.index]) + gmb.yaw_rad
        return euler_to_quaternion(0.0, gmb.pitch_rad, _wrap_pi(yaw))

    def _msg_camera_information(self) -> Msg:
        spec = self.config.camera_spec
        return mavlink2.MAVLink_camera_information_message(
            self._boot_ms(), _name32(spec.vendor), _name32(spec.model), 0x01000000,
            spec.focal_length_mm, spec.sensor_h_mm, spec.sensor_v_mm, spec.resolution_h_px,
            spec.resolution_v_px, 0, mavlink2.CAMERA_CAP_FLAGS_CAPTURE_IMAGE, 0, b"",
            GIMBAL_COMPID, 0,
        )  # fmt: skip

    def _msg_camera_settings(self) -> Msg:
        return mavlink2.MAVLink_camera_settings_message(
            self._boot_ms(), mavlink2.CAMERA_MODE_IMAGE, math.nan, math.nan, 0
        )

    def _used_mib(self) -> float:
        cam = self.camera
        return 0.0 if cam is None else _IMAGE_MIB * cam.image_count

    def _msg_storage_information(self) -> Msg:
        used = self._used_mib()
        return mavlink2.MAVLink_storage_information_message(
            self._boot_ms(), 1, 1, mavlink2.STORAGE_STATUS_READY, _STORAGE_MIB, used,
            _STORAGE_MIB - used, 90.0, 40.0, mavlink2.STORAGE_TYPE_MICROSD, b"",
            mavlink2.STORAGE_USAGE_FLAG_SET | mavlink2.STORAGE_USAGE_FLAG_PHOTO,
        )  # fmt: skip

    def _msg_camera_capture_status(self) -> Msg:
        cam = self.camera
        assert cam is not None
        interval = cam.capturing and cam.interval_s > 0.0
        return mavlink2.MAVLink_camera_capture_status_message(
            self._boot_ms(), 2 if interval else 0, 0, cam.interval_s if interval else 0.0, 0,
            _STORAGE_MIB - self._used_mib(), cam.image_count, 0,
        )  # fmt: skip

    # ================================================================ gimbal device
    def _gimbal_device_command(
        self, command: int, p: Sequence[float], src: tuple[int, int], *, broadcast: bool
    ) -> None:
        """The gimbal device answers REQUEST_MESSAGE for its GIMBAL_DEVICE_INFORMATION (and
        denies other messages); a device command it does not know is UNSUPPORTED; of a
        broadcast it answers only the request for its information."""
        info_id = mavlink2.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION
        if command == mavlink2.MAV_CMD_REQUEST_MESSAGE and _int(p[0]) == info_id:
            self._ack_as(self._gmb_mav, command, ACCEPTED, src)
            self._send_as(self._gmb_mav, self._msg_gimbal_device_information())
        elif not broadcast and src != (self.sysid, AUTOPILOT_COMPID):
            result = DENIED if command == mavlink2.MAV_CMD_REQUEST_MESSAGE else UNSUPPORTED
            self._ack_as(self._gmb_mav, command, result, src)

    def _gimbal_step(self, dt: float) -> None:
        """Turn the device toward the manager's setpoint for ``dt`` s at its rate limit."""
        gmb = self.gimbal
        assert gmb is not None
        spec = self.config.gimbal_spec
        i = self.index
        vyaw = float(self.phys.yaw_rad[i])
        pitch_t, yaw_t = math.nan, math.nan  # yaw_t: to the vehicle's heading
        pitch_rate, yaw_rate = gmb.pitch_rate_rad_s, gmb.yaw_rate_rad_s
        if gmb.control is GimbalControl.ROI and gmb.roi_ned_m is not None:
            d = gmb.roi_ned_m - self.phys.pos_ned_m[i]
            pitch_t = math.atan2(-float(d[2]), math.hypot(float(d[0]), float(d[1])))
            yaw_t = math.atan2(float(d[1]), float(d[0])) - vyaw
            pitch_rate = yaw_rate = math.nan
        elif gmb.control is GimbalControl.NEUTRAL:
            pitch_t, yaw_t = 0.0, (-vyaw if gmb.yaw_lock else 0.0)
            pitch_rate = yaw_rate = math.nan
        else:
            pitch_t = gmb.pitch_sp_rad
            yaw_t = gmb.yaw_sp_rad - vyaw if gmb.yaw_lock else gmb.yaw_sp_rad
            if self._now() - gmb.updated_s > _RATE_TIMEOUT_S:
                # OutputBase::check_and_handle_setpoint_timeout: a rate setpoint stops
                pitch_rate = gmb.pitch_rate_rad_s = 0.0 if math.isfinite(pitch_rate) else pitch_rate
                yaw_rate = gmb.yaw_rate_rad_s = 0.0 if math.isfinite(yaw_rate) else yaw_rate
        limit = math.radians(spec.rate_deg_s)
        lo, hi = math.radians(spec.pitch_min_deg), math.radians(spec.pitch_max_deg)
        pitch = _slew(gmb.pitch_rad, pitch_t, pitch_rate, limit, dt, wrap=False)
        pitch = min(hi, max(lo, pitch))
        yaw = _wrap_pi(_slew(gmb.yaw_rad, yaw_t, yaw_rate, limit, dt, wrap=True))
        gmb.pitch_rate_now_rad_s = (pitch - gmb.pitch_rad) / dt
        gmb.yaw_rate_now_rad_s = _wrap_pi(yaw - gmb.yaw_rad) / dt
        gmb.pitch_rad, gmb.yaw_rad = pitch, yaw

    def _device_flags(self) -> int:
        gmb = self.gimbal
        assert gmb is not None
        flags = (
            mavlink2.GIMBAL_DEVICE_FLAGS_ROLL_LOCK
            | mavlink2.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
            | mavlink2.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
        )
        if gmb.yaw_lock or gmb.control is GimbalControl.ROI:
            flags |= mavlink2.GIMBAL_DEVICE_FLAGS_YAW_LOCK
        return flags

    def _msg_gimbal_device_attitude_status(self) -> Msg:
        gmb = self.gimbal
        assert gmb is not None
        i, p = self.index, self.phys
        q = euler_to_quaternion(0.0, gmb.pitch_rad, gmb.yaw_rad)  # yaw in the vehicle frame
        return mavlink2.MAVLink_gimbal_device_attitude_status_message(
            0, 0, self._boot_ms(), self._device_flags(), list(q), 0.0,
            gmb.pitch_rate_now_rad_s, gmb.yaw_rate_now_rad_s, 0, float(p.yaw_rad[i]),
            float(p.yaw_rate_rad_s[i]), 0,
        )  # fmt: skip

    def _msg_gimbal_device_information(self) -> Msg:
        spec = self.config.gimbal_spec
        return mavlink2.MAVLink_gimbal_device_information_message(
            self._boot_ms(), b"stl-gcs", b"mock gimbal", b"", 0x01000000, 0,
            (self.uid + GIMBAL_COMPID) & 0xFFFF_FFFF_FFFF_FFFF, _DEVICE_CAPS, 0, 0.0, 0.0,
            math.radians(spec.pitch_min_deg), math.radians(spec.pitch_max_deg), -math.pi,
            math.pi, 0,
        )  # fmt: skip

    # ================================================================ gimbal manager
    def _msg_gimbal_manager_information(self) -> Msg:
        # InputMavlinkGimbalV2::_stream_gimbal_manager_information with a MAVLink v2 device:
        # the device's capabilities and limits, its component id
        spec = self.config.gimbal_spec
        return mavlink2.MAVLink_gimbal_manager_information_message(
            self._boot_ms(), _DEVICE_CAPS, GIMBAL_COMPID, 0.0, 0.0,
            math.radians(spec.pitch_min_deg), math.radians(spec.pitch_max_deg), -math.pi,
            math.pi,
        )  # fmt: skip

    def _msg_gimbal_manager_status(self) -> Msg:
        gmb = self.gimbal
        assert gmb is not None
        return mavlink2.MAVLink_gimbal_manager_status_message(
            self._boot_ms(), self._device_flags(), GIMBAL_COMPID, *gmb.primary, 0, 0
        )

    def gimbal_pitchyaw(self, p: Sequence[float], source: tuple[int, int]) -> int | None:
        """DO_GIMBAL_MANAGER_PITCHYAW from ``source``; the MAV_RESULT (None: no gimbal)."""
        gmb = self.gimbal
        if gmb is None:
            return None
        if source != gmb.primary:
            return DENIED
        pitch, yaw = math.radians(p[0]), math.radians(p[1])
        rates = math.radians(p[2]), math.radians(p[3])  # deg/s
        self._gimbal_set_attitude(gmb, _flags(p[4]), pitch, yaw, *rates)
        return ACCEPTED

    def _gimbal_set_attitude(
        self, gmb: GimbalState, flags: int, pitch: float, yaw: float, pitch_rate: float,
        yaw_rate: float,
    ) -> None:  # fmt: skip
        """``_set_control_data_from_set_attitude``: neutral, or angles with their locks."""
        gmb.updated_s = self._now()
        if flags & mavlink2.GIMBAL_MANAGER_FLAGS_RETRACT:
            return  # not implemented in PX4's ControlData
        if flags & mavlink2.GIMBAL_MANAGER_FLAGS_NEUTRAL:
            gmb.control = GimbalControl.NEUTRAL
            return
        gmb.control = GimbalControl.ANGLE
        # one quaternion of (0, pitch, yaw) in PX4: a NaN angle spoils both
        both = math.isfinite(pitch) and math.isfinite(yaw)
        gmb.pitch_sp_rad = pitch if both else math.nan
        gmb.yaw_sp_rad = _wrap_pi(yaw) if both else math.nan
        gmb.pitch_rate_rad_s = float(pitch_rate)
        gmb.yaw_rate_rad_s = float(yaw_rate)
        gmb.yaw_lock = bool(flags & mavlink2.GIMBAL_MANAGER_FLAGS_YAW_LOCK)

    def gimbal_configure(self, p: Sequence[float], source: tuple[int, int]) -> int | None:
        """DO_GIMBAL_MANAGER_CONFIGURE from ``source``: the primary control; None: no gimbal."""
        gmb = self.gimbal
        if gmb is None:
            return None
        own = (self.sysid, AUTOPILOT_COMPID)
        new = []
        for k in range(2):
            value = round(p[k]) if math.isfinite(p[k]) else -1
            if 0 <= value < 256:
                new.append(value)
            elif value == -2:
                new.append(own[k])  # set itself: the autopilot
            elif value == -3 and gmb.primary[k] == source[k]:
                new.append(0)  # release control if in control
            else:
                new.append(gmb.primary[k])  # -1 (or unknown): unchanged
        gmb.primary = (new[0], new[1])
        return ACCEPTED

    def set_roi(self, lat_deg: float, lon_deg: float, alt_m: float) -> None:
        """The navigator's ROI (DO_SET_ROI_LOCATION): the gimbal points at it."""
        if not all(math.isfinite(v) for v in (lat_deg, lon_deg, alt_m)):
            return
        roi = self.global_to_ned(lat_deg, lon_deg, alt_m)
        self._roi_ned_m = roi
        if self.gimbal is not None:
            self.gimbal.control = GimbalControl.ROI
            self.gimbal.roi_ned_m = roi
            self.gimbal.yaw_lock = True  # OutputBase::_handle_position_update

    def clear_roi(self) -> None:
        """DO_SET_ROI_NONE: no ROI; the gimbal goes neutral."""
        self._roi_ned_m = None
        if self.gimbal is not None:
            self.gimbal.control = GimbalControl.NEUTRAL
            self.gimbal.roi_ned_m = None

    def _cmd_gimbal_pitchyaw(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        _, sysid, compid = self._cmd_partner
        return self.gimbal_pitchyaw(p, (sysid, compid)), None

    def _cmd_gimbal_configure(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        _, sysid, compid = self._cmd_partner
        return self.gimbal_configure(p, (sysid, compid)), None

    def _cmd_roi_location(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        # COMMAND_INT carries degE7 in x/y; PX4 reads param7 as AMSL in either form
        scale = 1e-7 if is_int else 1.0
        self.set_roi(p[4] * scale, p[5] * scale, p[6])
        return ACCEPTED, None

    def _cmd_roi_none(self, p: Sequence[float], frame: int, is_int: bool) -> _Reply:
        self.clear_roi()
        return ACCEPTED, None

    def _on_gimbal_manager_set_attitude(self, msg: Msg) -> None:
        """GIMBAL_MANAGER_SET_ATTITUDE: angles (or rates) from the primary control only."""
        gmb = self.gimbal
        if gmb is None or not self._for_me(msg):  # PX4 looks at no target component
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != gmb.primary:
            return
        w, x, y, z = (float(v) for v in msg.q)
        if all(math.isfinite(v) for v in (w, x, y, z)):
            pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
            yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        else:
            pitch = yaw = math.nan
        self._gimbal_set_attitude(
            gmb, int(msg.flags), pitch, yaw, msg.angular_velocity_y, msg.angular_velocity_z
        )

    _PAYLOAD_COMMANDS: ClassVar[dict[int, Callable[..., _Reply]]] = {
        mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW: _cmd_gimbal_pitchyaw,
        mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE: _cmd_gimbal_configure,
        mavlink2.MAV_CMD_DO_SET_ROI_LOCATION: _cmd_roi_location,
        mavlink2.MAV_CMD_DO_SET_ROI_NONE: _cmd_roi_none,
    }

    # ================================================================ navigator
    def issue_command(self, command: int, p: Sequence[float], target_component: int) -> None:
        """A vehicle command of the navigator (``Navigator::publish_vehicle_command``): run in
        the autopilot (component 0) or at the camera, and sent out as COMMAND_LONG, re-sent
        while no ACK comes (:mod:`module docstring <mavlink.mock.payload>`)."""
        params = [float(v) for v in p]
        own = (self.sysid, AUTOPILOT_COMPID)
        if target_component == AUTOPILOT_COMPID:
            # addressed to the autopilot itself (a mission's camera item with param1 = 1):
            # internal, not sent out, and no module of PX4's takes it
            return
        acked = False
        if target_component == 0:
            if command == mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:
                self.gimbal_pitchyaw(params, own)
            elif command == mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE:
                self.gimbal_configure(params, own)
            elif command == mavlink2.MAV_CMD_DO_SET_ROI_LOCATION:
                self.set_roi(params[4], params[5], params[6])
            elif command == mavlink2.MAV_CMD_DO_SET_ROI_NONE:
                self.clear_roi()
        if self.camera is not None and target_component in (0, CAMERA_COMPID):
            acked = self._camera_command(command, params, own, broadcast=target_component == 0)
        self._send_command_long(command, params, target_component, 0)
        if not acked:
            now = self._now()
            for k, after_s in enumerate(_RESEND_AFTER_S, start=1):
                resend = functools.partial(
                    self._send_command_long, command, params, target_component, k
                )
                self._deferred.append((now + after_s, resend))

    def _send_command_long(
        self, command: int, p: Sequence[float], target_component: int, confirmation: int
    ) -> None:
        self.send(
            mavlink2.MAVLink_command_long_message(
                self.sysid, target_component, command, confirmation, *p
            )
        )

    def _mission_payload_item(self, item: Any) -> None:
        """A mission's camera, gimbal or ROI item becoming current (MissionBlock::issue_command)."""
        cmd = item.command
        p = [item.param1, item.param2, item.param3, item.param4, float(item.x), float(item.y),
             item.z]  # fmt: skip
        if cmd == mavlink2.MAV_CMD_DO_SET_ROI_LOCATION:
            # the position at double precision, the altitude AMSL
            p[4], p[5] = item.x * 1e-7, item.y * 1e-7
            if item.frame in _RELATIVE_FRAMES:
                p[6] = item.z + self.home_alt_amsl()
        target = 0
        if cmd in (mavlink2.MAV_CMD_IMAGE_START_CAPTURE, mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE):
            camera = _int(item.param1)
            target = camera if 0 < camera < 256 else CAMERA_COMPID
            if cmd == mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE:
                self._nav_capturing = False
            elif _int(item.param3) == 1:
                # a single picture goes through camera_trigger as DO_DIGICAM_CONTROL (shoot)
                cmd = mavlink2.MAV_CMD_DO_DIGICAM_CONTROL
                p = [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]
                target = CAMERA_COMPID
            else:
                self._nav_capturing = True
        self.issue_command(cmd, p, target)

    def _payload_mode_change(self, old: Px4Mode, new: Px4Mode) -> None:
        """The navigator's payload duties on a mode change (module docstring)."""
        if old is new:
            return
        if old is Px4Mode.AUTO_MISSION:
            # Navigator::disable_camera_trigger (camera_trigger does not run: nobody answers)
            self.issue_command(
                mavlink2.MAV_CMD_DO_TRIGGER_CONTROL, [-1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0], 0
            )
            if self._nav_capturing:  # Navigator::stop_capturing_images
                self._nav_capturing = False
                self.issue_command(mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE, [0.0] * 7, CAMERA_COMPID)
            if not self.landed and self._neutral_due_s == math.inf:
                self._neutral_due_s = self._now() + _NEUTRAL_DELAY_S
        if new in (Px4Mode.AUTO_LAND, Px4Mode.AUTO_RTL):
            self._level_gimbal()

    def _level_gimbal(self) -> None:
        """Navigator: take gimbal control, neutral, release (Navigator::set_gimbal_neutral)."""
        configure = mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE
        nan = math.nan
        own = [float(self.sysid), float(AUTOPILOT_COMPID), -1.0, -1.0, 0.0, 0.0, 0.0]
        self.issue_command(configure, own, 0)
        neutral = float(mavlink2.GIMBAL_MANAGER_FLAGS_NEUTRAL)
        self.issue_command(
            mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, [nan, nan, nan, nan, neutral, 0.0, 0.0], 0
        )
        self.issue_command(configure, [-3.0, -3.0, -1.0, -1.0, 0.0, 0.0, 0.0], 0)


_LEGACY_REQUESTS = {
    mavlink2.MAV_CMD_REQUEST_CAMERA_INFORMATION: mavlink2.MAVLINK_MSG_ID_CAMERA_INFORMATION,
    mavlink2.MAV_CMD_REQUEST_CAMERA_SETTINGS: mavlink2.MAVLINK_MSG_ID_CAMERA_SETTINGS,
    mavlink2.MAV_CMD_REQUEST_STORAGE_INFORMATION: mavlink2.MAVLINK_MSG_ID_STORAGE_INFORMATION,
    mavlink2.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS: mavlink2.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS,
    mavlink2.MAV_CMD_REQUEST_CAMERA_IMAGE_CAPTURE: mavlink2.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED,
}
_RELATIVE_FRAMES = frozenset(
    {mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
)


def _component_heartbeat(mav_type: int) -> Msg:
    return mavlink2.MAVLink_heartbeat_message(
        mav_type, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE, 3
    )


def _slew(now: float, target: float, rate: float, limit: float, dt: float, *, wrap: bool) -> float:
    """One step of an axis: toward ``target`` (NaN: none) at most ``limit`` rad/s, or at the
    commanded ``rate`` (rad/s, NaN: none) within the limit; else it stays."""
    step = limit * dt
    if math.isfinite(target):
        err = _wrap_pi(target - now) if wrap else target - now
        return now + max(-step, min(step, err))
    if math.isfinite(rate):
        return now + max(-step, min(step, rate * dt))
    return now


def _wrap_pi(a: float) -> float:
    """``a`` (rad) wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _int(value: float) -> int:
    return round(value) if math.isfinite(value) else 0


def _flags(value: float) -> int:
    return int(value) if math.isfinite(value) and value >= 0 else 0


def _name32(text: str) -> list[int]:
    raw = text.encode()[:32]
    return list(raw) + [0] * (32 - len(raw))
