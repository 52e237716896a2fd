"""The planner's input as values: :class:`Problem` and its parts (vehicles, timing, solver, clauses).

What :func:`planner.scenario.load_scenario` returns and :mod:`planner.optimize` consumes.  A
room of its own because these are frozen types with no reading or checking in them: the
planner, the plan files and the tests use a Problem without the YAML reader, and the
reader's modules (:mod:`planner.scenario`, :mod:`planner.scenario.sections`,
:mod:`planner.scenario.spec`) all build on them.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from planner.assurance import AssuranceGoal
from planner.frames import GeodeticPoint
from planner.spec.regions import Region
from planner.spec.terrain import Terrain
from planner.stl import Formula

__all__ = [
    "MAX_HORIZON_S",
    "QP_SOLVERS",
    "Clause",
    "DynamicsModel",
    "Problem",
    "SolverMethod",
    "SolverOptions",
    "Timing",
    "Vehicle",
]


#: Longest mission a scenario may plan (s): an hour is beyond any quad-rotor's battery.
MAX_HORIZON_S = 3600.0


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
    """One vehicle: start state at rest and its limits (per ENU axis, and optionally PX4-like:
    horizontal norm and vertical up/down; :func:`planner.dynamics.limits.vehicle_bounds` combines them)."""

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
class Timing:
    """Time grid: horizon, primitive segment length, planning sample step, checking step (s),
    and whether the plan ends at rest."""

    horizon_s: float
    segment_s: float
    sample_dt_s: float
    check_dt_s: float
    #: Every vehicle ends the horizon at rest (``timing.end: rest``, the default: a vehicle
    #: can fly the plan and hold after it); ``False`` (``end: free``) leaves the end state to
    #: the optimiser, for planning studies (``gcs verify`` then fails a plan that ends moving).
    end_at_rest: bool = True

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
    #: Starts of the multi-start (initial guesses with other route choices or shifted legs)
    #: tried in turn while the plan falls short of the mission; 1: the first guess only.
    starts: int = 4
    #: Once a start meets the mission, go on with the next starts for this long (s) and keep
    #: the best plan (a larger margin); 0: stop at the first plan that meets it.
    polish_s: float = 0.0
    #: Rounds of lexicographic refinement after the max-min: when a margin the start state
    #: fixes is the weakest, or the plan falls short of the mission, the weakest leaves are
    #: held at their margin and the others raised (planner.optimize); 0: off.
    lexicographic_rounds: int = 4
    #: Time budget (s) of the combinatorial stage (:mod:`planner.milp`: options, allocation,
    #: order and timing chosen as a mixed-integer program on a coarse model, its plan the
    #: NLP's first start), at most a quarter of the time limit; 0: off (the initial
    #: guess's starts only); None (auto): 30 s to find a coarse plan, 5 s once a plan is in
    #: hand (:data:`planner.solve.coarse_start.AUTO_BUDGET_S`).
    coarse_s: float | None = None
    #: Keep the row-wise constraints (keep-outs, separations, boxes) only where they can
    #: bind, grown until no row left out is missed (:mod:`planner.solve.screen`); None
    #: (auto): where the rows are many and most are far from binding
    #: (:func:`planner.solve.screen.chosen_screen`).
    screen: bool | None = None


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
    #: How far (degrees) a ``face`` may be off its target (the scenario's face_tolerance_deg).
    face_tolerance_deg: float = 15.0
    #: The scenario's ``assurance`` section (``gcs plan`` plans to that probability), or None.
    assurance: AssuranceGoal | None = None
    #: The ground under the mission (the scenario's ``terrain`` section: ``agl(d)`` is the
    #: height above it), or None (no ground: ``agl`` refused).
    terrain: Terrain | None = None
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
