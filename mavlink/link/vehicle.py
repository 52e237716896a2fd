"""One PX4 vehicle as the ground station sees it: its MAVSDK plugins, live state, commands.

:class:`Vehicle` subscribes to the vehicle telemetry the ground station uses as it comes
(MAVSDK's telemetry plugin: local position and velocity, in-air; mavlink_direct messages:
HEARTBEAT, GPS_GLOBAL_ORIGIN, STATUSTEXT, ESTIMATOR_STATUS, PARAM_VALUE, and of its MAVLink
camera CAMERA_IMAGE_CAPTURED and CAMERA_INFORMATION); the callbacks update its state directly
on MAVSDK's callback thread under a lock, and :meth:`Vehicle.status` takes a consistent
:class:`VehicleStatus` snapshot. The rest (heading, global position, home, battery) is read
from MAVSDK's own latest values when needed (the heading with each local position, the rest
when a snapshot is taken), not subscribed to: every subscribed message is a Python callback
on MAVSDK's one callback thread, whose queue MAVSDK cuts by dropping callbacks (and saying so
in its log) when it holds 100; twelve vehicles' subscriptions came to 800 callbacks a second,
now 300 (and a ``.tlog`` recording adds every message, :mod:`mavlink.tlog`). Its commands
(arm, modes, take-off, go-to, COMMAND_LONG to any of its components, parameters, telemetry
rates) are coroutines over :func:`mavlink.link.mavsdk_glue.mavsdk_call`.

A room of its own, apart from :mod:`mavlink.link.fleet` (which connects N of them through one
MAVSDK instance): everything here concerns one vehicle's link, and the missions, the
monitor and the offboard flight work on single vehicles.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from mavsdk.plugins.action import Action, ActionResult
from mavsdk.plugins.mavlink_direct import MavlinkDirect, MavlinkDirectResult, MavlinkMessage
from mavsdk.plugins.mission_raw import MissionRaw
from mavsdk.plugins.offboard import Offboard
from mavsdk.plugins.telemetry import Telemetry, TelemetryResult

from mavlink.clock import WALL, Clock
from mavlink.errors import CommandError, LinkError, LinkLostError
from mavlink.link.camera import (
    MAV_COMP_ID_CAMERA,
    MAV_TYPE_CAMERA,
    CameraInfo,
    CapturedImage,
    camera_info_from_fields,
    image_from_fields,
    unique_images,
)
from mavlink.link.mavsdk_glue import MAV_RESULT_NAMES, mavsdk_call, resolve_future
from mavlink.link.vehicle_status import VehicleSpec, VehicleStatus
from mavlink.px4_modes import (
    MAV_CMD_DO_SET_MODE,
    Px4Mode,
    UnknownModeError,
    decode_custom_mode,
    set_mode_params,
)
from mavlink.tracks import vehicle_instants
from planner.frames import GeodeticPoint

log = logging.getLogger(__name__)

MAV_CMD_NAV_TAKEOFF = 22
_MAV_CMD_REQUEST_MESSAGE = 512

#: STATUSTEXTs kept per vehicle (the latest).
_KEPT_TEXTS = 50
#: STATUSTEXT severities up to this one (MAV_SEVERITY_WARNING) explain a refusal
_WARNING = 4
#: how long a refusal waits for the vehicle's STATUSTEXT giving its reason (PX4 sends it with
#: the COMMAND_ACK, over the same link)
_REASON_GRACE_S = 0.1
#: MAV_PARAM_TYPE values of integer parameters (UINT8 .. INT64).
_INT_PARAM_TYPES = frozenset(range(1, 9))

#: MAVSDK results of a request that got no (usable) answer: worth sending again on a bad link.
_UNANSWERED = frozenset({"TIMEOUT", "BUSY", "NO_SYSTEM", "CONNECTION_ERROR", "UNKNOWN"})


# --------------------------------------------------------------------------
# Values
# --------------------------------------------------------------------------


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

    def __init__(
        self, spec: VehicleSpec, system: Any, *, link_timeout_s: float, clock: Clock = WALL
    ) -> None:
        self.spec = spec
        #: the clock of its telemetry's instants and of waits on it (:mod:`mavlink.clock`)
        self.clock = clock
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
        self._yaw_ned_rad = math.nan  # the latest heading, NED rad (NaN: none yet)
        self._t_heartbeat: float | None = None
        self._t_position: float | None = None
        self._track: list[tuple[float, ...]] | None = None
        self._texts: list[tuple[float, int, str]] = []
        self._pos_accuracy: tuple[float, float] | None = None
        self._track_accuracy: tuple[float, float] | None = None
        self._params: dict[str, float] = {}
        self._param_waiters: dict[str, list[asyncio.Future[float]]] = {}
        self._handles: list[tuple[Callable[[Any], None], Any]] = []
        # closed: the plugins may be gone; the lock keeps close() from passing a plugin read
        # under way on MAVSDK's callback thread
        self._closed = False
        self._plugin_lock = threading.Lock()
        # cameras heard (component ids), their optics, and the pictures reported
        self._cameras: set[int] = set()
        self._camera_info: dict[int, CameraInfo] = {}
        self._images: list[tuple[float, int, dict[str, Any]]] = []
        self._subscribe()

    # -- telemetry ------------------------------------------------------

    def _subscribe(self) -> None:
        """Subscribe to what is needed as it comes: local position and velocity (the track,
        the monitor), in-air, and the messages commands and the monitor wait for. Heading,
        global position, home and battery are read when needed instead (:meth:`_poll`:
        MAVSDK keeps their latest values whether or not anyone subscribes)."""
        tel = self.telemetry
        self._handles += [
            (
                self.direct.unsubscribe_message,
                self.direct.subscribe_message("LOCAL_POSITION_NED", self._on_pv),
            ),
            (tel.unsubscribe_in_air, tel.subscribe_in_air(self._on_in_air)),
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
            (
                self.direct.unsubscribe_message,
                self.direct.subscribe_message("CAMERA_IMAGE_CAPTURED", self._on_image),
            ),
            (
                self.direct.unsubscribe_message,
                self.direct.subscribe_message("CAMERA_INFORMATION", self._on_camera_info),
            ),
        ]

    def _on_pv(self, msg: MavlinkMessage, _ud: Any) -> None:
        """LOCAL_POSITION_NED, read whole (MAVSDK's telemetry drops its ``time_boot_ms``,
        which the track needs: :meth:`stop_track`)."""
        if msg.system_id != self.spec.sysid or msg.component_id != 1:
            return
        t = self.clock.monotonic()
        f = json.loads(msg.fields_json)
        pos = (float(f["x"]), float(f["y"]), float(f["z"]))
        vel = (float(f["vx"]), float(f["vy"]), float(f["vz"]))
        heading = self._latest_heading_deg()
        with self._lock:
            self._note_heading(heading)
            self._pos_ned, self._vel_ned, self._t_position = pos, vel, t
            if self._track is not None:
                self._track.append((t, *pos, *vel, self._yaw_ned_rad, 1e-3 * f["time_boot_ms"]))

    def _latest_heading_deg(self) -> float | None:
        """MAVSDK's latest heading (degrees; NaN: none yet, or unknown; ``None`` after
        :meth:`close`: nothing read, the last heading stays), from GLOBAL_POSITION_INT.hdg
        (PX4: the estimate's heading): read with each local position rather than subscribed
        to (one callback a sample instead of two), and rather than ATTITUDE (a 50 Hz
        subscription decoded in Python). Safe on MAVSDK's callback thread: :meth:`close`
        waits for a read under way, and none starts after it."""
        with self._plugin_lock:
            if self._closed:
                return None
            return float(self.telemetry.heading().heading_deg)

    def _note_heading(self, heading_deg: float | None) -> None:
        """Keep a heading read (under the state lock): the track's yaw stays the last known;
        ``None`` (nothing read: the link is closed) changes nothing."""
        if heading_deg is None:
            return
        known = math.isfinite(heading_deg)
        self._heading = heading_deg if known else None
        if known:
            self._yaw_ned_rad = math.radians(heading_deg)

    def _poll(self) -> None:
        """Take MAVSDK's latest heading, global position, home and battery (NaN until heard:
        kept ``None``); after :meth:`close` the last values stay."""
        if self._closed:
            return
        heading = self._latest_heading_deg()
        tel = self.telemetry
        p, h, b = tel.position(), tel.home(), tel.battery()
        position = home = None
        if math.isfinite(p.latitude_deg):
            position = GeodeticPoint(
                float(p.latitude_deg), float(p.longitude_deg), float(p.absolute_altitude_m)
            )
        if math.isfinite(h.latitude_deg):
            home = GeodeticPoint(
                float(h.latitude_deg), float(h.longitude_deg), float(h.absolute_altitude_m)
            )
        # MAVSDK reports percent (0..100) from SYS_STATUS / BATTERY_STATUS.
        remaining = float(b.remaining_percent)
        battery = (remaining / 100.0, float(b.voltage_v)) if math.isfinite(remaining) else None
        with self._lock:
            self._note_heading(heading)
            if position is not None:
                self._position, self._rel_alt = position, float(p.relative_altitude_m)
            if home is not None:
                self._home = home
            if battery is not None:
                self._battery = battery

    def _on_in_air(self, in_air: bool, _ud: Any) -> None:
        with self._lock:
            self._in_air = bool(in_air)

    def _on_heartbeat(self, msg: MavlinkMessage, _ud: Any) -> None:
        if msg.component_id != 1:  # the autopilot's heartbeat decides the mode; a camera's
            if msg.system_id == self.spec.sysid and _is_camera(msg):
                with self._lock:
                    self._cameras.add(int(msg.component_id))
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
            self._t_heartbeat = self.clock.monotonic()

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
            self._texts.append((self.clock.monotonic(), int(f.get("severity", 6)), str(text)))
            del self._texts[:-_KEPT_TEXTS]

    def _on_image(self, msg: MavlinkMessage, _ud: Any) -> None:
        if msg.system_id != self.spec.sysid:
            return
        t = self.clock.monotonic()
        fields = json.loads(msg.fields_json)
        with self._lock:
            self._images.append((t, int(msg.component_id), fields))

    def _on_camera_info(self, msg: MavlinkMessage, _ud: Any) -> None:
        if msg.system_id != self.spec.sysid:
            return
        info = camera_info_from_fields(json.loads(msg.fields_json), int(msg.component_id))
        with self._lock:
            self._camera_info[info.component] = info
            self._cameras.add(info.component)

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
            fut.get_loop().call_soon_threadsafe(resolve_future, fut, value)

    def statustexts(self, since_monotonic_s: float = 0.0) -> list[tuple[int, str]]:
        """STATUSTEXTs heard since ``since_monotonic_s`` (severity, text), oldest first."""
        return [(sev, text) for _t, sev, text in self.timed_statustexts(since_monotonic_s)]

    def timed_statustexts(self, since_monotonic_s: float = 0.0) -> list[tuple[float, int, str]]:
        """STATUSTEXTs heard since ``since_monotonic_s`` (time on the link's clock, severity,
        text), oldest first (the latest 50 are kept)."""
        with self._lock:
            return [m for m in self._texts if m[0] >= since_monotonic_s]

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
        now = self.clock.monotonic() if now is None else now
        self._poll()
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
                yaw_ned_rad=None if math.isnan(self._yaw_ned_rad) else self._yaw_ned_rad,
            )

    # -- the camera -----------------------------------------------------

    @property
    def camera_component(self) -> int | None:
        """The component id of the vehicle's (first) MAVLink camera heard, or ``None``."""
        with self._lock:
            return min(self._cameras) if self._cameras else None

    @property
    def camera_info(self) -> CameraInfo | None:
        """The optics of the camera :attr:`camera_component`, once CAMERA_INFORMATION came."""
        comp = self.camera_component
        with self._lock:
            return None if comp is None else self._camera_info.get(comp)

    async def request_camera_information(self, timeout_s: float = 3.0) -> CameraInfo | None:
        """Ask the camera for CAMERA_INFORMATION (MAV_CMD_REQUEST_MESSAGE 259) and wait for it;
        ``None`` without a camera, or when it does not answer."""
        comp = self.camera_component
        if comp is None:
            return None
        try:
            await self.command_long(
                "request CAMERA_INFORMATION", _MAV_CMD_REQUEST_MESSAGE, 259.0, component=comp
            )
        except CommandError as exc:
            log.info("vehicle %s: %s", self.name, exc)
            return None
        deadline = self.clock.monotonic() + timeout_s
        while self.clock.monotonic() < deadline:
            info = self.camera_info
            if info is not None:
                return info
            await self.clock.sleep(0.05)
        return None

    def images(self, t0_monotonic_s: float) -> list[CapturedImage]:
        """The pictures reported so far (CAMERA_IMAGE_CAPTURED), each once, by time; ``t_s``
        from ``t0_monotonic_s`` (the flight's shared start)."""
        with self._lock:
            got = list(self._images)
        return unique_images(
            image_from_fields(f, self.name, t - t0_monotonic_s, comp) for t, comp, f in got
        )

    @property
    def subscriptions(self) -> tuple[str, ...]:
        """The MAVSDK subscriptions it holds, by their unsubscribe function's name (a
        mavlink_direct message's is ``unsubscribe_message``)."""
        return tuple(unsubscribe.__name__ for unsubscribe, _ in self._handles)

    # -- recording of the flown track ----------------------------------

    def start_track(self) -> None:
        """Start recording every LOCAL_POSITION_NED sample (receive time, pos, vel, and the
        latest known heading MAVSDK has by then), and the worst estimator accuracy reported
        meanwhile (:attr:`track_accuracy_m`)."""
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
        """Stop recording; ``(k, 8)`` rows ``(t_monotonic_s, n, e, d, vn, ve, vd, yaw)``, the
        yaw the vehicle's NED heading (rad, clockwise from north; NaN before the first
        heading). :func:`mavlink.tracks.track_from_rows` makes them a flown track.

        Each sample's instant is when the vehicle took it, on :attr:`clock`: its own
        ``time_boot_ms`` carried onto the clock by the fastest delivery around it
        (:func:`mavlink.tracks.vehicle_instants`), so that the link's latency, which the
        receipt times carry (and a busy ground station lengthens), is not read as a lag
        of the vehicle."""
        with self._lock:
            rows, self._track = self._track, None
        if not rows:
            return np.zeros((0, 8))
        a = np.asarray(rows, dtype=float)
        a[:, 0] = vehicle_instants(a[:, 0], a[:, 8])
        return a[:, :8]

    # -- commands -------------------------------------------------------

    def _fail(self, what: str, result: Any, since_s: float | None = None) -> CommandError:
        """The refusal of ``what``, with the reasons the vehicle gave in STATUSTEXT (warning
        or worse) since ``since_s`` (on :attr:`clock`), e.g. PX4's "Arming denied: ..."."""
        name = getattr(result, "name", str(result))
        said = [] if since_s is None else self.statustexts(since_s)
        reasons = list(dict.fromkeys(text for sev, text in said if sev <= _WARNING))
        why = f' (the vehicle said: "{"; ".join(reasons)}")' if reasons else ""
        return CommandError(
            f"{what} failed: {name}{why}", result=name, vehicle=self.name, url=self.url
        )

    async def _action(self, what: str, start: Callable[..., None], *args: Any) -> None:
        t0 = self.clock.monotonic()
        try:
            result = await mavsdk_call(start, *args)
        except TimeoutError:
            raise self._fail(what, "TIMEOUT", t0) from None
        if result != ActionResult.SUCCESS:
            await self.clock.sleep(_REASON_GRACE_S)  # a reason sent just after the refusal
            raise self._fail(what, result, t0)

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

    async def command_long(
        self, what: str, command: int, *params: float, component: int = 1
    ) -> None:
        """Send COMMAND_LONG ``command`` (params 1..7, missing ones 0) to the vehicle's
        ``component`` (the autopilot, 1, unless told) and require ACCEPTED.

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
            "target_component": int(component),
            "command": int(command),
            "confirmation": 0,
        }
        fields.update({f"param{i + 1}": (None if math.isnan(x) else x) for i, x in enumerate(p)})  # type: ignore[misc]
        msg = MavlinkMessage(
            message_name="COMMAND_LONG",
            target_system_id=self.spec.sysid,
            target_component_id=int(component),
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
        deadline = self.clock.monotonic() + timeout_s
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
            if self.clock.monotonic() >= deadline:
                raise LinkError(
                    f"timed out after {timeout_s:.1f} s waiting for {what} "
                    f"(mode {st.mode.label if st.mode else st.custom_mode}, "
                    f"armed {st.armed}, position NED {_fmt(st.pos_ned_m)})",
                    vehicle=self.name,
                    url=self.url,
                )
            await self.clock.sleep(poll_s)

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
        """Drop the telemetry subscriptions (the plugins die with the Mavsdk instance); the
        state last heard stays readable."""
        with self._plugin_lock:
            self._closed = True
        handles, self._handles = self._handles, []
        for unsubscribe, handle in handles:
            unsubscribe(handle)


def _fmt(p: tuple[float, float, float] | None) -> str:
    return "unknown" if p is None else "(" + ", ".join(f"{x:.2f}" for x in p) + ")"


def _is_camera(msg: MavlinkMessage) -> bool:
    """Whether a HEARTBEAT is a MAVLink camera's (type MAV_TYPE_CAMERA, component 100-105)."""
    if not MAV_COMP_ID_CAMERA <= msg.component_id <= MAV_COMP_ID_CAMERA + 5:
        return False
    return int(json.loads(msg.fields_json).get("type", -1)) == MAV_TYPE_CAMERA
