"""A plan as KML or KMZ for review in Google Earth (``gcs export --format kml``), with fastkml.

The document has four folders:

* ``paths``: each vehicle's planned path, a ``LineString`` sampled every second (and at the
  horizon), altitudes absolute (above the WGS84 ellipsoid as the origin's ``alt`` is: the
  mission frame's up axis, :func:`planner.frames.enu_to_geodetic`);
* ``poles``: one ``Point`` per pole (the regions of kind ``pole``, in the plan's order) at its
  foot (the origin's altitude, or its ground over a terrain), ``altitudeMode`` absolute;
  these are what ``line: file:`` reads back from the file (:mod:`planner.scenario.kml`), so a
  line exported and imported again keeps its towers, and with ``terrain: {from: line}``
  their ground;
* ``keep-outs`` (obstacles, no-fly areas, conductors, the poles' cylinders) and
  ``inspection`` (inspection places) and ``regions`` (the others): each region as a solid,
  a ``MultiGeometry`` of its floor, roof and walls (a cylinder as a 48-gon), absolute
  altitudes;
* and the workspace's outline at its floor.

KML coordinates are ``lon,lat,alt`` (OGC KML 2.2). A ``.kmz`` is the same document zipped as
``doc.kml``.
"""

from __future__ import annotations

import io
import zipfile
from collections.abc import Sequence

import numpy as np
import pygeoif.geometry as geo
from fastkml import kml
from fastkml.containers import Document, Folder
from fastkml.enums import AltitudeMode
from fastkml.features import Placemark
from fastkml.geometry import LineString, MultiGeometry, Point, Polygon
from fastkml.styles import LineStyle, PolyStyle, Style, StyleUrl

from planner.frames import GeodeticPoint, enu_to_geodetic
from planner.planfile import Plan
from planner.spec.regions import Region, RegionKind

__all__ = ["PATH_DT_S", "kml_bytes", "plan_kml"]

#: Seconds between the points of a path.
PATH_DT_S = 1.0
_KEEP_OUT = {RegionKind.OBSTACLE, RegionKind.NO_FLY, RegionKind.CONDUCTOR, RegionKind.POLE}
#: (style id, line colour, fill colour): KML colours are aabbggrr
_STYLES = (
    ("keep-out", "ff1c1ce3", "601c1ce3"),
    ("inspection", "ff2ca02c", "602ca02c"),
    ("region", "ffb47800", "40b47800"),
    ("workspace", "ff808080", "00000000"),
)
#: path colours (aabbggrr) by vehicle, in turn
_PATH_COLOURS = ("ffb4771f", "ff0e7fff", "ff2ca02c", "ff2827d6", "ffbd6794", "ff4b568c")


def _lonlatalt(points_enu: np.ndarray, origin: GeodeticPoint) -> list[tuple[float, float, float]]:
    lat, lon, alt = enu_to_geodetic(np.atleast_2d(points_enu), origin)
    return [(float(a), float(b), float(c)) for a, b, c in zip(lon, lat, alt, strict=True)]


def _ring(xy: np.ndarray, z: float, origin: GeodeticPoint) -> Polygon:
    pts = np.column_stack([xy, np.full(len(xy), z)])
    coords = _lonlatalt(np.vstack([pts, pts[:1]]), origin)
    return Polygon(geometry=geo.Polygon(coords), altitude_mode=AltitudeMode.absolute)


def _solid(region: Region, origin: GeodeticPoint) -> MultiGeometry:
    """The region's floor, roof and walls as polygons."""
    xy = region.footprint_xy()
    z0, z1 = region.lo_enu_m[2], region.hi_enu_m[2]
    faces = [_ring(xy, z0, origin), _ring(xy, z1, origin)]
    for i in range(len(xy)):
        a, b = xy[i], xy[(i + 1) % len(xy)]
        wall = np.array([[*a, z0], [*b, z0], [*b, z1], [*a, z1], [*a, z0]])
        faces.append(
            Polygon(
                geometry=geo.Polygon(_lonlatalt(wall, origin)), altitude_mode=AltitudeMode.absolute
            )
        )
    return MultiGeometry(kml_geometries=faces)


def _styles() -> list[Style]:
    out = [
        Style(id=sid, styles=[LineStyle(color=line, width=1.5), PolyStyle(color=fill)])
        for sid, line, fill in _STYLES
    ]
    out += [
        Style(id=f"path{i}", styles=[LineStyle(color=c, width=2.5)])
        for i, c in enumerate(_PATH_COLOURS)
    ]
    return out


def _folder(name: str, features: Sequence[Placemark]) -> Folder:
    return Folder(name=name, features=list(features))


def plan_kml(plan: Plan, name: str = "plan") -> str:
    """The KML document of ``plan`` (see the module docstring)."""
    origin = plan.origin
    paths = []
    for i, v in enumerate(plan.vehicles):
        tr = v.trajectory
        t = np.append(np.arange(0.0, tr.duration_s, PATH_DT_S), tr.duration_s)
        line = LineString(
            geometry=geo.LineString(_lonlatalt(tr.position(t), origin)),
            altitude_mode=AltitudeMode.absolute,
        )
        paths.append(
            Placemark(
                name=v.name,
                style_url=StyleUrl(url=f"#path{i % len(_PATH_COLOURS)}"),
                kml_geometry=line,
            )
        )
    poles: list[Placemark] = []
    keep_outs: list[Placemark] = []
    inspection: list[Placemark] = []
    others: list[Placemark] = []
    for r in plan.regions:
        style = (
            "keep-out"
            if r.kind in _KEEP_OUT
            else "inspection"
            if r.kind is RegionKind.INSPECTION
            else "region"
        )
        mark = Placemark(
            name=r.name, style_url=StyleUrl(url=f"#{style}"), kml_geometry=_solid(r, origin)
        )
        {"keep-out": keep_outs, "inspection": inspection, "region": others}[style].append(mark)
        if r.kind is RegionKind.POLE:
            c = np.asarray(r.center_enu_m, dtype=float)
            foot = float(r.lo_enu_m[2])  # the pole's ground (over a terrain, its own)
            ((lon, lat, alt),) = _lonlatalt(np.array([c[0], c[1], foot]), origin)
            point = Point(geometry=geo.Point(lon, lat, alt), altitude_mode=AltitudeMode.absolute)
            poles.append(Placemark(name=r.name, kml_geometry=point))
    ws = plan.workspace
    outline = Placemark(
        name="workspace",
        style_url=StyleUrl(url="#workspace"),
        kml_geometry=_ring(ws.footprint_xy(), ws.lo_enu_m[2], origin),
    )
    folders = [
        _folder("paths", paths),
        _folder("poles", poles),
        _folder("keep-outs", keep_outs),
        _folder("inspection", inspection),
        _folder("regions", others),
        outline,
    ]
    doc = Document(name=name, styles=_styles(), features=folders)
    return str(kml.KML(features=[doc]).to_string(prettyprint=True))


def kml_bytes(plan: Plan, kmz: bool, name: str = "plan") -> bytes:
    """:func:`plan_kml` as a file's bytes: KML text (UTF-8), or zipped as ``doc.kml``."""
    text = ('<?xml version="1.0" encoding="UTF-8"?>\n' + plan_kml(plan, name)).encode()
    if not kmz:
        return text
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("doc.kml", text)
    return buf.getvalue()
