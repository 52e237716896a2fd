"""One mock PX4 quad-rotor: the MAVLink endpoint and the flight logic of PX4's commander/navigator.

A :class:`MockVehicle` owns row ``index`` of the fleet's vectorised
:class:`~mavlink.mock.sim.physics.FleetPhysics`; every physics tick the fleet
calls :meth:`MockVehicle.tick`, which runs the mode logic (takeoff, hold,
land, return, mission, offboard failsafe, geofence, auto-disarm), the mission
protocol timers and the telemetry streams due at that time.  Incoming
datagrams are parsed with pymavlink's MAVLink 2 codec and dispatched by
message type; every ``COMMAND_LONG``/``COMMAND_INT`` addressed to the autopilot is
answered with a ``COMMAND_ACK`` (and one addressed to the camera or the gimbal device by
that component).  This module keeps the vehicle's state, its
construction, the message dispatch and the tick; the rest is mixed in from rooms of
their own: the commands, arming and modes in :mod:`mavlink.mock.commands`, offboard
setpoints in :mod:`mavlink.mock.offboard`, the parameter protocol in
:mod:`mavlink.mock.parameters`, the local frame and EKF origin in
:mod:`mavlink.mock.origin`, the navigator (mission execution, return to launch,
geofence) in :mod:`mavlink.mock.navigator`, the telemetry messages in
:mod:`mavlink.mock.telemetry` and the payload (the camera, component 100, on a gimbal,
device 154, whose manager is the autopilot) in :mod:`mavlink.mock.payload`.

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

from mavlink.link.signing import signing_timestamp
from mavlink.mock.commands import CommandsMixin
from mavlink.mock.mission import MISSION, MissionItem, MissionServer
from mavlink.mock.navigator import NavigatorMixin
from mavlink.mock.offboard import OffboardMixin, Setpoint
from mavlink.mock.origin import OriginMixin
from mavlink.mock.parameters import ParametersMixin
from mavlink.mock.payload import PayloadMixin
from mavlink.mock.sim import px4
from mavlink.mock.sim.config import FaultConfig, MockVehicleConfig, Outage
from mavlink.mock.sim.errors import MockConfigError, MockError
from mavlink.mock.sim.estimator import EstimatorParams
from mavlink.mock.sim.navigation import AutoTrajectory, Geofence
from mavlink.mock.sim.params import vehicle_params
from mavlink.mock.sim.physics import FleetPhysics
from mavlink.mock.sim.px4 import Px4Mode
from mavlink.mock.telemetry import DEFAULT_RATES_HZ, Stream, TelemetryMixin
from mavlink.mock.vehicle_faults import PlanFaults


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
    utc_start_s: float

    def geodetic(self, i: int) -> tuple[float, float, float]: ...

    def configure_links(self, vehicle: MockVehicle, faults: FaultConfig) -> None: ...

    def origins_changed(self) -> None: ...

    def offline_links(self) -> None: ...


class Link(Protocol):
    """One direction of a vehicle's link: datagrams pushed in are delivered (or not)."""

    def push(self, data: bytes) -> None: ...


#: A pymavlink message (its fields are per message type: untyped to mypy).
Msg: TypeAlias = Any


_CLOSE_TO_GROUND_M = 1.0  # the land detector's "close to ground" height (estimate)


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


class MockVehicle(
    CommandsMixin,
    OffboardMixin,
    ParametersMixin,
    OriginMixin,
    TelemetryMixin,
    NavigatorMixin,
    PayloadMixin,
):
    """Vehicle ``index`` of a :class:`~mavlink.mock.fleet.MockFleet` (system id ``index + 1``)."""

    _COMMANDS: ClassVar[dict[int, Callable[..., Any]]] = {
        **CommandsMixin._COMMANDS,
        **PayloadMixin._PAYLOAD_COMMANDS,
    }

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
        try:
            self.params: dict[str, float] = vehicle_params(config.profile, dict(config.params))
        except MockConfigError as exc:
            raise MockConfigError(f"vehicle {index}: {exc}") from None
        self._param_specs = {p.name: p for p in px4.PARAM_SPECS}
        self._param_names = [p.name for p in px4.PARAM_SPECS]
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
        self._sp: Setpoint | None = None
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
        self.traj = AutoTrajectory()
        # (due time, action) run by tick: PX4's late second COMMAND_ACK
        self._deferred: list[tuple[float, Callable[[], None]]] = []
        #: faults injected on the plan's clock (:mod:`mavlink.mock.vehicle_faults`)
        self.plan_faults = PlanFaults()
        #: the battery's charge (%) a fault set (None: it drains with the flight time)
        self.battery_override_pct: float | None = None
        self._cmd_partner: tuple[int, int, int] = (0, 0, 0)
        # geofence in local NE (m): list of (kind, inclusion, data)
        self._fence = Geofence()
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
        self._streams: dict[int, Stream] = {}
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
            self._streams[msg_id] = Stream(msg_id, 1.0 / rate_hz, 0.0, self._builders[msg_id])
        self._payload_init()
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
            "GIMBAL_MANAGER_SET_ATTITUDE": self._on_gimbal_manager_set_attitude,
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
        """Encode ``msg`` as MAVLink 2 from (sysid, 1) and send it to the GCS.

        The payload's heartbeats ride in the datagram of the autopilot's HEARTBEAT, after
        it (PX4 packs what it forwards into its own UDP datagrams): a client that takes
        the next HEARTBEAT from the link gets the autopilot's.
        """
        mav = self._mav
        buf = msg.pack(mav)
        mav.seq = (mav.seq + 1) & 0xFF
        if self.camera is not None and msg.get_msgId() == mavlink2.MAVLINK_MSG_ID_HEARTBEAT:
            buf += self._payload_heartbeats()
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

    def _for_me(self, msg: Msg) -> bool:
        return msg.target_system in (0, self.sysid)

    def _on_timesync(self, msg: Msg) -> None:
        if msg.tc1 == 0:
            self.send(mavlink2.MAVLink_timesync_message(self._usec() * 1000, msg.ts1))

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
        # the gimbal manager and the navigator start afresh; the camera and the gimbal
        # device are devices of their own and keep their state
        self._roi_ned_m = None
        self._nav_capturing = False
        self._neutral_due_s = math.inf
        if self.gimbal is not None:
            self.gimbal.primary = (0, 0)

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
            pos_ned_m=_vec3(true_local),
            vel_ned_m_s=_vec3(p.true_vel_ned_m_s[i]),
            yaw_rad=float(p.yaw_rad[i]),
            mode=self.mode,
            armed=self.armed,
            landed=self.landed,
            failsafe=self.failsafe,
            mission_seq=self.mission_seq,
            home_ned_m=_vec3(self.home_ned_m),
            est_pos_ned_m=_vec3(p.pos_ned_m[i]),
            est_vel_ned_m_s=_vec3(p.vel_ned_m_s[i]),
        )

    @property
    def offboard_setpoint(self) -> Setpoint | None:
        """The latest offboard setpoint received (``None``: none since the last boot)."""
        return self._sp

    @property
    def last_setpoint_s(self) -> float:
        """When the latest offboard setpoint came, simulated s (-inf: none since the boot)."""
        return self._sp_last_s

    @property
    def mission_phase(self) -> str:
        """What the navigator does with the current mission item: ``"pre_takeoff"``,
        ``"takeoff"``, ``"goto"``, ``"hold"``, ``"delay"``, ``"loiter"``, ``"land_approach"``,
        ``"land"``, ``"done"`` (``""`` before a mission)."""
        return self._mis_phase

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
        ground_d = float(phys.ground_d_m[i])  # the ground under it (spawn frame; 0: flat)
        true_d = phys.true_pos_ned_m[i, 2] - ground_d  # below the ground under it
        true_vd = phys.true_vel_ned_m_s[i, 2]
        px4_nav = self.px4_nav
        if self.landed:
            if true_d < -0.3:
                self.landed = False
                self.has_flown = True
        elif (
            true_d > -0.05
            and abs(true_vd) < 0.3
            and (not px4_nav or float(self.home_ned_m[2]) + ground_d - d < _CLOSE_TO_GROUND_M)
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
        self.plan_faults.tick(self, now)
        self._payload_tick(now)
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


def _vec3(a: np.ndarray) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))
