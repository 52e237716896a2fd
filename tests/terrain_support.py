"""Elevation models the terrain tests make: rasters written from known surfaces near the
scenarios' origin, and a scenario with a ridge to fly over."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pymap3d
import yaml
from rasterio.warp import transform

from planner.frames import GeodeticPoint
from planner.spec.terrain import write_geotiff

ORIGIN = GeodeticPoint(47.397742, 8.545594, 488.0)
O3 = (ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m)
(E0,), (N0,) = transform("EPSG:4326", "EPSG:32632", [ORIGIN.lon_deg], [ORIGIN.lat_deg])


def utm_raster(path: Path, height: object, pixel: float = 5.0, nodata_at: tuple = ()) -> None:
    """A UTM 32N raster 600 m x 400 m round the origin, heights ``height(dE, dN)`` AMSL."""
    west, north = E0 - 200.0, N0 + 200.0
    cols, rows = np.meshgrid(np.arange(int(600 / pixel)), np.arange(int(400 / pixel)))
    d_e = west + (cols + 0.5) * pixel - E0
    d_n = north - (rows + 0.5) * pixel - N0
    h = np.asarray(height(d_e, d_n), dtype=float)  # type: ignore[operator]
    for r, c in nodata_at:
        h[r, c] = -9999.0
    write_geotiff(str(path), h, west, north, pixel, "EPSG:32632")


def plane(d_e: np.ndarray, d_n: np.ndarray) -> np.ndarray:
    return 480.0 + 0.1 * d_e + 0.05 * d_n


def ground_reference(xy: np.ndarray, height: object) -> np.ndarray:
    """The surface's mission-frame z under ENU points: through pymap3d and PROJ, not the grid."""
    lat, lon, _ = pymap3d.enu2geodetic(
        xy[:, 0], xy[:, 1], 0.0, ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.alt_m
    )
    e, n = transform("EPSG:4326", "EPSG:32632", list(lon), list(lat))
    h = height(np.asarray(e) - E0, np.asarray(n) - N0)  # type: ignore[operator]
    return np.asarray(pymap3d.geodetic2enu(lat, lon, h, *O3)[2])


def ridge(d_e: np.ndarray, d_n: np.ndarray) -> np.ndarray:
    """A 14 m ridge running north-south 40 m east of the origin, on ground at 486 m."""
    return 486.0 + 14.0 * np.exp(-(((d_e - 40.0) / 10.0) ** 2))


def ridge_scenario(tmp_path: Path, **over: object) -> Path:
    utm_raster(tmp_path / "ridge.tif", ridge)
    data: dict[str, object] = {
        "name": "ridge",
        "origin": {"lat": ORIGIN.lat_deg, "lon": ORIGIN.lon_deg, "alt": ORIGIN.alt_m},
        "workspace": {"min": [-20, -20, -10], "max": [100, 20, 40]},
        "terrain": {"file": "ridge.tif", "min_agl_m": 3},
        "regions": {"goal": {"kind": "goal", "min": [76, -3, 2], "max": [84, 3, 8]}},
        "limits": {  # PX4-like (MPC_XY_VEL_MAX, MPC_Z_VEL_MAX_UP/_DN, MPC_ACC_*)
            "v_xy_max_m_s": 5,
            "v_up_max_m_s": 3,
            "v_down_max_m_s": 1.5,
            "a_xy_max_m_s2": 3,
            "a_up_max_m_s2": 3,
            "a_down_max_m_s2": 2,
        },
        "vehicles": [{"name": "d1", "start": [0, 0, 4]}],
        "timing": {"horizon_s": 30, "segment_s": 3, "Ts_s": 0.5, "check_dt_s": 0.1},
        "epsilon": 0.01,
        "solver": {"coarse_s": 0},
        "spec": [
            "eventually[0, 26] always[0, 2] inside(d1, goal)",
            "always[0, 30] inside(d1, workspace)",
        ],
    }
    data.update(over)
    data = {k: v for k, v in data.items() if v is not None}  # None: leave the key out
    path = tmp_path / "ridge.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path
