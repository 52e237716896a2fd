"""Linear quad-rotor trajectory models for the planner.

* :mod:`planner.dynamics.primitives`: Mueller's closed-form minimum-jerk primitive.
* :mod:`planner.dynamics.linear`: the :class:`LinearModel` interface (sample matrices,
  continuous-time limits as linear inequalities).
* :class:`MinimumJerkChain`: primitives between waypoints every ``segment_s``.
* :class:`DoubleIntegrator`: zero-order-hold double integrator.
* :mod:`planner.dynamics.feasibility`: Mueller's thrust / body-rate check after planning.

Error tree::

    DynamicsError(ValueError)      bad model parameters, shapes or limits
"""

from __future__ import annotations

from planner.dynamics.chain import MinimumJerkChain
from planner.dynamics.double_integrator import DoubleIntegrator
from planner.dynamics.errors import DynamicsError
from planner.dynamics.feasibility import (
    FeasibilityReport,
    InputFeasibility,
    InputLimits,
    check_input_feasibility,
    primitive_input_feasibility,
)
from planner.dynamics.linear import LimitConstraints, LinearModel
from planner.dynamics.primitives import (
    EndState,
    jerk_cost,
    min_jerk_parameters,
    primitive_coefficients,
)

__all__ = [
    "DoubleIntegrator",
    "DynamicsError",
    "EndState",
    "FeasibilityReport",
    "InputFeasibility",
    "InputLimits",
    "LimitConstraints",
    "LinearModel",
    "MinimumJerkChain",
    "check_input_feasibility",
    "jerk_cost",
    "min_jerk_parameters",
    "primitive_coefficients",
    "primitive_input_feasibility",
]
