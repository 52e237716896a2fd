"""The test suite's wall time, alone and beside another heavy job (issue 41: tests on
simulated time).

Runs ``pytest`` as ``make test`` does (``-n WORKERS --dist load``; ``--tier fast`` adds
``-m "not slow"`` as ``make test-fast``) ``--runs`` times per load, where a load is ``none``
or ``busy`` (``--busy K`` processes multiplying numpy matrices beside the suite the whole
time: another heavy job on the same cores). Also times the rest of ``make test`` once (ruff,
import-linter, mypy, the strict docs build). Each row: wall seconds, passed, failed, errors,
skipped. Prints a table, then one JSON line. Usage::

    .venv/bin/python benchmarks/bench_suite.py [--runs 3] [--loads none,busy] [--tier all]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing as mp
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _burn(seed: int) -> None:
    """Another heavy job: dense matrix products, forever (numpy on one thread)."""
    os.environ["OMP_NUM_THREADS"] = "1"
    import numpy as np

    rng = np.random.default_rng(seed)
    a = rng.standard_normal((300, 300))
    while True:
        a = np.tanh(a @ a.T / 300.0)


@contextlib.contextmanager
def busy(k: int) -> Iterator[None]:
    """``k`` processes burning CPU while the block runs."""
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_burn, args=(i,), daemon=True) for i in range(k)]
    for p in procs:
        p.start()
    try:
        yield
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.join()


def _counts(text: str) -> dict[str, int]:
    """pytest's summary line: passed, failed, errors, skipped."""
    out = {"passed": 0, "failed": 0, "errors": 0, "skipped": 0}
    tail = text.strip().splitlines()[-1] if text.strip() else ""
    for n, what in re.findall(r"(\d+) (passed|failed|errors?|skipped)", tail):
        out["errors" if what.startswith("error") else what] += int(n)
    return out


def run_pytest(workers: int, tier: str, keep: Path | None) -> dict[str, object]:
    argv = [str(BIN / "python"), "-m", "pytest", "-q", "-n", str(workers), "--dist", "load"]
    argv += ["-p", "no:cacheprovider"]
    if tier == "fast":
        argv += ["-m", "not slow"]
    t = time.perf_counter()
    proc = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t
    row: dict[str, object] = {"wall_s": round(wall, 1), **_counts(proc.stdout)}
    failed = [ln for ln in proc.stdout.splitlines() if ln.startswith(("FAILED ", "ERROR tests"))]
    row["failures"] = failed
    if keep is not None and failed:  # the whole output of a run that failed, to read
        keep.mkdir(parents=True, exist_ok=True)
        path = keep / f"pytest-{time.strftime('%Y%m%d-%H%M%S')}.log"
        path.write_text(proc.stdout + proc.stderr, encoding="utf-8")
        row["log"] = str(path)
    return row


def run_checks() -> dict[str, float]:
    """The rest of ``make test``: each check's wall seconds."""
    with tempfile.TemporaryDirectory() as site:
        steps = {
            "ruff": [
                [str(BIN / "ruff"), "check", "."],
                [str(BIN / "ruff"), "format", "--check", "."],
            ],
            "lint-imports": [[str(BIN / "lint-imports")]],
            "mypy": [[str(BIN / "mypy")]],
            "docs": [[str(BIN / "mkdocs"), "build", "--strict", "--site-dir", site]],
        }
        out = {}
        env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
        for name, cmds in steps.items():
            t = time.perf_counter()
            for cmd in cmds:
                subprocess.run(cmd, cwd=ROOT, capture_output=True, check=True, env=env)
            out[name] = round(time.perf_counter() - t, 1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--loads", default="none,busy", help="comma-separated: none, busy")
    ap.add_argument("--busy", type=int, default=2, metavar="K", help="burning processes (2)")
    ap.add_argument("--workers", type=int, default=3)
    ap.add_argument("--tier", choices=["all", "fast"], default="all")
    ap.add_argument("--no-checks", action="store_true", help="time pytest only")
    ap.add_argument("--keep", type=Path, default=None, metavar="DIR",
                    help="write the whole output of a run that failed here")  # fmt: skip
    args = ap.parse_args()
    checks = {} if args.no_checks else run_checks()
    rows = []
    for load in args.loads.split(","):
        for k in range(args.runs):
            with busy(args.busy) if load == "busy" else contextlib.nullcontext():
                row = run_pytest(args.workers, args.tier, args.keep)
            row.update(load=load, run=k + 1)
            rows.append(row)
            print(
                f"  {load} run {k + 1}: {row['wall_s']} s, {row['failed']} failed", file=sys.stderr
            )
    print(f"pytest tier {args.tier}, -n {args.workers}, busy = {args.busy} burning processes")
    if checks:
        print("checks (s): " + ", ".join(f"{k} {v}" for k, v in checks.items()))
    print(
        f"{'load':6} {'run':>3} {'wall s':>7} {'passed':>6} {'failed':>6} {'errors':>6} {'skipped':>7}"
    )
    for r in rows:
        print(
            f"{r['load']:6} {r['run']:>3} {r['wall_s']:>7} {r['passed']:>6} {r['failed']:>6} "
            f"{r['errors']:>6} {r['skipped']:>7}"
        )
        for f in r["failures"]:  # type: ignore[attr-defined]
            print(f"    {f}")
    print(
        json.dumps(
            {
                "bench": "suite",
                "tier": args.tier,
                "workers": args.workers,
                "busy": args.busy,
                "checks_s": checks,
                "runs": rows,
            }
        )
    )


if __name__ == "__main__":
    main()
