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

from planner.frames import GeodeticPoint
from planner.milp.solve import solve_coarse
from planner.optimize import plan
from planner.planfile import PlanFileError, load_plan, plan_formula, save_plan
from planner.scenario import ScenarioError, load_scenario
from planner.spec.terrain import TerrainError, terrain_from_geotiff, write_geotiff
from planner.trajectory import Trajectory

ORIGIN = GeodeticPoint(47.397742, 8.545594, 488.0)
O3 = (ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
(E0,), (N0,) = transform("EPSG:4326", "EPSG:32632", [ORIGIN.lon_deg], [ORIGIN.lat_deg])


def _utm_raster(path: Path, height: object, pixel: float = 5.0, nodata_at: tuple = ()) -> None:
    """A UTM 32N raster 600 m x 400 m round the origin, heights ``height(dE, dN)`` AMSL."""
    west, north = E0 - 200.0, N0 + 200.0
    cols, rows = np.meshgrid(np.arange(int(600 / pixel)), np.arange(int(400 / pixel)))
    d_e = west + (cols + 0.5) * pixel - E0
    d_n = north - (rows + 0.5) * pixel - N0
    h = np.asarray(height(d_e, d_n), dtype=float)  # type: ignore[operator]
    for r, c in nodata_at:
        h[r, c] = -9999.0
    write_geotiff(str(path), h, west, north, pixel, "EPSG:32632")


def _plane(d_e: np.ndarray, d_n: np.ndarray) -> np.ndarray:
    return 480.0 + 0.1 * d_e + 0.05 * d_n


def _ground_reference(xy: np.ndarray, height: object) -> np.ndarray:
    """The surface's mission-frame z under ENU points: through pymap3d and PROJ, not the grid."""
    lat, lon, _ = pymap3d.enu2geodetic(
        xy[:, 0], xy[:, 1], 0.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m
    )
    e, n = transform("EPSG:4326", "EPSG:32632", list(lon), list(lat))
    h = height(np.asarray(e) - E0, np.asarray(n) - N0)  # type: ignore[operator]
    return np.asarray(pymap3d.geodetic2enu(lat, lon, h, *O3)[2])


def test_a_utm_raster_gives_the_surface_it_was_made_from(tmp_path: Path) -> None:
    _utm_raster(tmp_path / "dem.tif", _plane)
    t = terrain_from_geotiff(str(tmp_path / "dem.tif"), ORIGIN, [-100, -80], [300, 150])
    assert t.step_m == pytest.approx(5.0, rel=0.01)  # the pixel's size on the ground
    xy = np.random.default_rng(1).uniform([-100, -80], [300, 150], size=(50, 2))
    # a plane is bilinear in any grid: the only errors are the sampling's round-offs
    np.testing.assert_allclose(t.ground(xy), _ground_reference(xy, _plane), atol=1e-3)
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
    _utm_raster(tmp_path / "dem.tif", lambda e, n: 500.0 + rough)
    t = terrain_from_geotiff(str(tmp_path / "dem.tif"), ORIGIN, [-150, -150], [350, 150])
    nodes = [(3, 5), (20, 17), (47, 31), (88, 52)]
    xy = np.array([[t.xs_m[i], t.ys_m[j]] for i, j in nodes])
    lat, lon, _ = pymap3d.enu2geodetic(xy[:, 0], xy[:, 1], 0.0, *O3)
    e, n = transform("EPSG:4326", "EPSG:32632", list(lon), list(lat))
    with rasterio.open(tmp_path / "dem.tif") as src:
        for k, (i, j) in enumerate(nodes):
            west, north = E0 - 200.0, N0 + 200.0  # as _utm_raster wrote it, 5 m pixels
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
    _utm_raster(tmp_path / "dem.tif", _plane)
    with pytest.raises(TerrainError, match=r"dem.tif: does not cover .* is outside the raster"):
        terrain_from_geotiff(str(tmp_path / "dem.tif"), ORIGIN, [-100, -80], [900, 150])
    _utm_raster(tmp_path / "dem.tif", _plane, nodata_at=((40, 60),))
    # pixel (40, 60) is 100 m east of the west edge, 0 north of the origin: a hole there
    with pytest.raises(TerrainError, match=r"has no data \(nodata\)"):
        terrain_from_geotiff(str(tmp_path / "dem.tif"), ORIGIN, [-150, -50], [100, 50])
    (tmp_path / "not.tif").write_text("hello")
    with pytest.raises(TerrainError, match=r"not.tif: cannot read as a GeoTIFF"):
        terrain_from_geotiff(str(tmp_path / "not.tif"), ORIGIN, [0, 0], [10, 10])


def test_casadi_reads_the_same_ground_as_the_exact_semantics(tmp_path: Path) -> None:
    import casadi as ca

    rough = np.random.default_rng(2).normal(0.0, 2.0, size=(80, 120))
    _utm_raster(tmp_path / "dem.tif", lambda e, n: 490.0 + rough)
    t = terrain_from_geotiff(str(tmp_path / "dem.tif"), ORIGIN, [-50, -50], [150, 100])
    xy = np.random.default_rng(4).uniform([-80, -80], [180, 130], size=(200, 2))  # some beyond
    sym = ca.SX.sym("p", 200, 2)
    f = ca.Function("g", [sym], [t.ca_ground(sym)])
    np.testing.assert_allclose(np.asarray(f(xy)).ravel(), t.ground(xy), atol=1e-9)
    inside = np.all((xy >= [-50, -50]) & (xy <= [150, 100]), axis=1)
    assert 0 < inside.sum() < len(xy)  # both kinds checked


# ------------------------------------------------------------------------- scenarios


def _ridge(d_e: np.ndarray, d_n: np.ndarray) -> np.ndarray:
    """A 14 m ridge running north-south 40 m east of the origin, on ground at 486 m."""
    return 486.0 + 14.0 * np.exp(-(((d_e - 40.0) / 10.0) ** 2))


def _scenario(tmp_path: Path, **over: object) -> Path:
    _utm_raster(tmp_path / "ridge.tif", _ridge)
    data: dict[str, object] = {
        "name": "ridge",
        "origin": {"lat": ORIGIN.lat_deg, "lon": ORIGIN.lon_deg, "alt": ORIGIN.alt_m},
        "workspace": {"min": [-20, -20, -10], "max": [100, 20, 40]},
        "terrain": {"file": "ridge.tif", "min_agl_m": 3},
        "regions": {"goal": {"kind": "goal", "min": [76, -3, 2], "max": [84, 3, 8]}},
        "limits": {"v_max_m_s": 6, "a_max_m_s2": 3},
        "vehicles": [{"name": "d1", "start": [0, 0, 4]}],
        "timing": {"horizon_s": 30, "segment_s": 3, "Ts_s": 0.5, "check_dt_s": 0.1},
        "epsilon": 0.01,
        "solver": {"coarse_s": 0},
        "spec": [
            "eventually[0, 26] always[0, 2] inside(d1, goal)",
            "always[0, 30] inside(d1, workspace)",
        ],
    }
    data.update(over)
    data = {k: v for k, v in data.items() if v is not None}  # None: leave the key out
    path = tmp_path / "ridge.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_heights_of_the_line_and_the_starts_are_above_the_ground_there(tmp_path: Path) -> None:
    line = {
        "along": {"start": [0, 10], "bearing_deg": 90, "span_m": 40, "count": 3},
        "pole": {"radius_m": 0.4, "height_m": 12},
        "conductors": {"half_width_m": 1.8, "z": [9, 12], "clearance_m": 1.0},
        "inspection": {"standoff_m": 1.5, "depth_m": 2.2, "length_m": 5, "z": [9.5, 12.5]},
    }
    p = load_scenario(_scenario(tmp_path, line=line, spec=["always[0, 30] agl(d1) >= 1"]))
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
    path = _scenario(tmp_path, **over)
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert err.value.key_path == key
    assert words in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.slow
def test_a_path_over_a_ridge_keeps_its_height_above_the_ground(tmp_path: Path) -> None:
    """Planned with the floor, the path climbs over the ridge; the heights above ground along
    it, sampled densely and measured on the surface itself, keep min_agl_m."""
    path = _scenario(tmp_path)
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
    assert (pos[:, 2] - _ground_reference(pos[:, :2], _ridge)).min() >= 3.0 - 1.0
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


def test_the_coarse_stage_relaxes_the_floor_and_never_claims_a_ridge_impossible(
    tmp_path: Path,
) -> None:
    """Beside a ridge a plane through the ground is 3 m over the start: a floor on it would
    make the start break the floor and the coarse program infeasible. Relaxed, the stage plans,
    and its waypoints keep the floor over the plane under the ground."""
    problem = load_scenario(_scenario(tmp_path))
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
