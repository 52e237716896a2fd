"""Benchmark of ``gcs plot`` and ``gcs export``: wall time per stage against fleet size.

Plans are synthetic (no solver run): N vehicles over a 30 s horizon of 2 s rest-to-rest
quintic segments through random waypoints in a power-line-sized workspace, a spec of
``eventually ... inside``, ``always ... outside/inside`` per vehicle and ``dist`` per pair
(the powerline scenario's clause mix), checked every 0.05 s. Prints a table, then one JSON line.

    .venv/bin/python benchmarks/bench_plot_export.py
"""

from __future__ import annotations

import json
import tempfile
import time
from itertools import combinations
from pathlib import Path

import numpy as np

from gcs.export import ExportFormat, write_export
from gcs.plot import html_report
from gcs.plot.figure import figure_png, render_figure
from gcs.plot.traces import clause_traces
from planner.frames import GeodeticPoint
from planner.planfile import Plan, PlannedVehicle, save_plan
from planner.spec.regions import Region, RegionKind
from planner.trajectory import Trajectory

ORIGIN = GeodeticPoint(47.397742, 8.545594, 488.0)
HORIZON_S = 30.0
SEGMENT_S = 2.0


def _trajectory(rng: np.random.Generator, name: str) -> Trajectory:
    k = int(HORIZON_S / SEGMENT_S)
    w = rng.uniform([-5, -15, 2], [80, 5, 15], size=(k + 1, 3))
    coeffs = np.zeros((k, 3, 6))
    for s in range(k):
        d = w[s + 1] - w[s]
        coeffs[s, :, 0] = w[s]
        coeffs[s, :, 3] = 10 * d / SEGMENT_S**3
        coeffs[s, :, 4] = -15 * d / SEGMENT_S**4
        coeffs[s, :, 5] = 6 * d / SEGMENT_S**5
    return Trajectory(np.arange(k) * SEGMENT_S, np.full(k, SEGMENT_S), coeffs, name=name)


def synthetic_plan(n: int, seed: int = 0) -> Plan:
    rng = np.random.default_rng(seed)
    names = [f"d{i + 1}" for i in range(n)]
    vehicles = []
    for i, name in enumerate(names):
        traj = _trajectory(rng, name)
        start = traj.position(np.array([0.0]))[0]
        vehicles.append(
            PlannedVehicle(
                name, i + 1, traj, (start[0], start[1], start[2]), (5.0, 5.0, 2.0), (2.5, 2.5, 1.5)
            )
        )
    clauses = [f"eventually[0,29] always[0,1] inside({d}, insp1)" for d in names]
    clauses += [f"always[0,30] (inside({d}, workspace) and outside({d}, pole1))" for d in names]
    clauses += [f"always[0,30] dist({a}, {b}) >= 1.5" for a, b in combinations(names, 2)]
    regions = (
        Region("pole1", RegionKind.POLE, (-0.4, -0.4, 0.0), (0.4, 0.4, 12.0)),
        Region("corridor", RegionKind.CONDUCTOR, (-2.0, -2.8, 8.0), (77.0, 2.8, 12.5)),
        Region("insp1", RegionKind.INSPECTION, (-2.5, -5.5, 9.5), (2.5, -3.3, 12.5)),
        Region("keepout", RegionKind.NO_FLY, (60.0, -20.0, 0.5), (70.0, -15.0, 20.0)),
    )
    return Plan(
        scenario="bench.yaml",
        origin=ORIGIN,
        spec=" and\n".join(f"({c})" for c in clauses),
        robustness=0.0,
        smooth_robustness=0.0,
        status="synthetic",
        success=True,
        solve_time_s=0.0,
        vehicles=tuple(vehicles),
        workspace=Region("workspace", RegionKind.WORKSPACE, (-10, -20, 0.5), (85, 10, 20)),
        regions=regions,
        separation_m=1.5,
        epsilon=0.01,
        horizon_s=HORIZON_S,
        sample_dt_s=0.25,
        check_dt_s=0.05,
    )


def _time(fn, repeat: int = 3) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return float(best)


def main() -> None:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for n in (2, 4, 8):
            plan = synthetic_plan(n)
            plan_path = save_plan(d / f"bench{n}.json", plan)
            traces = clause_traces(plan)
            fig_holder: list = []
            row = {
                "vehicles": n,
                "clauses": len(traces),
                "traces_s": _time(lambda plan=plan: clause_traces(plan)),
                "render_s": _time(
                    lambda plan=plan, traces=traces, out=fig_holder: out.append(
                        render_figure(plan, traces)
                    ),
                    repeat=2,
                ),
            }
            fig = fig_holder[-1]
            png: list[bytes] = []
            row["png_s"] = _time(lambda fig=fig, out=png: out.append(figure_png(fig)), repeat=2)
            row["png_kib"] = len(png[-1]) / 1024
            row["html_s"] = _time(
                lambda plan=plan, traces=traces, data=png[-1]: html_report(plan, traces, data),
                repeat=3,
            )
            for fmt, key, kw in (
                (ExportFormat.QGC, "qgc_s", {}),
                (ExportFormat.CSV, "csv20_s", {"rate_hz": 20.0}),
                (ExportFormat.CSV, "csv100_s", {"rate_hz": 100.0}),
                (ExportFormat.JSON, "json20_s", {"rate_hz": 20.0}),
            ):
                row[key] = _time(
                    lambda plan=plan, plan_path=plan_path, fmt=fmt, kw=kw: write_export(
                        plan, plan_path, fmt, **kw
                    )
                )
            row["csv100_kib"] = (d / f"bench{n}.setpoints.csv").stat().st_size / 1024
            rows.append(row)
    cols = [
        ("vehicles", "{:>8d}"),
        ("clauses", "{:>7d}"),
        ("traces_s", "{:>9.3f}"),
        ("render_s", "{:>9.3f}"),
        ("png_s", "{:>7.3f}"),
        ("png_kib", "{:>8.0f}"),
        ("html_s", "{:>7.3f}"),
        ("qgc_s", "{:>7.3f}"),
        ("csv20_s", "{:>8.3f}"),
        ("csv100_s", "{:>9.3f}"),
        ("csv100_kib", "{:>10.0f}"),
        ("json20_s", "{:>9.3f}"),
    ]
    print("gcs plot / gcs export, synthetic 30 s plans (best of 2-3 runs, seconds)")
    print("traces: clause curves; render: build the figure; png: draw + encode 1600x1250")
    print(
        " ".join(
            f"{name:>{len(fmt.format(0)) if 'd' in fmt else int(fmt[3:].split('.')[0])}}"
            for name, fmt in cols
        )
    )
    for r in rows:
        print(" ".join(fmt.format(r[name]) for name, fmt in cols))
    print(json.dumps({"benchmark": "plot_export", "rows": rows}))


if __name__ == "__main__":
    main()
