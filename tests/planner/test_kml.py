"""Towers from KML and KMZ (planner.scenario.kml, ``line: file:``), and a plan exported as KML
(gcs.kml, ``gcs export --format kml``) read back.

References: the same towers given as a ``poles:`` list of lat/lon (the scenario reader's own
path, which the CSV and GeoJSON tests check against pymap3d); KML's coordinate order
lon,lat[,alt] (OGC 07-147r2); pymap3d for the exported paths' geodetic coordinates.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import pymap3d
import pytest
import yaml

from gcs import cli
from planner.optimize import plan
from planner.planfile import load_plan, save_plan
from planner.scenario import ScenarioError, load_scenario
from planner.scenario.kml import kml_towers
from tests.planner.line_support import ORIGIN, enu_poles, geodetic, pole_centres, scenario

KML22 = "http://www.opengis.net/kml/2.2"


def _points_kml(ll: list[tuple[float, float]], ns: str = KML22, alt: float = 0.0) -> str:
    """One Placemark per tower, in two folders."""
    marks = [
        f"<Placemark><name>T{i}</name><Point><coordinates>{o!r},{a!r},{alt}</coordinates>"
        "</Point></Placemark>"
        for i, (a, o) in enumerate(ll)
    ]
    half = len(marks) // 2
    xmlns = f' xmlns="{ns}"' if ns else ""
    return (
        f'<?xml version="1.0" encoding="UTF-8"?><kml{xmlns}><Document><name>towers</name>'
        f"<Folder><name>west</name>{''.join(marks[:half])}</Folder>"
        f"<Folder><name>east</name>{''.join(marks[half:])}</Folder></Document></kml>"
    )


def _line_kml(ll: list[tuple[float, float]]) -> str:
    coords = " ".join(f"{o!r},{a!r},0" for a, o in ll)
    return (
        f'<kml xmlns="{KML22}"><Placemark><name>route</name><LineString>'
        f"<coordinates>{coords}</coordinates></LineString></Placemark></kml>"
    )


def _kmz(text: str, name: str = "doc.kml") -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("files/readme.txt", "not the kml")
        z.writestr(name, text)
    return buf.getvalue()


def _load_with(tmp_path: Path, file_name: str) -> np.ndarray:
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(scenario(f"  file: {file_name}\n")))
    return pole_centres(load_scenario(path))


def test_towers_from_kml_points_a_linestring_old_namespaces_and_kmz_are_the_same_line(
    tmp_path: Path,
) -> None:
    xy = enu_poles()
    ll = geodetic(xy)
    listed = "  poles: [" + ", ".join(f"{{lat: {a!r}, lon: {o!r}}}" for a, o in ll) + "]\n"
    want = pole_centres(load_scenario(_write(tmp_path, listed)))
    np.testing.assert_allclose(want, xy, atol=1e-6)
    files = {
        "points.kml": _points_kml(ll).encode(),
        "route.kml": _line_kml(ll).encode(),
        "google21.kml": _points_kml(ll, "http://earth.google.com/kml/2.1").encode(),
        "bare.kml": _points_kml(ll, "").encode(),
        "towers.kmz": _kmz(_points_kml(ll)),
        "other_name.KMZ": _kmz(_line_kml(ll), "line.kml"),
    }
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
        np.testing.assert_allclose(_load_with(tmp_path, name), want, atol=1e-6, err_msg=name)


def _write(tmp_path: Path, line: str) -> Path:
    path = tmp_path / "listed.yaml"
    path.write_text(yaml.safe_dump(scenario(line)))
    return path


def test_kml_altitudes_are_read_and_missing_ones_are_nan() -> None:
    ll = geodetic(enu_poles())
    got = kml_towers(_points_kml(ll, alt=512.5).encode(), "t.kml")
    np.testing.assert_allclose(got[:, :2], np.array(ll), atol=1e-12)
    assert np.all(got[:, 2] == 512.5)
    two_d = _line_kml(ll).replace(",0 ", " ").replace(",0<", "<")
    assert np.all(np.isnan(kml_towers(two_d.encode(), "t.kml")[:, 2]))


@pytest.mark.parametrize(
    ("data", "says"),
    [
        (b"id,lat,lon\n1,2,3\n", r"bad\.kml: not KML \(XML line 1"),
        (b"<gpx><wpt/></gpx>", r"bad\.kml: not KML \(its root element is <gpx>\)"),
        (f'<kml xmlns="{KML22}"><Document/></kml>'.encode(), "no Placemark with a Point or"),
        (
            _line_kml([(47.4, 8.5), (47.5, 8.6)])
            .replace(
                "</kml>",
                "<Placemark><LineString><coordinates>8.5,47.4 8.6,47.5</coordinates>"
                "</LineString></Placemark></kml>",
            )
            .encode(),
            "2 LineStrings and no Point",
        ),
        (
            _points_kml([(120.5, 30.1), (120.6, 30.2)]).encode(),
            r"coordinate 1 is out of range \(KML is lon,lat",
        ),
        (_points_kml([(47.4, 8.5)]).replace("8.5,", "eight,").encode(), "bad.kml: Invalid"),
    ],
)
def test_a_bad_kml_is_one_line_naming_the_field_and_file(
    tmp_path: Path, data: bytes, says: str
) -> None:
    (tmp_path / "bad.kml").write_bytes(data)
    with pytest.raises(ScenarioError, match=says) as err:
        _load_with(tmp_path, "bad.kml")
    assert str(err.value).count("\n") == 0 and "line.file" in str(err.value)


def test_a_kmz_without_kml_or_not_a_zip_is_refused(tmp_path: Path) -> None:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("readme.txt", "no kml here")
    (tmp_path / "empty.kmz").write_bytes(buf.getvalue())
    with pytest.raises(ScenarioError, match=r"empty\.kmz: a zip archive with no \.kml"):
        _load_with(tmp_path, "empty.kmz")
    (tmp_path / "broken.kmz").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(ScenarioError, match=r"broken\.kmz: not a KMZ"):
        _load_with(tmp_path, "broken.kmz")


def test_import_plan_export_and_import_again_keeps_the_towers(tmp_path: Path) -> None:
    # Towers from a KMZ (the 4-pole line along 37 degrees), planned, exported as KML and KMZ
    # by `gcs export`, then read back as a line: the same towers within 1e-6 deg.
    ll = geodetic(enu_poles())
    (tmp_path / "towers.kmz").write_bytes(_kmz(_points_kml(ll)))
    scen_path = tmp_path / "s.yaml"
    scen_path.write_text(yaml.safe_dump(scenario("  file: towers.kmz\n")))
    result = plan(load_scenario(scen_path))
    assert result.success, result.status
    plan_path = tmp_path / "plan.json"
    save_plan(plan_path, result, str(scen_path))
    for out in ("plan.kml", "plan.kmz"):
        assert (
            cli.main(["export", str(plan_path), "--format", "kml", "-o", str(tmp_path / out)]) == 0
        )
        back = kml_towers((tmp_path / out).read_bytes(), out)
        np.testing.assert_allclose(back[:, :2], np.array(ll), atol=1e-6, rtol=0)
        np.testing.assert_allclose(back[:, 2], ORIGIN["alt"], atol=1e-3)  # on the ground
        np.testing.assert_allclose(_load_with(tmp_path, out), enu_poles(), atol=1e-3)
    # the paths: each vehicle's LineString starts where its trajectory does (pymap3d)
    text = (tmp_path / "plan.kml").read_text()
    saved = load_plan(plan_path)
    for v in saved.vehicles:
        x, y, z = v.trajectory.position(np.array([0.0]))[0]
        lat, lon, alt = pymap3d.enu2geodetic(x, y, z, ORIGIN["lat"], ORIGIN["lon"], ORIGIN["alt"])
        start = text.split(f"<name>{v.name}</name>")[1].split("<coordinates>")[1].split(" ")[0]
        got = [float(c) for c in start.split(",")]
        np.testing.assert_allclose(got, [lon, lat, alt], atol=1e-7)
    # every region is a solid in its folder; keep-outs and inspection places apart
    assert text.count("<MultiGeometry>") == len(saved.regions)
    assert "<name>keep-outs</name>" in text and "<name>inspection</name>" in text
