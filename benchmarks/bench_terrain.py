"""Terrain (issue 44): the hillside line planned over its elevation model and flown on the mock.

Two cases: ``configs/powerline_hillside.yaml`` (5 poles on a hillside, 2 drones, ``min_agl_m``
3 over ``configs/hillside_dem.tif``, a UTM GeoTIFF), and a ridge written here (a 14 m ridge
across the way of one drone to a goal 80 m off, ``min_agl_m`` 3: the floor binds on the
crest). Each:

1. reading: the scenario loaded (the GeoTIFF sampled onto the mission grid), its size;
2. planning (cold, in this process): time, robustness, and the least height above the ground
   along each planned path (dense samples, 0.02 s; the ground bilinear on the grid the plan
   carries, computed here by hand);
3. flying: ``gcs fly --dry-run`` on the px4 mock at ``--speed`` (default 4): exit status,
   flown robustness, and the least height above the ground along each flown path (the
   flight's CSV, the vehicles' estimates) against ``min_agl_m``; where each stood before its
   take-off (the ``.tlog``: its height above the ground there).

Printed: a table (one row per case), then one JSON line.

    .venv/bin/python benchmarks/bench_terrain.py [--speed K]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gcs import cli  # noqa: E402
from gcs.telemetry import load_telemetry  # noqa: E402
from mavlink.tlog import tracks_from_tlog  # noqa: E402
from planner.optimize import clear_cache, plan  # noqa: E402
from planner.planfile import load_plan, save_plan  # noqa: E402
from planner.scenario import load_scenario  # noqa: E402
from planner.spec.terrain import Terrain, write_geotiff  # noqa: E402

SCENARIO = ROOT / "configs" / "powerline_hillside.yaml"


def ground_by_hand(t: Terrain, xy: np.ndarray) -> np.ndarray:
    """Bilinear on the grid, written out (not the planner's interpolants)."""
    fx = np.clip((xy[:, 0] - t.x0_m) / t.step_m, 0, t.ground_z_m.shape[0] - 1 - 1e-9)
    fy = np.clip((xy[:, 1] - t.y0_m) / t.step_m, 0, t.ground_z_m.shape[1] - 1 - 1e-9)
    i, j = np.floor(fx).astype(int), np.floor(fy).astype(int)
    u, v = fx - i, fy - j
    g = t.ground_z_m
    return (
        g[i, j] * (1 - u) * (1 - v)
        + g[i + 1, j] * u * (1 - v)
        + g[i, j + 1] * (1 - u) * v
        + g[i + 1, j + 1] * u * v
    )


RIDGE_YAML = """
name: ridge
origin: {lat: 47.397742, lon: 8.545594, alt: 488.0}
workspace: {min: [-20, -20, -10], max: [100, 20, 40]}
terrain: {file: ridge.tif, min_agl_m: 3}
regions:
  goal: {kind: goal, min: [76, -3, 2], max: [84, 3, 8]}
limits: {v_xy_max_m_s: 5, v_up_max_m_s: 3, v_down_max_m_s: 1.5, a_xy_max_m_s2: 3,
         a_up_max_m_s2: 3, a_down_max_m_s2: 2}
vehicles:
  - {name: d1, start: [0, 0, 4]}
timing: {horizon_s: 30, segment_s: 3, Ts_s: 0.5, check_dt_s: 0.1}
epsilon: 0.01
spec:
  - eventually[0, 26] always[0, 2] inside(d1, goal)
  - always[0, 30] inside(d1, workspace)
"""


def write_ridge(folder: Path) -> Path:
    """A 14 m ridge 40 m east of the origin (UTM 32N raster, 5 m pixels) and a mission over it."""
    from rasterio.warp import transform

    (e0,), (n0,) = transform("EPSG:4326", "EPSG:32632", [8.545594], [47.397742])
    west, north = e0 - 200.0, n0 + 200.0
    cols, _ = np.meshgrid(np.arange(120), np.arange(80))
    d_e = west + (cols + 0.5) * 5.0 - e0
    write_geotiff(str(folder / "ridge.tif"), 486.0 + 14.0 * np.exp(-(((d_e - 40.0) / 10.0) ** 2)),
                  west, north, 5.0, "EPSG:32632")  # fmt: skip
    path = folder / "ridge.yaml"
    path.write_text(RIDGE_YAML)
    return path


def run_case(scenario: Path, speed: float, tmp: Path) -> dict[str, object]:
    """Load, plan (cold) and fly ``scenario``; the figures as a dict."""
    out: dict[str, object] = {"scenario": scenario.name}
    t0 = time.perf_counter()
    problem = load_scenario(scenario)
    out["load_s"] = round(time.perf_counter() - t0, 3)
    terrain = problem.terrain
    assert terrain is not None
    out["grid"] = list(terrain.ground_z_m.shape)
    out["grid_step_m"] = round(terrain.step_m, 3)
    out["ground_range_m"] = [
        round(float(terrain.ground_z_m.min()), 2),
        round(float(terrain.ground_z_m.max()), 2),
    ]
    floors = [c.text for c in problem.clauses if c.key_path == "terrain.min_agl_m"]
    out["min_agl_m"] = float(floors[0].split(">=")[1].strip(" )")) if floors else None
    clear_cache()
    t0 = time.perf_counter()
    res = plan(problem)
    out["plan_s"] = round(time.perf_counter() - t0, 2)
    out["planned_robustness"] = round(res.robustness, 4)
    out["met"] = bool(res.success)
    planned_agl = {}
    for name, traj in zip((v.name for v in problem.vehicles), res.trajectories, strict=True):
        pos = traj.position(np.arange(0.0, problem.timing.horizon_s + 1e-9, 0.02))
        planned_agl[name] = round(float((pos[:, 2] - ground_by_hand(terrain, pos[:, :2])).min()), 3)
    out["planned_min_agl_m"] = planned_agl
    plan_path = tmp / f"{scenario.stem}.plan.json"
    save_plan(plan_path, res, str(scenario))
    log = tmp / f"{scenario.stem}-log"
    buf = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
        rc = cli.main(["fly", str(plan_path), "--dry-run", "--speed", f"{speed:g}",
                       "--log", str(log), "--json"])  # fmt: skip
    out["fly_wall_s"] = round(time.perf_counter() - t0, 1)
    out["fly_exit"] = rc
    flight = json.loads(buf.getvalue())
    out["flown_robustness"] = round(float(flight["flown_robustness"]), 4)
    flown = load_plan(plan_path)
    flown_agl = {}
    for name, tr in load_telemetry(log / "flight.csv").vehicles.items():
        keep = (tr.t_s >= 0.0) & (tr.t_s <= flown.horizon_s)
        p = tr.pos_enu_m[keep]
        flown_agl[name] = round(float((p[:, 2] - ground_by_hand(terrain, p[:, :2])).min()), 3)
    out["flown_min_agl_m"] = flown_agl
    ids = {i + 1: v.name for i, v in enumerate(flown.vehicles)}
    stood = {}
    for name, tr in tracks_from_tlog(
        log / "flight.tlog", ids, flown.origin, flight["t0_unix_s"]
    ).items():
        p = tr.pos_enu_m[tr.t_s < tr.t_s[0] + 0.5]
        stood[name] = [round(float(p[:, 2].mean()), 2),
                       round(float((p[:, 2] - ground_by_hand(terrain, p[:, :2])).mean()), 2)]  # fmt: skip
    out["stood_z_and_agl_m"] = stood
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speed", type=float, default=4.0)
    args = ap.parse_args()
    cases = []
    with tempfile.TemporaryDirectory() as tmp:
        for scenario in (SCENARIO, write_ridge(Path(tmp))):
            cases.append(run_case(scenario, args.speed, Path(tmp)))
    head = ("case", "load s", "grid", "ground z m", "plan s", "rho", "min agl plan", "fly",
            "flown rho", "min agl flown", "floor", "stood z (agl)")  # fmt: skip
    print("  ".join(f"{h:>14}" for h in head))
    for c in cases:
        g = c["ground_range_m"]
        stood = c["stood_z_and_agl_m"]
        row = (
            str(c["scenario"]).removesuffix(".yaml")[:14],
            f"{c['load_s']:.3f}",
            "x".join(map(str, c["grid"])),  # type: ignore[call-overload]
            f"{g[0]:+.1f}..{g[1]:+.1f}",  # type: ignore[index]
            f"{c['plan_s']:.2f}",
            f"{c['planned_robustness']:+.4f}",
            f"{min(c['planned_min_agl_m'].values()):.3f}",  # type: ignore[attr-defined]
            f"exit {c['fly_exit']}",
            f"{c['flown_robustness']:+.4f}",
            f"{min(c['flown_min_agl_m'].values()):.3f}",  # type: ignore[attr-defined]
            f"{c['min_agl_m']:g}",
            "; ".join(f"{v[0]:+.2f} ({v[1]:+.2f})" for v in stood.values()),  # type: ignore[attr-defined]
        )
        print("  ".join(f"{x:>14}" for x in row))
    print(json.dumps({"speed": args.speed, "cases": cases}))


if __name__ == "__main__":
    main()
