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

CSV (:func:`write_tracks_csv`, :func:`read_tracks_csv`): one row per
LOCAL_POSITION_NED sample of each vehicle with mission-frame ENU position and
velocity, the input of ``gcs verify`` on flown data. :func:`tracks_from_tlog`
rebuilds the same tracks from a ``.tlog`` alone (GPS_GLOBAL_ORIGIN and
LOCAL_POSITION_NED per system id).
"""

from __future__ import annotations

import csv
import json
import math
import struct
import threading
import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav

from mavlink.errors import LinkError
from planner.frames import GeodeticPoint, ned_to_enu, ned_vector_to_enu

if TYPE_CHECKING:
    from mavlink.fleet import Fleet

CSV_COLUMNS = (
    "vehicle",
    "t_s",
    "x_enu_m",
    "y_enu_m",
    "z_enu_m",
    "vx_enu_m_s",
    "vy_enu_m_s",
    "vz_enu_m_s",
    "north_m",
    "east_m",
    "down_m",
)


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
        t_us = int(time.time() * 1e6)
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


@dataclass(frozen=True, slots=True, eq=False)
class FlownTrack:
    """What one vehicle reported during the flight, in the mission frame.

    Attributes:
        name: vehicle name.
        t_s: ``(k,)`` receive times, seconds from the shared start.
        pos_enu_m: ``(k, 3)`` mission-frame ENU positions.
        vel_enu_m_s: ``(k, 3)`` mission-frame ENU velocities.
        pos_ned_m: ``(k, 3)`` the raw LOCAL_POSITION_NED positions.
    """

    name: str
    t_s: np.ndarray
    pos_enu_m: np.ndarray
    vel_enu_m_s: np.ndarray
    pos_ned_m: np.ndarray

    def resample(self, dt_s: float, t_end_s: float) -> np.ndarray:
        """Positions ``(n, 3)`` at ``t = 0, dt, ..., t_end`` by linear interpolation.

        Raises:
            LinkError: the track does not cover ``[0, t_end]`` (names the gap).
        """
        n = math.floor(t_end_s / dt_s + 1e-9) + 1
        t = np.arange(n) * dt_s
        if self.t_s.size < 2 or self.t_s[0] > dt_s or self.t_s[-1] < t[-1] - dt_s:
            covered = f"{self.t_s[0]:.2f}..{self.t_s[-1]:.2f} s" if self.t_s.size else "no samples"
            raise LinkError(
                f"flown track covers {covered}, need 0..{t[-1]:.2f} s", vehicle=self.name
            )
        return np.column_stack([np.interp(t, self.t_s, self.pos_enu_m[:, a]) for a in range(3)])


# --------------------------------------------------------------------------
# CSV tracks
# --------------------------------------------------------------------------


def write_tracks_csv(path: str | Path, tracks: Mapping[str, FlownTrack]) -> Path:
    """Write flown tracks as CSV (columns :data:`CSV_COLUMNS`, times from the plan's start)."""
    p = Path(path)
    with p.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(CSV_COLUMNS)
        for name, tr in tracks.items():
            for k in range(tr.t_s.size):
                w.writerow(
                    [
                        name,
                        repr(float(tr.t_s[k])),
                        *(repr(float(x)) for x in tr.pos_enu_m[k]),
                        *(repr(float(x)) for x in tr.vel_enu_m_s[k]),
                        *(repr(float(x)) for x in tr.pos_ned_m[k]),
                    ]
                )
    return p


def read_tracks_csv(path: str | Path) -> dict[str, FlownTrack]:
    """Read :func:`write_tracks_csv` output back.

    Raises:
        LinkError: missing columns or a malformed number (naming the line).
    """
    p = Path(path)
    rows: dict[str, list[list[float]]] = {}
    try:
        with p.open(newline="", encoding="utf-8") as f:
            reader = csv.reader(f)
            header = next(reader, None)
            if header is None or tuple(header) != CSV_COLUMNS:
                raise LinkError(f"{p}: line 1: expected the columns {', '.join(CSV_COLUMNS)}")
            for line, row in enumerate(reader, start=2):
                if len(row) != len(CSV_COLUMNS):
                    raise LinkError(
                        f"{p}: line {line}: expected {len(CSV_COLUMNS)} fields, got {len(row)}"
                    )
                try:
                    rows.setdefault(row[0], []).append([float(x) for x in row[1:]])
                except ValueError:
                    raise LinkError(f"{p}: line {line}: malformed number") from None
    except OSError as exc:
        raise LinkError(f"cannot read {p}: {exc.strerror or exc}") from None
    out = {}
    for name, data in rows.items():
        a = np.asarray(data)
        out[name] = FlownTrack(name, a[:, 0], a[:, 1:4], a[:, 4:7], a[:, 7:10])
    return out


def tracks_from_tlog(
    path: str | Path,
    names_by_sysid: Mapping[int, str],
    mission_origin: GeodeticPoint,
    t0_unix_s: float,
) -> dict[str, FlownTrack]:
    """Flown tracks from a ``.tlog`` read with pymavlink.

    Each vehicle's local frame origin is the last GPS_GLOBAL_ORIGIN it sent
    before its first LOCAL_POSITION_NED.

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
    while True:
        m = log.recv_match(type=["GPS_GLOBAL_ORIGIN", "LOCAL_POSITION_NED"])
        if m is None:
            break
        sid = m.get_srcSystem()
        if sid not in rows:
            continue
        if m.get_type() == "GPS_GLOBAL_ORIGIN":
            origins[sid] = GeodeticPoint(m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3)
        else:
            rows[sid].append([m._timestamp - t0_unix_s, m.x, m.y, m.z, m.vx, m.vy, m.vz])
    out = {}
    for sid, data in rows.items():
        name = names_by_sysid[sid]
        if not data:
            continue
        if sid not in origins:
            raise LinkError(f"{path}: no GPS_GLOBAL_ORIGIN from system {sid}", vehicle=name)
        a = np.asarray(data)
        ned = a[:, 1:4]
        out[name] = FlownTrack(
            name,
            a[:, 0],
            ned_to_enu(ned, mission_origin, origins[sid]),
            ned_vector_to_enu(a[:, 4:7], mission_origin, origins[sid]),
            ned,
        )
    return out
