"""Plan files (docs/scenario-format.md, "Plan files", contract): JSON written by ``gcs plan``, read by the rest.

Layout (the contract's keys, plus extensions that make a plan self-contained for
``gcs verify``: ``success``, ``epsilon``, ``separation_m``, ``horizon_s``, ``check_dt_s``,
``sample_dt_s``, ``workspace``, ``regions``, and per vehicle ``limits`` and ``start``)::

    {"format": "stl-gcs-plan", "version": 1,
     "scenario": "configs/reach_avoid.yaml", "origin": {"lat": .., "lon": .., "alt": ..},
     "spec": "<expanded STL text>", "robustness": 0.12, "smooth_robustness": 0.10,
     "status": "...", "success": true, "solve_time_s": 0.8, ...,
     "vehicles": [{"name": "d1", "sysid": 1, "t": [...], "pos": [[x, y, z], ...],
                   "vel": [...], "acc": [...], "yaw": [...],
                   "segments": [...],      # Trajectory.to_segments(): lossless
                   "limits": {"v_max_m_s": [..], "a_max_m_s2": [..]}, "start": [x, y, z]}]}

The samples ``t/pos/vel/acc/yaw`` are for other tools (plots, spreadsheets); the source of
truth is ``segments`` (floats are written with ``repr`` precision, so they round-trip).

The spec is checked against the plan it belongs to by :func:`plan_formula` (every name it
uses is a vehicle or region of the plan, it looks no further ahead than ``horizon_s``), not by
:func:`load_plan`, which stays free of the STL engine and its CasADi predicates.

Errors::

    PlanFileError(FileFieldError)   "<file>: <key path>: <problem>" for missing/malformed plans,
                                    a spec that does not fit the plan, or a spec that cannot
                                    be evaluated on it (:func:`spec_errors`)
"""

from __future__ import annotations

import json
import math
import os
import stat
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.assurance import Assurance, assurance_from_json
from planner.dynamics.limits import PX4_LIMIT_KEYS
from planner.errors import FileFieldError
from planner.frames import GeodeticPoint
from planner.mission_model import FORMAT, VERSION, PlanFileModel, RegionModel, validate
from planner.problem import MAX_HORIZON_S
from planner.scenario.checks import horizon_sum
from planner.scenario.spec import FUNCTION_NAMES
from planner.spec.heading import heading_signals, uses_heading
from planner.spec.predicates import build_registry
from planner.spec.regions import Cylinder, Prism, Region, ShapeError
from planner.spec.terrain import Terrain, TerrainError, ground_below
from planner.stl import BinOp, Call, Comparison, Neg, Predicate, Signal, SpecError, STLError, parse
from planner.strict_read import DuplicateKeyError, NotTextError, load_json, read_text
from planner.trajectory import Trajectory, TrajectoryError

if TYPE_CHECKING:
    from planner.stl import Expr, Formula

__all__ = [
    "FORMAT",
    "VERSION",
    "Plan",
    "PlanFileError",
    "PlannedVehicle",
    "check_writable",
    "load_plan",
    "plan_formula",
    "plan_to_json",
    "save_plan",
    "spec_errors",
]

#: The optional limit fields of :class:`PlannedVehicle`, as :meth:`VehicleLimits.given` names them.
_LIMIT_FIELDS = (
    "thrust_min_m_s2",
    "thrust_max_m_s2",
    "body_rate_max_rad_s",
    *PX4_LIMIT_KEYS,
)
#: Most check samples (``horizon_s / check_dt_s``) a plan may ask for: an hour at 1 ms is
#: 3.6e6, and ten million (n, 3) float samples already take 240 MB per vehicle.
MAX_CHECK_SAMPLES = 10_000_000


class PlanFileError(FileFieldError):
    """A plan file that is missing, not JSON, or not a valid plan: names file and key."""


#: Makes the error of a key path and a problem.
_Fail = Callable[[str, str], PlanFileError]


@dataclass(frozen=True, slots=True)
class PlannedVehicle:
    """One vehicle of a plan: its trajectory (mission ENU frame) and limits."""

    name: str
    sysid: int
    trajectory: Trajectory
    start_enu_m: tuple[float, float, float]
    v_max_m_s: tuple[float, float, float]
    a_max_m_s2: tuple[float, float, float]
    thrust_min_m_s2: float | None = None
    thrust_max_m_s2: float | None = None
    body_rate_max_rad_s: float | None = None
    #: PX4-like limits (:mod:`planner.dynamics.limits`): horizontal norm, vertical up/down (None: none
    #: beyond the per-axis ``v_max_m_s`` / ``a_max_m_s2``).
    v_xy_max_m_s: float | None = None
    v_up_max_m_s: float | None = None
    v_down_max_m_s: float | None = None
    a_xy_max_m_s2: float | None = None
    a_up_max_m_s2: float | None = None
    a_down_max_m_s2: float | None = None
    #: the turn rate a yaw schedule may ask for (deg/s; None: 45, PX4's MPC_YAWRAUTO_MAX)
    yaw_rate_max_deg_s: float | None = None


@dataclass(frozen=True, slots=True)
class Plan:
    """A plan as stored in a plan file (what ``gcs verify``, ``fly``, ``upload`` consume)."""

    scenario: str
    origin: GeodeticPoint
    spec: str
    robustness: float
    smooth_robustness: float
    status: str
    success: bool
    solve_time_s: float
    vehicles: tuple[PlannedVehicle, ...]
    workspace: Region
    regions: tuple[Region, ...]
    separation_m: float
    epsilon: float
    horizon_s: float
    sample_dt_s: float
    check_dt_s: float
    #: How far (degrees) a ``face`` may be off its target (the scenario's; 15 in older files).
    face_tolerance_deg: float = 15.0
    #: How the plan was made to a probability (``gcs plan --target-probability``), else None.
    assurance: Assurance | None = None
    #: The ground ``agl`` measures from (the scenario's terrain), else None.
    terrain: Terrain | None = None
    #: The file the plan was read from; ``""`` for a plan made in memory (``PlanResult.to_plan``).
    source: str = field(default="", compare=False)
    #: The parsed and checked spec, made on first use (:func:`plan_formula`), once per plan.
    _formula: Formula | None = field(default=None, init=False, repr=False, compare=False)

    def __getstate__(self) -> list[Any]:
        """Pickled without the parsed spec (its functions are closures over the plan's
        regions); the copy parses it again on first use."""
        return [None if f.name == "_formula" else getattr(self, f.name) for f in fields(self)]

    @property
    def input_file(self) -> str:
        """The file to name in errors about the plan: its plan file, else its scenario."""
        return self.source or self.scenario

    @property
    def all_regions(self) -> tuple[Region, ...]:
        """The workspace followed by the named regions."""
        return (self.workspace, *self.regions)

    def region(self, name: str) -> Region:
        """The region called ``name`` (``workspace`` included); KeyError if unknown."""
        for r in self.all_regions:
            if r.name == name:
                return r
        raise KeyError(name)

    def vehicle(self, name: str) -> PlannedVehicle:
        """The vehicle called ``name``; KeyError if absent."""
        for v in self.vehicles:
            if v.name == name:
                return v
        raise KeyError(name)

    def ground_spawns(self) -> list[tuple[float, float, float]]:
        """Where each vehicle stands before its flight (plan order, mission frame): on the
        ground below its planned start, ``z = 0`` or the plan's terrain there (dry runs,
        ``gcs assess``'s runs, the exports' home, the take-off note)."""
        return ground_below(self.terrain, [v.start_enu_m for v in self.vehicles])


def _region_json(r: Region) -> dict[str, Any]:
    """``{kind, min, max}`` (a shaped region's bounding box), and a prism's ``polygon`` and
    ``z``, a cylinder's ``center``, ``radius`` and ``z``."""
    out: dict[str, Any] = {"kind": r.kind.value, "min": list(r.lo_enu_m), "max": list(r.hi_enu_m)}
    if isinstance(r.shape, Prism):
        out.update(
            polygon=[list(v) for v in r.shape.vertices_xy], z=[r.shape.z_lo_m, r.shape.z_hi_m]
        )
    elif isinstance(r.shape, Cylinder):
        s = r.shape
        out.update(center=list(s.center_xy), radius=s.radius_m, z=[s.z_lo_m, s.z_hi_m])
    if r.part_of is not None:
        out["part_of"] = r.part_of
    return out


def plan_to_json(plan: Plan) -> dict[str, Any]:
    """The plan as the JSON object of docs/scenario-format.md, "Plan files" (plus extensions)."""
    vehicles = []
    for v in plan.vehicles:
        sp = v.trajectory.sample(1.0 / plan.sample_dt_s)
        limits: dict[str, Any] = {"v_max_m_s": list(v.v_max_m_s), "a_max_m_s2": list(v.a_max_m_s2)}
        for key in PX4_LIMIT_KEYS:
            if getattr(v, key) is not None:
                limits[key] = getattr(v, key)
        if v.thrust_min_m_s2 is not None and v.thrust_max_m_s2 is not None:
            limits["thrust_m_s2"] = [v.thrust_min_m_s2, v.thrust_max_m_s2]
        if v.body_rate_max_rad_s is not None:
            limits["body_rate_max_rad_s"] = v.body_rate_max_rad_s
        vehicles.append(
            {
                "name": v.name,
                "sysid": v.sysid,
                "t": np.asarray(sp.t_s).tolist(),
                "pos": np.asarray(sp.pos_enu_m).tolist(),
                "vel": np.asarray(sp.vel_enu_m_s).tolist(),
                "acc": np.asarray(sp.acc_enu_m_s2).tolist(),
                "yaw": np.asarray(sp.yaw_rad).tolist(),
                "segments": v.trajectory.to_segments(),
                "limits": limits,
                "start": list(v.start_enu_m),
            }
        )
    return {
        "format": FORMAT,
        "version": VERSION,
        "scenario": plan.scenario,
        "origin": {
            "lat": plan.origin.lat_deg,
            "lon": plan.origin.lon_deg,
            "alt": plan.origin.alt_m,
        },
        "spec": plan.spec,
        "robustness": _finite_or_none(plan.robustness),
        "smooth_robustness": _finite_or_none(plan.smooth_robustness),
        "status": plan.status,
        "success": plan.success,
        "solve_time_s": plan.solve_time_s,
        "epsilon": plan.epsilon,
        "separation_m": plan.separation_m,
        "face_tolerance_deg": plan.face_tolerance_deg,
        "horizon_s": plan.horizon_s,
        "sample_dt_s": plan.sample_dt_s,
        "check_dt_s": plan.check_dt_s,
        "workspace": _region_json(plan.workspace),
        "regions": {r.name: _region_json(r) for r in plan.regions},
        "vehicles": vehicles,
        **({} if plan.assurance is None else {"assurance": plan.assurance.to_json()}),
        **({} if plan.terrain is None else {"terrain": plan.terrain.to_dict()}),
    }


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def save_plan(path: str | Path, plan: Any, scenario_path: str | None = None) -> Path:
    """Write a plan (a :class:`Plan` or a ``PlanResult``) as JSON; returns the path.

    ``scenario_path`` overrides the scenario recorded in the file.
    """
    if not isinstance(plan, Plan):
        plan = plan.to_plan()
    data = plan_to_json(plan)
    if scenario_path is not None:
        data["scenario"] = str(scenario_path)
    p = Path(path)
    try:
        p.write_text(json.dumps(data, indent=None, separators=(",", ":")) + "\n", encoding="utf-8")
    except OSError as exc:
        raise PlanFileError(str(p), "", f"cannot write: {exc.strerror or exc}") from None
    return p


def check_writable(path: str | Path) -> None:
    """Fail now, not after a long solve, if :func:`save_plan` could not write ``path``.

    Leaves the file system as it was: an existing file is opened for appending and closed
    untouched; a missing one is created exclusively and removed again. A FIFO or device is
    only checked for write permission (opening a FIFO would wait for a reader).

    Raises:
        PlanFileError: ``"<path>: cannot write: <reason>"``, as :func:`save_plan` words it.
    """
    p = Path(path)
    try:
        try:
            mode = p.stat().st_mode
        except FileNotFoundError:
            if p.is_symlink():  # dangling: save_plan creates its target, O_EXCL would refuse
                return
            fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            os.close(fd)
            p.unlink()
            return
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(21, "Is a directory")
        if not stat.S_ISREG(mode):
            if not os.access(p, os.W_OK):
                raise PermissionError(13, "Permission denied")
            return
        os.close(os.open(p, os.O_WRONLY | os.O_APPEND))
    except OSError as exc:
        raise PlanFileError(str(p), "", f"cannot write: {exc.strerror or exc}") from None


def _region(name: str, m: RegionModel, path: str, fail: _Fail) -> Region:
    """A plan file's region as the planner's: a box, or a polygon's or circle's prism."""
    kind = m.kind
    if m.polygon is None and m.radius is None:
        return Region(name, kind, m.min, m.max)
    try:
        if m.z is None:
            raise ShapeError("expected z: [bottom, top]")
        if m.polygon is not None:
            shape: Prism | Cylinder = Prism.from_polygon([list(p) for p in m.polygon], *m.z)
        else:
            if m.center is None or m.radius is None:
                raise ShapeError("expected center: [x, y]")
            shape = Cylinder(m.center, m.radius, *m.z)
    except (ShapeError, TypeError, ValueError) as exc:
        raise fail(path, f"bad shape: {exc}") from None
    return Region.of_shape(name, kind, shape, m.part_of)


def _read_json(src: str) -> Any:
    p = Path(src)
    try:
        text = read_text(p)
    except OSError as exc:
        raise PlanFileError(src, "", f"cannot read: {exc.strerror or exc}") from None
    except NotTextError as exc:
        raise PlanFileError(src, "", f"{exc} (expected a JSON plan file)") from None
    try:
        return load_json(text)
    except DuplicateKeyError as exc:
        raise PlanFileError(src, exc.mapping_path, str(exc)) from None
    except RecursionError:
        raise PlanFileError(src, "", "not JSON: nested too deeply") from None
    except json.JSONDecodeError as exc:
        raise PlanFileError(
            src, f"line {exc.lineno}, column {exc.colno}", f"not JSON: {exc.msg}"
        ) from None


def load_plan(path: str | Path) -> Plan:
    """Read and validate a plan file; trajectories are rebuilt from ``segments``.

    The file is validated against :class:`planner.mission_model.PlanFileModel` (the plan
    file's JSON Schema, docs/plan-file.schema.json); what the schema cannot say (a
    trajectory's continuity, a shape, the horizon's size) is checked here.
    """
    src = str(Path(path))

    def fail(key: str, problem: str) -> PlanFileError:
        return PlanFileError(src, key, problem)

    data = _read_json(src)
    if not isinstance(data, dict):
        raise fail("", "expected a JSON object")
    if data.get("format") != FORMAT:
        raise fail("format", f"expected {FORMAT!r}, got {data.get('format')!r}")
    if data.get("version") != VERSION:
        raise fail("version", f"unsupported version {data.get('version')!r} (this reads {VERSION})")
    m = validate(PlanFileModel, data, fail)
    regions = tuple(_region(k, r, f"regions.{k}", fail) for k, r in m.regions.items())
    workspace = _region("workspace", m.workspace, "workspace", fail)
    vehicles = []
    for i, v in enumerate(m.vehicles):
        vp = f"vehicles[{i}]"
        try:
            traj = Trajectory.from_segments(
                data["vehicles"][i]["segments"], name=v.name, where=f"{vp}.segments"
            )
        except TrajectoryError as exc:
            raise fail("", str(exc)) from None
        lim = v.limits.given()
        vehicles.append(
            PlannedVehicle(
                name=v.name,
                sysid=v.sysid,
                trajectory=traj,
                start_enu_m=v.start,
                v_max_m_s=v.limits.v_max_m_s,
                a_max_m_s2=v.limits.a_max_m_s2,
                **{k: lim.get(k) for k in _LIMIT_FIELDS},
            )
        )
    if m.horizon_s > MAX_HORIZON_S:
        raise fail("horizon_s", f"{m.horizon_s:g} s is longer than {MAX_HORIZON_S:g} s")
    if m.horizon_s / m.check_dt_s > MAX_CHECK_SAMPLES:
        raise fail(
            "check_dt_s",
            f"{m.check_dt_s:g} s gives more than {MAX_CHECK_SAMPLES:g} check samples "
            f"over the {m.horizon_s:g} s horizon",
        )
    return Plan(
        scenario=m.scenario,
        origin=GeodeticPoint(m.origin.lat, m.origin.lon, m.origin.alt),
        spec=m.spec,
        robustness=math.nan if m.robustness is None else m.robustness,
        smooth_robustness=math.nan if m.smooth_robustness is None else m.smooth_robustness,
        status=m.status,
        success=m.success,
        solve_time_s=m.solve_time_s,
        vehicles=tuple(vehicles),
        workspace=workspace,
        regions=regions,
        separation_m=m.separation_m,
        epsilon=m.epsilon,
        horizon_s=m.horizon_s,
        sample_dt_s=m.sample_dt_s,
        check_dt_s=m.check_dt_s,
        face_tolerance_deg=m.face_tolerance_deg,
        assurance=None if m.assurance is None else assurance_from_json(m.assurance, fail),
        terrain=None if m.terrain is None else _terrain(m.terrain, fail),
        source=src,
    )


def _terrain(t: Any, fail: Callable[[str, str], Exception]) -> Terrain:
    rows = {len(r) for r in t.ground_z_m}
    if len(rows) != 1:
        raise fail("terrain.ground_z_m", f"rows of different lengths {sorted(rows)}")
    try:
        return Terrain(t.x0_m, t.y0_m, t.step_m, np.array(t.ground_z_m, dtype=float), t.source)
    except TerrainError as exc:
        raise fail("terrain", str(exc)) from None


def planned_signals(plan: Plan, t_s: np.ndarray) -> dict[str, np.ndarray]:
    """Each vehicle's planned signal at ``t_s``: positions (n, 3), with the heading as a
    fourth column when the spec reads it (``face``: :mod:`planner.spec.heading`)."""

    trajectories = [v.trajectory for v in plan.vehicles]
    return heading_signals(trajectories, t_s, uses_heading([plan_formula(plan)]))


def plan_formula(plan: Plan) -> Formula:
    """The plan's whole spec with the scenario's predicates (exact numpy semantics).

    Besides parsing it, checks the spec against the plan, so that evaluating it on the plan's
    trajectories cannot fail on a name or a length: every function argument names a vehicle or
    a region of the plan (by the argument's kind in
    :data:`planner.scenario.spec.FUNCTION_NAMES`), a bare name in a comparison is not a vehicle
    (vehicles are positions), and the spec looks no further ahead than ``horizon_s``.

    Raises:
        PlanFileError: naming :attr:`Plan.input_file` and ``spec`` (or ``horizon_s``).
    """
    if plan._formula is not None:
        return plan._formula
    phi = _checked_formula(plan)
    object.__setattr__(plan, "_formula", phi)
    return phi


def _checked_formula(plan: Plan) -> Formula:

    def fail(problem: str, key: str = "spec") -> PlanFileError:
        return PlanFileError(plan.input_file, key, problem)

    def atoms(e: Expr) -> Iterator[Expr]:
        if isinstance(e, BinOp):
            yield from atoms(e.lhs)
            yield from atoms(e.rhs)
        elif isinstance(e, Neg):
            yield from atoms(e.operand)
        elif isinstance(e, Signal | Call):
            yield e

    try:
        phi = parse(plan.spec, build_registry(plan))
    except SpecError as exc:
        raise fail(f"line {exc.line}, column {exc.column}: {exc.detail}") from None
    known = {
        "v": ("vehicle", [v.name for v in plan.vehicles]),
        "r": ("region", [r.name for r in plan.all_regions]),
    }
    for node in phi.walk():
        if isinstance(node, Predicate):
            exprs: tuple[Expr, ...] = (node.call,)
        elif isinstance(node, Comparison):
            exprs = (node.lhs, node.rhs)
        else:
            continue
        for atom in (a for e in exprs for a in atoms(e)):
            if isinstance(atom, Signal):
                if atom.name in known["v"][1]:
                    raise fail(
                        f"{atom.name!r} is used as a number in {str(node)!r}; vehicles are "
                        f"positions: use x({atom.name}), y({atom.name}), z({atom.name}) or a "
                        "function such as dist"
                    )
                raise fail(
                    f"unknown name {atom.name!r} in {str(node)!r} "
                    f"(vehicles: {', '.join(known['v'][1])})"
                )
            assert isinstance(atom, Call)
            if atom.name == "agl" and plan.terrain is None:
                raise fail(
                    f"{str(atom)!r} is a height above the ground, and the plan has no terrain"
                )
            for arg, kind in zip(atom.args, FUNCTION_NAMES[atom.name], strict=True):
                what, names = known[kind]
                if arg not in names:
                    raise fail(
                        f"unknown {what} {arg!r} in {str(atom)!r} ({what}s: {', '.join(names)})"
                    )
    for i, clause in enumerate(phi.clauses, start=1):
        if clause.horizon > plan.horizon_s * (1 + 1e-9):
            raise fail(
                f"{plan.horizon_s:g} s is shorter than spec clause {i} ({clause}), which looks "
                f"{horizon_sum(clause)} ahead",
                "horizon_s",
            )
    return phi


@contextmanager
def spec_errors(plan: Plan, key: str = "spec") -> Iterator[None]:
    """Turn an STL error raised while evaluating ``plan``'s spec into a :class:`PlanFileError`.

    What :func:`plan_formula` cannot rule out depends on the check step, e.g. an interval
    holding no sample step at the ``dt`` given; the error names ``plan.input_file`` and ``key``.
    """

    try:
        yield
    except STLError as exc:
        raise PlanFileError(plan.input_file, key, str(exc)) from None
