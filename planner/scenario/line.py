"""A power line from its pole coordinates: the regions a scenario's ``line:`` section makes.

::

    line:
      poles: [[0, 0], [24, 18], ...]      # ENU [x, y] metres, or {lat: .., lon: ..} each
      # along: {start: [0, 0], bearing_deg: 37, span_m: 30, count: 10}
      # file: poles.csv                   # a GIS export: CSV (x,y or lat,lon columns, and
      #                                   # alt or elevation: the ground at the foot),
      #                                   # GeoJSON or KML/KMZ (Points, or one LineString)
      pole: {radius_m: 0.4, height_m: 12}
      conductors: {half_width_m: 1.8, z: [9, 12], clearance_m: 1.0}
      inspection: {standoff_m: 1.5, depth_m: 2.2, length_m: 5, z: [9.5, 12.5], side: right}

For pole ``i`` (1-based, in line order) it makes:

* ``pole{i}``: a :class:`~planner.spec.regions.Cylinder` (``radius_m``, ground to ``height_m``);
* ``span{i}`` (between poles ``i`` and ``i + 1``): the conductors' keep-out, a box along the
  span, ``half_width_m + clearance_m`` either side of it, reaching ``clearance_m`` past
  each pole, over ``z`` widened by ``clearance_m``;
* ``insp{i}``: where a camera inspects the insulators of pole ``i``: a box ``length_m``
  along the line and ``depth_m`` across it, ``standoff_m`` beyond the conductors'
  half-width on the ``side`` (``right`` or ``left`` of the line's direction, pole 1 to the
  last; ``both``: ``insp{i}_left`` and ``insp{i}_right``), turned with the line there (the
  mean direction of the spans on either side).

Heights are above the ground at each pole: ``z = 0`` without a terrain; with one (the
scenario's ``terrain:`` section) the ground under the pole, and a span's keep-out, a level
box, reaches from the lower pole's conductors to the higher one's.

It also makes the lists ``poles``, ``spans`` and ``inspections`` of those names, which a clause's
``each`` may bind (``each: [d in all, s in spans]``).  A straight line along the x or y
axis makes axis-aligned boxes (the planner's fastest form); any other direction makes
prisms.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from planner.frames import GeodeticPoint, geodetic_to_enu
from planner.scenario.kml import KmlError, read_kml_towers
from planner.spec.regions import Cylinder, Region, RegionKind
from planner.strict_read import DuplicateKeyError, NotTextError, load_json, read_text

__all__ = ["LineModel", "line_regions"]

#: Sides an inspection box may be on.
SIDES = ("left", "right", "both")


@dataclass(frozen=True, slots=True)
class LineModel:
    """A line's parameters (see the module docstring), metres.

    Attributes:
        poles_xy: the poles' ENU positions, (n, 2), in line order.
        pole_radius_m, pole_height_m: each pole's cylinder.
        half_width_m, conductor_z_m, clearance_m: the conductors (outer phase's distance
            from the line's axis, their height range) and the keep-out's clearance.
        standoff_m, depth_m, length_m, inspection_z_m, side: the inspection boxes.
        ground_z_m: the ground's mission-frame ``z`` at each pole, ``(n,)`` (a scenario's
            terrain); every height above is from there. None: flat ground at ``z = 0``.
        tower_alt_m: the ground's altitude (m AMSL) at each tower's foot as its file gives
            it (a CSV's ``alt`` or ``elevation`` column, a GeoJSON position's third number, a
            KML coordinate's altitude under ``altitudeMode`` absolute), NaN where it gives
            none; None for poles written in the scenario (``terrain: {from: line}``).
    """

    poles_xy: np.ndarray
    pole_radius_m: float = 0.4
    pole_height_m: float = 12.0
    half_width_m: float = 1.8
    conductor_z_m: tuple[float, float] = (9.0, 12.0)
    clearance_m: float = 1.0
    standoff_m: float = 1.5
    depth_m: float = 2.2
    length_m: float = 5.0
    inspection_z_m: tuple[float, float] = (9.5, 12.5)
    side: str = "right"
    ground_z_m: np.ndarray | None = None
    #: each tower's ground altitude (m AMSL) as its file gave it (NaN where none), or None
    tower_alt_m: np.ndarray | None = None


def _region(name: str, kind: RegionKind, center_xy: np.ndarray, half: Sequence[float],
            z: tuple[float, float], direction: np.ndarray) -> Region:  # fmt: skip
    """A box centred at ``center_xy`` with half-sizes ``half`` (along, across) over ``z``,
    turned along ``direction`` (:meth:`Region.turned_box`: along an axis, the axis-aligned
    box itself)."""
    c = [float(center_xy[0]), float(center_xy[1]), 0.5 * (z[0] + z[1])]
    yaw = math.atan2(float(direction[1]), float(direction[0]))
    return Region.turned_box(name, kind, c, [half[0], half[1], 0.5 * (z[1] - z[0])], yaw)


def line_regions(model: LineModel) -> tuple[list[Region], dict[str, list[str]]]:
    """The regions of ``model`` and the name lists ``poles``, ``spans``, ``inspections``."""
    p = np.asarray(model.poles_xy, dtype=float)
    g = np.zeros(len(p)) if model.ground_z_m is None else np.asarray(model.ground_z_m, float)
    spans = np.diff(p, axis=0)
    regions: list[Region] = []
    names: dict[str, list[str]] = {"poles": [], "spans": [], "inspections": []}
    for i, xy in enumerate(p, start=1):
        name = f"pole{i}"
        g_i = float(g[i - 1])
        cyl = Cylinder(
            (float(xy[0]), float(xy[1])), model.pole_radius_m, g_i, g_i + model.pole_height_m
        )
        regions.append(Region.of_shape(name, RegionKind.POLE, cyl))
        names["poles"].append(name)
    c = model.clearance_m
    for i, d in enumerate(spans, start=1):
        name = f"span{i}"
        half = (0.5 * float(np.linalg.norm(d)) + c, model.half_width_m + c)
        # over sloping ground the conductors run from one pole's height to the next: the
        # keep-out (a box, level) spans both ends' heights
        lo_g, hi_g = float(min(g[i - 1], g[i])), float(max(g[i - 1], g[i]))
        z_keep = (lo_g + model.conductor_z_m[0] - c, hi_g + model.conductor_z_m[1] + c)
        regions.append(_region(name, RegionKind.CONDUCTOR, p[i - 1] + 0.5 * d, half, z_keep, d))
        names["spans"].append(name)
    sides = ("left", "right") if model.side == "both" else (model.side,)
    reach = model.half_width_m + model.standoff_m + 0.5 * model.depth_m
    for i, xy in enumerate(p, start=1):
        here = [spans[j] / np.linalg.norm(spans[j]) for j in (i - 2, i - 1) if 0 <= j < len(spans)]
        direction = np.sum(here, axis=0)
        if np.linalg.norm(direction) < 1e-9:  # the line turns back on itself here
            direction = here[-1]
        u = direction / np.linalg.norm(direction)
        left = np.array([-u[1], u[0]])
        for side in sides:
            name = f"insp{i}" if len(sides) == 1 else f"insp{i}_{side}"
            normal = left if side == "left" else -left
            half = (0.5 * model.length_m, 0.5 * model.depth_m)
            z_insp = (g[i - 1] + model.inspection_z_m[0], g[i - 1] + model.inspection_z_m[1])
            regions.append(
                _region(name, RegionKind.INSPECTION, xy + reach * normal, half, z_insp, u)
            )
            names["inspections"].append(name)
    return regions, names


# ---------------------------------------------------------------------------- reading


def read_line(
    value: Mapping[str, Any],
    origin: GeodeticPoint,
    base_dir: Path,
    fail: Callable[[str, str], Exception],
    number: Callable[..., float],
) -> LineModel:
    """The :class:`LineModel` of a scenario's ``line:`` mapping (``fail(path, problem)``
    makes the error to raise; ``number(value, path, positive=..)`` reads a number)."""
    sources = [k for k in ("poles", "along", "file") if k in value]
    if len(sources) != 1:
        raise fail("line", "give the poles one way: poles, along or file")
    src = sources[0]
    alt = None
    if src == "poles":
        xy = _pole_list(value["poles"], origin, fail, number)
    elif src == "along":
        xy = _along(value["along"], fail, number)
    else:
        xy, alt = _pole_file(value["file"], origin, base_dir, fail)
    # a file's poles are named with the file (the mistake is in it, not in the scenario)
    in_file = f"{value['file']}: " if src == "file" else ""
    if len(xy) < 2:
        raise fail(f"line.{src}", f"{in_file}a line needs at least 2 poles, got {len(xy)}")
    gaps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    if np.any(gaps < 1.0):
        j = int(np.argmin(gaps))
        raise fail(
            f"line.{src}",
            f"{in_file}poles {j + 1} and {j + 2} are {gaps[j]:.3g} m apart (< 1 m)",
        )
    kw: dict[str, Any] = {"poles_xy": xy, "tower_alt_m": alt}
    sections = {
        "pole": {"radius_m": "pole_radius_m", "height_m": "pole_height_m"},
        "conductors": {"half_width_m": "half_width_m", "z": "conductor_z_m",
                       "clearance_m": "clearance_m"},
        "inspection": {"standoff_m": "standoff_m", "depth_m": "depth_m", "length_m": "length_m",
                       "z": "inspection_z_m", "side": "side"},
    }  # fmt: skip
    unknown = set(value) - {"poles", "along", "file", *sections}
    if unknown:
        raise fail(
            f"line.{sorted(unknown)[0]}",
            f"unknown key (keys: poles|along|file, {', '.join(sections)})",
        )
    for sec, keys in sections.items():
        m = value.get(sec, {}) or {}
        if not isinstance(m, dict):
            raise fail(f"line.{sec}", "expected a mapping")
        for k, v in m.items():
            path = f"line.{sec}.{k}"
            if k not in keys:
                raise fail(path, f"unknown key (keys: {', '.join(keys)})")
            if k == "side":
                if v not in SIDES:
                    raise fail(path, f"expected one of {', '.join(SIDES)}, got {v!r}")
                kw["side"] = v
            elif k == "z":
                if not isinstance(v, list) or len(v) != 2:
                    raise fail(path, "expected [bottom, top]")
                z = (number(v[0], f"{path}[0]"), number(v[1], f"{path}[1]"))
                if not z[0] < z[1]:
                    raise fail(path, f"empty height range: {z[0]:g} is not below {z[1]:g}")
                kw[keys[k]] = z
            else:
                kw[keys[k]] = number(
                    v, path, nonnegative=k == "clearance_m", positive=k != "clearance_m"
                )
    return LineModel(**kw)


def _xy_or_geodetic(
    v: Any, path: str, origin: GeodeticPoint, fail: Any, number: Any
) -> list[float]:
    if isinstance(v, dict):
        if set(v) - {"lat", "lon"} or not {"lat", "lon"} <= set(v):
            raise fail(path, "expected {lat, lon} (degrees) or [x, y] (ENU metres)")
        lat, lon = number(v["lat"], f"{path}.lat"), number(v["lon"], f"{path}.lon")
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):
            raise fail(path, f"not a latitude/longitude: {lat:g}, {lon:g}")
        enu = geodetic_to_enu(lat, lon, origin.alt_m, origin)
        return [float(enu[0, 0]), float(enu[0, 1])]
    if not isinstance(v, list | tuple) or len(v) != 2:
        raise fail(path, "expected [x, y] (ENU metres) or {lat, lon} (degrees)")
    return [number(v[0], f"{path}[0]"), number(v[1], f"{path}[1]")]


def _pole_list(v: Any, origin: GeodeticPoint, fail: Any, number: Any) -> np.ndarray:
    if not isinstance(v, list):
        raise fail("line.poles", "expected a list of [x, y] or {lat, lon}")
    return np.array(
        [_xy_or_geodetic(p, f"line.poles[{i}]", origin, fail, number) for i, p in enumerate(v)]
    )


def _along(v: Any, fail: Any, number: Any) -> np.ndarray:
    keys = {"start", "bearing_deg", "span_m", "count"}
    if not isinstance(v, dict) or set(v) != keys:
        raise fail("line.along", f"expected {{{', '.join(sorted(keys))}}}")
    s = v["start"]
    if not isinstance(s, list) or len(s) != 2:
        raise fail("line.along.start", "expected [x, y] (ENU metres)")
    start = np.array([number(s[0], "line.along.start[0]"), number(s[1], "line.along.start[1]")])
    bearing = math.radians(number(v["bearing_deg"], "line.along.bearing_deg"))
    span = number(v["span_m"], "line.along.span_m", positive=True)
    count = v["count"]
    if isinstance(count, bool) or not isinstance(count, int) or count < 2:
        raise fail("line.along.count", f"expected an integer >= 2, got {count!r}")
    u = np.array([math.sin(bearing), math.cos(bearing)])  # bearing: clockwise from north
    return start + span * np.arange(count)[:, None] * u


def _pole_file(
    v: Any, origin: GeodeticPoint, base_dir: Path, fail: Any
) -> tuple[np.ndarray, np.ndarray]:
    """The towers' ENU ``(n, 2)`` and their ground altitudes ``(n,)`` (m AMSL, NaN where the
    file gives none)."""
    if not isinstance(v, str):
        raise fail("line.file", "expected a file name (CSV, GeoJSON, KML or KMZ)")
    path = (base_dir / v) if not Path(v).is_absolute() else Path(v)
    if path.suffix.lower() in (".kml", ".kmz"):
        try:
            towers = read_kml_towers(path, absolute_only=True)
        except OSError as exc:
            raise fail("line.file", f"cannot read {path}: {exc.strerror or exc}") from None
        except KmlError as exc:
            raise fail("line.file", str(exc)) from None
        return _to_enu(towers[:, 0], towers[:, 1], origin), towers[:, 2]
    try:
        text = read_text(path)
    except OSError as exc:
        raise fail("line.file", f"cannot read {path}: {exc.strerror or exc}") from None
    except NotTextError as exc:
        raise fail("line.file", f"{path}: {exc} (expected CSV or GeoJSON text)") from None
    if path.suffix.lower() in (".geojson", ".json"):
        return _geojson_poles(text, path, origin, fail)
    return _csv_poles(text, path, origin, fail)


def _to_enu(lat: np.ndarray, lon: np.ndarray, origin: GeodeticPoint) -> np.ndarray:
    return geodetic_to_enu(lat, lon, np.full(len(lat), origin.alt_m), origin)[:, :2]


def _csv_poles(
    text: str, path: Path, origin: GeodeticPoint, fail: Any
) -> tuple[np.ndarray, np.ndarray]:
    reader = csv.DictReader(text.splitlines())
    try:
        rows = list(reader)
    except csv.Error as exc:
        raise fail("line.file", f"{path.name} line {reader.line_num}: not CSV ({exc})") from None
    cols = {c.strip().lower(): c for c in (reader.fieldnames or []) if rows}
    pair = next(
        (p for p in (("x", "y"), ("lat", "lon"), ("latitude", "longitude")) if set(p) <= set(cols)),
        None,
    )
    if pair is None:
        raise fail(
            "line.file", f"{path.name}: expected columns x,y (ENU metres) or lat,lon (degrees)"
        )
    alt_col = next((c for c in ("alt", "elevation") if c in cols), None)
    vals = []
    for i, r in enumerate(rows, start=2):
        ab = []
        for name in (*pair, *((alt_col,) if alt_col else ())):
            col = cols[name]
            cell = r.get(col)
            if name == alt_col and (cell is None or not cell.strip()):
                ab.append(math.nan)  # a tower without its ground: only from: line needs it
                continue
            try:
                x = float(cell)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                got = "nothing" if cell is None or not cell.strip() else repr(cell)
                raise fail(
                    "line.file",
                    f"{path.name} line {i}, column {col.strip()}: expected a number, got {got}",
                ) from None
            if not math.isfinite(x):
                raise fail(
                    "line.file",
                    f"{path.name} line {i}, column {col.strip()}: not a finite number ({cell})",
                )
            ab.append(x)
        vals.append((ab[0], ab[1], ab[2] if alt_col else math.nan))
    arr = np.array(vals, dtype=float).reshape(-1, 3)
    if pair == ("x", "y"):
        return arr[:, :2], arr[:, 2]
    if np.any(np.abs(arr[:, 0]) > 90) or np.any(np.abs(arr[:, 1]) > 180):
        raise fail("line.file", f"{path.name}: a latitude/longitude out of range")
    return _to_enu(arr[:, 0], arr[:, 1], origin), arr[:, 2]


def _geojson_poles(
    text: str, path: Path, origin: GeodeticPoint, fail: Any
) -> tuple[np.ndarray, np.ndarray]:
    """Points (a FeatureCollection of Point features, in order) or one LineString's vertices;
    GeoJSON coordinates are [lon, lat] (RFC 7946)."""
    try:
        doc = load_json(text)
    except json.JSONDecodeError as exc:
        raise fail("line.file", f"{path.name}: not JSON (line {exc.lineno}: {exc.msg})") from None
    except DuplicateKeyError as exc:
        raise fail("line.file", f"{path.name}: {exc}") from None
    except RecursionError:
        raise fail("line.file", f"{path.name}: not JSON: nested too deeply") from None
    geoms = (
        [f.get("geometry") or {} for f in doc.get("features", [])]
        if isinstance(doc, dict) and doc.get("type") == "FeatureCollection"
        else [doc.get("geometry", doc) if isinstance(doc, dict) else {}]
    )
    coords: list[Any] = []
    for g in geoms:
        if g.get("type") == "Point":
            coords.append(g.get("coordinates"))
        elif g.get("type") == "LineString":
            coords.extend(g.get("coordinates") or [])
    try:
        arr = np.array(
            [[float(c[1]), float(c[0]), float(c[2]) if len(c) > 2 else math.nan] for c in coords],
            dtype=float,
        ).reshape(-1, 3)
    except (TypeError, ValueError, IndexError):
        raise fail("line.file", f"{path.name}: a coordinate is not [lon, lat]") from None
    if not len(arr):
        raise fail("line.file", f"{path.name}: no Point features or LineString found")
    if np.any(np.abs(arr[:, 0]) > 90) or np.any(np.abs(arr[:, 1]) > 180):
        raise fail(
            "line.file", f"{path.name}: a coordinate is out of range (GeoJSON is [lon, lat])"
        )
    return _to_enu(arr[:, 0], arr[:, 1], origin), arr[:, 2]
