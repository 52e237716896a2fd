"""Scenario files: YAML -> a frozen :class:`Problem` (regions, vehicles, limits, timing, spec).

A scenario names everything the planner needs (see ``configs/*.yaml`` for commented examples)::

    name: reach_avoid
    origin: {lat: 47.3977, lon: 8.5456, alt: 488.0}        # geodetic, alt AMSL in metres
    workspace: {min: [-2, -2, 0], max: [2, 2, 2]}           # ENU metres
    regions:                                                # boxes, prisms, cylinders
      obstacle: {kind: obstacle, min: [-1, -1, 0], max: [1, 1, 1.5]}
      goal: {kind: goal, center: [1.75, 1.75, 0.75], half_size: 0.25}
      # turned about the vertical: yaw_deg (ccw from east) or bearing_deg (cw from north)
      # row: {center: [0, 0, 5], half_size: [20, 3, 5], bearing_deg: 37}
      # nofly: {kind: no_fly, polygon: [[x, y], ...], z: [0, 50]}   # any simple polygon
      # pole: {kind: pole, center: [x, y], radius: 0.3, z: [0, 12]}
    # line: {along: {...}, ...}                             # poles, spans, inspection boxes
    # terrain: {file: dem.tif, min_agl_m: 3}                # the ground (or from: line)
    limits: {v_max_m_s: 0.751, a_max_m_s2: 1.0}             # scalar or [x, y, z] per axis
    vehicles:                                               # a list of vehicles ...
      - {name: d1, start: [-1.5, -1.5, 0.5]}
    # ... or a generator, whose count `gcs plan --vehicles N` overrides:
    # vehicles: {count: 2, max_count: 16, name: "d{i}",
    #            starts: {grid: {min: [...], max: [...], shape: [nx, ny, nz]}},
    #            groups: [{name: g1, fraction: 0.5}, {name: g2, fraction: 0.5}]}
    groups: {pair: [d1, d2]}                                # optional; `all` always exists
    timing: {horizon_s: 6, segment_s: 1, Ts_s: 0.05}          # end: rest (default) or free
    separation_m: 0.2
    epsilon: 0.01
    face_tolerance_deg: 15                                  # how far face(d, T) may be off T
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

This module reads the file and puts the sections together (:func:`parse_scenario`); its rooms:

* :mod:`planner.problem`: what a scenario becomes (:class:`~planner.problem.Problem`,
  ``Vehicle``, ``Timing``, ``SolverOptions``, ``Clause``);
* :mod:`planner.scenario.sections`: :class:`~planner.scenario.sections.ScenarioError` and
  the typed reading of single sections (boxes, limits, vehicles, solver);
* :mod:`planner.scenario.spec`: the spec's expansion (``each``, ``$constants``), its calls
  and :func:`~planner.scenario.spec.parse_clause`;
* :mod:`planner.scenario.checks`: the load-time mistakes no plan can mend.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from planner.frames import GeodeticPoint
from planner.mission_model import OriginModel, validate
from planner.problem import MAX_HORIZON_S, DynamicsModel, Problem, Timing
from planner.scenario.checks import clause_findings, start_findings
from planner.scenario.sections import (
    Reader,
    ScenarioError,
    join_key,
    read_assurance,
    read_limits,
    read_region,
    read_solver,
    read_vehicles,
)
from planner.scenario.spec import check_calls, expand_spec, parse_clause, spell_parts
from planner.scenario.terrain import floor_clauses, read_terrain
from planner.spec.predicates import build_registry
from planner.spec.regions import Region, RegionKind
from planner.spec.terrain import Terrain
from planner.strict_read import DuplicateKeyError, NotTextError, load_yaml, read_text

__all__ = ["load_scenario", "parse_scenario"]

_TOP_KEYS = {
    "name",
    "origin",
    "workspace",
    "regions",
    "line",
    "limits",
    "vehicles",
    "groups",
    "timing",
    "separation_m",
    "epsilon",
    "face_tolerance_deg",
    "model",
    "solver",
    "constants",
    "spec",
    "description",
    "assurance",
    "terrain",
}


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
    rd = Reader(source)
    top = rd.mapping(data, "", _TOP_KEYS)
    name = top.get("name", Path(source).stem)
    if not isinstance(name, str):
        raise rd.fail("name", "expected a string")

    # the origin, as a plan file keeps it: one model (planner.mission_model)
    o = rd.mapping(rd.require(top, "origin", ""), "origin", set(OriginModel.model_fields))
    om = validate(OriginModel, o, rd.fail, "origin")
    origin = GeodeticPoint(lat_deg=om.lat, lon_deg=om.lon, alt_m=om.alt)

    (workspace, *more) = read_region(
        rd, "workspace", rd.require(top, "workspace", ""), "workspace", RegionKind.WORKSPACE
    )
    if more or workspace.shape is not None:
        raise rd.fail(
            "workspace",
            "the workspace is an axis-aligned box (min/max or center/half_size): put a "
            "turned or polygonal area in regions and keep to it in the spec",
        )

    regions = read_regions(rd, top.get("regions", {}) or {})

    base = Path(source).parent if source and not source.startswith("<") else Path.cwd()
    line_model = None
    if "line" in top:
        from planner.scenario.line import line_regions, read_line  # fastkml, lxml: on use

        line_model = read_line(rd.mapping(top["line"], "line"), origin, base, rd.fail, rd.number)
    terrain, min_agl, feet = None, None, None
    if "terrain" in top:
        line_file = str(top["line"].get("file", "")) if line_model is not None else ""
        terrain, min_agl, feet = read_terrain(
            rd, top["terrain"], origin, workspace, base, line_model, line_file
        )

    line_names: dict[str, list[str]] = {}
    if line_model is not None:
        if terrain is not None:  # the poles stand on their own feet's ground where known
            ground = terrain.ground(line_model.poles_xy) if feet is None else feet
            line_model = dataclasses.replace(line_model, ground_z_m=ground)
        made, line_names = line_regions(line_model)
        taken = {r.name for r in regions}
        for r in made:
            if r.name in taken:
                raise rd.fail(
                    join_key("regions", r.name), f"{r.name!r} is also made by the line section"
                )
        regions.extend(made)

    limits: dict[str, Any] = {}
    if "limits" in top:
        limits = read_limits(rd, top["limits"], "limits", {})

    vlist, groups = read_vehicles(rd, rd.require(top, "vehicles", ""), limits, vehicles)
    if terrain is not None:  # a start's z is above the ground where it is
        vlist = [dataclasses.replace(v, start_enu_m=_above(v.start_enu_m, terrain)) for v in vlist]
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
        p = join_key("groups", gname)
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
        rd.require(top, "timing", ""),
        "timing",
        {"horizon_s", "segment_s", "Ts_s", "check_dt_s", "end"},
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
    end = t.get("end", "rest")
    if end not in ("rest", "free"):
        raise rd.fail("timing.end", f"expected 'rest' or 'free', got {end!r}")
    timing = Timing(horizon, seg, ts, check_dt, end_at_rest=end == "rest")

    sep = rd.number(top.get("separation_m", 0.0), "separation_m", nonnegative=True)
    eps = rd.number(top.get("epsilon", 0.0), "epsilon", nonnegative=True)
    face_tol = rd.number(top.get("face_tolerance_deg", 15.0), "face_tolerance_deg", positive=True)
    if face_tol >= 90.0:
        raise rd.fail("face_tolerance_deg", f"must be below 90 degrees, got {face_tol:g}")

    model_s = top.get("model", "minimum_jerk")
    try:
        model = DynamicsModel(model_s)
    except ValueError:
        raise rd.fail(
            "model", f"unknown model {model_s!r} (models: minimum_jerk, double_integrator)"
        ) from None

    solver = read_solver(rd, top.get("solver", {}) or {})

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
        i, j = (int(x) for x in np.unravel_index(np.argmin(d), d.shape))
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
        p = join_key("constants", cname)
        rd.name(cname, p)
        if cname in constants:
            raise rd.fail(p, f"${cname} is predefined")
        constants[cname] = rd.number(cval, p)

    for lname in line_names:
        if lname in groups:
            raise rd.fail(
                join_key("groups", lname), f"{lname!r} is the line section's list of its {lname}"
            )
    clauses = expand_spec(rd, rd.require(top, "spec", ""), {**groups, **line_names}, constants)
    clauses = spell_parts(rd, clauses, regions)
    if min_agl is not None:
        clauses.extend(floor_clauses(names, min_agl, horizon))
    check_calls(rd, clauses, seen, region_names, ground=terrain is not None)

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
        face_tolerance_deg=face_tol,
        assurance=None if top.get("assurance") is None else read_assurance(rd, top["assurance"]),
        terrain=terrain,
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


def _above(start: tuple[float, float, float], terrain: Terrain) -> tuple[float, float, float]:
    """A start written above the ground, in the mission frame."""
    return (start[0], start[1], start[2] + float(terrain.ground(start[:2])[0]))


def load_scenario(path: str | Path, *, vehicles: int | None = None) -> Problem:
    """Read and validate a scenario YAML file (safe YAML, a key written twice refused:
    :func:`planner.strict_read.load_yaml`); see :func:`parse_scenario`."""
    p = Path(path)
    try:
        text = read_text(p)
    except OSError as exc:
        raise ScenarioError(str(p), "", f"cannot read: {exc.strerror or exc}") from None
    except NotTextError as exc:
        raise ScenarioError(str(p), "", f"{exc} (expected a YAML scenario)") from None
    try:
        data = load_yaml(text)
    except DuplicateKeyError as exc:
        raise ScenarioError(str(p), exc.mapping_path, str(exc)) from None
    except RecursionError:
        raise ScenarioError(str(p), "", "invalid YAML: nested too deeply") from None
    except yaml.reader.ReaderError as exc:
        # a character YAML does not allow (a control character): say where, on one line
        before = text[: exc.position]
        where = f"line {before.count(chr(10)) + 1}, column {exc.position - before.rfind(chr(10))}"
        raise ScenarioError(
            str(p), where, f"invalid YAML: character 0x{exc.character:x} is not allowed"
        ) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ScenarioError(str(p), where, f"invalid YAML: {' '.join(problem.split())}") from None
    return parse_scenario(data, str(p), vehicles=vehicles)


def read_regions(
    rd: Reader, reg_map: Any, path: str = "regions", default_kind: str = "region"
) -> list[Region]:
    """The regions of a ``regions:`` mapping (name -> region, :func:`read_region`), a
    polygon that is not convex as its convex parts; ScenarioError naming the key."""
    regions: list[Region] = []
    rd.mapping(reg_map, path)
    for rname, rval in reg_map.items():
        p = join_key(path, rname)
        rd.name(rname, p)
        if rname == "workspace":
            raise rd.fail(p, "'workspace' is defined by the top-level workspace key")
        rm = rd.mapping(rval, p)
        kind_s = rm.get("kind", default_kind)
        try:
            kind = RegionKind(kind_s)
        except ValueError:
            raise rd.fail(
                join_key(p, "kind"),
                f"unknown kind {kind_s!r} (kinds: {', '.join(k.value for k in RegionKind)})",
            ) from None
        for r in read_region(rd, rname, rval, p, kind):
            if r.part_of is not None and (
                r.name in reg_map or any(q.name == r.name for q in regions)
            ):
                raise rd.fail(p, f"its part {r.name!r} has the name of another region")
            regions.append(r)
    return regions


def load_live_regions(path: str | Path) -> tuple[Region, ...]:
    """The keep-outs of a live-regions file (``gcs fly --replan --live-regions FILE``): a
    YAML mapping with one key, ``regions``, in the scenario's syntax, mission frame; a
    region's kind is ``no_fly`` unless it says otherwise.

    Raises:
        ScenarioError: the file unreadable, not such a mapping, or a bad region (names the
            key).
    """
    rd = Reader(str(path))
    try:
        top = load_yaml(read_text(Path(path)))
    except (OSError, NotTextError, DuplicateKeyError, yaml.YAMLError) as exc:
        raise rd.fail("", f"cannot read: {exc}") from None
    rd.mapping(top, "", {"regions"})
    return tuple(read_regions(rd, top.get("regions", {}) or {}, default_kind="no_fly"))
