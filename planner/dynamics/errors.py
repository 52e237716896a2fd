"""Errors of :mod:`planner.dynamics`.

Error tree::

    DynamicsError(PlannerError, ValueError)  bad model parameters, shapes or limits
"""

from __future__ import annotations

from planner.errors import PlannerError

__all__ = ["DynamicsError"]


class DynamicsError(PlannerError, ValueError):
    """Invalid input to a dynamics model (parameter, array shape or limit); the message names it."""
