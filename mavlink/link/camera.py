"""The vehicles' cameras as the ground station sees them: the pictures taken, and the optics.

A MAVLink camera (component ``MAV_COMP_ID_CAMERA`` 100.. of the vehicle's system, behind
PX4's routing) reports each picture with ``CAMERA_IMAGE_CAPTURED``: where the vehicle was
(lat, lon, alt AMSL, as the autopilot estimated it) and the camera's attitude in the NED
earth frame (``q``: the vehicle's heading and the gimbal's angles).  :class:`CapturedImage` is
one such report with the time it was received (plan time: seconds from the flight's shared
start, as the flown tracks), :class:`CameraInfo` the optics of ``CAMERA_INFORMATION`` (the
field of view a footprint is drawn with).  Both are read from a message's fields, whether it
came live (:class:`mavlink.link.vehicle.Vehicle`, through MAVSDK's mavlink_direct JSON) or from a
``.tlog`` (:func:`images_from_tlog`); :func:`write_images_csv` keeps the image log of a
flight (``images.csv``), which :func:`gcs.telemetry.load_images` reads back (as
:func:`mavlink.tracks.write_tracks_csv`'s tracks are read there).

Numpy and pymap3d only, except the ``.tlog`` reader (pymavlink, imported there).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from planner.frames import GeodeticPoint, geodetic_to_enu

__all__ = [
    "IMAGE_COLUMNS",
    "MAV_COMP_ID_CAMERA",
    "MAV_TYPE_CAMERA",
    "CameraInfo",
    "CapturedImage",
    "camera_info_from_fields",
    "image_from_fields",
    "images_from_tlog",
    "write_images_csv",
]

#: The first of the camera component ids (MAV_COMP_ID_CAMERA .. CAMERA6: 100-105).
MAV_COMP_ID_CAMERA = 100
#: HEARTBEAT.type of a camera.
MAV_TYPE_CAMERA = 30
#: CAMERA_INFORMATION.flags bit: the camera takes still pictures.
CAMERA_CAP_FLAGS_CAPTURE_IMAGE = 2


@dataclass(frozen=True, slots=True)
class CapturedImage:
    """One picture, as its ``CAMERA_IMAGE_CAPTURED`` reported it.

    Attributes:
        vehicle: the vehicle's name.
        t_s: when it was received, seconds from the flight's start (plan time).
        lat_deg, lon_deg, alt_amsl_m: where the vehicle was (its estimate).
        rel_alt_m: height above home.
        q_wxyz: the camera's attitude in the NED earth frame (w, x, y, z).
        index: the camera's image index (from 0).
        ok: the capture succeeded (``capture_result`` 1).
        component: the camera's component id.
        file_url: where the camera keeps it (may be empty).
    """

    vehicle: str
    t_s: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    rel_alt_m: float
    q_wxyz: tuple[float, float, float, float]
    index: int
    ok: bool = True
    component: int = MAV_COMP_ID_CAMERA
    file_url: str = ""

    def position_enu_m(self, origin: GeodeticPoint) -> np.ndarray:
        """Where it was taken in the mission frame (ENU, m), ``(3,)``."""
        return geodetic_to_enu(self.lat_deg, self.lon_deg, self.alt_amsl_m, origin)[0]

    def axis_enu(self) -> np.ndarray:
        """The camera's optical axis (its attitude's forward x axis) as an ENU unit vector."""
        w, x, y, z = self.q_wxyz
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        if not norm > 0:
            return np.full(3, math.nan)
        w, x, y, z = w / norm, x / norm, y / norm, z / norm
        # first column of the rotation matrix (body x in NED)
        north = 1.0 - 2.0 * (y * y + z * z)
        east = 2.0 * (x * y + w * z)
        down = 2.0 * (x * z - w * y)
        return np.array([east, north, -down])

    def yaw_pitch_deg(self) -> tuple[float, float]:
        """The optical axis's compass heading (degrees from north, clockwise, [0, 360)) and
        elevation (degrees, negative: down)."""
        a = self.axis_enu()
        heading = math.degrees(math.atan2(a[0], a[1])) % 360.0
        return heading, math.degrees(math.atan2(a[2], math.hypot(a[0], a[1])))


@dataclass(frozen=True, slots=True)
class CameraInfo:
    """A camera's optics from ``CAMERA_INFORMATION``.

    Attributes:
        vendor, model: as the camera names itself.
        focal_length_mm: focal length; sensor_h_mm, sensor_v_mm: sensor size.
        resolution: (horizontal, vertical) pixels.
        flags: CAMERA_CAP_FLAGS.
        component: the camera's component id.
    """

    vendor: str
    model: str
    focal_length_mm: float
    sensor_h_mm: float
    sensor_v_mm: float
    resolution: tuple[int, int]
    flags: int
    component: int = MAV_COMP_ID_CAMERA

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view (NaN when the optics are not given)."""
        if not (self.focal_length_mm > 0 and self.sensor_h_mm > 0):
            return math.nan
        return math.degrees(2.0 * math.atan(self.sensor_h_mm / (2.0 * self.focal_length_mm)))

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view (NaN when the optics are not given)."""
        if not (self.focal_length_mm > 0 and self.sensor_v_mm > 0):
            return math.nan
        return math.degrees(2.0 * math.atan(self.sensor_v_mm / (2.0 * self.focal_length_mm)))

    @property
    def takes_pictures(self) -> bool:
        return bool(self.flags & CAMERA_CAP_FLAGS_CAPTURE_IMAGE)


def _text(v: Any) -> str:
    """A char array as MAVSDK's JSON (a string or its codes) or pymavlink (bytes/str) give it."""
    if isinstance(v, bytes):
        v = v.decode("utf-8", errors="replace")
    if isinstance(v, list):
        v = "".join(chr(int(c)) for c in v if int(c))
    return str(v).rstrip("\x00")


def image_from_fields(
    f: Mapping[str, Any], vehicle: str, t_s: float, component: int
) -> CapturedImage:
    """A :class:`CapturedImage` from ``CAMERA_IMAGE_CAPTURED``'s fields (degE7, mm)."""
    q = f["q"]
    return CapturedImage(
        vehicle=vehicle,
        t_s=float(t_s),
        lat_deg=int(f["lat"]) * 1e-7,
        lon_deg=int(f["lon"]) * 1e-7,
        alt_amsl_m=int(f["alt"]) * 1e-3,
        rel_alt_m=int(f["relative_alt"]) * 1e-3,
        q_wxyz=(float(q[0]), float(q[1]), float(q[2]), float(q[3])),
        index=int(f["image_index"]),
        ok=int(f["capture_result"]) == 1,
        component=int(component),
        file_url=_text(f.get("file_url", "")),
    )


def camera_info_from_fields(f: Mapping[str, Any], component: int) -> CameraInfo:
    """A :class:`CameraInfo` from ``CAMERA_INFORMATION``'s fields."""
    return CameraInfo(
        vendor=_text(f.get("vendor_name", "")),
        model=_text(f.get("model_name", "")),
        focal_length_mm=float(f.get("focal_length", 0.0) or 0.0),
        sensor_h_mm=float(f.get("sensor_size_h", 0.0) or 0.0),
        sensor_v_mm=float(f.get("sensor_size_v", 0.0) or 0.0),
        resolution=(int(f.get("resolution_h", 0) or 0), int(f.get("resolution_v", 0) or 0)),
        flags=int(f.get("flags", 0) or 0),
        component=int(component),
    )


def unique_images(images: Iterable[CapturedImage]) -> list[CapturedImage]:
    """The pictures by time, each (vehicle, camera, index) once: a camera may report a picture
    again (a GCS that missed one asks for it; some cameras repeat the message)."""
    seen: set[tuple[str, int, int]] = set()
    out = []
    for im in sorted(images, key=lambda i: i.t_s):
        key = (im.vehicle, im.component, im.index)
        if key not in seen:
            seen.add(key)
            out.append(im)
    return out


def images_from_tlog(
    path: str | Path, names_by_sysid: Mapping[int, str], t0_unix_s: float
) -> tuple[dict[str, list[CapturedImage]], dict[str, CameraInfo]]:
    """The pictures (by vehicle, in time order) and the camera optics in a ``.tlog``.

    ``t_s`` is the record's timestamp minus ``t0_unix_s`` (the plan's start), as for the
    positions (:func:`mavlink.tlog.tracks_from_tlog`).
    """
    from pymavlink import mavutil

    log = mavutil.mavlogfile(str(path), robust_parsing=True)
    images: dict[str, list[CapturedImage]] = {}
    infos: dict[str, CameraInfo] = {}
    while True:
        m = log.recv_match(type=["CAMERA_IMAGE_CAPTURED", "CAMERA_INFORMATION"])
        if m is None:
            break
        name = names_by_sysid.get(m.get_srcSystem())
        if name is None:
            continue
        comp = m.get_srcComponent()
        d = m.to_dict()
        if m.get_type() == "CAMERA_INFORMATION":
            infos[name] = camera_info_from_fields(d, comp)
        else:
            images.setdefault(name, []).append(
                image_from_fields(d, name, m._timestamp - t0_unix_s, comp)
            )
    return {n: unique_images(v) for n, v in images.items()}, infos


#: The image log's columns (:func:`write_images_csv`).
IMAGE_COLUMNS = (
    *(f.name for f in fields(CapturedImage) if f.name != "q_wxyz"),
    "qw",
    "qx",
    "qy",
    "qz",
)


def write_images_csv(path: str | Path, images: Iterable[CapturedImage]) -> Path:
    """Write the image log (one row per picture, :data:`IMAGE_COLUMNS`); returns the path."""
    p = Path(path)
    with p.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(IMAGE_COLUMNS)
        for im in images:
            w.writerow(
                [
                    im.vehicle,
                    f"{im.t_s:.3f}",
                    f"{im.lat_deg:.7f}",
                    f"{im.lon_deg:.7f}",
                    f"{im.alt_amsl_m:.3f}",
                    f"{im.rel_alt_m:.3f}",
                    im.index,
                    int(im.ok),
                    im.component,
                    im.file_url,
                    *(f"{c:.6f}" for c in im.q_wxyz),
                ]
            )
    return p
