"""Flown tracks: what each vehicle reported during a flight, in the mission frame, and their CSV.

The one track type of the project (:class:`FlownTrack`): the flight records it
(:mod:`mavlink.offboard`, :mod:`gcs.flight`), a ``.tlog`` rebuilds it
(:func:`mavlink.tlog.tracks_from_tlog`), a telemetry file is read into it
(:func:`gcs.telemetry.load_telemetry`, the one reader of :func:`write_tracks_csv`'s files).
A module of its own, numpy and the STL engine's window filter only, so that reading flown
data never loads pymavlink.

A track may carry the vehicle's heading (``yaw_enu_rad``: the mission frame's ENU yaw, 0 =
east, counter-clockwise, from ATTITUDE.yaw), which ``face(d, target)`` reads as the fourth
column of a vehicle's signal (:meth:`FlownTrack.signal`). Without it (a user's position-only
file, an old flight CSV) a spec that reads the heading cannot be judged on the track, and
:meth:`FlownTrack.yaw` says so (:class:`MissingHeadingError`) instead of assuming a heading.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mavlink.errors import LinkError, MissingHeadingError
from planner.frames import ned_to_enu, ned_vector_to_enu, yaw_ned_to_enu
from planner.stl.exact import window_extreme

if TYPE_CHECKING:
    from planner.frames import GeodeticPoint

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
    "yaw_enu_rad",
)

#: What a track without a heading says (the vehicle is named by the error).
NO_HEADING = "the telemetry has no heading (no yaw_enu_rad or yaw column, no ATTITUDE)"


def wrap_pi(angle_rad: np.ndarray) -> np.ndarray:
    """Angles wrapped to ``(-pi, pi]``."""
    return np.pi - np.mod(np.pi - np.asarray(angle_rad, dtype=float), 2.0 * np.pi)


@dataclass(frozen=True, slots=True, eq=False)
class FlownTrack:
    """What one vehicle reported during the flight, in the mission frame.

    Attributes:
        name: vehicle name.
        t_s: ``(k,)`` receive times, seconds from the shared start.
        pos_enu_m: ``(k, 3)`` mission-frame ENU positions.
        vel_enu_m_s: ``(k, 3)`` mission-frame ENU velocities (``None``: not recorded, as in a
            user's telemetry file).
        pos_ned_m: ``(k, 3)`` the raw LOCAL_POSITION_NED positions (``None``: not recorded).
        yaw_enu_rad: ``(k,)`` the heading at each sample, mission-frame ENU yaw in radians
            (0 = east, counter-clockwise), NaN where it was not known yet; ``None``: no
            heading at all (a position-only file).
    """

    name: str
    t_s: np.ndarray
    pos_enu_m: np.ndarray
    vel_enu_m_s: np.ndarray | None = None
    pos_ned_m: np.ndarray | None = None
    yaw_enu_rad: np.ndarray | None = None

    @property
    def heading_t_s(self) -> np.ndarray:
        """``(j,)`` the times of the samples whose heading is known (empty: none)."""
        if self.yaw_enu_rad is None:
            return np.zeros(0)
        return np.asarray(self.t_s[np.isfinite(self.yaw_enu_rad)], dtype=float)

    @property
    def has_heading(self) -> bool:
        """Whether any sample carries the heading."""
        return self.heading_t_s.size > 0

    def position(self, t_s: np.ndarray) -> np.ndarray:
        """Positions ``(m, 3)`` at times ``t_s`` ``(m,)``: linear between samples, held outside."""
        return np.column_stack([np.interp(t_s, self.t_s, self.pos_enu_m[:, a]) for a in range(3)])

    def yaw(self, t_s: np.ndarray) -> np.ndarray:
        """Headings ``(m,)`` (ENU rad, in ``(-pi, pi]``) at times ``t_s`` ``(m,)``: between the
        samples whose heading is known, linear along the shorter turn (unwrapped, interpolated,
        wrapped again); held outside them.

        Raises:
            MissingHeadingError: the track has no heading (names the vehicle).
        """
        known = self.heading_t_s
        if known.size == 0:
            raise MissingHeadingError(NO_HEADING, vehicle=self.name)
        assert self.yaw_enu_rad is not None
        y = np.unwrap(self.yaw_enu_rad[np.isfinite(self.yaw_enu_rad)])
        return wrap_pi(np.interp(t_s, known, y))

    def signal(self, t_s: np.ndarray, *, heading: bool = False) -> np.ndarray:
        """The vehicle's STL signal at times ``t_s`` ``(m,)``: positions ``(m, 3)``, with
        ``heading`` the ENU yaw as a fourth column ``(m, 4)`` (what ``face`` reads).

        Raises:
            MissingHeadingError: ``heading`` asked of a track without one.
        """
        pos = self.position(t_s)
        return np.column_stack([pos, self.yaw(t_s)]) if heading else pos

    def resample(self, dt_s: float, t_end_s: float, *, heading: bool = False) -> np.ndarray:
        """The signal (:meth:`signal`: ``(n, 3)``, with ``heading`` ``(n, 4)``) at
        ``t = 0, dt, ..., t_end`` by linear interpolation.

        Raises:
            LinkError: the track does not cover ``[0, t_end]`` (names the gap).
            MissingHeadingError: ``heading`` asked of a track without one.
        """
        n = math.floor(t_end_s / dt_s + 1e-9) + 1
        t = np.arange(n) * dt_s
        covers = [("flown track", self.t_s)]
        if heading:
            if not self.has_heading:
                raise MissingHeadingError(NO_HEADING, vehicle=self.name)
            covers.append(("flown heading", self.heading_t_s))
        for what, ts in covers:
            if ts.size < 2 or ts[0] > dt_s or ts[-1] < t[-1] - dt_s:
                covered = f"{ts[0]:.2f}..{ts[-1]:.2f} s" if ts.size else "no samples"
                raise LinkError(
                    f"{what} covers {covered}, need 0..{t[-1]:.2f} s", vehicle=self.name
                )
        return self.signal(t, heading=heading)


#: The span of samples (s) among which the fastest delivery sets a sample's clock offset
#: (:func:`vehicle_instants`): long enough to hold a quick delivery on a busy link, short
#: enough that two clocks' rates (a few ppm apart) do not part within it.
INSTANT_WINDOW_S = 5.0

#: ``time_boot_ms`` is a uint32 of milliseconds: it wraps after 2**32 ms (49.7 days).
_BOOT_WRAP_S = 2.0**32 * 1e-3


def vehicle_instants(
    t_recv_s: np.ndarray, t_boot_s: np.ndarray, window_s: float = INSTANT_WINDOW_S
) -> np.ndarray:
    """When each sample was taken, on the receiver's clock: the vehicle's own time
    (``time_boot_ms``, s) plus the smallest ``t_recv - t_boot`` among the samples received
    within ``window_s / 2`` of it.

    A sample's receipt time is its instant plus the link's latency, and the latency varies:
    MAVSDK hands telemetry over on its own thread, and on a busy machine (or link) a sample
    waits. The fastest delivery around a sample bounds the clocks' offset best (the
    minimum-delay filter of clock synchronisation: NTP's, Mills, RFC 5905), so only that
    latency, which no sample escapes, is left in the instants. A vehicle clock that jumps
    back (a reboot) keeps the receipt times.

    Args:
        t_recv_s: receipt times, in order of receipt.
        t_boot_s: the same samples' ``time_boot_ms`` in seconds.
        window_s: the span of samples whose fastest delivery counts.
    """
    t_recv = np.asarray(t_recv_s, dtype=float)
    t_boot = np.asarray(t_boot_s, dtype=float).copy()
    n = t_recv.size
    if n < 2:
        return t_recv.copy()
    step = np.diff(t_boot)
    t_boot[1:] += _BOOT_WRAP_S * np.cumsum(step < -0.5 * _BOOT_WRAP_S)
    if np.any(np.diff(t_boot) < -1.0):  # a reboot: the vehicle's time means nothing here
        return t_recv.copy()
    offset = t_recv - t_boot
    period = float(np.median(np.diff(t_recv)))
    half = min(n, round(0.5 * window_s / period)) if period > 0 else n
    padded = np.pad(offset, (half, half), mode="edge")
    return t_boot + window_extreme(padded, 0, 2 * half, minimum=True)


def track_from_rows(
    name: str,
    rows: np.ndarray,
    t0_s: float,
    mission_origin: GeodeticPoint,
    vehicle_origin: GeodeticPoint,
) -> FlownTrack:
    """A flown track in the mission frame from recorded rows
    ``(t_s, n, e, d, vn, ve, vd[, yaw_ned])`` (:meth:`mavlink.link.vehicle.Vehicle.stop_track`) of
    a vehicle whose local NED origin is ``vehicle_origin``: times from ``t0_s``, positions and
    velocities into mission ENU, the NED yaw (rad, clockwise from north; NaN where unknown)
    into the mission frame's ENU yaw by the same rotation (:func:`planner.frames.yaw_ned_to_enu`).
    Without a yaw column, or with none known, the track has no heading.
    """

    rows = np.asarray(rows, dtype=float)
    if rows.shape[0] == 0:
        z = np.zeros((0, 3))
        return FlownTrack(name, np.zeros(0), z, z.copy(), z.copy())
    ned = rows[:, 1:4]
    yaw = None
    if rows.shape[1] > 7 and np.isfinite(rows[:, 7]).any():
        yaw = np.asarray(yaw_ned_to_enu(rows[:, 7], mission_origin, vehicle_origin), dtype=float)
    return FlownTrack(
        name=name,
        t_s=rows[:, 0] - t0_s,
        pos_enu_m=ned_to_enu(ned, mission_origin, vehicle_origin),
        vel_enu_m_s=ned_vector_to_enu(rows[:, 4:7], mission_origin, vehicle_origin),
        pos_ned_m=ned,
        yaw_enu_rad=yaw,
    )


def write_tracks_csv(path: str | Path, tracks: Mapping[str, FlownTrack]) -> Path:
    """Write flown tracks as CSV (columns :data:`CSV_COLUMNS`, times from the plan's start);
    ``gcs verify --telemetry`` and ``gcs plot --telemetry`` read it (:mod:`gcs.telemetry`).
    The ``yaw_enu_rad`` field is empty where the heading is unknown.

    Raises:
        LinkError: a track without its velocities or raw positions (not a flown track).
    """
    p = Path(path)
    bare = [n for n, tr in tracks.items() if tr.vel_enu_m_s is None or tr.pos_ned_m is None]
    if bare:
        raise LinkError(f"{p}: tracks without velocities or raw positions: {', '.join(bare)}")
    with p.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(CSV_COLUMNS)
        for name, tr in tracks.items():
            assert tr.vel_enu_m_s is not None and tr.pos_ned_m is not None
            yaw = np.full(tr.t_s.size, np.nan) if tr.yaw_enu_rad is None else tr.yaw_enu_rad
            for k in range(tr.t_s.size):
                w.writerow(
                    [
                        name,
                        repr(float(tr.t_s[k])),
                        *(repr(float(x)) for x in tr.pos_enu_m[k]),
                        *(repr(float(x)) for x in tr.vel_enu_m_s[k]),
                        *(repr(float(x)) for x in tr.pos_ned_m[k]),
                        repr(float(yaw[k])) if math.isfinite(yaw[k]) else "",
                    ]
                )
    return p
