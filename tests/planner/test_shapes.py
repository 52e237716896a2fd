"""Regions in any direction (prisms over convex polygons, turned boxes, cylinders): exact
margins against brute-force geometry, the smooth ones never above them, the planner's
linear forms sound, scenario and plan files, and a turned mission planned as well as the
same mission laid along the axes."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from matplotlib.path import Path as MplPath

from planner.scenario import ScenarioError, parse_scenario
from planner.spec.predicates import build_registry, predicate_sharpness
from planner.spec.regions import Cylinder, Prism, Region, RegionKind, ShapeError
from planner.stl import parse

RNG = np.random.default_rng(37)


def _random_convex(rng: np.random.Generator, n: int) -> np.ndarray:
    """A random convex polygon: the hull of points on an ellipse, shuffled start."""
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    pts = np.column_stack([3.0 * np.cos(a) + 1.0, 1.5 * np.sin(a) - 2.0])
    rot = rng.uniform(0, np.pi)
    c, s = math.cos(rot), math.sin(rot)
    return pts @ np.array([[c, s], [-s, c]])


def _surface_samples(region: Region, step: float = 0.02) -> np.ndarray:
    """Dense points on the region's boundary surface (walls/mantle, floor and roof)."""
    fp = region.footprint_xy(sides=720)
    lo, hi = region.lo_enu_m[2], region.hi_enu_m[2]
    zs = np.arange(lo, hi + step / 2, step)
    ring = []
    for a, b in zip(fp, np.roll(fp, -1, axis=0), strict=True):
        t = np.linspace(0, 1, max(2, int(np.linalg.norm(b - a) / step) + 1))
        ring.append(a + t[:, None] * (b - a))
    ring_xy = np.vstack(ring)
    walls = np.column_stack([np.repeat(ring_xy, len(zs), axis=0), np.tile(zs, len(ring_xy))])
    gx = np.arange(region.lo_enu_m[0], region.hi_enu_m[0] + step, step)
    gy = np.arange(region.lo_enu_m[1], region.hi_enu_m[1] + step, step)
    xy = np.column_stack([g.ravel() for g in np.meshgrid(gx, gy)])
    xy = xy[MplPath(fp).contains_points(xy)]
    caps = [np.column_stack([xy, np.full(len(xy), z)]) for z in (lo, hi)]
    return np.vstack([walls, *caps])


def _brute_inside(region: Region, p: np.ndarray) -> np.ndarray:
    """Independent membership: matplotlib's point-in-polygon and the height range."""
    fp = region.footprint_xy(sides=720)
    in_xy = MplPath(fp).contains_points(p[:, :2])
    return in_xy & (p[:, 2] >= region.lo_enu_m[2]) & (p[:, 2] <= region.hi_enu_m[2])


def _shapes() -> list[Region]:
    return [
        Region.of_shape(
            "hexa", RegionKind.NO_FLY, Prism.from_polygon(_random_convex(RNG, 6), 0.5, 3.0)
        ),
        Region.of_shape(
            "turned", RegionKind.INSPECTION, Prism.oriented_box([1, 2, 4], [2.5, 0.8, 1.2], 0.6458)
        ),
        Region.of_shape("pole", RegionKind.POLE, Cylinder((-1.0, 0.5), 0.7, 0.0, 2.5)),
    ]


@pytest.mark.parametrize("region", _shapes(), ids=lambda r: r.name)
@pytest.mark.slow
def test_a_shapes_margin_is_its_distance_to_the_boundary_inside_and_a_lower_bound_outside(
    region: Region,
) -> None:
    surface = _surface_samples(region)
    lo, hi = np.asarray(region.lo_enu_m) - 1.0, np.asarray(region.hi_enu_m) + 1.0
    p = RNG.uniform(lo, hi, size=(400, 3))
    m = region.margin(p)
    inside = _brute_inside(region, p)
    ok = np.abs(m) > 0.03  # away from the boundary, where sampling decides the reference
    assert np.array_equal(m[ok] > 0, inside[ok])
    assert inside.sum() > 20 and (~inside).sum() > 20
    dist = np.array([np.min(np.linalg.norm(surface - q, axis=1)) for q in p])
    # inside: the Euclidean distance to the boundary (the samples are 0.02 m apart)
    np.testing.assert_allclose(m[inside & ok], dist[inside & ok], atol=0.03)
    # outside: minus the largest face violation, never more than the distance
    assert np.all(-m[~inside & ok] <= dist[~inside & ok] + 1e-9)
    assert np.all(-m[~inside & ok] > 0)


def test_a_box_turned_by_zero_or_a_right_angle_has_the_boxs_margins() -> None:
    box = Region("b", RegionKind.REGION, (-1.0, -2.0, 0.0), (3.0, 4.0, 1.0))
    p = RNG.uniform(-4, 6, size=(300, 3))
    same = Region.of_shape(
        "p", RegionKind.REGION, Prism.oriented_box([1, 1, 0.5], [2, 3, 0.5], 0.0)
    )
    quarter = Region.of_shape(
        "q", RegionKind.REGION, Prism.oriented_box([1, 1, 0.5], [3, 2, 0.5], math.pi / 2)
    )
    np.testing.assert_allclose(same.margin(p), box.margin(p), atol=1e-12)
    np.testing.assert_allclose(quarter.margin(p), box.margin(p), atol=1e-12)
    np.testing.assert_allclose(
        np.sort(same.face_margins(p), 1), np.sort(box.face_margins(p), 1), atol=1e-12
    )


@pytest.mark.parametrize("region", _shapes(), ids=lambda r: r.name)
def test_the_smooth_margins_are_never_above_the_exact_ones_and_within_their_bound(
    region: Region,
) -> None:
    from dataclasses import dataclass

    import casadi as ca

    @dataclass
    class Src:
        all_regions: tuple[Region, ...]

        def region(self, name: str) -> Region:
            return {r.name: r for r in self.all_regions}[name]

    src = Src((Region("workspace", RegionKind.WORKSPACE, (-9, -9, -1), (9, 9, 9)), region))
    k = predicate_sharpness(src)
    reg = build_registry(src, k)
    p = RNG.uniform(np.asarray(region.lo_enu_m) - 1, np.asarray(region.hi_enu_m) + 1, (300, 3))
    bound = math.log(region.faces) / k + 2e-4
    for text in (f"inside(d, {region.name}) >= 0", f"outside(d, {region.name}) >= 0"):
        f = parse(text, reg)
        exact = np.asarray(f.robustness_trace({"d": p}, 1.0))
        sym = ca.SX.sym("p", len(p), 3)
        smooth_expr = f.smooth_robustness_trace({"d": sym}, 1.0, 50.0)
        smooth = np.asarray(ca.Function("f", [sym], [smooth_expr])(p)).ravel()
        assert np.all(smooth <= exact + 1e-9), text
        assert np.all(smooth >= exact - bound), (text, float(np.max(exact - smooth)), bound)


def test_a_cylinders_linear_forms_are_inside_it_for_a_place_and_around_it_for_a_keep_out() -> None:
    pole = _shapes()[2]
    p = RNG.uniform(np.asarray(pole.lo_enu_m) - 0.3, np.asarray(pole.hi_enu_m) + 0.3, (4000, 3))
    for outer in (False, True):
        A, b = pole.half_spaces(outer)
        assert np.allclose(np.linalg.norm(A, axis=1), 1.0)
        in_poly = np.all(p @ A.T <= b, axis=1)
        in_cyl = pole.contains(p)
        if outer:
            assert np.all(in_poly[in_cyl])  # the keep-out's polygon covers the cylinder
        else:
            assert np.all(in_cyl[in_poly])  # the place's polygon lies within it
        assert np.mean(in_poly != in_cyl) < 0.03


@pytest.mark.parametrize(
    ("corners", "says"),
    [
        ([[0, 0], [4, 0], [1, 1], [0, 4]], "not convex at corner 3"),
        ([[0, 0], [4, 0], [4, 0], [0, 4]], "repeats a corner"),
        ([[0, 0], [1, 1]], "at least 3 corners"),
        ([[0, 0], [1, 1], [2, 2]], "not convex"),
        ([[0, 1], [0.588, -0.809], [-0.951, 0.309], [0.951, 0.309], [-0.588, -0.809]], "cross"),
    ],
)
def test_a_polygon_that_is_not_convex_is_refused_naming_the_corner(corners, says) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ShapeError, match=says):
        Prism.from_polygon(corners, 0.0, 1.0)


def test_a_polygon_given_clockwise_is_the_same_prism() -> None:
    ccw = Prism.from_polygon([[0, 0], [4, 0], [3, 3], [0, 2]], 0, 1)
    cw = Prism.from_polygon([[0, 2], [3, 3], [4, 0], [0, 0]], 0, 1)
    p = RNG.uniform(-1, 5, (200, 3))
    a = Region.of_shape("a", RegionKind.REGION, ccw)
    b = Region.of_shape("b", RegionKind.REGION, cw)
    np.testing.assert_allclose(a.margin(p), b.margin(p), atol=1e-12)


_SCENARIO = """
name: shapes
origin: {{lat: 47.397742, lon: 8.545594, alt: 488.0}}
workspace: {{min: [-20, -20, 0], max: [20, 20, 10]}}
regions:
{regions}
limits: {{v_max_m_s: 3, a_max_m_s2: 2}}
vehicles:
  - {{name: d1, start: [-6, -6, 3]}}
timing: {{horizon_s: 12, segment_s: 2, Ts_s: 0.1}}
separation_m: 0.5
epsilon: 0.01
spec:
  - each: d in all
    formula: eventually[0, 10] always[0, 1] inside(d, goal)
  - each: d in all
    formula: always[0, 12] (outside(d, wall) and outside(d, pole) and inside(d, workspace))
"""


def _scenario(regions: str) -> str:
    return _SCENARIO.format(regions=regions)


def test_a_turned_box_may_be_given_by_yaw_or_by_bearing() -> None:
    by_yaw = parse_scenario(
        yaml.safe_load(
            _scenario(
                "  goal: {center: [5, 4, 3], half_size: [1, 0.6, 0.6], yaw_deg: 53}\n"
                "  wall: {kind: obstacle, center: [0, 0, 3], half_size: [1, 4, 3], yaw_deg: 53}\n"
                "  pole: {kind: pole, center: [-3, 2], radius: 0.5, z: [0, 8]}\n"
            )
        ),
        "s.yaml",
    )
    by_bearing = parse_scenario(
        yaml.safe_load(
            _scenario(
                "  goal: {center: [5, 4, 3], half_size: [1, 0.6, 0.6], bearing_deg: 37}\n"
                "  wall: {kind: obstacle, center: [0, 0, 3], half_size: [1, 4, 3], bearing_deg: 37}\n"
                "  pole: {kind: pole, center: [-3, 2], radius: 0.5, z: [0, 8]}\n"
            )
        ),
        "s.yaml",
    )
    p = RNG.uniform(-8, 8, (200, 3))
    for name in ("goal", "wall", "pole"):
        np.testing.assert_allclose(
            by_yaw.region(name).margin(p), by_bearing.region(name).margin(p), atol=1e-12
        )
    assert isinstance(by_yaw.region("goal").shape, Prism)
    assert isinstance(by_yaw.region("pole").shape, Cylinder)


@pytest.mark.parametrize(
    ("regions", "says"),
    [
        (
            "  goal: {polygon: [[0, 0], [4, 4], [4, 0], [0, 4]], z: [0, 5]}\n",
            r"regions\.goal\.polygon.*edges cross or touch at \(2, 2\)",
        ),
        ("  goal: {center: [5, 4, 3], half_size: 1, yaw_deg: 3, bearing_deg: 4}\n", "not both"),
        ("  goal: {center: [5, 4], radius: 0, z: [0, 5]}\n", r"regions\.goal\.radius.*> 0"),
        ("  goal: {center: [5, 4], radius: 1, z: [5, 5]}\n", r"regions\.goal\.z.*empty height"),
        ("  goal: {polygon: [[0, 0], [4, 0], [1, 1]], z: [0, 5], yaw_deg: 3}\n", "yaw_deg"),
    ],
)
def test_a_bad_shape_is_one_line_naming_its_field(regions: str, says: str) -> None:
    with pytest.raises(ScenarioError, match=says) as err:
        parse_scenario(yaml.safe_load(_scenario(regions)), "s.yaml")
    assert "\n" not in str(err.value)


def test_the_workspace_stays_an_axis_aligned_box() -> None:
    text = _scenario("  goal: {center: [5, 4, 3], half_size: 1}\n").replace(
        "workspace: {min: [-20, -20, 0], max: [20, 20, 10]}",
        "workspace: {center: [0, 0, 5], half_size: [20, 20, 5], yaw_deg: 10}",
    )
    with pytest.raises(ScenarioError, match=r"workspace.*axis-aligned"):
        parse_scenario(yaml.safe_load(text), "s.yaml")


def _turned_mission(yaw_deg: float) -> str:
    """A drone flies along a right of way, past a pole in it, to hover in an inspection box
    at its far end: the same geometry turned ``yaw_deg`` about the origin (boxes along the
    axes when 0).  Its optimum is the inspection box's 0.6 m half-size, whatever the turn."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))

    def at(x: float, y: float) -> str:
        return f"[{c * x - s * y:.9f}, {s * x + c * y:.9f}"

    return (
        _SCENARIO.format(
            regions=(
                f"  goal: {{center: {at(7, 0)}, 3], half_size: [1, 0.6, 0.6], yaw_deg: {yaw_deg}}}\n"
                f"  wall: {{kind: region, center: {at(0, 0)}, 3], half_size: [10, 1.5, 3], yaw_deg: {yaw_deg}}}\n"
                f"  pole: {{kind: pole, center: {at(0, 0.8)}], radius: 0.3, z: [0, 8]}}\n"
            )
        )
        .replace("start: [-6, -6, 3]", f"start: {at(-7, 0)}, 3]")
        .replace("outside(d, wall)", "inside(d, wall)")
    )


@pytest.mark.slow
def test_a_turned_mission_plans_as_well_as_the_same_mission_along_the_axes(tmp_path: Path) -> None:
    from planner.optimize import plan
    from planner.planfile import load_plan, plan_to_json
    from planner.scenario import load_scenario

    got = {}
    for yaw in (0.0, 37.0):
        path = tmp_path / f"m{yaw:g}.yaml"
        path.write_text(_turned_mission(yaw))
        problem = load_scenario(path)
        result = plan(problem)
        assert result.success, result.status
        got[yaw] = result.robustness
        if yaw:
            assert isinstance(problem.region("wall").shape, Prism)
            out = tmp_path / "p.json"
            out.write_text(json.dumps(plan_to_json(result.to_plan(str(path)))))
            loaded = load_plan(out)
            assert loaded.region("wall").shape == problem.region("wall").shape
            assert loaded.region("pole").shape == problem.region("pole").shape
    # both reach the inspection box's 0.6 m half-size, the optimum (within 3 %)
    assert got[0.0] >= 0.97 * 0.6 and got[37.0] >= 0.97 * 0.6, got


def test_a_start_inside_a_turned_keep_out_is_refused_describing_its_shape() -> None:
    text = _scenario(
        "  goal: {center: [5, 4, 3], half_size: 1}\n"
        "  wall: {kind: obstacle, center: [-6, -6, 3], half_size: [1, 4, 3], bearing_deg: 37}\n"
        "  pole: {kind: pole, center: [9, 9], radius: 0.5, z: [0, 8]}\n"
    )
    with pytest.raises(ScenarioError, match=r"'wall' \(a prism over 4 corners, z 0 to 6\)"):
        parse_scenario(yaml.safe_load(text), "s.yaml")
