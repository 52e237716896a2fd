"""Errors of the ``gcs`` command, and what exit status each means.

Exception tree::

    GcsError(Exception)           the root of the command's own errors
      UserError                   bad input from the user: one line, exit 2
        InputFileError            a file that is missing, unreadable or malformed
      gcs.flight.FlightRefused    a check before the flight failed (exit 1)
      gcs.flight.mission.MissionRefused   the predicted mission misses the spec (exit 1)

Exit statuses (one meaning each; README "Exit statuses"): :data:`EXIT_OK` 0,
:data:`EXIT_CHECK_FAILED` 1 (a check failed or the mission was not met),
:data:`EXIT_BAD_INPUT` 2 (bad input: file, field, spec, option, connection address),
:data:`EXIT_VEHICLE_FAILED` 3 (a vehicle or its link failed: a refused command, a lost link,
a mission transfer that gave up), :data:`EXIT_INTERRUPTED` 130 (Ctrl-C), 141 (standard
output closed by its reader, :mod:`gcs.cli`).  The packages' errors are sorted into these by
type: :data:`USER_ERRORS`, :data:`CHECK_ERRORS`, :data:`VEHICLE_ERRORS`.

Errors that cannot name the file themselves stay out of :data:`USER_ERRORS` and are converted
where the file is known: ``planner.stl.EvaluationError`` (unknown signal or region, trace too
short, ...) from a plan's spec becomes a ``PlanFileError`` naming the plan file
(``planner.planfile.plan_formula`` and ``spec_errors``); one that still reaches the command is
a bug, and its traceback is what a bug report needs.
"""

from __future__ import annotations

import importlib

EXIT_OK = 0
EXIT_CHECK_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_VEHICLE_FAILED = 3
EXIT_INTERRUPTED = 130


class GcsError(Exception):
    """Root of the errors the ``gcs`` command raises itself."""


class UserError(GcsError):
    """Bad user input; the message names the file, field or position."""


class InputFileError(UserError):
    """A file given on the command line is missing, unreadable or malformed."""


def _optional(module: str, name: str) -> tuple[type[BaseException], ...]:
    """The exception class ``module.name`` if that module already exists."""
    try:
        return (getattr(importlib.import_module(module), name),)
    except (ImportError, AttributeError):
        return ()


#: A vehicle or its link failed (exit status 3): it refused a command (arming, a mode, a
#: take-off), went silent, or a mission transfer gave up or read back wrong.  Checked before
#: :data:`USER_ERRORS`, which holds their base ``LinkError``.
VEHICLE_ERRORS: tuple[type[BaseException], ...] = (
    *_optional("mavlink.errors", "CommandError"),
    *_optional("mavlink.errors", "LinkLostError"),
    *_optional("mavlink.errors", "MissionError"),
    *_optional("mavlink.px4_modes", "UnknownModeError"),
)

#: A check refused what was asked (exit status 1): a vehicle that may not start the plan
#: (too far from its start, below PX4's take-off height, ...).  Commands catch their own
#: refusals (``FlightRefused``, ``MissionRefused``) and say more; these are the rest.
CHECK_ERRORS: tuple[type[BaseException], ...] = (*_optional("mavlink.errors", "PreflightError"),)

#: Exception types that mean "the user gave bad input" (exit status 2): a file, a field, a
#: spec, an option, or a connection (a malformed address, nothing answering there, two
#: autopilots on one system id, a bad signing key).
USER_ERRORS: tuple[type[BaseException], ...] = (
    UserError,
    *_optional("planner.errors", "FileFieldError"),
    *_optional("planner.stl", "SpecError"),
    *_optional("planner.frames", "FrameError"),
    *_optional("mavlink.errors", "LinkError"),
)


def exit_status_of(exc: BaseException) -> int | None:
    """The exit status an error of a package means (``None``: a bug, let it raise)."""
    if isinstance(exc, VEHICLE_ERRORS):
        return EXIT_VEHICLE_FAILED
    if isinstance(exc, CHECK_ERRORS):
        return EXIT_CHECK_FAILED
    if isinstance(exc, USER_ERRORS):
        return EXIT_BAD_INPUT
    return None


def format_user_error(exc: BaseException) -> str:
    """One line for the user: the message with newlines folded."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text
