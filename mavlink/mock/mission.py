"""Vehicle side of the MAVLink mission protocol (mavlink.io services/mission), PX4 flavour.

:class:`MissionServer` keeps the three plans (MISSION, FENCE, RALLY) of one
vehicle and answers upload, download and clear transfers:

* upload: ``MISSION_COUNT`` -> ``MISSION_REQUEST_INT(0..n-1)`` -> items ->
  ``MISSION_ACK``.  A request is re-sent every 250 ms until the item arrives; the
  transfer is abandoned (``MAV_MISSION_OPERATION_CANCELLED``) after 5 s with
  nothing received, as PX4's ``mavlink_mission.cpp`` does.  An item with an
  unexpected sequence number is dropped and the expected one re-requested (a
  copy of the item just received is dropped silently, as PX4 does).  A
  repeated ``MISSION_COUNT`` while item 0 is outstanding re-sends the request;
  a repeated last item after completion is answered with the ACK again.  A
  client sending legacy ``MISSION_ITEM`` is answered with legacy
  ``MISSION_REQUEST``.  A bad item ends the transfer with the error ACK (the
  previous plan is kept).
* download: ``MISSION_REQUEST_LIST`` -> ``MISSION_COUNT``; ``MISSION_REQUEST_INT``
  (or legacy ``MISSION_REQUEST``) -> the item; a sequence out of range gets
  ``MAV_MISSION_INVALID_SEQUENCE``.
* ``MISSION_CLEAR_ALL`` and ``MISSION_COUNT(0)`` clear a plan.

Camera and gimbal items (IMAGE_START/STOP_CAPTURE, DO_GIMBAL_MANAGER_PITCHYAW/_CONFIGURE,
DO_SET_ROI_NONE) are accepted in MAV_FRAME_MISSION only and DO_SET_ROI_LOCATION in a global
frame only, as PX4 does (``MAV_MISSION_UNSUPPORTED`` otherwise).

Items are kept as received (legacy float lat/lon are converted to ``*_INT`` degE7).
With ``px4_storage`` a download returns what PX4 v1.17 stores
(``mavlink_mission.cpp``, ``docs/px4-behaviour.md``): waypoint and take-off yaw
(param4) as float32 radians wrapped to [0, 2 pi), returned in degrees; MAV_FRAME_MISSION
items with x/y through float32; DO_SET_ROI_LOCATION (a position to PX4) with param1-4
zero; FENCE items
with autocontinue 0, param2-4 zero, param1 the rounded vertex count or the radius
and the frame rewritten to GLOBAL_INT (GLOBAL for a legacy download); RALLY items
with param1-4 zero and the same frame rewrite; ``current`` taken from the
mission's current item for every plan type.  Without it a download returns
exactly what was uploaded.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

MISSION = mavlink2.MAV_MISSION_TYPE_MISSION
FENCE = mavlink2.MAV_MISSION_TYPE_FENCE
RALLY = mavlink2.MAV_MISSION_TYPE_RALLY
ALL_TYPES = mavlink2.MAV_MISSION_TYPE_ALL

RETRY_TIMEOUT_S = 0.25
PROTOCOL_TIMEOUT_S = 5.0
MAX_ITEMS: dict[int, int] = {MISSION: 2000, FENCE: 256, RALLY: 32}

#: Frames PX4 accepts for items that carry a position (global only: PX4 has no
#: local-frame mission items).  Legacy float frames are accepted too.
GLOBAL_FRAMES = frozenset(
    {
        mavlink2.MAV_FRAME_GLOBAL,
        mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT,
        mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT,
        mavlink2.MAV_FRAME_GLOBAL_INT,
        mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
    }
)
_LEGACY_TO_INT_FRAME = {
    mavlink2.MAV_FRAME_GLOBAL: mavlink2.MAV_FRAME_GLOBAL_INT,
    mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT: mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT: mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
}
_INT_TO_LEGACY_FRAME = {v: k for k, v in _LEGACY_TO_INT_FRAME.items()}

#: Commands whose x/y/z are a position.
POSITION_COMMANDS = frozenset(
    {
        mavlink2.MAV_CMD_NAV_WAYPOINT,
        mavlink2.MAV_CMD_NAV_LOITER_UNLIM,
        mavlink2.MAV_CMD_NAV_LOITER_TURNS,
        mavlink2.MAV_CMD_NAV_LOITER_TIME,
        mavlink2.MAV_CMD_NAV_LAND,
        mavlink2.MAV_CMD_NAV_TAKEOFF,
        mavlink2.MAV_CMD_NAV_VTOL_TAKEOFF,
        mavlink2.MAV_CMD_NAV_VTOL_LAND,
        mavlink2.MAV_CMD_NAV_FENCE_RETURN_POINT,
        mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
        mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
        mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
        mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
        mavlink2.MAV_CMD_NAV_RALLY_POINT,
        mavlink2.MAV_CMD_DO_SET_ROI_LOCATION,
    }
)

#: Camera and gimbal items PX4 takes only in MAV_FRAME_MISSION, and the ROI location only in
#: a global frame (``MavlinkMissionManager::parse_mavlink_mission_item``: either branch
#: answers MAV_MISSION_UNSUPPORTED for a command it does not list).
_MISSION_FRAME_ONLY = frozenset(
    {
        mavlink2.MAV_CMD_IMAGE_START_CAPTURE,
        mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE,
        mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
        mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
        mavlink2.MAV_CMD_DO_SET_ROI_NONE,
    }
)

#: Commands PX4 multicopters accept per plan type.
SUPPORTED_COMMANDS: dict[int, frozenset[int]] = {
    MISSION: frozenset(
        {
            mavlink2.MAV_CMD_NAV_WAYPOINT,
            mavlink2.MAV_CMD_NAV_LOITER_UNLIM,
            mavlink2.MAV_CMD_NAV_LOITER_TURNS,
            mavlink2.MAV_CMD_NAV_LOITER_TIME,
            mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH,
            mavlink2.MAV_CMD_NAV_LAND,
            mavlink2.MAV_CMD_NAV_TAKEOFF,
            mavlink2.MAV_CMD_NAV_DELAY,
            mavlink2.MAV_CMD_NAV_VTOL_TAKEOFF,
            mavlink2.MAV_CMD_NAV_VTOL_LAND,
            mavlink2.MAV_CMD_CONDITION_DELAY,
            mavlink2.MAV_CMD_CONDITION_YAW,
            mavlink2.MAV_CMD_DO_JUMP,
            mavlink2.MAV_CMD_DO_CHANGE_SPEED,
            mavlink2.MAV_CMD_DO_SET_HOME,
            mavlink2.MAV_CMD_DO_SET_SERVO,
            mavlink2.MAV_CMD_DO_LAND_START,
            mavlink2.MAV_CMD_DO_SET_ROI_LOCATION,
            mavlink2.MAV_CMD_DO_SET_ROI_NONE,
            mavlink2.MAV_CMD_DO_SET_ROI,
            mavlink2.MAV_CMD_DO_DIGICAM_CONTROL,
            mavlink2.MAV_CMD_DO_MOUNT_CONTROL,
            mavlink2.MAV_CMD_DO_SET_CAM_TRIGG_DIST,
            mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
            mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
            mavlink2.MAV_CMD_IMAGE_START_CAPTURE,
            mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE,
            mavlink2.MAV_CMD_VIDEO_START_CAPTURE,
            mavlink2.MAV_CMD_VIDEO_STOP_CAPTURE,
            mavlink2.MAV_CMD_SET_CAMERA_MODE,
            mavlink2.MAV_CMD_DO_VTOL_TRANSITION,
        }
    ),
    FENCE: frozenset(
        {
            mavlink2.MAV_CMD_NAV_FENCE_RETURN_POINT,
            mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
            mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
            mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
            mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
        }
    ),
    RALLY: frozenset({mavlink2.MAV_CMD_NAV_RALLY_POINT}),
}


@dataclass(frozen=True, slots=True)
class MissionItem:
    """One stored plan item, the fields of ``MISSION_ITEM_INT`` (x, y: degE7 or raw int).

    The ground station has its own (:class:`mavlink.mission.items.MissionItem`) on purpose: the
    mock is the vehicle's side and shares nothing with the client it tests but the wire, so a
    mistake in one cannot hide the same mistake in the other.
    """

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    mission_type: int

    @classmethod
    def from_message(cls, msg: mavlink2.MAVLink_message) -> MissionItem:
        """From a ``MISSION_ITEM_INT`` or a legacy ``MISSION_ITEM`` (float lat/lon -> degE7)."""
        if msg.get_type() == "MISSION_ITEM":
            frame = _LEGACY_TO_INT_FRAME.get(msg.frame, msg.frame)
            if msg.command in POSITION_COMMANDS and msg.frame in GLOBAL_FRAMES:
                x, y = _deg_to_e7(msg.x), _deg_to_e7(msg.y)
            else:
                x, y = int(msg.x), int(msg.y)
        else:
            frame, x, y = msg.frame, int(msg.x), int(msg.y)
        return cls(
            seq=msg.seq,
            frame=frame,
            command=msg.command,
            current=msg.current,
            autocontinue=msg.autocontinue,
            param1=msg.param1,
            param2=msg.param2,
            param3=msg.param3,
            param4=msg.param4,
            x=x,
            y=y,
            z=msg.z,
            mission_type=msg.mission_type,
        )


_YAW_COMMANDS = frozenset(
    {
        mavlink2.MAV_CMD_NAV_WAYPOINT,
        mavlink2.MAV_CMD_NAV_TAKEOFF,
        mavlink2.MAV_CMD_NAV_LOITER_TIME,
        mavlink2.MAV_CMD_NAV_LOITER_UNLIM,
        mavlink2.MAV_CMD_NAV_LAND,
        mavlink2.MAV_CMD_NAV_VTOL_TAKEOFF,
        mavlink2.MAV_CMD_NAV_VTOL_LAND,
    }
)
_VERTEX_COMMANDS = frozenset(
    {
        mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
        mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
    }
)


def px4_stored(item: MissionItem, current: int, legacy: bool) -> MissionItem:
    """``item`` as PX4 v1.17 returns it on download (see the module docstring).

    ``current`` is the vehicle's current mission item; ``legacy``: a MISSION_REQUEST
    (float) download, whose frames PX4 reports without ``_INT``.
    """
    f32 = np.float32
    mtype = item.mission_type
    if mtype == MISSION and item.command == mavlink2.MAV_CMD_DO_SET_ROI_LOCATION:
        # stored as a position (lat, lon, altitude): returned with param1-4 zero
        return dataclasses.replace(
            item, param1=0.0, param2=0.0, param3=0.0, param4=0.0, z=float(f32(item.z)),
            current=int(item.seq == current),
        )  # fmt: skip
    if mtype == MISSION and item.frame == mavlink2.MAV_FRAME_MISSION:
        # params 5-7 kept as float32 (mission_item_s::params), x/y rounded back
        return dataclasses.replace(
            item, x=round(float(f32(item.x))), y=round(float(f32(item.y))),
            current=int(item.seq == current),
        )  # fmt: skip
    if mtype == MISSION:
        p4 = item.param4
        if item.command in _YAW_COMMANDS and math.isfinite(p4):
            # PX4's float math: radians(x) = x * (pi / 180), wrap_2pi, degrees(r) = r * (180 / pi)
            pi, two_pi = f32(math.pi), f32(2.0 * math.pi)
            rad = f32(p4) * (pi / f32(180.0))
            if not (f32(0.0) <= rad < two_pi):
                rad = rad - two_pi * f32(math.floor(rad / two_pi))
            p4 = float(rad * (f32(180.0) / pi))
        return dataclasses.replace(item, param4=p4, current=int(item.seq == current))
    frame = mavlink2.MAV_FRAME_GLOBAL if legacy else mavlink2.MAV_FRAME_GLOBAL_INT
    z = float(f32(item.z))
    if mtype == FENCE:
        p1 = float(int(item.param1 + 0.5)) if item.command in _VERTEX_COMMANDS else item.param1
        return dataclasses.replace(
            item, frame=frame, autocontinue=0, param1=float(f32(p1)), param2=0.0,
            param3=0.0, param4=0.0, z=z, current=int(item.seq == current),
        )  # fmt: skip
    return dataclasses.replace(
        item, frame=frame, param1=0.0, param2=0.0, param3=0.0, param4=0.0, z=z,
        current=int(item.seq == current),
    )  # fmt: skip


def _deg_to_e7(value_deg: float) -> int:
    if not math.isfinite(value_deg):
        return 0
    return round(value_deg * 1e7)


def validate_item(item: MissionItem, mission_type: int) -> int:
    """``MAV_MISSION_RESULT`` for one item of a plan of ``mission_type`` (0 = accepted)."""
    if item.command not in SUPPORTED_COMMANDS[mission_type]:
        return mavlink2.MAV_MISSION_UNSUPPORTED
    if item.command in _MISSION_FRAME_ONLY and item.frame != mavlink2.MAV_FRAME_MISSION:
        return mavlink2.MAV_MISSION_UNSUPPORTED
    if item.command == mavlink2.MAV_CMD_DO_SET_ROI_LOCATION and item.frame not in GLOBAL_FRAMES:
        return mavlink2.MAV_MISSION_UNSUPPORTED
    if item.command in POSITION_COMMANDS:
        if item.frame not in GLOBAL_FRAMES:
            return mavlink2.MAV_MISSION_UNSUPPORTED_FRAME
        if abs(item.x) > 900_000_000:
            return mavlink2.MAV_MISSION_INVALID_PARAM5_X
        if abs(item.y) > 1_800_000_000:
            return mavlink2.MAV_MISSION_INVALID_PARAM6_Y
        if not math.isfinite(item.z) and item.command not in (
            mavlink2.MAV_CMD_NAV_LAND,
            mavlink2.MAV_CMD_NAV_TAKEOFF,
        ):
            return mavlink2.MAV_MISSION_INVALID_PARAM7
    elif item.frame not in GLOBAL_FRAMES and item.frame != mavlink2.MAV_FRAME_MISSION:
        return mavlink2.MAV_MISSION_UNSUPPORTED_FRAME
    if item.command in (
        mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
        mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
    ) and not (item.param1 >= 3):
        return mavlink2.MAV_MISSION_INVALID_PARAM1
    if item.command in (
        mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
        mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
    ) and not (item.param1 > 0):
        return mavlink2.MAV_MISSION_INVALID_PARAM1
    return mavlink2.MAV_MISSION_ACCEPTED


@dataclass(slots=True)
class _Upload:
    mission_type: int
    count: int
    partner: tuple[int, int]
    next_seq: int = 0
    legacy: bool = False
    last_recv_s: float = 0.0
    last_sent_s: float = 0.0
    items: list[MissionItem] | None = None


class MissionServer:
    """The three plans of one vehicle and the vehicle side of their transfers.

    ``send(msg)`` transmits a message to the GCS; ``clock_s()`` is the
    simulation time; ``on_changed(mission_type)`` is called after a plan was
    replaced or cleared; ``current_seq()`` gives the vehicle's current mission
    item (marked ``current=1`` in downloads); ``statustext(severity, text)``
    tells the operator.
    """

    def __init__(
        self,
        send: Callable[[mavlink2.MAVLink_message], None],
        clock_s: Callable[[], float],
        on_changed: Callable[[int], None],
        current_seq: Callable[[], int],
        statustext: Callable[[int, str], None],
        px4_storage: Callable[[], bool] = lambda: False,
    ) -> None:
        self._px4_storage = px4_storage
        self.send = send
        self._clock_s = clock_s
        self._on_changed = on_changed
        self._current_seq = current_seq
        self._statustext = statustext
        self.plans: dict[int, tuple[MissionItem, ...]] = {MISSION: (), FENCE: (), RALLY: ()}
        self._upload: _Upload | None = None
        # last completed upload: (type, count, partner) for re-sending its ACK
        self._done: tuple[int, int, tuple[int, int]] | None = None
        self.uploads_completed = 0

    @property
    def busy(self) -> bool:
        """True while an upload is in progress."""
        return self._upload is not None

    # ---------------------------------------------------------------- dispatch
    def handle(self, msg: mavlink2.MAVLink_message) -> bool:
        """Process a mission-protocol message; False if ``msg`` is not one."""
        kind = msg.get_type()
        handler = self._HANDLERS.get(kind)
        if handler is None:
            return False
        handler(self, msg)
        return True

    def tick(self) -> None:
        """Re-send an outstanding request, or give up after the protocol timeout."""
        up = self._upload
        if up is None:
            return
        now = self._clock_s()
        if now - up.last_recv_s > PROTOCOL_TIMEOUT_S:
            self._upload = None
            self._statustext(mavlink2.MAV_SEVERITY_WARNING, "Mission upload timeout")
            self._ack(up.partner, mavlink2.MAV_MISSION_OPERATION_CANCELLED, up.mission_type)
        elif now - up.last_sent_s > RETRY_TIMEOUT_S:
            self._request(up)

    # ---------------------------------------------------------------- upload
    def _on_count(self, msg: mavlink2.MAVLink_message) -> None:
        partner = (msg.get_srcSystem(), msg.get_srcComponent())
        mtype = msg.mission_type
        if mtype not in self.plans:
            self._ack(partner, mavlink2.MAV_MISSION_INVALID, mtype)
            return
        up = self._upload
        if up is not None:
            if up.next_seq == 0 and up.mission_type == mtype and up.count == msg.count:
                # our first request was lost: ask again
                up.last_recv_s = self._clock_s()
                self._request(up)
            else:
                self._statustext(mavlink2.MAV_SEVERITY_WARNING, "IGN MISSION_COUNT: Busy")
            return
        if msg.count == 0:
            self.plans[mtype] = ()
            self._done = None
            self._ack(partner, mavlink2.MAV_MISSION_ACCEPTED, mtype)
            self._on_changed(mtype)
            return
        if msg.count > MAX_ITEMS[mtype]:
            self._ack(partner, mavlink2.MAV_MISSION_NO_SPACE, mtype)
            return
        now = self._clock_s()
        self._done = None
        up = _Upload(mtype, msg.count, partner, last_recv_s=now, items=[])
        self._upload = up
        self._request(up)

    def _on_item(self, msg: mavlink2.MAVLink_message) -> None:
        up = self._upload
        partner = (msg.get_srcSystem(), msg.get_srcComponent())
        if up is None:
            done = self._done
            if (
                done is not None
                and done[0] == msg.mission_type
                and msg.seq == done[1] - 1
                and done[2] == partner
            ):
                # our final ACK was lost: the client re-sent the last item
                self._ack(partner, mavlink2.MAV_MISSION_ACCEPTED, msg.mission_type)
            return
        if msg.mission_type != up.mission_type or partner != up.partner:
            return
        up.last_recv_s = self._clock_s()
        if msg.get_type() == "MISSION_ITEM":
            up.legacy = True
        if msg.seq != up.next_seq:
            # A copy of the item just stored (a duplicated datagram) is ignored, as
            # PX4 does; answering it with another request would make the client see
            # a repeated request and spend one of its retries (MAVSDK gives up after 5).
            if msg.seq != up.next_seq - 1:
                self._request(up)
            return
        item = MissionItem.from_message(msg)
        result = validate_item(item, up.mission_type)
        if result != mavlink2.MAV_MISSION_ACCEPTED:
            self._upload = None
            self._statustext(
                mavlink2.MAV_SEVERITY_WARNING,
                f"Mission item {item.seq} rejected (command {item.command}, frame {item.frame})",
            )
            self._ack(partner, result, up.mission_type)
            return
        assert up.items is not None
        up.items.append(item)
        up.next_seq += 1
        if up.next_seq < up.count:
            self._request(up)
            return
        self._upload = None
        self.plans[up.mission_type] = tuple(up.items)
        self._done = (up.mission_type, up.count, partner)
        self.uploads_completed += 1
        self._ack(partner, mavlink2.MAV_MISSION_ACCEPTED, up.mission_type)
        self._on_changed(up.mission_type)

    def _request(self, up: _Upload) -> None:
        tsys, tcomp = up.partner
        if up.legacy:
            msg = mavlink2.MAVLink_mission_request_message(
                tsys, tcomp, up.next_seq, up.mission_type
            )
        else:
            msg = mavlink2.MAVLink_mission_request_int_message(
                tsys, tcomp, up.next_seq, up.mission_type
            )
        up.last_sent_s = self._clock_s()
        self.send(msg)

    def _on_ack(self, msg: mavlink2.MAVLink_message) -> None:
        up = self._upload
        if (
            up is not None
            and msg.mission_type == up.mission_type
            and msg.type != mavlink2.MAV_MISSION_ACCEPTED
        ):
            # the client cancelled the upload
            self._upload = None

    # ---------------------------------------------------------------- download
    def _on_request_list(self, msg: mavlink2.MAVLink_message) -> None:
        partner = (msg.get_srcSystem(), msg.get_srcComponent())
        mtype = msg.mission_type
        if mtype not in self.plans:
            self._ack(partner, mavlink2.MAV_MISSION_INVALID, mtype)
            return
        self.send(
            mavlink2.MAVLink_mission_count_message(
                partner[0], partner[1], len(self.plans[mtype]), mtype
            )
        )

    def _on_request(self, msg: mavlink2.MAVLink_message) -> None:
        partner = (msg.get_srcSystem(), msg.get_srcComponent())
        mtype = msg.mission_type
        plan = self.plans.get(mtype)
        if plan is None:
            self._ack(partner, mavlink2.MAV_MISSION_INVALID, mtype)
            return
        if self._upload is not None:
            # a request for an item while *we* are receiving makes no sense: ignore it
            return
        if not (0 <= msg.seq < len(plan)):
            self._ack(partner, mavlink2.MAV_MISSION_INVALID_SEQUENCE, mtype)
            return
        it = plan[msg.seq]
        legacy = msg.get_type() == "MISSION_REQUEST"
        if self._px4_storage():
            it = px4_stored(it, self._current_seq(), legacy)
            current = it.current
        else:
            current = int(mtype == MISSION and it.seq == self._current_seq())
        if legacy:
            frame = _INT_TO_LEGACY_FRAME.get(it.frame, it.frame)
            positional = it.command in POSITION_COMMANDS and it.frame in GLOBAL_FRAMES
            x = it.x / 1e7 if positional else float(it.x)
            y = it.y / 1e7 if positional else float(it.y)
            out = mavlink2.MAVLink_mission_item_message(
                partner[0], partner[1], it.seq, frame, it.command, current, it.autocontinue,
                it.param1, it.param2, it.param3, it.param4, x, y, it.z, mtype,
            )  # fmt: skip
        else:
            out = mavlink2.MAVLink_mission_item_int_message(
                partner[0], partner[1], it.seq, it.frame, it.command, current, it.autocontinue,
                it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z, mtype,
            )  # fmt: skip
        self.send(out)

    # ---------------------------------------------------------------- clear
    def _on_clear_all(self, msg: mavlink2.MAVLink_message) -> None:
        partner = (msg.get_srcSystem(), msg.get_srcComponent())
        mtype = msg.mission_type
        types = list(self.plans) if mtype == ALL_TYPES else [mtype]
        if any(t not in self.plans for t in types):
            self._ack(partner, mavlink2.MAV_MISSION_INVALID, mtype)
            return
        self._upload = None
        self._done = None
        for t in types:
            self.plans[t] = ()
        self._ack(partner, mavlink2.MAV_MISSION_ACCEPTED, mtype)
        for t in types:
            self._on_changed(t)

    def _ack(self, partner: tuple[int, int], result: int, mission_type: int) -> None:
        self.send(
            mavlink2.MAVLink_mission_ack_message(partner[0], partner[1], result, mission_type)
        )

    _HANDLERS: ClassVar[dict[str, Callable[[MissionServer, mavlink2.MAVLink_message], None]]] = {
        "MISSION_COUNT": _on_count,
        "MISSION_ITEM_INT": _on_item,
        "MISSION_ITEM": _on_item,
        "MISSION_ACK": _on_ack,
        "MISSION_REQUEST_LIST": _on_request_list,
        "MISSION_REQUEST_INT": _on_request,
        "MISSION_REQUEST": _on_request,
        "MISSION_CLEAR_ALL": _on_clear_all,
    }
