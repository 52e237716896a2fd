"""Run a ``gcs`` command in this process for a benchmark: its exit status, its JSON line and
its wall time (``bench_loss.py``, ``bench_replan.py``)."""

from __future__ import annotations

import contextlib
import io
import json
import time
from typing import Any

from gcs import cli


def run_cli(args: list[str]) -> tuple[int, dict[str, Any], float]:
    """``gcs ARGS`` with its output captured: (exit status, the last JSON line of its
    standard output or ``{}``, wall seconds)."""
    out, err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main(args)
    lines = [ln for ln in out.getvalue().splitlines() if ln.startswith("{")]
    return rc, json.loads(lines[-1]) if lines else {}, time.perf_counter() - t0
