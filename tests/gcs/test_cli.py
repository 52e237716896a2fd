"""The ``gcs`` front end: discovery of subcommands and exit statuses."""

from __future__ import annotations

import subprocess
import sys

import pytest

from gcs import cli


def test_help_lists_only_installed_subcommands(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in cli.COMMAND_NAMES:
        assert (name in cli.available_commands()) == (f"    {name}" in out)


def test_no_subcommand_is_bad_input(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main([]) == cli.EXIT_BAD_INPUT


def test_unknown_subcommand_exits_2() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "gcs.cli", "no-such-command"], capture_output=True, text=True
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
