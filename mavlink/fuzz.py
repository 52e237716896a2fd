"""Hostile MAVLink frames for fuzzing the mock vehicle and the GCS's parsing paths.

:class:`FrameFuzzer` draws datagrams from a seeded ``random.Random``, one
:class:`FrameKind` at a time:

* ``RANDOM``: random bytes (0..300), sometimes starting with a MAVLink magic;
* ``VALID_RANDOM``: a well-formed MAVLink 2 frame (correct CRC with the
  message's CRC_EXTRA) of a known message id with a random payload of random
  length (MAVLink 2 truncates trailing zeros, the receiver pads them back);
* ``BAD_CRC``: the same with the checksum corrupted;
* ``TRUNCATED``: a well-formed frame cut short;
* ``OVERSIZED``: a known message id with a payload longer than the message
  (up to 255 bytes, correct CRC), or a datagram of several frames and junk
  longer than any single frame (up to 2 kB);
* ``UNKNOWN_ID``: a well-formed frame of a message id the common dialect does
  not define;
* ``MUTATED``: a valid frame of a message the vehicle acts on, with 1..4
  random bytes changed (the CRC catches nearly all of them);
* ``MAVLINK1``: a MAVLink 1 frame (0xFE) with a random payload, valid CRC;
* ``BOGUS_SIGNED``: a valid frame flagged signed with a random signature;
* ``WRONG_TARGET``: a valid state-changing message (arm, mode change,
  takeoff, parameter set, mission count/clear, setpoints, origin, mission
  current) addressed to another system id than ``own_sysid``.

:func:`decoded_target` tells which frames a receiver must treat as addressed
to it (so a fuzz test can require that nothing else changes its state).
"""

from __future__ import annotations

import random
import struct
from collections.abc import Iterator
from enum import Enum

from pymavlink.dialects.v20 import common as mavlink2
from pymavlink.generator.mavcrc import x25crc

_KNOWN = sorted(mavlink2.mavlink_map)
_CLASSES = mavlink2.mavlink_map


class FrameKind(Enum):
    """The families of hostile frames (see the module docstring)."""

    RANDOM = "random"
    VALID_RANDOM = "valid_random"
    BAD_CRC = "bad_crc"
    TRUNCATED = "truncated"
    OVERSIZED = "oversized"
    UNKNOWN_ID = "unknown_id"
    MUTATED = "mutated"
    MAVLINK1 = "mavlink1"
    BOGUS_SIGNED = "bogus_signed"
    WRONG_TARGET = "wrong_target"


def frame_v2(
    msgid: int,
    payload: bytes,
    *,
    sysid: int = 245,
    compid: int = 190,
    seq: int = 0,
    crc_extra: int | None = None,
    incompat: int = 0,
    signature: bytes = b"",
) -> bytes:
    """A MAVLink 2 frame with a correct checksum (``crc_extra`` defaults to the dialect's).

    ``payload`` is sent as given (at most 255 bytes); the caller decides whether
    trailing zeros are truncated.
    """
    if crc_extra is None:
        crc_extra = _CLASSES[msgid].crc_extra if msgid in _CLASSES else 0
    header = struct.pack(
        "<BBBBBBBHB",
        253,
        len(payload),
        incompat,
        0,
        seq & 0xFF,
        sysid,
        compid,
        msgid & 0xFFFF,
        msgid >> 16,
    )
    crc = x25crc(header[1:] + payload)
    crc.accumulate(bytes([crc_extra]))
    return header + payload + struct.pack("<H", crc.crc) + signature


def frame_v1(msgid: int, payload: bytes, *, sysid: int = 245, compid: int = 190) -> bytes:
    """A MAVLink 1 frame with a correct checksum (message id < 256)."""
    crc_extra = _CLASSES[msgid].crc_extra if msgid in _CLASSES else 0
    header = struct.pack("<BBBBBB", 254, len(payload), 0, sysid, compid, msgid)
    crc = x25crc(header[1:] + payload)
    crc.accumulate(bytes([crc_extra]))
    return header + payload + struct.pack("<H", crc.crc)


def wrong_target_messages(target: int) -> list[mavlink2.MAVLink_message]:
    """Messages that change a vehicle's state when addressed to it, sent to ``target``."""
    m = mavlink2
    nan = float("nan")
    return [
        m.MAVLink_command_long_message(target, 1, m.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                       1, 21196, 0, 0, 0, 0, 0),
        m.MAVLink_command_long_message(target, 1, m.MAV_CMD_DO_SET_MODE, 0, 1, 4, 2, 0, 0, 0, 0),
        m.MAVLink_command_long_message(target, 1, m.MAV_CMD_NAV_TAKEOFF, 0,
                                       0, 0, 0, nan, nan, nan, 500.0),
        m.MAVLink_command_int_message(target, 1, m.MAV_FRAME_GLOBAL_INT, m.MAV_CMD_DO_REPOSITION,
                                      0, 0, -1, 0, 0, 0, 473977000, 85456000, 520.0),
        m.MAVLink_command_long_message(target, 1, m.MAV_CMD_DO_SET_HOME, 0,
                                       0, 0, 0, 0, 47.0, 8.0, 400.0),
        m.MAVLink_param_set_message(target, 1, b"MPC_XY_CRUISE", 1.0, m.MAV_PARAM_TYPE_REAL32),
        m.MAVLink_mission_count_message(target, 1, 3, 0),
        m.MAVLink_mission_clear_all_message(target, 1, 0),
        m.MAVLink_mission_set_current_message(target, 1, 2),
        m.MAVLink_set_position_target_local_ned_message(
            0, target, 1, m.MAV_FRAME_LOCAL_NED, 0, 5.0, 5.0, -5.0, 0, 0, 0, 0, 0, 0, 0, 0),
        m.MAVLink_set_attitude_target_message(0, target, 1, 0, [1, 0, 0, 0], 0, 0, 0, 0.9),
        m.MAVLink_set_gps_global_origin_message(target, 470000000, 80000000, 400000),
    ]  # fmt: skip


class FrameFuzzer:
    """Seeded generator of hostile datagrams for a receiver with system id ``own_sysid``.

    Frames claim to come from system ``src_sysid`` (component 190).
    """

    def __init__(self, seed: int, own_sysid: int = 1, src_sysid: int = 245) -> None:
        self.rng = random.Random(seed)
        self.own_sysid = own_sysid
        self.src_sysid = src_sysid
        self._mav = mavlink2.MAVLink(None, srcSystem=src_sysid, srcComponent=190)
        self._kinds = list(FrameKind)

    def _valid_random(self) -> tuple[int, bytes]:
        rng = self.rng
        msgid = rng.choice(_KNOWN)
        size = _CLASSES[msgid].unpacker.size
        payload = rng.randbytes(rng.randint(1, size))
        return msgid, payload

    def _packed(self, msg: mavlink2.MAVLink_message) -> bytes:
        buf = msg.pack(self._mav)
        self._mav.seq = (self._mav.seq + 1) & 0xFF
        return bytes(buf)

    def _other_target(self) -> int:
        t = self.rng.randint(1, 255)
        return t if t != self.own_sysid else (t % 255) + 1

    def frame(self, kind: FrameKind) -> bytes:
        """One datagram of ``kind``."""
        rng = self.rng
        if kind is FrameKind.RANDOM:
            data = rng.randbytes(rng.randint(0, 300))
            if data and rng.random() < 0.5:
                data = bytes([rng.choice((253, 254))]) + data[1:]
            return data
        if kind is FrameKind.VALID_RANDOM:
            msgid, payload = self._valid_random()
            return frame_v2(msgid, payload, sysid=self.src_sysid, seq=rng.randrange(256))
        if kind is FrameKind.BAD_CRC:
            msgid, payload = self._valid_random()
            f = bytearray(frame_v2(msgid, payload, sysid=self.src_sysid))
            f[-rng.randint(1, 2)] ^= rng.randint(1, 255)
            return bytes(f)
        if kind is FrameKind.TRUNCATED:
            msgid, payload = self._valid_random()
            whole = frame_v2(msgid, payload, sysid=self.src_sysid)
            return bytes(whole[: rng.randint(1, len(whole) - 1)])
        if kind is FrameKind.OVERSIZED:
            if rng.random() < 0.5:
                msgid = rng.choice(_KNOWN)
                size = _CLASSES[msgid].unpacker.size
                return frame_v2(
                    msgid,
                    rng.randbytes(rng.randint(min(size + 1, 255), 255)),
                    sysid=self.src_sysid,
                )
            parts = [self.frame(rng.choice(self._kinds[:7])) for _ in range(rng.randint(4, 12))]
            return b"".join(parts)[:2048]
        if kind is FrameKind.UNKNOWN_ID:
            while (msgid := rng.randrange(1 << 24)) in _CLASSES:
                pass
            return frame_v2(msgid, rng.randbytes(rng.randint(0, 255)), sysid=self.src_sysid)
        if kind is FrameKind.MUTATED:
            msg = rng.choice(wrong_target_messages(self.own_sysid))
            f = bytearray(self._packed(msg))
            for _ in range(rng.randint(1, 4)):
                f[rng.randrange(len(f))] = rng.randrange(256)
            return bytes(f)
        if kind is FrameKind.MAVLINK1:
            msgid = rng.choice([i for i in _KNOWN if i < 256])
            size = _CLASSES[msgid].unpacker.size
            return frame_v1(msgid, rng.randbytes(rng.randint(0, size)), sysid=self.src_sysid)
        if kind is FrameKind.BOGUS_SIGNED:
            msg = rng.choice(wrong_target_messages(self.own_sysid))
            f = bytearray(self._packed(msg))
            f[2] |= 0x01  # incompat flags: signed
            # the CRC covers the flags: recompute it, then append a random signature
            body = bytes(f[:-2])
            crc = x25crc(body[1:])
            crc.accumulate(bytes([msg.crc_extra]))
            return body + struct.pack("<H", crc.crc) + rng.randbytes(13)
        if kind is FrameKind.WRONG_TARGET:
            msg = rng.choice(wrong_target_messages(self._other_target()))
            return self._packed(msg)
        raise ValueError(f"unknown frame kind {kind!r}")

    def frames(self, n: int) -> Iterator[tuple[FrameKind, bytes]]:
        """``n`` datagrams, the kinds drawn uniformly."""
        for _ in range(n):
            kind = self.rng.choice(self._kinds)
            yield kind, self.frame(kind)


def decoded_target(data: bytes, own_sysid: int = 1) -> bool:
    """True if a receiver must treat ``data`` as (possibly) addressed to ``own_sysid``.

    Decodes the datagram with pymavlink as the mock does; a message with a
    ``target_system`` of 0 or ``own_sysid``, or a HEARTBEAT (to everyone), is
    addressed to it; everything else (bad frames, other targets, messages
    without a target) is not.
    """
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    try:
        msgs = parser.parse_buffer(data) or []
    except mavlink2.MAVError:
        return False
    for msg in msgs:
        if msg.get_type() == "BAD_DATA":
            continue
        target = getattr(msg, "target_system", None)
        if target in (0, own_sysid) or msg.get_type() == "HEARTBEAT":
            return True
    return False
