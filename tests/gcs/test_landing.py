"""``--end land`` clear of the keep-outs: where each vehicle lands (:mod:`gcs.flight.landing`),
checked by dense sampling; the missions' NAV_LAND; a dry-run flight landing there; and the
refusal when no clear point exists."""

from __future__ import annotations

import asyncio
import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from gcs.cli import main
from gcs.flight.landing import CLEARANCE_M, keep_outs, landing_point, landing_points
from planner.planfile import load_plan
from planner.spec.regions import Region, RegionKind

DATA = Path(__file__).resolve().parents[1] / "mavlink" / "data"
PLAN = DATA / "reach_avoid_2.plan.json"


def _end(plan, name: str) -> np.ndarray:  # type: ignore[no-untyped-def]
    pv = next(v for v in plan.vehicles if v.name == name)
    return pv.trajectory.position(np.array([pv.trajectory.duration_s]))[0]


def _with(plan, *regions: Region):  # type: ignore[no-untyped-def]
    return dataclasses.replace(plan, regions=(*plan.regions, *regions))


def _inside_widened(p: np.ndarray, r: Region, dims: int) -> bool:
    lo, hi = np.asarray(r.lo_enu_m) - CLEARANCE_M, np.asarray(r.hi_enu_m) + CLEARANCE_M
    return bool(np.all(p[:dims] >= lo[:dims]) and np.all(p[:dims] <= hi[:dims]))


def _usable(plan, end: np.ndarray, q: np.ndarray) -> bool:  # type: ignore[no-untyped-def]
    """The definition, by sampling: the column below q and the transit end -> q at the end's
    altitude keep the clearance from every keep-out, and q is over the workspace."""
    boxes = keep_outs(plan)
    ws = plan.workspace
    if not (np.all(q[:2] >= np.asarray(ws.lo_enu_m)[:2]) and np.all(q[:2] <= np.asarray(ws.hi_enu_m)[:2])):  # fmt: skip
        return False
    for z in np.linspace(0.0, end[2], 50):
        if any(_inside_widened(np.array([q[0], q[1], z]), r, 3) for r in boxes if r.lo_enu_m[2] <= end[2]):  # fmt: skip
            return False
    for s in np.linspace(0.0, 1.0, 400):
        p = np.array([*(end[:2] + s * (q[:2] - end[:2])), end[2]])
        level = [r for r in boxes if r.lo_enu_m[2] <= end[2] <= r.hi_enu_m[2]]
        if any(_inside_widened(p, r, 2) for r in level):
            return False
    return True


def test_a_clear_end_lands_straight_down_and_a_blocked_one_at_the_nearest_clear_point() -> None:
    plan = load_plan(PLAN)
    assert all(
        lp.blocked_by is None and lp.describe() == "" for lp in landing_points(plan).values()
    )
    end = _end(plan, "d1")
    # a mast below d1's end, up to 0.3 m under it
    mast = Region("mast", RegionKind.POLE, (end[0] - 0.1, end[1] - 0.1, 0.0), (end[0] + 0.1, end[1] + 0.1, end[2] - 0.3))  # fmt: skip
    edited = _with(plan, mast)
    lp = landing_point(edited, "d1")
    assert lp.blocked_by is mast and lp.found
    assert _usable(edited, end, lp.point_enu_m) and lp.point_enu_m[2] == pytest.approx(end[2])
    # no usable point on a fine grid is nearer by more than the search's ring step
    xs = np.arange(-2.0, 2.0001, 0.05)
    nearer = [
        (x, y) for x in xs for y in xs
        if np.hypot(x - end[0], y - end[1]) < lp.moved_m - 0.5
        and _usable(edited, end, np.array([x, y, end[2]]))
    ]  # fmt: skip
    assert nearer == [], nearer[:3]
    assert "d1: straight down from its plan's end would pass pole 'mast'" in lp.describe()
    # d2 is unaffected
    assert landing_point(edited, "d2").blocked_by is None


@pytest.mark.slow
def test_missions_land_at_the_clear_point_and_no_clear_point_refuses_land(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from gcs.errors import UserError
    from gcs.flight.landing import landing_targets
    from gcs.flight.missions import convert_plan
    from mavlink.mission import Cmd, MissionEnd
    from planner.frames import enu_to_geodetic

    plan = load_plan(PLAN)
    end = _end(plan, "d1")
    mast = Region("mast", RegionKind.POLE, (end[0] - 0.1, end[1] - 0.1, 0.0), (end[0] + 0.1, end[1] + 0.1, end[2] - 0.3))  # fmt: skip
    edited = _with(plan, mast)
    point = landing_targets(edited)["d1"]
    conv = convert_plan(edited, end=MissionEnd.LAND, iterations=1)
    go, land = conv.missions["d1"].items[-2:]
    assert land.command == Cmd.NAV_LAND
    lat, lon, _ = enu_to_geodetic(point, plan.origin)
    assert (land.x, land.y) == (round(float(lat) * 1e7), round(float(lon) * 1e7))
    # first there at the end's altitude (PX4's NAV_LAND descends on its way to its point)
    before = conv.missions["d1"].items[-3]
    assert go.command == Cmd.NAV_WAYPOINT and (go.x, go.y) == (land.x, land.y)
    assert go.z == pytest.approx(before.z) and go.z == pytest.approx(land.z)

    # one waypoint more than the plan's for d1; d2 lands straight down, none more
    def waypoints(name: str) -> int:
        return sum(1 for it in conv.missions[name].items if it.command == Cmd.NAV_WAYPOINT)

    assert waypoints("d1") == len(conv.missions["d1"].hold_s) + 1
    assert waypoints("d2") == len(conv.missions["d2"].hold_s)
    # a no-fly zone under the whole workspace: nowhere to land
    ws = plan.workspace
    road = Region("road", RegionKind.NO_FLY, (ws.lo_enu_m[0], ws.lo_enu_m[1], -1.0), (ws.hi_enu_m[0], ws.hi_enu_m[1], 0.1))  # fmt: skip
    with pytest.raises(UserError, match=r"--end land: d1: straight down .* no clear landing point"):
        landing_targets(_with(plan, road))
    # through the command line: one line, exit 2, before connecting to anything
    data = json.loads(PLAN.read_text())
    data["regions"]["road"] = {"kind": "no_fly", "min": [*ws.lo_enu_m[:2], -1.0], "max": [*ws.hi_enu_m[:2], 0.1]}  # fmt: skip
    path = tmp_path / "road.json"
    path.write_text(json.dumps(data))
    capsys.readouterr()
    assert main(["fly", str(path), "--end", "land", "--connection", "udpin://127.0.0.1:9", "--connection", "udpin://127.0.0.1:10"]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no clear landing point" in err and "Traceback" not in err


def _turned_excess(p_xy: np.ndarray, centre: tuple[float, float], half: tuple[float, float], yaw: float) -> np.ndarray:  # fmt: skip
    """Reference for a turned box grown by the clearance, computed in its own axes: how far
    points ``(n, 2)`` lie outside it (<= 0: within the clearance or inside)."""
    u = np.array([np.cos(yaw), np.sin(yaw)])
    w = np.array([-u[1], u[0]])
    rel = np.atleast_2d(p_xy) - np.asarray(centre)
    return np.maximum(np.abs(rel @ u) - half[0], np.abs(rel @ w) - half[1]) - CLEARANCE_M


def _turned(name: str, centre: tuple[float, float], half: tuple[float, float], yaw: float, top_m: float, kind: RegionKind = RegionKind.NO_FLY) -> Region:  # fmt: skip
    from planner.spec.regions import Prism

    prism = Prism.oriented_box((*centre, top_m / 2), (*half, top_m / 2), yaw)
    return Region.of_shape(name, kind, prism)


def test_column_and_transit_use_a_turned_box_and_a_cylinder_not_their_bounding_boxes() -> None:
    from gcs.flight.landing import column_blocker, transit_clear
    from planner.spec.regions import Cylinder, Prism

    centre, half, yaw = (0.0, 0.0), (2.0, 0.3), math.pi / 4
    wall = _turned("wall", centre, half, yaw, 3.0)
    rng = np.random.default_rng(7)
    pts = rng.uniform(-3.0, 3.0, (3000, 2))
    excess = _turned_excess(pts, centre, half, yaw)
    pts, excess = pts[np.abs(excess) > 1e-6], excess[np.abs(excess) > 1e-6]
    blocked = np.array([column_blocker(q, 2.0, (wall,)) is wall for q in pts])
    np.testing.assert_array_equal(blocked, excess <= 0.0)
    # where a test of the bounding box (grown alike) would block, and the turned box does not
    lo, hi = (
        np.asarray(wall.lo_enu_m[:2]) - CLEARANCE_M,
        np.asarray(wall.hi_enu_m[:2]) + CLEARANCE_M,
    )
    in_bbox = np.all((pts >= lo) & (pts <= hi), axis=1)
    assert np.count_nonzero(in_bbox & ~blocked) > 500
    assert column_blocker(np.array([1.4, -1.4]), 2.0, (wall,)) is None  # 1.68 m off the wall
    assert column_blocker(np.array([1.4, 1.4]), 2.0, (wall,)) is wall  # on its long axis
    raised = Region.of_shape("raised", RegionKind.NO_FLY, Prism.oriented_box((0, 0, 4), (2, 0.3, 1), yaw))  # fmt: skip
    assert column_blocker(np.array([1.4, 1.4]), 2.0, (raised,)) is None  # its floor is above 2 m

    # transits at 2 m (level with the wall): exact vs. 4001 samples along each segment
    starts, ends = rng.uniform(-3.5, 3.5, (400, 2)), rng.uniform(-3.5, 3.5, (400, 2))
    s = np.linspace(0.0, 1.0, 4001)[:, None]
    checked = 0
    for a, b in zip(starts, ends, strict=True):
        worst = float(_turned_excess(a + s * (b - a), centre, half, yaw).min())
        if abs(worst) < 0.01:  # grazing: the sampling cannot tell
            continue
        assert transit_clear(a, b, 2.0, (wall,)) == (worst > 0.0), (a, b, worst)
        checked += 1
    assert checked > 350
    # through the bounding box's empty corner: clear; across the wall: not; over it: clear
    assert transit_clear(np.array([1.0, -2.5]), np.array([2.5, -1.0]), 2.0, (wall,))
    assert not transit_clear(np.array([-2.0, 1.0]), np.array([1.0, -2.0]), 2.0, (wall,))
    assert transit_clear(np.array([-2.0, 1.0]), np.array([1.0, -2.0]), 3.5, (wall,))

    pole = Region.of_shape("pole", RegionKind.POLE, Cylinder((0.0, 0.0), 0.5, 0.0, 3.0))
    reach = 0.5 + CLEARANCE_M
    assert column_blocker(np.array([0.69, 0.69]), 2.0, (pole,)) is pole  # 0.976 m off the axis
    assert column_blocker(np.array([0.8, 0.8]), 2.0, (pole,)) is None  # 1.13 m: in its box only
    for a, b in (((-2.0, 0.95), (2.0, 0.95)), ((-2.0, 1.05), (2.0, 1.05)), ((0.3, 1.5), (1.5, 0.3)), ((0.5, 2.0), (0.5, 1.2))):  # fmt: skip
        pa, pb = np.array(a), np.array(b)
        gap = np.hypot(*(pa + s * (pb - pa)).T).min()  # distance to the axis, sampled
        assert transit_clear(pa, pb, 2.0, (pole,)) == (gap > reach), (a, b, gap)


def test_an_end_beside_a_turned_keep_out_lands_straight_down_and_one_over_it_just_clear() -> None:
    plan = load_plan(PLAN)
    end = _end(plan, "d1")
    top = end[2] - 0.3  # below the transit: only the descent can meet it
    # a long wall turned 45 degrees whose bounding box holds d1's end, the wall itself 1.1 m off
    wall = _turned("wall", (end[0] + 1.0, end[1] + 1.0), (1.5, 0.2), -math.pi / 4, top)
    assert np.all(np.abs(end[:2] - wall.center_enu_m[:2]) < np.subtract(wall.hi_enu_m, wall.lo_enu_m)[:2] / 2)  # fmt: skip
    lp = landing_point(_with(plan, wall), "d1")
    assert lp.blocked_by is None and lp.moved_m == 0.0
    # the same wall right under the end: it moves across the wall, not out of its bounding box
    under = _turned("under", (end[0], end[1]), (1.5, 0.2), -math.pi / 4, top)
    lp = landing_point(_with(plan, under), "d1")
    assert lp.blocked_by is under and lp.found
    assert _turned_excess(lp.point_enu_m[:2], (end[0], end[1]), (1.5, 0.2), -math.pi / 4)[0] > 0
    half_bbox = (np.subtract(under.hi_enu_m, under.lo_enu_m)[:2] / 2 + CLEARANCE_M).min()
    assert 0.2 + CLEARANCE_M <= lp.moved_m < half_bbox  # 0.7 m would do; 1.56 m for its box
    assert lp.point_enu_m[2] == pytest.approx(end[2])


@pytest.mark.slow
def test_an_offboard_flight_ending_over_a_keep_out_lands_clear_of_it() -> None:
    from mavlink.offboard import fly_offboard
    from mavlink.offboard.setpoints import EndAction, OffboardConfig
    from planner.frames import enu_to_geodetic
    from tests.mavlink.linkutil import mock_and_fleet

    plan = load_plan(PLAN)
    end = _end(plan, "d1")
    mast = Region("mast", RegionKind.POLE, (end[0] - 0.1, end[1] - 0.1, 0.0), (end[0] + 0.1, end[1] + 0.1, end[2] - 0.3))  # fmt: skip
    point = landing_point(_with(plan, mast), "d1").point_enu_m
    lat, lon, alt = (float(np.ravel(x)[0]) for x in enu_to_geodetic(point, plan.origin))
    names = [v.name for v in plan.vehicles]
    spawns = [(v.start_enu_m[0], v.start_enu_m[1], 0.0) for v in plan.vehicles]
    trajs = {v.name: v.trajectory for v in plan.vehicles}

    async def run():  # type: ignore[no-untyped-def]
        async with mock_and_fleet(names, plan.origin, spawns, profile="ideal") as (mock, fleet):
            cfg = OffboardConfig(end_action=EndAction.LAND, land_at={"d1": (lat, lon, alt)},
                                 arrive_m=0.3)  # fmt: skip
            result = await fly_offboard(fleet, trajs, plan.origin, cfg)
            for _ in range(300):  # until both are down
                if all(v.state.landed for v in mock.vehicles):
                    break
                await asyncio.sleep(0.1)
            return result, mock.truth_enu_m(), [v.state.landed for v in mock.vehicles]

    result, truth, landed = asyncio.run(run())
    assert result.completed and not result.end_failures and all(landed)
    assert np.hypot(*(truth[0, :2] - point[:2])) < 0.35  # d1 at its landing point
    assert not _inside_widened(np.array([*truth[0, :2], 0.0]), mast, 2)
    assert np.hypot(*(truth[1, :2] - _end(plan, "d2")[:2])) < 0.35  # d2 straight down
