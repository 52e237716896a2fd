"""QGroundControl export: golden structure, and a round trip through MAVSDK's QGC importer.

The reference for the mission items is the link's own conversion
(:func:`gcs.flight.missions.convert_plan`, what ``gcs upload`` sends for PX4 defaults); the reader is the
real MAVSDK 4.1 C++ importer (``mission_raw.import_qgroundcontrol_mission_from_string``),
reached in-process: a ``raw://`` connection is fed one PX4 HEARTBEAT (encoded by pymavlink),
which makes MAVSDK discover a System that the mission_raw plugin can be created on. No
network and no vehicle are involved: the importer only parses the file.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d
import pytest

from gcs import cli
from gcs.export import QgcOptions, qgc_plan
from gcs.flight.missions import convert_plan, fence_plan
from mavlink.mission import (
    Cmd,
    MissionEnd,
    MissionItem,
    compare_items,
)
from planner.planfile import load_plan
from tests.gcs.test_export_support import ORIGIN, reach_avoid_plan, write_plan

MAV_FRAME_GLOBAL = 0
LINK_PLAN = Path(__file__).resolve().parents[1] / "mavlink" / "data" / "reach_avoid_2.plan.json"


class Importer:
    """MAVSDK's QGC plan importer on an in-process System (see module docstring)."""

    def __init__(self) -> None:
        from mavsdk import ComponentType, Configuration, Mavsdk
        from mavsdk.plugins.mission_raw import MissionRaw
        from pymavlink.dialects.v20 import common as mavlink2

        self.sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        result = self.sdk.add_any_connection("raw://")
        assert int(result) == 0, result  # ConnectionResult.SUCCESS
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        heartbeat = mavlink2.MAVLink_heartbeat_message(
            mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_PX4, 0, 0, 4, 3
        ).pack(mav)
        self.sdk.pass_received_raw_bytes(heartbeat)
        system = self.sdk.first_autopilot(timeout_s=10.0)
        assert system is not None, "MAVSDK did not discover the system from the heartbeat"
        self.plugin = MissionRaw(system)
        self._system = system

    def load(self, text: str) -> Any:
        return self.plugin.import_qgroundcontrol_mission_from_string(text)

    def close(self) -> None:
        self.sdk.destroy()


@pytest.fixture(scope="module")
def importer() -> Iterator[Importer]:
    imp = Importer()
    yield imp
    imp.close()


def _items(raw: list[Any]) -> list[MissionItem]:
    return [MissionItem.from_mavsdk(r) for r in raw]


def _export(tmp_path: Path, *extra: str, plan: Any = None) -> dict[str, str]:
    plan_path = write_plan(tmp_path / "p.json", plan)
    out = tmp_path / "qgc"
    assert cli.main(["export", str(plan_path), "--format", "qgc", "-o", str(out), *extra]) == 0
    return {p.stem.split("-")[-1]: p.read_text() for p in sorted(out.glob("*.plan"))}


@pytest.mark.parametrize(
    ("extra", "end", "velocity_yaw"),
    [
        ((), MissionEnd.LAND, False),
        (("--end", "return", "--acceptance-radius", "0.15"), MissionEnd.RETURN, True),
        (("--end", "hold"), MissionEnd.HOLD, False),
    ],
)
@pytest.mark.slow
def test_mavsdk_importer_gives_back_exactly_the_uploaded_items(
    importer: Importer,
    tmp_path: Path,
    extra: tuple[str, ...],
    end: MissionEnd,
    velocity_yaw: bool,
) -> None:
    plan = reach_avoid_plan(velocity_yaw=velocity_yaw)
    files = _export(tmp_path, *extra, plan=plan)
    loaded = load_plan(tmp_path / "p.json")
    radius = 0.15 if "--acceptance-radius" in extra else None
    assert sorted(files) == ["d1", "d2"]
    # what gcs upload sends to vehicles with PX4's defaults: the same conversion
    sent_missions = convert_plan(loaded, end=end, acceptance_m=radius).missions
    for v in loaded.vehicles:
        sent = sent_missions[v.name].items
        data = importer.load(files[v.name])
        back = _items(data.mission_items)
        # Every field but `current` (the importer marks the first item current, as QGC does).
        assert compare_items(sent, back) == []
        assert [b.seq for b in back] == list(range(len(sent)))
        assert back[0].current == 1
        commands = [it.command for it in back]
        if end is MissionEnd.LAND:
            assert commands[-1] == Cmd.NAV_LAND and np.isnan(back[-1].param4)
        elif end is MissionEnd.RETURN:
            assert commands[-1] == Cmd.NAV_RETURN_TO_LAUNCH
        else:
            assert commands[-1] == Cmd.NAV_WAYPOINT
        if velocity_yaw:  # the yaw (param4) changes along the path and survives the trip
            yaws = {round(it.param4, 3) for it in back if it.command == Cmd.NAV_WAYPOINT}
            assert len(yaws) > 1

        fence_sent = fence_plan(loaded).items
        fence_back = _items(data.geofence_items)
        # QGC's fence polygons carry only lat/lon and inclusion: the importer sets the frame to
        # MAV_FRAME_GLOBAL and autocontinue to 0 where the link sends GLOBAL_INT and 1 (same
        # lat/lon; autocontinue means nothing for a fence vertex). Every other field matches.
        assert {(f.frame, f.autocontinue) for f in fence_back} == {(MAV_FRAME_GLOBAL, 0)}
        assert compare_items([_as_imported(f) for f in fence_sent], fence_back) == []
        # Workspace (inclusion), the full-height no-fly box and pole (exclusions; the low obstacle
        # can be flown over, so it is no fence): 3 polygons of 4 vertices.
        assert len(fence_back) == 12
        assert list(data.rally_items) == []


def _as_imported(item: MissionItem) -> MissionItem:
    """A fence item with the two fields QGC's polygon format cannot carry set as imported."""
    return replace(item, frame=MAV_FRAME_GLOBAL, autocontinue=0)


def test_no_fence_option_leaves_an_empty_fence_that_still_imports(
    importer: Importer, tmp_path: Path
) -> None:
    files = _export(tmp_path, "--no-fence")
    for text in files.values():
        plan = json.loads(text)
        assert plan["geoFence"] == {"version": 2, "circles": [], "polygons": []}
        data = importer.load(text)
        assert list(data.geofence_items) == []
        assert len(data.mission_items) > 0


def test_importer_rejects_what_qgc_rejects(importer: Importer, tmp_path: Path) -> None:
    """Sanity of the reference: the importer is strict about the versions we write."""
    from mavsdk.plugins.mission_raw import MissionRawError

    text = next(iter(_export(tmp_path).values()))
    for path, bad in ((("mission", "version"), 1), (("geoFence", "version"), 1)):
        plan = json.loads(text)
        plan[path[0]][path[1]] = bad
        with pytest.raises(MissionRawError):
            importer.load(json.dumps(plan))
    plan = json.loads(text)
    del plan["rallyPoints"]
    with pytest.raises(MissionRawError):
        importer.load(json.dumps(plan))


def test_a_turned_box_and_a_cylinder_export_as_qgc_polygon_and_circle_that_import_back(
    importer: Importer,
) -> None:
    """Full-height keep-outs of other shapes: a no-fly box turned 30 degrees is the polygon of
    its corners, a pole (vertical cylinder) a QGC circle; MAVSDK's importer gives back the
    very items ``gcs upload --fence`` sends."""
    from planner.spec.regions import Cylinder, Prism, Region, RegionKind

    base = reach_avoid_plan()
    turned = Prism.oriented_box((-1.2, 1.2, 1.0), (0.5, 0.2, 1.0), math.radians(30.0))
    regions = (
        *base.regions,
        Region.of_shape("mast", RegionKind.POLE, Cylinder((1.0, -0.5), 0.25, 0.0, 2.5)),
        Region.of_shape("turned", RegionKind.NO_FLY, turned),
    )
    plan = replace(base, regions=regions)
    doc = _no_nan(json.dumps(qgc_plan(plan, plan.vehicles[0], QgcOptions())))
    fence = doc["geoFence"]
    # workspace, the full-height box no-fly zone and pole1, then the turned box: 4 polygons
    assert [p["inclusion"] for p in fence["polygons"]] == [True, False, False, False]
    (circle,) = fence["circles"]
    assert set(circle) == {"circle", "inclusion", "version"} and set(circle["circle"]) == {
        "center",
        "radius",
    }
    assert circle["inclusion"] is False and circle["version"] == 1
    assert circle["circle"]["radius"] == 0.25
    lat, lon, _ = pymap3d.enu2geodetic(1.0, -0.5, 0.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    assert circle["circle"]["center"] == pytest.approx([lat, lon], abs=1.5e-7)
    # the turned box's corners, computed here from its centre, half sizes and bearing
    c, s = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    corners = [
        (-1.2 + a * 0.5 * c - b * 0.2 * s, 1.2 + a * 0.5 * s + b * 0.2 * c)
        for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))
    ]
    polygon = fence["polygons"][3]["polygon"]
    assert len(polygon) == 4
    for (x, y), vertex in zip(corners, polygon, strict=True):
        rlat, rlon, _ = pymap3d.enu2geodetic(x, y, 0.0, ORIGIN.lat_deg, ORIGIN.lon_deg, 488.0)
        assert vertex == pytest.approx([rlat, rlon], abs=1.5e-7)
    # MAVSDK's importer: polygons, then the circle, the items the link uploads
    sent = fence_plan(plan).items
    assert [it.command for it in sent][-1] == Cmd.NAV_FENCE_CIRCLE_EXCLUSION
    back = _items(importer.load(json.dumps(doc)).geofence_items)
    assert compare_items([_as_imported(f) for f in sent], back) == []
    assert len(back) == 17


# ------------------------------------------------------------------------- golden structure

TOP_KEYS = {"fileType", "version", "groundStation", "mission", "geoFence", "rallyPoints"}
MISSION_KEYS = {
    "version",
    "firmwareType",
    "vehicleType",
    "globalPlanAltitudeMode",
    "cruiseSpeed",
    "hoverSpeed",
    "plannedHomePosition",
    "items",
}
ITEM_KEYS = {"type", "autoContinue", "command", "doJumpId", "frame", "params"}
ALT_KEYS = {"AMSLAltAboveTerrain", "Altitude", "AltitudeMode"}


def _no_nan(text: str) -> Any:
    def bad(token: str) -> None:
        raise AssertionError(f"non-JSON number {token} in the export")

    return json.loads(text, parse_constant=bad)


def test_qgc_plan_has_the_field_names_and_versions_of_qgc_plan_format(tmp_path: Path) -> None:
    files = _export(tmp_path)
    for text in files.values():
        plan = _no_nan(text)
        assert set(plan) == TOP_KEYS
        assert plan["fileType"] == "Plan"
        assert plan["version"] == 1
        assert plan["groundStation"] == "stl-gcs"
        m = plan["mission"]
        assert set(m) == MISSION_KEYS
        assert (m["version"], m["firmwareType"], m["vehicleType"]) == (2, 12, 2)
        assert m["globalPlanAltitudeMode"] == 2  # absolute (AMSL), as every item
        assert m["hoverSpeed"] > 0 and m["cruiseSpeed"] > 0
        assert len(m["plannedHomePosition"]) == 3
        assert set(plan["geoFence"]) == {"version", "circles", "polygons"}
        assert plan["geoFence"]["version"] == 2 and plan["geoFence"]["circles"] == []
        for poly in plan["geoFence"]["polygons"]:
            assert set(poly) == {"inclusion", "polygon", "version"}
            assert poly["version"] == 1 and isinstance(poly["inclusion"], bool)
            assert all(len(v) == 2 for v in poly["polygon"])
        assert [p["inclusion"] for p in plan["geoFence"]["polygons"]] == [True, False, False]
        assert plan["rallyPoints"] == {"version": 2, "points": []}
        for k, item in enumerate(m["items"]):
            assert item["type"] == "SimpleItem"
            assert item["doJumpId"] == k + 1
            assert isinstance(item["autoContinue"], bool)
            assert len(item["params"]) == 7
            if item["frame"] == 5:  # positional, AMSL
                assert set(item) == ITEM_KEYS | ALT_KEYS
                assert item["AltitudeMode"] == 2
                assert item["AMSLAltAboveTerrain"] is None
                assert item["Altitude"] == item["params"][6]
            else:  # speed change / return: no position, no altitude keys (as QGC writes)
                assert item["frame"] == 2
                assert set(item) == ITEM_KEYS
        land = m["items"][-1]
        assert land["command"] == 21 and land["params"][3] is None  # NaN yaw -> null


def test_home_and_fence_vertices_are_the_geodetic_points_of_the_plan() -> None:
    plan = reach_avoid_plan()
    doc = qgc_plan(plan, plan.vehicles[0], QgcOptions())
    x0, y0, _ = plan.vehicles[0].start_enu_m
    lat, lon, alt = pymap3d.enu2geodetic(x0, y0, 0.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
    assert doc["mission"]["plannedHomePosition"] == pytest.approx([lat, lon, alt], abs=1e-9)
    ws = plan.workspace
    d = fence_plan(plan).inflate_m  # the workspace moved out by PX4's braking distance
    assert d > 0.5
    lo, hi = (ws.lo_enu_m[0] - d, ws.lo_enu_m[1] - d), (ws.hi_enu_m[0] + d, ws.hi_enu_m[1] + d)
    corners = [(lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1])]
    polygon = doc["geoFence"]["polygons"][0]["polygon"]
    for (x, y), (plat, plon) in zip(corners, polygon, strict=True):
        rlat, rlon, _ = pymap3d.enu2geodetic(x, y, 0.0, ORIGIN.lat_deg, ORIGIN.lon_deg, 488.0)
        assert (plat, plon) == pytest.approx((rlat, rlon), abs=1.5e-7)  # degE7 resolution
    # The takeoff goes to the start point, AMSL.
    takeoff = doc["mission"]["items"][0]
    _, _, start_alt = pymap3d.enu2geodetic(
        x0, y0, plan.vehicles[0].start_enu_m[2], ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m
    )
    assert takeoff["command"] == 22
    assert takeoff["Altitude"] == pytest.approx(start_alt, abs=1e-6)


# ------------------------------------------------------------------ end to end on a real plan

E2E_SCENARIO = """\
name: export_e2e
origin: {lat: 47.397742, lon: 8.545594, alt: 488.0}
workspace: {min: [-4, -4, 0], max: [4, 4, 3]}
regions:
  obstacle: {kind: obstacle, min: [-0.6, -0.6, 0], max: [0.6, 0.6, 3]}
  goal: {kind: goal, center: [2.0, 2.0, 1.5], half_size: 0.7}
  keepout: {kind: no_fly, min: [-4, 3, 0], max: [-3, 4, 3]}
limits: {v_max_m_s: 1.5, a_max_m_s2: 2.0}
vehicles:
  - {name: d1, start: [-2.0, -2.0, 1.5]}
  - {name: d2, start: [-1.0, -2.5, 1.5]}
timing: {horizon_s: 6, segment_s: 1, Ts_s: 0.1, check_dt_s: 0.02}
separation_m: 0.5
epsilon: 0.05
model: minimum_jerk
spec:
  - each: d in all
    formula: eventually[0, $horizon] inside(d, goal)
  - each: d in all
    formula: always[0, $horizon] (outside(d, obstacle) and inside(d, workspace))
  - each: (a, b) in pairs(all)
    formula: always[0, $horizon] dist(a, b) >= $separation
"""


@pytest.mark.slow
def test_planned_scenario_plots_verifies_and_exports_round_trip(
    importer: Importer, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """gcs plan -> gcs verify --json -> gcs plot (HTML) -> gcs export qgc -> MAVSDK import."""
    from gcs.plot.traces import clause_traces

    scenario = tmp_path / "e2e.yaml"
    scenario.write_text(E2E_SCENARIO)
    plan_path = tmp_path / "e2e.json"
    assert cli.main(["plan", str(scenario), "-o", str(plan_path), "--json"]) in (0, 1)
    capsys.readouterr()
    verify_status = cli.main(["verify", str(plan_path), "--json"])
    checks = json.loads(capsys.readouterr().out)["checks"]
    assert verify_status in (0, 1)
    plan = load_plan(plan_path)

    # The plot's clause values are verify's spec checks (same dense grid, same semantics).
    spec_checks = {c["name"].removeprefix("spec: "): c["value"] for c in checks}
    traces = clause_traces(plan)
    assert len(traces) == 5
    for tr in traces:
        assert tr.robustness == pytest.approx(spec_checks[tr.text], abs=1e-12)
    assert cli.main(["plot", str(plan_path), "-o", str(tmp_path / "e2e.html")]) == 0
    assert "data:image/png;base64," in (tmp_path / "e2e.html").read_text()

    assert cli.main(["export", str(plan_path), "--format", "qgc"]) == 0
    sent_missions = convert_plan(plan, end=MissionEnd.LAND).missions
    for v in plan.vehicles:
        text = (tmp_path / f"e2e-{v.name}.plan").read_text()
        data = importer.load(text)
        sent = sent_missions[v.name].items
        assert compare_items(sent, _items(data.mission_items)) == []
        fence = [_as_imported(f) for f in fence_plan(plan).items]
        assert compare_items(fence, _items(data.geofence_items)) == []
        polygons = json.loads(text)["geoFence"]["polygons"]
        assert [p["inclusion"] for p in polygons] == [True, False, False]


def test_homes_are_the_ground_below_each_start_as_px4_home_variables(tmp_path: Path) -> None:
    plan = reach_avoid_plan(velocity_yaw=False)
    path = tmp_path / "p.json"
    write_plan(path, plan)
    assert cli.main(["export", str(path), "--format", "homes"]) == 0
    lines = (tmp_path / "p.homes").read_text().splitlines()[1:]
    assert [ln.split()[0] for ln in lines] == [v.name for v in plan.vehicles]
    for line, v in zip(lines, plan.vehicles, strict=True):
        env = dict(kv.split("=") for kv in line.split()[1:])
        e, n, u = pymap3d.geodetic2enu(
            float(env["PX4_HOME_LAT"]), float(env["PX4_HOME_LON"]), float(env["PX4_HOME_ALT"]),
            plan.origin.lat_deg, plan.origin.lon_deg, plan.origin.alt_m,
        )  # fmt: skip
        assert (e, n, u) == pytest.approx((v.start_enu_m[0], v.start_enu_m[1], 0.0), abs=0.01)


@pytest.mark.slow
def test_missions_and_setpoints_of_a_failing_plan_are_refused_unless_forced(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import json as _json

    from gcs.cli import main

    # the stored plan, with a speed limit it breaks: it fails gcs verify
    data = _json.loads(LINK_PLAN.read_text(encoding="utf-8"))
    data["vehicles"][0]["limits"]["v_max_m_s"] = [0.2, 0.2, 0.2]
    bad = tmp_path / "bad.json"
    bad.write_text(_json.dumps(data), encoding="utf-8")
    for fmt in ("qgc", "csv", "json"):
        out_dir = tmp_path / fmt
        rc = main(["export", str(bad), "--format", fmt, "-o", str(out_dir / "x")])
        out, err = capsys.readouterr()
        assert rc == 1 and out == "" and not out_dir.exists(), (fmt, out, err)
        assert err.count("\n") == 1 and "refused: the plan fails verification: d1 velocity" in err
        assert "--force exports anyway" in err
    rc = main(["export", str(bad), "--format", "qgc", "-o", str(tmp_path / "forced"), "--force"])
    out, err = capsys.readouterr()
    assert rc == 0 and "wrote" in out and "warning: exported with --force" in err
    assert list((tmp_path / "forced").glob("*.plan"))
    # where the vehicles stand is not a flight: written whatever the plan's checks say
    assert main(["export", str(bad), "--format", "homes", "-o", str(tmp_path / "h.txt")]) == 0


@pytest.mark.slow
def test_camera_and_gimbal_items_export_to_qgc_and_import_back_as_sent(
    importer: Importer, tmp_path: Path
) -> None:
    """A plan that faces an inspection target carries the camera's items (gimbal pitch, start
    and stop capture) in its QGC plan; MAVSDK's importer gives them back as gcs upload sends
    them, and --photo-interval 0 leaves them out."""
    from gcs.flight.payload import capture_spans
    from tests.gcs.face_plan import write_face_plan

    plan_path = write_face_plan(tmp_path)
    plan = load_plan(plan_path)
    for interval in (0.5, 0.0):
        out = tmp_path / f"qgc{interval}"
        argv = ["export", str(plan_path), "--format", "qgc", "-o", str(out)]
        assert cli.main([*argv, "--photo-interval", str(interval)]) == 0
        (text,) = [p.read_text() for p in out.glob("*.plan")]
        sent = convert_plan(
            plan, end=MissionEnd.LAND, captures=capture_spans(plan, interval)
        ).missions["d1"]
        back = _items(importer.load(text).mission_items)
        assert compare_items(sent.items, back) == []
        commands = [int(it.command) for it in back]
        camera = [Cmd.DO_GIMBAL_MANAGER_PITCHYAW, Cmd.IMAGE_START_CAPTURE]
        if interval == 0:
            assert not set(camera) & set(commands) and Cmd.IMAGE_STOP_CAPTURE not in commands
            continue
        i = commands.index(Cmd.IMAGE_START_CAPTURE)
        assert commands[i - 1] == Cmd.DO_GIMBAL_MANAGER_PITCHYAW
        assert back[i].param2 == interval and back[i].param3 == sent.captures[0].images
        (cap,) = sent.captures
        assert cap.images >= 2.0 / interval  # the 2 s hover at least
        assert Cmd.IMAGE_STOP_CAPTURE in commands[i:]
