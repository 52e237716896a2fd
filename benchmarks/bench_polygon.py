"""Polygons that are not convex (issue 21's L-shaped right of way): the convex cover of
``planner/spec/cover.py`` and what it buys in planning.

1. The cover of each polygon: corners, reflex corners, parts, and the time to build it
   (median of ``--repeat``), and how much of a point's depth in the polygon the margin
   keeps (on the parts' edges inside it, where parts that only touched would keep 0; and
   over points drawn inside).
2. The L-shaped line of 8 poles (``powerline_lshape8_2drones``) planned cold by ``gcs plan``
   four ways, in turn (A B C D A B C D ...): within its bounding box only (the zoo's); inside
   its L-shaped right of way read as the cover (``powerline_lshape8_row_2drones``); the same
   right of way split by hand into two arms that only touch; and into two arms that overlap
   (what the cover makes).  Per way: plans met, robustness, the right of way's clause value
   and wall time.

Printed: two tables, then one JSON line.

    .venv/bin/python benchmarks/bench_polygon.py --runs 2
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_zoo import GCS, SCENARIOS, planner_version, run_one

from planner.spec.cover import convex_cover, polygon_regions, reflex_corners
from planner.spec.regions import RegionKind

L_SHAPE = [(-10, -16), (104, -16), (104, 130), (80, 130), (80, 8), (-10, 8)]
U_SHAPE = [(0, 0), (30, 0), (30, 30), (20, 30), (20, 10), (10, 10), (10, 30), (0, 30)]
COMB = [(0, 0), (90, 0), (90, 40)]
COMB += [c for i in range(4, 0, -1) for c in ((20 * i, 40), (20 * i, 10), (20 * i - 10, 10), (20 * i - 10, 40))]  # fmt: skip
COMB += [(0, 40)]


def _corridor(bends: int, width_m: float = 30.0, leg_m: float = 200.0) -> np.ndarray:
    """A right of way along a line that turns at each of ``bends`` angle poles, alternately
    left and right by 35-70 degrees: the line's buffer (shapely), its corners."""
    import shapely

    rng = np.random.default_rng(bends)
    heading, pts = 0.0, [np.zeros(2)]
    for k in range(bends + 1):
        pts.append(pts[-1] + leg_m * np.array([np.cos(heading), np.sin(heading)]))
        heading += (1 if k % 2 else -1) * np.radians(rng.uniform(35, 70))
    ring = shapely.LineString(pts).buffer(width_m / 2, cap_style="flat", join_style="mitre")
    return np.asarray(ring.exterior.coords)[:-1]


POLYGONS: dict[str, Any] = {
    "L right of way": np.asarray(L_SHAPE, float),
    "U": np.asarray(U_SHAPE, float),
    "comb of 4 bays": np.asarray(COMB, float),
    "corridor, 3 bends": _corridor(3),
    "corridor, 8 bends": _corridor(8),
}


def _depth_kept(corners: np.ndarray) -> tuple[float, float, float]:
    """How much of a point's depth in the polygon (its distance to the boundary) the union
    margin keeps: the least share on the parts' edges inside the polygon (1-99 % along each
    edge; a seam of parts that only touch would show 0), and the least and median share
    over 4000 points drawn inside.  All 1 for a convex polygon."""
    import shapely

    parts = polygon_regions("p", RegionKind.REGION, corners, 0.0, 1e4)
    poly = shapely.Polygon(corners)
    size = float(np.ptp(corners, axis=0).max())

    def share(pts: np.ndarray) -> np.ndarray:
        depth = shapely.distance(shapely.points(pts), poly.exterior)
        keep = (depth > 1e-6 * size) & shapely.contains(poly, shapely.points(pts))
        p3 = np.column_stack([pts[keep], np.full(int(keep.sum()), 5e3)])
        return np.max([r.margin(p3) for r in parts], axis=0) / depth[keep]

    t = np.linspace(0.01, 0.99, 99)
    edges = [
        a + t[:, None] * (b - a)
        for part in parts
        for a, b in zip(
            np.asarray(part.shape.vertices_xy),
            np.roll(np.asarray(part.shape.vertices_xy), -1, 0),
            strict=True,
        )
    ]
    seam = share(np.vstack(edges))
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    drawn = share(np.random.default_rng(0).uniform(lo, hi, (4000, 2)))
    least = float(seam.min()) if seam.size else 1.0
    return least, float(drawn.min()), float(np.median(drawn))


def _variants(tmp: Path) -> dict[str, Path]:
    row = (SCENARIOS / "powerline_lshape8_row_2drones.yaml").read_text(encoding="utf-8")
    line = row[row.index("\n  row: {") : row.index("\n  corridor_ew:")]

    def split(north_arm_from_y: float, name: str) -> Path:
        text = row.replace(
            line,
            "\n  row_ew: {kind: region, min: [-10, -16, 0.5], max: [104, 8, 20]}"
            f"\n  row_ns: {{kind: region, min: [80, {north_arm_from_y:g}, 0.5], max: [104, 130, 20]}}",
        ).replace("inside(d, row)", "(inside(d, row_ew) or inside(d, row_ns))")
        path = tmp / f"powerline_lshape8_{name}.yaml"
        path.write_text(text.replace("name: powerline_lshape8_row_2drones", f"name: {path.stem}"))
        return path

    return {
        "bounding box only": SCENARIOS / "powerline_lshape8_2drones.yaml",
        "L right of way (cover)": SCENARIOS / "powerline_lshape8_row_2drones.yaml",
        "L split by hand, touching": split(8, "row_touching"),
        "L split by hand, overlapping": split(-16, "row_overlapping"),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=2, help="runs of each planning way (default 2)")
    ap.add_argument("--repeat", type=int, default=5, help="cover builds per polygon (default 5)")
    ap.add_argument("--time-limit", type=float, default=120.0, help="gcs plan --time-limit")
    args = ap.parse_args(argv)
    out: dict[str, Any] = {"bench": "polygon", "planner": planner_version(), "runs": args.runs}

    print(f"{'polygon':<20} {'corners':>7} {'reflex':>6} {'parts':>5} {'cover ms':>9} "
          f"{'depth kept: seams min':>21} {'inside min':>10} {'median':>7}")  # fmt: skip
    covers: dict[str, Any] = {}
    for name, corners in POLYGONS.items():
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            parts = convex_cover(corners)
            times.append(1e3 * (time.perf_counter() - t0))
        seam, least, median = _depth_kept(corners)
        ms = statistics.median(times)
        print(f"{name:<20} {len(corners):>7} {len(reflex_corners(corners)):>6} {len(parts):>5} "
              f"{ms:>9.1f} {seam:>21.3f} {least:>10.3f} {median:>7.3f}")  # fmt: skip
        covers[name] = {"corners": len(corners), "reflex": len(reflex_corners(corners)),
                        "parts": len(parts), "cover_ms": ms, "seam_depth_kept_min": seam,
                        "depth_kept_min": least, "depth_kept_median": median}  # fmt: skip
    out["covers"] = covers

    with tempfile.TemporaryDirectory(prefix="bench-polygon-") as tmp:
        ways = _variants(Path(tmp))
        rows: dict[str, list[dict[str, Any]]] = {w: [] for w in ways}
        for _ in range(args.runs):
            for way, path in ways.items():
                rows[way].append(run_one(path, args.time_limit, GCS))
    print()
    print(
        f"{'planned':<30} {'met':>5} {'robustness':>10} {'wall s (median, min-max)':>26}  weakest"
    )
    plans: dict[str, Any] = {}
    for way, rs in rows.items():
        walls = [r["wall_s"] for r in rs]
        met = sum(bool(r["solved"]) for r in rs)
        rho = [r.get("robustness") for r in rs]
        med = statistics.median(walls)
        rho_txt = "/".join(
            f"{x:+.3f}" if isinstance(x, int | float) else "?" for x in dict.fromkeys(rho)
        )
        weakest = rs[-1].get("weakest") or "?"
        print(f"{way:<30} {met:>2}/{len(rs):<2} {rho_txt:>10} "
              f"{f'{med:.1f} ({min(walls):.1f}-{max(walls):.1f})':>26}  {weakest[:60]}")  # fmt: skip
        plans[way] = {"met": met, "runs": len(rs), "robustness": rho, "wall_s": walls,
                      "wall_median_s": med, "weakest": weakest}  # fmt: skip
    out["plans"] = plans
    print(json.dumps(out))
    good = ("bounding box only", "L right of way (cover)", "L split by hand, overlapping")
    return 0 if all(plans[w]["met"] == plans[w]["runs"] for w in good) else 1


if __name__ == "__main__":
    sys.exit(main())
