"""Telemetry recording: MAVLink ``.tlog`` files (pymavlink reads them) and CSV tracks.

A ``.tlog`` is what QGroundControl and MAVProxy write: for every message an
8-byte big-endian timestamp (microseconds since the Unix epoch) followed by
the raw MAVLink packet. :class:`TlogRecorder` receives every message each
vehicle sends through MAVSDK's ``mavlink_direct`` subscription (MAVSDK has no
raw-byte tap per connection; its messages come as name + JSON fields) and
re-encodes them with pymavlink's codec under the vehicle's own system and
component ids, so ``pymavlink.mavutil.mavlink_connection(path)`` reads the
file like any other tlog. Messages pymavlink's ``common`` dialect does not
know are counted in :attr:`TlogStats.unknown`, never dropped silently. Only
what the vehicles send is recorded (the GCS's own setpoints are in the
flight result's statistics).

:func:`tracks_from_tlog` rebuilds the flown tracks (:class:`mavlink.tracks.FlownTrack`, whose
CSV is :func:`mavlink.tracks.write_tracks_csv`) from a ``.tlog`` alone (GPS_GLOBAL_ORIGIN,
LOCAL_POSITION_NED and, for the heading, ATTITUDE per system id).
"""

from __future__ import annotations

import json
import math
import struct
import threading
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav

from mavlink.errors import LinkError
from mavlink.tracks import FlownTrack, track_from_rows, vehicle_instants
from planner.frames import GeodeticPoint

if TYPE_CHECKING:
    from mavlink.link.fleet import Fleet


@dataclass(frozen=True, slots=True)
class TlogStats:
    """What a recording holds.

    Attributes:
        path: the file.
        messages: records written.
        by_type: records per message name.
        unknown: messages not encodable with pymavlink's common dialect, by name.
    """

    path: Path
    messages: int
    by_type: dict[str, int]
    unknown: dict[str, int]


class TlogRecorder:
    """Record every message the fleet's vehicles send into one ``.tlog``.

    Use as a context manager around a flight::

        with TlogRecorder(fleet, "flight.tlog") as rec:
            result = await fly_offboard(...)
        print(rec.stats.messages)

    Callbacks run on MAVSDK's thread; writes are serialised by a lock.
    """

    def __init__(self, fleet: Fleet, path: str | Path) -> None:
        self.fleet = fleet
        self.path = Path(path)
        self._lock = threading.Lock()
        self._file: Any = None
        self._codecs: dict[tuple[int, int], mav.MAVLink] = {}
        self._by_type: Counter[str] = Counter()
        self._unknown: Counter[str] = Counter()
        self._handles: list[tuple[Any, Any]] = []
        self.stats: TlogStats | None = None

    def start(self) -> None:
        """Open the file and subscribe to every vehicle's messages."""
        try:
            self._file = self.path.open("wb")
        except OSError as exc:
            raise LinkError(
                f"cannot write telemetry log {self.path}: {exc.strerror or exc}"
            ) from None
        for v in self.fleet.vehicles:
            self._handles.append((v, v.direct.subscribe_message("", self._on_message)))

    def _codec(self, sysid: int, compid: int) -> mav.MAVLink:
        codec = self._codecs.get((sysid, compid))
        if codec is None:
            codec = mav.MAVLink(None, srcSystem=sysid, srcComponent=compid)
            codec.robust_parsing = True
            self._codecs[(sysid, compid)] = codec
        return codec

    def _on_message(self, msg: Any, _ud: Any) -> None:
        clock = self.fleet.clock  # UTC on the flight's clock (a dry run's is simulated)
        t_us = int((clock.monotonic() + clock.unix_offset()) * 1e6)
        fields = json.loads(msg.fields_json)
        msg_id = fields.pop("message_id", None)
        fields.pop("message_name", None)
        cls = mav.mavlink_map.get(msg_id) if msg_id is not None else None
        with self._lock:
            if self._file is None:
                return
            if cls is None:
                self._unknown[msg.message_name] += 1
                return
            try:
                args = [_field_value(fields[name]) for name in cls.fieldnames]
                packet = cls(*args).pack(self._codec(msg.system_id, msg.component_id))
            except (KeyError, TypeError, ValueError, struct.error):
                self._unknown[msg.message_name] += 1
                return
            self._file.write(struct.pack(">Q", t_us) + packet)
            self._by_type[msg.message_name] += 1

    def stop(self) -> TlogStats:
        """Unsubscribe, close the file and return its :class:`TlogStats`."""
        for v, h in self._handles:
            v.direct.unsubscribe_message(h)
        self._handles = []
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None
        self.stats = TlogStats(
            path=self.path,
            messages=sum(self._by_type.values()),
            by_type=dict(self._by_type),
            unknown=dict(self._unknown),
        )
        return self.stats

    def __enter__(self) -> TlogRecorder:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _field_value(value: Any) -> Any:
    """A JSON field as pymavlink's constructor wants it (char arrays as bytes)."""
    if isinstance(value, str):
        return value.encode("utf-8")
    return value


def tracks_from_tlog(
    path: str | Path,
    names_by_sysid: Mapping[int, str],
    mission_origin: GeodeticPoint,
    t0_unix_s: float,
) -> dict[str, FlownTrack]:
    """Flown tracks from a ``.tlog`` read with pymavlink.

    Each vehicle's local frame origin is the last GPS_GLOBAL_ORIGIN it sent
    before its first LOCAL_POSITION_NED. Each position sample carries the latest
    ATTITUDE.yaw the autopilot sent before it (as the live recording does,
    :func:`mavlink.tracks.track_from_rows`); a log without ATTITUDE gives tracks without a
    heading. Each sample's instant is when the vehicle took it, as in the live track: its
    ``time_boot_ms`` carried onto the log's receipt times by the fastest delivery around it
    (:func:`mavlink.tracks.vehicle_instants`), so a busy recorder's latency is not read as
    the vehicle's lag.

    Args:
        path: the ``.tlog``.
        names_by_sysid: vehicle name per system id.
        mission_origin: origin of the mission frame.
        t0_unix_s: Unix time of the plan's start (``t_s = 0``).

    Raises:
        LinkError: a vehicle has positions but never sent its origin.
    """
    # mavlogfile, not mavlink_connection: for a .tlog the latter picks pymavlink's
    # memory-mapped reader, which raises AttributeError on a corrupted file.
    log = mavutil.mavlogfile(str(path), robust_parsing=True)
    origins: dict[int, GeodeticPoint] = {}
    rows: dict[int, list[list[float]]] = {s: [] for s in names_by_sysid}
    yaw_ned: dict[int, float] = dict.fromkeys(names_by_sysid, math.nan)
    while True:
        m = log.recv_match(type=["GPS_GLOBAL_ORIGIN", "LOCAL_POSITION_NED", "ATTITUDE"])
        if m is None:
            break
        sid = m.get_srcSystem()
        if sid not in rows:
            continue
        kind = m.get_type()
        if kind == "GPS_GLOBAL_ORIGIN":
            origins[sid] = GeodeticPoint(m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3)
        elif kind == "ATTITUDE":
            if m.get_srcComponent() == 1 and math.isfinite(m.yaw):
                yaw_ned[sid] = float(m.yaw)
        else:
            t = m._timestamp - t0_unix_s
            rows[sid].append(
                [t, m.x, m.y, m.z, m.vx, m.vy, m.vz, yaw_ned[sid], 1e-3 * m.time_boot_ms]
            )
    out = {}
    for sid, data in rows.items():
        name = names_by_sysid[sid]
        if not data:
            continue
        if sid not in origins:
            raise LinkError(f"{path}: no GPS_GLOBAL_ORIGIN from system {sid}", vehicle=name)
        a = np.asarray(data)
        a[:, 0] = vehicle_instants(a[:, 0], a[:, 8])
        out[name] = track_from_rows(name, a[:, :8], 0.0, mission_origin, origins[sid])
    return out
