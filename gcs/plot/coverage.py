"""What the pictures of a flight cover: per inspection target, covered or not, and from where.

The targets are those of the spec's facing rules (:func:`planner.spec.heading.facing_rules`:
``face(d, T)`` with the place ``d`` must be in, and the window if any).  A picture
(:class:`mavlink.link.camera.CapturedImage`, from the camera's CAMERA_IMAGE_CAPTURED) *counts*
for a rule's target when

* the rule's vehicle took it, within the rule's window (if any);
* from within the rule's place, ``place_tolerance_m`` allowed (the place is the
  inspection box: the stand-off the spec asks for);
* its optical axis (the camera's attitude ``q``: the vehicle's heading and the gimbal's
  angles) is within ``view_tolerance_deg`` of the line to the aim point (the target's axis
  at the camera's height, clamped to the target's heights: :func:`planner.spec.captures.aim_point`),
  by default ``face``'s own tolerance.

A target is *covered* when at least one picture counts for it.  Each target's row gives the
pictures that count, the planned ones (the mission's or the offboard schedule's count), and
the range and view angle of its counting pictures (or of the nearest miss, to say why it is
not covered).  :func:`coverage_lines` prints the table, :func:`coverage_json` its JSON and
:func:`coverage_figure` draws the line from above with every picture's position and view
wedge (the camera's horizontal field of view, out to the range of its target).

A room of its own because it joins the plan (targets, places) and the camera's log; it
speaks to no vehicle (``gcs fly`` and ``gcs verify --images`` call it).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gcs.checks import Check
from gcs.plot.figure import KIND_STYLE, is_large
from mavlink.link.camera import CameraInfo, CapturedImage
from planner.planfile import plan_formula
from planner.spec.captures import aim_point
from planner.spec.cover import drawn_regions
from planner.spec.heading import facing_rules
from planner.spec.predicates import face_tolerance_deg

if TYPE_CHECKING:
    from planner.planfile import Plan

__all__ = [
    "PLACE_TOLERANCE_M",
    "CoverageReport",
    "ImageView",
    "TargetCoverage",
    "compute_coverage",
    "coverage_checks",
    "coverage_figure",
    "coverage_json",
    "coverage_lines",
]

#: How far outside the inspection place a picture still counts (m).
PLACE_TOLERANCE_M = 0.5


@dataclass(frozen=True, slots=True)
class ImageView:
    """One picture seen from one target.

    Attributes:
        image: the picture.
        target: the target's name.
        range_m: distance from the camera to the aim point.
        view_deg: angle between the optical axis and the line to the aim point.
        place_margin_m: the picture's position's margin in the rule's place (>= 0 inside;
            ``inf`` for a rule without a place).
        counts: it counts for the target (module docstring).
    """

    image: CapturedImage
    target: str
    range_m: float
    view_deg: float
    place_margin_m: float
    counts: bool


@dataclass(frozen=True, slots=True)
class TargetCoverage:
    """One inspection target's coverage.

    Attributes:
        target: its name; vehicles: the vehicles asked to picture it.
        images: pictures that count for it; planned: pictures planned of it (``None``: not
            known).
        views: the counting pictures' views, or (uncovered) the nearest miss alone.
    """

    target: str
    vehicles: tuple[str, ...]
    images: int
    planned: int | None
    views: tuple[ImageView, ...]

    @property
    def covered(self) -> bool:
        return self.images > 0

    @property
    def range_m(self) -> tuple[float, float] | None:
        """Smallest and largest range of the counting pictures (``None``: none)."""
        r = [v.range_m for v in self.views if v.counts]
        return (min(r), max(r)) if r else None

    @property
    def view_deg(self) -> float | None:
        """Largest view angle of the counting pictures (``None``: none)."""
        a = [v.view_deg for v in self.views if v.counts]
        return max(a) if a else None


@dataclass(frozen=True, slots=True)
class CoverageReport:
    """The coverage of every inspection target of a plan by a flight's pictures.

    Attributes:
        targets: per target, in spec order.
        images: pictures taken (all vehicles); unmatched: those counting for no target.
        view_tolerance_deg, place_tolerance_m: what a picture had to meet.
        cameras: the optics per vehicle, where CAMERA_INFORMATION came.
    """

    targets: tuple[TargetCoverage, ...]
    images: int
    unmatched: int
    view_tolerance_deg: float
    place_tolerance_m: float
    cameras: Mapping[str, CameraInfo]

    @property
    def covered(self) -> int:
        return sum(t.covered for t in self.targets)

    @property
    def all_covered(self) -> bool:
        return bool(self.targets) and all(t.covered for t in self.targets)


def _view(image: CapturedImage, target: Any, where: Any, origin: Any) -> tuple[float, float, float]:
    """(range, view angle, place margin) of ``image`` seen from ``target``."""

    pos = image.position_enu_m(origin)
    aim = aim_point(target, pos)[0]
    d = aim - pos
    rng = float(np.linalg.norm(d))
    axis = image.axis_enu()
    if rng > 0 and np.all(np.isfinite(axis)):
        c = float(np.dot(axis, d) / (rng * np.linalg.norm(axis)))
        view = math.degrees(math.acos(max(-1.0, min(1.0, c))))
    else:
        view = math.nan
    margin = math.inf
    if where is not None:
        margin = float(np.min(where.b - where.A @ pos))
    return rng, view, margin


def compute_coverage(
    plan: Plan,
    images: Mapping[str, Sequence[CapturedImage]],
    *,
    planned: Mapping[str, int] | None = None,
    cameras: Mapping[str, CameraInfo] | None = None,
    view_tolerance_deg: float | None = None,
    place_tolerance_m: float = PLACE_TOLERANCE_M,
    window_slack_s: float = 1.0,
) -> CoverageReport:
    """The coverage of ``plan``'s inspection targets by ``images`` (module docstring).

    Args:
        images: the pictures per vehicle name (any order).
        planned: pictures planned per target (``None``: not known).
        cameras: the optics per vehicle (for the figure).
        view_tolerance_deg: largest view angle that counts (default ``face``'s tolerance).
        place_tolerance_m: how far outside the place a picture still counts.
        window_slack_s: how far outside a rule's window a picture still counts.
    """

    tol = face_tolerance_deg(plan) if view_tolerance_deg is None else float(view_tolerance_deg)
    rules = facing_rules(plan_formula(plan), plan)
    order: list[str] = []
    by_target: dict[str, list[Any]] = {}
    for r in rules:
        if r.target not in by_target:
            order.append(r.target)
        by_target.setdefault(r.target, []).append(r)
    counted: set[tuple[str, int, int]] = set()
    rows = []
    for target in order:
        region = plan.region(target)
        views: list[ImageView] = []
        for r in by_target[target]:
            for im in images.get(r.vehicle, ()):
                if not im.ok:
                    continue
                rng, view, margin = _view(im, region, r.where, plan.origin)
                in_window = r.window_s is None or (
                    r.window_s[0] - window_slack_s <= im.t_s <= r.window_s[1] + window_slack_s
                )
                counts = (
                    in_window
                    and margin >= -place_tolerance_m
                    and math.isfinite(view)
                    and view <= tol
                )
                views.append(ImageView(im, target, rng, view, margin, counts))
        good = [v for v in views if v.counts]
        for v in good:
            counted.add((v.image.vehicle, v.image.component, v.image.index))
        if good:
            shown = tuple(sorted(good, key=lambda v: v.image.t_s))
        elif views:
            shown = (min(views, key=lambda v: (max(0.0, -v.place_margin_m), v.view_deg)),)
        else:
            shown = ()
        rows.append(
            TargetCoverage(
                target=target,
                vehicles=tuple(dict.fromkeys(r.vehicle for r in by_target[target])),
                images=len(good),
                planned=None if planned is None else int(planned.get(target, 0)),
                views=shown,
            )
        )
    total = sum(1 for ims in images.values() for im in ims)
    unmatched = sum(
        1
        for ims in images.values()
        for im in ims
        if (im.vehicle, im.component, im.index) not in counted
    )
    return CoverageReport(
        targets=tuple(rows),
        images=total,
        unmatched=unmatched,
        view_tolerance_deg=tol,
        place_tolerance_m=place_tolerance_m,
        cameras=dict(cameras or {}),
    )


def _why_not(t: TargetCoverage, tol: float, place_tol: float) -> str:
    if not t.views:
        return "no picture by " + ", ".join(t.vehicles)
    v = t.views[0]
    why = []
    if v.place_margin_m < -place_tol:
        why.append(f"{-v.place_margin_m:.2f} m outside the inspection place")
    if not (v.view_deg <= tol):
        why.append(f"view {v.view_deg:.1f} deg > {tol:g}")
    return "nearest: " + ("; ".join(why) if why else "outside the rule's window")


def coverage_lines(report: CoverageReport) -> list[str]:
    """The coverage table, one line per target, and a summary line."""
    n = len(report.targets)
    out = [
        f"coverage: {report.covered}/{n} inspection targets pictured "
        f"({report.images} pictures, {report.unmatched} of no target; a picture counts from "
        f"within {report.place_tolerance_m:g} m of the inspection place, view within "
        f"{report.view_tolerance_deg:g} deg)"
    ]
    for t in report.targets:
        planned = "" if t.planned is None else f" of {t.planned} planned"
        if t.covered:
            lo, hi = t.range_m or (math.nan, math.nan)
            out.append(
                f"  {t.target:<10} covered   {t.images:3d} pictures{planned}, range "
                f"{lo:.2f}-{hi:.2f} m, view <= {t.view_deg:.1f} deg ({', '.join(t.vehicles)})"
            )
        else:
            out.append(
                f"  {t.target:<10} NOT covered: 0 pictures{planned} "
                f"({_why_not(t, report.view_tolerance_deg, report.place_tolerance_m)})"
            )
    return out


def coverage_checks(report: CoverageReport) -> list[Any]:
    """One :class:`gcs.checks.Check` per target: pictured at least once (``gcs verify``)."""

    out = []
    for t in report.targets:
        if t.covered:
            lo, hi = t.range_m or (math.nan, math.nan)
            detail = f"range {lo:.2f}-{hi:.2f} m, view <= {t.view_deg:.1f} deg"
        else:
            detail = _why_not(t, report.view_tolerance_deg, report.place_tolerance_m)
        out.append(Check(f"pictures of {t.target}", float(t.images), 1.0, t.covered, detail))
    return out


def coverage_json(report: CoverageReport) -> dict[str, Any]:
    """The report as JSON-ready values."""

    def num(x: float | None) -> float | None:
        return None if x is None or not math.isfinite(x) else round(float(x), 4)

    return {
        "covered": report.covered,
        "targets": len(report.targets),
        "images": report.images,
        "unmatched": report.unmatched,
        "view_tolerance_deg": report.view_tolerance_deg,
        "place_tolerance_m": report.place_tolerance_m,
        "by_target": [
            {
                "target": t.target,
                "vehicles": list(t.vehicles),
                "covered": t.covered,
                "images": t.images,
                "planned": t.planned,
                "range_m": None if t.range_m is None else [num(x) for x in t.range_m],
                "view_deg": num(t.view_deg),
            }
            for t in report.targets
        ],
    }


def _draw_regions_xy(ax: Any, plan: Plan) -> None:
    """The regions' footprints from above (poles grey, inspection places green, keep-outs red
    outlines where large), the workspace left out."""
    from matplotlib.patches import Polygon

    for r in drawn_regions(plan.regions):
        kind = r.kind.value
        face, alpha, edge, _ = KIND_STYLE.get(kind, KIND_STYLE["region"])
        big = is_large(r, plan.workspace)
        ax.add_patch(
            Polygon(
                r.footprint_xy(),
                closed=True,
                facecolor="none" if big else face,
                alpha=None if big else alpha,
                edgecolor=edge,
                linewidth=0.6,
            )
        )


@dataclass(frozen=True, slots=True)
class _Shot:
    """One picture as drawn: where, which way (ENU degrees from east), how far, whether it
    counts."""

    x: float
    y: float
    heading_deg: float
    reach_m: float
    hfov_deg: float
    counts: bool


def _shots(
    plan: Plan, report: CoverageReport, images: Mapping[str, Sequence[CapturedImage]]
) -> list[_Shot]:
    views = {
        (v.image.vehicle, v.image.component, v.image.index): v
        for t in report.targets
        for v in t.views
    }
    out = []
    for name, ims in images.items():
        info = report.cameras.get(name)
        hfov = info.hfov_deg if info is not None and math.isfinite(info.hfov_deg) else 60.0
        for im in ims:
            at = im.position_enu_m(plan.origin)
            yaw_deg, _ = im.yaw_pitch_deg()
            v = views.get((im.vehicle, im.component, im.index))
            out.append(
                _Shot(
                    float(at[0]),
                    float(at[1]),
                    90.0 - yaw_deg,  # compass -> ENU angle from east
                    v.range_m if v is not None else 3.0,
                    hfov,
                    v is not None and v.counts,
                )
            )
    return out


def _draw_shots(ax: Any, shots: Sequence[_Shot]) -> None:
    """Each picture's view wedge (green: it counts, grey: it does not) and position."""
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Wedge

    for counts, colour, alpha in ((False, "#9a9a9a", 0.22), (True, "#2ca02c", 0.16)):
        wedges = [
            Wedge(
                (s.x, s.y),
                s.reach_m,
                s.heading_deg - s.hfov_deg / 2,
                s.heading_deg + s.hfov_deg / 2,
            )
            for s in shots
            if s.counts is counts
        ]
        if wedges:
            ax.add_collection(
                PatchCollection(wedges, facecolor=colour, edgecolor="none", alpha=alpha),
                autolim=False,
            )
    if shots:
        ax.scatter(
            [s.x for s in shots],
            [s.y for s in shots],
            s=5,
            c=["#1a701a" if s.counts else "#6f6f6f" for s in shots],
            zorder=3,
        )


def coverage_figure(
    plan: Plan,
    report: CoverageReport,
    images: Mapping[str, Sequence[CapturedImage]],
    path: str | Path,
    max_panels: int = 12,
) -> Path:
    """Draw the pictures over the line from above (module docstring); returns the path.

    Left, the whole line: the regions' footprints (poles grey, inspection places green,
    conductor corridors and keep-outs), every picture's position and view wedge (the camera's
    horizontal field of view, 60 degrees where the camera gave none, out to its target's
    range; green where it counts, grey where not) and each target's count of counting over
    planned pictures.  Right, one panel per target (the first ``max_panels``), centred on it:
    the same, close enough to see which way each picture looked.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    shots = _shots(plan, report, images)
    n = min(len(report.targets), max_panels)
    fig = Figure(figsize=(15, 8), layout="constrained")
    subs: Any = fig.subfigures(1, 2, width_ratios=[1.0, 1.25] if n else [1.0, 0.01])
    left, right = subs[0], subs[1]
    ax = left.add_subplot(1, 1, 1)
    ax.set_aspect("equal")
    _draw_regions_xy(ax, plan)
    _draw_shots(ax, shots)
    pts = [plan.region(t.target).center_enu_m[:2] for t in report.targets]
    pts += [np.array([s.x, s.y]) for s in shots]
    ws = plan.workspace
    if pts:
        xy = np.asarray(pts)
        lo = np.maximum(xy.min(axis=0) - 10.0, np.asarray(ws.lo_enu_m[:2]))
        hi = np.minimum(xy.max(axis=0) + 10.0, np.asarray(ws.hi_enu_m[:2]))
    else:
        lo, hi = np.asarray(ws.lo_enu_m[:2]), np.asarray(ws.hi_enu_m[:2])
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    for t in report.targets:
        c = plan.region(t.target).center_enu_m
        label = f"{t.target}: {t.images}" + ("" if t.planned is None else f"/{t.planned}")
        ax.annotate(
            label,
            (c[0], c[1]),
            xytext=(6, -10),
            textcoords="offset points",
            fontsize=7,
            color="#1a701a" if t.covered else "#d62728",
        )
    ax.set_xlabel("east x (m)")
    ax.set_ylabel("north y (m)")
    ax.set_title(
        f"pictures and coverage: {report.covered}/{len(report.targets)} targets covered, "
        f"{report.images} pictures ({report.unmatched} of no target)",
        fontsize=10,
    )
    if n:
        cols = math.ceil(math.sqrt(n * 1.25))
        rows = math.ceil(n / cols)
        for k, t in enumerate(report.targets[:n]):
            sub = right.add_subplot(rows, cols, k + 1)
            sub.set_aspect("equal")
            _draw_regions_xy(sub, plan)
            _draw_shots(sub, shots)
            c = plan.region(t.target).center_enu_m
            reach = max([v.range_m for v in t.views] + [4.0]) + 2.0
            sub.set_xlim(c[0] - reach, c[0] + reach)
            sub.set_ylim(c[1] - reach, c[1] + reach)
            planned = "" if t.planned is None else f" of {t.planned}"
            sub.set_title(
                f"{t.target} ({', '.join(t.vehicles)}): {t.images}{planned}",
                fontsize=8,
                color="#1a701a" if t.covered else "#d62728",
            )
            sub.tick_params(labelsize=6)
    p = Path(path)
    fig.savefig(p, dpi=110)
    return p
