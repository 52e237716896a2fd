"""Flown tracks: what each vehicle reported during a flight, in the mission frame, and their CSV.

The one track type of the project (:class:`FlownTrack`): the flight records it
(:mod:`mavlink.offboard`, :mod:`gcs.flight`), a ``.tlog`` rebuilds it
(:func:`mavlink.tlog.tracks_from_tlog`), a telemetry file is read into it
(:func:`gcs.telemetry.load_telemetry`, the one reader of :func:`write_tracks_csv`'s files).
A module of its own, numpy only, so that reading flown data never loads pymavlink.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mavlink.errors import LinkError

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
    """

    name: str
    t_s: np.ndarray
    pos_enu_m: np.ndarray
    vel_enu_m_s: np.ndarray | None = None
    pos_ned_m: np.ndarray | None = None

    def position(self, t_s: np.ndarray) -> np.ndarray:
        """Positions ``(m, 3)`` at times ``t_s`` ``(m,)``: linear between samples, held outside."""
        return np.column_stack([np.interp(t_s, self.t_s, self.pos_enu_m[:, a]) for a in range(3)])

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


def write_tracks_csv(path: str | Path, tracks: Mapping[str, FlownTrack]) -> Path:
    """Write flown tracks as CSV (columns :data:`CSV_COLUMNS`, times from the plan's start);
    ``gcs verify --telemetry`` and ``gcs plot --telemetry`` read it (:mod:`gcs.telemetry`).

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
