"""Helpers of the line tests (tests/planner/test_line.py, test_kml.py): a two-drone scenario
with a ``line:`` section, one 4-pole line, its poles in lat/lon, and the pole centres a
scenario made."""

from __future__ import annotations

from typing import Any

import numpy as np
import pymap3d
import yaml

ORIGIN = {"lat": 47.397742, "lon": 8.545594, "alt": 488.0}


def enu_poles() -> np.ndarray:
    """Four poles, ENU metres, not in a straight line."""
    return np.array([[0.0, 0.0], [24.0, 18.0], [55.0, 30.0], [80.0, 52.0]])


def geodetic(xy: np.ndarray) -> list[tuple[float, float]]:
    """``(lat, lon)`` of ENU points on the ground at :data:`ORIGIN` (pymap3d)."""
    lat, lon, _ = pymap3d.enu2geodetic(
        xy[:, 0], xy[:, 1], 0.0, ORIGIN["lat"], ORIGIN["lon"], ORIGIN["alt"]
    )
    return list(zip(np.atleast_1d(lat).tolist(), np.atleast_1d(lon).tolist(), strict=True))


def pole_centres(problem: Any) -> np.ndarray:
    """The centres of a scenario's ``pole*`` cylinders, (n, 2)."""
    return np.array([r.shape.center_xy for r in problem.regions if r.name.startswith("pole")])


BASE = """
name: line
origin: {lat: 47.397742, lon: 8.545594, alt: 488.0}
workspace: {min: [-150, -150, 0.5], max: [250, 250, 20]}
line:
LINE
vehicles:
  - {name: d1, start: [-12, -12, 8]}
  - {name: d2, start: [-8, -12, 8]}
limits: {v_max_m_s: 5, a_max_m_s2: 3}
timing: {horizon_s: 60, segment_s: 3, Ts_s: 0.5}
separation_m: 1.5
spec:
  - formula: eventually[0, 55] always[0, 2] inside(d1, insp2)
  - each: [d in all, s in spans]
    formula: always[0, $horizon] outside(d, s)
  - each: [d in all, p in poles]
    formula: always[0, $horizon] outside(d, p)
"""

PARTS = """
  pole: {radius_m: 0.4, height_m: 12}
  conductors: {half_width_m: 1.8, z: [9, 12], clearance_m: 1.0}
  inspection: {standoff_m: 1.5, depth_m: 2.2, length_m: 5, z: [9.5, 12.5], side: SIDE}
"""


def scenario(poles: str, side: str = "right") -> dict[str, Any]:
    """The scenario with ``poles`` (the ``line:`` keys that place them) and the inspection
    boxes on ``side``."""
    text = BASE.replace("LINE", poles.rstrip("\n") + PARTS.replace("SIDE", side).rstrip("\n"))
    if side == "both":
        text = text.replace("inside(d1, insp2)", "inside(d1, insp2_left)")
    return yaml.safe_load(text)  # type: ignore[no-any-return]
