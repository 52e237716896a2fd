"""The ground under the mission: a height grid in the mission frame, and ``agl(d)`` over it.

A scenario's ``terrain:`` section (docs/scenario-format.md, "Terrain") gives an elevation
model, a GeoTIFF of heights above mean sea level in any coordinate reference system that
PROJ knows (a national DEM in its projected grid, SRTM in latitude and longitude). The
planner does not read the raster while it plans: :func:`terrain_from_geotiff` samples it
once onto a regular grid of the mission frame (ENU metres from the scenario's origin, the
height of the ground as mission-frame ``z``), over the workspace, and a :class:`Terrain`
is that grid. Between its nodes the ground is bilinear, in the exact semantics
(:meth:`Terrain.ground`, scipy) and in the NLP (:meth:`Terrain.ca_ground`, CasADi's linear
interpolant: the same numbers); beyond the grid it is the nearest edge's. A plan file
carries the grid, so ``gcs verify`` and a flight judge ``agl`` on the ground the plan was
made over, without the raster.

Heights: the raster's values are taken in the vertical datum of the origin's ``alt`` (AMSL;
pymap3d treats both as heights over the ellipsoid, and the geoid's undulation is the same
to a millimetre over a mission's few kilometres); a node's mission-frame ``z`` is
``pymap3d.geodetic2enu`` of its ground point, so the earth's curvature (8 cm at 1 km) is in.

Sampling: the raster is read bilinearly between its pixel centres (GDAL's convention: a
pixel's value is at its centre) at each node; a node whose four neighbours are not all data
(outside the raster, or a nodata pixel) is refused, naming the file and the place.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.errors import PlannerError
from planner.frames import GeodeticPoint, enu_to_geodetic

__all__ = [
    "MAX_NODES",
    "Terrain",
    "TerrainError",
    "ground_below",
    "terrain_from_geotiff",
    "terrain_from_profile",
    "write_geotiff",
]

#: Most grid nodes a terrain keeps (a finer raster is sampled at a coarser step).
MAX_NODES = 250_000


class TerrainError(PlannerError, ValueError):
    """An elevation model that cannot be read, or does not cover the mission."""


@dataclass(frozen=True, eq=False)
class Terrain:
    """The ground's mission-frame height on a regular grid.

    Attributes:
        x0_m, y0_m: the grid's south-west node (ENU metres).
        step_m: the distance between nodes along x and y.
        ground_z_m: ``(nx, ny)``: the ground's ``z`` at ``(x0 + i step, y0 + j step)``.
        source: where it came from (a file's name), for messages and plan files.
    """

    x0_m: float
    y0_m: float
    step_m: float
    ground_z_m: NDArray[np.float64]
    source: str = ""
    _interp: Any = field(default=None, init=False, repr=False)
    _ca: Any = field(default=None, init=False, repr=False)
    _plane: Any = field(default=None, init=False, repr=False)
    _digest: str = field(default="", init=False, repr=False)

    def __post_init__(self) -> None:
        g = np.asarray(self.ground_z_m, dtype=float)
        if g.ndim != 2 or min(g.shape) < 2:
            raise TerrainError(f"a terrain grid needs at least 2 x 2 nodes, got {g.shape}")
        if not np.all(np.isfinite(g)):
            raise TerrainError("a terrain grid's heights must be finite")
        if not (math.isfinite(self.step_m) and self.step_m > 0):
            raise TerrainError(f"a terrain grid's step must be > 0 m, got {self.step_m!r}")
        g.setflags(write=False)
        object.__setattr__(self, "ground_z_m", g)

    def __getstate__(self) -> dict[str, Any]:
        """Pickled without the built interpolants (the copy builds its own on first use)."""
        return {k: getattr(self, k) for k in ("x0_m", "y0_m", "step_m", "ground_z_m", "source")}

    def __setstate__(self, state: dict[str, Any]) -> None:
        for k, v in state.items():
            object.__setattr__(self, k, v)
        object.__setattr__(self, "_interp", None)
        object.__setattr__(self, "_ca", None)
        object.__setattr__(self, "_plane", None)
        object.__setattr__(self, "_digest", "")

    @property
    def xs_m(self) -> NDArray[np.float64]:
        """The nodes' x (m), ascending."""
        return self.x0_m + self.step_m * np.arange(self.ground_z_m.shape[0], dtype=float)

    @property
    def ys_m(self) -> NDArray[np.float64]:
        """The nodes' y (m), ascending."""
        return self.y0_m + self.step_m * np.arange(self.ground_z_m.shape[1], dtype=float)

    @property
    def digest(self) -> str:
        """A fingerprint of the grid (what the planner's caches key a built NLP by)."""
        if not self._digest:
            h = hashlib.sha1()
            h.update(repr((self.x0_m, self.y0_m, self.step_m, self.ground_z_m.shape)).encode())
            h.update(np.ascontiguousarray(self.ground_z_m).tobytes())
            object.__setattr__(self, "_digest", h.hexdigest())
        return self._digest

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Terrain) and self.digest == other.digest

    def __hash__(self) -> int:
        return hash(self.digest)

    def _clamped(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        xs, ys = self.xs_m, self.ys_m
        return np.column_stack([np.clip(xy[:, 0], xs[0], xs[-1]), np.clip(xy[:, 1], ys[0], ys[-1])])

    def ground(self, xy: ArrayLike) -> NDArray[np.float64]:
        """The ground's ``z`` under points ``(n, 2)`` (or ``(n, 3)``, whose ``z`` is ignored;
        one point ``(2,)`` gives shape ``(1,)``): bilinear between nodes, beyond the grid
        its nearest edge's."""
        p = np.asarray(xy, dtype=float)
        p = p.reshape(-1, p.shape[-1])[:, :2]
        if self._interp is None:
            from scipy.interpolate import RegularGridInterpolator

            object.__setattr__(
                self,
                "_interp",
                RegularGridInterpolator((self.xs_m, self.ys_m), self.ground_z_m, method="linear"),
            )
        out: NDArray[np.float64] = self._interp(self._clamped(p))
        return out

    def agl(self, pos_enu_m: ArrayLike) -> NDArray[np.float64]:
        """Height above the ground of positions ``(n, 3)``: ``z - ground(x, y)``."""
        p = np.asarray(pos_enu_m, dtype=float).reshape(-1, np.shape(pos_enu_m)[-1])
        out: NDArray[np.float64] = p[:, 2] - self.ground(p[:, :2])
        return out

    def ca_ground(self, xy: Any) -> Any:
        """The same ground in CasADi: ``xy`` an ``(m, 2)`` SX/MX, out ``(m, 1)`` (CasADi's
        linear interpolant on the grid, the inputs clamped to it as :meth:`ground`)."""
        import casadi as ca

        if self._ca is None:
            f = ca.interpolant(
                "ground",
                "linear",
                [self.xs_m.tolist(), self.ys_m.tolist()],
                np.asarray(self.ground_z_m).ravel(order="F").tolist(),
            )
            object.__setattr__(self, "_ca", f)
        xs, ys = self.xs_m, self.ys_m
        x = ca.fmin(ca.fmax(xy[:, 0], float(xs[0])), float(xs[-1]))
        y = ca.fmin(ca.fmax(xy[:, 1], float(ys[0])), float(ys[-1]))
        return self._ca(ca.horzcat(x, y).T).T

    def plane_bounds(self) -> tuple[float, float, float, float]:
        """``(a, b, c_lo, c_hi)`` with ``a x + b y + c_lo <= ground(x, y) <= a x + b y + c_hi``
        over the grid (the workspace): the nodes' least-squares plane moved down and up by
        their largest excess and shortfall (in a cell, ground less plane is bilinear, so its
        extremes are at the cell's nodes). The combinatorial stage's linear
        ground (:mod:`planner.milp.encode`)."""
        if self._plane is None:
            xs, ys = np.meshgrid(self.xs_m, self.ys_m, indexing="ij")
            a_mat = np.column_stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
            coef, *_ = np.linalg.lstsq(a_mat, self.ground_z_m.ravel(), rcond=None)
            resid = self.ground_z_m.ravel() - a_mat @ coef
            c = float(coef[2])
            bounds = (
                float(coef[0]),
                float(coef[1]),
                c + float(resid.min()),
                c + float(resid.max()),
            )
            object.__setattr__(self, "_plane", bounds)
        return self._plane

    def to_dict(self) -> dict[str, Any]:
        """The plan file's ``terrain`` (a grid read from a raster is already to the millimetre)."""
        return {
            "source": self.source,
            "x0_m": self.x0_m,
            "y0_m": self.y0_m,
            "step_m": self.step_m,
            "ground_z_m": np.round(self.ground_z_m, 3).tolist(),
        }


def ground_below(
    terrain: Terrain | None, points: Sequence[Sequence[float]]
) -> list[tuple[float, float, float]]:
    """Each point ``(x, y, ...)`` put on the ground below it: the mission frame's ``z = 0``
    without a terrain, else the terrain there (a plan's spawns, ``gcs mock --ground-spawn``)."""
    xy = np.array([[p[0], p[1]] for p in points], dtype=float).reshape(-1, 2)
    z = np.zeros(len(xy)) if terrain is None else terrain.ground(xy)
    return [(float(p[0]), float(p[1]), float(h)) for p, h in zip(xy, z, strict=True)]


def _grid_axis(lo: float, hi: float, step: float) -> NDArray[np.float64]:
    n = max(2, math.ceil((hi - lo) / step - 1e-9) + 1)
    return lo + step * np.arange(n, dtype=float)


def terrain_from_geotiff(
    path: str,
    origin: GeodeticPoint,
    lo_xy: ArrayLike,
    hi_xy: ArrayLike,
    step_m: float | None = None,
    name: str | None = None,
) -> Terrain:
    """Sample the GeoTIFF at ``path`` onto a mission-frame grid over ``[lo_xy, hi_xy]``.

    ``step_m``: the grid's step (default: the raster's pixel size on the ground, at least
    0.5 m, coarser if the area would need more than :data:`MAX_NODES` nodes). ``name``: how
    messages and the plan file name the file (default ``path``). Raises
    :class:`TerrainError` (one line, naming the file) when it cannot be read or does not
    cover the area.
    """
    import pymap3d
    import rasterio
    from rasterio.errors import RasterioError
    from rasterio.warp import transform as warp_transform

    label = name or str(path)
    lo = np.asarray(lo_xy, dtype=float)
    hi = np.asarray(hi_xy, dtype=float)
    try:
        with rasterio.open(path) as src:
            if src.crs is None:
                raise TerrainError(f"{label}: the raster has no coordinate reference system")
            band = src.read(1, masked=True)
            crs, aff = src.crs, src.transform
    except RasterioError as exc:
        raise TerrainError(f"{label}: cannot read as a GeoTIFF ({exc})") from None
    data = np.ma.getdata(band).astype(float)
    bad = np.ma.getmaskarray(band) | ~np.isfinite(data)

    def to_pixels(x_e: NDArray[np.float64], y_n: NDArray[np.float64]) -> NDArray[np.float64]:
        lat, lon, _ = enu_to_geodetic(np.column_stack([x_e, y_n, np.zeros_like(x_e)]), origin)
        rx, ry = warp_transform("EPSG:4326", crs, np.atleast_1d(lon), np.atleast_1d(lat))
        inv = ~aff
        x, y = np.asarray(rx), np.asarray(ry)
        col, row = inv.a * x + inv.b * y + inv.c, inv.d * x + inv.e * y + inv.f
        # pixel (r, c)'s value sits at its centre (c + 0.5, r + 0.5) of the affine grid
        return np.column_stack([row - 0.5, col - 0.5])

    if step_m is None:
        c = 0.5 * (lo + hi)
        rc = to_pixels(np.array([c[0], c[0] + 10.0, c[0]]), np.array([c[1], c[1], c[1] + 10.0]))
        per_m = np.linalg.norm(rc[1:] - rc[0], axis=1) / 10.0  # pixels per metre, x and y
        step_m = max(0.5, float(1.0 / max(per_m.max(), 1e-12)))
    area = float(np.prod(np.maximum(hi - lo, step_m)))
    step_m = max(step_m, math.sqrt(area / MAX_NODES))
    xs, ys = _grid_axis(lo[0], hi[0], step_m), _grid_axis(lo[1], hi[1], step_m)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    rc = to_pixels(gx.ravel(), gy.ravel())
    nr, nc = data.shape
    r0 = np.floor(rc[:, 0]).astype(int)
    c0 = np.floor(rc[:, 1]).astype(int)
    # a node on the last pixel centre row/column reads that row/column (no neighbour beyond)
    r0 = np.where((r0 == nr - 1) & (rc[:, 0] <= nr - 1 + 1e-9), nr - 2, r0)
    c0 = np.where((c0 == nc - 1) & (rc[:, 1] <= nc - 1 + 1e-9), nc - 2, c0)
    inside = (r0 >= 0) & (c0 >= 0) & (r0 + 1 < nr) & (c0 + 1 < nc)
    rs, cs = np.clip(r0, 0, max(nr - 2, 0)), np.clip(c0, 0, max(nc - 2, 0))
    if nr < 2 or nc < 2:
        raise TerrainError(f"{label}: a raster of {nr} x {nc} pixels is too small to interpolate")
    holes = bad[rs, cs] | bad[rs + 1, cs] | bad[rs, cs + 1] | bad[rs + 1, cs + 1]
    missing = ~inside | holes
    if np.any(missing):
        i = int(np.argmax(missing))
        lat, lon, _ = enu_to_geodetic(np.array([gx.ravel()[i], gy.ravel()[i], 0.0]), origin)
        what = "has no data (nodata)" if inside[i] else "is outside the raster"
        raise TerrainError(
            f"{label}: does not cover the workspace: the ground at ENU "
            f"({gx.ravel()[i]:.1f}, {gy.ravel()[i]:.1f}) m (lat {float(lat):.6f}, "
            f"lon {float(lon):.6f}) {what}"
        )
    tr, tc = rc[:, 0] - rs, rc[:, 1] - cs
    h = (
        data[rs, cs] * (1 - tr) * (1 - tc)
        + data[rs + 1, cs] * tr * (1 - tc)
        + data[rs, cs + 1] * (1 - tr) * tc
        + data[rs + 1, cs + 1] * tr * tc
    )
    lat, lon, _ = enu_to_geodetic(
        np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)]), origin
    )
    _, _, z = pymap3d.geodetic2enu(lat, lon, h, origin.lat_deg, origin.lon_deg, origin.alt_m)
    # to the millimetre, as a plan file keeps it: the plan is checked on the ground it was made on
    ground = np.round(np.asarray(z, dtype=float).reshape(gx.shape), 3)
    return Terrain(float(xs[0]), float(ys[0]), float(step_m), ground, label)


def write_geotiff(
    path: str,
    heights_m: ArrayLike,
    west: float,
    north: float,
    pixel: float,
    crs: str = "EPSG:4326",
) -> None:
    """Write ``heights_m`` (rows north to south, columns west to east) as a one-band float32
    GeoTIFF whose north-west corner is ``(west, north)`` in ``crs`` and whose pixels are
    ``pixel`` wide and tall in its units (what the tests and the shipped example make
    their elevation models with)."""
    import rasterio
    from affine import Affine

    h = np.asarray(heights_m, dtype=np.float32)
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        height=h.shape[0],
        width=h.shape[1],
        count=1,
        dtype="float32",
        crs=crs,
        transform=Affine(pixel, 0.0, west, 0.0, -pixel, north),
        nodata=-9999.0,
        compress="deflate",
        predictor=3,
    ) as dst:
        dst.write(h, 1)


def terrain_from_profile(
    poles_xy: ArrayLike,
    ground_z_m: ArrayLike,
    lo_xy: ArrayLike,
    hi_xy: ArrayLike,
    step_m: float = 5.0,
    name: str = "",
) -> Terrain:
    """The ground from a line's towers alone (their files' ground altitudes, as mission
    ``z``): at any point, the ground at the nearest point of the line, linear between two
    towers, the end tower's beyond an end; level across the line. A grid over
    ``[lo_xy, hi_xy]`` at ``step_m`` (coarser past :data:`MAX_NODES`)."""
    p = np.asarray(poles_xy, dtype=float).reshape(-1, 2)
    g = np.asarray(ground_z_m, dtype=float).reshape(-1)
    if len(p) < 2 or len(g) != len(p):
        raise TerrainError("a ground profile needs at least 2 towers, each with its ground")
    lo, hi = np.asarray(lo_xy, dtype=float), np.asarray(hi_xy, dtype=float)
    area = float(np.prod(np.maximum(hi - lo, step_m)))
    step_m = max(float(step_m), math.sqrt(area / MAX_NODES))
    xs, ys = _grid_axis(lo[0], hi[0], step_m), _grid_axis(lo[1], hi[1], step_m)
    nodes = np.column_stack([c.ravel() for c in np.meshgrid(xs, ys, indexing="ij")])
    a, d = p[:-1], np.diff(p, axis=0)  # segments a + t d, t in [0, 1]
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-12)
    out = np.empty(len(nodes))
    for k in range(0, len(nodes), 20_000):  # nodes x segments in blocks
        q = nodes[k : k + 20_000, None, :] - a[None]
        t = np.clip(np.einsum("nsj,sj->ns", q, d) / dd, 0.0, 1.0)
        dist = np.linalg.norm(q - t[..., None] * d[None], axis=2)
        s = np.argmin(dist, axis=1)
        ts = t[np.arange(len(s)), s]
        out[k : k + 20_000] = g[s] + ts * (g[s + 1] - g[s])
    ground = np.round(out.reshape(len(xs), len(ys)), 3)
    return Terrain(float(xs[0]), float(ys[0]), float(step_m), ground, name)
