"""Scenario files: YAML -> a frozen :class:`Problem` (regions, vehicles, limits, timing, spec).

A scenario names everything the planner needs (see ``configs/*.yaml`` for commented examples)::

    name: reach_avoid
    origin: {lat: 47.3977, lon: 8.5456, alt: 488.0}        # geodetic, alt AMSL in metres
    workspace: {min: [-2, -2, 0], max: [2, 2, 2]}           # ENU metres
    regions:                                                # axis-aligned boxes
      obstacle: {kind: obstacle, min: [-1, -1, 0], max: [1, 1, 1.5]}
      goal: {kind: goal, center: [1.75, 1.75, 0.75], half_size: 0.25}
    limits: {v_max_m_s: 0.751, a_max_m_s2: 1.0}             # scalar or [x, y, z] per axis
    vehicles:                                               # a list of vehicles ...
      - {name: d1, start: [-1.5, -1.5, 0.5]}
    # ... or a generator, whose count `gcs plan --vehicles N` overrides:
    # vehicles: {count: 2, max_count: 16, name: "d{i}",
    #            starts: {grid: {min: [...], max: [...], shape: [nx, ny, nz]}},
    #            groups: [{name: g1, fraction: 0.5}, {name: g2, fraction: 0.5}]}
    groups: {pair: [d1, d2]}                                # optional; `all` always exists
    timing: {horizon_s: 6, segment_s: 1, Ts_s: 0.05}
    separation_m: 0.2
    epsilon: 0.01
    model: minimum_jerk                                     # or double_integrator
    constants: {t_hover: 1}                                 # usable in the spec as $t_hover
    spec:                                                   # the conjunction of the clauses
      - each: d in all
        formula: eventually[0, $horizon] inside(d, goal)
      - each: (a, b) in pairs(all)
        formula: always[0, $horizon] dist(a, b) >= $separation

Repetition: a clause's ``each`` binds identifiers (``d in GROUP``, ``d in [d1, d3]``,
``(a, b) in pairs(GROUP)`` for the unordered pairs); a list of bindings takes the product.
The bound identifiers are replaced token by token in ``formula``; ``$name`` is replaced by a
constant (``$horizon``, ``$half_horizon``, ``$separation``, ``$epsilon`` and the scenario's
``constants``).  The expanded text (:attr:`Problem.spec_text`) is plain STL and parses on its
own (``gcs plan --print-spec``).

Errors (one tree, everything a user can get wrong in a file)::

    ScenarioError(FileFieldError)    names the file, the key path (``vehicles[2].start``) and the problem
"""

from __future__ import annotations

import enum
import itertools
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from planner.errors import FileFieldError
from planner.frames import GeodeticPoint
from planner.predicates import PREDICATES, build_registry
from planner.regions import Region, RegionKind
from planner.scenario_checks import clause_findings, horizon_sum, start_findings
from planner.stl import (
    BinOp,
    Comparison,
    Expr,
    Formula,
    FunctionRegistry,
    Neg,
    Signal,
    SpecError,
    parse,
)

__all__ = [
    "FUNCTION_NAMES",
    "Clause",
    "DynamicsModel",
    "Problem",
    "Region",
    "RegionKind",
    "ScenarioError",
    "SolverMethod",
    "SolverOptions",
    "Timing",
    "Vehicle",
    "load_scenario",
    "parse_clause",
    "parse_scenario",
]

#: Function predicates a scenario's spec may call, with the kinds of their arguments
#: (``v`` a vehicle, ``r`` a region): :data:`planner.predicates.PREDICATES`.
FUNCTION_NAMES: dict[str, tuple[str, ...]] = {p.name: p.args for p in PREDICATES.values()}


#: Longest mission a scenario may plan (s): an hour is beyond any quad-rotor's battery.
MAX_HORIZON_S = 3600.0


class ScenarioError(FileFieldError):
    """A mistake in a scenario file: ``"<file>: <key path>: <problem>"``."""


class DynamicsModel(enum.Enum):
    """Which linear vehicle model the planner optimises over (:mod:`planner.dynamics`)."""

    MINIMUM_JERK = "minimum_jerk"
    DOUBLE_INTEGRATOR = "double_integrator"


class SolverMethod(enum.Enum):
    """NLP method: interior point (IPOPT) or CasADi's SQP (``solver.qpsol`` for its QPs)."""

    IPOPT = "ipopt"
    SQP = "sqpmethod"


@dataclass(frozen=True, slots=True)
class Vehicle:
    """One vehicle: start state at rest and its per-axis limits (ENU axes)."""

    name: str
    sysid: int
    start_enu_m: tuple[float, float, float]
    v_max_m_s: tuple[float, float, float]
    a_max_m_s2: tuple[float, float, float]
    #: Mass-normalised thrust range (m/s^2) for Mueller's feasibility check, or None.
    thrust_min_m_s2: float | None = None
    thrust_max_m_s2: float | None = None
    #: Body-rate bound (rad/s) for Mueller's feasibility check, or None.
    body_rate_max_rad_s: float | None = None
    groups: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class Timing:
    """Time grid: horizon, primitive segment length, planning sample step, checking step (s)."""

    horizon_s: float
    segment_s: float
    sample_dt_s: float
    check_dt_s: float

    @property
    def n_samples(self) -> int:
        """Planning samples t = 0, Ts, ..., horizon (inclusive)."""
        return round(self.horizon_s / self.sample_dt_s) + 1


#: QP solvers of CasADi's wheel that sqpmethod can use here (convex QPs, sparse or dense).
QP_SOLVERS: tuple[str, ...] = ("piqp", "qpoases", "osqp", "proxqp", "highs", "qrqp")


@dataclass(frozen=True, slots=True)
class SolverOptions:
    """How to solve; every field has a measured default (see planner.optimize)."""

    method: SolverMethod = SolverMethod.IPOPT
    #: "exact" or "limited-memory" (IPOPT hessian_approximation; BFGS for sqpmethod, whose
    #: default in a scenario is limited-memory).
    hessian: str = "exact"
    max_iter: int = 300
    #: IPOPT's tolerance on the scaled NLP error.  Robustness is in metres, so 1e-4 is
    #: 0.1 mm; 1e-6 spent a third to a half of the iterations polishing digits nobody
    #: flies (reach-avoid N = 8: 91 -> 75 iterations, robustness 0.0477 -> 0.0471).
    tol: float = 1e-4
    #: Smoothing sharpness k of the top-level soft min/max; None: fitted to the problem.
    k: float | None = None
    #: Solve with these k in turn (warm started), ending at ``k``; empty: a single solve.
    continuation: tuple[float, ...] = ()
    #: Add the paper's constraint smooth robustness >= epsilon (+ margin) to the maximisation.
    robustness_constraint: bool = False
    #: Spacing (s) of the row-wise constraints (separation, obstacles, boxes) in the NLP;
    #: None: max(Ts, 0.1 s).  The exact check afterwards uses every check_dt_s regardless.
    constraint_dt_s: float | None = None
    #: Upper bound (m) on the maximised robustness: once the spec holds with this margin
    #: the NLP only has to settle (smoothness term), not squeeze out the last centimetres;
    #: None: unbounded (the plain maximisation).
    robustness_cap_m: float | None = None
    #: QP solver of ``sqpmethod`` (one that ships with CasADi's wheel).
    qpsol: str = "piqp"
    #: IPOPT limited_memory_max_history (pairs kept by L-BFGS; IPOPT's default 6).
    lbfgs_history: int = 6
    #: Keep the curvature of the separation rows ``dist(a, b) >= s`` in the exact
    #: Hessian.  Off by default: it is negative (keeping apart is reverse-convex) and made
    #: IPOPT correct the inertia, i.e. factorise again, in most iterations.
    separation_curvature: bool = False
    print_level: int = 0


@dataclass(frozen=True, slots=True)
class Clause:
    """One top-level conjunct of the spec after expansion."""

    key_path: str
    text: str


@dataclass(frozen=True, slots=True)
class Problem:
    """A validated scenario, ready for :func:`planner.optimize.plan`."""

    name: str
    source: str
    origin: GeodeticPoint
    workspace: Region
    regions: tuple[Region, ...]
    vehicles: tuple[Vehicle, ...]
    groups: Mapping[str, tuple[str, ...]]
    timing: Timing
    separation_m: float
    epsilon: float
    model: DynamicsModel
    solver: SolverOptions
    clauses: tuple[Clause, ...]
    constants: Mapping[str, float] = field(default_factory=dict)
    #: The clauses parsed at load (exact and smooth semantics), in order; empty for a
    #: problem made otherwise (``dataclasses.replace``), which is parsed where it is used.
    formulas: tuple[Formula, ...] = field(default=(), init=False, repr=False, compare=False)

    def __getstate__(self) -> list[Any]:
        """Pickled without the parsed clauses (their functions are closures over the regions);
        the planner parses the copy's again."""
        return [() if f.name == "formulas" else getattr(self, f.name) for f in fields(self)]

    @property
    def spec_text(self) -> str:
        """The expanded STL text: the conjunction of the clauses, one per line."""
        if len(self.clauses) == 1:
            return self.clauses[0].text
        return " and\n".join(f"({c.text})" for c in self.clauses)

    def region(self, name: str) -> Region:
        """The region called ``name`` (``workspace`` included); KeyError if unknown."""
        if name == self.workspace.name:
            return self.workspace
        for r in self.regions:
            if r.name == name:
                return r
        raise KeyError(name)

    @property
    def all_regions(self) -> tuple[Region, ...]:
        """The workspace followed by the named regions."""
        return (self.workspace, *self.regions)


# ----------------------------------------------------------------------------------- parsing


_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_RESERVED = {
    "true",
    "false",
    "not",
    "and",
    "or",
    "implies",
    "always",
    "eventually",
    "until",
    "G",
    "F",
    "U",
    "pairs",
    "in",
    *FUNCTION_NAMES,
}
_TOP_KEYS = {
    "name",
    "origin",
    "workspace",
    "regions",
    "limits",
    "vehicles",
    "groups",
    "timing",
    "separation_m",
    "epsilon",
    "model",
    "solver",
    "constants",
    "spec",
    "description",
}


class _Reader:
    """Typed access to YAML values that raises ScenarioError with the key path."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, path: str, problem: str) -> ScenarioError:
        return ScenarioError(self.source, path, problem)

    def mapping(self, value: Any, path: str, allowed: set[str] | None = None) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(path, f"expected a mapping, got {_kind(value)}")
        for key in value:
            if not isinstance(key, str):
                raise self.fail(path, f"keys must be strings, got {key!r}")
            if allowed is not None and key not in allowed:
                raise self.fail(
                    _join(path, key), f"unknown key (allowed: {', '.join(sorted(allowed))})"
                )
        return value

    def require(self, m: Mapping[str, Any], key: str, path: str) -> Any:
        if key not in m:
            raise self.fail(_join(path, key), "missing")
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
            raise self.fail(path, f"expected a number, got {_kind(value)}")
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
            raise self.fail(path, f"expected an integer, got {_kind(value)}")
        if minimum is not None and value < minimum:
            raise self.fail(path, f"must be >= {minimum}, got {value}")
        return int(value)

    def vec3(self, value: Any, path: str) -> tuple[float, float, float]:
        if not isinstance(value, list | tuple) or len(value) != 3:
            raise self.fail(path, f"expected a list of 3 numbers [x, y, z], got {_kind(value)}")
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
        if not isinstance(value, str) or not _NAME_RE.match(value):
            raise self.fail(path, f"expected an identifier (letters, digits, _), got {value!r}")
        if value in _RESERVED:
            raise self.fail(path, f"{value!r} is a reserved word of the spec language")
        return value


def _kind(value: Any) -> str:
    if value is None:
        return "nothing"
    return f"{type(value).__name__} {value!r}" if not isinstance(value, dict) else "a mapping"


def _join(path: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{path}[{key}]"
    return f"{path}.{key}" if path else key


def _box(rd: _Reader, value: Any, path: str) -> tuple[np.ndarray, np.ndarray]:
    """A box given as {min, max} or {center, half_size} (half_size scalar or per axis)."""
    m = rd.mapping(value, path, {"min", "max", "center", "half_size", "kind"})
    if "min" in m or "max" in m:
        if "center" in m or "half_size" in m:
            raise rd.fail(path, "give either min/max or center/half_size, not both")
        lo = np.array(rd.vec3(rd.require(m, "min", path), _join(path, "min")))
        hi = np.array(rd.vec3(rd.require(m, "max", path), _join(path, "max")))
    elif "center" in m:
        c = np.array(rd.vec3(m["center"], _join(path, "center")))
        h = np.array(rd.per_axis(rd.require(m, "half_size", path), _join(path, "half_size")))
        lo, hi = c - h, c + h
    else:
        raise rd.fail(path, "a box needs min/max or center/half_size")
    for i, axis in enumerate("xyz"):
        if not lo[i] < hi[i]:
            raise rd.fail(path, f"empty box: min {axis} {lo[i]:g} is not below max {hi[i]:g}")
    return lo, hi


def _region(rd: _Reader, name: str, value: Any, path: str, kind: RegionKind) -> Region:
    lo, hi = _box(rd, value, path)
    return Region(name, kind, tuple(lo.tolist()), tuple(hi.tolist()))  # type: ignore[arg-type]


def _limits(rd: _Reader, value: Any, path: str, base: dict[str, Any]) -> dict[str, Any]:
    allowed = {"v_max_m_s", "a_max_m_s2", "thrust_m_s2", "body_rate_max_rad_s"}
    m = rd.mapping(value, path, allowed)
    out = dict(base)
    if "v_max_m_s" in m:
        out["v_max_m_s"] = rd.per_axis(m["v_max_m_s"], _join(path, "v_max_m_s"))
    if "a_max_m_s2" in m:
        out["a_max_m_s2"] = rd.per_axis(m["a_max_m_s2"], _join(path, "a_max_m_s2"))
    if "thrust_m_s2" in m:
        p = _join(path, "thrust_m_s2")
        t = m["thrust_m_s2"]
        if not isinstance(t, list) or len(t) != 2:
            raise rd.fail(p, "expected [min, max] mass-normalised thrust in m/s^2")
        lo = rd.number(t[0], f"{p}[0]", nonnegative=True)
        hi = rd.number(t[1], f"{p}[1]", positive=True)
        if not lo < hi:
            raise rd.fail(p, f"min {lo:g} must be below max {hi:g}")
        if hi <= 9.81:
            raise rd.fail(p, f"max thrust {hi:g} m/s^2 cannot hover (needs > 9.81)")
        out["thrust_min_m_s2"], out["thrust_max_m_s2"] = lo, hi
    if "body_rate_max_rad_s" in m:
        out["body_rate_max_rad_s"] = rd.number(
            m["body_rate_max_rad_s"], _join(path, "body_rate_max_rad_s"), positive=True
        )
    return out


def _grid_starts(rd: _Reader, value: Any, path: str, count: int) -> list[np.ndarray]:
    """``count`` deterministic start points: a grid in a box filled x fastest, then y, then z."""
    m = rd.mapping(value, path, {"grid", "positions"})
    if "positions" in m:
        p = _join(path, "positions")
        pos = m["positions"]
        if not isinstance(pos, list):
            raise rd.fail(p, "expected a list of [x, y, z]")
        if len(pos) < count:
            raise rd.fail(p, f"{len(pos)} positions for {count} vehicles")
        return [np.array(rd.vec3(v, f"{p}[{i}]")) for i, v in enumerate(pos[:count])]
    g_path = _join(path, "grid")
    g = rd.mapping(rd.require(m, "grid", path), g_path, {"min", "max", "shape"})
    lo = np.array(rd.vec3(rd.require(g, "min", g_path), _join(g_path, "min")))
    hi = np.array(rd.vec3(rd.require(g, "max", g_path), _join(g_path, "max")))
    shape_v = rd.require(g, "shape", g_path)
    if not isinstance(shape_v, list) or len(shape_v) != 3:
        raise rd.fail(_join(g_path, "shape"), "expected [nx, ny, nz]")
    shape = [rd.integer(s, f"{g_path}.shape[{i}]", minimum=1) for i, s in enumerate(shape_v)]
    if math.prod(shape) < count:
        raise rd.fail(g_path, f"grid {shape} has {math.prod(shape)} points for {count} vehicles")
    axes = [np.linspace(lo[i], hi[i], shape[i]) if shape[i] > 1 else [lo[i]] for i in range(3)]
    pts = list(itertools.product(axes[2], axes[1], axes[0]))[:count]
    return [np.array(p[::-1], dtype=float) for p in pts]


def _vehicles(
    rd: _Reader,
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
            m = rd.mapping(v, p, {"name", "start", "sysid", "limits", "groups"})
            name = rd.name(rd.require(m, "name", p), _join(p, "name"))
            sysid = rd.integer(m.get("sysid", i + 1), _join(p, "sysid"), minimum=1)
            start = rd.vec3(rd.require(m, "start", p), _join(p, "start"))
            lim = _limits(rd, m["limits"], _join(p, "limits"), limits) if "limits" in m else limits
            gs = m.get("groups", [])
            if not isinstance(gs, list):
                raise rd.fail(_join(p, "groups"), "expected a list of group names")
            g_names = tuple(rd.name(g, f"{p}.groups[{j}]") for j, g in enumerate(gs))
            for g in g_names:
                groups.setdefault(g, []).append(name)
            out.append(_make_vehicle(rd, p, name, sysid, start, lim, g_names))
        return out, groups
    p = "vehicles"
    m = rd.mapping(value, p, {"count", "max_count", "name", "starts", "groups", "limits"})
    max_count = rd.integer(m.get("max_count", 16), _join(p, "max_count"), minimum=1)
    count = rd.integer(rd.require(m, "count", p), _join(p, "count"), minimum=1)
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
        raise rd.fail(_join(p, "count"), f"{count} exceeds max_count {max_count}")
    pattern = m.get("name", "d{i}")
    if not isinstance(pattern, str) or "{i}" not in pattern:
        raise rd.fail(_join(p, "name"), "expected a pattern containing {i}, e.g. 'd{i}'")
    starts = _grid_starts(rd, rd.require(m, "starts", p), _join(p, "starts"), count)
    lim = _limits(rd, m["limits"], _join(p, "limits"), limits) if "limits" in m else limits
    # Groups by fraction: contiguous blocks in vehicle order, sizes rounded so that they sum
    # to the count (the first groups get the extra vehicle).
    g_spec = m.get("groups", [])
    if not isinstance(g_spec, list):
        raise rd.fail(_join(p, "groups"), "expected a list of {name, fraction}")
    fractions: list[tuple[str, float]] = []
    for j, g in enumerate(g_spec):
        gp = f"{p}.groups[{j}]"
        gm = rd.mapping(g, gp, {"name", "fraction"})
        fractions.append(
            (
                rd.name(rd.require(gm, "name", gp), _join(gp, "name")),
                rd.number(rd.require(gm, "fraction", gp), _join(gp, "fraction"), positive=True),
            )
        )
    if fractions and abs(sum(f for _, f in fractions) - 1.0) > 1e-9:
        raise rd.fail(_join(p, "groups"), "fractions must sum to 1")
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
        rd.name(name, _join(p, "name"))
        for g in member_of[i]:
            groups.setdefault(g, []).append(name)
        start = tuple(starts[i].tolist())
        out.append(_make_vehicle(rd, p, name, i + 1, start, lim, member_of[i]))  # type: ignore[arg-type]
    return out, groups


def _make_vehicle(
    rd: _Reader,
    path: str,
    name: str,
    sysid: int,
    start: tuple[float, float, float],
    lim: dict[str, Any],
    groups: tuple[str, ...],
) -> Vehicle:
    for key in ("v_max_m_s", "a_max_m_s2"):
        if key not in lim:
            raise rd.fail(_join(path, "limits"), f"{key} missing (give it in limits)")
    return Vehicle(
        name=name,
        sysid=sysid,
        start_enu_m=start,
        v_max_m_s=lim["v_max_m_s"],
        a_max_m_s2=lim["a_max_m_s2"],
        thrust_min_m_s2=lim.get("thrust_min_m_s2"),
        thrust_max_m_s2=lim.get("thrust_max_m_s2"),
        body_rate_max_rad_s=lim.get("body_rate_max_rad_s"),
        groups=groups,
    )


_BIND_ONE = re.compile(r"^\s*([A-Za-z_]\w*)\s+in\s+(.+?)\s*$")
_BIND_PAIR = re.compile(r"^\s*\(\s*([A-Za-z_]\w*)\s*,\s*([A-Za-z_]\w*)\s*\)\s+in\s+(.+?)\s*$")
_PAIRS = re.compile(r"^pairs\(\s*(.+?)\s*\)$")
_LIST = re.compile(r"^\[(.*)\]$")
_DOLLAR = re.compile(r"\$([A-Za-z_]\w*)")
_CALL = re.compile(r"\b([A-Za-z_]\w*)\s*\(([^()]*)\)")


def _collection(
    rd: _Reader, text: str, path: str, groups: Mapping[str, Sequence[str]]
) -> list[str]:
    lm = _LIST.match(text)
    if lm:
        items = [s.strip() for s in lm.group(1).split(",") if s.strip()]
        if not items:
            raise rd.fail(path, "empty list")
        for it in items:
            if not _NAME_RE.match(it):
                raise rd.fail(path, f"{it!r} is not a name")
        return items
    if text in groups:
        return list(groups[text])
    raise rd.fail(path, f"unknown group {text!r} (groups: {', '.join(sorted(groups))})")


def _bindings(
    rd: _Reader, value: Any, path: str, groups: Mapping[str, Sequence[str]]
) -> list[dict[str, str]]:
    """All assignments of the clause's ``each`` (a string or a list: product of bindings)."""
    items = value if isinstance(value, list) else [value]
    per: list[list[dict[str, str]]] = []
    for j, b in enumerate(items):
        p = f"{path}[{j}]" if isinstance(value, list) else path
        if not isinstance(b, str):
            raise rd.fail(p, "expected 'VAR in GROUP', 'VAR in [a, b]' or '(A, B) in pairs(GROUP)'")
        pm = _BIND_PAIR.match(b)
        if pm:
            a, c, coll = pm.groups()
            pairs_m = _PAIRS.match(coll)
            if not pairs_m:
                raise rd.fail(p, f"a pair binding needs pairs(GROUP), got {coll!r}")
            members = _collection(rd, pairs_m.group(1), p, groups)
            per.append([{a: u, c: v} for u, v in itertools.combinations(members, 2)])
            continue
        om = _BIND_ONE.match(b)
        if not om:
            raise rd.fail(p, f"cannot read binding {b!r}; expected 'VAR in GROUP'")
        var, coll = om.groups()
        if _PAIRS.match(coll):
            raise rd.fail(p, "pairs(...) binds two names: write '(a, b) in pairs(GROUP)'")
        per.append([{var: m} for m in _collection(rd, coll, p, groups)])
    out: list[dict[str, str]] = []
    for combo in itertools.product(*per):
        merged: dict[str, str] = {}
        for d in combo:
            merged.update(d)
        out.append(merged)
    return out


def _substitute(text: str, binding: Mapping[str, str]) -> str:
    if not binding:
        return text
    pattern = re.compile(r"\b(" + "|".join(re.escape(k) for k in binding) + r")\b")
    return pattern.sub(lambda m: binding[m.group(1)], text)


def _fmt(x: float) -> str:
    return f"{x:.12g}"


def _expand_spec(
    rd: _Reader,
    value: Any,
    groups: Mapping[str, Sequence[str]],
    constants: Mapping[str, float],
) -> list[Clause]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value:
        raise rd.fail("spec", "expected a non-empty list of clauses (or one STL string)")
    clauses: list[Clause] = []
    for i, c in enumerate(value):
        p = f"spec[{i}]"
        if isinstance(c, str):
            formula, each = c, None
        else:
            m = rd.mapping(c, p, {"formula", "each", "name"})
            formula = rd.require(m, "formula", p)
            if not isinstance(formula, str):
                raise rd.fail(_join(p, "formula"), "expected STL text")
            each = m.get("each")
        fpath = p if isinstance(c, str) else _join(p, "formula")

        def dollar(mt: re.Match[str], fpath: str = fpath) -> str:
            key = mt.group(1)
            if key not in constants:
                raise rd.fail(
                    fpath, f"unknown constant ${key} (known: {', '.join(sorted(constants))})"
                )
            return _fmt(constants[key])

        formula = _DOLLAR.sub(dollar, formula)
        binds = [{}] if each is None else _bindings(rd, each, _join(p, "each"), groups)
        for b in binds:
            text = " ".join(_substitute(formula, b).split())
            clauses.append(Clause(fpath, text))
    return clauses


def _check_calls(
    rd: _Reader,
    clauses: Sequence[Clause],
    vehicles: set[str],
    regions: set[str],
) -> None:
    """Every function call names a known predicate with arguments of the right kinds."""
    for cl in clauses:
        for mt in _CALL.finditer(cl.text):
            fn, args_text = mt.group(1), mt.group(2)
            if fn not in FUNCTION_NAMES:
                raise rd.fail(
                    cl.key_path,
                    f"unknown function {fn!r} in {cl.text!r} (known: {', '.join(FUNCTION_NAMES)})",
                )
            args = [a.strip() for a in args_text.split(",")] if args_text.strip() else []
            kinds = FUNCTION_NAMES[fn]
            if len(args) != len(kinds):
                raise rd.fail(
                    cl.key_path,
                    f"{fn} takes {len(kinds)} argument(s), got {len(args)} in {mt[0]!r}",
                )
            for a, k in zip(args, kinds, strict=True):
                if k == "v" and a not in vehicles:
                    raise rd.fail(cl.key_path, f"unknown vehicle {a!r} in {mt[0]!r}")
                if k == "r" and a not in regions:
                    raise rd.fail(
                        cl.key_path,
                        f"unknown region {a!r} in {mt[0]!r} (regions: {', '.join(sorted(regions))})",
                    )


def parse_scenario(
    data: Any,
    source: str = "<scenario>",
    *,
    vehicles: int | None = None,
) -> Problem:
    """Validate scenario data (already loaded from YAML) into a :class:`Problem`.

    ``vehicles`` overrides the generator's vehicle count (``gcs plan --vehicles N``).
    Raises :class:`ScenarioError` naming ``source`` and the key path of the first mistake;
    the expanded spec is parsed with the STL engine, so a spec syntax error is reported here.
    """
    rd = _Reader(source)
    top = rd.mapping(data, "", _TOP_KEYS)
    name = top.get("name", Path(source).stem)
    if not isinstance(name, str):
        raise rd.fail("name", "expected a string")

    o = rd.mapping(rd.require(top, "origin", ""), "origin", {"lat", "lon", "alt"})
    lat = rd.number(rd.require(o, "lat", "origin"), "origin.lat")
    lon = rd.number(rd.require(o, "lon", "origin"), "origin.lon")
    alt = rd.number(rd.require(o, "alt", "origin"), "origin.alt")
    if not -90 <= lat <= 90:
        raise rd.fail("origin.lat", f"latitude {lat:g} is outside [-90, 90]")
    if not -180 <= lon <= 180:
        raise rd.fail("origin.lon", f"longitude {lon:g} is outside [-180, 180]")
    origin = GeodeticPoint(lat_deg=lat, lon_deg=lon, alt_m=alt)

    workspace = _region(
        rd, "workspace", rd.require(top, "workspace", ""), "workspace", RegionKind.WORKSPACE
    )

    regions: list[Region] = []
    reg_map = top.get("regions", {}) or {}
    rd.mapping(reg_map, "regions")
    for rname, rval in reg_map.items():
        p = _join("regions", rname)
        rd.name(rname, p)
        if rname == "workspace":
            raise rd.fail(p, "'workspace' is defined by the top-level workspace key")
        rm = rd.mapping(rval, p)
        kind_s = rm.get("kind", "region")
        try:
            kind = RegionKind(kind_s)
        except ValueError:
            raise rd.fail(
                _join(p, "kind"),
                f"unknown kind {kind_s!r} (kinds: {', '.join(k.value for k in RegionKind)})",
            ) from None
        regions.append(_region(rd, rname, rval, p, kind))

    limits: dict[str, Any] = {}
    if "limits" in top:
        limits = _limits(rd, top["limits"], "limits", {})

    vlist, groups = _vehicles(rd, rd.require(top, "vehicles", ""), limits, vehicles)
    names = [v.name for v in vlist]
    region_names = {"workspace"} | {r.name for r in regions}
    seen: set[str] = set()
    for i, v in enumerate(vlist):
        if v.name in seen:
            raise rd.fail(f"vehicles[{i}].name", f"duplicate vehicle name {v.name!r}")
        if v.name in region_names:
            raise rd.fail(f"vehicles[{i}].name", f"{v.name!r} is also a region name")
        seen.add(v.name)
    sysids = [v.sysid for v in vlist]
    if len(set(sysids)) != len(sysids):
        raise rd.fail("vehicles", f"duplicate system ids {sysids}")

    g_top = top.get("groups", {}) or {}
    rd.mapping(g_top, "groups")
    for gname, members in g_top.items():
        p = _join("groups", gname)
        rd.name(gname, p)
        if gname == "all":
            raise rd.fail(p, "'all' is predefined (every vehicle)")
        if not isinstance(members, list) or not members:
            raise rd.fail(p, "expected a non-empty list of vehicle names")
        for j, mname in enumerate(members):
            if mname not in seen:
                raise rd.fail(f"{p}[{j}]", f"unknown vehicle {mname!r}")
        groups.setdefault(gname, [])
        groups[gname].extend(m for m in members if m not in groups[gname])
    groups["all"] = names

    t = rd.mapping(
        rd.require(top, "timing", ""), "timing", {"horizon_s", "segment_s", "Ts_s", "check_dt_s"}
    )
    horizon = rd.number(rd.require(t, "horizon_s", "timing"), "timing.horizon_s", positive=True)
    if horizon > MAX_HORIZON_S:
        raise rd.fail("timing.horizon_s", f"{horizon:g} s is longer than {MAX_HORIZON_S:g} s")
    seg = rd.number(rd.require(t, "segment_s", "timing"), "timing.segment_s", positive=True)
    ts = rd.number(rd.require(t, "Ts_s", "timing"), "timing.Ts_s", positive=True)
    # The plan is a chain of whole motion primitives sampled on one grid: the horizon must
    # be a whole number of segments and of sample steps (README, "Scenario files").
    for key, val, what in (("segment_s", seg, "segments"), ("Ts_s", ts, "sample steps")):
        ratio = horizon / val
        if abs(ratio - round(ratio)) > 1e-9:
            lo, hi = math.floor(ratio) * val, math.ceil(ratio) * val
            near = f"{lo:g} or {hi:g} s" if lo > 0 else f"{hi:g} s"
            raise rd.fail(
                f"timing.{key}",
                f"the horizon {horizon:g} s is not a whole number of {what} of {val:g} s "
                f"({ratio:.4g}): the plan is a chain of whole {what}; make timing.horizon_s "
                f"{near}, or change timing.{key}",
            )
    if seg < ts:
        raise rd.fail("timing.segment_s", f"segment {seg:g} s is shorter than Ts {ts:g} s")
    check_dt = rd.number(t.get("check_dt_s", ts / 5), "timing.check_dt_s", positive=True)
    if check_dt > ts:
        raise rd.fail("timing.check_dt_s", f"check step {check_dt:g} s is coarser than Ts")
    timing = Timing(horizon, seg, ts, check_dt)

    sep = rd.number(top.get("separation_m", 0.0), "separation_m", nonnegative=True)
    eps = rd.number(top.get("epsilon", 0.0), "epsilon", nonnegative=True)

    model_s = top.get("model", "minimum_jerk")
    try:
        model = DynamicsModel(model_s)
    except ValueError:
        raise rd.fail(
            "model", f"unknown model {model_s!r} (models: minimum_jerk, double_integrator)"
        ) from None

    solver = _solver(rd, top.get("solver", {}) or {})

    start_keys: dict[str, str] = {}
    for i, v in enumerate(vlist):
        if isinstance(top["vehicles"], list):
            start_keys[v.name] = f"vehicles[{i}].start"
        elif "positions" in (top["vehicles"].get("starts") or {}):
            start_keys[v.name] = f"vehicles.starts.positions[{i}]"
        else:
            start_keys[v.name] = "vehicles.starts.grid"
    starts = np.array([v.start_enu_m for v in vlist])
    if len(vlist) > 1 and sep > 0:
        d = np.linalg.norm(starts[:, None, :] - starts[None, :, :], axis=-1)
        d[np.diag_indices(len(vlist))] = np.inf
        i, j = np.unravel_index(np.argmin(d), d.shape)
        if d[i, j] < sep:
            raise rd.fail(
                "vehicles",
                f"starts of {names[i]} and {names[j]} are {d[i, j]:.3g} m apart, "
                f"closer than separation_m {sep:g}",
            )

    constants: dict[str, float] = {
        "horizon": horizon,
        "half_horizon": horizon / 2,
        "separation": sep,
        "epsilon": eps,
    }
    c_top = top.get("constants", {}) or {}
    rd.mapping(c_top, "constants")
    for cname, cval in c_top.items():
        p = _join("constants", cname)
        rd.name(cname, p)
        if cname in constants:
            raise rd.fail(p, f"${cname} is predefined")
        constants[cname] = rd.number(cval, p)

    clauses = _expand_spec(rd, rd.require(top, "spec", ""), groups, constants)
    _check_calls(rd, clauses, seen, region_names)

    problem = Problem(
        name=name,
        source=source,
        origin=origin,
        workspace=workspace,
        regions=tuple(regions),
        vehicles=tuple(vlist),
        groups={g: tuple(m) for g, m in groups.items()},
        timing=timing,
        separation_m=sep,
        epsilon=eps,
        model=model,
        solver=solver,
        clauses=tuple(clauses),
        constants=constants,
    )
    for finding in start_findings(problem, start_keys):
        raise rd.fail(finding.key_path, finding.message)
    # Parse every clause with the STL engine now, so a syntax error names the clause's key.
    registry = build_registry(problem)
    parsed = tuple(parse_clause(problem, cl, registry) for cl in problem.clauses)
    object.__setattr__(problem, "formulas", parsed)
    # What no plan can mend: a start breaking a clause at t = 0, a target out of reach.
    for finding in clause_findings(problem, start_keys):
        raise rd.fail(finding.key_path, finding.message)
    return problem


def _solver(rd: _Reader, value: Any) -> SolverOptions:
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
    return SolverOptions(**kw)


def load_scenario(path: str | Path, *, vehicles: int | None = None) -> Problem:
    """Read and validate a scenario YAML file (``yaml.safe_load``); see :func:`parse_scenario`."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ScenarioError(str(p), "", f"cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ScenarioError(str(p), "", f"not UTF-8 text (byte {exc.start})") from None
    try:
        data = yaml.safe_load(text)
    except RecursionError:
        raise ScenarioError(str(p), "", "invalid YAML: nested too deeply") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ScenarioError(str(p), where, f"invalid YAML: {problem}") from None
    return parse_scenario(data, str(p), vehicles=vehicles)


def parse_clause(
    problem: Problem, clause: Clause, registry: FunctionRegistry | None = None
) -> Formula:
    """Parse one expanded clause; a SpecError becomes a ScenarioError naming the clause's key."""
    try:
        phi = parse(clause.text, functions=registry or build_registry(problem))
    except SpecError as exc:
        raise ScenarioError(problem.source, clause.key_path, f"{exc} in {clause.text!r}") from None
    for node in phi.walk():
        if isinstance(node, Comparison):
            bare = _bare_signals(node.lhs) | _bare_signals(node.rhs)
            if bare:
                name = sorted(bare)[0]
                raise ScenarioError(
                    problem.source,
                    clause.key_path,
                    f"{name!r} is used as a number in {str(node)!r}; vehicles are positions: "
                    f"use x({name}), y({name}), z({name}) or a function such as dist",
                )
    horizon = problem.timing.horizon_s
    if phi.horizon > horizon * (1 + 1e-9):
        raise ScenarioError(
            problem.source,
            clause.key_path,
            f"the clause looks {horizon_sum(phi)} ahead, more than the plan's horizon "
            f"{horizon:g} s (timing.horizon_s)",
        )
    return phi


def _bare_signals(e: Expr) -> set[str]:
    if isinstance(e, Signal):
        return {e.name}
    if isinstance(e, Neg):
        return _bare_signals(e.operand)
    if isinstance(e, BinOp):
        return _bare_signals(e.lhs) | _bare_signals(e.rhs)
    return set()
