"""Polygons that are not convex (an L-shaped right of way, a comb of bays): their convex
parts tile them and overlap where they meet, checked against brute-force geometry
(matplotlib's point-in-polygon, point-to-segment distances); the spec's ``inside``/
``outside`` of them read as the parts'; an L planned across its corner."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from matplotlib.path import Path as MplPath

from planner.scenario import ScenarioError, parse_scenario
from planner.spec.cover import (
    convex_cover,
    crossing_fan,
    polygon_regions,
    reflex_corners,
    seam_bridge,
)
from planner.spec.regions import Prism, Region, RegionKind, ShapeError

RNG = np.random.default_rng(21)

L_SHAPE = [(0, 0), (40, 0), (40, 10), (10, 10), (10, 40), (0, 40)]
U_SHAPE = [(0, 0), (30, 0), (30, 30), (20, 30), (20, 10), (10, 10), (10, 30), (0, 30)]
PLUS = [(-3, -1), (-1, -1), (-1, -3), (1, -3), (1, -1), (3, -1)]
PLUS += [(3, 1), (1, 1), (1, 3), (-1, 3), (-1, 1), (-3, 1)]
COMB = [(0, 0), (9, 0), (9, 4)] + [
    c for i in range(4, 0, -1) for c in ((2 * i, 4), (2 * i, 1), (2 * i - 1, 1), (2 * i - 1, 4))
]
COMB += [(0, 4)]


def _turned(
    corners: list[tuple[float, float]], deg: float, shift: tuple[float, float]
) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.asarray(corners, dtype=float) @ np.array([[c, s], [-s, c]]) + np.asarray(shift)


def _random_star(rng: np.random.Generator) -> np.ndarray:
    """A random simple polygon: corners at sorted angles round a centre, random radii."""
    n = int(rng.integers(5, 16))
    a = np.sort(rng.uniform(0.0, 2.0 * np.pi, n))
    r = rng.uniform(2.0, 10.0, n)
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def _seg_distance(p: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Brute force: each point's distance to the polygon's boundary (its edges as segments)."""
    a, b = corners, np.roll(corners, -1, axis=0)
    ab = b - a
    t = np.clip(
        np.einsum("nkj,kj->nk", p[:, None, :] - a[None], ab) / np.einsum("kj,kj->k", ab, ab),
        0.0,
        1.0,
    )
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None, :] - closest, axis=2).min(axis=1)


def _union_margin(parts: list[Region], p_xy: np.ndarray) -> np.ndarray:
    """``inside`` of the polygon as the spec reads it: the largest part margin (at mid
    height, so the floor and roof do not decide)."""
    z = 0.5 * (parts[0].lo_enu_m[2] + parts[0].hi_enu_m[2])
    p = np.column_stack([p_xy, np.full(len(p_xy), z)])
    return np.max([r.margin(p) for r in parts], axis=0)


POLYGONS = {
    "L": np.asarray(L_SHAPE, float),
    "U": np.asarray(U_SHAPE, float),
    "plus": np.asarray(PLUS, float),
    "comb": np.asarray(COMB, float),
    "L turned 37 deg": _turned(L_SHAPE, 37.0, (120.0, -40.0)),
    **{f"star {i}": _random_star(np.random.default_rng(100 + i)) for i in range(12)},
}


def test_an_l_is_its_two_arms_each_with_the_corner_square() -> None:
    parts = polygon_regions("row", RegionKind.REGION, L_SHAPE, 0.0, 15.0)
    assert [r.name for r in parts] == ["row_part1", "row_part2"]
    assert all(r.part_of == "row" and isinstance(r.shape, Prism) for r in parts)
    boxes = sorted((r.lo_enu_m, r.hi_enu_m) for r in parts)
    assert boxes == [((0, 0, 0), (10, 40, 15)), ((0, 0, 0), (40, 10, 15))]
    # 5 m inside the corner square's seam with either arm: touching parts would give 0 here
    np.testing.assert_allclose(_union_margin(list(parts), np.array([[5, 10], [10, 5]])), 5.0)
    # near the inner corner: 1 m from each inner wall, 1.41 m from the corner itself
    assert _union_margin(list(parts), np.array([[9.0, 9.0]]))[0] == pytest.approx(1.0)


def test_a_convex_polygon_is_one_region_of_its_own_name_without_its_straight_corners() -> None:
    (r,) = polygon_regions("a", RegionKind.NO_FLY, [(0, 0), (2, 0), (4, 0), (4, 3), (0, 3)], 0, 5)
    assert r.name == "a" and r.part_of is None and r.kind is RegionKind.NO_FLY
    assert isinstance(r.shape, Prism) and r.shape.walls == 4


def test_figures_draw_a_polygon_as_its_outline_not_as_its_parts() -> None:
    from planner.spec.cover import Outline, drawn_regions

    parts = polygon_regions("row", RegionKind.NO_FLY, _turned(L_SHAPE, 37.0, (5, 5)), 0, 15)
    pole = Region("pole", RegionKind.POLE, (1, 1, 0), (2, 2, 9))
    drawn = drawn_regions([pole, *parts])
    assert drawn[0] is pole and len(drawn) == 2
    row = drawn[1]
    assert isinstance(row, Outline) and row.name == "row" and row.kind is RegionKind.NO_FLY
    corners = row.footprint_xy()
    np.testing.assert_allclose(
        np.sort(corners, axis=0), np.sort(_turned(L_SHAPE, 37.0, (5, 5)), axis=0), atol=1e-9
    )
    assert MplPath(corners).contains_point(row.center_enu_m[:2])  # the label is on the L
    assert row.hi_enu_m[2] == 15 and row.lo_enu_m[2] == 0
    assert (row.shape.z_lo_m, row.shape.z_hi_m) == (0, 15)
    np.testing.assert_array_equal(np.asarray(row.shape.vertices_xy), corners)


def test_a_no_fly_polygon_is_fenced_as_its_parts_which_px4_reads_as_their_union() -> None:
    """PX4 passes a point only if it is outside every exclusion polygon (navigator's
    Geofence::isInsidePolygonOrCircle ANDs them), so the parts fence exactly the L."""
    from mavlink.mission import fence_zones

    ws = Region("workspace", RegionKind.WORKSPACE, (-20, -20, 0), (60, 60, 20))
    parts = polygon_regions("nofly", RegionKind.NO_FLY, L_SHAPE, 0.0, 20.0)
    zones = fence_zones(ws, parts)
    exclusions = [z for z in zones if not z.inclusion]
    assert [z.name for z in exclusions] == ["nofly_part1", "nofly_part2"]
    grid = RNG.uniform(-5, 45, (5000, 2))
    grid = grid[_seg_distance(grid, np.asarray(L_SHAPE, float)) > 1e-6]
    barred = np.any([MplPath(z.vertices_xy()).contains_points(grid) for z in exclusions], axis=0)
    np.testing.assert_array_equal(barred, MplPath(np.asarray(L_SHAPE)).contains_points(grid))


@pytest.mark.parametrize("name", list(POLYGONS))
def test_the_parts_are_convex_and_tile_the_polygon(name: str) -> None:
    corners = POLYGONS[name]
    parts = convex_cover(corners)
    assert len(parts) >= (2 if reflex_corners(corners) else 1)
    lo, hi = corners.min(axis=0) - 1.0, corners.max(axis=0) + 1.0
    grid = np.column_stack([g.ravel() for g in np.meshgrid(*np.linspace(lo, hi, 160).T)])
    inside = MplPath(corners).contains_points(grid)
    in_parts = np.zeros(len(grid), bool)
    for p in parts:
        e = np.roll(p, -1, axis=0) - p
        turns = np.roll(e, 1, axis=0)[:, 0] * e[:, 1] - np.roll(e, 1, axis=0)[:, 1] * e[:, 0]
        assert np.all(turns > 0), f"{name}: a part is not strictly convex"
        mine = MplPath(p).contains_points(grid)
        # a part lies in the polygon (but for grid points on its boundary)
        stray = mine & ~inside
        assert np.all(_seg_distance(grid[stray], corners) < 1e-6), name
        in_parts |= mine
    missed = grid[inside & ~in_parts]  # only on a part's boundary (where Path may say no)
    if len(missed):
        on_edge = np.min([_seg_distance(missed, p) for p in parts], axis=0)
        assert np.all(on_edge < 1e-6), name


@pytest.mark.parametrize("name", list(POLYGONS))
def test_the_parts_overlap_where_they_meet_so_no_seam_inside_has_zero_margin(name: str) -> None:
    corners = POLYGONS[name]
    parts = list(polygon_regions(name.replace(" ", "_"), RegionKind.REGION, corners, 0.0, 100.0))
    size = float(np.ptp(corners, axis=0).max())
    for k, part in enumerate(parts):
        v = np.asarray(part.shape.vertices_xy)
        t = np.linspace(0.0, 1.0, 41)[1:-1]
        edge_pts = np.vstack(
            [a + t[:, None] * (b - a) for a, b in zip(v, np.roll(v, -1, 0), strict=True)]
        )
        depth = _seg_distance(edge_pts, corners)
        seam = edge_pts[depth > 1e-6 * size]  # a part's edge inside the polygon
        if len(seam) == 0:
            continue
        others = [r for j, r in enumerate(parts) if j != k]
        assert others, name
        got = _union_margin(others, seam)
        # strictly inside another part, by a share of the depth in the polygon
        assert np.all(got > 0.0), f"{name}: a seam of zero margin"
        assert np.all(got <= _seg_distance(seam, corners) + 1e-9), name


@pytest.mark.parametrize("name", list(POLYGONS))
def test_the_margin_is_sound_and_signed_against_brute_force(name: str) -> None:
    """Inside, at most the distance to the boundary (the disc of that radius is in the
    polygon) and > 0; outside, minus at most the distance to the polygon and < 0."""
    corners = POLYGONS[name]
    parts = list(polygon_regions("p", RegionKind.REGION, corners, 0.0, 100.0))
    lo, hi = corners.min(axis=0) - 3.0, corners.max(axis=0) + 3.0
    p = RNG.uniform(lo, hi, (3000, 2))
    dist = _seg_distance(p, corners)
    keep = dist > 1e-6
    p, dist = p[keep], dist[keep]
    inside = MplPath(corners).contains_points(p)
    m = _union_margin(parts, p)
    assert np.all(m[inside] > 0.0) and np.all(m[~inside] < 0.0), name
    assert np.all(np.abs(m) <= dist + 1e-9), name
    # outside, beside the polygon, it is the distance (the nearest part's wall margin)
    inner = m[inside] / dist[inside]
    assert np.median(inner) > 0.9, name  # equal to it in most of the polygon


def test_a_bridge_over_a_seam_and_a_fan_round_a_crossing_are_convex_and_hold_them() -> None:
    """The two fallbacks for a seam or crossing no convex union of cells holds."""
    import shapely

    a = shapely.Polygon([(0, 0), (4, 0), (4, 1), (0, 3)])  # trapezoids sharing x in [0, 4]
    b = shapely.Polygon([(0, 0), (0, -3), (4, -1), (4, 0)])
    bridge = seam_bridge(a, b)
    assert bridge.is_valid and bridge.convex_hull.area == pytest.approx(bridge.area)
    assert bridge.difference(a.union(b)).area < 1e-12
    for x in np.linspace(0.05, 3.95, 40):
        assert bridge.contains(shapely.Point(x, 0.0))  # the seam's inside, not on its edge
    quads = [
        shapely.Polygon([(0, 0), (3, 0), (2, 2), (0, 1)]),
        shapely.Polygon([(0, 0), (0, 1), (-2, 3), (-1, 0)]),
        shapely.Polygon([(0, 0), (-1, 0), (-2, -2), (0, -1)]),
        shapely.Polygon([(0, 0), (0, -1), (3, -1), (3, 0)]),
    ]
    fan = crossing_fan(np.zeros(2), quads, 1e-9)
    assert fan.is_valid and fan.convex_hull.area == pytest.approx(fan.area)
    assert fan.difference(shapely.union_all(quads)).area < 1e-12
    assert fan.contains(shapely.Point(0, 0)) and fan.exterior.distance(shapely.Point(0, 0)) > 0.1


@pytest.mark.parametrize(
    ("corners", "says"),
    [
        ([(0, 0), (4, 4), (4, 0), (0, 4)], r"edges cross or touch at \(2, 2\)"),
        (_turned([(0, 1), (0.588, -0.809), (-0.951, 0.309), (0.951, 0.309), (-0.588, -0.809)], 0, (0, 0)), "edges cross"),
        ([(0, 0), (4, 0), (4, 0), (0, 4)], "repeats a corner"),
        ([(0, 0), (1, 1)], "at least 3 corners"),
    ],
)  # fmt: skip
def test_a_polygon_that_is_not_simple_is_refused(corners: object, says: str) -> None:
    """A pentagram turns the same way at every corner: not convex, though no corner is
    reflex; its edges cross."""
    with pytest.raises(ShapeError, match=says):
        polygon_regions("p", RegionKind.REGION, corners, 0.0, 1.0)


def test_a_polygon_that_would_need_too_many_parts_is_refused_saying_so() -> None:
    rng = np.random.default_rng(3)
    for n, says in ((20, r"needs 48 convex parts \(at most 32"), (200, "too intricate")):
        a = np.sort(rng.uniform(0.0, 2.0 * np.pi, n))
        r = rng.uniform(2.0, 10.0, n)
        with pytest.raises(ShapeError, match=says):
            convex_cover(np.column_stack([r * np.cos(a), r * np.sin(a)]))


_SPEC_SCENARIO = """
name: row
origin: {{lat: 47.397742, lon: 8.545594, alt: 488.0}}
workspace: {{min: [-5, -5, 0], max: [45, 45, 20]}}
regions:
  row: {{polygon: {row}, z: [0, 15]}}
  nofly: {{kind: no_fly, polygon: [[20, 20], [30, 20], [30, 30], [25, 25], [20, 30]], z: [0, 20]}}
  goal: {{min: [2, 32, 4], max: [8, 38, 8]}}
{more}
limits: {{v_max_m_s: 5, a_max_m_s2: 2}}
vehicles:
  - {{name: d1, start: [35, 5, 5]}}
timing: {{horizon_s: 30, segment_s: 2, Ts_s: 0.1, check_dt_s: 0.02}}
spec:
  - always[0, 30] (inside(d1, row) and outside(d1, nofly))
  - eventually[20, 30] {last}
"""


def _spec_scenario(last: str = "inside(d1, goal)", more: str = "") -> str:
    return _SPEC_SCENARIO.format(row=json.dumps(L_SHAPE).replace("(", "["), last=last, more=more)


def test_the_spec_reads_inside_a_polygon_as_inside_one_part_and_outside_as_outside_all() -> None:
    problem = parse_scenario(yaml.safe_load(_spec_scenario()), "row.yaml")
    assert problem.clauses[0].text == (
        "always[0, 30] ((inside(d1, row_part1) or inside(d1, row_part2)) and "
        "(outside(d1, nofly_part1) and outside(d1, nofly_part2)))"
    )
    parts = [r for r in problem.regions if r.part_of == "row"]
    assert [r.name for r in parts] == ["row_part1", "row_part2"]
    nofly = [r for r in problem.regions if r.part_of == "nofly"]
    assert len(nofly) == 2 and all(r.kind is RegionKind.NO_FLY for r in nofly)
    # the clause's robustness is the union's margin: the exact semantics over the parts
    (phi, _goal) = problem.formulas
    t = np.linspace(0.0, 30.0, 61)
    path = np.column_stack([np.full_like(t, 5.0), 5.0 + t, np.full_like(t, 5.0)])
    rho = phi.robustness({"d1": path}, dt=0.5)
    ref = min(_union_margin(parts, path[:, :2]).min(), -max(r.margin(path).max() for r in nofly))
    assert rho == pytest.approx(ref)


@pytest.mark.parametrize(
    ("last", "more", "says"),
    [
        ("face(d1, row)", "", r"spec\[1\].*'face\(d1, row\)': row is a polygon that is not convex"),
        ("inside(d1, goal)", "  row_part2: {min: [0, 0, 0], max: [1, 1, 1]}",
         r"regions\.row: its part 'row_part2' has the name of another region"),
        ("inside(d1, goal)", "  bad: {polygon: [[0, 0], [4, 4], [4, 0], [0, 4]], z: [0, 1]}",
         r"regions\.bad\.polygon: the polygon's edges cross or touch at \(2, 2\)"),
    ],
)  # fmt: skip
def test_a_polygon_misused_in_a_scenario_is_one_line_naming_the_field(
    last: str, more: str, says: str
) -> None:
    with pytest.raises(ScenarioError, match=says) as err:
        parse_scenario(yaml.safe_load(_spec_scenario(last, more)), "row.yaml")
    assert "\n" not in str(err.value)


@pytest.mark.slow
def test_an_l_shaped_right_of_way_is_flown_across_its_corner_with_margin(tmp_path: Path) -> None:
    """Start at the end of the east arm, hover in a box at the end of the north arm, never
    leaving the L: the optimum is the goal's 2 m half-height, which the corner's 10 m arms
    leave room for; touching parts would leave 0 at the seam the path must cross."""
    from planner.optimize import plan
    from planner.planfile import load_plan, plan_to_json
    from planner.scenario import load_scenario

    path = tmp_path / "row.yaml"
    path.write_text(_spec_scenario().replace(" and outside(d1, nofly)", ""))
    problem = load_scenario(path)
    result = plan(problem)
    assert result.success, result.status
    assert result.robustness >= 0.95 * 2.0
    out = tmp_path / "row.json"
    out.write_text(json.dumps(plan_to_json(result.to_plan(str(path)))))
    loaded = load_plan(out)
    parts = [r for r in loaded.regions if r.part_of == "row"]
    assert [r.shape for r in parts] == [problem.region(r.name).shape for r in parts]
    sp = loaded.vehicles[0].trajectory.sample(50.0)
    xy = np.asarray(sp.pos_enu_m)[:, :2]
    assert xy[0, 0] > 30 and xy[-1, 1] > 30  # from one arm's end to the other's
    margin = _union_margin(parts, xy)
    assert np.all(margin >= 0.95 * 2.0 - 1e-6)
    assert np.all(margin <= _seg_distance(xy, np.asarray(L_SHAPE, float)) + 1e-9)
