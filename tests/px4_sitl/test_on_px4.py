"""Against a real PX4 (SITL or hardware) that is already running: opt-in, never in CI.

Set ``STL_GCS_PX4`` to the connection of one PX4 vehicle standing on the ground, e.g.
``STL_GCS_PX4=udpin://0.0.0.0:14540`` for PX4 v1.17 SITL instance 0 (SIH quad-rotor, system
id 1), and run ``.venv/bin/python -m pytest tests/px4_sitl``.  Without it every test here is
skipped.  The vehicle must be armable and free to fly 4 m east and 3 m up of where it
stands; the tests plan around its own home position, so no spawn pose is needed.

What is checked is PX4's side of the contracts the mock was calibrated to
(``docs/px4-behaviour.md``): the read-back of a mission and a fence as PX4 stores them,
a mission start confirmed only when PX4 really flies it, an offboard flight with the drag
fed forward that keeps the plan's margin, mission mode on one shared clock, and a replan in
flight (an area closed by ``--live-regions``) switched into the stream without a break.
"""

from __future__ import annotations

import asyncio
import json
import os
from pathlib import Path

import pytest

from gcs.cli import main

URL = os.environ.get("STL_GCS_PX4", "")
pytestmark = pytest.mark.skipif(not URL, reason="STL_GCS_PX4 names no running PX4 vehicle")

SCENARIO = """\
name: px4_hop
origin: {{lat: {lat:.8f}, lon: {lon:.8f}, alt: {alt:.3f}}}
workspace: {{min: [-3, -3, 0], max: [8, 3, 6]}}
regions:
  goal: {{kind: goal, center: [4.0, 0.0, 3.0], half_size: 0.8}}
limits: {{v_max_m_s: 1.5, a_max_m_s2: 1.5}}
vehicles:
  - {{name: d1, start: [0.0, 0.0, 3.0]}}
timing: {{horizon_s: 10, segment_s: 2, Ts_s: 0.1, check_dt_s: 0.02}}
separation_m: 1.0
epsilon: 0.05
model: minimum_jerk
spec:
  - formula: eventually[3, 9] always[0, 1] inside(d1, goal)
  - formula: always[0, 10] inside(d1, workspace)
"""


def _here() -> tuple[float, float, float]:
    """Where the vehicle stands now (its estimate; a landing ends up to ~1 m from home)."""
    from mavlink.link.fleet import Fleet
    from mavlink.link.vehicle_status import VehicleSpec

    async def read() -> tuple[float, float, float]:
        async with Fleet([VehicleSpec("d1", URL, 1)], connect_timeout_s=15.0) as fleet:
            st = await fleet["d1"].wait_for(
                lambda s: s.position is not None and s.home is not None, "position", timeout_s=15.0
            )
            assert st.position is not None and st.home is not None
            return st.position.lat_deg, st.position.lon_deg, st.home.alt_m

    return asyncio.run(read())


@pytest.fixture
def plan_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 10 s hop planned around where the vehicle stands (its start 3 m above home)."""
    lat, lon, alt = _here()
    d = tmp_path_factory.mktemp("px4")
    (d / "hop.yaml").write_text(SCENARIO.format(lat=lat, lon=lon, alt=alt), encoding="utf-8")
    assert main(["plan", str(d / "hop.yaml"), "-o", str(d / "hop.json"), "--json"]) == 0
    return d / "hop.json"


def _land_and_wait() -> None:
    """Wait until the vehicle is back home and disarmed (every flight here ends in RTL)."""
    from mavlink.link.fleet import Fleet
    from mavlink.link.vehicle_status import VehicleSpec

    async def land() -> None:
        async with Fleet([VehicleSpec("d1", URL, 1)], connect_timeout_s=15.0) as fleet:
            v = fleet["d1"]
            if (
                v.status().armed
                and v.status().mode is not None
                and "RTL" not in v.status().mode.label
            ):
                await v.return_to_launch()
            await v.wait_for(lambda s: s.armed is False, "disarmed at home", timeout_s=120.0)

    asyncio.run(land())


def test_upload_fence_and_start_are_read_back_and_confirmed_as_px4_does_them(
    plan_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(
        [
            "upload",
            str(plan_file),
            "--fence",
            "--start",
            "--force",
            "--end",
            "return",
            "--json",
            "--connection",
            URL,
        ]
    )
    out, err = capsys.readouterr()
    assert out, err
    res = json.loads(out)
    row = res["vehicles"][0]
    assert row["verified"], row  # fence autocontinue 0, yaw wrapped: still "as sent"
    assert rc == (0 if row["started"] else 1)
    assert row["started"], row["start_detail"]  # AUTO.MISSION, armed and climbing
    _land_and_wait()


def test_offboard_with_the_drag_fed_forward_keeps_the_margin(
    plan_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(["fly", str(plan_file), "--json", "--end", "return", "--connection", URL])
    out, err = capsys.readouterr()
    assert out, err
    res = json.loads(out)
    assert res["completed"] and res["safety_event"] is None, err
    assert abs(res["tracking"][0]["lag_s"]) < 0.2  # SIH's 0.585 s drag lag fed forward
    assert res["flown_robustness"] > 0 and rc == 0
    _land_and_wait()


def test_mission_mode_flies_on_one_clock_as_predicted(
    plan_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["fly", str(plan_file), "--json", "--mode", "mission", "--force", "--end", "return"]
    main([*argv, "--connection", URL])
    out, err = capsys.readouterr()
    assert out, err
    res = json.loads(out)
    m = res["missions"]["d1"]
    assert m["finished"] and m["late_s"] < 10.0, (m, res["safety_event"], err[-300:])
    assert res["flown_robustness"] is not None
    pred = res["mission_prediction"]["predicted_robustness"]
    assert abs(res["flown_robustness"] - pred) < 0.3, (res["flown_robustness"], pred)
    _land_and_wait()


FACING = """\
name: px4_facing
origin: {{lat: {lat:.8f}, lon: {lon:.8f}, alt: {alt:.3f}}}
workspace: {{min: [-3, -3, 0], max: [8, 6, 6]}}
regions:
  pole: {{kind: pole, center: [4.0, 2.5], radius: 0.3, z: [0, 6]}}
  insp: {{kind: inspection, center: [4.0, -0.3, 3.0], half_size: [0.7, 0.7, 0.6]}}
limits: {{v_max_m_s: 1.5, a_max_m_s2: 1.5}}
vehicles:
  - {{name: d1, start: [0.0, 0.0, 3.0]}}
timing: {{horizon_s: 12, segment_s: 2, Ts_s: 0.1, check_dt_s: 0.02}}
separation_m: 1.0
epsilon: 0.05
model: minimum_jerk
spec:
  - formula: eventually[3, 8] always[0, 3] (inside(d1, insp) and face(d1, pole))
  - formula: always[0, 12] inside(d1, workspace)
  - formula: always[0, 12] outside(d1, pole)
"""


def test_a_facing_mission_carries_its_camera_items_and_px4_flies_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """PX4 accepts the camera and gimbal items (MAV_FRAME_MISSION) and reads them back as sent;
    the mission is flown to its end (AUTO.LOITER where it ends is not "leaving the mission"),
    and the pictures reported are the ones that happened: SIH SITL has no camera."""
    lat, lon, alt = _here()
    (tmp_path / "facing.yaml").write_text(FACING.format(lat=lat, lon=lon, alt=alt))
    plan = tmp_path / "facing.json"
    assert main(["plan", str(tmp_path / "facing.yaml"), "-o", str(plan), "--json"]) == 0
    capsys.readouterr()
    argv = ["fly", str(plan), "--json", "--mode", "mission", "--force", "--end", "hold"]
    main([*argv, "--log", str(tmp_path / "log"), "--connection", URL])
    out, err = capsys.readouterr()
    res = json.loads(out)
    assert res["completed"] and res["safety_event"] is None, err
    assert res["missions"]["d1"]["finished"]
    cov = res["coverage"]
    assert cov["targets"] == 1 and cov["by_target"][0]["planned"] >= 3
    if not res["images"]:  # PX4 SIH: no camera, and the flight says so
        assert "no camera heard" in err and cov["covered"] == 0
    _land_and_wait()


CORRIDOR = """\
name: px4_corridor
origin: {{lat: {lat:.8f}, lon: {lon:.8f}, alt: {alt:.3f}}}
workspace: {{min: [-4, -4, 0], max: [12, 12, 6]}}
regions:
  row: {{polygon: [[-2, -2], [10, -2], [10, 2], [2, 2], [2, 10], [-2, 10]], z: [0, 6]}}
  nofly: {{kind: no_fly, polygon: [[5, 5], [11, 5], [11, 11], [9, 11], [9, 8], [5, 8]], z: [0, 6]}}
  east: {{kind: goal, center: [7.0, 0.0, 3.0], half_size: [1.2, 1.2, 0.8]}}
  north: {{kind: goal, center: [0.0, 7.0, 3.0], half_size: [1.2, 1.2, 0.8]}}
limits: {{v_max_m_s: 2, a_max_m_s2: 1.5}}
vehicles:
  - {{name: d1, start: [0.0, 0.0, 3.0]}}
timing: {{horizon_s: 24, segment_s: 2, Ts_s: 0.1, check_dt_s: 0.02}}
separation_m: 1.0
epsilon: 0.05
model: minimum_jerk
spec:
  - formula: eventually[4, 10] always[0, 1] inside(d1, east)
  - formula: eventually[15, 22] always[0, 1] inside(d1, north)
  - formula: always[0, 24] (inside(d1, row) and outside(d1, nofly) and inside(d1, workspace))
"""


def test_an_l_shaped_right_of_way_and_no_fly_area_are_fenced_and_flown_as_px4_does_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Polygons that are not convex: the L-shaped no-fly area is fenced as its two convex
    parts (PX4 reads them back as sent and ANDs them as exclusions), and the plan, which
    crosses the L-shaped right of way's corner from one arm to the other, is flown offboard
    inside that fence without PX4's fence firing, keeping a positive margin."""
    lat, lon, alt = _here()
    (tmp_path / "corridor.yaml").write_text(CORRIDOR.format(lat=lat, lon=lon, alt=alt))
    plan = tmp_path / "corridor.json"
    assert main(["plan", str(tmp_path / "corridor.yaml"), "-o", str(plan), "--json"]) == 0
    capsys.readouterr()
    rc = main(["upload", str(plan), "--fence", "--json", "--connection", URL])
    out, err = capsys.readouterr()
    row = json.loads(out)["vehicles"][0]
    assert rc == 0 and row["verified"], (row, err[-300:])
    from gcs.flight.missions import fence_plan
    from planner.planfile import load_plan

    polygons = {int(i.param1) for i in fence_plan(load_plan(plan)).items}
    assert polygons == {4}  # the workspace and the no-fly area's two parts, 4 corners each
    main(["fly", str(plan), "--json", "--end", "return", "--connection", URL])
    out, err = capsys.readouterr()
    res = json.loads(out)
    assert res["completed"] and res["safety_event"] is None, err[-300:]
    assert res["flown_robustness"] > 0, res["flown_robustness"]
    _land_and_wait()


def test_an_area_closed_in_flight_is_replanned_around_and_the_stream_switches_without_a_break(
    plan_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # a strip south of the hop, closed from the start (gcs fly --replan --live-regions): the
    # replan comes at the first poll, the stream switches a waypoint later on PX4's clock
    live = plan_file.parent / "closed.yaml"
    live.write_text("regions:\n  strip: {min: [-3, -3, 0], max: [8, -1.5, 6]}\n", "utf-8")
    rc = main(
        ["fly", str(plan_file), "--json", "--end", "return", "--connection", URL,
         "--replan", "--live-regions", str(live)]
    )  # fmt: skip
    out, err = capsys.readouterr()
    assert out, err
    res = json.loads(out)
    [r] = res["replans"]
    assert r["success"] and r["event"].endswith(": strip"), r
    assert "outside(d1, strip)" in res["judged_spec"]
    assert res["completed"] and res["safety_event"] is None, err
    assert res["tracking"][0]["max_m"] < 1.0  # no jump at the switch
    assert res["flown_robustness"] > 0 and rc == 0
    _land_and_wait()
