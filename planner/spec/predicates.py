"""The scenario's function predicates: numpy (exact) and CasADi (smooth) implementations.

A scenario's spec calls these functions (:data:`PREDICATES`: each one's argument kinds and
its *role*, which is how the planner, the initial guess and the checks treat it; a new
predicate is added there and in the two implementation tables below); vehicle arguments are
signal names whose values are positions, shape (n, 3) ENU metres; region arguments are
names the function resolves from the scenario or plan (:class:`RegionSource`).

========================  ==========================================================
``inside(d, box)``        Chebyshev (L-infinity) margin to the box boundary:
                          ``min_i min(p_i - lo_i, hi_i - p_i)``; > 0 strictly inside,
                          = distance to the nearest face; < 0 outside.  Any region:
                          the smallest face margin (:meth:`planner.spec.regions.Region.margin`:
                          a prism's walls, floor and roof; a cylinder's mantle
                          ``r - |p_xy - c|``, floor and roof).
``outside(d, box)``       ``max_i max(lo_i - p_i, p_i - hi_i)``; > 0 outside (the
                          L-infinity distance to the box), < 0 inside (minus the depth);
                          any region: minus its margin.
``dist(d1, d2)``          Euclidean distance between two vehicles (m).
``face(d, target)``       the camera (the vehicle's heading) points at the target's centre
                          (a pole's axis) within the scenario's ``face_tolerance_deg``
                          (``FACE_TOLERANCE_DEG``, 15, unless given):
                          ``r (tol - |yaw - bearing|)``, ``r`` the horizontal distance to
                          it: in metres, how far the aim may slip at the target before it
                          leaves the tolerance.  Needs the heading (a vehicle signal of
                          shape (n, 4): ENU position, then ENU yaw in rad).
``alt(d)``, ``z(d)``      height above the mission origin (m); ``x(d)``, ``y(d)`` east, north.
``agl(d)``                height above the ground under the vehicle (m): ``z - ground(x, y)``
                          over the scenario's or plan's terrain
                          (:class:`planner.spec.terrain.Terrain`: bilinear between its
                          nodes); refused without one.
========================  ==========================================================

Exact values (numpy) are what the checker uses, on dense samples.  The CasADi versions are
smooth enough for IPOPT (twice differentiable everywhere) and *never above* the exact value,
so a smooth margin >= 0 implies an exact margin >= 0:

* ``inside``: soft-min by log-sum-exp over the six face margins,
  ``-log(sum exp(-k m_j)) / k``, shifted by the exact min for stability; lies in
  ``[exact - log(6)/k, exact]`` (a region of ``m`` faces: ``log(m)/k``; a cylinder's mantle
  is ``r - sqrt(|p_xy - c|^2 + delta^2)``, within ``delta`` below the exact one).
* ``outside``: soft-max minus its bound, ``log(sum exp(k m_j)) / k - log(6)/k``; lies in
  ``[exact - log(6)/k, exact]`` (the mantle's violation ``sqrt(|p_xy - c|^2 + delta^2) -
  delta - r``).
* ``dist``: ``sqrt(|p1 - p2|^2 + delta^2) - delta`` with ``delta = 1e-4`` m; lies in
  ``[exact - delta, exact]`` and is smooth where the exact distance is not (at 0).
* ``agl``: the same bilinear ground (CasADi's linear interpolant on the terrain's grid): exact.
* ``face``: ``FACE_NLP_M`` (a constant far above any margin): the heading is not a decision
  of the NLP; :mod:`planner.spec.heading` derives it from the plan (facing the target wherever
  the spec asks), and the exact check decides.

``k`` here is the *predicate* sharpness (1/m), fitted by :func:`predicate_sharpness` so that
the bound ``log(faces)/k`` (6 for boxes) is 10 % of the smallest region half-size (measured: 2 % made
the obstacle margins so sharp that IPOPT stalled inside the obstacle on reach-avoid).
A box is the conjunction (disjunction) of its six face half-spaces.  The planner's second,
sharp solve (:func:`planner.solve.refine.sharpen`, when a plan's margin is within that 10 %)
smooths a box in a smooth leaf (a formula under ``eventually``, ``or``, ``until``) as that
conjunction would be: at the leaf's own sharpness, with its ``log(6)/k`` counted in the
leaf's error bound (:func:`planner.solve.leaf_templates.smoothing_terms`).  ``inside(d, box)`` and
the same box spelled as six comparisons then give the same NLP.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from planner.spec.regions import Cylinder, Prism, Region
from planner.spec.terrain import Terrain
from planner.stl import Call, EvaluationError, Expr, Formula, FunctionRegistry, Predicate

__all__ = [
    "DIST_DELTA_M",
    "FACE_TOLERANCE_DEG",
    "PREDICATES",
    "Role",
    "box_margins",
    "build_registry",
    "ca_box_margins",
    "casadi_functions",
    "face_margin",
    "face_tolerance_deg",
    "numpy_functions",
    "positions",
    "predicate_sharpness",
    "role_of",
    "terrain_of",
]

#: Smoothing offset of ``dist`` in metres (see module docstring).
DIST_DELTA_M = 1e-4
#: Fraction of the smallest region half-size the predicate soft-min/max may lose.
_PRED_TOLERANCE = 0.1
#: How far (degrees) the heading may be off the bearing to a ``face`` target.
FACE_TOLERANCE_DEG = 15.0
#: ``face`` in the NLP: a value no margin reaches (metres), so it never decides a min.
FACE_NLP_M = 1.0e3


class Role(enum.Enum):
    """How the planner treats a predicate (beyond evaluating it)."""

    #: ``inside(d, box)``: a place to be; the NLP writes it as six exact linear face
    #: margins, the initial guess routes the vehicle through the box.
    TARGET_BOX = "target box"
    #: ``outside(d, box)``: a place to stay out of; the initial guess routes around it.
    KEEP_OUT = "keep out"
    #: ``dist(a, b)``: two vehicles' distance; ``dist(a, b) >= c`` is a keep-apart row
    #: (its curvature optional in the NLP's Hessian).
    KEEP_APART = "keep apart"
    #: ``x(d)``, ``y(d)``, ``z(d)``, ``alt(d)``: one coordinate of a vehicle.
    COORDINATE = "coordinate"
    #: ``agl(d)``: height above the terrain (a vehicle's ``z`` less the ground under it).
    TERRAIN = "terrain"
    #: ``face(d, target)``: the vehicle's heading; derived after the NLP
    #: (:mod:`planner.spec.heading`), a constant in it.
    HEADING = "heading"


@dataclass(frozen=True, slots=True)
class PredicateKind:
    """A function a spec may call.

    Attributes:
        name: its name in the spec.
        args: the kind of each argument: ``"v"`` a vehicle, ``"r"`` a region.
        role: how the planner treats it (:class:`Role`).
        terms: how many margins its smooth version soft-mins or soft-maxes over (its error
            is at most ``log(terms)/k``; 1: smooth only by a fixed offset, or exact): a
            box's; a region of another shape has its own (``Region.faces``).
    """

    name: str
    args: tuple[str, ...]
    role: Role
    terms: int = 1


#: Every function a spec may call, by name.
PREDICATES: dict[str, PredicateKind] = {
    p.name: p
    for p in (
        PredicateKind("inside", ("v", "r"), Role.TARGET_BOX, terms=6),
        PredicateKind("outside", ("v", "r"), Role.KEEP_OUT, terms=6),
        PredicateKind("dist", ("v", "v"), Role.KEEP_APART),
        PredicateKind("face", ("v", "r"), Role.HEADING),
        PredicateKind("alt", ("v",), Role.COORDINATE),
        PredicateKind("x", ("v",), Role.COORDINATE),
        PredicateKind("y", ("v",), Role.COORDINATE),
        PredicateKind("z", ("v",), Role.COORDINATE),
        PredicateKind("agl", ("v",), Role.TERRAIN),
    )
}


def role_of(node: Formula | Expr) -> Role | None:
    """The role of a predicate atom or call (``None``: anything else)."""
    call = node.call if isinstance(node, Predicate) else node
    if not isinstance(call, Call):
        return None
    kind = PREDICATES.get(call.name)
    return None if kind is None else kind.role


class RegionSource(Protocol):
    """Where predicates look up boxes: a scenario's ``Problem`` or a loaded plan."""

    @property
    def all_regions(self) -> tuple[Region, ...]: ...

    def region(self, name: str) -> Region: ...


def terrain_of(problem: Any) -> Terrain:
    """The terrain ``agl`` is measured over (a scenario's or plan's ``terrain``), else an
    :class:`EvaluationError` saying there is none."""
    t = getattr(problem, "terrain", None)
    if t is None:
        raise EvaluationError(
            "agl(d) is the height above the ground, and there is no ground: give the "
            "scenario a terrain section (docs/scenario-format.md, Terrain)"
        )
    return t


def predicate_sharpness(problem: RegionSource) -> float:
    """Sharpness k (1/m) of the smooth region margins: ``log(faces)/k = 10 %`` of the smallest
    half-size (``faces`` the most any region has: 6 with boxes only)."""
    smallest = min(r.min_half_m for r in problem.all_regions)
    faces = max(r.faces for r in problem.all_regions)
    return math.log(max(6, faces)) / (_PRED_TOLERANCE * smallest)


def box_margins(pos_enu_m: np.ndarray, region: Region) -> np.ndarray:
    """Signed face margins of points to a region, shape (n, faces); a box's ``p - lo`` then
    ``hi - p`` (:meth:`planner.spec.regions.Region.face_margins`)."""
    return region.face_margins(pos_enu_m)


def box_margin(pos_enu_m: np.ndarray, region: Region) -> np.ndarray:
    """The region's margin at each point, shape (n,): the smallest face margin
    (:meth:`planner.spec.regions.Region.margin`)."""
    return region.margin(pos_enu_m)


def _ca(v: Any) -> Any:
    import casadi as ca

    return v if isinstance(v, ca.SX | ca.MX) else ca.DM(v)


def ca_box_margins(pos: Any, region: Region) -> Any:
    """CasADi (n, faces) face margins of an (n, 3) position expression, each at most the
    exact one: linear for a box's and a prism's faces; a cylinder's mantle within
    ``DIST_DELTA_M`` below.

    The numbers may be CasADi symbols (the planner's leaf templates,
    :mod:`planner.solve.leaf_templates`, take regions as inputs: :meth:`Region.symbolic`)."""
    import casadi as ca

    n = pos.shape[0]
    s = region.shape
    if isinstance(s, Prism):
        normals, offsets = _ca(s.normals_xy), _ca(s.offsets_m)
        walls = ca.repmat(ca.reshape(offsets, 1, -1), n, 1) - ca.mtimes(pos[:, 0:2], normals.T)
        return ca.horzcat(walls, pos[:, 2] - s.z_lo_m, s.z_hi_m - pos[:, 2])
    if isinstance(s, Cylinder):
        dx, dy = pos[:, 0] - s.center_xy[0], pos[:, 1] - s.center_xy[1]
        radial = s.radius_m - ca.sqrt(dx**2 + dy**2 + DIST_DELTA_M**2)
        return ca.horzcat(radial, pos[:, 2] - s.z_lo_m, s.z_hi_m - pos[:, 2])
    lo, hi = _ca(region.lo_enu_m), _ca(region.hi_enu_m)
    return ca.horzcat(pos - ca.repmat(lo.T, n, 1), ca.repmat(hi.T, n, 1) - pos)


def _ca_violations(pos: Any, region: Region) -> Any:
    """CasADi (n, faces) face violations (minus the margins), each at most the exact one
    (a cylinder's mantle: ``sqrt(|p_xy - c|^2 + delta^2) - delta - r``)."""
    import casadi as ca

    m = -ca_box_margins(pos, region)
    if isinstance(region.shape, Cylinder):
        m = ca.horzcat(m[:, 0] - DIST_DELTA_M, m[:, 1:])
    return m


def _ca_softmin_rows(m: Any, k: float) -> Any:
    """Row-wise soft-min (n, 1) by LSE, shifted by the row min; in [min - log(c)/k, min]."""
    import casadi as ca

    c = m.shape[1]
    mn = m[:, 0]
    for j in range(1, c):
        mn = ca.fmin(mn, m[:, j])
    s = 0
    for j in range(c):
        s = s + ca.exp(-k * (m[:, j] - mn))
    return mn - ca.log(s) / k


def _ca_softmax_rows_lower(m: Any, k: float) -> Any:
    """Row-wise soft-max minus its bound (n, 1); in [max - log(c)/k, max]: the soft-min of
    ``-m``, negated and shifted down by ``log(c)/k``."""
    return -_ca_softmin_rows(-m, k) - math.log(m.shape[1]) / k


def _vehicle_signal(signals: Mapping[str, Any], name: str) -> Any:
    # The engine's signal views raise UnknownSignalError (naming the signal) themselves.
    return signals[name]


def _rows(signal: Any) -> np.ndarray:
    """A vehicle signal as rows, (n, columns): a single sample (3,) or (4,) is one row."""
    a = np.asarray(signal, dtype=float)
    return a.reshape(-1, a.shape[-1]) if a.ndim else a.reshape(-1, 3)


def positions(signal: Any) -> np.ndarray:
    """A vehicle signal's positions, (n, 3): its first three columns (a signal of shape
    (n, 4) carries the heading last)."""
    return _rows(signal)[:, :3]


def face_margin(
    signal: Any, target: Region, tolerance_deg: float = FACE_TOLERANCE_DEG
) -> np.ndarray:
    """``face``'s exact margin (m), shape (n,), from a vehicle signal of shape (n, 4): the
    range times how far the aim is within ``tolerance_deg`` (the scenario's
    ``face_tolerance_deg``)."""
    a = _rows(signal)
    if a.shape[1] < 4:
        raise EvaluationError(
            f"face({target.name}) needs the vehicle's heading, which this evaluation does not "
            f"have (a signal of shape (n, 4): position, then yaw)"
        )
    c = target.center_enu_m
    d = c[None, :2] - a[:, :2]
    r = np.hypot(d[:, 0], d[:, 1])
    err = np.abs(np.angle(np.exp(1j * (a[:, 3] - np.arctan2(d[:, 1], d[:, 0])))))
    return r * (math.radians(tolerance_deg) - err)


def face_tolerance_deg(problem: Any) -> float:
    """How far a ``face`` may be off its target (degrees): the scenario's or plan's
    ``face_tolerance_deg``, else :data:`FACE_TOLERANCE_DEG`."""
    return float(getattr(problem, "face_tolerance_deg", FACE_TOLERANCE_DEG))


def _region(problem: RegionSource, name: str) -> Region:
    try:
        return problem.region(name)
    except KeyError:
        known = ", ".join(r.name for r in problem.all_regions)
        raise EvaluationError(f"unknown region {name!r} (regions: {known})") from None


def numpy_functions(problem: RegionSource) -> dict[str, Callable[..., np.ndarray]]:
    def inside(args: tuple[str, ...], signals: Mapping[str, Any]) -> np.ndarray:
        return box_margin(positions(_vehicle_signal(signals, args[0])), _region(problem, args[1]))

    def outside(args: tuple[str, ...], signals: Mapping[str, Any]) -> np.ndarray:
        return -box_margin(positions(_vehicle_signal(signals, args[0])), _region(problem, args[1]))

    def dist(args: tuple[str, ...], signals: Mapping[str, Any]) -> np.ndarray:
        a = positions(_vehicle_signal(signals, args[0]))
        b = positions(_vehicle_signal(signals, args[1]))
        return np.linalg.norm(a - b, axis=1)

    face_tol = face_tolerance_deg(problem)

    def face(args: tuple[str, ...], signals: Mapping[str, Any]) -> np.ndarray:
        return face_margin(_vehicle_signal(signals, args[0]), _region(problem, args[1]), face_tol)

    def axis(i: int) -> Callable[..., np.ndarray]:
        def f(args: tuple[str, ...], signals: Mapping[str, Any]) -> np.ndarray:
            return positions(_vehicle_signal(signals, args[0]))[:, i]

        return f

    def agl(args: tuple[str, ...], signals: Mapping[str, Any]) -> np.ndarray:
        return terrain_of(problem).agl(positions(_vehicle_signal(signals, args[0])))

    return {
        "inside": inside,
        "outside": outside,
        "dist": dist,
        "face": face,
        "alt": axis(2),
        "x": axis(0),
        "y": axis(1),
        "z": axis(2),
        "agl": agl,
    }


def casadi_functions(problem: RegionSource, k_pred: float) -> dict[str, Callable[..., Any]]:
    """The smooth CasADi implementations by name: ``f(args, signals) -> (m, 1)``."""
    import casadi as ca

    def inside(args: tuple[str, ...], signals: Mapping[str, Any]) -> Any:
        m = ca_box_margins(_vehicle_signal(signals, args[0]), _region(problem, args[1]))
        return _ca_softmin_rows(m, k_pred)

    def outside(args: tuple[str, ...], signals: Mapping[str, Any]) -> Any:
        m = _ca_violations(_vehicle_signal(signals, args[0]), _region(problem, args[1]))
        return _ca_softmax_rows_lower(m, k_pred)

    def dist(args: tuple[str, ...], signals: Mapping[str, Any]) -> Any:
        d = _vehicle_signal(signals, args[0]) - _vehicle_signal(signals, args[1])
        sq = d[:, 0] ** 2 + d[:, 1] ** 2 + d[:, 2] ** 2
        return ca.sqrt(sq + DIST_DELTA_M**2) - DIST_DELTA_M

    def face(args: tuple[str, ...], signals: Mapping[str, Any]) -> Any:
        return FACE_NLP_M * ca.DM.ones(_vehicle_signal(signals, args[0]).shape[0], 1)

    def axis(i: int) -> Callable[..., Any]:
        def f(args: tuple[str, ...], signals: Mapping[str, Any]) -> Any:
            return _vehicle_signal(signals, args[0])[:, i]

        return f

    def agl(args: tuple[str, ...], signals: Mapping[str, Any]) -> Any:
        pos = _vehicle_signal(signals, args[0])
        return pos[:, 2] - terrain_of(problem).ca_ground(pos[:, 0:2])

    return {
        "inside": inside,
        "outside": outside,
        "dist": dist,
        "face": face,
        "alt": axis(2),
        "x": axis(0),
        "y": axis(1),
        "z": axis(2),
        "agl": agl,
    }


def build_registry(problem: RegionSource, k_pred: float | None = None) -> FunctionRegistry:
    """The FunctionRegistry of the scenario's predicates (numpy exact + CasADi smooth).

    ``k_pred`` is the predicate sharpness (1/m); default :func:`predicate_sharpness`.
    """
    k = predicate_sharpness(problem) if k_pred is None else k_pred
    np_f = numpy_functions(problem)
    # The CasADi side is built on first use: checking and flying a plan (exact semantics,
    # numpy) never imports CasADi.
    built: dict[str, Callable[..., Any]] = {}

    def smooth(name: str) -> Callable[..., Any]:
        def impl(args: tuple[str, ...], signals: Mapping[str, Any]) -> Any:
            if not built:
                built.update(casadi_functions(problem, k))
            return built[name](args, signals)

        return impl

    reg = FunctionRegistry()
    for name, kind in PREDICATES.items():
        signal_args = tuple(i for i, a in enumerate(kind.args) if a == "v")
        reg.register(name, len(kind.args), np_f[name], smooth(name), signal_args=signal_args)
    return reg
