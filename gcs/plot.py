"""Pictures of a plan: regions and paths in 3-D, clause robustness over time, kinematics.

Everything :func:`plot_plan` draws is computed from the plan's stored ``segments`` (the source
of truth ``gcs verify`` uses too) and, when given, the flown telemetry:

* **3-D view**: every region box of the plan drawn by kind (obstacles and no-fly zones red,
  inspection boxes and goals green, poles grey, conductor corridors orange, other regions
  blue, the workspace as a dashed outline), each vehicle's path with a start (o) and end
  (square) marker; flown paths dashed over the planned ones when telemetry is given.
* **Robustness over time** of every top-level clause of the spec, exact semantics
  (:mod:`planner.stl`) on the dense grid ``t = 0, dt, ..., horizon`` (``dt`` the plan's
  ``check_dt_s``). For a clause ``always[a,b] body`` or ``eventually[a,b] body`` the curve is
  the trace of ``body``: the clause's value is its minimum (maximum) over ``[a, b]``, marked
  with a dot, so the picture shows *when* the margin is small. Any other clause is drawn as
  its own trace (defined while its horizon fits in the plan). A zero line separates
  satisfaction from violation; with many clauses the weakest ones get colours and the rest
  one grey style.
* **Per-axis velocity and acceleration** (east, north, up) of every vehicle against its
  per-axis limits ``v_max`` / ``a_max`` (dashed).

Outputs: a PNG, or a self-contained HTML page (the PNG embedded as base64 and a table of the
clause robustness, planned and flown).

Telemetry (``--telemetry``): a CSV file with a header line and at least the columns
``t,vehicle,x,y,z``: time in seconds from the plan's start, the vehicle name of the plan,
position in the mission ENU frame in metres (extra columns are ignored); the link's track CSV
(:func:`mavlink.tlog.write_tracks_csv`: ``vehicle,t_s,x_enu_m,y_enu_m,z_enu_m,...``) is read
alike. A ``.tlog`` goes through :func:`mavlink.tlog.tracks_from_tlog`; since a tlog does not
record when the plan started, its Unix start time must be given (``--t0``). Flown robustness is
evaluated on the same grid, positions linearly interpolated between telemetry samples and
held before the first and after the last sample of each vehicle (the table says how much of
the horizon the telemetry covers).

Errors::

    gcs.errors.InputFileError        unreadable/malformed telemetry (file, line, column), telemetry
                                     without any vehicle of the plan, a bad output path or --dt
    planner.planfile.PlanFileError   a spec that does not parse, or a clause that cannot be
                                     evaluated on the plan (e.g. longer than its horizon)
    mavlink.errors.LinkError         a .tlog the link's reader rejects (no origin message)
"""

from __future__ import annotations

import base64
import csv
import html
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from gcs.errors import InputFileError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from planner.planfile import Plan
    from planner.stl import Formula

__all__ = [
    "TELEMETRY_COLUMNS",
    "ClauseTrace",
    "FlownPath",
    "PlotResult",
    "Telemetry",
    "clause_traces",
    "figure_png",
    "html_report",
    "load_telemetry",
    "plan_grid",
    "plot_plan",
    "render_figure",
]

#: Columns a telemetry CSV must have (more are allowed).
TELEMETRY_COLUMNS = ("t", "vehicle", "x", "y", "z")

#: Accepted names of those columns: ours, and the link's track CSV (:mod:`mavlink.tlog`).
_TELEMETRY_ALIASES: dict[str, tuple[str, ...]] = {
    "t": ("t", "t_s"),
    "vehicle": ("vehicle",),
    "x": ("x", "x_enu_m"),
    "y": ("y", "y_enu_m"),
    "z": ("z", "z_enu_m"),
}

#: At most this many clauses get their own colour and legend entry; the rest are grey.
MAX_COLOURED_CLAUSES = 8

_AXES = ("east x", "north y", "up z")


# ----------------------------------------------------------------------------- telemetry


@dataclass(frozen=True, slots=True, eq=False)
class FlownPath:
    """One vehicle's recorded positions.

    Attributes:
        t_s: ``(n,)`` non-decreasing seconds from the plan's start.
        pos_enu_m: ``(n, 3)`` mission-frame ENU positions in m.
    """

    t_s: NDArray[np.float64]
    pos_enu_m: NDArray[np.float64]

    def position(self, t_s: NDArray[np.float64]) -> NDArray[np.float64]:
        """Positions ``(m, 3)`` at times ``t_s`` ``(m,)``: linear between samples, held outside."""
        return np.column_stack([np.interp(t_s, self.t_s, self.pos_enu_m[:, a]) for a in range(3)])


@dataclass(frozen=True, slots=True)
class Telemetry:
    """Flown paths by vehicle name, read from ``source``."""

    source: str
    vehicles: Mapping[str, FlownPath]


def _column_map(header: list[str]) -> dict[str, int] | None:
    """Index of t, vehicle, x, y, z in either CSV layout (None if a column is missing)."""
    out = {}
    for key, names in _TELEMETRY_ALIASES.items():
        idx = next((header.index(n) for n in names if n in header), None)
        if idx is None:
            return None
        out[key] = idx
    return out


def load_telemetry(
    path: str | Path, plan: Plan | None = None, t0_unix_s: float | None = None
) -> Telemetry:
    """Read flown telemetry (module docstring); CSV rows may come in any order.

    Args:
        path: a CSV file (either layout) or a ``.tlog``.
        plan: the plan flown (needed for a ``.tlog``: vehicle names by system id, origin).
        t0_unix_s: Unix time of the plan's start (needed for a ``.tlog``, which does not
            record it).

    Raises:
        InputFileError: missing file, missing columns, a bad number (names file, line, column),
            no rows, a ``.tlog`` without ``t0_unix_s``.
        mavlink.errors.LinkError: a ``.tlog`` the link's reader rejects.
    """
    p = Path(path)
    src = str(p)
    if p.suffix.lower() == ".tlog":
        return _load_tlog(p, plan, t0_unix_s)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputFileError(f"{src}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise InputFileError(f"{src}: not a text (CSV) file") from None
    reader = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise InputFileError(f"{src}: empty file (expected a header t,vehicle,x,y,z)") from None
    col = _column_map(header)
    if col is None:
        missing = [k for k, names in _TELEMETRY_ALIASES.items() if not set(names) & set(header)]
        raise InputFileError(
            f"{src}: line 1: missing column(s) {', '.join(missing)} "
            f"(need {','.join(TELEMETRY_COLUMNS)}, or the link's vehicle,t_s,x_enu_m,...)"
        )
    rows: dict[str, list[tuple[float, float, float, float]]] = {}
    for lineno, row in enumerate(reader, start=2):
        if not row or all(not f.strip() for f in row):
            continue
        if len(row) < len(header):
            raise InputFileError(
                f"{src}: line {lineno}: {len(row)} fields, the header has {len(header)}"
            )
        vals = []
        for key in ("t", "x", "y", "z"):
            field = row[col[key]].strip()
            try:
                v = float(field)
            except ValueError:
                raise InputFileError(
                    f"{src}: line {lineno}: column {header[col[key]]}: not a number: {field!r}"
                ) from None
            if not math.isfinite(v):
                raise InputFileError(
                    f"{src}: line {lineno}: column {header[col[key]]}: must be finite"
                )
            vals.append(v)
        name = row[col["vehicle"]].strip()
        if not name:
            raise InputFileError(f"{src}: line {lineno}: column vehicle: empty")
        rows.setdefault(name, []).append((vals[0], vals[1], vals[2], vals[3]))
    if not rows:
        raise InputFileError(f"{src}: no telemetry rows after the header")
    vehicles: dict[str, FlownPath] = {}
    for name, r in rows.items():
        a = np.asarray(r, dtype=float)
        a = a[np.argsort(a[:, 0], kind="stable")]
        vehicles[name] = FlownPath(t_s=a[:, 0], pos_enu_m=a[:, 1:4])
    return Telemetry(source=src, vehicles=vehicles)


def _load_tlog(p: Path, plan: Plan | None, t0_unix_s: float | None) -> Telemetry:
    """Tracks from a ``.tlog`` through the link's reader (:func:`mavlink.tlog.tracks_from_tlog`)."""
    if plan is None or t0_unix_s is None:
        raise InputFileError(
            f"{p}: a .tlog does not record when the plan started: give --t0 UNIX_SECONDS "
            "(or use the flight's CSV track file)"
        )
    if not p.is_file():
        raise InputFileError(f"{p}: cannot read: no such file")
    from mavlink.tlog import tracks_from_tlog

    tracks = tracks_from_tlog(
        p, {v.sysid: v.name for v in plan.vehicles}, plan.origin, float(t0_unix_s)
    )
    if not tracks:
        raise InputFileError(f"{p}: no LOCAL_POSITION_NED from the plan's vehicles")
    return Telemetry(
        source=str(p),
        vehicles={
            name: FlownPath(t_s=np.asarray(tr.t_s), pos_enu_m=np.asarray(tr.pos_enu_m))
            for name, tr in tracks.items()
        },
    )


# ----------------------------------------------------------------------------- robustness


@dataclass(frozen=True, slots=True, eq=False)
class ClauseTrace:
    """What the robustness panel draws for one top-level clause.

    Attributes:
        text: the clause as STL text.
        robustness: exact robustness of the clause at t = 0 on the planned paths.
        shown: ``"body"`` when the curve is the body of a top-level always/eventually,
            ``"until"`` for a top-level until (the curve whose maximum over ``[a, b]`` is
            the clause's value, NaN outside), else ``"clause"``.
        operator: ``"always"``, ``"eventually"``, ``"until"`` or ``""`` (``"clause"``).
        window_s: ``(a, b)`` of the top-level operator, else None.
        vehicles: the vehicles the clause reads (its colour: one vehicle's own, several black).
        t_s: ``(m,)`` times of the curve.
        rho: ``(m,)`` planned robustness of what is shown.
        witness_t_s: time where the clause value is attained on the curve (``t_s[0]`` for
            ``shown == "clause"``).
        flown_robustness: the clause on the flown paths (None without telemetry or when the
            telemetry lacks a vehicle the clause reads).
        flown_rho: ``(m,)`` flown counterpart of ``rho`` (or None).
    """

    text: str
    robustness: float
    shown: str
    operator: str
    window_s: tuple[float, float] | None
    t_s: NDArray[np.float64]
    rho: NDArray[np.float64]
    witness_t_s: float
    flown_robustness: float | None = None
    flown_rho: NDArray[np.float64] | None = None
    vehicles: tuple[str, ...] = ()


def plan_grid(plan: Plan, dt_s: float | None = None) -> tuple[NDArray[np.float64], float]:
    """The dense grid ``t = 0, dt, ..., horizon`` (s) and its ``dt`` (the plan's check step)."""
    dt = plan.check_dt_s if dt_s is None else float(dt_s)
    if not (math.isfinite(dt) and dt > 0):
        raise InputFileError(f"--dt: must be a positive number of seconds, got {dt_s!r}")
    n = round(plan.horizon_s / dt) + 1
    return np.arange(n) * dt, dt


def _curve(clause: Formula, signals: Mapping[str, Any], dt: float) -> tuple[str, NDArray]:
    """``("body", trace of the body)`` for a top-level always/eventually; for a top-level
    ``p until[a,b] q`` ``("until", c)`` with ``c(t') = min(q(t'), min over [0, t') of p)``
    on ``[a, b]`` (NaN elsewhere), whose maximum is the clause's value at t = 0; else the
    clause's own trace."""
    from planner.stl import Always, Eventually, Until

    if isinstance(clause, Always | Eventually):
        return "body", clause.child.robustness_trace(signals, dt)
    if isinstance(clause, Until):
        lo, hi = clause.steps(dt)
        q = clause.rhs.robustness_trace(signals, dt)[: hi + 1]
        p = clause.lhs.robustness_trace(signals, dt)[: hi + 1]
        before = np.concatenate([[np.inf], np.minimum.accumulate(p)[:-1]])  # min over [0, t')
        curve = np.full(hi + 1, np.nan)
        curve[lo:] = np.minimum(q[lo:], before[lo : hi + 1])
        return "until", curve
    return "clause", clause.robustness_trace(signals, dt)


def _witness(
    clause: Formula, rho: NDArray[np.float64], dt: float
) -> tuple[int, str, tuple[float, float] | None]:
    """Step of the curve where the clause value is attained, operator name, window (s).

    Only called once the clause itself evaluated, so its window lies inside ``rho``.
    """
    from planner.stl import Always, Eventually, Until

    if isinstance(clause, Always | Eventually):
        lo, hi = clause.steps(dt)
        pick = np.argmin if isinstance(clause, Always) else np.argmax
        k = lo + int(pick(rho[lo : hi + 1]))
        op = "always" if isinstance(clause, Always) else "eventually"
        return k, op, (clause.start_s, clause.end_s)
    if isinstance(clause, Until):
        lo, hi = clause.steps(dt)
        return lo + int(np.nanargmax(rho[lo : hi + 1])), "until", (clause.start_s, clause.end_s)
    return 0, "", None


def clause_traces(
    plan: Plan, telemetry: Telemetry | None = None, dt_s: float | None = None
) -> tuple[ClauseTrace, ...]:
    """Robustness curves of every top-level clause (see :class:`ClauseTrace`).

    The planned curves come from the trajectories' exact positions on :func:`plan_grid`; the
    flown ones from the telemetry on the same grid (module docstring).
    """
    from planner.planfile import plan_formula, spec_errors

    phi = plan_formula(plan)
    t, dt = plan_grid(plan, dt_s)
    planned = {v.name: v.trajectory.position(t) for v in plan.vehicles}
    flown: dict[str, NDArray[np.float64]] | None = None
    if telemetry is not None:
        known = {v.name for v in plan.vehicles}
        if not known & telemetry.vehicles.keys():
            raise InputFileError(
                f"{telemetry.source}: no vehicle of the plan in the telemetry (it has "
                f"{', '.join(sorted(telemetry.vehicles))}; the plan has {', '.join(sorted(known))})"
            )
        flown = {name: path.position(t) for name, path in telemetry.vehicles.items()}
    out: list[ClauseTrace] = []
    for i, clause in enumerate(phi.clauses):
        with spec_errors(plan, f"spec clause {i + 1} ({clause})"):
            # The clause's own value (planner.stl), which also rejects a plan too short for it.
            value = float(clause.robustness(planned, dt))
            shown, rho = _curve(clause, planned, dt)
            flown_value: float | None = None
            flown_rho: NDArray[np.float64] | None = None
            if flown is not None and clause.signal_names() <= flown.keys():
                _, flown_rho = _curve(clause, flown, dt)
                flown_value = float(clause.robustness(flown, dt))
        k, op, window = _witness(clause, rho, dt)
        out.append(
            ClauseTrace(
                text=str(clause),
                robustness=value,
                shown=shown,
                operator=op,
                window_s=window,
                t_s=t[: rho.size],
                rho=rho,
                witness_t_s=float(t[k]),
                flown_robustness=flown_value,
                flown_rho=flown_rho,
                vehicles=tuple(v.name for v in plan.vehicles if v.name in clause.signal_names()),
            )
        )
    return tuple(out)


# ----------------------------------------------------------------------------- drawing

#: Face colour, face alpha, edge colour and legend label of each region kind.
_KIND_STYLE: dict[str, tuple[str, float, str, str]] = {
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


def _vehicle_colours(n: int) -> list[Any]:
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
    """Whether ``region`` is drawn as an outline (see :data:`_LARGE_AREA`)."""
    span = np.asarray(region.hi_enu_m) - np.asarray(region.lo_enu_m)
    ws = np.asarray(workspace.hi_enu_m) - np.asarray(workspace.lo_enu_m)
    area = float(span[0] * span[1]) / max(float(ws[0] * ws[1]), 1e-12)
    return area > _LARGE_AREA or bool(np.any(span[:2] > _LARGE_SPAN * ws[:2]))


def _draw_regions(ax: Any, plan: Plan) -> list[Any]:
    """Draw the workspace outline and region boxes; returns legend handles (one per kind).

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
    ordered = sorted(plan.regions, key=lambda r: r.kind.value in _TARGET_KINDS)
    for r in ordered:
        face, alpha, edge, label = _KIND_STYLE.get(r.kind.value, _KIND_STYLE["region"])
        if is_large(r, ws):
            ax.add_collection3d(
                Line3DCollection(_box_edges(r.lo_enu_m, r.hi_enu_m), colors=edge, linewidths=1.1)
            )
            label = f"{label} (outline)"
            handles.setdefault(label, Line2D([], [], color=edge, lw=1.1, label=label))
        else:
            target = r.kind.value in _TARGET_KINDS
            poly = Poly3DCollection(
                _box_faces(r.lo_enu_m, r.hi_enu_m),
                facecolors=face,
                edgecolors=edge,
                linewidths=0.9 if target else 0.5,
                alpha=min(1.0, 1.6 * alpha) if target else alpha,
            )
            ax.add_collection3d(poly)
            handles.setdefault(label, Patch(facecolor=face, edgecolor=edge, alpha=0.5, label=label))
        top = (np.asarray(r.lo_enu_m) + np.asarray(r.hi_enu_m)) / 2.0
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


def flown_velocity(path: FlownPath) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
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
) -> Figure:
    """The whole picture as a matplotlib Figure (Agg canvas; no screen needed).

    ``name`` titles it (default: the scenario's file stem).
    """
    import mpl_toolkits.mplot3d  # noqa: F401  (registers the 3-D projection)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    t, _ = plan_grid(plan, dt_s)
    fig = Figure(figsize=(16, 12.5), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    gs = fig.add_gridspec(3, 3, height_ratios=[2.3, 1.0, 1.0])
    top = gs[0, :].subgridspec(1, 2, width_ratios=[1.2, 1.0])
    rows = 3 if telemetry is not None else 2
    ratios = [2.0, 1.0, 1.0] if telemetry is not None else [2.0, 1.0]
    right = top[0, 1].subgridspec(rows, 1, height_ratios=ratios)
    ax3 = fig.add_subplot(top[0, 0], projection="3d")
    axr = fig.add_subplot(right[0, 0])
    axl = fig.add_subplot(right[rows - 1, 0])
    axes_v = [fig.add_subplot(gs[1, a]) for a in range(3)]
    axes_a = [fig.add_subplot(gs[2, a], sharex=axes_v[a]) for a in range(3)]
    colours = _vehicle_colours(len(plan.vehicles))
    _draw_3d(ax3, plan, telemetry, colours, t)
    by_name = dict(zip((v.name for v in plan.vehicles), colours, strict=True))
    _draw_robustness(axr, axl, traces, plan.epsilon, by_name)
    if telemetry is not None:
        _draw_tracking(fig.add_subplot(right[1, 0]), plan, telemetry, colours, t)
    _draw_kinematics(axes_v, axes_a, plan, colours, t, telemetry)
    rho = min((tr.robustness for tr in traces), default=math.nan)
    _, dt = plan_grid(plan, dt_s)
    status = plan.status.split(":")[0].strip()  # the outcome in words (optimize._user_status)
    fig.suptitle(
        f"{name or Path(plan.scenario).stem}: {len(plan.vehicles)} vehicle(s), horizon {plan.horizon_s:g} s"
        f" | spec robustness {rho:+.4f} (exact, dt {dt:g} s; epsilon {plan.epsilon:g})"
        f" | planner: {status[:40]}",
        fontsize=12,
    )
    return fig


def figure_png(fig: Figure) -> bytes:
    """The figure as PNG bytes."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def _fmt(x: float | None) -> str:
    if x is None:
        return "n/a"
    return f"{x:+.4f}" if math.isfinite(x) else str(x)


def html_report(
    plan: Plan,
    traces: Sequence[ClauseTrace],
    png: bytes,
    telemetry: Telemetry | None = None,
    name: str | None = None,
) -> str:
    """A self-contained HTML page: the PNG (base64) and a table of clause robustness.

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
        parts = []
        for v in plan.vehicles:
            path = telemetry.vehicles.get(v.name)
            if path is None:
                parts.append(f"{esc(v.name)}: no telemetry")
            else:
                parts.append(
                    f"{esc(v.name)}: {path.t_s[0]:.2f}-{path.t_s[-1]:.2f} s ({path.t_s.size} samples)"
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
img {{ max-width: 100%; }}
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
<h2>Picture</h2>
<img alt="regions, paths, clause robustness and kinematics of the plan" src="data:image/png;base64,{png64}">
</body></html>
"""


@dataclass(frozen=True, slots=True)
class PlotResult:
    """What :func:`plot_plan` wrote."""

    path: Path
    traces: tuple[ClauseTrace, ...]


def plot_plan(
    plan: Plan,
    output: str | Path,
    telemetry: Telemetry | None = None,
    dt_s: float | None = None,
    name: str | None = None,
) -> PlotResult:
    """Draw ``plan`` to ``output`` (``.png`` or ``.html``), titled ``name`` (e.g. the plan file).

    Raises:
        InputFileError: another extension, or the file cannot be written.
    """
    out = Path(output)
    kind = out.suffix.lower()
    if kind not in (".png", ".html", ".htm"):
        raise InputFileError(f"{out}: output must end in .png or .html")
    traces = clause_traces(plan, telemetry, dt_s)
    fig = render_figure(plan, traces, telemetry, dt_s, name)
    png = figure_png(fig)
    data = (
        png if kind == ".png" else html_report(plan, traces, png, telemetry, name).encode("utf-8")
    )
    try:
        out.write_bytes(data)
    except OSError as exc:
        raise InputFileError(f"{out}: cannot write: {exc.strerror or exc}") from None
    return PlotResult(path=out, traces=traces)
