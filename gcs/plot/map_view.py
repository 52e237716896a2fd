"""The plan from above (``gcs plot --view map``): a map, north up, in metres east (x) and north
(y) of the scenario's origin (the mission ENU frame), one metre as long on both axes.

What :func:`draw_map` draws:

* the workspace as a dashed outline, and every region as its footprint (a box, a turned box
  or polygon, a pole's circle): keep-outs hatched (obstacles and no-fly zones red, conductor
  corridors and spans orange), inspection places and goals green and drawn over the
  keep-outs, other regions blue;
* the poles (towers) with a mark that stays visible at any scale and their names; when the
  plan's poles are ``pole1``, ``pole2``, ... (the names a scenario's ``line:`` section
  gives them, in line order) the line itself, pole to pole: its spans;
* each vehicle's path in its colour, from a circle (start) to a square (end), with a dot every
  :func:`tick_step_s` seconds labelled with its time, and a ring where it hovers
  (:func:`find_hovers`: its speed stays under :data:`HOVER_SPEED_M_S` for
  :data:`HOVER_MIN_S` or longer) labelled with when;
* the flown paths, broad and faint, when telemetry is given.

Labels that would overlap one already placed are left out (hovers first, then poles, time
ticks, the other regions): the marks stay, the map stays readable.

Which view ``auto`` picks (:func:`choose_view`): the map when the workspace's footprint is
at least :data:`MAP_FROM_M` (200 m) across its diagonal, else the 3-D view. At 200 m a pole
(0.8 m) is under 4 pixels in the 3-D panel and the perspective flattens the line into a
strip; inspection engineers read such lines on maps.

The HTML page (:mod:`gcs.plot`) carries the map of :func:`render_map` as inline SVG
(:func:`map_svg`) to pan and zoom.
"""

from __future__ import annotations

import enum
import io
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from gcs.plot.figure import KIND_STYLE, fit_titles, vehicle_colours
from gcs.plot.traces import plan_grid
from planner.spec.cover import drawn_regions
from planner.spec.regions import KEEP_OUT_KINDS, RegionKind

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from gcs.telemetry import Telemetry
    from planner.planfile import Plan

__all__ = [
    "HOVER_MIN_S",
    "HOVER_SPEED_M_S",
    "MAP_FROM_M",
    "Hover",
    "View",
    "choose_view",
    "draw_map",
    "find_hovers",
    "line_poles",
    "map_aspect",
    "map_svg",
    "render_map",
    "tick_step_s",
]


class View(enum.Enum):
    """The panel of regions and paths: ``auto`` (:func:`choose_view`), ``3d`` or ``map``."""

    AUTO = "auto"
    THREE_D = "3d"
    MAP = "map"


#: ``auto`` draws a map when the workspace's footprint is at least this long (m) across its
#: diagonal (module docstring).
MAP_FROM_M = 200.0
#: A vehicle hovers where its speed stays at most this (m/s) ...
HOVER_SPEED_M_S = 0.2
#: ... for at least this long (s): longer than the slow start and end of a few seconds'
#: move from rest to rest.
HOVER_MIN_S = 2.0
#: About this many time ticks over the horizon, at most (:func:`tick_step_s`).
_MOST_TICKS = 12
#: The steps (s) time ticks are chosen from.
_TICK_STEPS_S = (0.1, 0.2, 0.5, 1, 2, 5, 10, 15, 20, 30, 60, 120, 300, 600, 900, 1800, 3600)
#: Font size (pt) of the map's labels.
_LABEL_PT = 6.5


def scene_diagonal_m(plan: Plan) -> float:
    """The diagonal (m) of the workspace's east-north footprint."""
    lo, hi = plan.workspace.lo_enu_m, plan.workspace.hi_enu_m
    return math.hypot(hi[0] - lo[0], hi[1] - lo[1])


def choose_view(plan: Plan, view: View | str = View.AUTO) -> View:
    """``view`` (a :class:`View` or its value); ``auto``: :attr:`View.MAP` when the workspace
    is at least :data:`MAP_FROM_M` across (:func:`scene_diagonal_m`), else
    :attr:`View.THREE_D`."""
    chosen = View(view)
    if chosen is not View.AUTO:
        return chosen
    return View.MAP if scene_diagonal_m(plan) >= MAP_FROM_M else View.THREE_D


@dataclass(frozen=True, slots=True)
class Hover:
    """Where and when a vehicle hovers: ``t0_s``-``t1_s``, at ``pos_enu_m`` (its mean
    position then, m)."""

    vehicle: str
    t0_s: float
    t1_s: float
    pos_enu_m: tuple[float, float, float]


def find_hovers(plan: Plan, t_s: NDArray[np.float64]) -> list[Hover]:
    """Every vehicle's hovers on the grid ``t_s`` (n,): the longest runs of samples whose
    speed is at most :data:`HOVER_SPEED_M_S` that last :data:`HOVER_MIN_S` or more, in
    vehicle then time order."""
    out = []
    for v in plan.vehicles:
        slow = np.linalg.norm(v.trajectory.velocity(t_s), axis=1) <= HOVER_SPEED_M_S
        edges = np.diff(np.concatenate([[0], slow.astype(np.int8), [0]]))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
        for a, b in zip(starts, stops, strict=True):
            if t_s[b] - t_s[a] >= HOVER_MIN_S - 1e-9:
                p = v.trajectory.position(t_s[a : b + 1]).mean(axis=0)
                at = (float(p[0]), float(p[1]), float(p[2]))
                out.append(Hover(v.name, float(t_s[a]), float(t_s[b]), at))
    return out


def tick_step_s(horizon_s: float) -> float:
    """The time between two ticks on a path (s): the smallest of 0.1, 0.2, 0.5, 1, 2, 5, 10,
    15, 20, 30 s, 1, 2, 5, 10, 15, 30, 60 min that puts at most :data:`_MOST_TICKS` on the
    horizon."""
    for step in _TICK_STEPS_S:
        if horizon_s / step <= _MOST_TICKS:
            return float(step)
    return float(_TICK_STEPS_S[-1])


def line_poles(plan: Plan) -> NDArray[np.float64] | None:
    """The poles' centres ``(n, 2)`` in line order when the plan's poles include ``pole1`` to
    ``poleN`` (n >= 2, none missing): the line a scenario's ``line:`` section made (or one
    named alike); else None."""
    found: dict[int, NDArray[np.float64]] = {}
    for r in plan.regions:
        m = re.fullmatch(r"pole(\d+)", r.name)
        if m is not None and r.kind is RegionKind.POLE and r.part_of is None:
            found[int(m.group(1))] = np.asarray(r.center_enu_m[:2], dtype=float)
    n = 0
    while n + 1 in found:
        n += 1
    if n < 2:
        return None
    return np.array([found[i] for i in range(1, n + 1)])


def _extent(
    plan: Plan, telemetry: Telemetry | None, paths: Sequence[NDArray[np.float64]] = ()
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(lo, hi)`` (2,) of what the map shows: the workspace, the regions, the paths."""
    pts = [np.asarray(plan.workspace.lo_enu_m[:2]), np.asarray(plan.workspace.hi_enu_m[:2])]
    for r in plan.regions:
        pts += [np.asarray(r.lo_enu_m[:2]), np.asarray(r.hi_enu_m[:2])]
    for p in paths:
        if len(p):
            pts += [p[:, :2].min(axis=0), p[:, :2].max(axis=0)]
    if telemetry is not None:
        for track in telemetry.vehicles.values():
            if track.pos_enu_m.size:
                pts += [track.pos_enu_m[:, :2].min(axis=0), track.pos_enu_m[:, :2].max(axis=0)]
    xy = np.array(pts, dtype=float)
    return xy.min(axis=0), xy.max(axis=0)


def map_aspect(plan: Plan, telemetry: Telemetry | None = None) -> float:
    """How many times wider (east) than tall (north) the map's content is."""
    lo, hi = _extent(plan, telemetry)
    span = np.maximum(hi - lo, 1e-9)
    return float(span[0] / span[1])


class _Labels:
    """Places labels that keep clear of those already placed: their boxes estimated in
    pixels at the map's scale (``px_per_m``) from the font size and the text's length."""

    def __init__(self, ax: Any, px_per_m: float) -> None:
        self.ax = ax
        self.px_per_m = px_per_m
        self.px_per_pt = ax.figure.dpi / 72.0
        self.boxes: list[tuple[float, float, float, float]] = []

    def add(
        self,
        x_m: float,
        y_m: float,
        text: str,
        offset_pt: tuple[float, float] = (3.0, 3.0),
        ha: str = "left",
        **style: Any,
    ) -> bool:
        """Label ``(x_m, y_m)`` with ``text``, ``offset_pt`` from it, if it overlaps no label
        placed yet; whether it was placed."""
        k = self.px_per_pt
        w = 0.6 * _LABEL_PT * k * len(text)
        h = 1.25 * _LABEL_PT * k
        x0 = x_m * self.px_per_m + offset_pt[0] * k - (w / 2 if ha == "center" else 0.0)
        y0 = y_m * self.px_per_m + offset_pt[1] * k
        box = (x0, y0, x0 + w, y0 + h)
        for b in self.boxes:
            if box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3]:
                return False
        self.boxes.append(box)
        self.ax.annotate(
            text,
            (x_m, y_m),
            xytext=offset_pt,
            textcoords="offset points",
            ha=ha,
            va="bottom",
            fontsize=_LABEL_PT,
            zorder=9,
            annotation_clip=True,
            bbox={"boxstyle": "square,pad=0.05", "fc": "white", "ec": "none", "alpha": 0.6},
            **style,
        )
        return True


def _px_per_m(ax: Any, lo: NDArray[np.float64], hi: NDArray[np.float64]) -> float:
    """The map's scale (px per m) as it will be drawn, estimated from the axes' share of
    the figure before the layout (the legend beside it takes about a sixth)."""
    fig_w, fig_h = ax.figure.get_size_inches() * ax.figure.dpi
    pos = ax.get_position()
    w_px, h_px = 0.85 * pos.width * fig_w, pos.height * fig_h
    span = np.maximum(hi - lo, 1e-9)
    return float(min(w_px / span[0], h_px / span[1]))


def _draw_regions(ax: Any, plan: Plan, labels: _Labels) -> dict[str, Any]:
    """The workspace, the regions' footprints, the line and the poles; legend handles."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Polygon

    ws = plan.workspace.footprint_xy()
    ax.add_patch(Polygon(ws, closed=True, fill=False, ls="--", lw=0.8, ec="k", zorder=1))
    handles: dict[str, Any] = {"workspace": Line2D([], [], color="k", lw=0.8, ls="--", label="workspace")}  # fmt: skip
    regions = drawn_regions(plan.regions)
    poles = [r for r in regions if r.kind is RegionKind.POLE]
    targets = [r for r in regions if r.kind.value in ("inspection", "goal")]
    line = line_poles(plan)
    if line is not None:
        ax.plot(line[:, 0], line[:, 1], color="#303030", lw=1.0, zorder=3, gid="line")
        handles["line"] = Line2D([], [], color="#303030", lw=1.0, label="line (spans, pole to pole)")  # fmt: skip
    for r in regions:
        face, alpha, edge, label = KIND_STYLE.get(r.kind.value, KIND_STYLE["region"])
        keep_out = r.kind in KEEP_OUT_KINDS and r.kind is not RegionKind.POLE
        target = r in targets
        fill = (*_rgb(face), 0.5 if target else 0.25 if r.kind is RegionKind.POLE else alpha / 2)
        hatch = ("////" if r.kind in (RegionKind.OBSTACLE, RegionKind.NO_FLY) else "\\\\\\\\") if keep_out else None  # fmt: skip
        ax.add_patch(
            Polygon(
                r.footprint_xy(),
                closed=True,
                facecolor=fill,
                edgecolor=edge,
                hatch=hatch,
                lw=0.9 if target else 0.6,
                zorder=4 if target else 3.5 if r.kind is RegionKind.POLE else 2,
                gid=f"region-{r.name}",
            )
        )
        if keep_out:
            label = f"{label} (keep-out)"
        handles.setdefault(label, Patch(facecolor=fill, edgecolor=edge, hatch=hatch, label=label))
    if poles:
        xy = np.array([r.center_enu_m[:2] for r in poles])
        ax.plot(xy[:, 0], xy[:, 1], ls="", marker="^", ms=5, color="#404040", mec="k",
                mew=0.5, zorder=5, gid="poles")  # fmt: skip
        handles["pole"] = Line2D([], [], ls="", marker="^", ms=5, color="#404040", mec="k", mew=0.5, label="pole / tower")  # fmt: skip
        for i in _spread(len(poles)):  # the first, the last, then halfway between: even gaps
            c = poles[i].center_enu_m
            labels.add(float(c[0]), float(c[1]), poles[i].name, (0.0, 5.0), ha="center", color="#303030")  # fmt: skip
    return handles


def _spread(n: int) -> list[int]:
    """``0 .. n-1`` in the order that labels them evenly at any density: both ends, then
    the middle of every gap, halving the gaps."""
    if n <= 2:
        return list(range(n))
    order, gaps = [0, n - 1], [(0, n - 1)]
    while gaps:
        nxt = []
        for a, b in gaps:
            if b - a > 1:
                m = (a + b) // 2
                order.append(m)
                nxt += [(a, m), (m, b)]
        gaps = nxt
    return order


def _label_regions(plan: Plan, labels: _Labels) -> None:
    """Name the regions other than poles at their centres, places to be first, where there
    is room."""
    regions = [r for r in drawn_regions(plan.regions) if r.kind is not RegionKind.POLE]
    regions.sort(key=lambda r: r.kind.value not in ("inspection", "goal"))
    for r in regions:
        c = r.center_enu_m
        _, _, edge, _ = KIND_STYLE.get(r.kind.value, KIND_STYLE["region"])
        labels.add(float(c[0]), float(c[1]), r.name, (0.0, -9.0), ha="center", color=edge)


def _rgb(colour: str) -> tuple[float, float, float]:
    from matplotlib.colors import to_rgb

    r, g, b = to_rgb(colour)
    return (r, g, b)


def draw_map(
    ax: Any,
    plan: Plan,
    telemetry: Telemetry | None,
    colours: Sequence[Any],
    t_s: NDArray[np.float64],
) -> None:
    """Draw the map (module docstring) on the 2-D axes ``ax``: paths sampled on ``t_s`` (n,)
    seconds, vehicle ``i`` in ``colours[i]``."""
    from matplotlib.lines import Line2D

    paths = [v.trajectory.position(t_s) for v in plan.vehicles]
    lo, hi = _extent(plan, telemetry, paths)
    pad = 0.03 * float(max(hi - lo))
    lo, hi = lo - pad, hi + pad
    labels = _Labels(ax, _px_per_m(ax, lo, hi))
    step = tick_step_s(plan.horizon_s)
    digits = 0 if step >= 1.0 else 1  # times to the precision of the ticks
    hovers = find_hovers(plan, t_s)
    for h in hovers:  # first: their labels have the first choice of room
        colour = colours[[v.name for v in plan.vehicles].index(h.vehicle)]
        x, y, _ = h.pos_enu_m
        ax.plot([x], [y], ls="", marker="o", ms=11, mfc="none", mec=colour, mew=1.8, zorder=7,
                gid=f"hover-{h.vehicle}-{h.t0_s:g}-{h.t1_s:g}")  # fmt: skip
        labels.add(x, y, f"{h.t0_s:.{digits}f}-{h.t1_s:.{digits}f} s", (6.0, 5.0), color=colour,
                   fontweight="bold")  # fmt: skip
    handles = _draw_regions(ax, plan, labels)
    ticks = np.arange(1, math.floor(plan.horizon_s / step + 1e-9) + 1) * step
    ticks = ticks[ticks < plan.horizon_s - 1e-9]
    for v, c, p in zip(plan.vehicles, colours, paths, strict=True):
        flown = telemetry.vehicles.get(v.name) if telemetry is not None else None
        if flown is not None:
            f = flown.pos_enu_m
            ax.plot(f[:, 0], f[:, 1], color=c, lw=3.0, alpha=0.35, zorder=5.5)
        ax.plot(p[:, 0], p[:, 1], color=c, lw=1.4, zorder=6, gid=f"path-{v.name}")
        ax.plot([p[0, 0]], [p[0, 1]], marker="o", ms=5.5, color=c, mec="k", mew=0.5, zorder=8)
        ax.plot([p[-1, 0]], [p[-1, 1]], marker="s", ms=5.5, color=c, mec="k", mew=0.5, zorder=8)
        q = v.trajectory.position(ticks)
        ax.plot(q[:, 0], q[:, 1], ls="", marker="o", ms=3.2, color=c, mec="k", mew=0.4,
                zorder=7.5, gid=f"ticks-{v.name}")  # fmt: skip
        handles[v.name] = Line2D([], [], color=c, lw=1.4, label=v.name)
        for tk, (x, y, _) in zip(ticks, q, strict=True):
            labels.add(float(x), float(y), f"{tk:g} s", (4.0, -10.0), color=c)
    _label_regions(plan, labels)
    handles["start"] = Line2D([], [], color="k", marker="o", ls="", ms=5, label="start")
    handles["end"] = Line2D([], [], color="k", marker="s", ls="", ms=5, label="end")
    handles["tick"] = Line2D([], [], color="0.5", marker="o", ls="", ms=3.2, mec="k", mew=0.4, label=f"every {step:g} s")  # fmt: skip
    if hovers:
        label = f"hover (under {HOVER_SPEED_M_S:g} m/s for {HOVER_MIN_S:g} s or more)"
        handles["hover"] = Line2D([], [], ls="", marker="o", ms=9, mfc="none", mec="k", mew=1.5, label=label)  # fmt: skip
    if telemetry is not None:
        handles["flown"] = Line2D([], [], color="k", lw=3.0, alpha=0.35, label="flown (telemetry)")  # fmt: skip
    # the extent as data limits, the axes scaled to fit them at one scale: the frame fills
    # the panel (matplotlib widens the shorter side)
    ax.update_datalim(np.array([lo, hi]))
    ax.margins(0.0)
    ax.autoscale_view()
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east x (m)", fontsize=8)
    ax.set_ylabel("north y (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.25, lw=0.5)
    ax.annotate("N", (0.985, 0.97), xytext=(0.985, 0.80), xycoords="axes fraction",
                textcoords="axes fraction", ha="center", va="top", fontsize=9, fontweight="bold",
                arrowprops={"arrowstyle": "-|>", "color": "k", "lw": 1.2}, zorder=10)  # fmt: skip
    ax.set_title(
        "Map, north up (mission ENU frame: metres east and north of the origin)", fontsize=10
    )
    ncol = 1 if len(handles) <= 16 else 2
    ax.legend(handles=list(handles.values()), loc="upper left", bbox_to_anchor=(1.01, 1.0),
              fontsize=7, ncol=ncol, framealpha=0.85, borderaxespad=0.0)  # fmt: skip


def render_map(
    plan: Plan,
    telemetry: Telemetry | None = None,
    dt_s: float | None = None,
    name: str | None = None,
) -> Figure:
    """The map alone as a matplotlib Figure (Agg canvas), 12 in wide, as tall as its
    content needs (3.5-10 in): the HTML page's pan-and-zoom map. ``name`` titles it
    (default: the scenario's file stem)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    t, _ = plan_grid(plan, dt_s)
    height_in = min(max(10.0 / map_aspect(plan, telemetry) + 1.2, 3.5), 10.0)
    fig = Figure(figsize=(12, height_in), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    draw_map(ax, plan, telemetry, vehicle_colours(len(plan.vehicles)), t)
    title = fig.suptitle(f"{name or Path(plan.scenario).stem}: {len(plan.vehicles)} vehicle(s), "
                         f"horizon {plan.horizon_s:g} s", fontsize=10)  # fmt: skip
    fit_titles(fig, title)
    return fig


def map_svg(fig: Figure) -> str:
    """``fig`` as an inline ``<svg>`` element for an HTML page: text as text (small,
    searchable), stable element ids, without the XML prolog and doctype, the metadata, the
    namespace declarations (an inline ``<svg>`` needs none) and the fixed size (the page
    sizes it; the ``viewBox`` stays): no ``http`` address is left in it."""
    import matplotlib

    buf = io.StringIO()
    meta: dict[str, Any] = {"Date": None, "Creator": None, "Format": None, "Type": None}
    with matplotlib.rc_context({"svg.fonttype": "none", "svg.hashsalt": "stl-gcs-map"}):
        fig.savefig(buf, format="svg", metadata=meta)
    svg = buf.getvalue()
    svg = svg[svg.index("<svg") :]
    svg = re.sub(r"<metadata>.*?</metadata>\s*", "", svg, flags=re.S)
    end = svg.index(">")
    head = re.sub(r'\s+(xmlns(:\w+)?|width|height)="[^"]*"', "", svg[:end])
    return (head + svg[end:]).replace("xlink:href=", "href=").strip()
