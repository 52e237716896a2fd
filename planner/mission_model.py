"""The mission's data model, one for the scenario and the plan file, and the plan file's
JSON Schema.

The fields a scenario and a plan file share are declared once here as pydantic models
(pydantic 2, https://docs.pydantic.dev): a vehicle's limits (:class:`VehicleLimits`, read
from a scenario's ``limits:`` and written to each vehicle of a plan file) and the plan file
itself (:class:`PlanFileModel`, with its origin, boxes, vehicles and trajectory segments).
:func:`validate` runs a model on parsed JSON or YAML and turns pydantic's first error into
the readers' one line, ``<file>: <key path>: <problem>``, the path in the files' own
spelling (``vehicles[0].limits.v_max_m_s``), the problem in the words the readers have
always used ("missing", "expected a number, got str 'x'", "must be > 0, got 0").

What a model cannot say stays in the readers: a plan's trajectory is rebuilt (and its
segments' continuity checked) by :meth:`planner.trajectory.Trajectory.from_segments`, its
regions' shapes by :mod:`planner.spec.regions`, its spec by :func:`planner.planfile.plan_formula`.

:func:`plan_file_schema` is the plan file's JSON Schema (draft 2020-12), published as
``docs/plan-file.schema.json`` (a test keeps the file equal to the model) for the tools that
read plan files without this package.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Annotated, Any, Literal, TypeVar

from pydantic import (
    AfterValidator,
    AllowInfNan,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    Strict,
    ValidationError,
    WithJsonSchema,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from planner.spec.predicates import PREDICATES
from planner.spec.regions import RegionKind

__all__ = [
    "FORMAT",
    "NAME_RE",
    "RESERVED",
    "VERSION",
    "OriginModel",
    "PlanFileModel",
    "PlannedLimits",
    "PlannedVehicleModel",
    "RegionModel",
    "SegmentModel",
    "VehicleEntry",
    "VehicleLimits",
    "VehicleModel",
    "key_path",
    "kind_of",
    "name_problem",
    "plan_file_schema",
    "validate",
]

FORMAT = "stl-gcs-plan"
VERSION = 1

#: A name of a vehicle, region or group: what the spec's text can refer to.
NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
#: Words of the spec language, which no name may be.
RESERVED = frozenset(
    {
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
        # the spec's function names (planner.scenario.spec.FUNCTION_NAMES has the same keys)
        *PREDICATES,
    }
)


def kind_of(value: Any) -> str:
    """How a problem names a value it did not expect: its type and, short, the value."""
    if value is None:
        return "nothing"
    if isinstance(value, dict):
        return "a mapping"
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 40 else text[:37] + '...'}"


def _fail(problem: str) -> PydanticCustomError:
    # no context: the message is used as written (no {placeholders} filled in)
    return PydanticCustomError("mission_model", problem)


def _list_of(n: int, what: str) -> Callable[[Any], Any]:
    def check(value: Any) -> Any:
        if not isinstance(value, list | tuple) or len(value) != n:
            raise _fail(f"expected a list of {n} numbers {what}, got {kind_of(value)}")
        return value

    return check


def _per_axis(value: Any) -> Any:
    """One number for every axis, or ``[x, y, z]``."""
    if isinstance(value, list | tuple):
        return _list_of(3, "[x, y, z]")(value)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _fail(f"expected a number or [x, y, z], got {kind_of(value)}")
    if not (math.isfinite(value) and value > 0):
        raise _fail(f"must be > 0, got {value:g}")  # named as given, not per axis
    return (value, value, value)


def _sysid(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 255:
        raise _fail(f"expected 1..255, got {value!r}")
    return value


def _text(value: Any) -> str:
    if not isinstance(value, str):
        raise _fail(f"expected a string, got {kind_of(value)}")
    return value


def name_problem(value: Any) -> str | None:
    """Why ``value`` cannot name a vehicle, region or group (``None``: it can)."""
    if not isinstance(value, str) or not NAME_RE.match(value):
        return f"expected an identifier (letters, digits, _), got {value!r}"
    if value in RESERVED:
        return f"{value!r} is a reserved word of the spec language"
    return None


def _identifier(value: Any) -> str:
    problem = name_problem(value)
    if problem is not None:
        raise _fail(problem)
    return str(value)


def _flag(value: Any) -> bool:
    if not isinstance(value, bool):
        raise _fail(f"expected true or false, got {kind_of(value)}")
    return value


#: A finite number (JSON's ``NaN`` and ``Infinity``, which Python's ``json`` reads, refused;
#: ``true`` is not 1). Validated by pydantic's core, not by Python: a long plan has millions.
Number = Annotated[float, Strict(), AllowInfNan(False)]
#: A finite number > 0.
Positive = Annotated[float, Strict(), AllowInfNan(False), Field(gt=0)]
#: A finite number >= 0.
NonNegative = Annotated[float, Strict(), AllowInfNan(False), Field(ge=0)]
#: A number or ``null`` (a robustness the planner could not compute).
NumberOrNull = Annotated[float, Strict()] | None
#: A sample for other tools: any number (a heading may be NaN where it is unknown).
Sample = Annotated[float, Strict()]
#: A point or extent ``[x, y, z]`` (m, the mission's ENU frame).
Vec3 = Annotated[tuple[Number, Number, Number], BeforeValidator(_list_of(3, "[x, y, z]"))]
#: A positive limit per axis: ``[x, y, z]``, or one number for all three (scenarios).
PerAxis = Annotated[
    tuple[Positive, Positive, Positive],
    BeforeValidator(_per_axis),
    WithJsonSchema(
        {
            "anyOf": [
                {"type": "number", "exclusiveMinimum": 0},
                {
                    "type": "array",
                    "items": {"type": "number", "exclusiveMinimum": 0},
                    "minItems": 3,
                    "maxItems": 3,
                },
            ]
        }
    ),
]
SysId = Annotated[int, Field(ge=1), Field(le=255), BeforeValidator(_sysid)]
Text = Annotated[str, BeforeValidator(_text)]
#: A vehicle's (region's, group's) name: an identifier that is not a word of the spec language.
Name = Annotated[
    str,
    BeforeValidator(_identifier),
    WithJsonSchema({"type": "string", "pattern": NAME_RE.pattern}),
]
Flag = Annotated[bool, BeforeValidator(_flag)]


class VehicleLimits(BaseModel):
    """A vehicle's limits, as a scenario's ``limits:`` gives them and a plan file keeps them.

    Per-axis caps (``v_max_m_s``, ``a_max_m_s2``), the PX4-like norms and vertical limits of
    :mod:`planner.dynamics.limits` (each optional, > 0), the mass-normalised thrust range and
    the body-rate limit. Every field is optional here: a scenario's vehicle inherits what its
    own ``limits:`` leaves out from the scenario's, and says what is still missing
    (:func:`planner.scenario.sections.read_limits`).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, defer_build=True)

    v_max_m_s: PerAxis | None = Field(None, description="velocity cap per axis (m/s)")
    a_max_m_s2: PerAxis | None = Field(None, description="acceleration cap per axis (m/s^2)")
    v_xy_max_m_s: Positive | None = Field(None, description="horizontal speed (MPC_XY_VEL_MAX)")
    v_up_max_m_s: Positive | None = Field(None, description="climb rate (MPC_Z_VEL_MAX_UP)")
    v_down_max_m_s: Positive | None = Field(None, description="descent rate (MPC_Z_VEL_MAX_DN)")
    a_xy_max_m_s2: Positive | None = Field(None, description="horizontal acceleration")
    a_up_max_m_s2: Positive | None = Field(None, description="upward acceleration")
    a_down_max_m_s2: Positive | None = Field(None, description="downward acceleration")
    yaw_rate_max_deg_s: Positive | None = Field(
        None, description="turn rate a heading schedule may ask for (MPC_YAWRAUTO_MAX)"
    )
    thrust_m_s2: (
        Annotated[tuple[NonNegative, Positive], BeforeValidator(_list_of(2, "[min, max]"))] | None
    ) = Field(None, description="mass-normalised thrust range [min, max] (m/s^2)")
    body_rate_max_rad_s: Positive | None = Field(None, description="body rate limit (rad/s)")

    @field_validator("thrust_m_s2")
    @classmethod
    def _thrust_can_hover(cls, thrust: tuple[float, float] | None) -> tuple[float, float] | None:
        if thrust is not None:
            lo, hi = thrust
            if not lo < hi:
                raise _fail(f"min {lo:g} must be below max {hi:g}")
            if hi <= 9.81:
                raise _fail(f"max thrust {hi:g} m/s^2 cannot hover (needs > 9.81)")
        return thrust

    def given(self) -> dict[str, Any]:
        """The fields given, by name (``thrust_m_s2`` as ``thrust_min_m_s2`` and
        ``thrust_max_m_s2``, the vehicle's fields)."""
        out = self.model_dump(exclude_none=True)
        thrust = out.pop("thrust_m_s2", None)
        if thrust is not None:
            out["thrust_min_m_s2"], out["thrust_max_m_s2"] = thrust
        return out


class PlannedLimits(VehicleLimits):
    """A planned vehicle's limits: the per-axis caps are always written."""

    v_max_m_s: PerAxis = Field(description="velocity cap per axis (m/s)")
    a_max_m_s2: PerAxis = Field(description="acceleration cap per axis (m/s^2)")


def _within(what: str, bound: float) -> Callable[[float], float]:
    def check(x: float) -> float:
        if not -bound <= x <= bound:
            raise _fail(f"{what} {x:g} is outside [{-bound:g}, {bound:g}]")
        return x

    return check


#: A latitude (degrees, WGS-84), refused in words outside [-90, 90].
Latitude = Annotated[
    float,
    Strict(),
    AllowInfNan(False),
    AfterValidator(_within("latitude", 90.0)),
    WithJsonSchema({"type": "number", "minimum": -90.0, "maximum": 90.0}),
]
#: A longitude (degrees), refused in words outside [-180, 180].
Longitude = Annotated[
    float,
    Strict(),
    AllowInfNan(False),
    AfterValidator(_within("longitude", 180.0)),
    WithJsonSchema({"type": "number", "minimum": -180.0, "maximum": 180.0}),
]


class VehicleModel(BaseModel):
    """What a scenario's listed vehicle and a plan file's vehicle both are: a name and a start
    (m, the mission's ENU frame); each has a MAVLink system id (a scenario's by default its
    place) and :class:`VehicleLimits` (a plan file's with the per-axis caps written)."""

    model_config = ConfigDict(extra="forbid", frozen=True, defer_build=True)

    name: Name
    start: Vec3


class VehicleEntry(VehicleModel):
    """A vehicle listed in a scenario's ``vehicles:``: its system id by default its place
    (1-based), its limits over the scenario's (any of them), its groups."""

    sysid: SysId | None = Field(None, description="MAVLink system id (default: its place, 1-based)")
    limits: VehicleLimits | None = None
    groups: list[Name] = Field(default_factory=list)


class OriginModel(BaseModel):
    """The mission frame's origin (WGS-84 degrees, metres above mean sea level): a scenario's
    ``origin:`` and a plan file's ``origin``."""

    model_config = ConfigDict(extra="forbid", frozen=True, defer_build=True)

    lat: Latitude
    lon: Longitude
    alt: Number


class RegionModel(BaseModel):
    """A region of a plan file: its bounding box, and where it is a polygon or a circle, its
    shape (a prism from ``z[0]`` to ``z[1]``)."""

    model_config = ConfigDict(extra="ignore", frozen=True, defer_build=True)

    kind: RegionKind = Field(RegionKind.REGION, description="what the box means to the mission")
    min: Vec3
    max: Vec3
    polygon: list[tuple[Number, Number]] | None = None
    center: Annotated[tuple[Number, Number], BeforeValidator(_list_of(2, "[x, y]"))] | None = None
    radius: Positive | None = None
    z: Annotated[tuple[Number, Number], BeforeValidator(_list_of(2, "[bottom, top]"))] | None = None
    part_of: Annotated[str, Field(min_length=1)] | None = Field(
        None, description="the name of the polygon this convex piece is part of"
    )

    @model_validator(mode="after")
    def _not_empty(self) -> RegionModel:
        if not all(a < b for a, b in zip(self.min, self.max, strict=True)):
            raise _fail("empty box (min must be below max)")
        return self


class SegmentModel(BaseModel):
    """One polynomial piece of a trajectory (:meth:`planner.trajectory.Trajectory.to_segments`):
    from ``t0_s`` for ``duration_s``, ``coeffs`` per axis (east, north, up) in powers of the
    time since ``t0_s``, and the heading policy."""

    model_config = ConfigDict(extra="ignore", frozen=True, defer_build=True)

    t0_s: Number
    duration_s: Number
    coeffs: list[list[Number]]
    yaw: dict[str, Any] | None = None


class PlannedVehicleModel(VehicleModel):
    """A vehicle of a plan file: its trajectory and, for other tools, its samples; its limits
    with the per-axis caps always written."""

    model_config = ConfigDict(extra="ignore", frozen=True, defer_build=True)

    sysid: SysId
    limits: PlannedLimits
    segments: Annotated[list[SegmentModel], Field(min_length=1)] = Field(
        description="the trajectory, lossless: the source of truth"
    )
    t: list[Sample] = Field(default_factory=list, description="sample instants (s), for tools")
    pos: list[list[Sample]] = Field(default_factory=list, description="positions (m), ENU")
    vel: list[list[Sample]] = Field(default_factory=list, description="velocities (m/s)")
    acc: list[list[Sample]] = Field(default_factory=list, description="accelerations (m/s^2)")
    yaw: list[Sample] = Field(default_factory=list, description="headings (rad, ENU)")


class TerrainModel(BaseModel):
    """The ground under the mission (a scenario's ``terrain:``), as a plan file keeps it: a
    regular grid of the ground's mission-frame ``z`` (:class:`planner.spec.terrain.Terrain`)."""

    model_config = ConfigDict(extra="forbid", frozen=True, defer_build=True)

    source: Text = Field("", description="the elevation model it was sampled from")
    x0_m: Number = Field(description="east of the grid's south-west node (m, ENU)")
    y0_m: Number = Field(description="north of the grid's south-west node (m, ENU)")
    step_m: Positive = Field(description="distance between nodes along x and y (m)")
    ground_z_m: Annotated[
        list[Annotated[list[Number], Field(min_length=2)]], Field(min_length=2)
    ] = Field(description="the ground's z (m) at node (i, j): x0 + i step, y0 + j step")


class PlanFileModel(BaseModel):
    """A plan file: what ``gcs plan`` writes and ``gcs verify``, ``fly``, ``upload`` read."""

    model_config = ConfigDict(
        extra="ignore",
        frozen=True,
        defer_build=True,
        title="stl-gcs plan file",
        json_schema_extra={
            "$schema": "https://json-schema.org/draft/2020-12/schema",
        },
    )

    format: Literal["stl-gcs-plan"]
    version: Literal[1]
    origin: OriginModel
    regions: dict[str, RegionModel]
    workspace: RegionModel
    vehicles: Annotated[list[PlannedVehicleModel], Field(min_length=1)]
    robustness: NumberOrNull = Field(None, description="exact robustness of the plan (m)")
    smooth_robustness: NumberOrNull = None
    horizon_s: Positive
    check_dt_s: Positive
    scenario: Text = Field(description="the scenario file the plan was made from")
    spec: Text = Field(description="the expanded STL specification")
    status: Text
    success: Flag = False
    solve_time_s: Number
    separation_m: NonNegative
    epsilon: NonNegative
    sample_dt_s: Positive
    face_tolerance_deg: Annotated[float, Strict(), AllowInfNan(False), Field(gt=0, lt=90)] = Field(
        15.0, description="how far (degrees) a face clause may be off its target"
    )
    assurance: dict[str, Any] | None = Field(
        None, description="how the plan was made to a probability (gcs plan --target-probability)"
    )
    terrain: TerrainModel | None = Field(
        None, description="the ground agl() measures from (a scenario's terrain section)"
    )


def key_path(base: str, loc: tuple[int | str, ...]) -> str:
    """``base`` and a pydantic location in the files' spelling: ``vehicles[0].limits.x``."""
    out = base
    for part in loc:
        if isinstance(part, int):
            out = f"{out}[{part}]"
        elif not part.startswith(("function-", "tagged-union")):
            out = f"{out}.{part}" if out else part
    return out


def _problem(err: Any) -> str:
    kind, value = err["type"], err.get("input")
    if kind == "missing":
        return "missing"
    if kind == "float_type":
        return f"expected a number, got {kind_of(value)}"
    if kind == "finite_number":
        return f"must be finite, got {value}"
    if kind in ("dict_type", "model_type", "model_attributes_type"):
        return f"expected a mapping, got {kind_of(value)}"
    if kind in ("list_type", "tuple_type"):
        return f"expected a list, got {kind_of(value)}"
    if kind == "extra_forbidden":
        return "unknown key"
    if kind == "too_short":
        n = err["ctx"]["min_length"]
        return "must not be empty" if n == 1 else f"expected at least {n} items, got {len(value)}"
    if kind == "literal_error":
        return f"expected {err['ctx']['expected']}, got {value!r}"
    if kind in ("less_than", "less_than_equal", "greater_than", "greater_than_equal"):
        op = {"less_than": "<", "less_than_equal": "<=", "greater_than": ">"}.get(kind, ">=")
        bound = next(iter(err["ctx"].values()))
        return f"must be {op} {bound:g}, got {value:g}"
    msg = str(err["msg"])
    return msg[:1].lower() + msg[1:]


_M = TypeVar("_M", bound=BaseModel)


def validate(
    model: type[_M], data: Any, fail: Callable[[str, str], Exception], base: str = ""
) -> _M:
    """``data`` as ``model``, or ``fail(key path, problem)`` raised for its first error.

    Args:
        fail: makes the reader's error (e.g. :class:`planner.planfile.PlanFileError`) from
            the key path (under ``base``) and the problem.
        base: the key path of ``data`` in its file.
    """
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        raise fail(key_path(base, tuple(err["loc"])), _problem(err)) from None


def plan_file_schema() -> dict[str, Any]:
    """The plan file's JSON Schema (draft 2020-12), as published in docs/."""
    return PlanFileModel.model_json_schema(mode="validation")


if __name__ == "__main__":  # python -m planner.mission_model > docs/plan-file.schema.json
    import json
    import sys

    json.dump(plan_file_schema(), sys.stdout, indent=2)
    sys.stdout.write("\n")
