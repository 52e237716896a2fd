"""KML round trip (issue 44): towers from a KMZ, planned, exported as KML/KMZ, imported again.

1. The 10-pole line of ``powerline_line10_bearing37_3drones`` (its towers' lat/lon from the
   scenario's ``along:``) written as a KMZ of Placemark Points; the scenario read with
   ``line: file:`` that KMZ; its pole centres against the ``along:`` line's (metres).
2. Planned (cold, in this process), exported by ``gcs export --format kml`` (and ``-o .kmz``),
   read back: the towers against the originals (degrees), the files' sizes, each step's time.
3. The 40 towers of ``benchmarks/scenarios/line40_poles.csv`` as KML: reading time, and the
   pole centres against the CSV's.

Printed: a table, then one JSON line.

    .venv/bin/python benchmarks/bench_kml.py
"""

from __future__ import annotations

import io
import json
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
import yaml

from gcs import cli
from planner.frames import enu_to_geodetic
from planner.optimize import clear_cache, plan
from planner.planfile import save_plan
from planner.scenario import load_scenario
from planner.scenario.kml import kml_towers

ROOT = Path(__file__).resolve().parents[1]
SCEN = ROOT / "benchmarks" / "scenarios"


def towers_kml(latlon: np.ndarray) -> str:
    marks = "".join(
        f"<Placemark><name>T{i + 1}</name><Point><coordinates>{float(lon)!r},{float(lat)!r},0"
        "</coordinates>"
        "</Point></Placemark>"
        for i, (lat, lon) in enumerate(latlon)
    )
    return f'<kml xmlns="http://www.opengis.net/kml/2.2"><Document>{marks}</Document></kml>'


def kmz(text: str) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("doc.kml", text)
    return buf.getvalue()


def centres(problem: object) -> np.ndarray:
    return np.array(
        [r.shape.center_xy for r in problem.regions if r.name.startswith("pole")]  # type: ignore[attr-defined]
    )


def main() -> int:
    out: dict[str, object] = {"bench": "kml"}
    rows: list[tuple[str, str]] = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        src = SCEN / "powerline_line10_bearing37_3drones.yaml"
        data = yaml.safe_load(src.read_text())
        ref = load_scenario(src)
        xy = centres(ref)
        lat, lon, _ = enu_to_geodetic(np.column_stack([xy, np.zeros(len(xy))]), ref.origin)
        latlon = np.column_stack([lat, lon])
        (tmp / "towers.kmz").write_bytes(kmz(towers_kml(latlon)))
        data["line"].pop("along")
        data["line"]["file"] = "towers.kmz"
        scen = tmp / "line10_kmz.yaml"
        scen.write_text(yaml.safe_dump(data))
        t0 = time.perf_counter()
        problem = load_scenario(scen)
        t_import = time.perf_counter() - t0
        err_import_m = float(np.abs(centres(problem) - xy).max())
        clear_cache()
        t0 = time.perf_counter()
        result = plan(problem)
        t_plan = time.perf_counter() - t0
        plan_path = tmp / "plan.json"
        save_plan(plan_path, result, str(scen))
        for suffix in ("kml", "kmz"):
            target = tmp / f"plan.{suffix}"
            t0 = time.perf_counter()
            code = cli.main(["export", str(plan_path), "--format", "kml", "-o", str(target)])
            t_export = time.perf_counter() - t0
            assert code == 0
            back = kml_towers(target.read_bytes(), target.name)
            err_deg = float(np.abs(back[:, :2] - latlon).max())
            out[suffix] = {"export_s": t_export, "bytes": target.stat().st_size,
                           "towers_max_error_deg": err_deg}  # fmt: skip
            rows.append((f"10-pole line: export {suffix}, {target.stat().st_size:,} bytes",
                         f"{t_export * 1e3:.0f} ms; towers back within {err_deg:.1e} deg"))  # fmt: skip
        out.update(import_s=t_import, import_error_m=err_import_m, plan_s=t_plan,
                   planned=result.success, robustness=result.robustness)  # fmt: skip
        rows.insert(0, ("10-pole line from a KMZ: import", f"{t_import * 1e3:.0f} ms; pole centres "
                        f"within {err_import_m:.1e} m of the along: line"))  # fmt: skip
        rows.insert(1, ("  planned", f"{t_plan:.1f} s, robustness {result.robustness:+.3f}, "
                        f"{'met' if result.success else 'NOT met'}"))  # fmt: skip
        # 40 towers from the CSV, as KML
        csv = np.loadtxt(SCEN / "line40_poles.csv", delimiter=",", skiprows=1, usecols=(1, 2))
        (tmp / "line40.kml").write_text(towers_kml(csv))
        data40 = yaml.safe_load((SCEN / "powerline_line40_4drones_300s.yaml").read_text())
        data40["line"]["file"] = str(SCEN / "line40_poles.csv")
        (tmp / "csv.yaml").write_text(yaml.safe_dump(data40))
        data40["line"]["file"] = "line40.kml"
        (tmp / "kml.yaml").write_text(yaml.safe_dump(data40))
        a = centres(load_scenario(tmp / "csv.yaml"))
        t0 = time.perf_counter()
        b = centres(load_scenario(tmp / "kml.yaml"))
        t40 = time.perf_counter() - t0
        err40 = float(np.abs(a - b).max())
        out.update(line40_load_s=t40, line40_error_m=err40)
        rows.append(("40 towers as KML: the scenario loaded",
                     f"{t40 * 1e3:.0f} ms; pole centres within {err40:.1e} m of the CSV's"))  # fmt: skip
    width = max(len(r[0]) for r in rows)
    for name, val in rows:
        print(f"{name:<{width}}  {val}")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
