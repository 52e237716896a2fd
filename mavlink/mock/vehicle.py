"""One mock PX4 quad-rotor: the MAVLink endpoint and the flight logic of PX4's commander/navigator.

A :class:`MockVehicle` owns row ``index`` of the fleet's vectorised
:class:`~mavlink.mock.physics.FleetPhysics`; every physics tick the fleet
calls :meth:`MockVehicle.tick`, which runs the mode logic (takeoff, hold,
land, return, mission, offboard failsafe, geofence, auto-disarm), the mission
protocol timers and the telemetry streams due at that time.  Incoming
datagrams are parsed with pymavlink's MAVLink 2 codec and dispatched by
message type; every ``COMMAND_LONG``/``COMMAND_INT`` addressed to the vehicle is
answered with a ``COMMAND_ACK``.  The navigator (mission execution, return to
launch, geofence) lives in :mod:`mavlink.mock.navigator`, the telemetry
messages in :mod:`mavlink.mock.telemetry`.

Frames: the vehicle's local NED origin is its EKF origin, the spawn point;
global positions are that origin's geodetic coordinates plus the local offset
(pymap3d).  Altitudes are AMSL; "relative" altitudes are above home.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, ClassVar, Protocol, TypeAlias

import numpy as np
import pymap3d
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import px4
from mavlink.mock.config import FaultConfig, MockVehicleConfig, Outage
from mavlink.mock.errors import MockConfigError, MockError
from mavlink.mock.estimator import EstimatorParams
from mavlink.mock.mission import MISSION, MissionItem, MissionServer
from mavlink.mock.navigator import NavigatorMixin
from mavlink.mock.physics import GRAVITY_M_S2, FleetPhysics
from mavlink.mock.profiles import profile_params
from mavlink.mock.px4 import Px4Mode
from mavlink.mock.telemetry import DEFAULT_RATES_HZ, TelemetryMixin
from mavlink.signing import signing_timestamp


class FleetSide(Protocol):
    """What a vehicle needs from the fleet that runs it (:class:`mavlink.mock.fleet.MockFleet`
    is one): the shared clock and physics step, its geodetic position, the link settings.
    Declared here so that the vehicle does not import the fleet, which imports it."""

    time_s: float
    dt_s: float
    signing_key: bytes | None
    seed: int
    gcs_host: str
    gcs_ports: list[int]
    physics: FleetPhysics

    def geodetic(self, i: int) -> tuple[float, float, float]: ...

    def configure_links(self, vehicle: MockVehicle, faults: FaultConfig) -> None: ...

    def origins_changed(self) -> None: ...

    def offline_links(self) -> None: ...


class Link(Protocol):
    """One direction of a vehicle's link: datagrams pushed in are delivered (or not)."""

    def push(self, data: bytes) -> None: ...


#: A pymavlink message (its fields are per message type: untyped to mypy).
Msg: TypeAlias = Any

ACCEPTED = mavlink2.MAV_RESULT_ACCEPTED
TEMPORARILY_REJECTED = mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
DENIED = mavlink2.MAV_RESULT_DENIED
UNSUPPORTED = mavlink2.MAV_RESULT_UNSUPPORTED
FAILED = mavlink2.MAV_RESULT_FAILED


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
_FORCE_MAGIC = 21196.0
_STREAM_GAP_S = 0.5  # setpoints at >= 2 Hz
_STREAM_MIN_S = 1.0  # ... for at least 1 s before offboard is allowed
_CLOSE_TO_GROUND_M = 1.0
_MAX_ORIGIN_MOVE_M = 50_000.0  # the land detector's "close to ground" height (estimate)


@dataclass(frozen=True, slots=True)
class VehicleState:
    """A snapshot of one vehicle's state (for tests and status displays).

    ``pos_ned_m`` / ``vel_ned_m_s`` are the *true* position and velocity, and
    ``est_pos_ned_m`` / ``est_vel_ned_m_s`` what the vehicle believes (and reports,
    and flies on), all in its local NED frame (m, m/s) whose origin is its EKF origin
    (with the ideal profile: exactly its spawn point, and estimate = truth).
    """

    sysid: int
    time_s: float
    pos_ned_m: tuple[float, float, float]
    vel_ned_m_s: tuple[float, float, float]
    yaw_rad: float
    mode: Px4Mode
    armed: bool
    landed: bool
    failsafe: bool
    mission_seq: int
    home_ned_m: tuple[float, float, float]
    est_pos_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    est_vel_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(slots=True)
class _Stream:
    msg_id: int
    interval_s: float
    next_s: float
    build: Callable[[], Msg | None]


@dataclass(slots=True)
class _Setpoint:
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


class MockVehicle(TelemetryMixin, NavigatorMixin):
    """Vehicle ``index`` of a :class:`~mavlink.mock.fleet.MockFleet` (system id ``index + 1``)."""

    def __init__(
        self,
        fleet: FleetSide,
        index: int,
        config: MockVehicleConfig,
        spawn_lla: tuple[float, float, float],
        uid: int,
    ) -> None:
        self.fleet = fleet
        self.index = index
        self.sysid = index + 1
        self.config = config
        self.uid = uid
        #: where the vehicle really stands at boot (lat, lon, alt AMSL)
        self.spawn_lla = spawn_lla
        self.phys = fleet.physics
        self._mav = mavlink2.MAVLink(None, srcSystem=self.sysid, srcComponent=1)
        self.signing_rejected = 0
        self._rx = self._new_parser()
        if fleet.signing_key is not None:
            self._mav.signing.secret_key = fleet.signing_key
            self._mav.signing.sign_outgoing = True
            self._mav.signing.link_id = 0
            self._mav.signing.timestamp = signing_timestamp()
        self.params: dict[str, float] = {p.name: float(p.default) for p in px4.PARAM_SPECS}
        self._param_specs = {p.name: p for p in px4.PARAM_SPECS}
        self._param_names = [p.name for p in px4.PARAM_SPECS]
        self.params.update(profile_params(config.profile))
        for name, value in config.params:
            spec = self._param_specs.get(name)
            if spec is None:
                raise MockConfigError(f"vehicle {index}: unknown parameter {name!r}")
            if not spec.accepts(value):
                raise MockConfigError(
                    f"vehicle {index}: parameter {name} = {value!r} outside "
                    f"[{spec.min:g}, {spec.max:g}]"
                )
            self.params[name] = value
        # the EKF origin: the first (noisy) GPS fix, drawn anew at every boot
        est = self.phys.estimator
        est.configure(index, EstimatorParams.from_params(self.params), new_boot=True)
        o = est.origin_ned_m[index]
        lat, lon, alt = pymap3d.ned2geodetic(o[0], o[1], o[2], *spawn_lla)
        #: the EKF origin (lat, lon, alt AMSL): GPS_GLOBAL_ORIGIN, the local frame's origin
        self.origin_lla = (float(lat), float(lon), float(alt))
        self.mode = Px4Mode.AUTO_LOITER
        self.armed = False
        self.landed = True
        self.failsafe = False
        self.has_flown = False
        self._armed_at_s = 0.0
        self._landed_since_s = 0.0
        #: since when the land detector's conditions hold (None: not now)
        self._ground_since_s: float | None = None
        self.home_ned_m = np.zeros(3)
        self.cruise_speed_m_s = self.params["MPC_XY_CRUISE"]
        # offboard
        self._sp: _Setpoint | None = None
        self._sp_last_s = -math.inf
        self._sp_stream_start_s = -math.inf
        self._frame_warned: set[int] = set()
        # auto modes
        self._takeoff_d_m = 0.0
        self._rtl_phase = ""
        self._rtl_alt_d_m = 0.0
        # mission execution
        self.mission_seq = 0
        self.mission_finished = False
        self._mis_phase = ""
        #: a mission land flew to its land point first (PX4 reports that arrival reached)
        self._mis_land_moved = False
        self._mis_target = np.zeros(3)
        self._mis_hold_until_s = 0.0
        self._mis_reached_sent = -1
        self._seq_reached = -1
        self._reached_resends = 0
        self._reached_next_s = 0.0
        # decides which MISSION_CURRENT changes PX4 would send at once (_announce_current)
        self._mc_rng = random.Random(f"mission-current:{fleet.seed}:{index}")
        self._mission_valid_s = -math.inf
        self._jump_counts: dict[int, int] = {}
        # PX4's auto-mode trajectory setpoint (MOCK_PX4_NAV)
        self._traj_active = False
        self._traj_pos = np.zeros(3)
        self._traj_vel = np.zeros(3)
        self._traj_from = np.zeros(3)
        self._traj_exit_m_s = 0.0
        self._leg_prev = np.zeros(3)  # PX4's previous triplet waypoint
        self._leg_radius_m = 2.0  # the current item's acceptance radius
        self._leg_next: np.ndarray | None = None
        # (due time, action) run by tick: PX4's late second COMMAND_ACK
        self._deferred: list[tuple[float, Callable[[], None]]] = []
        self._cmd_partner: tuple[int, int, int] = (0, 0, 0)
        # geofence in local NE (m): list of (kind, inclusion, data)
        self._fence: list[tuple[str, bool, np.ndarray, float]] = []
        self._fence_breached = False
        self.missions = MissionServer(
            send=self.send,
            clock_s=self._now,
            on_changed=self._on_plan_changed,
            current_seq=lambda: self.mission_seq,
            statustext=self.statustext,
            px4_storage=lambda: self.px4_nav,
        )
        self.received: dict[str, int] = {}
        self.remote_addr: tuple[str, int] = (fleet.gcs_host, fleet.gcs_ports[index])
        self._rx_addr = self.remote_addr
        self._transport_send: Callable[[bytes, tuple[str, int]], None] | None = None
        self.uplink: Link | None = None  # a FaultyChannel, set by the fleet
        self.downlink: Link | None = None
        self._streams: dict[int, _Stream] = {}
        self._builders: dict[int, Callable[[], Msg | None]] = {
            mavlink2.MAVLINK_MSG_ID_HEARTBEAT: self._msg_heartbeat,
            mavlink2.MAVLINK_MSG_ID_SYS_STATUS: self._msg_sys_status,
            mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._msg_extended_sys_state,
            mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS: self._msg_battery_status,
            mavlink2.MAVLINK_MSG_ID_HOME_POSITION: self._msg_home_position,
            mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: self._msg_gps_global_origin,
            mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT: self._msg_gps_raw_int,
            mavlink2.MAVLINK_MSG_ID_MISSION_CURRENT: self._msg_mission_current,
            mavlink2.MAVLINK_MSG_ID_VFR_HUD: self._msg_vfr_hud,
            mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._msg_global_position_int,
            mavlink2.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: self._msg_position_target,
            mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._msg_local_position_ned,
            mavlink2.MAVLINK_MSG_ID_ATTITUDE: self._msg_attitude,
            mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._msg_autopilot_version,
            mavlink2.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self._msg_attitude_quaternion,
            mavlink2.MAVLINK_MSG_ID_ALTITUDE: self._msg_altitude,
            mavlink2.MAVLINK_MSG_ID_ESTIMATOR_STATUS: self._msg_estimator_status,
            mavlink2.MAVLINK_MSG_ID_HIL_STATE_QUATERNION: self._msg_truth,
        }
        for msg_id, rate_hz in DEFAULT_RATES_HZ.items():
            self._streams[msg_id] = _Stream(msg_id, 1.0 / rate_hz, 0.0, self._builders[msg_id])
        self._handlers: dict[str, Callable[[Msg], None]] = {
            "COMMAND_LONG": self._on_command_long,
            "COMMAND_INT": self._on_command_int,
            "SET_POSITION_TARGET_LOCAL_NED": self._on_set_position_target_local,
            "SET_POSITION_TARGET_GLOBAL_INT": self._on_set_position_target_global,
            "SET_ATTITUDE_TARGET": self._on_set_attitude_target,
            "PARAM_REQUEST_LIST": self._on_param_request_list,
            "PARAM_REQUEST_READ": self._on_param_request_read,
            "PARAM_SET": self._on_param_set,
            "TIMESYNC": self._on_timesync,
            "MISSION_SET_CURRENT": self._on_mission_set_current,
            "SET_GPS_GLOBAL_ORIGIN": self._on_set_gps_global_origin,
        }
        self._takeoff_wanted_s = math.nan
        self._apply_params()
        self.phys.update_estimate()
        self.phys.hold_here(index)

    # ================================================================ plumbing
    def _new_parser(self) -> mavlink2.MAVLink:
        """The uplink parser; with the fleet's signing key it accepts only signed frames.

        As PX4 with ``MAV_SIGN_CFG`` set, only RADIO_STATUS may come unsigned;
        wrong signatures and replays (a timestamp not newer than the last one
        of the same link/system/component, or a minute older than the newest
        seen) are dropped and counted in :attr:`signing_rejected`.
        """
        rx = mavlink2.MAVLink(None, srcSystem=self.sysid, srcComponent=1)
        rx.robust_parsing = True
        key = self.fleet.signing_key
        if key is not None:
            rx.signing.secret_key = key
            rx.signing.sign_outgoing = False
            rx.signing.timestamp = signing_timestamp()
            rx.signing.allow_unsigned_callback = _radio_status_only
        return rx

    def _now(self) -> float:
        return self.fleet.time_s

    def _boot_ms(self) -> int:
        return int(self.fleet.time_s * 1000.0) & 0xFFFFFFFF

    def _usec(self) -> int:
        return int(self.fleet.time_s * 1e6)

    def send(self, msg: Msg) -> None:
        """Encode ``msg`` as MAVLink 2 from (sysid, 1) and send it to the GCS."""
        mav = self._mav
        buf = msg.pack(mav)
        mav.seq = (mav.seq + 1) & 0xFF
        assert self.downlink is not None, "the fleet sets the links before anything is sent"
        self.downlink.push(buf)

    def _deliver_down(self, data: bytes) -> None:
        if self._transport_send is not None:
            self._transport_send(data, self.remote_addr)

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        """A datagram arrived on the vehicle port: parse it (through the uplink's faults).

        The sender becomes the telemetry destination (as PX4 does) only once a
        valid message from it addressed to this vehicle (``target_system`` 0 or
        its own) or a HEARTBEAT is decoded: junk, unknown messages or frames for
        other systems must not redirect the link.
        """
        self._rx_addr = addr
        assert self.uplink is not None, "the fleet sets the links before it receives"
        self.uplink.push(data)

    def _deliver_up(self, data: bytes) -> None:
        rx = self._rx
        msgs = rx.parse_buffer(data)
        # A datagram holds whole frames: drop what a truncated frame left in the
        # parser, or it would swallow the start of the next (valid) datagram.
        if rx.buf_len():
            rx.buf = bytearray()
            rx.buf_index = 0
            rx.expected_length = mavlink2.HEADER_LEN_V1 + 2
        if not msgs:
            return
        for msg in msgs:
            kind = msg.get_type()
            if kind == "BAD_DATA":
                if "signature" in str(getattr(msg, "reason", "")):
                    self.signing_rejected += 1
                continue
            if getattr(msg, "target_system", None) in (0, self.sysid) or kind == "HEARTBEAT":
                self.remote_addr = self._rx_addr
            self.received[kind] = self.received.get(kind, 0) + 1
            handler = self._handlers.get(kind)
            if handler is not None:
                handler(msg)
            elif kind.startswith("MISSION_"):
                tgt = getattr(msg, "target_system", self.sysid)
                if tgt in (0, self.sysid):
                    self.missions.handle(msg)

    def receive(self, msg: Msg, sysid: int = 255, compid: int = 190) -> None:
        """Hand ``msg`` to the vehicle as if it arrived from (sysid, compid) over its link."""
        if self.uplink is None:
            self.fleet.offline_links()
        mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.datagram_received(msg.pack(mav), self._rx_addr)

    def sent_messages(self) -> list[Msg]:
        """Decode and forget what an offline vehicle sent (:meth:`MockFleet.advance`)."""
        link = self.downlink
        sent: list[bytes] = getattr(link, "sent", [])
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        out: list[Msg] = []
        for data in sent:
            out.extend(m for m in parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA")
        sent.clear()
        return out

    def set_faults(self, faults: FaultConfig) -> None:
        """Replace the link faults of this vehicle (takes effect for the next datagram)."""
        self.fleet.configure_links(self, faults)

    def reboot(self, silent_s: float, *, in_air: bool = False) -> None:
        """Simulate an autopilot reboot on the ground: silent, then back fresh.

        For ``silent_s`` seconds of simulation time nothing passes the link in
        either direction (no heartbeat); the vehicle then comes back disarmed
        in AUTO_LOITER with no offboard setpoint, a new parser and its MAVLink
        sequence restarted at 0.  Stored plans survive (PX4 keeps them on the
        SD card).  A reboot in the air is refused (:class:`MockError`): PX4
        refuses MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN when not landed; ``in_air``
        injects one anyway (a brown-out or a crash of the autopilot in flight,
        which no command asks for).
        """
        if not self.landed and not in_air:
            raise MockError(f"vehicle {self.index}: no reboot in the air")
        if not (silent_s > 0.0 and math.isfinite(silent_s)):
            raise MockConfigError(f"reboot silent_s must be a finite number > 0, got {silent_s!r}")
        now = self._now()
        faults = self.config.faults
        outage = Outage(now, now + silent_s)
        self.fleet.configure_links(self, replace(faults, outages=(*faults.outages, outage)))
        self.armed = False
        self.phys.armed[self.index] = False
        self.failsafe = False
        self._sp = None
        self._sp_last_s = -math.inf
        self.mode = Px4Mode.AUTO_LOITER
        self.phys.hold_here(self.index)
        self._mav.seq = 0
        self._rx = self._new_parser()

    def statustext(self, severity: int, text: str) -> None:
        """Send a STATUSTEXT (text cut to the 50 bytes MAVLink allows)."""
        raw = text.encode("ascii", "replace")[:50]
        self.send(mavlink2.MAVLink_statustext_message(severity, raw, 0, 0))

    @property
    def state(self) -> VehicleState:
        """Snapshot of the true state (thread-safe enough for tests: values are copied)."""
        i = self.index
        p = self.phys
        true_local = p.true_pos_ned_m[i] - p.estimator.origin_ned_m[i]
        return VehicleState(
            sysid=self.sysid,
            time_s=self.fleet.time_s,
            pos_ned_m=tuple(float(v) for v in true_local),
            vel_ned_m_s=tuple(float(v) for v in p.true_vel_ned_m_s[i]),
            yaw_rad=float(p.yaw_rad[i]),
            mode=self.mode,
            armed=self.armed,
            landed=self.landed,
            failsafe=self.failsafe,
            mission_seq=self.mission_seq,
            home_ned_m=tuple(float(v) for v in self.home_ned_m),
            est_pos_ned_m=tuple(float(v) for v in p.pos_ned_m[i]),
            est_vel_ned_m_s=tuple(float(v) for v in p.vel_ned_m_s[i]),
        )

    def mission_items(self, mission_type: int = MISSION) -> tuple[MissionItem, ...]:
        """The stored plan of ``mission_type`` (MAV_MISSION_TYPE_*)."""
        return self.missions.plans[mission_type]

    def store_plan(self, items: Sequence[Any], mission_type: int = MISSION) -> None:
        """Store ``items`` (anything with MISSION_ITEM_INT's fields) as if uploaded.

        For offline use (prediction, tests): no transfer, the vehicle reacts as to a
        completed upload.
        """
        self.missions.plans[mission_type] = tuple(
            MissionItem(**{f: getattr(it, f) for f in MissionItem.__dataclass_fields__})
            for it in items
        )
        self._on_plan_changed(mission_type)

    # ================================================================ geodesy
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

    def _home_alt_amsl(self) -> float:
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

    # ================================================================ parameters
    def _apply_params(self) -> None:
        i, p, prm = self.index, self.phys, self.params
        p.kp_pos[i] = (prm["MPC_XY_P"], prm["MPC_XY_P"], prm["MPC_Z_P"])
        p.kp_vel[i] = (prm["MPC_XY_VEL_P_ACC"], prm["MPC_XY_VEL_P_ACC"], prm["MPC_Z_VEL_P_ACC"])
        p.ki_vel[i] = (prm["MPC_XY_VEL_I_ACC"], prm["MPC_XY_VEL_I_ACC"], prm["MPC_Z_VEL_I_ACC"])
        p.kd_vel[i] = (prm["MPC_XY_VEL_D_ACC"], prm["MPC_XY_VEL_D_ACC"], prm["MPC_Z_VEL_D_ACC"])
        p.kdv_per_s[i] = prm["SIH_KDV"] / prm["SIH_MASS"]  # SIH: force per m/s over mass
        p.yaw_p[i] = prm["MC_YAW_P"]
        # the tilt follows PX4's attitude loop (1 / MC_ROLL_P, MC_PITCH_P: the slower one)
        gain = min(prm["MC_ROLL_P"], prm["MC_PITCH_P"])
        p.att_tau_s[i] = 1.0 / gain if prm["MOCK_ATT_DYN"] >= 0.5 and gain > 0.0 else 0.0
        p.set_thrust_tau(i, prm["SIH_T_TAU"])
        p.estimator.configure(i, EstimatorParams.from_params(prm), new_boot=False)
        self._apply_limits()

    @property
    def px4_nav(self) -> bool:
        """True when PX4 v1.17's navigator, take-off and storage are modelled (MOCK_PX4_NAV)."""
        return self.params["MOCK_PX4_NAV"] >= 0.5

    def _apply_limits(self) -> None:
        """Speed/acceleration limits of the current mode from the parameters."""
        i, p, prm = self.index, self.phys, self.params
        auto = self.mode.value[0] == 4
        p.vel_xy_max_m_s[i] = (
            min(self.cruise_speed_m_s, prm["MPC_XY_VEL_MAX"]) if auto else prm["MPC_XY_VEL_MAX"]
        )
        self._vel_up_base = (
            prm["MPC_TKO_SPEED"] if self.mode is Px4Mode.AUTO_TAKEOFF else prm["MPC_Z_VEL_MAX_UP"]
        )
        p.vel_up_max_m_s[i] = self._vel_up_base
        p.vel_dn_max_m_s[i] = prm["MPC_Z_VEL_MAX_DN"]
        if self.px4_nav:
            # PX4's position controller limits the acceleration only by the tilt; the
            # trajectory generators of the auto modes respect MPC_ACC_HOR themselves
            p.acc_xy_max_m_s2[i] = GRAVITY_M_S2 * math.tan(math.radians(prm["MPC_TILTMAX_AIR"]))
        else:
            p.acc_xy_max_m_s2[i] = prm["MPC_ACC_HOR"] if auto else prm["MPC_ACC_HOR_MAX"]
        p.acc_up_max_m_s2[i] = prm["MPC_ACC_UP_MAX"]
        p.acc_dn_max_m_s2[i] = prm["MPC_ACC_DOWN_MAX"]
        yaw_max = (
            prm["MC_YAWRATE_MAX"] if self.mode is Px4Mode.OFFBOARD else prm["MPC_YAWRAUTO_MAX"]
        )
        p.yaw_rate_max_rad_s[i] = math.radians(yaw_max)

    def _param_value_msg(self, name: str) -> Msg:
        spec = self._param_specs[name]
        return mavlink2.MAVLink_param_value_message(
            name.encode("ascii"),
            px4.encode_param_value(self.params[name], spec.type),
            int(spec.type),
            len(self._param_names),
            self._param_names.index(name),
        )

    def _for_me(self, msg: Msg) -> bool:
        return msg.target_system in (0, self.sysid)

    def _on_param_request_list(self, msg: Msg) -> None:
        if self._for_me(msg):
            for name in self._param_names:
                self.send(self._param_value_msg(name))

    def _on_param_request_read(self, msg: Msg) -> None:
        if not self._for_me(msg):
            return
        if msg.param_index >= 0:
            if msg.param_index < len(self._param_names):
                self.send(self._param_value_msg(self._param_names[msg.param_index]))
            return
        name = _param_name(msg.param_id)
        if name in self.params:
            self.send(self._param_value_msg(name))
        else:
            self.statustext(mavlink2.MAV_SEVERITY_WARNING, f"Parameter {name} not found")

    def _on_param_set(self, msg: Msg) -> None:
        if not self._for_me(msg):
            return
        name = _param_name(msg.param_id)
        spec = self._param_specs.get(name)
        if spec is None:
            self.statustext(mavlink2.MAV_SEVERITY_WARNING, f"Parameter {name} not found")
            return
        value = px4.decode_param_value(msg.param_value, spec.type)
        if not spec.accepts(value):
            self.statustext(
                mavlink2.MAV_SEVERITY_WARNING, f"Parameter {name}: {value:g} out of range"
            )
        else:
            self.params[name] = value
            if name == "MPC_XY_CRUISE":
                self.cruise_speed_m_s = value
            self._apply_params()
        self.send(self._param_value_msg(name))

    def _on_timesync(self, msg: Msg) -> None:
        if msg.tc1 == 0:
            self.send(mavlink2.MAVLink_timesync_message(self._usec() * 1000, msg.ts1))

    # ================================================================ commands
    def _on_command_long(self, msg: Msg) -> None:
        if not self._for_me(msg) or msg.target_component not in (0, 1):
            return
        p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        self._command(msg, msg.command, p, mavlink2.MAV_FRAME_GLOBAL, is_int=False)

    def _on_command_int(self, msg: Msg) -> None:
        if not self._for_me(msg) or msg.target_component not in (0, 1):
            return
        p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y, msg.z)
        self._command(msg, msg.command, p, msg.frame, is_int=True)

    def _command(
        self, msg: Msg, command: int, p: tuple[float, ...], frame: int, is_int: bool
    ) -> None:
        handler = self._COMMANDS.get(command)
        self._cmd_partner = (command, msg.get_srcSystem(), msg.get_srcComponent())
        if handler is None:
            result = UNSUPPORTED
            after = None
        else:
            result, after = handler(self, p, frame, is_int)
        self.send(
            mavlink2.MAVLink_command_ack_message(
                command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            )
        )
        if after is not None:
            after()

    def _cmd_arm_disarm(self, p, frame, is_int):  # type: ignore[no-untyped-def]
        force = abs(p[1] - _FORCE_MAGIC) < 0.5
        if p[0] >= 0.5:
            return self.arm(force=force), None
        return self.disarm(force=force), None

    def arm(self, force: bool = False) -> int:
        """Arm as PX4 does (pre-arm checks unless forced); returns a MAV_RESULT."""
        if self.armed:
            return ACCEPTED
        if not force:
            reason = self._arming_denied_reason()
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

    def _arming_denied_reason(self) -> str:
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

    def _cmd_set_mode(self, p, frame, is_int):  # type: ignore[no-untyped-def]
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
        self.mode = mode
        self._traj_active = False
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

    def _cmd_takeoff(self, p, frame, is_int):  # type: ignore[no-untyped-def]
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

    def _cmd_land(self, p, frame, is_int):  # type: ignore[no-untyped-def]
        self.failsafe = False
        self.set_mode(Px4Mode.AUTO_LAND)
        return ACCEPTED, None

    def _cmd_rtl(self, p, frame, is_int):  # type: ignore[no-untyped-def]
        self.failsafe = False
        self.set_mode(Px4Mode.AUTO_RTL)
        return ACCEPTED, None

    def _cmd_mission_start(self, p, frame, is_int):  # type: ignore[no-untyped-def]
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

    def _cmd_set_mission_current(self, p, frame, is_int):  # type: ignore[no-untyped-def]
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

    def _cmd_reposition(self, p, frame, is_int):  # type: ignore[no-untyped-def]
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

    def _cmd_change_speed(self, p, frame, is_int):  # type: ignore[no-untyped-def]
        if p[1] > 0:
            self.cruise_speed_m_s = float(p[1])
        elif p[1] == -1:
            self.cruise_speed_m_s = self.params["MPC_XY_CRUISE"]
        self._apply_limits()
        return ACCEPTED, None

    def _cmd_set_home(self, p, frame, is_int):  # type: ignore[no-untyped-def]
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

    def _cmd_request_message(self, p, frame, is_int):  # type: ignore[no-untyped-def]
        msg_id = int(p[0])
        build = self._builders.get(msg_id)
        if build is None:
            return DENIED, None

        def send_it() -> None:
            msg = build()
            if msg is not None:
                self.send(msg)

        return ACCEPTED, send_it

    def _cmd_request_capabilities(self, p, frame, is_int):  # type: ignore[no-untyped-def]
        return ACCEPTED, lambda: self.send(self._msg_autopilot_version())

    def _cmd_set_message_interval(self, p, frame, is_int):  # type: ignore[no-untyped-def]
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
        self._streams[msg_id] = _Stream(msg_id, interval_s, self._now(), build)
        return ACCEPTED, None

    def _cmd_get_message_interval(self, p, frame, is_int):  # type: ignore[no-untyped-def]
        msg_id = int(p[0])
        stream = self._streams.get(msg_id)
        interval_us = -1 if stream is None else round(stream.interval_s * 1e6)
        if msg_id not in self._builders:
            interval_us = 0
        return ACCEPTED, lambda: self.send(
            mavlink2.MAVLink_message_interval_message(msg_id, interval_us)
        )

    _COMMANDS: ClassVar[dict[int, Callable[..., tuple[int, Callable[[], None] | None]]]] = {
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

    # ================================================================ offboard
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
        self._sp = _Setpoint(
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

    # ================================================================ tick
    def _takeoff_gate(self, now: float, est_d: float) -> None:
        """PX4's take-off state machine: spin up only when a climb is wanted, then ramp.

        On the ground an armed PX4 idles until its setpoint asks for a climb (a position
        more than 0.2 m above the estimate, or an upward velocity); the climb speed then
        ramps up over MPC_TKO_RAMP_T (``TakeoffHandling`` in mc_pos_control).
        """
        i, phys = self.index, self.phys
        if self.landed:
            want = bool(
                (phys.m_pos[i, 2] and phys.sp_pos_ned_m[i, 2] < est_d - 0.2)
                or (phys.m_vel[i, 2] and phys.sp_vel_ned_m_s[i, 2] < -0.3)
                or (
                    phys.m_acc[i, 2]
                    and not phys.m_pos[i, 2]
                    and not phys.m_vel[i, 2]
                    and phys.sp_acc_ned_m_s2[i, 2] < -0.3
                )
            )
            if want and phys.idle[i]:
                self._takeoff_wanted_s = now
            phys.idle[i] = not want
        ramp_s = self.params["MPC_TKO_RAMP_T"]
        since = now - self._takeoff_wanted_s
        if ramp_s > 0 and since < ramp_s:
            phys.vel_up_max_m_s[i] = self._vel_up_base * max(0.05, since / ramp_s)
        elif since < ramp_s + 0.1:
            phys.vel_up_max_m_s[i] = self._vel_up_base

    def tick(self, now: float) -> None:
        """Mode logic, protocol timers and telemetry for simulation time ``now``."""
        i = self.index
        phys = self.phys
        d = phys.pos_ned_m[i, 2]
        true_d = phys.true_pos_ned_m[i, 2]
        true_vd = phys.true_vel_ned_m_s[i, 2]
        px4_nav = self.px4_nav
        if self.landed:
            if true_d < -0.3:
                self.landed = False
                self.has_flown = True
        elif (
            true_d > -0.05
            and abs(true_vd) < 0.3
            and (not px4_nav or float(self.home_ned_m[2]) - d < _CLOSE_TO_GROUND_M)
        ):
            # PX4's land detector also needs the *estimate* close to the ground: with the
            # ground-effect creep a vehicle sitting on the ground can stay "in air"; and it
            # says landed only after ground contact, maybe-landed and landed have each held
            # for LNDMC_TRIG_TIME / 3 (MulticopterLandDetector, without a range sensor; SITL
            # reported a mission land 1.9 s after touching down)
            if self._ground_since_s is None:
                self._ground_since_s = now
            if not px4_nav or now - self._ground_since_s >= self.params["LNDMC_TRIG_TIME"]:
                self.landed = True
                self._landed_since_s = now
                self._ground_since_s = None
        else:
            self._ground_since_s = None
        if px4_nav and self.armed:
            self._takeoff_gate(now, d)
        mode = self.mode
        if self.armed:
            if mode is Px4Mode.OFFBOARD:
                if now - self._sp_last_s > self.params["COM_OF_LOSS_T"]:
                    self._offboard_lost()
            elif mode is Px4Mode.AUTO_MISSION:
                if self._mis_phase == "rtl":
                    self._rtl_tick()
                    if self._rtl_phase == "land" and self.landed:
                        self._item_reached(self.mission_seq)
                        self._mission_finish()
                else:
                    self._mission_tick()
            elif mode is Px4Mode.AUTO_TAKEOFF:
                reached_m = (
                    self.params["NAV_MC_ALT_RAD"]
                    if px4_nav
                    else 0.1 * self.params["MIS_TAKEOFF_ALT"] + 0.05
                )
                if abs(d - self._takeoff_d_m) < reached_m:
                    # PX4 holds at the takeoff altitude once it is (nearly) reached, on
                    # the take-off's heading
                    yaw = phys.sp_yaw_rad[i]
                    self.set_mode(Px4Mode.AUTO_LOITER)
                    phys.sp_pos_ned_m[i, 2] = self._takeoff_d_m
                    phys.sp_yaw_rad[i] = yaw
            elif mode is Px4Mode.AUTO_RTL:
                self._rtl_tick()
            elif mode is Px4Mode.AUTO_LAND and not self.landed:
                phys.sp_vel_ned_m_s[i, 2] = self._land_speed_m_s()
            if self.landed:
                t_land = self.params["COM_DISARM_LAND"]
                t_pre = self.params["COM_DISARM_PRFLT"]
                if self.has_flown:
                    if t_land > 0 and now - self._landed_since_s >= t_land:
                        self.has_flown = False
                        self._do_disarm("Disarmed by auto preflight disarming")
                elif t_pre > 0 and now - self._armed_at_s >= t_pre:
                    self._do_disarm("Disarmed by auto preflight disarming")
            if self._fence:
                self._fence_tick()
        elif mode is Px4Mode.OFFBOARD and now - self._sp_last_s > self.params["COM_OF_LOSS_T"]:
            # PX4 leaves offboard on the ground too when the stream stops
            self.set_mode(Px4Mode.AUTO_LOITER)
        if px4_nav:
            self._reached_tick(now)
        if self._deferred:
            due = [a for a in self._deferred if a[0] <= now]
            self._deferred = [a for a in self._deferred if a[0] > now]
            for _, action in due:
                action()
        if self.missions.busy:
            self.missions.tick()
        for stream in list(self._streams.values()):
            if now + 1e-9 >= stream.next_s:
                stream.next_s += stream.interval_s
                if stream.next_s < now:
                    stream.next_s = now + stream.interval_s
                msg = stream.build()
                if msg is not None:
                    self.send(msg)


def _radio_status_only(_mav: mavlink2.MAVLink, msg_id: int) -> bool:
    return msg_id == mavlink2.MAVLINK_MSG_ID_RADIO_STATUS


def _param_name(raw: str | bytes) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return raw.split("\x00", 1)[0]
