"""The root of the planner's errors and the base of its file-input errors.

The tree is in :mod:`planner`'s docstring.
"""

from __future__ import annotations


class PlannerError(Exception):
    """Any error the planner raises on purpose (bad input to it, never a failed solve)."""


class FileFieldError(PlannerError, ValueError):
    """A mistake in an input file: ``"<file>: <key path>: <problem>"`` (no key path: the file).

    Attributes:
        source: the file.
        key_path: where in it (``vehicles[2].start``), ``""`` for the file as a whole.
        problem: what is wrong.
    """

    def __init__(self, source: str, key_path: str, problem: str) -> None:
        self.source = source
        self.key_path = key_path
        self.problem = problem
        where = f"{source}: {key_path}" if key_path else source
        super().__init__(f"{where}: {problem}")
