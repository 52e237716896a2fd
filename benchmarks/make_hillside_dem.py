"""Write configs/hillside_dem.tif, the elevation model of configs/powerline_hillside.yaml.

A hillside near the scenarios' origin (47.397742 N, 8.545594 E, 488 m AMSL) as a national
survey would give it: a GeoTIFF in UTM zone 32N (EPSG:32632), 5 m pixels, heights AMSL.
The ground rises 10 m per 100 m eastward with a 6 m swell every 150 m, and 8 m per 100 m
northward; it is written once and shipped (about 3 KB), so nothing is downloaded::

    .venv/bin/python benchmarks/make_hillside_dem.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from rasterio.warp import transform

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from planner.spec.terrain import write_geotiff  # noqa: E402

ORIGIN = (47.397742, 8.545594, 488.0)
PIXEL_M = 5.0


def height_amsl(d_east: np.ndarray, d_north: np.ndarray) -> np.ndarray:
    """The hillside (m AMSL) at UTM offsets from the origin's UTM position."""
    return (
        ORIGIN[2] - 4.0 + 0.10 * d_east + 6.0 * np.sin(2 * np.pi * d_east / 150.0) + 0.08 * d_north
    )


def main() -> None:
    (e0,), (n0,) = transform("EPSG:4326", "EPSG:32632", [ORIGIN[1]], [ORIGIN[0]])
    west, north = e0 - 100.0, n0 + 150.0
    cols, rows = np.meshgrid(np.arange(80), np.arange(60))
    d_e = west + (cols + 0.5) * PIXEL_M - e0
    d_n = north - (rows + 0.5) * PIXEL_M - n0
    out = ROOT / "configs" / "hillside_dem.tif"
    write_geotiff(str(out), height_amsl(d_e, d_n), west, north, PIXEL_M, "EPSG:32632")
    print(f"wrote {out.relative_to(ROOT)} ({out.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
