"""``gcs plot``'s map view: when ``auto`` picks it, what it draws against the plan's own
geometry and times, the HTML page's pan-and-zoom map, and the script that pans and zooms it.

The long line is built, not planned: a 2 km line along a bearing of 20 degrees from the
regions a scenario's ``line:`` section makes (:func:`planner.scenario.line.line_regions`), and two
vehicles on rest-to-rest quintic segments that hold still at inspection places, so where
and when each hovers is known in closed form (the reference speed below is the quintic's
derivative written out, not the trajectory's polynomial).
"""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from gcs import cli
from gcs.plot import PAN_ZOOM_JS
from gcs.plot.figure import render_figure
from gcs.plot.map_view import (
    HOVER_MIN_S,
    HOVER_SPEED_M_S,
    MAP_FROM_M,
    View,
    choose_view,
    find_hovers,
    line_poles,
    tick_step_s,
)
from gcs.plot.traces import clause_traces, plan_grid
from planner.planfile import Plan, PlannedVehicle
from planner.scenario import load_scenario
from planner.scenario.line import LineModel, line_regions
from planner.spec.regions import Region, RegionKind
from tests.gcs.test_export_support import ORIGIN, quintic_trajectory, reach_avoid_plan, write_plan

ROOT = Path(__file__).resolve().parents[2]
BEARING = math.radians(20.0)
SPAN_M = 50.0
POLES = 41  # 40 spans of 50 m: 2 km


def _pole_xy() -> np.ndarray:
    u = np.array([math.cos(BEARING), math.sin(BEARING)])
    return np.arange(POLES)[:, None] * SPAN_M * u


def _at(regions: dict[str, Region], name: str, z: float = 11.0) -> list[float]:
    c = regions[name].center_enu_m
    return [float(c[0]), float(c[1]), z]


def _waypoints() -> dict[str, tuple[list[list[float]], list[float]]]:
    """Each vehicle's waypoints and segment durations (s): a repeated waypoint is a hold."""
    regions, _ = line_regions(LineModel(poles_xy=_pole_xy()))
    by = {r.name: r for r in regions}
    insp5, insp12, insp30 = _at(by, "insp5"), _at(by, "insp12"), _at(by, "insp30")
    return {
        # out to insp5 (45 s), still for 4 s, on to insp12 (60 s), still for 11 s: 120 s
        "d1": ([[0.0, -20.0, 8.0], insp5, insp5, insp12, insp12], [45.0, 4.0, 60.0, 11.0]),
        # out to insp30 (100 s), still for 20 s: 120 s
        "d2": ([[10.0, -20.0, 8.0], insp30, insp30], [100.0, 20.0]),
    }


def long_line_plan() -> Plan:
    """The 2 km line and its two vehicles (module docstring), a 120 s horizon."""
    regions, _ = line_regions(LineModel(poles_xy=_pole_xy()))
    vehicles = []
    for i, (name, (wps, durs)) in enumerate(_waypoints().items()):
        vehicles.append(
            PlannedVehicle(
                name=name,
                sysid=i + 1,
                trajectory=quintic_trajectory(wps, durs, name),
                start_enu_m=(wps[0][0], wps[0][1], wps[0][2]),
                v_max_m_s=(30.0, 30.0, 3.0),  # d2's 1.4 km leg peaks at 26 m/s
                a_max_m_s2=(3.0, 3.0, 2.0),
            )
        )
    xy = _pole_xy()
    lo, hi = xy.min(axis=0) - 40.0, xy.max(axis=0) + 40.0
    spec = (
        "(eventually[0, 110] always[0, 2] inside(d1, insp5)) and\n"
        "(eventually[0, 110] always[0, 2] inside(d2, insp30)) and\n"
        "(always[0, 120] outside(d1, pole5))"
    )
    return Plan(
        scenario="generated/line_2km.yaml",
        origin=ORIGIN,
        spec=spec,
        robustness=1.1,
        smooth_robustness=1.0,
        status="the mission is met: robustness 1.1 >= epsilon 0.01 (solver: Solve_Succeeded)",
        success=True,
        solve_time_s=1.0,
        vehicles=tuple(vehicles),
        workspace=Region(
            "workspace", RegionKind.WORKSPACE, (lo[0], lo[1], 0.5), (hi[0], hi[1], 20.0)
        ),
        regions=tuple(regions),
        separation_m=1.5,
        epsilon=0.01,
        horizon_s=120.0,
        sample_dt_s=0.5,
        check_dt_s=0.2,
    )


def _map_axes(fig: Figure) -> Axes:
    return next(ax for ax in fig.axes if ax.get_title().startswith("Map"))


def _by_gid(ax: Axes, prefix: str) -> dict[str, Any]:
    """The artists on ``ax`` whose id (``gid``, the element id in SVG) starts with ``prefix``."""
    return {a.get_gid(): a for a in ax.get_children() if (a.get_gid() or "").startswith(prefix)}


def test_auto_draws_a_map_for_a_long_line_and_3d_for_the_shipped_short_line() -> None:
    assert choose_view(long_line_plan()) is View.MAP  # 2 km
    base = reach_avoid_plan()
    for scenario, want in (
        (ROOT / "configs/powerline_inspection.yaml", View.THREE_D),  # 95 x 30 m: 100 m across
        (ROOT / "configs/reach_avoid.yaml", View.THREE_D),
        (ROOT / "benchmarks/scenarios/powerline_line20_4drones_300s.yaml", View.MAP),  # 590 m
        (ROOT / "configs/powerline_line10_camera.yaml", View.MAP),  # 355 m across
    ):
        problem = load_scenario(scenario)
        assert choose_view(replace(base, workspace=problem.workspace)) is want, scenario
    # the rule's edge: the workspace footprint's diagonal against MAP_FROM_M
    side = MAP_FROM_M / math.sqrt(2.0)
    for scale, want in ((0.99, View.THREE_D), (1.01, View.MAP)):
        ws = Region("workspace", RegionKind.WORKSPACE, (0, 0, 0), (scale * side, scale * side, 5))
        assert choose_view(replace(base, workspace=ws)) is want
    # asked for, a view is drawn whatever the size
    assert choose_view(long_line_plan(), "3d") is View.THREE_D
    assert choose_view(base, View.MAP) is View.MAP


@pytest.mark.slow
def test_map_is_north_up_in_metres_at_one_scale_with_the_line_regions_and_flown_paths() -> None:
    from matplotlib.colors import to_rgba

    from gcs.telemetry import Telemetry
    from mavlink.tracks import FlownTrack

    plan = long_line_plan()
    t_tel = np.arange(0.0, 120.01, 0.5)
    flown = plan.vehicles[0].trajectory.position(t_tel) + np.array([0.0, 3.0, 0.0])
    telemetry = Telemetry("flown.csv", {"d1": FlownTrack("d1", t_tel, flown)})
    fig = render_figure(plan, clause_traces(plan, telemetry), telemetry)
    fig.canvas.draw()
    assert not any(ax.name == "3d" for ax in fig.axes)
    ax = _map_axes(fig)
    assert ax.get_aspect() == 1.0
    assert ax.get_xlabel() == "east x (m)" and ax.get_ylabel() == "north y (m)"
    # north up and one scale: 100 m north is as many pixels straight up as 100 m east is
    # straight right (to matplotlib's rounding of the box)
    o, east, north = ax.transData.transform([[500.0, 200.0], [600.0, 200.0], [500.0, 300.0]])
    assert east[0] - o[0] > 0 and east[1] == pytest.approx(o[1])
    assert north[1] - o[1] == pytest.approx(east[0] - o[0], rel=1e-3)
    assert north[0] == pytest.approx(o[0])
    # the whole workspace is on the map
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    ws = plan.workspace
    assert x0 <= ws.lo_enu_m[0] and x1 >= ws.hi_enu_m[0]
    assert y0 <= ws.lo_enu_m[1] and y1 >= ws.hi_enu_m[1]

    # every region as its footprint (the turned spans and inspection boxes' corners, the
    # poles' circles); keep-outs hatched, inspection places not
    patches = _by_gid(ax, "region-")
    assert len(patches) == len(plan.regions)
    for r in plan.regions:
        p = patches[f"region-{r.name}"]
        corners = p.get_xy()[:-1]  # closed: the first corner repeated
        np.testing.assert_allclose(corners, r.footprint_xy(), atol=1e-9)
        assert (p.get_hatch() is not None) == r.name.startswith("span"), r.name
    # the poles marked at their centres, the line drawn pole to pole, in line order
    poles = _pole_xy()
    np.testing.assert_allclose(line_poles(plan), poles, atol=1e-9)
    (marks,) = _by_gid(ax, "poles").values()
    np.testing.assert_allclose(np.column_stack(marks.get_data()), poles, atol=1e-9)
    (line,) = _by_gid(ax, "line").values()
    np.testing.assert_allclose(np.column_stack(line.get_data()), poles, atol=1e-9)
    # the poles named, the two ends and evenly between where there is room
    names = {t.get_text() for t in ax.texts if t.get_text().startswith("pole")}
    assert "pole41" in names and "pole21" in names and len(names) >= 10
    # each vehicle's path in its colour; the flown one broad and faint beside it
    paths = _by_gid(ax, "path-")
    t, _ = plan_grid(plan)
    for v in plan.vehicles:
        xy = np.column_stack(paths[f"path-{v.name}"].get_data())
        np.testing.assert_allclose(xy, v.trajectory.position(t)[:, :2], atol=1e-9)
    faint = [ln for ln in ax.get_lines() if ln.get_alpha() == pytest.approx(0.35)]
    assert len(faint) == 1
    np.testing.assert_allclose(np.column_stack(faint[0].get_data()), flown[:, :2])
    assert to_rgba(faint[0].get_color()) == to_rgba(paths["path-d1"].get_color())
    labels = {t.get_text() for t in ax.get_legend().get_texts()}
    assert {"d1", "d2", "pole / tower", "flown (telemetry)", "every 10 s"} <= labels


def _reference_hovers(wps: list[list[float]], durs: list[float], dt: float) -> list[tuple[float, float]]:  # fmt: skip
    """Runs of at least HOVER_MIN_S with speed <= HOVER_SPEED_M_S, from the quintic's speed
    in closed form: |p1 - p0| / T * 30 s^2 (1 - s)^2, on the grid of step ``dt``."""
    w = np.asarray(wps)
    t = np.arange(round(sum(durs) / dt) + 1) * dt
    ends = np.cumsum(durs)
    speed = np.zeros(t.size)
    for k, big_t in enumerate(durs):
        start = ends[k] - big_t
        inside = (t >= start) & (t <= ends[k])
        s = (t[inside] - start) / big_t
        dist = float(np.linalg.norm(w[k + 1] - w[k]))
        speed[inside] = dist / big_t * 30.0 * s**2 * (1.0 - s) ** 2
    runs, begin = [], None
    for i, slow in enumerate(np.append(speed <= HOVER_SPEED_M_S, False)):
        if slow and begin is None:
            begin = i
        elif not slow and begin is not None:
            if t[i - 1] - t[begin] >= HOVER_MIN_S - 1e-9:
                runs.append((float(t[begin]), float(t[i - 1])))
            begin = None
    return runs


@pytest.mark.slow
def test_time_ticks_and_hovers_are_where_and_when_the_plan_puts_them() -> None:
    plan = long_line_plan()
    t, dt = plan_grid(plan)
    hovers = find_hovers(plan, t)
    for name, (wps, durs) in _waypoints().items():
        mine = [(h.t0_s, h.t1_s) for h in hovers if h.vehicle == name]
        ref = _reference_hovers(wps, durs, dt)
        assert len(mine) == len(ref), (name, mine, ref)
        for (a, b), (ra, rb) in zip(mine, ref, strict=True):
            assert a == pytest.approx(ra, abs=dt + 1e-9) and b == pytest.approx(rb, abs=dt + 1e-9)
    # each hold (a repeated waypoint) lies inside a hover, marked at the hold's place
    d1_holds = [(45.0, 49.0, 1), (109.0, 120.0, 3)]
    for t0, t1, k in d1_holds:
        h = next(h for h in hovers if h.vehicle == "d1" and h.t0_s <= t0 and h.t1_s >= t1)
        np.testing.assert_allclose(h.pos_enu_m[:2], _waypoints()["d1"][0][k][:2], atol=0.05)
    # no hover while flying
    assert not [h for h in hovers if h.vehicle == "d1" and 55.0 < h.t0_s < 100.0]

    fig = render_figure(plan, clause_traces(plan), view="map")
    ax = _map_axes(fig)
    marks = _by_gid(ax, "hover-")
    assert len(marks) == len(hovers)
    for h in hovers:
        mark = marks[f"hover-{h.vehicle}-{h.t0_s:g}-{h.t1_s:g}"]
        np.testing.assert_allclose(np.column_stack(mark.get_data())[0], h.pos_enu_m[:2])
    # labelled with when (the two holds of d1 have room for theirs)
    texts = {tx.get_text() for tx in ax.texts}
    spans = [tuple(map(int, m.groups())) for s in texts if (m := re.fullmatch(r"(\d+)-(\d+) s", s))]  # fmt: skip
    for t0, t1, _ in d1_holds:
        h = next(h for h in hovers if h.vehicle == "d1" and h.t0_s <= t0 and h.t1_s >= t1)
        assert any(abs(a - h.t0_s) <= 0.5 and abs(b - h.t1_s) <= 0.5 for a, b in spans), spans
    # ticks: every 10 s (at most 12 on the 120 s horizon; 5 s would make 24), at the
    # vehicle's position then
    step = tick_step_s(plan.horizon_s)
    assert step == 10.0
    ticks = _by_gid(ax, "ticks-")
    for v in plan.vehicles:
        want = v.trajectory.position(np.arange(10.0, 120.0, 10.0))[:, :2]
        np.testing.assert_allclose(np.column_stack(ticks[f"ticks-{v.name}"].get_data()), want)
    assert {"10 s", "50 s"} <= texts


def test_tick_steps_are_readable_for_any_horizon() -> None:
    for horizon, step in ((6.0, 0.5), (30.0, 5.0), (90.0, 10.0), (300.0, 30.0), (3600.0, 300.0)):
        assert tick_step_s(horizon) == step
        assert horizon / step <= 12


@pytest.mark.slow
def test_html_of_a_long_line_carries_an_svg_map_to_pan_and_zoom_and_loads_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan_path = write_plan(tmp_path / "line.json", long_line_plan())
    out = tmp_path / "line.html"
    assert cli.main(["plot", str(plan_path), "-o", str(out)]) == 0
    assert "(map view;" in capsys.readouterr().out
    page = out.read_text()
    section = page[page.index('<div id="map">') :]
    assert section.count("<svg") == 1 and page.count("<svg") == 1
    svg = section[section.index("<svg") : section.index("</svg>")]
    assert re.search(r'viewBox="0 0 [\d.]+ [\d.]+"', svg)
    assert 'id="path-d1"' in svg and 'id="ticks-d2"' in svg and 'id="region-insp30"' in svg
    t, _ = plan_grid(long_line_plan())
    assert len(re.findall(r'id="hover-d[12]-', svg)) == len(find_hovers(long_line_plan(), t))
    assert re.search(r">pole\d+</text>", svg)  # text kept as text
    script = page[page.index("<script>") : page.index("</script>")]
    assert PAN_ZOOM_JS.strip() in script
    for event in ("wheel", "pointerdown", "pointermove", "dblclick"):
        assert f'"{event}"' in script
    # offline: no web address at all; everything referred to is in the page
    assert re.search(r"https?://", page, re.I) is None
    assert not re.search(r"<script[^>]*\bsrc=|<link\b|<iframe|@import|url\((?!#)", page)
    refs = re.findall(r'\b(?:src|href)="([^"]*)"', page)
    assert refs and all(r.startswith(("data:image/png;base64,", "#")) for r in refs)
    # the PNG beside it shows the map as well
    assert '<img alt="regions, paths' in page

    # a short line is drawn in 3-D, without a map; asked for, the map is there too
    short = write_plan(tmp_path / "short.json")
    assert cli.main(["plot", str(short), "-o", str(tmp_path / "s.html")]) == 0
    assert "(3d view;" in capsys.readouterr().out
    assert "<svg" not in (tmp_path / "s.html").read_text()
    assert cli.main(["plot", str(short), "-o", str(tmp_path / "m.html"), "--view", "map"]) == 0
    assert '<div id="map">' in (tmp_path / "m.html").read_text()
    # and the long one in 3-D when asked
    assert cli.main(["plot", str(plan_path), "--view", "3d", "-o", str(tmp_path / "l.png")]) == 0
    assert "(3d view;" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:  # argparse refuses another view
        cli.main(["plot", str(plan_path), "--view", "globe"])
    assert exc.value.code == 2


#: A fake of the little of the DOM the script touches: an svg element of 800 x 400 px at
#: the page's corner, whose screen CTM maps client pixels onto its current viewBox.
_FAKE_DOM = """
var handlers = {}, buttons = {}, attrs = {viewBox: "0 0 1200 600"};
function vb() { return attrs.viewBox.split(" ").map(Number); }
var svg = {
  style: {},
  getAttribute: function (k) { return attrs[k]; },
  setAttribute: function (k, v) { attrs[k] = v; },
  addEventListener: function (k, f) { handlers[k] = f; },
  setPointerCapture: function () {},
  createSVGPoint: function () {
    return {x: 0, y: 0, matrixTransform: function (m) { return m(this); }};
  },
  getScreenCTM: function () {
    return {inverse: function () {
      var v = vb();
      return function (p) { return {x: v[0] + p.x * v[2] / 800, y: v[1] + p.y * v[3] / 400}; };
    }};
  }
};
function button() { var b = {addEventListener: function (k, f) { b.click = f; }}; return b; }
buttons[".reset"] = button(); buttons[".zoom-in"] = button(); buttons[".zoom-out"] = button();
var box = {querySelector: function (q) { return q === "svg" ? svg : buttons[q]; }};
var document = {getElementById: function (id) { return id === "map" ? box : null; }};
var log = [];
function ev(x, y, extra) {
  var e = {clientX: x, clientY: y, pointerId: 1, deltaMode: 0, preventDefault: function () {}};
  for (var k in extra) { e[k] = extra[k]; }
  return e;
}
"""

_FAKE_RUN = """
log.push(vb());
handlers.wheel(ev(200, 100, {deltaY: -200}));     // zoom in about client (200, 100)
log.push(vb());
handlers.pointerdown(ev(400, 200));
handlers.pointermove(ev(480, 240));                // drag 80 px right, 40 px down
handlers.pointerup(ev(480, 240));
log.push(vb());
handlers.pointermove(ev(600, 300));                // not dragging: nothing moves
log.push(vb());
buttons[".zoom-out"].click();
log.push(vb());
handlers.dblclick(ev(0, 0));
log.push(vb());
console.log(JSON.stringify(log));
"""


@pytest.mark.skipif(shutil.which("node") is None, reason="needs node to run the page's script")
def test_pan_zoom_script_zooms_about_the_pointer_pans_with_the_drag_and_resets() -> None:
    run = subprocess.run(
        ["node", "-e", _FAKE_DOM + PAN_ZOOM_JS + _FAKE_RUN],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    home, zoomed, dragged, still, out, reset = (np.array(v) for v in json.loads(run.stdout))
    np.testing.assert_allclose(home, [0, 0, 1200, 600])
    # zoomed in by 1.0015^-200 about the map point under the pointer, which stays under it
    f = 1.0015**-200
    np.testing.assert_allclose(zoomed[2:], home[2:] * f)
    under = np.array([200 * 1200 / 800, 100 * 600 / 400])
    np.testing.assert_allclose(zoomed[:2] + np.array([200 / 800, 100 / 400]) * zoomed[2:], under)
    # dragging moves the map with the pointer: the view goes the other way by the same
    # distance in map units
    np.testing.assert_allclose(dragged[2:], zoomed[2:])
    np.testing.assert_allclose(dragged[:2], zoomed[:2] - np.array([80 / 800, 40 / 400]) * zoomed[2:])  # fmt: skip
    np.testing.assert_allclose(still, dragged)
    # the button zooms out about the centre
    np.testing.assert_allclose(out[2:], dragged[2:] * 1.5)
    np.testing.assert_allclose(out[:2] + out[2:] / 2, dragged[:2] + dragged[2:] / 2)
    np.testing.assert_allclose(reset, home)
