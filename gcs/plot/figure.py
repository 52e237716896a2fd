"""The plan's picture as one matplotlib figure (:func:`render_figure`), panel by panel:

* **3-D view**: every region of the plan drawn by kind (obstacles and no-fly zones red,
  inspection boxes and goals green, poles grey, conductor corridors orange, other regions
  blue, the workspace as a dashed outline) as it is: a box, a prism (its polygon extruded from
  floor to roof: an oriented box, a no-fly area), a cylinder (a 48-gon extruded); each
  vehicle's path with a start (o) and end (square) marker; flown paths broad and faint over
  the planned ones when telemetry is given.
* **Robustness over time** of every top-level clause of the spec, exact semantics
  (:mod:`planner.stl`) on the dense grid ``t = 0, dt, ..., horizon`` (``dt`` the plan's
  ``check_dt_s``). For a clause ``always[a,b] body`` or ``eventually[a,b] body`` the curve is
  the trace of ``body``: the clause's value is its minimum (maximum) over ``[a, b]``, marked
  with a dot, so the picture shows *when* the margin is small. Any other clause is drawn as
  its own trace (defined while its horizon fits in the plan). A zero line separates
  satisfaction from violation; with many clauses the weakest ones get colours and the rest
  one grey style (the curves: :mod:`gcs.plot.traces`).
* **Tracking error** ``|flown - planned|`` per vehicle, when telemetry is given.
* **Per-axis velocity and acceleration** (east, north, up) of every vehicle against its
  per-axis limits ``v_max`` / ``a_max`` (dashed).

In the map view (``view``: :func:`gcs.plot.map_view.choose_view` picks it for a long line) a
top-down map (:func:`gcs.plot.map_view.draw_map`) takes the 3-D view's place; a scene at least
twice as wide as it is tall gets the whole top row, the robustness panels going beneath it.

Colour means vehicle in every panel (:func:`render_figure` picks them). Titles never run off
the figure: :func:`fit_titles` breaks one that would onto further lines (at its ``|``
separators first, then between words) and the constrained layout makes room for them.

A room of its own because it is all the matplotlib there is: :mod:`gcs.plot` writes the PNG
or HTML page, and the figure is drawn on an Agg canvas, so no screen is needed.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from gcs.plot.traces import plan_grid
from planner.spec.cover import drawn_regions
from planner.spec.regions import Cylinder

if TYPE_CHECKING:
    from matplotlib.figure import Figure
    from matplotlib.text import Text

    from gcs.plot.map_view import View
    from gcs.plot.traces import ClauseTrace
    from gcs.telemetry import Telemetry
    from mavlink.tracks import FlownTrack
    from planner.planfile import Plan
    from planner.spec.cover import Outline
    from planner.spec.regions import Region

__all__ = ["figure_png", "fit_titles", "render_figure", "vehicle_colours", "wrap_to_width"]

#: At most this many clauses get their own colour and legend entry; the rest are grey.
MAX_COLOURED_CLAUSES = 8

_AXES = ("east x", "north y", "up z")

#: Face colour, face alpha, edge colour and legend label of each region kind.
KIND_STYLE: dict[str, tuple[str, float, str, str]] = {
    "obstacle": ("#d62728", 0.22, "#a01010", "obstacle / no-fly"),
    "no_fly": ("#d62728", 0.22, "#a01010", "obstacle / no-fly"),
    "pole": ("#7f7f7f", 0.45, "#404040", "pole"),
    "conductor": ("#ff9f1c", 0.12, "#c06000", "conductor corridor"),
    "inspection": ("#2ca02c", 0.22, "#1a701a", "inspection box / goal"),
    "goal": ("#2ca02c", 0.22, "#1a701a", "inspection box / goal"),
    "region": ("#1f77b4", 0.12, "#1f4f84", "other region"),
}


def _box_faces(lo: Sequence[float], hi: Sequence[float]) -> list[NDArray[np.float64]]:
    """The six faces of an axis-aligned box, each ``(4, 3)``."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    c = np.array(
        [
            [x0, y0, z0],
            [x1, y0, z0],
            [x1, y1, z0],
            [x0, y1, z0],
            [x0, y0, z1],
            [x1, y0, z1],
            [x1, y1, z1],
            [x0, y1, z1],
        ]
    )
    idx = [[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 5, 4], [2, 3, 7, 6], [1, 2, 6, 5], [0, 3, 7, 4]]
    return [c[i] for i in idx]


def _box_edges(lo: Sequence[float], hi: Sequence[float]) -> list[NDArray[np.float64]]:
    """The twelve edges of a box, each ``(2, 3)``."""
    faces = _box_faces(lo, hi)
    edges = []
    for f in faces[:2]:
        edges += [np.array([f[i], f[(i + 1) % 4]]) for i in range(4)]
    bottom, top = faces[0], faces[1]
    edges += [np.array([bottom[i], top[i]]) for i in range(4)]
    return edges


def _prism_faces(
    footprint_xy: NDArray[np.float64], z0: float, z1: float
) -> list[NDArray[np.float64]]:
    """Floor, roof and the ``m`` walls of the footprint ``(m, 2)`` extruded from ``z0`` to
    ``z1``: ``(m, 3)``, ``(m, 3)``, then ``m`` faces ``(4, 3)``."""
    m = len(footprint_xy)
    bottom = np.column_stack([footprint_xy, np.full(m, z0)])
    top = np.column_stack([footprint_xy, np.full(m, z1)])
    walls = [np.array([bottom[i], bottom[(i + 1) % m], top[(i + 1) % m], top[i]]) for i in range(m)]
    return [bottom, top, *walls]


def _prism_edges(
    footprint_xy: NDArray[np.float64], z0: float, z1: float, verticals: int | None = None
) -> list[NDArray[np.float64]]:
    """Edges of the extruded footprint, each ``(2, 3)``: the floor's and roof's outlines and
    vertical edges at every corner (``verticals``: that many, evenly spaced: a cylinder's
    48-gon would be all lines)."""
    m = len(footprint_xy)
    bottom = np.column_stack([footprint_xy, np.full(m, z0)])
    top = np.column_stack([footprint_xy, np.full(m, z1)])
    edges = [np.array([ring[i], ring[(i + 1) % m]]) for ring in (bottom, top) for i in range(m)]
    step = 1 if verticals is None else max(1, m // verticals)
    edges += [np.array([bottom[i], top[i]]) for i in range(0, m, step)]
    return edges


#: Vertical edges drawn on a cylinder's outline.
_CYLINDER_VERTICALS = 4


def region_faces(region: Region | Outline) -> list[NDArray[np.float64]]:
    """The faces of a region (:class:`planner.spec.regions.Region`) as drawn: a box's six
    ``(4, 3)``; a prism's or cylinder's floor and roof ``(m, 3)`` and ``m`` walls (a polygon
    that is not convex: its :class:`planner.spec.cover.Outline`'s)."""
    if region.shape is None:
        return _box_faces(region.lo_enu_m, region.hi_enu_m)
    return _prism_faces(region.footprint_xy(), region.shape.z_lo_m, region.shape.z_hi_m)


def region_edges(region: Region | Outline) -> list[NDArray[np.float64]]:
    """The edges of a region as drawn in outline, each ``(2, 3)``."""
    if region.shape is None:
        return _box_edges(region.lo_enu_m, region.hi_enu_m)
    verticals = _CYLINDER_VERTICALS if isinstance(region.shape, Cylinder) else None
    return _prism_edges(region.footprint_xy(), region.shape.z_lo_m, region.shape.z_hi_m, verticals)


def _footprint_area(xy: NDArray[np.float64]) -> float:
    """Area of a polygon ``(m, 2)`` (shoelace)."""
    return 0.5 * abs(
        float(np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1]))
    )


def vehicle_colours(n: int) -> list[Any]:
    """One colour per vehicle (RGBA tuples), in the plan's vehicle order: the colour that
    means that vehicle in every panel."""
    from matplotlib import colormaps

    cmap = colormaps["tab10"] if n <= 10 else colormaps["tab20"]
    return [cmap(i % cmap.N) for i in range(n)]


#: A region whose footprint covers more than this share of the workspace's, or that spans
#: more than :data:`_LARGE_SPAN` of it along east or north (a right of way, a corridor), is
#: drawn as an outline: a solid would hide what lies inside it.
_LARGE_AREA = 0.4
_LARGE_SPAN = 0.6
#: Kinds drawn last and more opaque: the places to be, visible inside keep-outs.
_TARGET_KINDS = ("inspection", "goal")


def is_large(region: Any, workspace: Any) -> bool:
    """Whether ``region`` is drawn as an outline (see :data:`_LARGE_AREA`; a shaped region's
    area is its footprint's, its span its bounding box's)."""
    span = np.asarray(region.hi_enu_m) - np.asarray(region.lo_enu_m)
    ws = np.asarray(workspace.hi_enu_m) - np.asarray(workspace.lo_enu_m)
    own = float(span[0] * span[1])
    if getattr(region, "shape", None) is not None:
        own = _footprint_area(region.footprint_xy())
    area = own / max(float(ws[0] * ws[1]), 1e-12)
    return area > _LARGE_AREA or bool(np.any(span[:2] > _LARGE_SPAN * ws[:2]))


def _draw_regions(ax: Any, plan: Plan) -> list[Any]:
    """Draw the workspace outline and the regions (:func:`region_faces`,
    :func:`region_edges`); returns legend handles (one per kind).

    Large regions are outlines, others translucent solids; inspection boxes and goals are
    drawn last and more opaque, so one inside a keep-out stays visible."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    ws = plan.workspace
    ax.add_collection3d(
        Line3DCollection(
            _box_edges(ws.lo_enu_m, ws.hi_enu_m), colors="k", linewidths=0.7, linestyles="--"
        )
    )
    handles: dict[str, Any] = {
        "workspace": Line2D([], [], color="k", lw=0.7, ls="--", label="workspace")
    }
    ordered = sorted(drawn_regions(plan.regions), key=lambda r: r.kind.value in _TARGET_KINDS)
    for r in ordered:
        face, alpha, edge, label = KIND_STYLE.get(r.kind.value, KIND_STYLE["region"])
        if is_large(r, ws):
            ax.add_collection3d(
                Line3DCollection(region_edges(r), colors=edge, linewidths=1.1), autolim=False
            )
            label = f"{label} (outline)"
            handles.setdefault(label, Line2D([], [], color=edge, lw=1.1, label=label))
        else:
            target = r.kind.value in _TARGET_KINDS
            faces = region_faces(r)
            edges: Any = edge
            if isinstance(r.shape, Cylinder):  # no line along each side of its 48-gon
                edges = [edge, edge] + ["none"] * (len(faces) - 2)
            poly = Poly3DCollection(
                faces,
                facecolors=face,
                edgecolors=edges,
                linewidths=0.9 if target else 0.5,
                alpha=min(1.0, 1.6 * alpha) if target else alpha,
            )
            # the axes' limits are the workspace's (set after); autoscaling on faces of mixed
            # sizes (a cylinder's quads and 48-gon caps) reads matplotlib's padding, which is
            # not always finite
            ax.add_collection3d(poly, autolim=False)
            handles.setdefault(label, Patch(facecolor=face, edgecolor=edge, alpha=0.5, label=label))
        top = r.center_enu_m  # the label at the top centre
        ax.text(top[0], top[1], r.hi_enu_m[2], r.name, fontsize=7, color=edge, ha="center")
    return list(handles.values())


def _aspect(plan: Plan) -> tuple[tuple[float, float, float], float]:
    """Box aspect of the 3-D axes (true scale unless an axis would be thinner than 1/4 of the
    longest; then it is stretched) and the vertical exaggeration factor that results."""
    span = np.asarray(plan.workspace.hi_enu_m) - np.asarray(plan.workspace.lo_enu_m)
    shown = np.maximum(span, 0.25 * span.max())
    return (float(shown[0]), float(shown[1]), float(shown[2])), float(shown[2] / span[2])


def _draw_3d(
    ax: Any, plan: Plan, telemetry: Telemetry | None, colours: Sequence[Any], t: NDArray
) -> None:
    from matplotlib.lines import Line2D

    handles = _draw_regions(ax, plan)
    for v, c in zip(plan.vehicles, colours, strict=True):
        p = v.trajectory.position(t)
        ax.plot(p[:, 0], p[:, 1], p[:, 2], color=c, lw=1.6)
        ax.scatter(
            *p[0], color=c, marker="o", s=28, edgecolors="k", linewidths=0.5, depthshade=False
        )
        ax.scatter(
            *p[-1], color=c, marker="s", s=28, edgecolors="k", linewidths=0.5, depthshade=False
        )
        handles.append(Line2D([], [], color=c, lw=1.6, label=v.name))
        if telemetry is not None and v.name in telemetry.vehicles:
            f = telemetry.vehicles[v.name].pos_enu_m
            ax.plot(f[:, 0], f[:, 1], f[:, 2], color=c, lw=2.6, alpha=0.35)
    handles.append(
        Line2D([], [], color="k", marker="o", ls="", markersize=5, label="start"),
    )
    handles.append(Line2D([], [], color="k", marker="s", ls="", markersize=5, label="end"))
    if telemetry is not None:
        handles.append(Line2D([], [], color="k", lw=2.6, alpha=0.35, label="flown (telemetry)"))
    ws = plan.workspace
    ax.set_xlim(ws.lo_enu_m[0], ws.hi_enu_m[0])
    ax.set_ylim(ws.lo_enu_m[1], ws.hi_enu_m[1])
    ax.set_zlim(ws.lo_enu_m[2], ws.hi_enu_m[2])
    aspect, exaggeration = _aspect(plan)
    ax.set_box_aspect(aspect, zoom=1.15)
    ax.set_xlabel("east x (m)", fontsize=8)
    ax.set_ylabel("north y (m)", fontsize=8)
    zlabel = "up z (m)"
    if exaggeration > 1.01:
        zlabel += f", x{exaggeration:.2g} stretched"
    ax.set_zlabel(zlabel, fontsize=8)
    ax.tick_params(labelsize=7)
    ax.view_init(elev=28, azim=-62)
    ax.set_title("Regions and paths (mission ENU frame)", fontsize=10)
    ax.legend(handles=handles, loc="upper left", fontsize=7, ncol=2, framealpha=0.85)


def _short(text: str, n: int = 70) -> str:
    text = " ".join(text.split())
    return text if len(text) <= n else text[: n - 3] + "..."


#: Line styles that tell apart the clauses drawn in one colour.
_CLAUSE_STYLES: tuple[Any, ...] = ("-", (0, (6, 2)), (0, (1, 1.5)), (0, (6, 2, 1, 2)), (0, (3, 1, 1, 1, 1, 1)))  # fmt: skip


def _draw_robustness(
    ax: Any,
    legend_ax: Any,
    traces: Sequence[ClauseTrace],
    epsilon: float,
    colours: Mapping[str, Any] | None = None,
) -> None:
    """Colour means vehicle here as in every panel: a clause about one vehicle is drawn in
    that vehicle's colour, one about several in black; line styles tell apart the clauses of
    one colour; the clauses beyond the weakest :data:`MAX_COLOURED_CLAUSES` are thin grey."""
    from matplotlib.lines import Line2D

    colours = colours or {}
    order = sorted(range(len(traces)), key=lambda i: traces[i].robustness)
    coloured = set(order[:MAX_COLOURED_CLAUSES])
    handles = []
    used: dict[Any, int] = {}
    grey_min = math.inf
    for i in order:
        tr = traces[i]
        style: Any = "-"
        if i in coloured:
            colour = colours.get(tr.vehicles[0], "k") if len(tr.vehicles) == 1 else "k"
            key = colour if isinstance(colour, str) else tuple(colour)
            style = _CLAUSE_STYLES[used.get(key, 0) % len(_CLAUSE_STYLES)]
            used[key] = used.get(key, 0) + 1
            lw, alpha = 1.3, 1.0
            flown = "" if tr.flown_robustness is None else f" (flown {tr.flown_robustness:+.3f})"
            label = f"{tr.robustness:+.3f}{flown}  {_short(tr.text)}"
            handles.append(Line2D([], [], color=colour, lw=lw, ls=style, label=label))
        else:
            colour, lw, alpha = "0.6", 0.8, 0.7
            grey_min = min(grey_min, tr.robustness)
        ax.plot(tr.t_s, tr.rho, color=colour, lw=lw, alpha=alpha, ls=style)
        ax.plot(
            [tr.witness_t_s],
            [tr.robustness],
            "o",
            color=colour,
            markersize=4.5 if i in coloured else 3,
            markeredgecolor="k",
            markeredgewidth=0.4,
        )
        if tr.flown_rho is not None:
            ax.plot(tr.t_s[: tr.flown_rho.size], tr.flown_rho, color=colour, lw=2.4, ls=style,
                    alpha=0.35)  # fmt: skip
    n_grey = len(traces) - len(coloured)
    if n_grey:
        handles.append(
            Line2D(
                [],
                [],
                color="0.6",
                lw=0.8,
                label=f"{n_grey} other clauses (each >= {grey_min:+.3f})",
            )
        )
    ax.axhline(0.0, color="k", lw=0.9)
    if epsilon > 0:
        ax.axhline(epsilon, color="k", lw=0.6, ls=":")
        handles.append(Line2D([], [], color="k", lw=0.6, ls=":", label=f"epsilon = {epsilon:g}"))
    handles.append(
        Line2D(
            [],
            [],
            color="k",
            marker="o",
            ls="",
            markersize=4,
            label="clause value (min/max over window)",
        )
    )
    if any(tr.flown_rho is not None for tr in traces):
        handles.append(
            Line2D([], [], color="k", lw=2.4, alpha=0.35, label="flown (telemetry): broad, faint")
        )
    # The band around zero decides the verdict: show the values of the coloured (weakest)
    # clauses with room above; curves far above (e.g. distances to far walls) run off the top.
    weakest = np.array([traces[i].robustness for i in order[:MAX_COLOURED_CLAUSES]], dtype=float)
    weakest = weakest[np.isfinite(weakest)]
    lo = min(float(weakest.min()) if weakest.size else 0.0, 0.0)
    top = max(float(weakest.max()) if weakest.size else 0.0, epsilon, 0.0)
    span = max(top - lo, 0.05)
    ax.set_ylim(lo - 0.3 * span, top + 0.9 * span)
    ax.set_xlabel("time t (s)", fontsize=8)
    ax.set_ylabel("robustness (m for spatial predicates)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)
    ax.set_title(
        "Clause robustness over time (always/eventually: the body; until: the option at t; "
        "dot = clause value)",
        fontsize=9,
    )
    legend_ax.axis("off")
    legend_ax.legend(
        handles=handles,
        loc="upper left",
        fontsize=7,
        ncol=1,
        frameon=False,
        title="clause robustness at t = 0, weakest first",
        title_fontsize=8,
        alignment="left",
    )


#: Flown velocities are differentiated over this window (s): telemetry positions carry
#: centimetres of noise that a sample-to-sample difference would turn into m/s.
_FLOWN_VEL_WINDOW_S = 0.25


def flown_velocity(path: FlownTrack) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(t, v)``: the flown velocity ``(m, 3)``, central differences over
    :data:`_FLOWN_VEL_WINDOW_S`, at the sample times whose window lies inside the track."""
    t = path.t_s
    if t.size < 3:
        return np.zeros(0), np.zeros((0, 3))
    half = _FLOWN_VEL_WINDOW_S / 2.0
    ok = (t - half >= t[0]) & (t + half <= t[-1])
    tc = t[ok]
    v = (path.position(tc + half) - path.position(tc - half)) / (2.0 * half)
    return tc, v


def _draw_kinematics(
    axes_v: Sequence[Any],
    axes_a: Sequence[Any],
    plan: Plan,
    colours: Sequence[Any],
    t: NDArray,
    telemetry: Telemetry | None = None,
) -> None:
    for v, c in zip(plan.vehicles, colours, strict=True):
        vel = v.trajectory.velocity(t)
        acc = v.trajectory.acceleration(t)
        for a in range(3):
            axes_v[a].plot(t, vel[:, a], color=c, lw=1.0, label=v.name)
            axes_a[a].plot(t, acc[:, a], color=c, lw=1.0, label=v.name)
        if telemetry is not None and v.name in telemetry.vehicles:
            tf, vf = flown_velocity(telemetry.vehicles[v.name])
            for a in range(3):
                axes_v[a].plot(tf, vf[:, a], color=c, lw=2.4, alpha=0.35)
    for a in range(3):
        for row, limits, unit, what in (
            (axes_v, {v.v_max_m_s[a] for v in plan.vehicles}, "m/s", "velocity"),
            (axes_a, {v.a_max_m_s2[a] for v in plan.vehicles}, "m/s²", "acceleration"),
        ):
            ax = row[a]
            for lim in sorted(limits):
                ax.axhline(lim, color="k", lw=0.8, ls="--")
                ax.axhline(-lim, color="k", lw=0.8, ls="--")
            ax.set_title(
                f"{what} {_AXES[a]} (limit ±{', '.join(f'{x:g}' for x in sorted(limits))} {unit})",
                fontsize=8,
            )
            ax.set_ylabel(unit, fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
            top = max(limits) * 1.15
            lo_data, hi_data = ax.get_ylim()
            ax.set_ylim(min(-top, lo_data), max(top, hi_data))
        axes_a[a].set_xlabel("time t (s)", fontsize=8)
    axes_v[0].legend(fontsize=6, ncol=min(4, len(plan.vehicles)), loc="upper right")


def tracking_error(plan: Plan, telemetry: Telemetry, t: NDArray) -> dict[str, tuple[NDArray, NDArray]]:  # fmt: skip
    """Per vehicle in the telemetry: ``(t, |flown - planned|)`` on the grid ``t``, where the
    telemetry covers it."""
    out = {}
    for v in plan.vehicles:
        path = telemetry.vehicles.get(v.name)
        if path is None or path.t_s.size == 0:
            continue
        tt = t[(t >= path.t_s[0]) & (t <= path.t_s[-1])]
        err = np.linalg.norm(path.position(tt) - v.trajectory.position(tt), axis=1)
        out[v.name] = (tt, err)
    return out


def _draw_tracking(ax: Any, plan: Plan, telemetry: Telemetry, colours: Sequence[Any], t: NDArray) -> None:  # fmt: skip
    by_name = dict(zip((v.name for v in plan.vehicles), colours, strict=True))
    for name, (tt, err) in tracking_error(plan, telemetry, t).items():
        ax.plot(tt, err, color=by_name[name], lw=1.1, label=f"{name} (max {err.max():.2f} m)")
    if plan.robustness > 0:
        ax.axhline(plan.robustness, color="k", lw=0.8, ls=":", label="the plan's margin")
    ax.set_title("Tracking error |flown - planned| (m)", fontsize=9)
    ax.set_xlabel("time t (s)", fontsize=8)
    ax.set_ylabel("m", fontsize=8)
    ax.set_ylim(bottom=0.0)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, ncol=min(4, len(plan.vehicles) + 1), loc="upper left")


def render_figure(
    plan: Plan,
    traces: Sequence[ClauseTrace],
    telemetry: Telemetry | None = None,
    dt_s: float | None = None,
    name: str | None = None,
    view: View | str = "auto",
) -> Figure:
    """The whole picture as a matplotlib Figure (Agg canvas; no screen needed).

    ``name`` titles it (default: the scenario's file stem); ``view`` (``auto``, ``3d`` or
    ``map``, :class:`gcs.plot.map_view.View`) picks the panel of regions and paths: the 3-D view
    or the top-down map (``auto``: :func:`gcs.plot.map_view.choose_view`).
    """
    import mpl_toolkits.mplot3d  # noqa: F401  (registers the 3-D projection)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from gcs.plot.map_view import View, choose_view, draw_map, map_aspect

    shown = choose_view(plan, view)
    t, dt = plan_grid(plan, dt_s)
    rows = 3 if telemetry is not None else 2
    aspect = map_aspect(plan, telemetry) if shown is View.MAP else 1.0
    if aspect >= WIDE_MAP_ASPECT:
        # a long strip: the map across the whole width (about 13.5 in of it beside its
        # legend), the robustness panels in a row beneath it
        map_h_in = min(max(13.5 / aspect + 1.0, 3.2), 6.5)
        fig = Figure(figsize=(16, map_h_in + 9.6), dpi=100, layout="constrained")
        gs = fig.add_gridspec(4, 3, height_ratios=[map_h_in, 4.2, 2.5, 2.5])
        ax_view = fig.add_subplot(gs[0, :])
        middle = gs[1, :].subgridspec(1, rows, width_ratios=[1.3, 1.0, 1.0][:rows])
        axr = fig.add_subplot(middle[0, 0])
        axl = fig.add_subplot(middle[0, rows - 1])
        ax_track = fig.add_subplot(middle[0, 1]) if telemetry is not None else None
        axes_v = [fig.add_subplot(gs[2, a]) for a in range(3)]
        axes_a = [fig.add_subplot(gs[3, a], sharex=axes_v[a]) for a in range(3)]
    else:
        fig = Figure(figsize=(16, 12.5), dpi=100, layout="constrained")
        gs = fig.add_gridspec(3, 3, height_ratios=[2.3, 1.0, 1.0])
        top = gs[0, :].subgridspec(1, 2, width_ratios=[1.2, 1.0])
        ratios = [2.0, 1.0, 1.0] if telemetry is not None else [2.0, 1.0]
        right = top[0, 1].subgridspec(rows, 1, height_ratios=ratios)
        projection = "3d" if shown is View.THREE_D else None
        ax_view = fig.add_subplot(top[0, 0], projection=projection)
        axr = fig.add_subplot(right[0, 0])
        axl = fig.add_subplot(right[rows - 1, 0])
        ax_track = fig.add_subplot(right[1, 0]) if telemetry is not None else None
        axes_v = [fig.add_subplot(gs[1, a]) for a in range(3)]
        axes_a = [fig.add_subplot(gs[2, a], sharex=axes_v[a]) for a in range(3)]
    FigureCanvasAgg(fig)
    colours = vehicle_colours(len(plan.vehicles))
    if shown is View.MAP:
        draw_map(ax_view, plan, telemetry, colours, t)
    else:
        _draw_3d(ax_view, plan, telemetry, colours, t)
    by_name = dict(zip((v.name for v in plan.vehicles), colours, strict=True))
    _draw_robustness(axr, axl, traces, plan.epsilon, by_name)
    if ax_track is not None and telemetry is not None:
        _draw_tracking(ax_track, plan, telemetry, colours, t)
    _draw_kinematics(axes_v, axes_a, plan, colours, t, telemetry)
    rho = min((tr.robustness for tr in traces), default=math.nan)
    status = plan.status.split(":")[0].strip()  # the outcome in words (solver_runs.user_status)
    title = fig.suptitle(
        f"{name or Path(plan.scenario).stem}: {len(plan.vehicles)} vehicle(s), horizon {plan.horizon_s:g} s"
        f" | spec robustness {rho:+.4f} (exact, dt {dt:g} s; epsilon {plan.epsilon:g})"
        f" | planner: {status}",
        fontsize=12,
    )
    fit_titles(fig, title)
    return fig


#: A map at least this many times wider than tall gets the figure's whole top row.
WIDE_MAP_ASPECT = 2.0
#: The figure's title keeps this far (px) from the figure's edges.
_TITLE_MARGIN_PX = 10.0
#: What a title is broken at first: the sections of the figure's title.
_TITLE_SEPARATOR = " | "


def wrap_to_width(text: str, width_px: float, measure: Callable[[str], float]) -> str:
    """``text`` broken onto lines each at most ``width_px`` wide (``measure(line)``: its width
    in px): at ``" | "`` (the separator dropped) where a section fits on a line of its own,
    else between words, else (one word wider than the line) between characters. Lines it
    already has are kept; a text that fits is returned as it is."""
    out: list[str] = []
    for line in text.split("\n"):
        if measure(line) <= width_px:
            out.append(line)
            continue
        current = ""
        for section in line.split(_TITLE_SEPARATOR):
            joined = f"{current}{_TITLE_SEPARATOR}{section}" if current else section
            if measure(joined) <= width_px:
                current = joined
                continue
            if current:
                out.append(current)
            current = ""
            for word in section.split(" "):
                joined = f"{current} {word}" if current else word
                if measure(joined) <= width_px:
                    current = joined
                    continue
                if current:
                    out.append(current)
                current = ""
                for ch in word:  # a word wider than the line (a long file name)
                    if current and measure(current + ch) > width_px:
                        out.append(current)
                        current = ""
                    current += ch
        out.append(current)
    return "\n".join(out)


def fit_titles(fig: Figure, title: Text | None = None) -> None:
    """Break the figure's ``title`` (what ``fig.suptitle`` returned) onto further lines
    (:func:`wrap_to_width`) where it is wider than the figure less :data:`_TITLE_MARGIN_PX`
    either side, and every axes' title where it is wider than its axes: nothing is cut off
    at an edge or runs into the next panel. The layout is computed once to know the axes'
    widths; the constrained layout makes room for the added lines when the figure is
    drawn (``fig``: on an Agg canvas)."""
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]

    def fit(text: Text, width_px: float) -> None:
        whole = text.get_text()
        if not whole:
            return

        def measure(s: str) -> float:
            text.set_text(s)
            return float(text.get_window_extent(renderer).width)

        text.set_text(wrap_to_width(whole, width_px, measure))

    if title is not None:
        fit(title, fig.bbox.width - 2.0 * _TITLE_MARGIN_PX)
    engine = fig.get_layout_engine()
    if engine is not None:  # the layout alone (no drawing): the axes' widths
        engine.execute(fig)
    for ax in fig.axes:
        box = ax.get_position().transformed(fig.transFigure)
        fit(ax.title, max(box.width, 50.0))


def figure_png(fig: Figure) -> bytes:
    """The figure as PNG bytes."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()
