"""A fleet of PX4 vehicles reached through one in-process MAVSDK instance.

:class:`Fleet` connects N vehicles by URL (vehicle ``i`` defaults to
``udpin://0.0.0.0:{14540+i}`` with system id ``i+1``), waits for each one's
heartbeat with a timeout and keeps a live :class:`VehicleStatus` per vehicle:
connected, armed, PX4 mode (decoded from ``HEARTBEAT.custom_mode`` with
:mod:`mavlink.px4_modes`), local NED and global position, home, EKF/GPS
global origin, battery.

MAVSDK 4 is the native (ctypes) binding: every plugin call exists in a
blocking form and an ``*_async(callback)`` form. This module bridges the
callback forms to asyncio futures (:func:`mavsdk_call`), so N vehicles can
wait on N commands without N threads, and telemetry callbacks update each
vehicle's state directly on MAVSDK's callback thread under a lock. (The
``mavsdk.asyncio`` wrappers instead run every call, setpoints included, in
the default thread pool; ``benchmarks/bench_stream.py`` measures both.)

Example::

    specs = default_specs(["d1", "d2"])
    async with Fleet(specs, connect_timeout_s=10.0) as fleet:
        for status in fleet.statuses():
            print(status.name, status.mode, status.pos_ned_m)
        await fleet.hold_all()
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from mavsdk import ComponentType, Configuration, LogLevel, Mavsdk, log_subscribe
from mavsdk.exceptions import MavsdkError
from mavsdk.plugins.action import Action, ActionResult
from mavsdk.plugins.mavlink_direct import MavlinkDirect, MavlinkDirectResult, MavlinkMessage
from mavsdk.plugins.mission_raw import MissionRaw
from mavsdk.plugins.offboard import Offboard
from mavsdk.plugins.telemetry import Telemetry, TelemetryResult

from mavlink.errors import (
    CommandError,
    ConnectTimeoutError,
    DuplicateSystemError,
    LinkError,
    LinkLostError,
)
from mavlink.px4_modes import (
    MAV_CMD_DO_SET_MODE,
    Px4Mode,
    UnknownModeError,
    decode_custom_mode,
    set_mode_params,
)
from mavlink.urls import Scheme, default_sysid, default_url, parse_url
from planner.frames import GeodeticPoint

log = logging.getLogger(__name__)

#: MAV_AUTOPILOT of PX4 in its HEARTBEAT.
MAV_AUTOPILOT_PX4 = 12
_AUTOPILOTS = {0: "generic", 3: "ArduPilot", 8: "invalid (not an autopilot)", 12: "PX4"}


def _autopilot_name(value: int) -> str:
    name = _AUTOPILOTS.get(value)
    return f", {name}" if name else ""


MAV_CMD_NAV_TAKEOFF = 22
#: MAVSDK's system id as a ground station (component 190).
GCS_SYSID = 245

#: STATUSTEXTs kept per vehicle (the latest).
_KEPT_TEXTS = 50
#: MAV_PARAM_TYPE values of integer parameters (UINT8 .. INT64).
_INT_PARAM_TYPES = frozenset(range(1, 9))

#: MAVSDK results of a request that got no (usable) answer: worth sending again on a bad link.
_UNANSWERED = frozenset({"TIMEOUT", "BUSY", "NO_SYSTEM", "CONNECTION_ERROR", "UNKNOWN"})

#: MAV_RESULT names, for COMMAND_ACK results reported through mavlink_direct.
MAV_RESULT_NAMES = {
    0: "ACCEPTED",
    1: "TEMPORARILY_REJECTED",
    2: "DENIED",
    3: "UNSUPPORTED",
    4: "FAILED",
    5: "IN_PROGRESS",
    6: "CANCELLED",
}


# --------------------------------------------------------------------------
# MAVSDK glue
# --------------------------------------------------------------------------

_logs_routed = threading.Lock()
_routed = False


def route_mavsdk_logs() -> None:
    """Send MAVSDK's own log lines to the ``mavlink.mavsdk`` logger (not stderr)."""
    global _routed
    with _logs_routed:
        if _routed:
            return
        mlog = logging.getLogger("mavlink.mavsdk")
        levels = {
            LogLevel.DEBUG: logging.DEBUG,
            LogLevel.INFO: logging.INFO,
            LogLevel.WARN: logging.WARNING,
            LogLevel.ERROR: logging.ERROR,
        }

        def forward(level: LogLevel, message: str, file: str | None, line: int) -> bool:
            mlog.log(levels.get(level, logging.INFO), "%s (%s:%d)", message, file, line)
            return True

        log_subscribe(forward)
        _routed = True


def _resolve(fut: asyncio.Future[Any], value: Any) -> None:
    if not fut.done():
        fut.set_result(value)


async def mavsdk_call(start: Callable[..., None], *args: Any, timeout_s: float = 10.0) -> Any:
    """Await one MAVSDK ``*_async`` call.

    Args:
        start: a bound MAVSDK method taking ``(*args, callback)``; the
            callback gets ``(result, [data,] user_data)``.
        args: its arguments before the callback.
        timeout_s: give up after this long (MAVSDK's own timeouts normally
            answer first).

    Returns:
        The callback's arguments without ``user_data``: the result alone, or
        ``(result, data)``.

    Raises:
        TimeoutError: no callback within ``timeout_s``.
    """
    loop = asyncio.get_running_loop()
    fut: asyncio.Future[Any] = loop.create_future()

    def callback(*values: Any) -> None:
        out = values[:-1]
        loop.call_soon_threadsafe(_resolve, fut, out[0] if len(out) == 1 else out)

    start(*args, callback)
    return await asyncio.wait_for(fut, timeout_s)


# --------------------------------------------------------------------------
# Values
# --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class VehicleSpec:
    """How to reach one vehicle.

    Attributes:
        name: the plan's vehicle name (``"d1"``).
        url: connection URL (validated by :func:`mavlink.urls.parse_url`).
        sysid: the MAVLink system id the vehicle uses (1..255).
    """

    name: str
    url: str
    sysid: int


def default_specs(
    names: Sequence[str], urls: Sequence[str | None] | None = None
) -> tuple[VehicleSpec, ...]:
    """Specs by the PX4 SITL convention: vehicle ``i`` is system ``i+1`` at ``udpin://0.0.0.0:{14540+i}``.

    Args:
        names: vehicle names in plan order.
        urls: optional URL per vehicle (``None`` entries take the default).
    """
    if urls is not None and len(urls) != len(names):
        raise LinkError(f"{len(urls)} connection URLs given for {len(names)} vehicles")
    out = []
    for i, name in enumerate(names):
        url = urls[i] if urls is not None and urls[i] is not None else default_url(i)
        out.append(VehicleSpec(name=name, url=str(url), sysid=default_sysid(i)))
    return tuple(out)


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
        heading_deg: heading, degrees clockwise from north (GLOBAL_POSITION_INT.hdg).
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


# --------------------------------------------------------------------------
# One vehicle
# --------------------------------------------------------------------------


class Vehicle:
    """One connected vehicle: its MAVSDK plugins and live state.

    Telemetry callbacks run on MAVSDK's thread and update the state under a
    lock; :meth:`status` takes a consistent snapshot. Commands are
    coroutines that raise :class:`CommandError` naming the vehicle, its URL
    and the MAVSDK result.
    """

    def __init__(self, spec: VehicleSpec, system: Any, *, link_timeout_s: float) -> None:
        self.spec = spec
        self.name = spec.name
        self.url = spec.url
        self.link_timeout_s = link_timeout_s
        self.system = system
        self.action = Action(system)
        self.telemetry = Telemetry(system)
        self.offboard = Offboard(system)
        self.mission_raw = MissionRaw(system)
        self.direct = MavlinkDirect(system)
        self._lock = threading.Lock()
        self._armed: bool | None = None
        self._in_air: bool | None = None
        self._custom_mode: int | None = None
        self._mode: Px4Mode | None = None
        self._pos_ned: tuple[float, float, float] | None = None
        self._vel_ned: tuple[float, float, float] | None = None
        self._position: GeodeticPoint | None = None
        self._rel_alt: float | None = None
        self._home: GeodeticPoint | None = None
        self._origin: GeodeticPoint | None = None
        self._battery: tuple[float, float] | None = None
        self._heading: float | None = None
        self._t_heartbeat: float | None = None
        self._t_position: float | None = None
        self._track: list[tuple[float, ...]] | None = None
        self._texts: list[tuple[float, int, str]] = []
        self._pos_accuracy: tuple[float, float] | None = None
        self._track_accuracy: tuple[float, float] | None = None
        self._params: dict[str, float] = {}
        self._param_waiters: dict[str, list[asyncio.Future[float]]] = {}
        self._handles: list[tuple[Callable[[Any], None], Any]] = []
        self._subscribe()

    # -- telemetry ------------------------------------------------------

    def _subscribe(self) -> None:
        tel = self.telemetry
        self._handles += [
            (
                tel.unsubscribe_position_velocity_ned,
                tel.subscribe_position_velocity_ned(self._on_pv),
            ),
            (tel.unsubscribe_position, tel.subscribe_position(self._on_position)),
            (tel.unsubscribe_home, tel.subscribe_home(self._on_home)),
            (tel.unsubscribe_battery, tel.subscribe_battery(self._on_battery)),
            (tel.unsubscribe_in_air, tel.subscribe_in_air(self._on_in_air)),
            (tel.unsubscribe_heading, tel.subscribe_heading(self._on_heading)),
            (
                self.direct.unsubscribe_message,
                self.direct.subscribe_message("HEARTBEAT", self._on_heartbeat),
            ),
            (
                self.direct.unsubscribe_message,
                self.direct.subscribe_message("GPS_GLOBAL_ORIGIN", self._on_origin),
            ),
            (
                self.direct.unsubscribe_message,
                self.direct.subscribe_message("STATUSTEXT", self._on_statustext),
            ),
            (
                self.direct.unsubscribe_message,
                self.direct.subscribe_message("ESTIMATOR_STATUS", self._on_estimator_status),
            ),
            (
                self.direct.unsubscribe_message,
                self.direct.subscribe_message("PARAM_VALUE", self._on_param_value),
            ),
        ]

    def _on_pv(self, pv: Any, _ud: Any) -> None:
        t = time.monotonic()
        p, v = pv.position, pv.velocity
        pos = (float(p.north_m), float(p.east_m), float(p.down_m))
        vel = (float(v.north_m_s), float(v.east_m_s), float(v.down_m_s))
        with self._lock:
            self._pos_ned, self._vel_ned, self._t_position = pos, vel, t
            if self._track is not None:
                self._track.append((t, *pos, *vel))

    def _on_position(self, p: Any, _ud: Any) -> None:
        point = GeodeticPoint(
            float(p.latitude_deg), float(p.longitude_deg), float(p.absolute_altitude_m)
        )
        with self._lock:
            self._position, self._rel_alt = point, float(p.relative_altitude_m)

    def _on_home(self, h: Any, _ud: Any) -> None:
        point = GeodeticPoint(
            float(h.latitude_deg), float(h.longitude_deg), float(h.absolute_altitude_m)
        )
        with self._lock:
            self._home = point

    def _on_battery(self, b: Any, _ud: Any) -> None:
        remaining = float(b.remaining_percent)
        # MAVSDK reports percent (0..100) from SYS_STATUS / BATTERY_STATUS.
        with self._lock:
            self._battery = (remaining / 100.0, float(b.voltage_v))

    def _on_heading(self, h: Any, _ud: Any) -> None:
        with self._lock:
            self._heading = float(h.heading_deg)

    def _on_in_air(self, in_air: bool, _ud: Any) -> None:
        with self._lock:
            self._in_air = bool(in_air)

    def _on_heartbeat(self, msg: MavlinkMessage, _ud: Any) -> None:
        if msg.component_id != 1:  # only the autopilot's heartbeat
            return
        fields = json.loads(msg.fields_json)
        custom = int(fields["custom_mode"])
        try:
            mode: Px4Mode | None = decode_custom_mode(custom)
        except UnknownModeError as exc:
            mode = None  # kept raw in custom_mode; status shows mode=None
            log.debug("vehicle %s: %s", self.name, exc)
        armed = bool(int(fields["base_mode"]) & 128)
        with self._lock:
            self._custom_mode, self._mode, self._armed = custom, mode, armed
            self._t_heartbeat = time.monotonic()

    def _on_origin(self, msg: MavlinkMessage, _ud: Any) -> None:
        f = json.loads(msg.fields_json)
        point = GeodeticPoint(f["latitude"] * 1e-7, f["longitude"] * 1e-7, f["altitude"] * 1e-3)
        with self._lock:
            self._origin = point

    def _on_statustext(self, msg: MavlinkMessage, _ud: Any) -> None:
        if msg.system_id != self.spec.sysid:
            return
        f = json.loads(msg.fields_json)
        text = f.get("text", "")
        if isinstance(text, list):  # a char array may come as its codes
            text = "".join(chr(c) for c in text if c)
        with self._lock:
            self._texts.append((time.monotonic(), int(f.get("severity", 6)), str(text)))
            del self._texts[:-_KEPT_TEXTS]

    def _on_estimator_status(self, msg: MavlinkMessage, _ud: Any) -> None:
        f = json.loads(msg.fields_json)
        acc = (
            float(f.get("pos_horiz_accuracy", math.nan)),
            float(f.get("pos_vert_accuracy", math.nan)),
        )
        with self._lock:
            self._pos_accuracy = acc

    def _on_param_value(self, msg: MavlinkMessage, _ud: Any) -> None:
        f = json.loads(msg.fields_json)
        name = f.get("param_id", "")
        if isinstance(name, list):
            name = "".join(chr(c) for c in name if c)
        name = str(name).rstrip("\x00")
        value = float(f.get("param_value", math.nan))
        if int(f.get("param_type", 9)) in _INT_PARAM_TYPES:
            # PX4 sends integer parameters bit-cast into the float field (MAV_PARAM_TYPE).
            value = float(np.frombuffer(np.float32(value).tobytes(), dtype=np.int32)[0])
        with self._lock:
            self._params[name] = value
            waiters = self._param_waiters.pop(name, [])
        for fut in waiters:
            fut.get_loop().call_soon_threadsafe(_resolve, fut, value)

    def statustexts(self, since_monotonic_s: float = 0.0) -> list[tuple[int, str]]:
        """STATUSTEXTs heard since ``since_monotonic_s`` (severity, text), oldest first."""
        with self._lock:
            return [(sev, text) for t, sev, text in self._texts if t >= since_monotonic_s]

    @property
    def position_accuracy_m(self) -> tuple[float, float] | None:
        """The estimator's reported (horizontal, vertical) position accuracy, 1-sigma metres
        (ESTIMATOR_STATUS), ``None`` before one arrived."""
        with self._lock:
            return self._pos_accuracy

    def _send_param_message(self, message: str, name: str, **fields: float | int) -> None:
        """Send PARAM_REQUEST_READ / PARAM_SET for parameter ``name`` to the autopilot."""
        body = {"target_system": self.spec.sysid, "target_component": 1, "param_id": name}
        self.direct.send_message(
            MavlinkMessage(
                message_name=message,
                target_system_id=self.spec.sysid,
                target_component_id=1,
                fields_json=json.dumps({**body, **fields}),
            )
        )

    async def param(self, name: str, *, timeout_s: float = 1.0, retries: int = 3) -> float | None:
        """The vehicle's parameter ``name`` (PARAM_REQUEST_READ; integers as their value).

        Sent through mavlink_direct, so it never blocks the event loop (MAVSDK's param
        plugin does); ``None`` if the vehicle did not answer (unknown name, lossy link).
        """
        with self._lock:
            if name in self._params:
                return self._params[name]
        loop = asyncio.get_running_loop()
        for _ in range(retries):
            fut: asyncio.Future[float] = loop.create_future()
            with self._lock:
                self._param_waiters.setdefault(name, []).append(fut)
            self._send_param_message("PARAM_REQUEST_READ", name, param_index=-1)
            try:
                return await asyncio.wait_for(fut, timeout_s)
            except TimeoutError:
                continue
        return None

    async def set_param_int(self, name: str, value: int, *, timeout_s: float = 1.0) -> None:
        """Set an INT32 parameter (PARAM_SET, the integer bit-cast into the float field as
        PX4 expects) and require the vehicle's PARAM_VALUE echo to carry it.

        Raises:
            CommandError: no echo, or the vehicle kept another value.
        """
        raw = float(np.frombuffer(np.int32(value).tobytes(), dtype=np.float32)[0])
        loop = asyncio.get_running_loop()
        for _ in range(3):
            fut: asyncio.Future[float] = loop.create_future()
            with self._lock:
                self._params.pop(name, None)
                self._param_waiters.setdefault(name, []).append(fut)
            self._send_param_message("PARAM_SET", name, param_value=raw, param_type=6)  # INT32
            try:
                got = await asyncio.wait_for(fut, timeout_s)
            except TimeoutError:
                continue
            if int(got) != int(value):
                raise self._fail(f"set {name} = {value}", f"the vehicle kept {int(got)}")
            return
        raise self._fail(f"set {name} = {value}", "TIMEOUT")

    def status(self, now: float | None = None) -> VehicleStatus:
        """A consistent snapshot of the vehicle's state."""
        now = time.monotonic() if now is None else now
        with self._lock:
            hb_age = None if self._t_heartbeat is None else now - self._t_heartbeat
            pos_age = None if self._t_position is None else now - self._t_position
            return VehicleStatus(
                name=self.name,
                sysid=self.spec.sysid,
                url=self.url,
                connected=hb_age is not None and hb_age <= self.link_timeout_s,
                armed=self._armed,
                in_air=self._in_air,
                mode=self._mode,
                custom_mode=self._custom_mode,
                pos_ned_m=self._pos_ned,
                vel_ned_m_s=self._vel_ned,
                position=self._position,
                relative_alt_m=self._rel_alt,
                home=self._home,
                origin=self._origin,
                battery_remaining=None if self._battery is None else self._battery[0],
                battery_voltage_v=None if self._battery is None else self._battery[1],
                heartbeat_age_s=hb_age,
                position_age_s=pos_age,
                heading_deg=self._heading,
            )

    # -- recording of the flown track ----------------------------------

    def start_track(self) -> None:
        """Start recording every LOCAL_POSITION_NED sample (receive time, pos, vel), and the
        worst estimator accuracy reported meanwhile (:attr:`track_accuracy_m`)."""
        with self._lock:
            self._track = []
            self._track_accuracy = self._pos_accuracy

    @property
    def track_accuracy_m(self) -> tuple[float, float] | None:
        """The worst (horizontal, vertical) position accuracy ESTIMATOR_STATUS reported while
        the track was recorded (1-sigma, m); ``None`` if none was reported."""
        with self._lock:
            return self._track_accuracy

    def stop_track(self) -> np.ndarray:
        """Stop recording; ``(k, 7)`` rows ``(t_monotonic_s, n, e, d, vn, ve, vd)``."""
        with self._lock:
            rows, self._track = self._track, None
        if not rows:
            return np.zeros((0, 7))
        return np.asarray(rows, dtype=float)

    # -- commands -------------------------------------------------------

    def _fail(self, what: str, result: Any) -> CommandError:
        name = getattr(result, "name", str(result))
        return CommandError(f"{what} failed: {name}", result=name, vehicle=self.name, url=self.url)

    async def _action(self, what: str, start: Callable[..., None], *args: Any) -> None:
        try:
            result = await mavsdk_call(start, *args)
        except TimeoutError:
            raise self._fail(what, "TIMEOUT") from None
        if result != ActionResult.SUCCESS:
            raise self._fail(what, result)

    async def arm(self) -> None:
        """Arm (MAV_CMD_COMPONENT_ARM_DISARM)."""
        await self._action("arm", self.action.arm_async)

    async def disarm(self) -> None:
        """Disarm."""
        await self._action("disarm", self.action.disarm_async)

    async def hold(self) -> None:
        """Switch to Hold (AUTO.LOITER) where the vehicle is."""
        await self._action("hold", self.action.hold_async)

    async def land(self) -> None:
        """Land where the vehicle is (AUTO.LAND)."""
        await self._action("land", self.action.land_async)

    async def return_to_launch(self) -> None:
        """Return to launch (AUTO.RTL)."""
        await self._action("return to launch", self.action.return_to_launch_async)

    async def command_long(self, what: str, command: int, *params: float) -> None:
        """Send COMMAND_LONG ``command`` (params 1..7, missing ones 0) and require ACCEPTED.

        Goes through MAVSDK's mavlink_direct ``send_command`` (retransmission
        until the final COMMAND_ACK), for commands MAVSDK has no action for.

        Raises:
            CommandError: no final ack, or a result other than ACCEPTED.
        """
        if len(params) > 7:
            raise ValueError("COMMAND_LONG has 7 params")
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        fields: dict[str, float | int] = {
            "target_system": self.spec.sysid,
            "target_component": 1,
            "command": int(command),
            "confirmation": 0,
        }
        fields.update({f"param{i + 1}": (None if math.isnan(x) else x) for i, x in enumerate(p)})  # type: ignore[misc]
        msg = MavlinkMessage(
            message_name="COMMAND_LONG",
            target_system_id=self.spec.sysid,
            target_component_id=1,
            fields_json=json.dumps(fields),
        )
        try:
            result, ack = await mavsdk_call(self.direct.send_command_async, msg)
        except TimeoutError:
            raise self._fail(what, "TIMEOUT") from None
        if result != MavlinkDirectResult.SUCCESS:
            raise self._fail(what, result)
        code = int(json.loads(ack.fields_json)["result"])
        if code != 0:
            raise self._fail(what, MAV_RESULT_NAMES.get(code, f"MAV_RESULT {code}"))

    async def set_mode(self, mode: Px4Mode) -> None:
        """Switch to any PX4 mode with MAV_CMD_DO_SET_MODE (params from :mod:`px4_modes`)."""
        await self.command_long(
            f"set mode {mode.label}", MAV_CMD_DO_SET_MODE, *set_mode_params(mode)
        )

    async def takeoff_to(self, alt_amsl_m: float, yaw_deg: float = math.nan) -> None:
        """Take off (AUTO.TAKEOFF) straight up to ``alt_amsl_m`` (metres AMSL), turning to
        ``yaw_deg`` (NED heading, degrees; NaN keeps the heading) on the way.

        MAV_CMD_NAV_TAKEOFF with param7 the altitude, param4 the yaw and NaN lat/lon (here),
        as PX4 accepts it. MAVSDK's ``Action.takeoff`` would first need
        ``set_takeoff_altitude`` (the MIS_TAKEOFF_ALT parameter), whose
        ``*_async`` form in MAVSDK 4.1.0 blocks the calling thread for the
        whole parameter transaction (measured: 3 s, its timeout, when the
        vehicle answers on the same event loop) - unusable from asyncio.
        """
        nan = float("nan")
        await self.command_long(
            "takeoff",
            MAV_CMD_NAV_TAKEOFF,
            0.0,
            0.0,
            0.0,
            float(yaw_deg),
            nan,
            nan,
            float(alt_amsl_m),
        )

    async def goto(self, lat_deg: float, lon_deg: float, alt_amsl_m: float, yaw_deg: float) -> None:
        """Fly to a point and hold there (MAV_CMD_DO_REPOSITION as COMMAND_INT, via MAVSDK's
        ``goto_location``: lat/lon at 1e-7 degrees, not float32)."""
        await self._action(
            "go to", self.action.goto_location_async, lat_deg, lon_deg, alt_amsl_m, yaw_deg
        )

    async def set_current_item(self, seq: int) -> None:
        """Make mission item ``seq`` the current one (where AUTO.MISSION starts)."""
        from mavsdk.plugins.mission_raw import MissionRawResult

        try:
            result = await mavsdk_call(self.mission_raw.set_current_mission_item_async, int(seq))
        except TimeoutError:
            result = "TIMEOUT"
        if result != MissionRawResult.SUCCESS:
            raise self._fail(f"set current mission item {seq}", result)

    async def request_origin(self, timeout_s: float = 5.0) -> GeodeticPoint:
        """The EKF origin of the vehicle's local frame (GPS_GLOBAL_ORIGIN).

        Uses the last streamed GPS_GLOBAL_ORIGIN if one arrived, else asks
        for it (MAVSDK sends MAV_CMD_REQUEST_MESSAGE).

        Raises:
            LinkError: the vehicle did not report an origin.
        """
        with self._lock:
            if self._origin is not None:
                return self._origin
        try:
            result, origin = await mavsdk_call(
                self.telemetry.get_gps_global_origin_async, timeout_s=timeout_s
            )
        except TimeoutError:
            result, origin = "TIMEOUT", None
        if result != TelemetryResult.SUCCESS:
            name = getattr(result, "name", str(result))
            raise LinkError(
                f"no GPS_GLOBAL_ORIGIN (EKF origin) from the vehicle: {name}",
                vehicle=self.name,
                url=self.url,
            )
        point = GeodeticPoint(
            float(origin.latitude_deg), float(origin.longitude_deg), float(origin.altitude_m)
        )
        with self._lock:
            self._origin = point
        return point

    async def wait_for(
        self,
        predicate: Callable[[VehicleStatus], bool],
        what: str,
        *,
        timeout_s: float,
        poll_s: float = 0.05,
    ) -> VehicleStatus:
        """Wait until ``predicate(status())`` holds.

        Raises:
            LinkLostError: the link timed out meanwhile.
            LinkError: ``what`` did not happen within ``timeout_s``.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            st = self.status()
            if predicate(st):
                return st
            if st.heartbeat_age_s is not None and not st.connected:
                raise LinkLostError(
                    f"link lost (no heartbeat for {st.heartbeat_age_s:.1f} s) while waiting for {what}",
                    vehicle=self.name,
                    url=self.url,
                )
            if time.monotonic() >= deadline:
                raise LinkError(
                    f"timed out after {timeout_s:.1f} s waiting for {what} "
                    f"(mode {st.mode.label if st.mode else st.custom_mode}, "
                    f"armed {st.armed}, position NED {_fmt(st.pos_ned_m)})",
                    vehicle=self.name,
                    url=self.url,
                )
            await asyncio.sleep(poll_s)

    async def set_telemetry_rate(self, rate_hz: float, *, retry_for_s: float = 0.0) -> None:
        """Ask for LOCAL_POSITION_NED and GLOBAL_POSITION_INT at ``rate_hz``.

        A request left unanswered (MAVSDK's own command retries all lost on a bad link) is
        sent again for up to ``retry_for_s`` seconds; setting a rate twice is harmless. A
        refusal (DENIED, UNSUPPORTED) is not retried.

        Raises:
            CommandError: refused, or still unanswered after ``retry_for_s`` (names the
                attempts).
        """
        deadline = time.monotonic() + retry_for_s
        for what, start in (
            ("set rate of local position", self.telemetry.set_rate_position_velocity_ned_async),
            ("set rate of global position", self.telemetry.set_rate_position_async),
        ):
            attempts = 0
            while True:
                attempts += 1
                try:
                    result = await mavsdk_call(start, float(rate_hz))
                except TimeoutError:
                    result = "TIMEOUT"
                if result == TelemetryResult.SUCCESS:
                    break
                name = getattr(result, "name", str(result))
                if name not in _UNANSWERED or time.monotonic() >= deadline:
                    tries = f" ({attempts} attempts in {retry_for_s:.1f} s)" if attempts > 1 else ""
                    raise self._fail(what + tries, result)

    def close(self) -> None:
        """Drop the telemetry subscriptions (the plugins die with the Mavsdk instance)."""
        handles, self._handles = self._handles, []
        for unsubscribe, handle in handles:
            unsubscribe(handle)


def _fmt(p: tuple[float, float, float] | None) -> str:
    return "unknown" if p is None else "(" + ", ".join(f"{x:.2f}" for x in p) + ")"


# --------------------------------------------------------------------------
# The fleet
# --------------------------------------------------------------------------


@dataclass(slots=True)
class FlightGuard:
    """What :meth:`Fleet.flight` did on the way out.

    Attributes:
        action: ``"hold"`` or ``"land"``, what an abnormal exit commands.
        stopped: the scope was left by an exception or a cancellation and the vehicles
            were commanded.
        failures: vehicles that did not accept the command, with the reason.
    """

    action: str
    stopped: bool = False
    failures: dict[str, str] = field(default_factory=dict)


class Fleet:
    """N vehicles behind one MAVSDK instance (the GCS is system 245, component 190).

    Args:
        specs: one :class:`VehicleSpec` per vehicle (see :func:`default_specs`).
        connect_timeout_s: how long :meth:`connect` waits for all heartbeats.
        link_timeout_s: a vehicle whose last heartbeat is older is not connected.
        telemetry_rate_hz: ask each vehicle for local/global position at this
            rate (``None``: leave the vehicle's rates alone).

    Raises (from :meth:`connect`):
        UrlError: a URL is malformed (before anything is opened).
        LinkError: a URL cannot be opened (port in use, no such device).
        ConnectTimeoutError: a vehicle did not appear; names it, its URL and sysid.
        DuplicateSystemError: two autopilots answer as one vehicle's system id (a scan of
            the ``udpin`` ports before MAVSDK opens them, up to ``scan_s``: it names both
            addresses; MAVSDK would merge them into one system).
        CommandError: a vehicle refused the telemetry rate, or never answered the request
            within ``connect_timeout_s``.
    """

    def __init__(
        self,
        specs: Sequence[VehicleSpec],
        *,
        connect_timeout_s: float = 10.0,
        link_timeout_s: float = 2.0,
        telemetry_rate_hz: float | None = 20.0,
        scan_s: float = 1.0,
    ) -> None:
        if not specs:
            raise LinkError("no vehicles to connect")
        names = [s.name for s in specs]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise LinkError(f"duplicate vehicle names: {', '.join(dup)}")
        sysids = [s.sysid for s in specs]
        for s in specs:
            if sysids.count(s.sysid) > 1:
                raise LinkError(
                    f"system id {s.sysid} used by more than one vehicle", vehicle=s.name, url=s.url
                )
            if not 1 <= s.sysid <= 255:
                raise LinkError(f"system id {s.sysid} outside 1..255", vehicle=s.name, url=s.url)
            if s.sysid == GCS_SYSID:
                raise LinkError(
                    f"system id {GCS_SYSID} is the ground station's own (MAVSDK)",
                    vehicle=s.name,
                    url=s.url,
                )
            parse_url(s.url, vehicle=s.name)
        self.specs = tuple(specs)
        self.connect_timeout_s = connect_timeout_s
        self.link_timeout_s = link_timeout_s
        self.telemetry_rate_hz = telemetry_rate_hz
        self.scan_s = scan_s
        self._mavsdk: Mavsdk | None = None
        self._vehicles: dict[str, Vehicle] = {}

    # -- lifecycle ------------------------------------------------------

    async def __aenter__(self) -> Fleet:
        await self.connect()
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()

    async def connect(self) -> None:
        """Open every URL and wait until each vehicle's system id has been seen.

        On a lossy link discovery waits for a heartbeat that gets through (PX4 sends one a
        second) and the telemetry-rate requests are repeated while unanswered, each within
        ``connect_timeout_s``.
        """
        route_mavsdk_logs()
        if self.scan_s > 0:
            await self._refuse_duplicates()
        config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        self._mavsdk = Mavsdk(config)
        try:
            for spec in self.specs:
                url = str(parse_url(spec.url, vehicle=spec.name))
                try:
                    self._mavsdk.add_any_connection_with_handle(url)
                except MavsdkError as exc:
                    raise LinkError(
                        f"cannot open connection: {exc}", vehicle=spec.name, url=spec.url
                    ) from exc
            systems = await self._wait_for_systems()
            for spec in self.specs:
                self._vehicles[spec.name] = Vehicle(
                    spec, systems[spec.sysid], link_timeout_s=self.link_timeout_s
                )
            # Discovery by sysid sees any message; wait for a decoded heartbeat too.
            await asyncio.gather(*(self._first_heartbeat(v) for v in self._vehicles.values()))
            if self.telemetry_rate_hz is not None:
                rate, wait = self.telemetry_rate_hz, self.connect_timeout_s
                await asyncio.gather(
                    *(v.set_telemetry_rate(rate, retry_for_s=wait) for v in self._vehicles.values())
                )
        except BaseException:
            self.close()
            raise

    async def _refuse_duplicates(self) -> None:
        """DuplicateSystemError if two autopilots answer as one of the fleet's system ids on
        the udpin ports (:mod:`mavlink.scan`), before MAVSDK merges them."""
        from mavlink.scan import duplicates, scan_udpin

        urls = [parse_url(s.url, vehicle=s.name) for s in self.specs]
        sysids = [s.sysid for s in self.specs]
        heard = await scan_udpin(urls, self.scan_s, expect=sysids)
        for spec, url in zip(self.specs, urls, strict=True):
            why = heard.busy.get(str(url))
            if why is not None:
                raise LinkError(
                    f"port {url.port} cannot be opened ({why}): another program (a ground "
                    "station, QGroundControl, a MAVSDK server, another gcs) uses it; close it, "
                    "or choose other ports with --base-port or --connection",
                    vehicle=spec.name,
                    url=spec.url,
                )
        found = duplicates(heard, sysids)
        if found:
            spec = next(s for s in self.specs if s.sysid == found[0].sysid)
            raise DuplicateSystemError(found[0].describe(), vehicle=spec.name, url=spec.url)
        for spec, url in zip(self.specs, urls, strict=True):
            if url.scheme is not Scheme.UDPIN:
                continue
            expected = {s.sysid for s, u in zip(self.specs, urls, strict=True) if u == url}
            there = heard.sysids_on(str(url))
            if there and not there & expected:
                raise LinkError(
                    f"system id(s) {', '.join(map(str, sorted(there)))} answer on port "
                    f"{url.port}, not {spec.sysid}: another program's vehicle, or a vehicle "
                    f"configured with another MAV_SYS_ID (give --connection per vehicle, and "
                    "the plan's system ids)",
                    vehicle=spec.name,
                    url=spec.url,
                )
            kinds = {
                snd.autopilot
                for snd in heard.senders.get(spec.sysid, {}).values()
                if snd.url == str(url) and snd.autopilot is not None
            }
            if kinds and MAV_AUTOPILOT_PX4 not in kinds:
                raise LinkError(
                    f"system id {spec.sysid} on port {url.port} is not PX4 (its heartbeat says "
                    f"MAV_AUTOPILOT {min(kinds)}{_autopilot_name(min(kinds))}): stl-gcs flies "
                    "PX4 vehicles",
                    vehicle=spec.name,
                    url=spec.url,
                )

    async def _first_heartbeat(self, v: Vehicle) -> None:
        """Wait for ``v``'s first autopilot HEARTBEAT; ConnectTimeoutError naming it if none."""
        try:
            await v.wait_for(
                lambda st: st.heartbeat_age_s is not None,
                "first heartbeat",
                timeout_s=self.connect_timeout_s,
            )
        except LinkLostError:
            raise
        except LinkError as exc:
            raise ConnectTimeoutError(
                f"no autopilot heartbeat from system id {v.spec.sysid} within "
                f"{self.connect_timeout_s:.1f} s",
                vehicle=v.name,
                url=v.url,
            ) from exc

    async def _wait_for_systems(self) -> dict[int, Any]:
        assert self._mavsdk is not None
        loop = asyncio.get_running_loop()
        changed = asyncio.Event()
        handle = self._mavsdk.subscribe_on_new_system(
            lambda _ud: loop.call_soon_threadsafe(changed.set)
        )
        wanted = {s.sysid for s in self.specs}
        deadline = loop.time() + self.connect_timeout_s
        found: dict[int, Any] = {}
        try:
            while True:
                changed.clear()
                for system in self._mavsdk.get_systems():
                    sid = system.get_system_id()
                    if sid in wanted and sid not in found and system.has_autopilot():
                        found[sid] = system
                if wanted <= found.keys():
                    return found
                remaining = deadline - loop.time()
                if remaining <= 0:
                    break
                # Also re-check periodically: the autopilot component of an
                # already discovered system may show up without a new-system event.
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(changed.wait(), min(remaining, 0.1))
        finally:
            self._mavsdk.unsubscribe_on_new_system(handle)
        seen = sorted(s.get_system_id() for s in self._mavsdk.get_systems())
        missing = [s for s in self.specs if s.sysid not in found]
        first = missing[0]
        others = ""
        if len(missing) > 1:
            others = "; also missing: " + ", ".join(f"{s.name} ({s.url})" for s in missing[1:])
        raise ConnectTimeoutError(
            f"no heartbeat from system id {first.sysid} within {self.connect_timeout_s:.1f} s "
            f"(systems seen: {', '.join(map(str, seen)) or 'none'}){others}",
            vehicle=first.name,
            url=first.url,
        )

    def close(self) -> None:
        """Unsubscribe and destroy the MAVSDK instance (closes every connection)."""
        for v in self._vehicles.values():
            v.close()
        self._vehicles = {}
        if self._mavsdk is not None:
            self._mavsdk.destroy()
            self._mavsdk = None

    # -- access ---------------------------------------------------------

    @property
    def vehicles(self) -> tuple[Vehicle, ...]:
        """The vehicles in spec order."""
        return tuple(self._vehicles[s.name] for s in self.specs if s.name in self._vehicles)

    def __getitem__(self, name: str) -> Vehicle:
        try:
            return self._vehicles[name]
        except KeyError:
            raise LinkError(
                f"no vehicle named {name!r} (have {', '.join(self._vehicles) or 'none'})"
            ) from None

    def __iter__(self) -> Iterator[Vehicle]:
        return iter(self.vehicles)

    def __len__(self) -> int:
        return len(self._vehicles)

    def statuses(self) -> list[VehicleStatus]:
        """One :class:`VehicleStatus` per vehicle, taken at the same instant."""
        now = time.monotonic()
        return [v.status(now) for v in self.vehicles]

    async def origins(self) -> dict[str, GeodeticPoint]:
        """Each vehicle's EKF origin (GPS_GLOBAL_ORIGIN), by name."""
        points = await asyncio.gather(*(v.request_origin() for v in self.vehicles))
        return {v.name: p for v, p in zip(self.vehicles, points, strict=True)}

    # -- all at once ----------------------------------------------------

    async def for_each(
        self,
        action: Callable[[Vehicle], Awaitable[None]],
        vehicles: Sequence[Vehicle] | None = None,
    ) -> dict[str, BaseException]:
        """Run ``action`` on the vehicles concurrently; failures by vehicle name.

        Every vehicle is attempted even if some fail (a safety stop must
        reach the ones that still answer); the caller decides what a failure
        means.
        """
        targets = list(self.vehicles if vehicles is None else vehicles)
        results = await asyncio.gather(*(action(v) for v in targets), return_exceptions=True)
        failures: dict[str, BaseException] = {}
        for v, r in zip(targets, results, strict=True):
            if isinstance(r, BaseException):
                if not isinstance(r, Exception):
                    raise r
                failures[v.name] = r
        return failures

    @contextlib.asynccontextmanager
    async def flight(
        self, vehicles: Sequence[Vehicle] | None = None, *, on_exit: str = "hold"
    ) -> AsyncIterator[FlightGuard]:
        """A flight scope: leaving it by an exception or a cancellation (Ctrl-C) first commands
        every vehicle (of ``vehicles``; default all) to hold where it is (``on_exit="land"``:
        to land), then lets the exception go on; a normal exit leaves them as they are.

        In the spirit of crazyflie-lib-python's ``MotionCommander``, whatever flies inside
        (``fly_offboard``, a mission flight) cannot leave the vehicles streaming to nobody::

            async with fleet.flight() as guard:
                result = await fly_offboard(fleet, trajectories, origin)

        The stop is MAVSDK's offboard stop (which holds) for a vehicle in offboard, Hold
        otherwise (:func:`mavlink.monitor.safe_stop`); every vehicle is attempted, and the
        guard records which did not accept it.
        """
        from mavlink.monitor import SafetyAction, safe_stop

        action = SafetyAction(on_exit)
        guard = FlightGuard(action=action.value)
        targets = list(self.vehicles if vehicles is None else vehicles)
        try:
            yield guard
        except BaseException:
            guard.stopped = True
            failed = await self.for_each(lambda v: safe_stop(v, action), targets)
            guard.failures = {k: str(e) for k, e in failed.items()}
            raise

    async def hold_all(self) -> dict[str, BaseException]:
        """Command Hold on every vehicle; returns the failures by name."""
        return await self.for_each(lambda v: v.hold())

    async def land_all(self) -> dict[str, BaseException]:
        """Command Land on every vehicle; returns the failures by name."""
        return await self.for_each(lambda v: v.land())
