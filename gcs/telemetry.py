"""Flown telemetry for the plan's pictures and checks: each vehicle's recorded track
(:class:`mavlink.tracks.FlownTrack`) by vehicle name (:class:`Telemetry`), read by
:func:`load_telemetry`, the one reader of flown-track files (the flight's ``flight.csv``
among them).

A room of its own because reading a file is not drawing: ``gcs plot --telemetry`` and
``gcs verify --telemetry`` both read flown data here, and :mod:`gcs.plot.traces` and
:mod:`gcs.plot.figure` only consume what it returns.

Telemetry (``--telemetry``): a CSV file with a header line and at least the columns
``t,vehicle,x,y,z``: time in seconds from the plan's start, the vehicle name of the plan,
position in the mission ENU frame in metres (extra columns are ignored); the link's track CSV
(:func:`mavlink.tracks.write_tracks_csv`: ``vehicle,t_s,x_enu_m,y_enu_m,z_enu_m,...``) is read
alike. An optional column ``yaw`` (or the link's ``yaw_enu_rad``) holds the heading, the
mission frame's ENU yaw in radians (0 = east, counter-clockwise), empty where unknown: what a
spec with ``face(d, target)`` reads; a file without it (an older flight's CSV among them) loads
with no heading, and judging such a spec on it says that the telemetry has no heading. A
``.tlog`` goes through :func:`mavlink.tlog.tracks_from_tlog` (the heading from its ATTITUDE
messages); since a tlog does not record when the plan started, its Unix start time must be
given (``--t0``).

Errors::

    gcs.errors.InputFileError        unreadable/malformed telemetry (file, line, column), no
                                     rows, a .tlog without its start time
    mavlink.errors.LinkError         a .tlog the link's reader rejects (no origin message)
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gcs.errors import InputFileError
from mavlink.link.camera import IMAGE_COLUMNS, CapturedImage
from mavlink.tlog import tracks_from_tlog
from mavlink.tracks import FlownTrack
from planner.strict_read import NotTextError, read_text

if TYPE_CHECKING:
    from mavlink.link.camera import CapturedImage
    from planner.planfile import Plan

__all__ = ["TELEMETRY_COLUMNS", "Telemetry", "load_images", "load_telemetry"]

#: Columns a telemetry CSV must have (more are allowed).
TELEMETRY_COLUMNS = ("t", "vehicle", "x", "y", "z")

#: Accepted names of the optional heading column (ENU yaw, rad; empty where unknown).
_YAW_ALIASES = ("yaw", "yaw_enu_rad")

#: Accepted names of those columns: ours, and the link's track CSV (:mod:`mavlink.tracks`).
_TELEMETRY_ALIASES: dict[str, tuple[str, ...]] = {
    "t": ("t", "t_s"),
    "vehicle": ("vehicle",),
    "x": ("x", "x_enu_m"),
    "y": ("y", "y_enu_m"),
    "z": ("z", "z_enu_m"),
}


@dataclass(frozen=True, slots=True)
class Telemetry:
    """Flown paths by vehicle name, read from ``source``."""

    source: str
    vehicles: Mapping[str, FlownTrack]


def _column_map(header: list[str]) -> dict[str, int] | None:
    """Index of t, vehicle, x, y, z in either CSV layout (None if a column is missing)."""
    out = {}
    for key, names in _TELEMETRY_ALIASES.items():
        idx = next((header.index(n) for n in names if n in header), None)
        if idx is None:
            return None
        out[key] = idx
    return out


def load_telemetry(
    path: str | Path, plan: Plan | None = None, t0_unix_s: float | None = None
) -> Telemetry:
    """Read flown telemetry (module docstring); CSV rows may come in any order.

    Args:
        path: a CSV file (either layout) or a ``.tlog``.
        plan: the plan flown (needed for a ``.tlog``: vehicle names by system id, origin).
        t0_unix_s: Unix time of the plan's start (needed for a ``.tlog``, which does not
            record it).

    Raises:
        InputFileError: missing file, missing columns, a bad number (names file, line, column),
            no rows, a ``.tlog`` without ``t0_unix_s``.
        mavlink.errors.LinkError: a ``.tlog`` the link's reader rejects.
    """
    p = Path(path)
    src = str(p)
    if p.suffix.lower() == ".tlog":
        return _load_tlog(p, plan, t0_unix_s)
    header, reader = _csv(p, "t,vehicle,x,y,z")
    col = _column_map(header)
    if col is None:
        missing = [k for k, names in _TELEMETRY_ALIASES.items() if not set(names) & set(header)]
        raise InputFileError(
            f"{src}: line 1: missing column(s) {', '.join(missing)} "
            f"(need {','.join(TELEMETRY_COLUMNS)}, or the link's vehicle,t_s,x_enu_m,...)"
        )
    yaw_col = next((header.index(n) for n in _YAW_ALIASES if n in header), None)
    rows: dict[str, list[tuple[float, float, float, float, float]]] = {}
    for lineno, row in _rows(src, header, reader):
        vals = [_number_field(src, lineno, header, row, col[key]) for key in ("t", "x", "y", "z")]
        name = _vehicle_field(src, lineno, row, col["vehicle"])
        yaw = math.nan if yaw_col is None else _yaw_field(src, lineno, header, row, yaw_col)
        rows.setdefault(name, []).append((vals[0], vals[1], vals[2], vals[3], yaw))
    if not rows:
        raise InputFileError(f"{src}: no telemetry rows after the header")
    vehicles: dict[str, FlownTrack] = {}
    for name, r in rows.items():
        a = np.asarray(r, dtype=float)
        a = a[np.argsort(a[:, 0], kind="stable")]
        heading = a[:, 4] if np.isfinite(a[:, 4]).any() else None
        vehicles[name] = FlownTrack(name, t_s=a[:, 0], pos_enu_m=a[:, 1:4], yaw_enu_rad=heading)
    return Telemetry(source=src, vehicles=vehicles)


def _csv(p: Path, expected: str) -> tuple[list[str], Iterator[list[str]]]:
    """The header (stripped) and the remaining rows of a CSV file (InputFileError naming the
    file when it cannot be read, is not text, or is empty: ``expected`` names its header)."""
    src = str(p)
    try:
        text = read_text(p)
    except OSError as exc:
        raise InputFileError(f"{src}: cannot read: {exc.strerror or exc}") from None
    except NotTextError as exc:
        raise InputFileError(f"{src}: {exc} (expected CSV text)") from None
    reader = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise InputFileError(f"{src}: empty file (expected a header {expected})") from None
    except csv.Error as exc:
        raise InputFileError(f"{src}: line 1: not CSV ({exc})") from None
    return header, _checked(src, reader)


def _checked(src: str, reader: Any) -> Iterator[list[str]]:
    """The reader's rows, a CSV syntax error (a stray carriage return, say) as one line."""
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise InputFileError(f"{src}: line {reader.line_num}: not CSV ({exc})") from None
        yield row


def _rows(
    src: str, header: list[str], reader: Iterator[list[str]]
) -> Iterator[tuple[int, list[str]]]:
    """(line number, fields) of each non-blank row, each with the header's fields at least."""
    for lineno, row in enumerate(reader, start=2):
        if not row or all(not f.strip() for f in row):
            continue
        if len(row) < len(header):
            raise InputFileError(
                f"{src}: line {lineno}: {len(row)} fields, the header has {len(header)}"
            )
        yield lineno, row


def _vehicle_field(src: str, lineno: int, row: list[str], col: int) -> str:
    name = row[col].strip()
    if not name:
        raise InputFileError(f"{src}: line {lineno}: column vehicle: empty")
    return name


def load_images(path: str | Path, plan: Plan | None = None) -> dict[str, list[CapturedImage]]:
    """Read a flight's image log (:func:`mavlink.link.camera.write_images_csv`): the pictures by
    vehicle, in the file's order.

    Raises:
        InputFileError: unreadable file, a missing column, a bad value (file, line, column),
            a vehicle that is not in ``plan``.
    """

    p = Path(path)
    src = str(p)
    header, reader = _csv(p, ",".join(IMAGE_COLUMNS))
    missing = [c for c in IMAGE_COLUMNS if c not in header]
    if missing:
        raise InputFileError(f"{src}: line 1: missing column(s) {', '.join(missing)}")
    col = {c: header.index(c) for c in IMAGE_COLUMNS}
    known = None if plan is None else {v.name for v in plan.vehicles}
    out: dict[str, list[CapturedImage]] = {}
    for lineno, row in _rows(src, header, reader):

        def num(name: str, row: list[str] = row, lineno: int = lineno) -> float:
            return _number_field(src, lineno, header, row, col[name])

        vehicle = _vehicle_field(src, lineno, row, col["vehicle"])
        if known is not None and vehicle not in known:
            raise InputFileError(
                f"{src}: vehicle {vehicle!r} is not in the plan ({', '.join(sorted(known))})"
            )
        out.setdefault(vehicle, []).append(
            CapturedImage(
                vehicle=vehicle,
                t_s=num("t_s"),
                lat_deg=num("lat_deg"),
                lon_deg=num("lon_deg"),
                alt_amsl_m=num("alt_amsl_m"),
                rel_alt_m=num("rel_alt_m"),
                q_wxyz=(num("qw"), num("qx"), num("qy"), num("qz")),
                index=int(num("index")),
                ok=bool(int(num("ok"))),
                component=int(num("component")),
                file_url=row[col["file_url"]].strip(),
            )
        )
    return out


def _yaw_field(src: str, lineno: int, header: list[str], row: list[str], col: int) -> float:
    """The heading of one row (NaN: the field is empty, the heading unknown there)."""
    if not row[col].strip():
        return math.nan
    return _number_field(src, lineno, header, row, col, " (empty where unknown)")


def _number_field(
    src: str, lineno: int, header: list[str], row: list[str], col: int, finite_hint: str = ""
) -> float:
    """A finite number from one field, or one line naming the file, line and column."""
    field = row[col].strip()
    try:
        v = float(field)
    except ValueError:
        raise InputFileError(
            f"{src}: line {lineno}: column {header[col]}: not a number: {field!r}"
        ) from None
    if not math.isfinite(v):
        raise InputFileError(
            f"{src}: line {lineno}: column {header[col]}: must be finite{finite_hint}"
        )
    return v


def _load_tlog(p: Path, plan: Plan | None, t0_unix_s: float | None) -> Telemetry:
    """Tracks from a ``.tlog`` through the link's reader (:func:`mavlink.tlog.tracks_from_tlog`)."""
    if plan is None or t0_unix_s is None:
        raise InputFileError(
            f"{p}: a .tlog does not record when the plan started: give --t0 UNIX_SECONDS "
            "(or use the flight's CSV track file)"
        )
    if not p.is_file():
        raise InputFileError(f"{p}: cannot read: no such file")

    tracks = tracks_from_tlog(
        p, {v.sysid: v.name for v in plan.vehicles}, plan.origin, float(t0_unix_s)
    )
    if not tracks:
        raise InputFileError(f"{p}: no LOCAL_POSITION_NED from the plan's vehicles")
    return Telemetry(source=str(p), vehicles=tracks)
