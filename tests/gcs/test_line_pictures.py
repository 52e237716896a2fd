"""The 10-pole line along a bearing of 37 degrees, three drones facing each pole while they hover
beside it (configs/powerline_line10_camera.yaml): planned, converted to PX4 missions with the
camera's items, and flown as missions on mock PX4 vehicles with a MAVLink camera and gimbal,
offline (simulated time, :meth:`MockFleet.advance`), every vehicle's CAMERA_IMAGE_CAPTURED
collected as it is sent.  Every pole is pictured from within its inspection place, the view
within face's tolerance, and the pictures are those the missions planned (issue 21).

The full-stack flight over UDP (``gcs fly --dry-run``, offboard and mission) of the same line
is ``benchmarks/bench_camera.py``; tests/gcs/test_fly.py flies a short facing plan both ways.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from gcs.flight.missions import convert_plan
from gcs.flight.payload import capture_spans
from gcs.plot.coverage import compute_coverage, coverage_lines
from mavlink.link.camera import image_from_fields
from mavlink.mission import Cmd, MissionEnd
from mavlink.mock import MockFleet, Px4Mode
from planner.planfile import load_plan, plan_to_json

pytestmark = pytest.mark.slow

SCENARIO = Path(__file__).resolve().parents[2] / "configs" / "powerline_line10_camera.yaml"


def test_the_10_pole_line_at_37_degrees_flown_as_missions_pictures_every_pole(
    tmp_path: Path,
) -> None:
    from planner.optimize import plan as make_plan
    from planner.scenario import load_scenario

    result = make_plan(load_scenario(SCENARIO))
    assert result.success, result.status
    path = tmp_path / "line10.plan.json"
    path.write_text(json.dumps(plan_to_json(result.to_plan(str(SCENARIO)))))
    plan = load_plan(path)
    spans = capture_spans(plan)
    assert sorted(s.target for ss in spans.values() for s in ss) == sorted(
        f"pole{i}" for i in range(1, 11)
    )
    conv = convert_plan(plan, end=MissionEnd.HOLD, captures=spans)
    planned: dict[str, int] = {}
    for m in conv.missions.values():
        for c in m.captures:
            planned[c.span.target] = planned.get(c.span.target, 0) + c.images
        commands = [int(it.command) for it in m.items]
        assert commands.count(Cmd.DO_GIMBAL_MANAGER_CONFIGURE) == 1
        assert commands.count(Cmd.IMAGE_START_CAPTURE) == len(m.captures)

    f = MockFleet(
        n=3, origin=plan.origin, spawns_enu_m=plan.ground_spawns(), seed=1, ready_after_s=0.0
    )
    f.offline_links()
    vs = list(f.vehicles)
    for v, pv in zip(vs, plan.vehicles, strict=True):
        v.store_plan(conv.missions[pv.name].items)
    f.advance(0.5)  # past PX4's mission-start window after an upload
    for v in vs:
        assert v.arm() == mavlink2.MAV_RESULT_ACCEPTED
        assert v.request_mode(Px4Mode.AUTO_MISSION) == mavlink2.MAV_RESULT_ACCEPTED
    # the plan's clock starts when each vehicle leaves its start waypoint (item 1), as the
    # ground station releases the missions there; pictures are timed from then
    release: dict[int, float] = {}
    shots: dict[str, list] = {pv.name: [] for pv in plan.vehicles}  # type: ignore[type-arg]
    senders: set[int] = set()
    while f.time_s < 300.0 and not all(v.mission_finished for v in vs):
        f.advance(0.05)
        for v, pv in zip(vs, plan.vehicles, strict=True):
            if v.index not in release and v.mission_seq > 1:
                release[v.index] = f.time_s
            for m in v.sent_messages():
                if m.get_type() == "CAMERA_IMAGE_CAPTURED":
                    senders.add(m.get_srcComponent())
                    t = f.time_s - release.get(v.index, f.time_s)
                    shots[pv.name].append(image_from_fields(m.to_dict(), pv.name, t, 100))
    assert all(v.mission_finished for v in vs), [
        (v.mission_seq, len(conv.missions[pv.name].items), v.mode, v.state.pos_ned_m)
        for v, pv in zip(vs, plan.vehicles, strict=True)
    ]
    assert senders == {100}  # the camera component, not the autopilot

    report = compute_coverage(plan, shots, planned=planned)
    text = "\n".join(coverage_lines(report))
    assert report.all_covered, text
    # nearly every picture counts: PX4's legs keep the plan's clock only roughly, so the
    # first or last of a hover may be taken just outside the inspection place
    assert report.covered == 10 and report.unmatched <= 0.1 * report.images, text
    for t in report.targets:
        assert t.planned is not None and max(1, t.planned - 2) <= t.images <= t.planned, text
        assert t.view_deg is not None and t.view_deg <= 15.0
        lo, hi = t.range_m or (0.0, 0.0)
        # from the stand-off: 1.5 m beyond the outer phase (1.8 m), within the 2.2 m deep box
        # (0.5 m allowed), up to 1 m above the pole's top (the box reaches 12.5 m, the pole 12)
        far = float(np.hypot(1.8 + 1.5 + 2.2 + 0.5, 12.5 + 0.5 - 12.0))
        assert 1.8 + 1.5 - 0.5 <= lo <= hi <= far, (t.target, lo, hi)
    # each vehicle pictured its own poles, in the planned order
    firsts = {t.target: min(v.image.t_s for v in t.views) for t in report.targets if t.views}
    for name, want in (("d1", [1, 2, 3]), ("d2", [4, 5, 6, 7]), ("d3", [8, 9, 10])):
        got = [x for x in sorted(firsts, key=firsts.get) if int(x[4:]) in want]  # type: ignore[arg-type]
        assert got == [f"pole{i}" for i in want], name
        assert {im.vehicle for im in shots[name]} == {name}
    assert np.all(np.diff([im.index for im in shots["d2"]]) == 1)
