"""Errors of :mod:`planner.dynamics`.

Error tree::

    DynamicsError(ValueError)      bad model parameters, shapes or limits
"""

from __future__ import annotations

__all__ = ["DynamicsError"]


class DynamicsError(ValueError):
    """Invalid input to a dynamics model (parameter, array shape or limit); the message names it."""
