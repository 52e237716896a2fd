"""Errors of :mod:`planner.stl` (the tree is written out in the package docstring)."""

from __future__ import annotations

from planner.errors import PlannerError


class STLError(PlannerError):
    """Root of every error raised by :mod:`planner.stl`."""


class SpecError(STLError, ValueError):
    """Specification text that does not parse.

    Attributes:
        line: 1-based line of the offending token.
        column: 1-based column of the offending token.
        token: the offending text (``"end of input"`` at the end).
        expected: what the parser expected there, in words.
        text: the whole specification text.
    """

    def __init__(
        self, message: str, *, line: int, column: int, token: str, expected: str, text: str
    ):
        self.line = line
        self.column = column
        self.token = token
        self.expected = expected
        self.text = text
        self.detail = message
        super().__init__(f"spec line {line}, column {column}: {message}")


class FormulaError(STLError, ValueError):
    """A formula node built in Python with invalid fields (e.g. interval [5, 2])."""


class RegistryError(STLError, ValueError):
    """Invalid function registration (bad name, duplicate, bad arity)."""


class EvaluationError(STLError, ValueError):
    """A formula cannot be evaluated on the given signals."""


class UnknownSignalError(EvaluationError):
    """A signal the formula (or one of its functions) reads is not in ``signals``.

    Attributes:
        name: the missing signal name.
    """

    def __init__(self, name: str, available: tuple[str, ...]):
        self.name = name
        self.available = available
        known = ", ".join(available) if available else "none"
        super().__init__(f"unknown signal {name!r} (signals given: {known})")


class TraceLengthError(EvaluationError):
    """The trace is shorter than the formula's horizon needs.

    Attributes:
        needed: samples the formula needs (horizon steps + 1).
        given: samples in the trace.
    """

    def __init__(self, needed: int, given: int, dt: float, horizon_s: float):
        self.needed = needed
        self.given = given
        super().__init__(
            f"trace too short: the formula's horizon {horizon_s:g} s at dt={dt:g} s needs "
            f"{needed} samples, the trace has {given}"
        )


class SignalShapeError(EvaluationError):
    """A signal (or a function's output) has the wrong shape, type or non-finite values."""


class SamplingError(EvaluationError):
    """Bad sampling: dt not positive/finite, or an interval holding no sample step at this dt."""
