"""A scenario's ``terrain:`` section: the ground from an elevation model.

::

    terrain:
      file: dem.tif          # a GeoTIFF of heights AMSL (any CRS PROJ knows), relative
                             # to the scenario's folder
      # from: line           # or: the ground at the towers' feet, from the line's file
                             # (CSV alt/elevation column, GeoJSON's third number, KML
                             # altitudes under altitudeMode absolute), linear along the
                             # line and level across it
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
from typing import TYPE_CHECKING, Any

import numpy as np
import pymap3d

from planner.frames import GeodeticPoint, enu_to_geodetic
from planner.problem import Clause
from planner.scenario.sections import Reader
from planner.spec.regions import Region
from planner.spec.terrain import (
    Terrain,
    TerrainError,
    terrain_from_geotiff,
    terrain_from_profile,
)

if TYPE_CHECKING:
    from planner.scenario.line import LineModel

__all__ = ["TERRAIN_KEYS", "floor_clauses", "read_terrain"]

#: The grid's step (m) of a ground made from the towers' altitudes (``from: line``).
_PROFILE_STEP_M = 2.0

#: The keys of a ``terrain:`` section.
TERRAIN_KEYS = {"file", "from", "min_agl_m", "step_m"}


def read_terrain(
    rd: Reader,
    value: Any,
    origin: GeodeticPoint,
    workspace: Region,
    base_dir: Path,
    line: LineModel | None = None,
    line_file: str = "",
) -> tuple[Terrain, float | None, np.ndarray | None]:
    """The :class:`Terrain` under the workspace, the section's ``min_agl_m`` (or None), and
    with ``from: line`` the ground's ``z`` at each tower's foot as its file gives it (the
    grid between them is an interpolation); ``line``: the scenario's line as read, its file
    ``line_file``."""
    m: Mapping[str, Any] = rd.mapping(value, "terrain", TERRAIN_KEYS)
    if ("file" in m) == ("from" in m):
        raise rd.fail("terrain", "give the ground one way: file (a GeoTIFF) or from: line")
    min_agl = None
    if "min_agl_m" in m:
        min_agl = rd.number(m["min_agl_m"], "terrain.min_agl_m", nonnegative=True)
    step = None
    if "step_m" in m:
        step = rd.number(m["step_m"], "terrain.step_m", positive=True)
    lo, hi = np.asarray(workspace.lo_enu_m), np.asarray(workspace.hi_enu_m)
    feet = None
    if "from" in m:
        terrain, feet = _from_line(rd, m["from"], origin, lo, hi, step, line, line_file)
    else:
        name = m["file"]
        if not isinstance(name, str) or not name:
            raise rd.fail("terrain.file", "expected the path of a GeoTIFF elevation model")
        path = Path(name) if Path(name).is_absolute() else base_dir / name
        if not path.is_file():
            raise rd.fail("terrain.file", f"{name}: no such file")
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
    return terrain, min_agl, feet


def _from_line(
    rd: Reader,
    what: Any,
    origin: GeodeticPoint,
    lo: np.ndarray,
    hi: np.ndarray,
    step: float | None,
    line: LineModel | None,
    line_file: str,
) -> tuple[Terrain, np.ndarray]:
    if what != "line":
        raise rd.fail("terrain.from", f"expected 'line' (the towers' ground), got {what!r}")
    if line is None or line.tower_alt_m is None:
        raise rd.fail(
            "terrain.from",
            "the ground from the line needs a line section whose file gives each tower's "
            "ground altitude",
        )
    missing = np.flatnonzero(~np.isfinite(line.tower_alt_m))
    if len(missing):
        raise rd.fail(
            "line.file",
            f"{line_file}: tower {int(missing[0]) + 1} has no ground altitude (terrain: from: "
            "line reads a CSV's alt or elevation column, a GeoJSON position's third number, a "
            "KML altitude under altitudeMode absolute)",
        )
    xy = np.asarray(line.poles_xy, dtype=float)
    lat, lon, _ = enu_to_geodetic(np.column_stack([xy, np.zeros(len(xy))]), origin)
    _, _, z = pymap3d.geodetic2enu(
        lat, lon, line.tower_alt_m, origin.lat_deg, origin.lon_deg, origin.alt_m
    )
    feet = np.asarray(z, dtype=float)
    step = _PROFILE_STEP_M if step is None else step
    return terrain_from_profile(xy, feet, lo[:2], hi[:2], step, line_file), feet


def floor_clauses(vehicles: list[str], min_agl_m: float, horizon_s: float) -> list[Clause]:
    """``min_agl_m`` as the spec's clauses: each vehicle keeps it over the whole horizon."""
    return [
        Clause("terrain.min_agl_m", f"always[0, {horizon_s:g}] (agl({v}) >= {min_agl_m:g})")
        for v in vehicles
    ]
