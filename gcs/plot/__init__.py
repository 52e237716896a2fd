"""Pictures of a plan: regions and paths (in 3-D, or on a map), clause robustness over time,
kinematics.

Everything :func:`plot_plan` draws is computed from the plan's stored ``segments`` (the source
of truth ``gcs verify`` uses too) and, when given, the flown telemetry. It calls on three
rooms:

* :mod:`gcs.telemetry` reads the flown telemetry (``--telemetry``: a CSV with the columns
  ``t,vehicle,x,y,z``, the link's track CSV, or a ``.tlog`` with its start time ``--t0``);
* :mod:`gcs.plot.traces` computes the robustness over time of every top-level clause of
  the spec, exact semantics on the dense grid ``t = 0, dt, ..., horizon``, planned and flown;
* :mod:`gcs.plot.figure` draws them: the 3-D view of regions and paths (flown paths over the
  planned ones), the clause robustness over time, the tracking error when telemetry is
  given, and every vehicle's per-axis velocity and acceleration against its limits;
* :mod:`gcs.plot.map_view` draws the map that takes the 3-D view's place for a long line
  (``view``: ``auto`` picks it when the workspace is 200 m or more across its diagonal,
  :func:`gcs.plot.map_view.choose_view`; ``3d`` and ``map`` force one).

Outputs: a PNG, or a self-contained HTML page (the PNG embedded as base64 and a table of the
clause robustness, planned and flown; in the map view also the map as inline SVG, to zoom
with the mouse wheel and pan by dragging: :data:`PAN_ZOOM_JS`, no network access).

Errors::

    gcs.errors.InputFileError        unreadable/malformed telemetry (file, line, column), telemetry
                                     without any vehicle of the plan, a bad output path or --dt
    planner.planfile.PlanFileError   a spec that does not parse, or a clause that cannot be
                                     evaluated on the plan (e.g. longer than its horizon)
    mavlink.errors.LinkError         a .tlog the link's reader rejects (no origin message)
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from gcs.errors import InputFileError
from gcs.flight.evaluation import heading_readers, plan_formula
from gcs.plot.figure import figure_png, render_figure
from gcs.plot.map_view import View, choose_view, render_map
from gcs.plot.map_view import map_svg as svg_of_map
from gcs.plot.traces import ClauseTrace, clause_traces

if TYPE_CHECKING:
    from gcs.telemetry import Telemetry
    from planner.planfile import Plan

__all__ = ["PAN_ZOOM_JS", "PlotResult", "html_report", "plot_plan"]


def _fmt(x: float | None) -> str:
    if x is None:
        return "n/a"
    return f"{x:+.4f}" if math.isfinite(x) else str(x)


#: Pan and zoom for the page's map (the ``<svg>`` inside ``<div id="map">``), by changing
#: its ``viewBox``: the wheel zooms about the pointer, dragging pans, a double click or the
#: reset button shows the whole map again; the buttons zoom about the centre. No library,
#: nothing loaded: the page works offline.
PAN_ZOOM_JS = """
(function () {
  var box = document.getElementById("map");
  var svg = box && box.querySelector("svg");
  if (!svg) { return; }
  var home = svg.getAttribute("viewBox").split(/[ ,]+/).map(Number);
  var vb = home.slice();
  var drag = null;
  function show() { svg.setAttribute("viewBox", vb.join(" ")); }
  function at(ev) {
    var p = svg.createSVGPoint();
    p.x = ev.clientX; p.y = ev.clientY;
    return p.matrixTransform(svg.getScreenCTM().inverse());
  }
  function zoom(f, cx, cy) {
    var w = Math.min(Math.max(vb[2] * f, home[2] / 200), home[2] * 2);
    f = w / vb[2];
    vb = [cx - (cx - vb[0]) * f, cy - (cy - vb[1]) * f, vb[2] * f, vb[3] * f];
    show();
  }
  svg.addEventListener("wheel", function (ev) {
    ev.preventDefault();
    var p = at(ev);
    var px = ev.deltaY * (ev.deltaMode === 1 ? 33 : ev.deltaMode === 2 ? 400 : 1);
    zoom(Math.pow(1.0015, px), p.x, p.y);
  }, {passive: false});
  svg.addEventListener("pointerdown", function (ev) {
    drag = at(ev);
    svg.setPointerCapture(ev.pointerId);
    svg.style.cursor = "grabbing";
  });
  svg.addEventListener("pointermove", function (ev) {
    if (!drag) { return; }
    var p = at(ev);
    vb[0] -= p.x - drag.x; vb[1] -= p.y - drag.y;
    show();
  });
  function stop() { drag = null; svg.style.cursor = "grab"; }
  svg.addEventListener("pointerup", stop);
  svg.addEventListener("pointercancel", stop);
  function reset() { vb = home.slice(); show(); }
  svg.addEventListener("dblclick", reset);
  box.querySelector(".reset").addEventListener("click", reset);
  box.querySelector(".zoom-in").addEventListener("click", function () {
    zoom(1 / 1.5, vb[0] + vb[2] / 2, vb[1] + vb[3] / 2);
  });
  box.querySelector(".zoom-out").addEventListener("click", function () {
    zoom(1.5, vb[0] + vb[2] / 2, vb[1] + vb[3] / 2);
  });
})();
"""


def _map_section(svg: str, plan: Plan) -> str:
    """The page's map: ``svg`` (:func:`gcs.plot.map_view.map_svg`) with its buttons and script."""
    return f"""<h2>Map</h2>
<p>North up, in metres east and north of the scenario's origin: the regions, and each
vehicle's path over the {plan.horizon_s:g} s horizon with its time ticks and hovers.
Mouse wheel: zoom; drag: pan; double click: the whole map.</p>
<div id="map">
<div class="tools"><button type="button" class="zoom-in">+</button>
<button type="button" class="zoom-out">&minus;</button>
<button type="button" class="reset">whole map</button></div>
{svg}
</div>
<script>{PAN_ZOOM_JS}</script>
"""


def html_report(
    plan: Plan,
    traces: Sequence[ClauseTrace],
    png: bytes,
    telemetry: Telemetry | None = None,
    name: str | None = None,
    map_svg: str | None = None,
) -> str:
    """A self-contained HTML page: the PNG (base64) and a table of clause robustness, and
    with ``map_svg`` (an inline ``<svg>``, :func:`gcs.plot.map_view.map_svg`) the map to pan and
    zoom. Nothing on it is loaded from elsewhere.

    ``name`` titles it (default: the scenario's file stem).
    """
    esc = html.escape
    title = name or Path(plan.scenario).stem
    flown = telemetry is not None
    rows = []
    for tr in sorted(traces, key=lambda c: c.robustness):
        ok = tr.robustness >= plan.epsilon
        cells = [
            f"<td class='num'>{_fmt(tr.robustness)}</td>",
            f"<td>{'ok' if ok else 'VIOLATED' if tr.robustness < 0 else 'below epsilon'}</td>",
        ]
        if flown:
            cells.append(f"<td class='num'>{_fmt(tr.flown_robustness)}</td>")
        cells.append(f"<td><code>{esc(tr.text)}</code></td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    coverage = ""
    if telemetry is not None:
        readers = heading_readers(plan_formula(plan))
        parts = []
        for v in plan.vehicles:
            path = telemetry.vehicles.get(v.name)
            if path is None:
                parts.append(f"{esc(v.name)}: no telemetry")
            else:
                no_heading = v.name in readers and not path.has_heading
                parts.append(
                    f"{esc(v.name)}: {path.t_s[0]:.2f}-{path.t_s[-1]:.2f} s ({path.t_s.size} samples"
                    + (", no heading: its face clauses are not judged" if no_heading else "")
                    + ")"
                )
        coverage = (
            f"<p>Telemetry <code>{esc(telemetry.source)}</code> covers "
            + "; ".join(parts)
            + f" of the 0-{plan.horizon_s:g} s horizon (positions held outside).</p>"
        )
    head = (
        "<th>planned ρ</th><th>verdict</th>"
        + ("<th>flown ρ</th>" if flown else "")
        + "<th>clause</th>"
    )
    png64 = base64.b64encode(png).decode("ascii")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>stl-gcs plan: {esc(title)}</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; }}
table {{ border-collapse: collapse; font-size: 0.9em; }}
td, th {{ border: 1px solid #bbb; padding: 0.2em 0.5em; text-align: left; }}
td.num {{ text-align: right; font-family: monospace; }}
h1, p, td {{ overflow-wrap: anywhere; }}
img {{ max-width: 100%; }}
#map {{ border: 1px solid #bbb; max-width: 100%; }}
#map .tools {{ padding: 0.2em; background: #f4f4f4; border-bottom: 1px solid #bbb; }}
#map svg {{ display: block; width: 100%; height: auto; max-height: 85vh;
  cursor: grab; touch-action: none; user-select: none; }}
</style></head><body>
<h1>Plan {esc(title)}</h1>
<p>Scenario <code>{esc(plan.scenario)}</code>; status {esc(plan.status)};
robustness {_fmt(plan.robustness)} (smooth {_fmt(plan.smooth_robustness)}, epsilon {plan.epsilon:g});
{len(plan.vehicles)} vehicle(s); horizon {plan.horizon_s:g} s; solve time {plan.solve_time_s:.2f} s.</p>
{coverage}
<h2>Clause robustness</h2>
<p>Exact robustness at t = 0 of each top-level clause, weakest first, on the dense grid
(every {plan.check_dt_s:g} s).</p>
<table><tr>{head}</tr>
{chr(10).join(rows)}
</table>
{_map_section(map_svg, plan) if map_svg else ""}<h2>Picture</h2>
<img alt="regions, paths, clause robustness and kinematics of the plan" src="data:image/png;base64,{png64}">
</body></html>
"""


@dataclass(frozen=True, slots=True)
class PlotResult:
    """What :func:`plot_plan` wrote."""

    path: Path
    traces: tuple[ClauseTrace, ...]
    #: the panel of regions and paths drawn (``auto`` resolved)
    view: View = View.THREE_D


def plot_plan(
    plan: Plan,
    output: str | Path,
    telemetry: Telemetry | None = None,
    dt_s: float | None = None,
    name: str | None = None,
    view: View | str = View.AUTO,
) -> PlotResult:
    """Draw ``plan`` to ``output`` (``.png`` or ``.html``), titled ``name`` (e.g. the plan file),
    with the panel of regions and paths ``view`` (``auto``: :func:`gcs.plot.map_view.choose_view`);
    an HTML page of a map view also carries the map to pan and zoom.

    Raises:
        InputFileError: another extension, or the file cannot be written.
    """
    out = Path(output)
    kind = out.suffix.lower()
    if kind not in (".png", ".html", ".htm"):
        raise InputFileError(f"{out}: output must end in .png or .html")
    shown = choose_view(plan, view)
    traces = clause_traces(plan, telemetry, dt_s)
    fig = render_figure(plan, traces, telemetry, dt_s, name, shown)
    png = figure_png(fig)
    if kind == ".png":
        data = png
    else:
        svg = svg_of_map(render_map(plan, telemetry, dt_s, name)) if shown is View.MAP else None
        data = html_report(plan, traces, png, telemetry, name, svg).encode("utf-8")
    try:
        out.write_bytes(data)
    except OSError as exc:
        raise InputFileError(f"{out}: cannot write: {exc.strerror or exc}") from None
    return PlotResult(path=out, traces=traces, view=shown)
