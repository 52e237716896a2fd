"""A scenario's ``terrain:`` section: the ground from an elevation model.

::

    terrain:
      file: dem.tif          # a GeoTIFF of heights AMSL (any CRS PROJ knows), relative
                             # to the scenario's folder
      min_agl_m: 5           # optional: every vehicle keeps this height above the ground
                             # over the whole horizon (one clause per vehicle)
      step_m: 2              # optional: the grid's step (default: the raster's pixel size)

With a terrain, heights the scenario writes *for the line and the starts* are above the ground
where they are (a pole's ``height_m``, the conductors' and inspection boxes' ``z``, a start's
``z``: 0 is on the ground); the workspace and the named regions keep the mission frame (``z``
above the origin's altitude). ``agl(d)`` in the spec is a vehicle's height above the ground.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from planner.frames import GeodeticPoint
from planner.problem import Clause
from planner.scenario.sections import Reader
from planner.spec.regions import Region
from planner.spec.terrain import Terrain, TerrainError, terrain_from_geotiff

__all__ = ["TERRAIN_KEYS", "floor_clauses", "read_terrain"]

#: The keys of a ``terrain:`` section.
TERRAIN_KEYS = {"file", "min_agl_m", "step_m"}


def read_terrain(
    rd: Reader, value: Any, origin: GeodeticPoint, workspace: Region, base_dir: Path
) -> tuple[Terrain, float | None]:
    """The :class:`Terrain` under the workspace and the section's ``min_agl_m`` (or None)."""
    m: Mapping[str, Any] = rd.mapping(value, "terrain", TERRAIN_KEYS)
    name = rd.require(m, "file", "terrain")
    if not isinstance(name, str) or not name:
        raise rd.fail("terrain.file", "expected the path of a GeoTIFF elevation model")
    path = Path(name) if Path(name).is_absolute() else base_dir / name
    if not path.is_file():
        raise rd.fail("terrain.file", f"{name}: no such file")
    min_agl = None
    if "min_agl_m" in m:
        min_agl = rd.number(m["min_agl_m"], "terrain.min_agl_m", nonnegative=True)
    step = None
    if "step_m" in m:
        step = rd.number(m["step_m"], "terrain.step_m", positive=True)
    lo, hi = np.asarray(workspace.lo_enu_m), np.asarray(workspace.hi_enu_m)
    try:
        terrain = terrain_from_geotiff(str(path), origin, lo[:2], hi[:2], step, name=name)
    except TerrainError as exc:
        raise rd.fail("terrain.file", str(exc)) from None
    top = float(terrain.ground_z_m.max()) + (min_agl or 0.0)
    if top >= hi[2]:
        raise rd.fail(
            "terrain",
            f"the ground rises to z = {terrain.ground_z_m.max():.1f} m under the workspace"
            + (f" (+ min_agl_m {min_agl:g})" if min_agl else "")
            + f", not below its top {hi[2]:g} m: raise workspace.max's z",
        )
    return terrain, min_agl


def floor_clauses(vehicles: list[str], min_agl_m: float, horizon_s: float) -> list[Clause]:
    """``min_agl_m`` as the spec's clauses: each vehicle keeps it over the whole horizon."""
    return [
        Clause("terrain.min_agl_m", f"always[0, {horizon_s:g}] (agl({v}) >= {min_agl_m:g})")
        for v in vehicles
    ]
