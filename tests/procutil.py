"""Helpers for tests that run ``gcs`` (or another tool) as a child process."""

from __future__ import annotations

import signal


def interruptible() -> None:
    """``preexec_fn`` that gives the child the default SIGINT disposition.

    A shell starts background jobs with SIGINT ignored, and a child inherits that: Python then
    installs no KeyboardInterrupt handler and a test's Ctrl-C (``send_signal(SIGINT)``) would
    be silently ignored, depending on how the suite was launched.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)
