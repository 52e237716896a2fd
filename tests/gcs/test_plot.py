"""``gcs plot``: the clause curves against brute-force robustness, the picture, the HTML page,
flown telemetry and bad input.

References: the robustness curves are checked against plain numpy formulas of the predicates
(Euclidean distance, Chebyshev box margins) on positions from the closed-form quintic, and the
clause values against the min/max of those over the clause's window.
"""

from __future__ import annotations

import base64
import csv
import html
import io
import math
import re
import struct
from dataclasses import replace
from pathlib import Path

import numpy as np
import pymap3d
import pytest
from matplotlib.image import imread
from pymavlink.dialects.v20 import common as mavlink2

from gcs import cli
from gcs.plot import plot_plan
from gcs.plot.figure import figure_png, render_figure, wrap_to_width
from gcs.plot.traces import clause_traces
from gcs.telemetry import load_telemetry
from planner.planfile import load_plan
from tests.gcs.test_export_support import (
    D1,
    D2,
    quintic_position,
    reach_avoid_plan,
    write_plan,
)

DT = 0.01
T = np.arange(601) * DT


def _inside(p: np.ndarray, lo: tuple, hi: tuple) -> np.ndarray:
    """Chebyshev margin to a box, positive inside (reference for ``inside``)."""
    return np.minimum(p - np.asarray(lo), np.asarray(hi) - p).min(axis=1)


def _outside(p: np.ndarray, lo: tuple, hi: tuple) -> np.ndarray:
    return np.maximum(np.asarray(lo) - p, p - np.asarray(hi)).max(axis=1)


P1 = quintic_position(*D1, T)
P2 = quintic_position(*D2, T)
GOAL = ((1.5, 1.5, 0.5), (2.0, 2.0, 1.0))
OBSTACLE = ((-1.0, -1.0, 0.0), (1.0, 1.0, 1.5))
WORKSPACE = ((-2.0, -2.0, 0.0), (2.0, 2.0, 2.0))


def test_clause_curves_match_brute_force_predicates_and_clause_values() -> None:
    plan = reach_avoid_plan()
    traces = {tr.text: tr for tr in clause_traces(plan)}
    assert len(traces) == 5

    dist = traces["always[0,6] (dist(d1, d2) >= 0.2)"]
    ref = np.linalg.norm(P1 - P2, axis=1) - 0.2
    assert dist.shown == "body" and dist.operator == "always"
    np.testing.assert_allclose(dist.t_s, T, atol=1e-12)
    np.testing.assert_allclose(dist.rho, ref, atol=1e-9)
    assert dist.robustness == pytest.approx(ref.min(), abs=1e-9)
    assert dist.witness_t_s == pytest.approx(T[np.argmin(ref)])

    goal = traces["eventually[0,6] inside(d1, goal)"]
    ref = _inside(P1, *GOAL)
    assert goal.operator == "eventually"
    np.testing.assert_allclose(goal.rho, ref, atol=1e-9)
    assert goal.robustness == pytest.approx(ref.max(), abs=1e-9)

    avoid = traces["always[0,6] (outside(d2, obstacle) and inside(d2, workspace))"]
    ref = np.minimum(_outside(P2, *OBSTACLE), _inside(P2, *WORKSPACE))
    np.testing.assert_allclose(avoid.rho, ref, atol=1e-9)
    assert avoid.robustness == pytest.approx(ref.min(), abs=1e-9)
    # Without telemetry there is nothing flown.
    assert all(tr.flown_rho is None and tr.flown_robustness is None for tr in traces.values())


def test_until_clause_is_drawn_over_its_whole_window() -> None:
    spec = "(not inside(d1, goal)) until[0,3] (always[0,1] inside(d1, goal))"
    (tr,) = clause_traces(reach_avoid_plan(spec))
    # The curve over t' in [0, 3] whose maximum is the clause's value: the option of
    # meeting q at t' (q(t') while p held on [0, t')), not a stub of the clause's own trace.
    assert tr.shown == "until" and tr.operator == "until" and tr.window_s == (0.0, 3.0)
    assert tr.t_s.size == 301 and not np.isnan(tr.rho).any()
    phi = _inside(P1, *GOAL)
    hold = np.array([phi[k : k + 101].min() for k in range(501)])  # always[0,1]
    for tp in (0, 1, 57, 180, 300):
        before = np.inf if tp == 0 else (-phi[:tp]).min()
        assert tr.rho[tp] == pytest.approx(min(hold[tp], before), abs=1e-9)
    # Reference: brute force of the until definition (docs/stl.md, "Semantics") at t = 0.
    best = max(min(hold[tp], np.inf if tp == 0 else (-phi[:tp]).min()) for tp in range(301))
    assert tr.robustness == pytest.approx(best, abs=1e-9)
    assert tr.robustness == pytest.approx(np.nanmax(tr.rho), abs=1e-12)
    assert tr.witness_t_s == pytest.approx(T[int(np.nanargmax(tr.rho))])
    # a window that starts later is NaN before it
    (late,) = clause_traces(reach_avoid_plan(spec.replace("until[0,3]", "until[1,3]")))
    assert np.isnan(late.rho[:100]).all() and not np.isnan(late.rho[100:]).any()


@pytest.mark.slow
def test_plot_png_is_written_with_all_panels(tmp_path: Path) -> None:
    plan_path = write_plan(tmp_path / "ra.json")
    assert cli.main(["plot", str(plan_path)]) == 0  # default: beside the plan, .png
    img = imread(tmp_path / "ra.png")
    assert img.shape[:2] == (1250, 1600)
    # The picture is not blank: many distinct colours (boxes, paths, curves).
    assert len(np.unique(img.reshape(-1, img.shape[2]), axis=0)) > 200

    plan = load_plan(plan_path)
    fig = render_figure(plan, clause_traces(plan))
    titles = [ax.get_title() for ax in fig.axes]
    assert any("Regions and paths" in t for t in titles)
    assert any("Clause robustness over time" in t for t in titles)
    for axis in ("east x", "north y", "up z"):
        assert any(t.startswith(f"velocity {axis}") and "m/s" in t for t in titles)
        assert any(t.startswith(f"acceleration {axis}") and "m/s²" in t for t in titles)
    ax3 = next(ax for ax in fig.axes if ax.name == "3d")
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from gcs.plot.figure import is_large

    boxes = [c for c in ax3.collections if isinstance(c, Poly3DCollection)]
    large = [r for r in plan.regions if is_large(r, plan.workspace)]
    # small regions solid; large ones (a corridor along the whole line) only outlined, so
    # what lies inside them stays visible
    assert [r.name for r in large] == ["line"]
    assert len(boxes) == len(plan.regions) - len(large)
    labels = {t.get_text() for t in ax3.get_legend().get_texts()}
    assert {
        "d1",
        "d2",
        "workspace",
        "start",
        "end",
        "pole",
        "conductor corridor (outline)",
    } <= labels
    # The velocity panels carry the per-axis limits as dashed lines at +-v_max.
    vx = next(ax for ax in fig.axes if ax.get_title().startswith("velocity east x"))
    levels = {round(ln.get_ydata()[0], 6) for ln in vx.get_lines() if ln.get_linestyle() == "--"}
    assert levels == {3.5, -3.5}


@pytest.mark.slow
def test_prisms_and_cylinders_are_drawn_as_their_shapes_not_their_bounding_boxes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A turned inspection box (solid), a pole cylinder (solid) and a long no-fly strip
    (outline) go through the plan file and into the 3-D view as their own outlines: the
    collections handed to matplotlib carry the shapes' corners (recorded on the way in)."""
    from dataclasses import replace

    from mpl_toolkits.mplot3d import art3d

    from planner.spec.regions import Cylinder, Prism, Region, RegionKind

    yaw = math.radians(25.0)
    turned = Prism.oriented_box((0.5, 0.6, 1.2), (0.3, 0.12, 0.15), yaw)
    strip_xy = [(-2.0, -0.2), (2.0, -0.6), (2.0, -0.3), (-2.0, 0.1)]
    base = reach_avoid_plan()
    plan = replace(
        base,
        regions=(
            *base.regions,
            Region.of_shape("turned", RegionKind.INSPECTION, turned),
            Region.of_shape("mast", RegionKind.POLE, Cylinder((-0.5, 1.2), 0.1, 0.0, 1.8)),
            Region.of_shape("strip", RegionKind.NO_FLY, Prism.from_polygon(strip_xy, 0.0, 2.0)),
        ),
    )
    plan_path = write_plan(tmp_path / "shapes.json", plan)
    assert cli.main(["plot", str(plan_path)]) == 0
    assert imread(tmp_path / "shapes.png").shape[:2] == (1250, 1600)

    recorded: list[tuple[str, list[np.ndarray]]] = []

    class Poly(art3d.Poly3DCollection):
        def __init__(self, verts, *args, **kwargs):  # type: ignore[no-untyped-def]
            recorded.append(("solid", [np.asarray(v) for v in verts]))
            super().__init__(verts, *args, **kwargs)

    class Lines(art3d.Line3DCollection):
        def __init__(self, segments, *args, **kwargs):  # type: ignore[no-untyped-def]
            recorded.append(("outline", [np.asarray(v) for v in segments]))
            super().__init__(segments, *args, **kwargs)

    monkeypatch.setattr(art3d, "Poly3DCollection", Poly)
    monkeypatch.setattr(art3d, "Line3DCollection", Lines)
    loaded = load_plan(plan_path)
    fig = render_figure(loaded, clause_traces(loaded))
    figure_png(fig)  # draws

    def drawn(kind: str, floor_xy: np.ndarray, z0: float, z1: float) -> bool:
        """Some recorded collection of ``kind`` holds these corners at both heights."""
        want = {(round(x, 9), round(y, 9), round(z, 9)) for z in (z0, z1) for x, y in floor_xy}
        for k, polys in recorded:
            pts = {tuple(np.round(q, 9)) for poly in polys for q in poly}
            if k == kind and want <= pts and len(pts) == len(want):
                return True
        return False

    # the turned box's corners, from its centre, half sizes and bearing
    u, w = np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])
    corners = np.array([[0.5, 0.6] + a * 0.3 * u + b * 0.12 * w for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])  # fmt: skip
    assert drawn("solid", corners, 1.05, 1.35)
    assert drawn("outline", np.array(strip_xy), 0.0, 2.0)
    ring = np.column_stack([np.cos(np.arange(48) * np.pi / 24), np.sin(np.arange(48) * np.pi / 24)])
    assert drawn("solid", np.array([-0.5, 1.2]) + 0.1 * ring, 0.0, 1.8)
    # not their bounding boxes: no box was drawn for them
    for name in ("turned", "strip", "mast"):
        r = next(r for r in loaded.regions if r.name == name)
        (x0, y0, z0), (x1, y1, z1) = r.lo_enu_m, r.hi_enu_m
        box = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
        assert not drawn("solid", box, z0, z1) and not drawn("outline", box, z0, z1)
    # a name at the top centre of each
    ax3 = next(ax for ax in fig.axes if ax.name == "3d")
    labels = {t.get_text(): t.get_position_3d() for t in ax3.texts}
    assert labels["turned"] == pytest.approx((0.5, 0.6, 1.35))
    assert labels["mast"] == pytest.approx((-0.5, 1.2, 1.8))
    assert labels["strip"] == pytest.approx((0.0, -0.25, 2.0))


@pytest.mark.slow
def test_html_embeds_the_png_and_tabulates_clause_robustness(tmp_path: Path) -> None:
    plan_path = write_plan(tmp_path / "ra.json")
    out = tmp_path / "report.html"
    assert cli.main(["plot", str(plan_path), "-o", str(out)]) == 0
    page = out.read_text()
    m = re.search(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    assert m is not None
    png = base64.b64decode(m.group(1))
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    rows = re.findall(r"<tr><td class='num'>([^<]+)</td><td>([^<]+)</td><td><code>([^<]+)", page)
    traces = clause_traces(load_plan(plan_path))
    assert len(rows) == len(traces)
    by_text = {tr.text: tr for tr in traces}
    for value, verdict, text in rows:
        tr = by_text[text.replace("&gt;", ">")]
        assert float(value) == pytest.approx(tr.robustness, abs=5e-5)
        assert verdict == ("ok" if tr.robustness >= 0.01 else "below epsilon")
    # Weakest first.
    values = [float(v) for v, _, _ in rows]
    assert values == sorted(values)


def _write_telemetry(path: Path, tracks: dict[str, np.ndarray], t: np.ndarray) -> Path:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "vehicle", "x", "y", "z", "mode"])
        # Interleaved and reversed rows: the reader must sort by time per vehicle.
        for k in reversed(range(t.size)):
            for name, p in tracks.items():
                w.writerow([repr(float(t[k])), name, *map(repr, p[k].tolist()), "OFFBOARD"])
    return path


@pytest.mark.slow
def test_flown_curves_follow_the_telemetry(tmp_path: Path) -> None:
    plan = reach_avoid_plan()
    shift = np.array([0.0, 0.1, 0.0])
    # d2 flew 0.1 m north of its plan, sampled every 0.02 s (a grid point every other step).
    t_tel = np.arange(301) * 0.02
    tel_path = _write_telemetry(
        tmp_path / "flown.csv",
        {"d1": quintic_position(*D1, t_tel), "d2": quintic_position(*D2, t_tel) + shift},
        t_tel,
    )
    telemetry = load_telemetry(tel_path)
    traces = {tr.text: tr for tr in clause_traces(plan, telemetry)}
    # At the telemetry samples the flown curve is exact; between them it is interpolated.
    dist = traces["always[0,6] (dist(d1, d2) >= 0.2)"]
    ref = np.linalg.norm(P1 - (P2 + shift), axis=1) - 0.2
    assert dist.flown_rho is not None
    np.testing.assert_allclose(dist.flown_rho[::2], ref[::2], atol=1e-9)
    assert dist.flown_robustness == pytest.approx(ref.min(), abs=2e-3)
    goal = traces["eventually[0,6] inside(d2, goal)"]
    ref_goal = _inside(P2 + shift, *GOAL)
    assert goal.flown_robustness == pytest.approx(ref_goal.max(), abs=1e-9)
    assert goal.flown_robustness < goal.robustness  # pushed towards the goal's north face
    # d1 flew exactly as planned.
    d1 = traces["eventually[0,6] inside(d1, goal)"]
    assert d1.flown_robustness == pytest.approx(d1.robustness, abs=1e-9)

    out = tmp_path / "flown.html"
    plot_plan(plan, out, telemetry)
    page = out.read_text()
    assert "flown ρ" in page and "flown.csv" in page and "d2: 0.00-6.00 s (301 samples)" in page


def test_telemetry_without_a_vehicle_leaves_its_clauses_unflown(tmp_path: Path) -> None:
    t = np.arange(61) * 0.1
    tel = load_telemetry(_write_telemetry(tmp_path / "d1.csv", {"d1": quintic_position(*D1, t)}, t))
    traces = {tr.text: tr for tr in clause_traces(reach_avoid_plan(), tel)}
    assert traces["eventually[0,6] inside(d1, goal)"].flown_robustness is not None
    assert traces["eventually[0,6] inside(d2, goal)"].flown_robustness is None
    assert traces["always[0,6] (dist(d1, d2) >= 0.2)"].flown_rho is None


def test_links_track_csv_layout_is_read(tmp_path: Path) -> None:
    path = tmp_path / "tracks.csv"
    path.write_text(
        "vehicle,t_s,x_enu_m,y_enu_m,z_enu_m,vx_enu_m_s,vy_enu_m_s,vz_enu_m_s,north_m,east_m,down_m\n"
        "d1,0.5,1.0,2.0,3.0,0,0,0,2.0,1.0,-3.0\n"
        "d1,0.0,0.0,0.0,1.0,0,0,0,0.0,0.0,-1.0\n"
    )
    tel = load_telemetry(path)
    np.testing.assert_array_equal(tel.vehicles["d1"].t_s, [0.0, 0.5])
    np.testing.assert_array_equal(tel.vehicles["d1"].pos_enu_m, [[0, 0, 1], [1, 2, 3]])


@pytest.mark.parametrize(
    ("content", "args", "message"),
    [
        (None, [], r"no\.json: cannot read"),
        ("{not json", [], r"bad\.json: line 1, column 2: not JSON"),
        ('{"format": "other"}', [], r"bad\.json: format: expected 'stl-gcs-plan'"),
        ("PLAN", ["-o", "pic.jpg"], r"pic\.jpg: output must end in \.png or \.html"),
        ("PLAN", ["--telemetry", "t.csv"], r"t\.csv: line 1: missing column\(s\) z"),
        ("PLAN", ["--telemetry", "n.csv"], r"n\.csv: line 3: column x: not a number: 'abc'"),
        ("PLAN", ["--telemetry", "f.tlog"], r"f\.tlog: a \.tlog does not record"),
        ("PLAN", ["--dt", "-1"], r"--dt: must be a positive number"),
    ],
)
def test_bad_input_exits_2_with_one_line(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    content: str | None,
    args: list[str],
    message: str,
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "t.csv").write_text("t,vehicle,x,y\n0,d1,0,0\n")
    (tmp_path / "n.csv").write_text("t,vehicle,x,y,z\n0,d1,0,0,1\n0.1,d1,abc,0,1\n")
    if content is None:
        plan = "no.json"
    elif content == "PLAN":
        plan = str(write_plan(tmp_path / "ok.json"))
    else:
        plan = "bad.json"
        (tmp_path / plan).write_text(content)
    assert cli.main(["plot", plan, *args]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith("gcs plot: error: ")
    assert re.search(message, err), err


def _write_tlog(path: Path, t0_unix_s: float, vehicle_origin: tuple[float, float, float]) -> None:
    """A .tlog as QGC/MAVProxy write it: 8-byte big-endian microseconds + MAVLink packet."""
    # The origin as the wire carries it (degE7, mm), so the reference uses the same point.
    lat, lon, alt = (
        round(vehicle_origin[0] * 1e7) / 1e7,
        round(vehicle_origin[1] * 1e7) / 1e7,
        round(vehicle_origin[2] * 1e3) / 1e3,
    )
    with path.open("wb") as f:
        for sysid, (wps, durs) in ((1, D1), (2, D2)):
            mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
            origin = mavlink2.MAVLink_gps_global_origin_message(
                round(lat * 1e7), round(lon * 1e7), round(alt * 1e3), 0
            )
            f.write(struct.pack(">Q", round(t0_unix_s * 1e6)) + origin.pack(mav))
            t = np.arange(61) * 0.1
            enu = quintic_position(wps, durs, t)
            # Local NED of the vehicle's own origin, computed with pymap3d directly.
            g = pymap3d.enu2geodetic(enu[:, 0], enu[:, 1], enu[:, 2], 47.397742, 8.545594, 488.0)
            e, n, u = pymap3d.geodetic2enu(*g, lat, lon, alt)
            for k in range(t.size):
                msg = mavlink2.MAVLink_local_position_ned_message(
                    int(t[k] * 1000), n[k], e[k], -u[k], 0.0, 0.0, 0.0
                )
                f.write(struct.pack(">Q", round((t0_unix_s + t[k]) * 1e6)) + msg.pack(mav))


@pytest.mark.slow
def test_tlog_telemetry_is_read_in_the_mission_frame_from_the_vehicles_own_origins(
    tmp_path: Path,
) -> None:
    t0 = 1_700_000_000.0
    tlog = tmp_path / "flight.tlog"
    # Vehicles spawned 30 m east and 2 m higher than the mission origin.
    _write_tlog(tlog, t0, (47.397742, 8.545594 + 30 / 75_300.0, 490.0))
    plan_path = write_plan(tmp_path / "ra.json")
    plan = load_plan(plan_path)
    tel = load_telemetry(tlog, plan, t0)
    t = np.arange(61) * 0.1
    for name, (wps, durs) in (("d1", D1), ("d2", D2)):
        path = tel.vehicles[name]
        np.testing.assert_allclose(path.t_s, t, atol=1e-6)
        # float32 NED on the wire (30 m east: resolution ~2e-6 m).
        np.testing.assert_allclose(path.pos_enu_m, quintic_position(wps, durs, t), atol=1e-5)
    out = tmp_path / "flown.png"
    args = ["plot", str(plan_path), "-o", str(out), "--telemetry", str(tlog), "--t0", str(t0)]
    assert cli.main(args) == 0
    assert imread(out).shape[:2] == (1250, 1600)


def test_unusable_telemetry_or_spec_is_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan_path = write_plan(tmp_path / "ok.json")
    tel = tmp_path / "other.csv"
    tel.write_text("t,vehicle,x,y,z\n0,x9,0,0,1\n")
    assert cli.main(["plot", str(plan_path), "--telemetry", str(tel)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        len(err) == 1 and "other.csv: no vehicle of the plan in the telemetry (it has x9" in err[0]
    )

    # A clause that needs 10 s of a 6 s plan.
    long = write_plan(
        tmp_path / "long.json", reach_avoid_plan("always[0,10] inside(d1, workspace)")
    )
    assert cli.main(["plot", str(long)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "spec clause 1 (always[0,10] inside(d1, workspace))" in err[0], err


def test_colour_means_vehicle_in_every_panel_and_telemetry_adds_tracking_and_velocity(
    tmp_path: Path,
) -> None:
    from matplotlib.colors import to_rgba

    from gcs.plot.figure import flown_velocity, tracking_error

    plan = reach_avoid_plan()
    # d2 flew 0.1 m north of its plan and 0.2 s late (so its velocity is the plan's, delayed)
    t_tel = np.arange(301) * 0.02
    shift = np.array([0.0, 0.1, 0.0])
    late = np.clip(t_tel - 0.2, 0.0, None)
    telemetry = load_telemetry(
        _write_telemetry(
            tmp_path / "f.csv",
            {"d1": quintic_position(*D1, t_tel), "d2": quintic_position(*D2, late) + shift},
            t_tel,
        )
    )
    traces = clause_traces(plan, telemetry)
    fig = render_figure(plan, traces, telemetry)
    vel_ax = next(ax for ax in fig.axes if ax.get_title().startswith("velocity east x"))
    vehicle_colour = {ln.get_label(): to_rgba(ln.get_color()) for ln in vel_ax.get_lines() if ln.get_label() in ("d1", "d2")}  # fmt: skip
    assert len(set(vehicle_colour.values())) == 2
    # robustness panel: a clause about one vehicle in that vehicle's colour, several in black
    rob = next(ax for ax in fig.axes if ax.get_title().startswith("Clause robustness"))
    legend = next(ax for ax in fig.axes if ax.get_legend() and "weakest first" in ax.get_legend().get_title().get_text())  # fmt: skip
    for handle in legend.get_legend().legend_handles:
        text = handle.get_label()
        names = [n for n in ("d1", "d2") if f"{n}," in text or f"{n})" in text]
        if not names:
            continue
        want = vehicle_colour[names[0]] if len(names) == 1 else to_rgba("k")
        assert to_rgba(handle.get_color()) == want, text
    clause_colours = {to_rgba(ln.get_color()) for ln in rob.get_lines()}
    assert clause_colours <= {*vehicle_colour.values(), to_rgba("k"), to_rgba("0.6")}
    # tracking error panel: |flown - planned| per vehicle, against a direct computation
    trk = next(ax for ax in fig.axes if ax.get_title().startswith("Tracking error"))
    err = tracking_error(plan, telemetry, T)
    assert np.allclose(err["d1"][1][::2], 0.0, atol=1e-9)  # at the samples; between, linear
    assert np.allclose(err["d1"][1], 0.0, atol=1e-3)
    ref = np.linalg.norm(quintic_position(*D2, np.clip(T - 0.2, 0, None)) + shift - P2, axis=1)
    np.testing.assert_allclose(err["d2"][1], ref, atol=2e-3)  # telemetry interpolated
    assert {ln.get_label().split()[0] for ln in trk.get_lines()} >= {"d1", "d2"}
    # flown velocities beside the planned ones: d2's is its plan's, 0.2 s later
    tf, vf = flown_velocity(telemetry.vehicles["d2"])
    inner = (tf > 0.5) & (tf < 5.5)
    assert np.all(np.isfinite(vf))
    pv = next(v for v in plan.vehicles if v.name == "d2")
    # (a central difference over 0.25 s: exact to h^2 / 6 of the jerk, under 0.05 m/s here)
    np.testing.assert_allclose(vf[inner], pv.trajectory.velocity(tf[inner] - 0.2), atol=0.05)
    flown_lines = [ln for ln in vel_ax.get_lines() if ln.get_alpha() == pytest.approx(0.35)]
    assert len(flown_lines) == 2


#: A planner status whose outcome (the part before the first colon) is long, and a long
#: plan file name: together the title is about twice the figure's width at 12 pt.
LONG_STATUS = (
    "stopped at the time limit (120 s); the best plan so far, and it meets the mission, "
    "though only just: robustness 0.05 >= epsilon 0.01 (solver: Maximum_Iterations_Exceeded)"
)
LONG_NAME = "powerline_inspection_north_section_with_the_new_poles_2024-06-11_replanned.json"


@pytest.mark.parametrize("view", ["3d", "map"])
@pytest.mark.slow
def test_long_titles_are_wrapped_inside_the_figure_not_cut_off(view: str) -> None:
    plan = replace(reach_avoid_plan(), status=LONG_STATUS)
    fig = render_figure(plan, clause_traces(plan), name=LONG_NAME, view=view)
    figure_png(fig)  # drawn as it is written
    renderer = fig.canvas.get_renderer()
    width, height = fig.bbox.width, fig.bbox.height
    from matplotlib.text import Text

    text = fig.get_suptitle()
    assert text
    title = next(t for t in fig.findobj(Text) if t.get_text() == text)
    # all of it, on more lines than one: the outcome in full (it was cut at 40 characters)
    assert len(text.splitlines()) >= 2
    assert LONG_STATUS.split(":")[0] in " ".join(text.split())
    assert LONG_NAME in text
    box = title.get_window_extent(renderer)
    assert box.x0 >= 0.0 and box.x1 <= width and box.y0 >= 0.0 and box.y1 <= height, box
    # every panel's title inside the figure too, within its panel's width, under the title
    for ax in fig.axes:
        if not ax.get_title():
            continue
        tb = ax.title.get_window_extent(renderer)
        assert tb.x0 >= 0.0 and tb.x1 <= width and tb.y1 <= box.y0 + 1.0, (ax.get_title(), tb)
        assert tb.width <= ax.get_position().width * width + 1.0, ax.get_title()


def test_the_html_page_shows_the_whole_long_title(tmp_path: Path) -> None:
    """The page's PNG has nothing drawn at its left and right edges where the title is (a
    title running off the figure leaves its letters cut there), and the page's own text
    carries the status whole and may break anywhere."""
    plan = replace(reach_avoid_plan(), status=LONG_STATUS)
    out = tmp_path / "long.html"
    plot_plan(plan, out, name=LONG_NAME)
    page = out.read_text()
    m = re.search(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    assert m is not None
    img = imread(io.BytesIO(base64.b64decode(m.group(1))), format="png")
    band = img[:60, :, :3]  # the title's lines
    assert (band[:, :4] == 1.0).all() and (band[:, -4:] == 1.0).all()
    assert (band < 0.5).any()  # and the title is there
    assert f"status {html.escape(LONG_STATUS)};" in page
    assert "overflow-wrap: anywhere" in page


def test_wrap_to_width_breaks_at_sections_then_words_then_letters() -> None:
    def measure(s: str) -> float:  # a monospace font: 10 px a character
        return 10.0 * len(s)

    assert wrap_to_width("short | title", 200.0, measure) == "short | title"
    text = "plan.json: 2 vehicles | robustness +0.1 (epsilon 0.01) | planner: the mission is met"
    lines = wrap_to_width(text, 400.0, measure).splitlines()
    # sections kept whole where they fit, the separator dropped at a break
    assert lines == [
        "plan.json: 2 vehicles",
        "robustness +0.1 (epsilon 0.01)",
        "planner: the mission is met",
    ]
    # a section too long for a line is broken between words; a word too long, anywhere
    lines = wrap_to_width("a_very_long_file_name.json: stopped at the limit", 160.0, measure).splitlines()  # fmt: skip
    assert all(measure(line) <= 160.0 for line in lines)
    assert lines == ["a_very_long_file", "_name.json:", "stopped at the", "limit"]
