"""Towers from KML or KMZ (Google Earth, utility GIS exports), read with fastkml.

KML (OGC 07-147r2, KML 2.2) gives a ``Point`` or a ``LineString`` as ``coordinates``:
``lon,lat[,alt]`` tuples, degrees on WGS84, altitude in metres. A KMZ is a zip archive
whose main KML is ``doc.kml`` or, failing that, the first ``.kml`` entry (Google's KMZ
reference). Tower files come two ways: one Placemark per tower (a ``Point``, in document
order, folders included), or the line as one ``LineString`` whose vertices are the towers.
The Points are taken if there are any (so a plan exported by ``gcs export --format kml``,
whose poles are Points beside the vehicles' paths, reads back as its poles), else the one
LineString; two LineStrings and no Point is refused as ambiguous.

Files written under the old Google namespaces (``http://earth.google.com/kml/2.x``) or none
are read as KML 2.2: fastkml reads one namespace only, so the tags are moved into it first.
"""

from __future__ import annotations

import io
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from fastkml import kml
from fastkml.exceptions import FastKMLError
from fastkml.features import Placemark
from lxml import etree

from planner.errors import PlannerError

__all__ = ["KML_NS", "KmlError", "kml_towers", "main_kml", "read_kml_towers"]

#: The KML 2.2 namespace (OGC).
KML_NS = "http://www.opengis.net/kml/2.2"
#: Namespaces read as KML 2.2 (Google's before OGC's, and none).
_OLD_NS = ("http://earth.google.com/kml/2.0", "http://earth.google.com/kml/2.1",
           "http://earth.google.com/kml/2.2", "")  # fmt: skip


class KmlError(PlannerError, ValueError):
    """A KML/KMZ file that gives no towers: the reason, in one line."""


def main_kml(data: bytes, name: str) -> bytes:
    """The KML text of ``data``: itself, or a KMZ's main KML."""
    if not data.startswith(b"PK"):
        return data
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            kmls = [n for n in z.namelist() if n.lower().endswith(".kml")]
            if not kmls:
                raise KmlError(f"{name}: a zip archive with no .kml file in it (not a KMZ)")
            main = "doc.kml" if "doc.kml" in kmls else kmls[0]
            return z.read(main)
    except zipfile.BadZipFile as exc:
        raise KmlError(f"{name}: not a KMZ (zip) archive: {exc}") from None


def _in_kml22(text: bytes, name: str) -> str:
    """``text`` with the old Google namespaces (or none) moved into KML 2.2's, as a string
    without its XML declaration (which fastkml's parser refuses in a string)."""
    parser = etree.XMLParser(resolve_entities=False, no_network=True, huge_tree=False)
    try:
        root = etree.fromstring(text, parser)
    except etree.XMLSyntaxError as exc:
        raise KmlError(f"{name}: not KML (XML line {exc.lineno}: {exc.msg})") from None
    if etree.QName(root).localname != "kml":
        raise KmlError(f"{name}: not KML (its root element is <{etree.QName(root).localname}>)")
    if etree.QName(root).namespace != KML_NS:
        for el in root.iter():
            if isinstance(el.tag, str) and (etree.QName(el).namespace or "") in _OLD_NS:
                el.tag = f"{{{KML_NS}}}{etree.QName(el).localname}"
        etree.cleanup_namespaces(root)
    return str(etree.tostring(root, encoding="unicode"))


def _placemarks(feature: Any) -> Iterator[Placemark]:
    """The Placemarks under ``feature``, in document order (into folders and documents)."""
    for f in getattr(feature, "features", None) or []:
        if isinstance(f, Placemark):
            yield f
        else:
            yield from _placemarks(f)


def kml_towers(data: bytes, name: str, absolute_only: bool = False) -> np.ndarray:
    """Towers ``(n, 3)`` as ``lat, lon, alt`` (degrees, metres; alt NaN where none is given)
    from KML or KMZ bytes (see the module docstring for which geometries). With
    ``absolute_only``, alt is NaN too where the geometry's ``altitudeMode`` is not
    ``absolute`` (KML's default, ``clampToGround``, ignores the altitude; Google Earth writes
    0 there).

    Raises:
        KmlError: not KML/KMZ, no Point or LineString, two LineStrings, a bad coordinate.
    """
    text = _in_kml22(main_kml(data, name), name)
    try:
        doc = kml.KML.from_string(text)
    except (FastKMLError, ValueError, TypeError) as exc:
        raise KmlError(f"{name}: {str(exc).splitlines()[0][:200]}") from None
    points: list[tuple[float, ...]] = []
    lines: list[list[tuple[float, ...]]] = []
    for pm in _placemarks(doc):
        g: Any = pm.geometry  # pygeoif's: Point and LineString have coords
        kind = getattr(g, "geom_type", None)
        if kind not in ("Point", "LineString"):
            continue
        mode = getattr(getattr(pm, "kml_geometry", None), "altitude_mode", None)
        drop = absolute_only and getattr(mode, "value", None) != "absolute"
        coords = [tuple(c)[:2] if drop else tuple(c) for c in g.coords]
        if kind == "Point":
            points.append(coords[0])
        elif kind == "LineString":
            lines.append(coords)
    if points:
        coords = points
    elif len(lines) == 1:
        coords = lines[0]
    elif lines:
        raise KmlError(
            f"{name}: {len(lines)} LineStrings and no Point: which one is the line? (give "
            "the towers as Points, or one LineString)"
        )
    else:
        raise KmlError(f"{name}: no Placemark with a Point or a LineString")
    out = np.full((len(coords), 3), np.nan)
    for i, c in enumerate(coords):
        lon, lat = float(c[0]), float(c[1])
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):
            raise KmlError(
                f"{name}: coordinate {i + 1} is out of range (KML is lon,lat[,alt]: {lon:g},{lat:g})"
            )
        out[i, :2] = lat, lon
        if len(c) > 2:
            out[i, 2] = float(c[2])
    return out


def read_kml_towers(path: Path, absolute_only: bool = False) -> np.ndarray:
    """:func:`kml_towers` of the file at ``path``."""
    return kml_towers(path.read_bytes(), path.name, absolute_only)
