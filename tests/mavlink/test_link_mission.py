"""Trajectories as PX4 missions: conversion (pure), and upload / read-back / flight on the mock."""

from __future__ import annotations

import asyncio
import dataclasses
import math

import numpy as np
import pymap3d
import pytest

from mavlink.errors import MissionError, MissionResult
from mavlink.flight import StartGate, fly
from mavlink.mission import (
    Cmd,
    Frame,
    MissionEnd,
    MissionItem,
    MissionType,
    compare_items,
    fence_boxes,
    fence_zones,
    geofence_items,
    path_deviation,
    path_robustness,
    start_mission_confirmed,
    trajectory_to_mission,
    upload,
    upload_and_verify,
    verify,
)
from mavlink.mission.flight import START_ITEM, MissionDriver
from mavlink.mock import Px4Mode
from planner.frames import GeodeticPoint
from planner.trajectory import Trajectory
from tests.mavlink.linkutil import mock_and_fleet, scenario, spec_formula, stored_plan

pytestmark = pytest.mark.slow  # flights or transfers over UDP (make test-fast skips)

ORIGIN = GeodeticPoint(47.397742, 8.545594, 488.0)


def min_jerk(waypoints: list[tuple[float, float, float]], seg_s: float) -> Trajectory:
    """Rest-to-rest quintic between consecutive waypoints (a repeated waypoint is a hover)."""
    w = np.asarray(waypoints, dtype=float)
    n = len(w) - 1
    c = np.zeros((n, 3, 6))
    for s in range(n):
        d = w[s + 1] - w[s]
        c[s, :, 0] = w[s]
        c[s, :, 3] = 10 * d / seg_s**3
        c[s, :, 4] = -15 * d / seg_s**4
        c[s, :, 5] = 6 * d / seg_s**5
    return Trajectory(np.arange(n) * seg_s, np.full(n, seg_s), c, name="d1")


def e7(lat_lon_alt: tuple[float, float, float]) -> tuple[int, int, float]:
    return round(lat_lon_alt[0] * 1e7), round(lat_lon_alt[1] * 1e7), lat_lon_alt[2]


def test_mission_items_follow_the_trajectory_legs_hovers_and_speeds() -> None:
    # 1 s segments: hover 2 s, leg east 3 m in 1 s, hover 2 s, leg north 4 m in 1 s, land.
    wps = [(0, 0, 2), (0, 0, 2), (0, 0, 2), (3, 0, 2), (3, 0, 2), (3, 0, 2), (3, 4, 2)]
    traj = min_jerk(wps, 1.0)
    mp = trajectory_to_mission(traj, ORIGIN, acceptance_radius_m=0.25, end=MissionEnd.LAND)
    cmds = [i.command for i in mp.items]
    assert cmds == [
        Cmd.NAV_TAKEOFF,
        Cmd.NAV_WAYPOINT,
        Cmd.DO_CHANGE_SPEED,
        Cmd.NAV_WAYPOINT,
        Cmd.DO_CHANGE_SPEED,
        Cmd.NAV_WAYPOINT,
        Cmd.NAV_LAND,
    ]
    assert [i.seq for i in mp.items] == list(range(7))
    wp_items = [i for i in mp.items if i.command == Cmd.NAV_WAYPOINT]
    assert [i.param1 for i in wp_items] == [2.0, 2.0, 0.0]  # hold times where the plan hovers
    assert all(i.param2 == 0.25 for i in wp_items)  # acceptance radius
    speeds = [i.param2 for i in mp.items if i.command == Cmd.DO_CHANGE_SPEED]
    assert speeds == pytest.approx([3.0, 4.0])  # chord length / leg duration
    # Positions: pymap3d's geodetic of the ENU waypoints (independent of the module's path).
    for item, (x, y, z) in zip(wp_items, [(0, 0, 2), (3, 0, 2), (3, 4, 2)], strict=True):
        lat, lon, alt = pymap3d.enu2geodetic(x, y, z, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
        assert (item.x, item.y) == e7((lat, lon, alt))[:2]
        assert item.z == pytest.approx(alt, abs=1e-6)
        assert item.frame == Frame.GLOBAL_INT
    assert math.isnan(mp.items[-1].param4)
    # The straight-leg path meets the plan at every waypoint at the planned time ...
    np.testing.assert_allclose(mp.arrival_t_s, [0.0, 3.0, 6.0])
    for t, p in (
        (0.0, (0, 0, 2)),
        (2.0, (0, 0, 2)),
        (3.0, (3, 0, 2)),
        (5.0, (3, 0, 2)),
        (6.0, (3, 4, 2)),
    ):
        np.testing.assert_allclose(mp.path.position(np.array([t]))[0], p, atol=1e-12)
    # ... and in between deviates as a min-jerk leg does from a constant-speed one:
    # max |s(u) - u| for s = 10u^3 - 15u^4 + 6u^5 over a 4 m leg.
    u = np.linspace(0, 1, 100001)
    ref = 4.0 * np.max(np.abs(10 * u**3 - 15 * u**4 + 6 * u**5 - u))
    dev = path_deviation(traj, mp.path, dt_s=0.001)
    assert dev.max_m == pytest.approx(ref, rel=1e-3)
    assert 5.0 < dev.t_at_max_s < 6.0


def test_mission_end_options_and_bad_radius() -> None:
    traj = min_jerk([(0, 0, 2), (2, 0, 2)], 2.0)
    rtl = trajectory_to_mission(traj, ORIGIN, end=MissionEnd.RETURN)
    assert rtl.items[-1].command == Cmd.NAV_RETURN_TO_LAUNCH
    hold = trajectory_to_mission(traj, ORIGIN, end=MissionEnd.HOLD)
    assert hold.items[-1].command == Cmd.NAV_WAYPOINT
    with pytest.raises(MissionError) as info:
        trajectory_to_mission(traj, ORIGIN, acceptance_radius_m=0.0)
    assert info.value.result is MissionResult.INVALID_ITEM and "acceptance_radius_m" in str(
        info.value
    )


def test_compare_items_works_at_wire_precision() -> None:
    a = trajectory_to_mission(min_jerk([(0, 0, 2), (2, 1, 2)], 2.0), ORIGIN).items
    same = [dataclasses.replace(i, param2=float(np.float32(i.param2)), current=1) for i in a]
    assert compare_items(a, same) == []  # float32 rounding and `current` are not differences
    moved = list(a)
    moved[1] = dataclasses.replace(a[1], x=a[1].x + 1)
    assert compare_items(a, moved) == [f"item 1: x sent {a[1].x}, read back {a[1].x + 1}"]
    assert compare_items(a, a[:-1])[0] == f"{len(a)} items sent, {len(a) - 1} read back"


def test_compare_items_reads_back_as_px4_stores_and_still_catches_what_matters() -> None:
    # docs/px4-behaviour.md's table, with PX4's own download of each item as the reference:
    # mavlink.mock.mission.px4_stored is that code path (mavlink_mission.cpp) in the mock.
    from mavlink.mock.mission import MissionItem as StoredItem
    from mavlink.mock.mission import px4_stored

    def as_px4(items: list[MissionItem]) -> list[MissionItem]:
        out = []
        for i in items:
            stored = px4_stored(StoredItem(**dataclasses.asdict(i)), current=0, legacy=False)
            out.append(MissionItem(**dataclasses.asdict(stored)))
        return out

    mission = list(trajectory_to_mission(min_jerk([(0, 0, 2), (2, 1, 2)], 2.0), ORIGIN).items)
    mission[1] = dataclasses.replace(mission[1], param4=-81.887)  # comes back as 278.113
    fence = list(geofence_items(fence_boxes(scenario(2).workspace, scenario(2).regions), ORIGIN))
    for sent in (mission, fence):
        back = as_px4(sent)
        assert back != sent  # autocontinue 0, yaw wrapped: not the bytes sent ...
        assert compare_items(sent, back) == []  # ... but what PX4 stores for them
        assert compare_items(sent, back, exact=True) != []
    # What matters still fails: a vertex moved, a vertex count, a yaw, a hold time.
    back = as_px4(fence)
    moved = dataclasses.replace(back[2], x=back[2].x + 10)
    assert compare_items(fence, [*back[:2], moved, *back[3:]]) == [
        f"item 2: x sent {fence[2].x}, read back {fence[2].x + 10}"
    ]
    five = dataclasses.replace(back[0], param1=5.0)
    assert "item 0: param1" in compare_items(fence, [five, *back[1:]])[0]
    back = as_px4(mission)
    turned = dataclasses.replace(back[1], param4=back[1].param4 + 1.0)
    assert "item 1: param4" in compare_items(mission, [back[0], turned, *back[2:]])[0]
    held = dataclasses.replace(back[1], param1=back[1].param1 + 1.0)
    assert "item 1: param1" in compare_items(mission, [back[0], held, *back[2:]])[0]


def test_pass_through_waypoints_get_the_drag_lag_as_radius_and_corners_keep_theirs() -> None:
    # A straight line in three 2 m/s legs, then a right angle: the two inner waypoints of
    # the line are flown through (radius = lag * speed + R / 2, capped at 45 % of a leg),
    # the corner and the end keep R.
    traj = min_jerk([(0, 0, 2), (4, 0, 2), (8, 0, 2), (12, 0, 2), (12, 4, 2)], 2.0)
    mp = trajectory_to_mission(traj, ORIGIN, acceptance_radius_m=0.6, pass_lag_s=0.585)
    assert mp.acceptance_m.tolist() == pytest.approx(
        [0.6, 0.585 * 2 + 0.3, 0.585 * 2 + 0.3, 0.6, 0.6]
    )
    wps = [i for i in mp.items if i.command == Cmd.NAV_WAYPOINT]
    assert [w.param2 for w in wps] == pytest.approx(mp.acceptance_m.tolist())
    speeds = trajectory_to_mission(traj, ORIGIN, leg_speed_m_s=[1.0, 2.0, 3.0, 4.0])
    assert [i.param2 for i in speeds.items if i.command == Cmd.DO_CHANGE_SPEED] == [1, 2, 3, 4]
    with pytest.raises(MissionError):
        trajectory_to_mission(traj, ORIGIN, leg_speed_m_s=[1.0, 2.0])


def test_mission_path_of_the_stored_plan_keeps_its_robustness_close() -> None:
    plan, problem = stored_plan(2), scenario(2)
    spec = spec_formula(problem)
    paths = {v.name: trajectory_to_mission(v.trajectory, plan.origin).path for v in plan.vehicles}
    dt, horizon = problem.timing.check_dt_s, problem.timing.horizon_s
    rho = path_robustness(spec, paths, dt, horizon)
    t = np.arange(round(horizon / dt) + 1) * dt
    rho_plan = spec.robustness({v.name: v.trajectory.position(t) for v in plan.vehicles}, dt)
    worst = max(path_deviation(v.trajectory, paths[v.name]).max_m for v in plan.vehicles)
    # Every predicate is 1-Lipschitz in each vehicle's position (box margins, distances), so
    # moving each vehicle by at most `worst` changes the robustness by at most 2 * worst
    # (dist(a, b) moves with both vehicles).
    assert rho_plan - 2 * worst - 1e-9 <= rho <= rho_plan + 2 * worst + 1e-9


@pytest.mark.parametrize("profile", ["ideal", "px4"])
def test_upload_read_back_identical_then_fly_the_mission_on_the_mock(profile: str) -> None:
    plan = stored_plan(2)
    v1 = plan.vehicles[0]
    mp = trajectory_to_mission(v1.trajectory, plan.origin, acceptance_radius_m=0.3)
    boxes = fence_boxes(plan.workspace, plan.regions)
    assert [(b.name, b.inclusion) for b in boxes] == [("workspace", True), ("obstacle", False)]
    fence = geofence_items(boxes, plan.origin)
    spawn = (v1.start_enu_m[0], v1.start_enu_m[1], 0.0)

    async def run():
        async with mock_and_fleet(["d1"], plan.origin, [spawn], profile=profile) as (mock, fleet):
            v = fleet["d1"]
            report = await upload_and_verify(v, mp.items)
            fence_report = await upload_and_verify(v, fence, MissionType.FENCE)
            stored = mock.vehicles[0].mission_items(0)
            stored_fence = mock.vehicles[0].mission_items(1)
            # A different upload replaces it; the read-back then reports the mismatch.
            changed = list(mp.items)
            changed[3] = dataclasses.replace(changed[3], param1=9.0)
            await upload(v, changed)
            with pytest.raises(MissionError) as info:
                await verify(v, mp.items)
            await upload(v, mp.items)
            # flown as gcs fly --mode mission flies it: take-off, onto the start, released
            # into the mission at its start waypoint (the mission already on the vehicle)
            yaw = {"d1": float(mp.items[START_ITEM].param4)}
            driver = MissionDriver(
                {"d1": np.asarray(v1.start_enu_m)}, yaw, plan.origin, plan.horizon_s,
                StartGate(arrive_m=0.3, arrive_timeout_s=30.0),
            )  # fmt: skip
            flown = await fly(fleet, driver, plan.origin)
            return report, fence_report, stored, stored_fence, info.value, flown, driver

    report, fence_report, stored, stored_fence, mismatch, flown, driver = asyncio.run(run())
    assert report.items == len(mp.items) and fence_report.items == 8
    # The vehicle's own copy (the mock's storage, not MAVSDK's download) equals what we sent.
    assert compare_items(mp.items, [MissionItem(**dataclasses.asdict(i)) for i in stored]) == []
    assert compare_items(fence, [MissionItem(**dataclasses.asdict(i)) for i in stored_fence]) == []
    assert mismatch.result is MissionResult.MISMATCH and mismatch.origin == "verify_mission"
    assert "item 3: param1 sent 2.0, read back 9.0" in str(mismatch) or "item 3: param1" in str(
        mismatch
    )
    run = flown.runs["d1"]
    assert run.finished and flown.completed and flown.safety_event is None
    assert driver.confirmed["d1"].started
    wp_seqs = [i.seq for i in mp.items if i.command == Cmd.NAV_WAYPOINT]
    assert run.passed(wp_seqs) == wp_seqs  # every waypoint
    # ... left in order (read from MISSION_CURRENT: PX4 reports only the last item processed)
    left = [run.left_s(s) for s in wp_seqs[:-1]]
    assert all(t is not None for t in left) and left == sorted(left)
    # each reached seq counted once, whatever PX4 re-sends
    reached = [seq for seq, _ in run.reached]
    assert len(reached) == len(set(reached))
    seqs = [seq for seq, _ in run.current]
    # MISSION_CURRENT walked through the items in order, to the last one.
    assert seqs == sorted(seqs) and seqs[-1] == len(mp.items) - 1


def test_geofence_polygons_are_the_box_footprints() -> None:
    from mavlink.mission import FenceBox

    items = geofence_items(
        [
            FenceBox("ws", (-4.0, -4.0, 0.0), (4.0, 4.0, 3.0), inclusion=True),
            FenceBox("nfz", (1.0, 2.0, 0.0), (1.5, 3.0, 9.0), inclusion=False),
        ],
        ORIGIN,
    )
    assert [i.command for i in items] == [Cmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION] * 4 + [
        Cmd.NAV_FENCE_POLYGON_VERTEX_EXCLUSION
    ] * 4
    assert all(i.param1 == 4.0 and i.mission_type == MissionType.FENCE for i in items)
    assert [i.seq for i in items] == list(range(8))
    corners = [(-4, -4), (4, -4), (4, 4), (-4, 4), (1, 2), (1.5, 2), (1.5, 3), (1, 3)]
    for item, (x, y) in zip(items, corners, strict=True):
        lat, lon, _ = pymap3d.enu2geodetic(x, y, 0.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
        assert (item.x, item.y) == (round(lat * 1e7), round(lon * 1e7))


def test_fence_excludes_only_stay_out_boxes_that_span_the_workspace_height() -> None:
    from planner.spec.regions import Region, RegionKind

    ws = Region("workspace", RegionKind.WORKSPACE, (-5.0, -5.0, 0.5), (5.0, 5.0, 20.0))
    regions = [
        # A fence prism has no ceiling: excluding this low obstacle would forbid flying over it.
        Region("low", RegionKind.OBSTACLE, (-1.0, -1.0, 0.0), (1.0, 1.0, 12.0)),
        Region("tower", RegionKind.POLE, (2.0, 2.0, 0.0), (2.5, 2.5, 25.0)),
        Region("nofly", RegionKind.NO_FLY, (-4.0, 3.0, 0.0), (-3.0, 4.0, 20.0)),
        Region("line", RegionKind.CONDUCTOR, (-5.0, -0.2, 0.0), (5.0, 0.2, 30.0)),
        Region("goal", RegionKind.GOAL, (3.0, -4.0, 0.0), (4.0, -3.0, 30.0)),
    ]
    boxes = fence_boxes(ws, regions)
    assert [(b.name, b.inclusion) for b in boxes] == [
        ("workspace", True),
        ("tower", False),
        ("nofly", False),
    ]


def _shaped_scenario():  # type: ignore[no-untyped-def]
    """A workspace with full-height keep-outs of every shape, and a low one (not fenced)."""
    from planner.spec.regions import Cylinder, Prism, Region, RegionKind

    ws = Region("workspace", RegionKind.WORKSPACE, (-10.0, -10.0, 0.0), (10.0, 10.0, 5.0))
    kinds = RegionKind
    regions = [
        # a cylinder first: its circle still follows every polygon (QGC's order)
        Region.of_shape("pole", kinds.POLE, Cylinder((-4.0, 3.0), 0.8, 0.0, 6.0)),
        Region.of_shape(
            "wall", kinds.NO_FLY, Prism.oriented_box((3.0, 0.0, 2.5), (2.0, 0.3, 2.5), math.pi / 4)
        ),
        Region.of_shape(
            "area",
            kinds.NO_FLY,
            Prism.from_polygon([[-8, -8], [-4, -9], [-3, -5], [-7, -4]], 0.0, 5.0),
        ),
        Region.of_shape(
            "low", kinds.OBSTACLE, Prism.oriented_box((0.0, 6.0, 1.0), (1.0, 0.5, 1.0), 0.3)
        ),
    ]
    return ws, regions


#: Turned-wall corners, independently: centre (3, 0) +- 2 along (1, 1)/sqrt2 and +- 0.3 across.
_WALL = [
    (
        3.0 + su * 2.0 * math.sqrt(0.5) - sv * 0.3 * math.sqrt(0.5),
        su * 2.0 * math.sqrt(0.5) + sv * 0.3 * math.sqrt(0.5),
    )
    for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1))
]
_AREA = [(-8.0, -8.0), (-4.0, -9.0), (-3.0, -5.0), (-7.0, -4.0)]


def _geodetic_e7(x: float, y: float) -> tuple[int, int]:
    lat, lon, _ = pymap3d.enu2geodetic(x, y, 0.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    return round(lat * 1e7), round(lon * 1e7)


def test_full_height_prisms_are_exclusion_polygons_and_cylinders_exclusion_circles() -> None:
    from mavlink.mission import FenceBox, FenceCircle, FencePolygon, fence_zones

    ws, regions = _shaped_scenario()
    zones = fence_zones(ws, regions)
    assert [(type(z), z.name, z.inclusion) for z in zones] == [
        (FenceBox, "workspace", True),
        (FenceCircle, "pole", False),
        (FencePolygon, "wall", False),
        (FencePolygon, "area", False),
    ]  # the low turned obstacle can be flown over: no fence
    items = geofence_items(zones, ORIGIN)
    assert [i.seq for i in items] == list(range(len(items))) == list(range(13))
    assert [i.command for i in items] == (
        [Cmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION] * 4
        + [Cmd.NAV_FENCE_POLYGON_VERTEX_EXCLUSION] * 8
        + [Cmd.NAV_FENCE_CIRCLE_EXCLUSION]
    )
    assert all(i.mission_type == MissionType.FENCE and i.frame == Frame.GLOBAL_INT for i in items)
    assert [i.param1 for i in items[:12]] == [4.0] * 12
    corners = [(-10, -10), (10, -10), (10, 10), (-10, 10), *_WALL, *_AREA]
    for item, (x, y) in zip(items[:12], corners, strict=True):
        assert abs(item.x - _geodetic_e7(x, y)[0]) <= 1 and abs(item.y - _geodetic_e7(x, y)[1]) <= 1
    circle = items[12]
    assert circle.param1 == 0.8  # the radius, m
    assert (circle.x, circle.y) == _geodetic_e7(-4.0, 3.0)  # the centre
    # a cylinder or prism lower than the workspace is not fenced, whatever its bounding box
    assert [
        z.name for z in fence_zones(dataclasses.replace(ws, hi_enu_m=(10.0, 10.0, 5.5)), regions)
    ] == ["workspace", "pole"]


def test_the_mock_vehicle_stores_the_shaped_fence_and_breaches_only_the_true_shapes() -> None:
    ws, regions = _shaped_scenario()
    fence = geofence_items(fence_zones(ws, regions), ORIGIN)

    async def run():  # type: ignore[no-untyped-def]
        spawn = [(0.0, -6.0, 0.0)]
        async with mock_and_fleet(["d1"], ORIGIN, spawn, profile="ideal") as (mock, fleet):
            # MAVSDK uploads, downloads and compares (upload_and_verify)
            report = await upload_and_verify(fleet["d1"], fence, MissionType.FENCE)
            return report, mock.vehicles[0].mission_items(1), mock.vehicles[0]

    report, stored, vehicle = asyncio.run(run())
    assert report.items == 13
    assert compare_items(fence, [MissionItem(**dataclasses.asdict(i)) for i in stored]) == []

    def breached(x: float, y: float) -> bool:
        lat, lon, alt = pymap3d.enu2geodetic(
            x, y, 2.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m
        )
        return bool(vehicle.fence_violated(vehicle.global_to_ned(lat, lon, alt)))

    # inside each keep-out, and inside each one's bounding box but outside the shape itself
    assert breached(3.0, 0.0) and not breached(4.3, -1.3)  # the turned wall; its box's corner
    assert breached(-4.0, 3.0) and not breached(-3.3, 3.7)  # the pole (0.99 m off its axis)
    assert breached(-6.0, -6.0) and not breached(-3.5, -8.5)  # the polygon area
    assert not breached(0.0, 6.0)  # over the low obstacle: not fenced
    assert not breached(0.0, 0.0) and breached(10.5, 0.0)  # the workspace


def test_upload_whose_final_ack_is_lost_is_settled_by_the_read_back() -> None:
    plan = stored_plan(2)
    v1 = plan.vehicles[0]
    mp = trajectory_to_mission(v1.trajectory, plan.origin, acceptance_radius_m=0.3)
    spawn = (v1.start_enu_m[0], v1.start_enu_m[1], 0.0)

    async def run():
        async with mock_and_fleet(["d1"], plan.origin, [spawn]) as (mock, fleet):
            vehicle = mock.vehicles[0]
            send = vehicle.missions.send

            def drop_mission_acks(msg):  # type: ignore[no-untyped-def]
                # Every ACCEPTED ack of a MISSION upload is lost on the way to the GCS.
                if msg.get_type() == "MISSION_ACK" and msg.type == 0 and msg.mission_type == 0:
                    return
                send(msg)

            vehicle.missions.send = drop_mission_acks
            with pytest.raises(MissionError) as plain:
                await upload(fleet["d1"], mp.items)
            report = await upload_and_verify(fleet["d1"], mp.items)
            return plain.value, report, vehicle.mission_items(0)

    plain, report, stored = asyncio.run(run())
    assert plain.mavsdk_result == "TIMEOUT"  # what MAVSDK alone reports
    assert report.items == len(mp.items)  # ... while the vehicle holds the whole mission
    assert compare_items(mp.items, [MissionItem(**dataclasses.asdict(i)) for i in stored]) == []


# ------------------------------------------------------------------ starts, confirmed


def _start_case(params: dict[str, float], climb_m: float | None, ground_m: float = 0.0):  # type: ignore[no-untyped-def]  # fmt: skip
    """Upload d1's mission to a px4 mock with ``params`` (standing on ground ``ground_m`` m
    up in the mission frame) and start it at once, confirmed."""
    plan = stored_plan(2)
    v1 = plan.vehicles[0]
    mp = trajectory_to_mission(v1.trajectory, plan.origin, acceptance_radius_m=1.0)
    spawn = (v1.start_enu_m[0], v1.start_enu_m[1], ground_m)

    async def run():  # type: ignore[no-untyped-def]
        async with mock_and_fleet(["d1"], plan.origin, [spawn], params=params) as (mock, fleet):
            v = fleet["d1"]
            await upload(v, mp.items)
            result = await start_mission_confirmed(v, climb_m=climb_m, timeout_s=3.0)
            return result, mock.vehicles[0].state, float(-mock.physics.true_pos_ned_m[0, 2])

    return asyncio.run(run())


def test_a_start_px4_rejects_right_after_the_upload_is_retried_until_it_takes_effect() -> None:
    # PX4: ACCEPTED, then TEMPORARILY_REJECTED 12 ms later while the commander still flags
    # the mission missing; here that window is 0.5 s, so the first start surely falls in it.
    result, state, _agl = _start_case({"MOCK_MIS_RDY_T": 0.5}, climb_m=0.3)
    assert result.started and result.attempts >= 2, result
    assert "climbing" in result.detail
    assert state.mode is Px4Mode.AUTO_MISSION and state.armed


def test_a_start_px4_keeps_rejecting_is_reported_as_not_started_with_the_reason() -> None:
    result, state, _agl = _start_case({"MOCK_MIS_RDY_T": 5.0}, climb_m=0.3)
    assert not result.started and result.attempts >= 2
    assert "TEMPORARILY_REJECTED" in result.detail
    assert state.mode is not Px4Mode.AUTO_MISSION


def test_a_mission_whose_takeoff_px4_skips_is_not_reported_as_started() -> None:
    # The start is 0.4 m above the vehicle (1.5 m in a frame whose ground is at 1.1 m): within
    # NAV_MC_ALT_RAD (0.8 m) PX4 treats the take-off as a waypoint already reached, never spins
    # up, and auto-disarms after COM_DISARM_PRFLT (1 s here), as PX4 SITL did with 0.32 m.
    result, state, agl = _start_case({"COM_DISARM_PRFLT": 1.0, "MOCK_GE_RATE": 0.0}, 0.3, 1.1)
    assert not result.started, result
    assert "never left the ground" in result.detail or "did not climb" in result.detail
    assert not state.armed and agl < 0.05, (state, agl)  # on the ground, disarmed


def test_a_mission_px4_disarms_before_its_heartbeat_shows_it_armed_is_not_started_again() -> None:
    # The same skipped take-off, with the auto-disarm (0.3 s) before PX4's 1 Hz heartbeat can
    # show the vehicle armed in AUTO.MISSION: PX4 took the start, so the vehicle is not armed
    # and started a second time (it was, under load, and then climbed: "started")
    result, state, agl = _start_case({"COM_DISARM_PRFLT": 0.3, "MOCK_GE_RATE": 0.0}, 0.3, 1.1)
    assert not result.started, result
    # said either way round: disarmed before a heartbeat showed it armed ("PX4 disarmed it in
    # AUTO.MISSION"), or, where a heartbeat came in between (a busy machine), after it
    assert "AUTO.MISSION accepted but the vehicle never left the ground" in result.detail, result
    assert not state.armed and agl < 0.05, (state, agl)
