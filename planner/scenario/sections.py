"""Reading a scenario's YAML sections: typed values with key paths, boxes, limits, vehicles, solver.

:class:`ScenarioError` and ``Reader`` turn every wrong value into one line naming the file
and the key path (``vehicles[2].start``); the section readers here build the parts of a
:class:`planner.problem.Problem`: boxes of the workspace and the regions, per-axis limits,
the vehicles (a list, or a generator with grid starts and groups by fraction) and the solver
options.  A room of its own: everything that checks one YAML value against its type and
range, apart from how :func:`planner.scenario.parse_scenario` puts the sections together
and how :mod:`planner.scenario.spec` expands the spec.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from planner.assurance import AssuranceGoal
from planner.dynamics.limits import PX4_LIMIT_KEYS
from planner.errors import FileFieldError
from planner.mission_model import VehicleEntry, VehicleLimits, kind_of, name_problem, validate
from planner.problem import QP_SOLVERS, SolverMethod, SolverOptions, Vehicle
from planner.spec.cover import polygon_regions
from planner.spec.regions import Cylinder, Region, RegionKind, ShapeError

__all__ = ["ScenarioError"]


class ScenarioError(FileFieldError):
    """A mistake in a scenario file: ``"<file>: <key path>: <problem>"``."""


class Reader:
    """Typed access to YAML values that raises ScenarioError with the key path."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, path: str, problem: str) -> ScenarioError:
        return ScenarioError(self.source, path, problem)

    def mapping(self, value: Any, path: str, allowed: set[str] | None = None) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(path, f"expected a mapping, got {kind_of(value)}")
        for key in value:
            if not isinstance(key, str):
                raise self.fail(path, f"keys must be strings, got {key!r}")
            if allowed is not None and key not in allowed:
                raise self.fail(
                    join_key(path, key), f"unknown key (allowed: {', '.join(sorted(allowed))})"
                )
        return value

    def require(self, m: Mapping[str, Any], key: str, path: str) -> Any:
        if key not in m:
            raise self.fail(join_key(path, key), "missing")
        return m[key]

    def number(
        self,
        value: Any,
        path: str,
        *,
        positive: bool = False,
        nonnegative: bool = False,
    ) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(path, f"expected a number, got {kind_of(value)}")
        x = float(value)
        if not math.isfinite(x):
            raise self.fail(path, f"must be finite, got {x}")
        if positive and x <= 0:
            raise self.fail(path, f"must be > 0, got {x:g}")
        if nonnegative and x < 0:
            raise self.fail(path, f"must be >= 0, got {x:g}")
        return x

    def integer(self, value: Any, path: str, *, minimum: int | None = None) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(path, f"expected an integer, got {kind_of(value)}")
        if minimum is not None and value < minimum:
            raise self.fail(path, f"must be >= {minimum}, got {value}")
        return int(value)

    def vec3(self, value: Any, path: str) -> tuple[float, float, float]:
        if not isinstance(value, list | tuple) or len(value) != 3:
            raise self.fail(path, f"expected a list of 3 numbers [x, y, z], got {kind_of(value)}")
        x, y, z = (self.number(v, f"{path}[{i}]") for i, v in enumerate(value))
        return (x, y, z)

    def per_axis(self, value: Any, path: str) -> tuple[float, float, float]:
        """A positive limit: one number for all axes or [x, y, z]."""
        if isinstance(value, list | tuple):
            vals = self.vec3(value, path)
            for i, v in enumerate(vals):
                if v <= 0:
                    raise self.fail(f"{path}[{i}]", f"must be > 0, got {v:g}")
            return vals
        v = self.number(value, path, positive=True)
        return (v, v, v)

    def name(self, value: Any, path: str) -> str:
        problem = name_problem(value)  # as the mission model's names
        if problem is not None:
            raise self.fail(path, problem)
        return str(value)


def join_key(path: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{path}[{key}]"
    return f"{path}.{key}" if path else key


def _box(rd: Reader, value: Any, path: str) -> tuple[np.ndarray, np.ndarray]:
    """A box given as {min, max} or {center, half_size} (half_size scalar or per axis)."""
    m = rd.mapping(value, path, {"min", "max", "center", "half_size", "kind"})
    if "min" in m or "max" in m:
        if "center" in m or "half_size" in m:
            raise rd.fail(path, "give either min/max or center/half_size, not both")
        lo = np.array(rd.vec3(rd.require(m, "min", path), join_key(path, "min")))
        hi = np.array(rd.vec3(rd.require(m, "max", path), join_key(path, "max")))
    elif "center" in m:
        c = np.array(rd.vec3(m["center"], join_key(path, "center")))
        h = np.array(rd.per_axis(rd.require(m, "half_size", path), join_key(path, "half_size")))
        lo, hi = c - h, c + h
    else:
        raise rd.fail(path, "a box needs min/max or center/half_size")
    for i, axis in enumerate("xyz"):
        if not lo[i] < hi[i]:
            raise rd.fail(path, f"empty box: min {axis} {lo[i]:g} is not below max {hi[i]:g}")
    return lo, hi


def _pair(rd: Reader, value: Any, path: str, what: str) -> tuple[float, float]:
    if not isinstance(value, list | tuple) or len(value) != 2:
        raise rd.fail(path, f"expected a list of 2 numbers {what}, got {kind_of(value)}")
    a, b = (rd.number(v, f"{path}[{i}]") for i, v in enumerate(value))
    return (a, b)


def _heights(rd: Reader, m: Mapping[str, Any], path: str) -> tuple[float, float]:
    z = _pair(rd, rd.require(m, "z", path), join_key(path, "z"), "[bottom, top]")
    if not z[0] < z[1]:
        raise rd.fail(join_key(path, "z"), f"empty height range: {z[0]:g} is not below {z[1]:g}")
    return z


def read_region(
    rd: Reader, name: str, value: Any, path: str, kind: RegionKind
) -> tuple[Region, ...]:
    """A region: a box ({min, max} or {center, half_size}), turned about the vertical with
    ``yaw_deg`` (counter-clockwise from east) or ``bearing_deg`` (of its x axis, clockwise
    from north); a prism ``{polygon: [[x, y], ...], z: [bottom, top]}`` over a simple
    polygon (one that is not convex: its convex parts, :func:`planner.spec.cover.polygon_regions`);
    a cylinder ``{center: [x, y], radius: r, z: [bottom, top]}``."""
    got = _one_region(rd, name, value, path, kind)
    return got if isinstance(got, tuple) else (got,)


def _one_region(
    rd: Reader, name: str, value: Any, path: str, kind: RegionKind
) -> Region | tuple[Region, ...]:
    m = rd.mapping(value, path)
    if "polygon" in m:
        rd.mapping(value, path, {"polygon", "z", "kind"})
        poly = m["polygon"]
        if not isinstance(poly, list) or len(poly) < 3:
            raise rd.fail(
                join_key(path, "polygon"),
                f"expected at least 3 corners [x, y], got {kind_of(poly)}",
            )
        corners = [
            _pair(rd, c, join_key(join_key(path, "polygon"), i), "[x, y]")
            for i, c in enumerate(poly)
        ]
        z = _heights(rd, m, path)
        try:
            return polygon_regions(name, kind, corners, *z)
        except ShapeError as exc:
            raise rd.fail(join_key(path, "polygon"), str(exc)) from None
    if "radius" in m:
        rd.mapping(value, path, {"center", "radius", "z", "kind"})
        c = _pair(rd, rd.require(m, "center", path), join_key(path, "center"), "[x, y]")
        r = rd.number(m["radius"], join_key(path, "radius"), positive=True)
        return Region.of_shape(name, kind, Cylinder(c, r, *_heights(rd, m, path)))
    turn = [k for k in ("yaw_deg", "bearing_deg") if k in m]
    if turn:
        if len(turn) > 1:
            raise rd.fail(path, "give either yaw_deg or bearing_deg, not both")
        if "center" not in m:
            raise rd.fail(path, f"a turned box needs center/half_size (with {turn[0]})")
        deg = rd.number(m[turn[0]], join_key(path, turn[0]))
        yaw_deg = deg if turn[0] == "yaw_deg" else 90.0 - deg
        c3 = np.array(rd.vec3(m["center"], join_key(path, "center")))
        h = np.array(rd.per_axis(rd.require(m, "half_size", path), join_key(path, "half_size")))
        rd.mapping(value, path, {"center", "half_size", "kind", turn[0]})
        return Region.turned_box(name, kind, c3, h, math.radians(yaw_deg))
    lo, hi = _box(rd, value, path)
    return Region(name, kind, tuple(lo.tolist()), tuple(hi.tolist()))


#: PX4-like limits (:mod:`planner.dynamics.limits`): horizontal norm and vertical up/down, for the
#: velocity and the acceleration; with the per-axis ``v_max_m_s``/``a_max_m_s2`` each holds.
_PX4_LIMITS = PX4_LIMIT_KEYS


def _per_axis_caps(
    rd: Reader, path: str, lim: dict[str, Any], per_axis: str, xy: str, up: str, down: str
) -> tuple[float, float, float]:
    """The per-axis caps of a vehicle: as given, or from the PX4-like limits when only
    those are (``[xy, xy, max(up, down)]``: every bound then still holds on its own)."""
    if per_axis in lim:
        return tuple(lim[per_axis])
    missing = [k for k in (xy, up, down) if k not in lim]
    if missing:
        raise rd.fail(
            join_key(path, "limits"),
            f"{per_axis} missing (give it in limits, or all of {xy}, {up}, {down}; "
            f"missing: {', '.join(missing)})",
        )
    return (lim[xy], lim[xy], max(lim[up], lim[down]))


def read_limits(rd: Reader, value: Any, path: str, base: dict[str, Any]) -> dict[str, Any]:
    """A ``limits:`` mapping over ``base`` (the scenario's, for a vehicle's own): the fields
    of :class:`planner.mission_model.VehicleLimits`, the model the plan file keeps them in."""
    m = rd.mapping(value, path, set(VehicleLimits.model_fields))
    out = dict(base)
    out.update(validate(VehicleLimits, m, rd.fail, path).given())
    return out


def _grid_starts(rd: Reader, value: Any, path: str, count: int) -> list[np.ndarray]:
    """``count`` deterministic start points: a grid in a box filled x fastest, then y, then z."""
    m = rd.mapping(value, path, {"grid", "positions"})
    if "positions" in m:
        p = join_key(path, "positions")
        pos = m["positions"]
        if not isinstance(pos, list):
            raise rd.fail(p, "expected a list of [x, y, z]")
        if len(pos) < count:
            raise rd.fail(p, f"{len(pos)} positions for {count} vehicles")
        return [np.array(rd.vec3(v, f"{p}[{i}]")) for i, v in enumerate(pos[:count])]
    g_path = join_key(path, "grid")
    g = rd.mapping(rd.require(m, "grid", path), g_path, {"min", "max", "shape"})
    lo = np.array(rd.vec3(rd.require(g, "min", g_path), join_key(g_path, "min")))
    hi = np.array(rd.vec3(rd.require(g, "max", g_path), join_key(g_path, "max")))
    shape_v = rd.require(g, "shape", g_path)
    if not isinstance(shape_v, list) or len(shape_v) != 3:
        raise rd.fail(join_key(g_path, "shape"), "expected [nx, ny, nz]")
    shape = [rd.integer(s, f"{g_path}.shape[{i}]", minimum=1) for i, s in enumerate(shape_v)]
    if math.prod(shape) < count:
        raise rd.fail(g_path, f"grid {shape} has {math.prod(shape)} points for {count} vehicles")
    axes = [np.linspace(lo[i], hi[i], shape[i]) if shape[i] > 1 else [lo[i]] for i in range(3)]
    pts = list(itertools.product(axes[2], axes[1], axes[0]))[:count]
    return [np.array(p[::-1], dtype=float) for p in pts]


def read_vehicles(
    rd: Reader,
    value: Any,
    limits: dict[str, Any],
    vehicles_override: int | None,
) -> tuple[list[Vehicle], dict[str, list[str]]]:
    groups: dict[str, list[str]] = {}
    out: list[Vehicle] = []
    if isinstance(value, list):
        if vehicles_override is not None:
            raise rd.fail(
                "vehicles", "this scenario lists its vehicles; --vehicles needs a generator"
            )
        if not value:
            raise rd.fail("vehicles", "no vehicles")
        for i, v in enumerate(value):
            p = f"vehicles[{i}]"
            m = rd.mapping(v, p, set(VehicleEntry.model_fields))
            if "limits" in m:  # its unknown keys named with what is allowed
                rd.mapping(m["limits"], join_key(p, "limits"), set(VehicleLimits.model_fields))
            e = validate(VehicleEntry, m, rd.fail, p)  # the plan file's model of a vehicle
            lim = limits if e.limits is None else {**limits, **e.limits.given()}
            for g in e.groups:
                groups.setdefault(g, []).append(e.name)
            sysid = i + 1 if e.sysid is None else e.sysid
            out.append(_make_vehicle(rd, p, e.name, sysid, e.start, lim, tuple(e.groups)))
        return out, groups
    p = "vehicles"
    m = rd.mapping(value, p, {"count", "max_count", "name", "starts", "groups", "limits"})
    max_count = rd.integer(m.get("max_count", 16), join_key(p, "max_count"), minimum=1)
    count = rd.integer(rd.require(m, "count", p), join_key(p, "count"), minimum=1)
    if vehicles_override is not None:
        # Every group needs a vehicle: the fewest a grouped scenario takes is its groups.
        g_count = len(m["groups"]) if isinstance(m.get("groups"), list) else 0
        min_count = max(1, g_count)
        if not min_count <= vehicles_override <= max_count:
            why = f" ({g_count} groups)" if g_count > 1 else ""
            raise rd.fail(
                p,
                f"--vehicles {vehicles_override} is outside {min_count}..{max_count} "
                f"for this scenario{why}",
            )
        count = vehicles_override
    if count > max_count:
        raise rd.fail(join_key(p, "count"), f"{count} exceeds max_count {max_count}")
    pattern = m.get("name", "d{i}")
    if not isinstance(pattern, str) or "{i}" not in pattern:
        raise rd.fail(join_key(p, "name"), "expected a pattern containing {i}, e.g. 'd{i}'")
    starts = _grid_starts(rd, rd.require(m, "starts", p), join_key(p, "starts"), count)
    lim = read_limits(rd, m["limits"], join_key(p, "limits"), limits) if "limits" in m else limits
    # Groups by fraction: contiguous blocks in vehicle order, sizes rounded so that they sum
    # to the count (the first groups get the extra vehicle).
    g_spec = m.get("groups", [])
    if not isinstance(g_spec, list):
        raise rd.fail(join_key(p, "groups"), "expected a list of {name, fraction}")
    fractions: list[tuple[str, float]] = []
    for j, g in enumerate(g_spec):
        gp = f"{p}.groups[{j}]"
        gm = rd.mapping(g, gp, {"name", "fraction"})
        fractions.append(
            (
                rd.name(rd.require(gm, "name", gp), join_key(gp, "name")),
                rd.number(rd.require(gm, "fraction", gp), join_key(gp, "fraction"), positive=True),
            )
        )
    if fractions and abs(sum(f for _, f in fractions) - 1.0) > 1e-9:
        raise rd.fail(join_key(p, "groups"), "fractions must sum to 1")
    if fractions and count < len(fractions):
        raise rd.fail(p, f"{count} vehicles cannot fill {len(fractions)} groups")
    sizes = [math.floor(f * count) for _, f in fractions]
    for j in range(count - sum(sizes) if sizes else 0):
        sizes[j % len(sizes)] += 1
    member_of: list[tuple[str, ...]] = [() for _ in range(count)]
    idx = 0
    for (g, _), size in zip(fractions, sizes, strict=True):
        for _ in range(size):
            member_of[idx] = (g,)
            idx += 1
    for i in range(count):
        name = pattern.replace("{i}", str(i + 1))
        rd.name(name, join_key(p, "name"))
        for g in member_of[i]:
            groups.setdefault(g, []).append(name)
        start = tuple(starts[i].tolist())
        out.append(_make_vehicle(rd, p, name, i + 1, start, lim, member_of[i]))
    return out, groups


def _make_vehicle(
    rd: Reader,
    path: str,
    name: str,
    sysid: int,
    start: tuple[float, float, float],
    lim: dict[str, Any],
    groups: tuple[str, ...],
) -> Vehicle:
    v_max = _per_axis_caps(
        rd, path, lim, "v_max_m_s", "v_xy_max_m_s", "v_up_max_m_s", "v_down_max_m_s"
    )
    a_max = _per_axis_caps(
        rd, path, lim, "a_max_m_s2", "a_xy_max_m_s2", "a_up_max_m_s2", "a_down_max_m_s2"
    )
    return Vehicle(
        name=name,
        sysid=sysid,
        start_enu_m=start,
        v_max_m_s=v_max,
        a_max_m_s2=a_max,
        **{key: lim.get(key) for key in _PX4_LIMITS},
        thrust_min_m_s2=lim.get("thrust_min_m_s2"),
        thrust_max_m_s2=lim.get("thrust_max_m_s2"),
        body_rate_max_rad_s=lim.get("body_rate_max_rad_s"),
        groups=groups,
    )


def read_solver(rd: Reader, value: Any) -> SolverOptions:
    allowed = {
        "method",
        "hessian",
        "max_iter",
        "tol",
        "k",
        "continuation",
        "robustness_constraint",
        "constraint_dt_s",
        "robustness_cap_m",
        "lbfgs_history",
        "qpsol",
        "separation_curvature",
        "print_level",
        "starts",
        "polish_s",
        "lexicographic_rounds",
        "coarse_s",
        "screen",
    }
    m = rd.mapping(value, "solver", allowed)
    kw: dict[str, Any] = {}
    if "method" in m:
        try:
            kw["method"] = SolverMethod(m["method"])
        except ValueError:
            raise rd.fail(
                "solver.method", f"unknown method {m['method']!r} (ipopt, sqpmethod)"
            ) from None
    if "hessian" in m:
        if m["hessian"] not in ("exact", "limited-memory"):
            raise rd.fail("solver.hessian", "expected 'exact' or 'limited-memory'")
        kw["hessian"] = m["hessian"]
    elif kw.get("method") is SolverMethod.SQP:
        # sqpmethod's measured default: an exact (indefinite) Hessian has to be regularised
        # into crawling steps (benchmarks/bench_solvers.py); BFGS converges.
        kw["hessian"] = "limited-memory"
    if "max_iter" in m:
        kw["max_iter"] = rd.integer(m["max_iter"], "solver.max_iter", minimum=1)
    if "tol" in m:
        kw["tol"] = rd.number(m["tol"], "solver.tol", positive=True)
    if "k" in m and m["k"] != "auto":
        kw["k"] = rd.number(m["k"], "solver.k", positive=True)
    if "continuation" in m:
        c = m["continuation"]
        if not isinstance(c, list):
            raise rd.fail("solver.continuation", "expected a list of k values")
        kw["continuation"] = tuple(
            rd.number(x, f"solver.continuation[{i}]", positive=True) for i, x in enumerate(c)
        )
    if "robustness_constraint" in m:
        if not isinstance(m["robustness_constraint"], bool):
            raise rd.fail("solver.robustness_constraint", "expected true or false")
        kw["robustness_constraint"] = m["robustness_constraint"]
    if "constraint_dt_s" in m:
        kw["constraint_dt_s"] = rd.number(
            m["constraint_dt_s"], "solver.constraint_dt_s", positive=True
        )
    if "robustness_cap_m" in m:
        kw["robustness_cap_m"] = rd.number(
            m["robustness_cap_m"], "solver.robustness_cap_m", positive=True
        )
    if "qpsol" in m:
        if m["qpsol"] not in QP_SOLVERS:
            raise rd.fail(
                "solver.qpsol", f"unknown QP solver {m['qpsol']!r} ({', '.join(QP_SOLVERS)})"
            )
        kw["qpsol"] = m["qpsol"]
    if "lbfgs_history" in m:
        kw["lbfgs_history"] = rd.integer(m["lbfgs_history"], "solver.lbfgs_history", minimum=1)
    if "separation_curvature" in m:
        if not isinstance(m["separation_curvature"], bool):
            raise rd.fail("solver.separation_curvature", "expected true or false")
        kw["separation_curvature"] = m["separation_curvature"]
    if "print_level" in m:
        kw["print_level"] = rd.integer(m["print_level"], "solver.print_level", minimum=0)
    if "starts" in m:
        kw["starts"] = rd.integer(m["starts"], "solver.starts", minimum=1)
    if "polish_s" in m:
        kw["polish_s"] = rd.number(m["polish_s"], "solver.polish_s", nonnegative=True)
    if "coarse_s" in m:
        kw["coarse_s"] = rd.number(m["coarse_s"], "solver.coarse_s", nonnegative=True)
    if "screen" in m and m["screen"] != "auto":
        if not isinstance(m["screen"], bool):
            raise rd.fail("solver.screen", "expected auto, true or false")
        kw["screen"] = m["screen"]
    if "lexicographic_rounds" in m:
        kw["lexicographic_rounds"] = rd.integer(
            m["lexicographic_rounds"], "solver.lexicographic_rounds", minimum=0
        )
    return SolverOptions(**kw)


def read_assurance(rd: Reader, value: Any) -> AssuranceGoal:
    """The ``assurance`` section: ``probability`` (required, in (0, 1)), ``disturbances``
    (``{name: distribution}``, as ``gcs assess -d``; the names and distributions are checked
    where the campaign is set up), ``runs``, ``final_runs``, ``rounds``, ``seed``,
    ``budget_s``."""
    allowed = {"probability", "disturbances", "runs", "final_runs", "rounds", "seed", "budget_s"}
    m = rd.mapping(value, "assurance", allowed)
    p = rd.number(rd.require(m, "probability", "assurance"), "assurance.probability")
    if not 0.0 < p < 1.0:
        raise rd.fail("assurance.probability", f"must be in (0, 1), got {p:g}")
    dist: dict[str, str] = {}
    for name, text in rd.mapping(m.get("disturbances", {}) or {}, "assurance.disturbances").items():
        key = join_key("assurance.disturbances", name)
        if isinstance(text, bool) or not isinstance(text, str | int | float):
            raise rd.fail(
                key, f"expected a distribution such as 'uniform(0, 6)', got {kind_of(text)}"
            )
        dist[name] = str(text)
    return AssuranceGoal(
        probability=p,
        disturbances=dist,
        runs=rd.integer(m.get("runs", 2000), "assurance.runs", minimum=1),
        final_runs=rd.integer(m.get("final_runs", 4000), "assurance.final_runs", minimum=1),
        rounds=rd.integer(m.get("rounds", 6), "assurance.rounds", minimum=1),
        seed=rd.integer(m.get("seed", 0), "assurance.seed", minimum=0),
        budget_s=rd.number(m.get("budget_s", 240.0), "assurance.budget_s", positive=True),
    )
