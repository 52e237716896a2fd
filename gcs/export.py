"""Exports of a plan: QGroundControl ``.plan`` files, setpoint CSV, setpoint JSON, KML/KMZ
for Google Earth (:mod:`gcs.kml`).

QGroundControl plan (one file per vehicle)
------------------------------------------
The mission items are those ``gcs upload`` sends to a vehicle with PX4's default parameters:
:func:`gcs.flight.missions.convert_plan` converts the vehicles' trajectories (takeoff, waypoints with
hold times, a speed change per leg, land/return/hold; the acceptance radius chosen and the legs
timed against PX4's predicted flight, as ``gcs upload`` does with the vehicles' own
parameters), and this module only writes each item in QGC's JSON form, so QGC (and
MAVSDK's importer, ``mission_raw.import_qgroundcontrol_mission``) read back the same
``MISSION_ITEM_INT`` fields. The geofence polygons and circles are the link's fence items
of ``gcs upload --fence`` (:func:`gcs.flight.missions.fence_plan`: the workspace moved out by
PX4's braking distance, full-height stay-out regions exact). Layout (QGC plan format,
``fileType`` "Plan" version 1)::

    {"fileType": "Plan", "version": 1, "groundStation": "stl-gcs",
     "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2,
                 "globalPlanAltitudeMode": 2, "cruiseSpeed": .., "hoverSpeed": ..,
                 "plannedHomePosition": [lat, lon, alt_amsl],
                 "items": [{"type": "SimpleItem", "autoContinue": true, "command": 22,
                            "doJumpId": 1, "frame": 5,
                            "params": [p1, p2, p3, p4, lat, lon, alt],   # null for NaN
                            "AMSLAltAboveTerrain": null, "Altitude": alt, "AltitudeMode": 2},
                           ...]},
     "geoFence": {"version": 2,
                  "polygons": [{"inclusion": true, "polygon": [[lat, lon], ...], "version": 1}],
                  "circles": [{"circle": {"center": [lat, lon], "radius": r_m},
                               "inclusion": false, "version": 1}]},
     "rallyPoints": {"version": 2, "points": []}}

Choices and why:

* Items keep the link's frame (``MAV_FRAME_GLOBAL_INT`` = 5, altitude AMSL) so an import gives
  back the very frame ``gcs upload`` sends. Positional items carry ``AltitudeMode`` 2 (QGC's
  "absolute", AMSL) and ``Altitude`` = the item's altitude; ``globalPlanAltitudeMode`` is 2 for
  the same reason (1 would tell QGC the altitudes are relative to home, which they are not).
  Items without a position (speed change, return) carry no altitude keys, as QGC writes them.
* ``params[4:6]`` are ``x / 1e7`` and ``y / 1e7`` of the item (degrees); importers compute
  ``round(deg * 1e7)``, which gives back the integer exactly. NaN params are ``null``.
* ``plannedHomePosition`` is the ground point below the vehicle's start (mission-frame
  ``z = 0``, the origin's AMSL altitude; over a terrain, the ground there), where the
  vehicle is armed.
* ``hoverSpeed`` / ``cruiseSpeed`` (QGC's defaults for time estimates) are the mean commanded
  leg speed; the legs themselves carry their own ``DO_CHANGE_SPEED``.
* The fence is what ``gcs upload --fence`` sends (:func:`gcs.flight.missions.fence_plan`): the
  workspace's footprint moved out by PX4's braking distance as inclusion, the full-height
  obstacles', poles' and no-fly zones' footprints as exclusions: a box a 4-vertex polygon, a
  prism the polygon of its corners, a cylinder a circle (QGC's ``circles``). The link sends
  the circles after all polygons, the order in which MAVSDK's importer (and QGC's upload)
  turns a plan file's fence into items, so the import gives back the very items.

Setpoints (CSV and JSON)
------------------------
Each vehicle's trajectory sampled at ``rate_hz`` (:meth:`planner.trajectory.Trajectory.sample`:
from 0 to the first sample at or after its end), mission ENU frame, SI units. CSV columns
``t,vehicle,x,y,z,vx,vy,vz,ax,ay,az,yaw`` (s, m, m/s, m/s^2, rad ENU: 0 = east, CCW), one
header line, rows vehicle by vehicle in time order, floats at full precision. JSON::

    {"format": "stl-gcs-setpoints", "version": 1, "frame": "mission ENU",
     "origin": {"lat", "lon", "alt"}, "rate_hz": 20.0,
     "vehicles": [{"name", "sysid", "t": [...], "pos": [[x, y, z], ...], "vel": [...],
                   "acc": [...], "yaw": [...]}]}

Errors::

    gcs.errors.UserError          bad option value (format, rate, acceptance radius)
      gcs.errors.InputFileError   an output path that cannot be written
"""

from __future__ import annotations

import csv
import enum
import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gcs.errors import InputFileError, UserError
from gcs.flight.missions import convert_plan, fence_plan
from gcs.flight.payload import capture_spans
from gcs.kml import kml_bytes
from mavlink.mission import Cmd, MissionEnd
from planner.frames import enu_to_geodetic

if TYPE_CHECKING:
    from mavlink.mission import MissionEnd, MissionItem, MissionPlan
    from planner.planfile import Plan, PlannedVehicle

__all__ = [
    "CSV_COLUMNS",
    "DEFAULT_RATE_HZ",
    "ExportFormat",
    "QgcOptions",
    "mission_item_to_qgc",
    "qgc_plan",
    "setpoints_json",
    "write_export",
    "write_qgc_plans",
    "write_setpoints_csv",
    "write_setpoints_json",
]

#: Columns of the setpoint CSV.
CSV_COLUMNS = ("t", "vehicle", "x", "y", "z", "vx", "vy", "vz", "ax", "ay", "az", "yaw")

#: Default setpoint rate: the offboard streaming default (docs/architecture.md, "The MAVLink side").
DEFAULT_RATE_HZ = 20.0

# QGroundControl plan format constants.
QGC_FILE_TYPE = "Plan"
QGC_PLAN_VERSION = 1
QGC_MISSION_VERSION = 2
QGC_GEOFENCE_VERSION = 2
QGC_RALLY_VERSION = 2
QGC_POLYGON_VERSION = 1
QGC_CIRCLE_VERSION = 1
GROUND_STATION = "stl-gcs"
MAV_AUTOPILOT_PX4 = 12
MAV_TYPE_QUADROTOR = 2
#: QGC's AltMode enum: 1 relative to home, 2 absolute (AMSL).
QGC_ALT_MODE_RELATIVE = 1
QGC_ALT_MODE_ABSOLUTE = 2
#: MAV_FRAME -> QGC AltitudeMode for frames whose items have a position.
_ALT_MODE_OF_FRAME = {0: 2, 5: 2, 3: 1, 6: 1}
_MAV_FRAME_MISSION = 2


class ExportFormat(enum.Enum):
    """What ``gcs export`` writes."""

    QGC = "qgc"
    CSV = "csv"
    JSON = "json"
    HOMES = "homes"
    KML = "kml"

    @classmethod
    def parse(cls, text: str | None) -> ExportFormat:
        """The format called ``text``; UserError naming the choices otherwise."""
        choices = ", ".join(f.value for f in cls)
        if text is None:
            raise UserError(f"--format: required ({choices})")
        try:
            return cls(text.lower())
        except ValueError:
            raise UserError(f"--format: unknown format {text!r} (choose {choices})") from None


@dataclass(frozen=True, slots=True)
class QgcOptions:
    """Mission conversion options (the same defaults as ``gcs upload``).

    Attributes:
        acceptance_radius_m: NAV_WAYPOINT acceptance radius (param2), > 0; ``None``: chosen
            (:func:`gcs.flight.missions.auto_acceptance_m`).
        end: what the mission ends with (land, return, hold).
        fence: write the geofence polygons.
        photo_interval_s: time between pictures where the plan faces an inspection target
            (camera and gimbal items: :mod:`gcs.flight.payload`); 0: none.
    """

    acceptance_radius_m: float | None = None
    end: MissionEnd | None = None
    fence: bool = True
    photo_interval_s: float = 1.0


def _json_number(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def mission_item_to_qgc(item: MissionItem) -> dict[str, Any]:
    """One MISSION item as a QGC ``SimpleItem`` (see module docstring)."""
    if item.frame == _MAV_FRAME_MISSION:
        lat, lon = float(item.x), float(item.y)
    else:
        lat, lon = item.x / 1e7, item.y / 1e7
    out: dict[str, Any] = {
        "type": "SimpleItem",
        "autoContinue": bool(item.autocontinue),
        "command": int(item.command),
        "doJumpId": int(item.seq) + 1,
        "frame": int(item.frame),
        "params": [
            _json_number(item.param1),
            _json_number(item.param2),
            _json_number(item.param3),
            _json_number(item.param4),
            lat,
            lon,
            _json_number(item.z),
        ],
    }
    mode = _ALT_MODE_OF_FRAME.get(int(item.frame))
    if mode is not None:
        out["AMSLAltAboveTerrain"] = None
        out["Altitude"] = _json_number(item.z)
        out["AltitudeMode"] = mode
    return out


def _fence_qgc(items: Sequence[MissionItem]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """FENCE items -> QGC ``(polygons, circles)``: polygon-vertex items (consecutive runs of
    ``param1`` vertices) and circle items (``param1`` the radius, m)."""

    vertex = (Cmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION, Cmd.NAV_FENCE_POLYGON_VERTEX_EXCLUSION)
    circle = (Cmd.NAV_FENCE_CIRCLE_INCLUSION, Cmd.NAV_FENCE_CIRCLE_EXCLUSION)
    polygons: list[dict[str, Any]] = []
    circles: list[dict[str, Any]] = []
    i = 0
    while i < len(items):
        first = items[i]
        if first.command in circle:
            if not first.param1 > 0:
                raise UserError(f"fence item {i}: circle radius {first.param1} is not > 0")
            circles.append(
                {
                    "circle": {
                        "center": [first.x / 1e7, first.y / 1e7],
                        "radius": float(first.param1),
                    },
                    "inclusion": first.command == Cmd.NAV_FENCE_CIRCLE_INCLUSION,
                    "version": QGC_CIRCLE_VERSION,
                }
            )
            i += 1
            continue
        if first.command not in vertex:
            raise UserError(
                f"fence item {i}: command {first.command} is not a polygon vertex or circle"
            )
        n = round(first.param1)
        run = items[i : i + n]
        if n < 3 or len(run) != n or any(it.command != first.command for it in run):
            raise UserError(f"fence item {i}: polygon of {n} vertices is incomplete")
        polygons.append(
            {
                "inclusion": first.command == Cmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                "polygon": [[it.x / 1e7, it.y / 1e7] for it in run],
                "version": QGC_POLYGON_VERSION,
            }
        )
        i += n
    return polygons, circles


def qgc_missions(plan: Plan, options: QgcOptions | None = None) -> dict[str, MissionPlan]:
    """Every vehicle's mission as ``gcs upload`` converts it for PX4's default parameters."""

    opts = options if options is not None else QgcOptions()
    conv = convert_plan(
        plan,
        end=opts.end or MissionEnd.LAND,
        acceptance_m=opts.acceptance_radius_m,
        captures=capture_spans(plan, opts.photo_interval_s),
    )
    return conv.missions


def qgc_plan(
    plan: Plan,
    vehicle: PlannedVehicle,
    options: QgcOptions | None = None,
    missions: dict[str, MissionPlan] | None = None,
) -> dict:
    """The QGroundControl plan (a JSON-ready dict) of one vehicle of ``plan`` (``missions``:
    :func:`qgc_missions`, computed here when not given)."""

    opts = options if options is not None else QgcOptions()
    mission = (missions if missions is not None else qgc_missions(plan, opts))[vehicle.name]
    names = [v.name for v in plan.vehicles]
    home = plan.ground_spawns()[names.index(vehicle.name)]  # the ground below its start
    home_lat, home_lon, home_alt = enu_to_geodetic(np.array(home), plan.origin)
    legs = np.asarray(mission.leg_speed_m_s, dtype=float)
    speed = float(legs.mean()) if legs.size else float(min(vehicle.v_max_m_s[:2]))
    polygons: list[dict[str, Any]] = []
    circles: list[dict[str, Any]] = []
    if opts.fence:
        polygons, circles = _fence_qgc(fence_plan(plan).items)  # as gcs upload --fence sends it
    return {
        "fileType": QGC_FILE_TYPE,
        "version": QGC_PLAN_VERSION,
        "groundStation": GROUND_STATION,
        "mission": {
            "version": QGC_MISSION_VERSION,
            "firmwareType": MAV_AUTOPILOT_PX4,
            "vehicleType": MAV_TYPE_QUADROTOR,
            "globalPlanAltitudeMode": QGC_ALT_MODE_ABSOLUTE,
            "cruiseSpeed": speed,
            "hoverSpeed": speed,
            "plannedHomePosition": [float(home_lat), float(home_lon), float(home_alt)],
            "items": [mission_item_to_qgc(it) for it in mission.items],
        },
        "geoFence": {"version": QGC_GEOFENCE_VERSION, "circles": circles, "polygons": polygons},
        "rallyPoints": {"version": QGC_RALLY_VERSION, "points": []},
    }


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "vehicle"


def _write_text(path: Path, text: str) -> None:
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise InputFileError(f"{path}: cannot write: {exc.strerror or exc}") from None


def write_qgc_plans(
    plan: Plan, out_dir: str | Path, stem: str, options: QgcOptions | None = None
) -> list[Path]:
    """Write ``<out_dir>/<stem>-<vehicle>.plan`` for every vehicle; returns the paths."""
    d = Path(out_dir)
    if d.exists() and not d.is_dir():
        raise InputFileError(f"{d}: -o for --format qgc must be a directory (one file per vehicle)")
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputFileError(f"{d}: cannot create directory: {exc.strerror or exc}") from None
    paths = []
    missions = qgc_missions(plan, options)
    for v in plan.vehicles:
        p = d / f"{stem}-{_safe_name(v.name)}.plan"
        text = json.dumps(qgc_plan(plan, v, options, missions), indent=2, allow_nan=False)
        _write_text(p, text + "\n")
        paths.append(p)
    return paths


def homes_text(plan: Plan) -> str:
    """Where each vehicle must stand for the plan: the ground point below its start (mission
    ``z = 0``, or the plan's terrain there), as PX4's home variables, one line per vehicle
    (SITL instance ``i`` = line ``i``): ``NAME PX4_HOME_LAT=.. PX4_HOME_LON=..
    PX4_HOME_ALT=..`` (degrees, m AMSL).

    PX4 v1.17's SIH takes them at start-up (``PX4_HOME_*`` become SIH_LOC_LAT0 / LON0 / H0,
    float32 parameters: about 0.4 m of quantisation at mid latitudes).
    """

    lines = [
        "# vehicle, then the environment of PX4 SITL instance i (line i): the ground below "
        "its planned start"
    ]
    for v, ground in zip(plan.vehicles, plan.ground_spawns(), strict=True):
        lat, lon, alt = (
            float(np.ravel(c)[0]) for c in enu_to_geodetic(np.array(ground), plan.origin)
        )
        lines.append(
            f"{v.name} PX4_HOME_LAT={lat:.8f} PX4_HOME_LON={lon:.8f} PX4_HOME_ALT={alt:.3f}"
        )
    return "\n".join(lines) + "\n"


def _check_rate(rate_hz: float) -> float:
    r = float(rate_hz)
    if not (math.isfinite(r) and 0.0 < r <= 1000.0):
        raise UserError(f"--rate: must be in (0, 1000] Hz, got {rate_hz!r}")
    return r


def write_setpoints_csv(plan: Plan, path: str | Path, rate_hz: float = DEFAULT_RATE_HZ) -> Path:
    """Write the setpoint CSV (module docstring); returns the path."""
    rate = _check_rate(rate_hz)
    p = Path(path)
    try:
        with p.open("w", encoding="utf-8", newline="") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(CSV_COLUMNS)
            for v in plan.vehicles:
                sp = v.trajectory.sample(rate)
                num = np.column_stack(
                    [sp.pos_enu_m, sp.vel_enu_m_s, sp.acc_enu_m_s2, sp.yaw_rad]
                ).tolist()
                times = sp.t_s.tolist()
                w.writerows([t, v.name, *row] for t, row in zip(times, num, strict=True))
    except OSError as exc:
        raise InputFileError(f"{p}: cannot write: {exc.strerror or exc}") from None
    return p


def setpoints_json(plan: Plan, rate_hz: float = DEFAULT_RATE_HZ) -> dict[str, Any]:
    """The sampled setpoints of every vehicle as a JSON-ready dict (module docstring)."""
    rate = _check_rate(rate_hz)
    vehicles = []
    for v in plan.vehicles:
        sp = v.trajectory.sample(rate)
        vehicles.append(
            {
                "name": v.name,
                "sysid": v.sysid,
                "t": sp.t_s.tolist(),
                "pos": sp.pos_enu_m.tolist(),
                "vel": sp.vel_enu_m_s.tolist(),
                "acc": sp.acc_enu_m_s2.tolist(),
                "yaw": sp.yaw_rad.tolist(),
            }
        )
    return {
        "format": "stl-gcs-setpoints",
        "version": 1,
        "frame": "mission ENU",
        "units": {"t": "s", "pos": "m", "vel": "m/s", "acc": "m/s^2", "yaw": "rad (ENU)"},
        "origin": {
            "lat": plan.origin.lat_deg,
            "lon": plan.origin.lon_deg,
            "alt": plan.origin.alt_m,
        },
        "rate_hz": rate,
        "vehicles": vehicles,
    }


def write_setpoints_json(plan: Plan, path: str | Path, rate_hz: float = DEFAULT_RATE_HZ) -> Path:
    """Write :func:`setpoints_json` to ``path``; returns the path."""
    p = Path(path)
    _write_text(p, json.dumps(setpoints_json(plan, rate_hz), separators=(",", ":")) + "\n")
    return p


def write_export(
    plan: Plan,
    plan_path: str | Path,
    fmt: ExportFormat,
    output: str | Path | None = None,
    *,
    rate_hz: float = DEFAULT_RATE_HZ,
    qgc: QgcOptions | None = None,
) -> list[Path]:
    """Write one export of ``plan`` (read from ``plan_path``); returns the files written.

    Defaults: QGC plans beside the plan file (``<plan stem>-<vehicle>.plan``), setpoints in
    ``<plan stem>.setpoints.csv`` / ``.json`` beside it.
    """
    src = Path(plan_path)
    stem = src.stem
    if fmt is ExportFormat.QGC:
        return write_qgc_plans(plan, output if output is not None else src.parent, stem, qgc)
    if fmt is ExportFormat.KML:
        target = Path(output) if output is not None else src.with_name(stem + ".kml")
        if target.is_dir():
            raise InputFileError(f"{target}: -o for --format kml must be a .kml or .kmz file")
        if target.suffix.lower() not in (".kml", ".kmz"):
            raise InputFileError(f"{target}: -o for --format kml must end in .kml or .kmz")
        data = kml_bytes(plan, target.suffix.lower() == ".kmz", name=stem)
        try:
            target.write_bytes(data)
        except OSError as exc:
            raise InputFileError(f"{target}: cannot write: {exc.strerror or exc}") from None
        return [target]
    if fmt is ExportFormat.HOMES:
        target = Path(output) if output is not None else src.with_name(stem + ".homes")
        if target.is_dir():
            raise InputFileError(f"{target}: -o for --format homes must be a file")
        _write_text(target, homes_text(plan))
        return [target]
    _check_rate(rate_hz)
    suffix = ".setpoints.csv" if fmt is ExportFormat.CSV else ".setpoints.json"
    target = Path(output) if output is not None else src.with_name(stem + suffix)
    if target.is_dir():
        raise InputFileError(
            f"{target}: -o for --format {fmt.value} must be a file, not a directory"
        )
    if fmt is ExportFormat.CSV:
        return [write_setpoints_csv(plan, target, rate_hz)]
    return [write_setpoints_json(plan, target, rate_hz)]
