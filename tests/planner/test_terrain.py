"""The ground from an elevation model (a GeoTIFF), ``agl(d)`` over it, and the line's heights
above it: checked against the surfaces the rasters were made from, rasterio's own reading of
a pixel, and brute-force heights above ground along a planned path."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pymap3d
import pytest
import yaml
from rasterio.warp import transform

from planner.milp.solve import solve_coarse
from planner.optimize import plan
from planner.planfile import PlanFileError, load_plan, plan_formula, save_plan
from planner.scenario import ScenarioError, load_scenario
from planner.spec.geometry import keep_out, place
from planner.spec.predicates import build_registry
from planner.spec.terrain import TerrainError, terrain_from_geotiff, write_geotiff
from planner.stl import parse
from planner.trajectory import Trajectory
from tests.planner.line_support import enu_poles, geodetic
from tests.planner.line_support import scenario as line_scenario
from tests.terrain_support import (
    E0,
    N0,
    O3,
    ORIGIN,
    ground_reference,
    plane,
    ridge,
    ridge_scenario,
    utm_raster,
)


def test_a_utm_raster_gives_the_surface_it_was_made_from(tmp_path: Path) -> None:
    utm_raster(tmp_path / "dem.tif", plane)
    t = terrain_from_geotiff(str(tmp_path / "dem.tif"), ORIGIN, [-100, -80], [300, 150])
    assert t.step_m == pytest.approx(5.0, rel=0.01)  # the pixel's size on the ground
    xy = np.random.default_rng(1).uniform([-100, -80], [300, 150], size=(50, 2))
    # a plane is bilinear in any grid: the only errors are the sampling's round-offs
    np.testing.assert_allclose(t.ground(xy), ground_reference(xy, plane), atol=1e-3)
    assert t.ground([0.0, 0.0])[0] == pytest.approx(-8.0, abs=1e-3)  # 480 m under 488 m
    # agl is z less that ground
    p = np.column_stack([xy, np.full(len(xy), 20.0)])
    np.testing.assert_allclose(t.agl(p), 20.0 - t.ground(xy))


def test_each_node_is_the_raster_read_bilinearly_between_its_pixel_centres(
    tmp_path: Path,
) -> None:
    """Against the raster's geometry as written (its corner and pixel size) and rasterio's own
    reading of its pixels (``sample`` at their centres), on a rough surface no plane explains."""
    import rasterio

    rough = np.random.default_rng(7).normal(0.0, 3.0, size=(80, 120))
    utm_raster(tmp_path / "dem.tif", lambda e, n: 500.0 + rough)
    t = terrain_from_geotiff(str(tmp_path / "dem.tif"), ORIGIN, [-150, -150], [350, 150])
    nodes = [(3, 5), (20, 17), (47, 31), (88, 52)]
    xy = np.array([[t.xs_m[i], t.ys_m[j]] for i, j in nodes])
    lat, lon, _ = pymap3d.enu2geodetic(xy[:, 0], xy[:, 1], 0.0, *O3)
    e, n = transform("EPSG:4326", "EPSG:32632", list(lon), list(lat))
    with rasterio.open(tmp_path / "dem.tif") as src:
        for k, (i, j) in enumerate(nodes):
            west, north = E0 - 200.0, N0 + 200.0  # as utm_raster wrote it, 5 m pixels
            r = (north - n[k]) / 5.0 - 0.5  # from the pixel centres
            c = (e[k] - west) / 5.0 - 0.5
            r0, c0 = math.floor(r), math.floor(c)
            centres = [src.xy(r0 + dr, c0 + dc) for dr in (0, 1) for dc in (0, 1)]
            v = [float(s[0]) for s in src.sample(centres)]
            fr, fc = r - r0, c - c0
            h = (
                v[0] * (1 - fr) * (1 - fc)
                + v[1] * (1 - fr) * fc
                + v[2] * fr * (1 - fc)
                + v[3] * fr * fc
            )
            z = pymap3d.geodetic2enu(lat[k], lon[k], h, *O3)[2]
            assert t.ground_z_m[i, j] == pytest.approx(z, abs=5e-4)  # kept to the mm
            assert t.ground(xy[k])[0] == t.ground_z_m[i, j]  # on a node: the node


def test_a_geographic_raster_reads_too(tmp_path: Path) -> None:
    """SRTM's kind of raster: EPSG:4326, heights per degree; a plane in degrees is bilinear."""
    px = 5e-5  # degrees (about 5.6 m north, 3.8 m east)

    def height(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
        return 470.0 + 2e4 * (lat - ORIGIN.lat_deg) - 1e4 * (lon - ORIGIN.lon_deg)

    west, north = ORIGIN.lon_deg - 0.004, ORIGIN.lat_deg + 0.003
    cols, rows = np.meshgrid(np.arange(160), np.arange(120))
    write_geotiff(
        str(tmp_path / "srtm.tif"),
        height(north - (rows + 0.5) * px, west + (cols + 0.5) * px),
        west,
        north,
        px,
        "EPSG:4326",
    )
    t = terrain_from_geotiff(str(tmp_path / "srtm.tif"), ORIGIN, [-200, -250], [250, 250])
    xy = np.random.default_rng(3).uniform([-200, -250], [250, 250], size=(40, 2))
    lat, lon, _ = pymap3d.enu2geodetic(xy[:, 0], xy[:, 1], 0.0, *O3)
    ref = pymap3d.geodetic2enu(lat, lon, height(lat, lon), *O3)[2]
    np.testing.assert_allclose(t.ground(xy), ref, atol=1e-3)


def test_a_raster_that_does_not_cover_the_workspace_is_refused_by_place(tmp_path: Path) -> None:
    utm_raster(tmp_path / "dem.tif", plane)
    with pytest.raises(TerrainError, match=r"dem.tif: does not cover .* is outside the raster"):
        terrain_from_geotiff(str(tmp_path / "dem.tif"), ORIGIN, [-100, -80], [900, 150])
    utm_raster(tmp_path / "dem.tif", plane, nodata_at=((40, 60),))
    # pixel (40, 60) is 100 m east of the west edge, 0 north of the origin: a hole there
    with pytest.raises(TerrainError, match=r"has no data \(nodata\)"):
        terrain_from_geotiff(str(tmp_path / "dem.tif"), ORIGIN, [-150, -50], [100, 50])
    (tmp_path / "not.tif").write_text("hello")
    with pytest.raises(TerrainError, match=r"not.tif: cannot read as a GeoTIFF"):
        terrain_from_geotiff(str(tmp_path / "not.tif"), ORIGIN, [0, 0], [10, 10])


def test_casadi_reads_the_same_ground_as_the_exact_semantics(tmp_path: Path) -> None:
    import casadi as ca

    rough = np.random.default_rng(2).normal(0.0, 2.0, size=(80, 120))
    utm_raster(tmp_path / "dem.tif", lambda e, n: 490.0 + rough)
    t = terrain_from_geotiff(str(tmp_path / "dem.tif"), ORIGIN, [-50, -50], [150, 100])
    xy = np.random.default_rng(4).uniform([-80, -80], [180, 130], size=(200, 2))  # some beyond
    sym = ca.SX.sym("p", 200, 2)
    f = ca.Function("g", [sym], [t.ca_ground(sym)])
    np.testing.assert_allclose(np.asarray(f(xy)).ravel(), t.ground(xy), atol=1e-9)
    inside = np.all((xy >= [-50, -50]) & (xy <= [150, 100]), axis=1)
    assert 0 < inside.sum() < len(xy)  # both kinds checked


# ------------------------------------------------------------------------- scenarios


def test_heights_of_the_line_and_the_starts_are_above_the_ground_there(tmp_path: Path) -> None:
    line = {
        "along": {"start": [0, 10], "bearing_deg": 90, "span_m": 40, "count": 3},
        "pole": {"radius_m": 0.4, "height_m": 12},
        "conductors": {"half_width_m": 1.8, "z": [9, 12], "clearance_m": 1.0},
        "inspection": {"standoff_m": 1.5, "depth_m": 2.2, "length_m": 5, "z": [9.5, 12.5]},
    }
    p = load_scenario(ridge_scenario(tmp_path, line=line, spec=["always[0, 30] agl(d1) >= 1"]))
    # the ground at each pole as the terrain has it (how near that is to the surface the
    # raster was made from is the tests above's business: on this ridge's crest, 0.9 m)
    ground = p.terrain.ground(np.array([[0.0, 10.0], [40.0, 10.0], [80.0, 10.0]]))
    for i, g in enumerate(ground, start=1):
        pole = p.region(f"pole{i}").shape
        assert (pole.z_lo_m, pole.z_hi_m) == pytest.approx((g, g + 12.0), abs=1e-3)
        assert p.region(f"insp{i}").lo_enu_m[2] == pytest.approx(g + 9.5, abs=1e-3)
    # a span's level keep-out reaches from the lower pole's conductors to the higher one's
    span1 = p.region("span1")
    assert span1.lo_enu_m[2] == pytest.approx(min(ground[:2]) + 8.0, abs=1e-3)
    assert span1.hi_enu_m[2] == pytest.approx(max(ground[:2]) + 13.0, abs=1e-3)
    start = p.vehicles[0].start_enu_m
    assert start[2] == pytest.approx(p.terrain.ground([0.0, 0.0])[0] + 4.0)
    # min_agl_m is a clause per vehicle, named by the section
    floor = [c for c in p.clauses if c.key_path == "terrain.min_agl_m"]
    assert [c.text for c in floor] == ["always[0, 30] (agl(d1) >= 3)"]


@pytest.mark.parametrize(
    ("over", "key", "words"),
    [
        (
            {"terrain": None, "spec": ["always[0, 30] agl(d1) >= 1"]},
            "spec[0]",
            "is a height above the ground, and the scenario has none",
        ),
        ({"terrain": {"file": "nowhere.tif"}}, "terrain.file", "nowhere.tif: no such file"),
        ({"terrain": {"file": "ridge.tif", "min_agl_m": -1}}, "terrain.min_agl_m", ">= 0"),
        ({"terrain": {"file": "ridge.tif", "hight": 3}}, "terrain.hight", "unknown key"),
        (
            {"workspace": {"min": [-20, -20, -10], "max": [900, 20, 40]}},
            "terrain.file",
            "does not cover the workspace",
        ),
        (
            {"workspace": {"min": [-20, -20, -10], "max": [100, 20, 12]}},
            "terrain",
            "the ground rises to z = 11.2 m under the workspace (+ min_agl_m 3), not below its",
        ),
    ],
)
def test_terrain_mistakes_are_one_line_naming_the_key(
    tmp_path: Path, over: dict[str, object], key: str, words: str
) -> None:
    path = ridge_scenario(tmp_path, **over)
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert err.value.key_path == key
    assert words in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.slow
def test_a_path_over_aridge_keeps_its_height_above_the_ground(tmp_path: Path) -> None:
    """Planned with the floor, the path climbs over the ridge; the heights above ground along
    it, sampled densely and measured on the surface itself, keep min_agl_m."""
    path = ridge_scenario(tmp_path)
    problem = load_scenario(path)
    res = plan(problem)
    assert res.success, res.status
    save_plan(tmp_path / "ridge.plan.json", res, str(path))
    back = load_plan(tmp_path / "ridge.plan.json")
    assert back.terrain == problem.terrain  # the grid travels with the plan
    traj: Trajectory = back.vehicles[0].trajectory
    pos = traj.position(np.linspace(0.0, 30.0, 3001))
    # the floor on the grid, by hand (bilinear in each cell, not the planner's interpolants)
    g = problem.terrain.ground_z_m
    fx = (pos[:, 0] - problem.terrain.x0_m) / problem.terrain.step_m
    fy = (pos[:, 1] - problem.terrain.y0_m) / problem.terrain.step_m
    i, j = np.floor(fx).astype(int), np.floor(fy).astype(int)
    u, v = fx - i, fy - j
    under = (
        g[i, j] * (1 - u) * (1 - v)
        + g[i + 1, j] * u * (1 - v)
        + g[i, j + 1] * (1 - u) * v
        + g[i + 1, j + 1] * u * v
    )
    assert (pos[:, 2] - under).min() >= 3.0 - 1e-6
    # and over the smooth ridge the raster was made from: within its 5 m pixels' reach
    assert (pos[:, 2] - ground_reference(pos[:, :2], ridge)).min() >= 3.0 - 1.0
    crest = np.argmin(np.abs(pos[:, 0] - 40.0))
    assert pos[crest, 2] > -2.0 + 14.0 + 3.0 - 1.0  # it went over the 14 m ridge
    # the plan's exact check reads the grid it carries: the whole spec holds
    phi = plan_formula(back)
    assert phi.robustness({"d1": traj.position(np.arange(0.0, 30.0 + 1e-9, 0.1))}, dt=0.1) >= (
        problem.epsilon
    )
    # without its terrain the plan cannot be judged, and says why
    data = json.loads((tmp_path / "ridge.plan.json").read_text())
    grid = data.pop("terrain")
    (tmp_path / "bare.plan.json").write_text(json.dumps(data))
    with pytest.raises(PlanFileError, match="is a height above the ground, and the plan has no"):
        plan_formula(load_plan(tmp_path / "bare.plan.json"))
    grid["ground_z_m"][1] = grid["ground_z_m"][1][:-1]
    (tmp_path / "ragged.plan.json").write_text(json.dumps({**data, "terrain": grid}))
    with pytest.raises(PlanFileError, match=r"terrain.ground_z_m.*rows of different lengths"):
        load_plan(tmp_path / "ragged.plan.json")


def test_the_coarse_stage_relaxes_the_floor_and_never_claims_aridge_impossible(
    tmp_path: Path,
) -> None:
    """Beside a ridge a plane through the ground is 3 m over the start: a floor on it would
    make the start break the floor and the coarse program infeasible. Relaxed, the stage plans,
    and its waypoints keep the floor over the plane under the ground."""
    problem = load_scenario(ridge_scenario(tmp_path))
    res = solve_coarse(problem, time_limit_s=20, robustness_cap_m=0.5, min_robustness=0.01)
    assert res.success, res.message
    a, b, c_lo, c_hi = problem.terrain.plane_bounds()
    assert any(n.startswith("agl: relaxed to planes under and over the ground") for n in res.notes)
    w = np.asarray(res.waypoints_enu_m["d1"])
    assert np.all(w[:, 2] - (a * w[:, 0] + b * w[:, 1] + c_lo) >= 3.0 + 0.01 - 1e-6)
    # the planes bound the ground at every node, and so between them
    xs, ys = np.meshgrid(problem.terrain.xs_m, problem.terrain.ys_m, indexing="ij")
    plane = a * xs + b * ys
    assert np.all(plane + c_lo <= problem.terrain.ground_z_m + 1e-9)
    assert np.all(problem.terrain.ground_z_m <= plane + c_hi + 1e-9)
    assert math.isfinite(c_hi - c_lo)


# ------------------------------------------------------------- the ground from the towers

#: ground altitudes (m AMSL) at the feet of line_support's four towers
TOWER_ALT = [490.0, 494.0, 486.0, 500.0]


def _towers_scenario(tmp_path: Path, name: str, text: str) -> Path:
    (tmp_path / name).write_text(text)
    data = line_scenario(f"  file: {name}\n")
    data["terrain"] = {"from": "line", "min_agl_m": 2}
    data["workspace"] = {"min": [-150, -150, -20], "max": [250, 250, 40]}
    data["vehicles"] = [{"name": "d1", "start": [-12, -12, 8]}, {"name": "d2", "start": [-8, -12, 8]}]  # fmt: skip
    path = tmp_path / "towers.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _tower_z(xy: np.ndarray, alt: list[float]) -> np.ndarray:
    lat, lon, _ = pymap3d.enu2geodetic(xy[:, 0], xy[:, 1], 0.0, *O3)
    return np.asarray(pymap3d.geodetic2enu(lat, lon, np.asarray(alt), *O3)[2])


def test_the_ground_from_the_towers_altitudes_runs_along_the_line(tmp_path: Path) -> None:
    xy = enu_poles()
    rows = "\n".join(f"{a!r},{o!r},{h}" for (a, o), h in zip(geodetic(xy), TOWER_ALT, strict=True))
    p = load_scenario(_towers_scenario(tmp_path, "towers.csv", "lat,lon,alt\n" + rows + "\n"))
    want = _tower_z(xy, TOWER_ALT)
    assert p.terrain is not None
    # the poles stand on their towers' ground; the 2 m grid rounds the profile's corners there
    for i, g in enumerate(want, start=1):
        assert p.region(f"pole{i}").shape.z_lo_m == pytest.approx(g, abs=1e-9)
    np.testing.assert_allclose(p.terrain.ground(xy), want, atol=0.3)
    # half-way along a span: half-way between its towers' ground; 10 m across: the same
    mid = 0.5 * (xy[1] + xy[2])
    across = mid + 10.0 * np.array([-(xy[2] - xy[1])[1], (xy[2] - xy[1])[0]]) / np.linalg.norm(
        xy[2] - xy[1]
    )
    assert p.terrain.ground(mid)[0] == pytest.approx(0.5 * (want[1] + want[2]), abs=0.05)
    assert p.terrain.ground(across)[0] == pytest.approx(0.5 * (want[1] + want[2]), abs=0.05)
    # beyond the last tower: its ground
    beyond = xy[3] + 30.0 * (xy[3] - xy[2]) / np.linalg.norm(xy[3] - xy[2])
    assert p.terrain.ground(beyond)[0] == pytest.approx(want[3], abs=0.05)
    assert p.vehicles[0].start_enu_m[2] == pytest.approx(want[0] + 8.0, abs=0.2)


def test_geojson_and_absolute_kml_altitudes_give_the_same_ground(tmp_path: Path) -> None:
    ll = geodetic(enu_poles())
    feats = [
        {"type": "Feature", "geometry": {"type": "Point", "coordinates": [o, a, h]}}
        for (a, o), h in zip(ll, TOWER_ALT, strict=True)
    ]
    gj = load_scenario(
        _towers_scenario(
            tmp_path, "t.geojson", json.dumps({"type": "FeatureCollection", "features": feats})
        )
    )
    marks = "".join(
        f"<Placemark><Point><altitudeMode>absolute</altitudeMode><coordinates>{o!r},{a!r},{h}"
        "</coordinates></Point></Placemark>"
        for (a, o), h in zip(ll, TOWER_ALT, strict=True)
    )
    kml = f'<kml xmlns="http://www.opengis.net/kml/2.2"><Document>{marks}</Document></kml>'
    km = load_scenario(_towers_scenario(tmp_path, "t.kml", kml))
    assert gj.terrain is not None and km.terrain is not None
    np.testing.assert_array_equal(gj.terrain.ground_z_m, km.terrain.ground_z_m)


@pytest.mark.parametrize(
    ("name", "text", "key", "words"),
    [
        (  # KML's default altitude mode (clampToGround) says nothing of the ground
            "t.kml",
            '<kml xmlns="http://www.opengis.net/kml/2.2"><Document><Placemark><Point>'
            "<coordinates>8.5456,47.3977,0</coordinates></Point></Placemark><Placemark><Point>"
            "<coordinates>8.5460,47.3980,0</coordinates></Point></Placemark></Document></kml>",
            "line.file",
            "t.kml: tower 1 has no ground altitude",
        ),
        ("t.csv", "lat,lon\n47.3977,8.5456\n47.3980,8.5460\n", "line.file", "tower 1 has no"),
        (  # an empty cell is a tower without its ground (a line read for its poles alone
            # does not mind), a word in it a mistake
            "t.csv",
            "lat,lon,alt\n47.3977,8.5456,490\n47.3980,8.5460,\n",
            "line.file",
            "tower 2 has no",
        ),
        ("t.csv", "lat,lon,alt\n47.3977,8.5456,high\n", "line.file", "column alt: expected a"),
    ],
)
def test_towers_without_their_ground_are_refused_naming_the_tower(
    tmp_path: Path, name: str, text: str, key: str, words: str
) -> None:
    with pytest.raises(ScenarioError) as err:
        load_scenario(_towers_scenario(tmp_path, name, text))
    assert err.value.key_path == key and words in str(err.value)


def test_the_ground_from_a_line_written_in_the_scenario_is_refused(tmp_path: Path) -> None:
    data = line_scenario("  along: {start: [0, 0], bearing_deg: 37, span_m: 30, count: 4}\n")
    data["terrain"] = {"from": "line"}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ScenarioError, match=r"terrain.from: the ground from the line needs"):
        load_scenario(path)
    data["terrain"] = {"from": "line", "file": "x.tif"}
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ScenarioError, match=r"terrain: give the ground one way"):
        load_scenario(path)


def test_a_height_above_the_ground_is_no_place_to_fly_to_even_over_a_plane(
    tmp_path: Path,
) -> None:
    """Over a plane, ``agl(d) >= 3`` is affine in the position; the initial guess must still
    not read it as a place to visit (it holds everywhere above the ground)."""
    path = ridge_scenario(tmp_path)
    utm_raster(tmp_path / "ridge.tif", plane)  # the scenario's raster, made a plane
    problem = load_scenario(path)
    floor = next(
        f for f, c in zip(problem.formulas, problem.clauses, strict=True) if "agl" in c.text
    )
    assert place(floor.child, problem) is None and keep_out(floor.child, problem) is None
    # x(d1) >= 3 is a place (the reading the guess does make)
    assert place(parse("x(d1) >= 3", functions=build_registry(problem)), problem) is not None


def test_a_towers_file_with_some_ground_altitudes_still_places_its_poles(tmp_path: Path) -> None:
    """Without ``from: line`` a missing ground altitude does not matter."""
    ll = geodetic(enu_poles())
    rows = "".join(f"{a!r},{o!r},{'' if i == 2 else 490}\n" for i, (a, o) in enumerate(ll))
    (tmp_path / "towers.csv").write_text("lat,lon,alt\n" + rows)
    path = tmp_path / "towers.yaml"
    path.write_text(yaml.safe_dump(line_scenario("  file: towers.csv\n")))
    p = load_scenario(path)
    assert p.terrain is None
    assert p.region("pole3").shape.z_lo_m == 0.0  # flat ground at the origin's altitude
