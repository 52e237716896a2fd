"""The ``line:`` section: poles, conductor keep-outs and inspection boxes from pole
coordinates (ENU, geodetic, a GIS export), checked against the geometry they promise."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from planner.scenario import ScenarioError, load_scenario, parse_scenario
from planner.spec.regions import Cylinder, Prism
from tests.planner.line_support import enu_poles, geodetic, pole_centres, scenario


def _along(bearing: float, count: int = 4) -> str:
    return f"  along: {{start: [0, 0], bearing_deg: {bearing}, span_m: 30, count: {count}}}\n"


def test_poles_along_a_bearing_are_spaced_and_turned_as_asked() -> None:
    pr = parse_scenario(scenario(_along(37.0)), "l.yaml")
    b = math.radians(37.0)
    u = np.array([math.sin(b), math.cos(b)])
    for i in range(4):
        pole = pr.region(f"pole{i + 1}")
        assert isinstance(pole.shape, Cylinder)
        np.testing.assert_allclose(pole.shape.center_xy, 30.0 * i * u, atol=1e-9)
        assert (pole.shape.radius_m, pole.shape.z_lo_m, pole.shape.z_hi_m) == (0.4, 0.0, 12.0)
    assert [r.name for r in pr.regions if r.name.startswith("span")] == ["span1", "span2", "span3"]
    assert all(isinstance(r.shape, Prism) for r in pr.regions if r.name[:4] in ("span", "insp"))


def test_a_line_along_an_axis_makes_axis_aligned_boxes() -> None:
    pr = parse_scenario(scenario(_along(90.0)), "l.yaml")
    assert all(r.shape is None for r in pr.regions if r.name[:4] in ("span", "insp"))
    insp = pr.region("insp2")  # east-bound: the right is south
    np.testing.assert_allclose(insp.lo_enu_m, (27.5, -1.8 - 1.5 - 2.2, 9.5), atol=1e-9)
    np.testing.assert_allclose(insp.hi_enu_m, (32.5, -1.8 - 1.5, 12.5), atol=1e-9)


@pytest.mark.parametrize("side", ["right", "left", "both"])
def test_inspection_boxes_face_the_insulators_from_the_standoff(side: str) -> None:
    pr = parse_scenario(scenario(_along(37.0), side), "l.yaml")
    b = math.radians(37.0)
    u = np.array([math.sin(b), math.cos(b)])
    left = np.array([-u[1], u[0]])
    sides = ["left", "right"] if side == "both" else [side]
    for i in range(4):
        pole = 30.0 * i * u
        for s in sides:
            name = f"insp{i + 1}" if side != "both" else f"insp{i + 1}_{s}"
            box = pr.region(name)
            n = left if s == "left" else -left
            insulator = np.array([[*(pole + 1.8 * n), 11.0]])
            # the outer insulator is exactly the standoff from the box's near face
            assert box.margin(insulator)[0] == pytest.approx(-1.5, abs=1e-9)
            deep = np.array([[*(pole + (1.8 + 1.5 + 1.1) * n), 11.0]])
            assert box.margin(deep)[0] == pytest.approx(1.1, abs=1e-9)  # half its depth
            other = np.array([[*(pole - (1.8 + 1.5 + 1.1) * n), 11.0]])
            assert box.margin(other)[0] < -5.0  # nothing on the other side


def test_the_span_keep_outs_hold_the_conductors_with_the_clearance() -> None:
    pr = parse_scenario(scenario(_along(37.0)), "l.yaml")
    b = math.radians(37.0)
    u = np.array([math.sin(b), math.cos(b)])
    left = np.array([-u[1], u[0]])
    for j in range(3):
        span = pr.region(f"span{j + 1}")
        t = np.linspace(0, 30, 61)[:, None]
        for off in (-1.8, 0.0, 1.8):
            for z in (9.0, 10.5, 12.0):
                wire = np.column_stack([30.0 * j * u + t * u + off * left, np.full(len(t), z)])
                m = span.margin(wire)
                assert np.all(m >= 1.0 - 1e-9), (j, off, z, m.min())
        # the outer conductors and the heights' ends sit exactly the clearance inside
        edge = np.array([[*(30.0 * j * u + 15 * u + 1.8 * left), 12.0]])
        assert span.margin(edge)[0] == pytest.approx(1.0, abs=1e-9)


def test_poles_given_as_enu_geodetic_csv_or_geojson_are_the_same_line(tmp_path: Path) -> None:
    xy = enu_poles()
    ll = geodetic(xy)
    listed = "  poles: [" + ", ".join(f"[{x}, {y}]" for x, y in xy) + "]\n"
    geo = "  poles: [" + ", ".join(f"{{lat: {a!r}, lon: {o!r}}}" for a, o in ll) + "]\n"
    (tmp_path / "poles.csv").write_text(
        "id,lat,lon\n" + "".join(f"P{i},{a!r},{o!r}\n" for i, (a, o) in enumerate(ll))
    )
    (tmp_path / "xy.csv").write_text("x,y\n" + "".join(f"{x},{y}\n" for x, y in xy))
    feats = [
        {
            "type": "Feature",
            "properties": {"id": i},
            "geometry": {"type": "Point", "coordinates": [o, a]},
        }
        for i, (a, o) in enumerate(ll)
    ]
    (tmp_path / "poles.geojson").write_text(
        json.dumps({"type": "FeatureCollection", "features": feats})
    )
    (tmp_path / "route.geojson").write_text(
        json.dumps(
            {
                "type": "Feature",
                "geometry": {"type": "LineString", "coordinates": [[o, a] for a, o in ll]},
            }
        )
    )
    for poles in (
        listed,
        geo,
        "  file: poles.csv\n",
        "  file: xy.csv\n",
        "  file: poles.geojson\n",
        "  file: route.geojson\n",
    ):
        path = tmp_path / "s.yaml"
        path.write_text(yaml.safe_dump(scenario(poles)))
        got = pole_centres(load_scenario(path))
        np.testing.assert_allclose(got, xy, atol=1e-6, err_msg=poles)


def test_the_line_names_bind_in_each() -> None:
    pr = parse_scenario(scenario(_along(37.0)), "l.yaml")
    texts = [c.text for c in pr.clauses]
    assert sum("outside(d1, span" in t for t in texts) == 3
    assert sum("outside(d2, pole" in t for t in texts) == 4


@pytest.mark.parametrize(
    ("line", "says"),
    [
        (_along(37.0, 1), r"line\.along\.count.*>= 2"),
        (_along(37.0) + "  poles: [[0, 0], [3, 3]]\n", "one way"),
        ("  poles: [[0, 0], [0.5, 0]]\n", r"poles 1 and 2 are 0\.5 m apart"),
        ("  poles: [[0, 0], {lat: 47.4}]\n", r"line\.poles\[1\]"),
        ("  file: missing.csv\n", r"line\.file.*cannot read"),
        ("  along: {start: [0, 0], bearing_deg: 37, span_m: -3, count: 3}\n", r"span_m.*> 0"),
    ],
)
def test_a_bad_line_is_one_line_naming_its_field(line: str, says: str) -> None:
    with pytest.raises(ScenarioError, match=says) as err:
        parse_scenario(scenario(line), "l.yaml")
    assert "\n" not in str(err.value)


def test_a_bad_side_or_key_names_its_field() -> None:
    with pytest.raises(ScenarioError, match=r"line\.inspection\.side.*left, right, both"):
        parse_scenario(scenario(_along(37.0), "north"), "l.yaml")
    bad = scenario(_along(37.0))
    bad["line"]["pole"]["radius"] = 1
    with pytest.raises(ScenarioError, match=r"line\.pole\.radius.*unknown key"):
        parse_scenario(bad, "l.yaml")


def test_a_bad_gis_file_is_one_line_naming_the_file_and_row(tmp_path: Path) -> None:
    (tmp_path / "bad.csv").write_text("lat,lon\n47.39,8.54\n47.40,eight\n")
    (tmp_path / "empty.geojson").write_text('{"type": "FeatureCollection", "features": []}')
    (tmp_path / "cols.csv").write_text("a,b\n1,2\n")
    for name, says in (
        ("bad.csv", "bad.csv line 3, column lon: expected a number, got 'eight'"),
        ("empty.geojson", "no Point features"),
        ("cols.csv", "expected columns x,y"),
    ):
        path = tmp_path / "s.yaml"
        path.write_text(yaml.safe_dump(scenario(f"  file: {name}\n")))
        with pytest.raises(ScenarioError, match=says):
            load_scenario(path)


def test_a_region_named_like_a_line_part_is_refused() -> None:
    data = scenario(_along(37.0))
    data["regions"] = {"pole2": {"min": [0, 0, 0], "max": [1, 1, 1]}}
    with pytest.raises(ScenarioError, match=r"regions\.pole2.*line section"):
        parse_scenario(data, "l.yaml")


@pytest.mark.slow
def test_a_line_along_a_bearing_plans_to_its_optimum() -> None:
    from planner.optimize import plan

    data = scenario(_along(37.0))
    c, s = math.cos(math.radians(53.0)), math.sin(math.radians(53.0))
    for v in data["vehicles"]:  # the starts turned with the line about pole 1
        x, y, z = v["start"]
        v["start"] = [c * x - s * y, s * x + c * y, z]
    result = plan(parse_scenario(data, "l.yaml"))
    assert result.success, result.status
    # the inspection box's half-depth (1.1 m) is the optimum: every keep-out stays clear
    assert result.robustness >= 0.97 * 1.1, result.robustness
