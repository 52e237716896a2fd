"""The ``gcs`` front end: discovery of subcommands and exit statuses."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

from gcs import cli
from gcs.errors import EXIT_BAD_INPUT

ROOT = Path(__file__).resolve().parents[2]


def test_help_lists_only_installed_subcommands(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in cli.COMMAND_NAMES:
        assert (name in cli.available_commands()) == (f"    {name}" in out)


def test_no_subcommand_is_bad_input(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main([]) == EXIT_BAD_INPUT


def test_unknown_subcommand_exits_2() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "gcs.cli", "no-such-command"], capture_output=True, text=True
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr


def _run_with_stdout_closed(*argv: str) -> subprocess.CompletedProcess[str]:
    """Run ``gcs argv`` with stdout a pipe whose reader is already gone (``| head -0``)."""
    read_fd, write_fd = os.pipe()
    os.close(read_fd)
    try:
        return subprocess.run(
            [sys.executable, "-m", "gcs.cli", *argv],
            stdout=write_fd,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
            timeout=120,
        )
    finally:
        os.close(write_fd)


@pytest.mark.parametrize(
    ("argv", "code"),
    [
        # The audit's case: ``gcs plan ... --print-spec | head -1``.
        (("plan", "configs/reach_avoid.yaml", "--vehicles", "16", "--print-spec"), 141),
        # argparse ignores a failed write of the help itself and exits 0.
        (("--help",), 0),
    ],
    ids=["plan-print-spec", "help"],
)
def test_closed_stdout_ends_quietly_like_a_unix_tool(argv: tuple[str, ...], code: int) -> None:
    proc = _run_with_stdout_closed(*argv)
    assert proc.stderr == ""  # no BrokenPipeError traceback, no "Exception ignored" at exit
    assert proc.returncode == code
    assert cli.EXIT_STDOUT_CLOSED == 141  # 128 + SIGPIPE, as a shell reports ``yes | head``


def test_broken_pipe_of_another_stream_is_not_swallowed(monkeypatch: pytest.MonkeyPatch) -> None:
    from gcs.commands import status

    def lost_link(args: argparse.Namespace) -> int:
        raise BrokenPipeError(32, "Broken pipe")  # e.g. a TCP link; stdout is fine

    monkeypatch.setattr(status, "run", lost_link)
    with pytest.raises(BrokenPipeError):
        cli.main(["status"])
