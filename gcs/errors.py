"""Errors of the ``gcs`` command.

Exception tree::

    UserError(Exception)          bad input from the user: one line, exit 2
      InputFileError              a file that is missing, unreadable or malformed

Errors raised by the packages for bad user input are treated alike (one
line, exit status 2): they are collected in :data:`USER_ERRORS`, which grows
as the packages define their error trees (``planner.stl.SpecError``,
``planner.scenario_sections.ScenarioError``, ``mavlink.LinkError``, ...).

Errors that cannot name the file themselves stay out of :data:`USER_ERRORS` and are converted
where the file is known: ``planner.stl.EvaluationError`` (unknown signal or region, trace too
short, ...) from a plan's spec becomes a ``PlanFileError`` naming the plan file
(``planner.planfile.plan_formula`` and ``spec_errors``); one that still reaches the command is
a bug, and its traceback is what a bug report needs.
"""

from __future__ import annotations

import importlib


class UserError(Exception):
    """Bad user input; the message names the file, field or position."""


class InputFileError(UserError):
    """A file given on the command line is missing, unreadable or malformed."""


def _optional(module: str, name: str) -> tuple[type[BaseException], ...]:
    """The exception class ``module.name`` if that module already exists."""
    try:
        return (getattr(importlib.import_module(module), name),)
    except (ImportError, AttributeError):
        return ()


#: Exception types that mean "the user gave bad input" (exit status 2).
USER_ERRORS: tuple[type[BaseException], ...] = (
    UserError,
    *_optional("planner.stl", "SpecError"),
    *_optional("planner.scenario_sections", "ScenarioError"),
    *_optional("planner.planfile", "PlanFileError"),
    *_optional("planner.frames", "FrameError"),
    *_optional("mavlink.errors", "LinkError"),
)


def format_user_error(exc: BaseException) -> str:
    """One line for the user: the message with newlines folded."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text
