"""The base of the planner's file-input errors (scenario and plan files)."""

from __future__ import annotations


class FileFieldError(ValueError):
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
