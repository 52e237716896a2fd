"""The combinatorial stage: STL over a coarse vehicle model as a mixed-integer linear program.

docs/solver-notes.md, "Two stages": the discrete structure of a mission (which option of each
``or``, which vehicle takes which task, when each visit happens, which side of each keep-out)
is decided here, on positions every ``dt_c`` seconds within the vehicles' limits
(:mod:`planner.milp.model`), with big-M encodings of the predicates and temporal operators
(:mod:`planner.milp.encode`, after Raman et al. 2014), solved by HiGHS under a time budget
(:mod:`planner.milp.solve`); the NLP refines the incumbent. When no coarse path meets the
spec, :mod:`planner.milp.conflict` names a small set of clauses that conflict.

Usage::

    from planner.milp import solve_coarse, find_conflict
    res = solve_coarse(problem, time_limit_s=10.0)
    if res.success:
        res.waypoints_enu_m["d1"]        # (N + 1, 3) ENU m at res.times_s
    conflict = find_conflict(problem, time_limit_s=10.0)   # None when the spec is feasible

Errors (a failed solve is a result, never an exception)::

    PlannerError
      MilpError                bad arguments to the stage
        NotEncodable           the spec uses what the MILP cannot encode; solve_coarse
                               reports it as CoarseStatus.NOT_ENCODABLE
"""

from __future__ import annotations

from planner.milp.conflict import Conflict, find_conflict
from planner.milp.encode import MilpError, NotEncodable
from planner.milp.model import SAMPLE_BUDGET, CoarseModel, choose_dt
from planner.milp.solve import CoarseResult, CoarseStatus, problem_formulas, solve_coarse

__all__ = [
    "SAMPLE_BUDGET",
    "CoarseModel",
    "CoarseResult",
    "CoarseStatus",
    "Conflict",
    "MilpError",
    "NotEncodable",
    "choose_dt",
    "find_conflict",
    "problem_formulas",
    "solve_coarse",
]
