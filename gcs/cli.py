"""The ``gcs`` command: a thin argparse front over pure functions.

Each subcommand lives in ``gcs/commands/<name>.py`` and exposes::

    HELP: str                                   # one line for ``gcs --help``
    def add_arguments(p: argparse.ArgumentParser) -> None
    def run(args: argparse.Namespace) -> int    # exit status

Only subcommands whose module exists are offered, so ``gcs --help`` never
lists a command that does not work.  A command line that names its subcommand imports that
subcommand's module alone (:func:`build_parser`), so a command loads only what it uses, and
each command module imports what it needs at its top.

Exit statuses (docs/architecture.md, "The gcs command", one meaning each; :mod:`gcs.errors`): 0 ok, 1 a check
failed or the mission was not met, 2 bad user input, 3 a vehicle or its link failed (a refused
command, a lost link), 130 interrupted.  User errors are exceptions derived from
:class:`gcs.errors.UserError` or the packages' own input errors
(:data:`gcs.errors.USER_ERRORS`); a vehicle's failure is one of
:data:`gcs.errors.VEHICLE_ERRORS`.  Either is printed as one line, without a traceback unless
``--debug`` is given.

A reader that closes standard output early (``gcs plan --print-spec | head -1``) ends the
command quietly with status 141 (128 + SIGPIPE), as a Unix tool killed by SIGPIPE does; the
SIGPIPE signal itself stays ignored (Python's default), so a broken *socket* is still an error
the link layer sees, not a silent death in flight.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import select
import sys
from collections.abc import Sequence

from gcs.errors import (
    EXIT_BAD_INPUT,
    EXIT_INTERRUPTED,
    exit_status_of,
    format_user_error,
)

#: Subcommands in the order ``gcs --help`` lists them (docs/architecture.md, "The gcs command").
COMMAND_NAMES: tuple[str, ...] = (
    "plan",
    "verify",
    "plot",
    "export",
    "mock",
    "fly",
    "upload",
    "status",
    "demo",
    "assess",
)

#: Standard output closed by its reader: 128 + SIGPIPE, what a shell shows for ``yes | head``.
EXIT_STDOUT_CLOSED = 141


def available_commands() -> list[str]:
    """Names of the subcommands whose implementation module is installed."""
    return [n for n in COMMAND_NAMES if importlib.util.find_spec(f"gcs.commands.{n}") is not None]


def command_named(argv: Sequence[str]) -> str | None:
    """The subcommand a command line names (its first word that is one), or None."""
    for word in argv:
        if word in COMMAND_NAMES:
            return word
        if not word.startswith("-"):
            return None  # an unknown command: argparse says so
    return None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The argument parser, one sub-parser per available subcommand (``only``: that one
    alone, the one a command line names; None: all of them, as ``gcs --help`` lists)."""
    parser = argparse.ArgumentParser(
        prog="gcs",
        description="Plan, verify and fly multi-drone missions from STL specifications.",
    )
    parser.add_argument(
        "--debug", action="store_true", help="show tracebacks for errors (for bug reports)"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in available_commands():
        if only is not None and name != only:
            continue
        module = importlib.import_module(f"gcs.commands.{name}")
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        p.add_argument(
            "--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS
        )
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``gcs`` console script; returns the exit status."""
    try:
        try:
            code = _main(argv)
        except SystemExit:  # argparse after --help or a usage error
            _flush_stdout()
            raise
        _flush_stdout()  # a reader that went away shows here, not at interpreter exit
        return code
    except BrokenPipeError:
        if not _stdout_closed():
            raise
        # Later writes, and the interpreter's own flush at exit, go nowhere instead of failing.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return EXIT_STDOUT_CLOSED


def _flush_stdout() -> None:
    if sys.stdout is not None:
        sys.stdout.flush()


def _stdout_closed() -> bool:
    """Whether standard output is a pipe or socket whose reader has gone.

    Tells a closed stdout from a BrokenPipeError of some other stream (a MAVLink TCP link),
    which stays an error.
    """
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # None, or replaced by a stream without fd
        return False
    if not hasattr(select, "poll"):  # Windows: no poll(); EPIPE there is stdout's in practice
        return True
    poller = select.poll()
    poller.register(fd, select.POLLOUT)
    return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))


def _main(argv: Sequence[str] | None) -> int:
    words = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(command_named(words))
    args = parser.parse_args(words)
    if getattr(args, "_run", None) is None:
        parser.print_help()
        return EXIT_BAD_INPUT
    try:
        return int(args._run(args))
    except KeyboardInterrupt:
        print("gcs: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:
        status = exit_status_of(exc)
        if status is None or args.debug:
            raise  # a bug: its traceback is what a report needs
        print(f"gcs {args.command}: error: {format_user_error(exc)}", file=sys.stderr)
        return status


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
