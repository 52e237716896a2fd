"""The planner's solver runs CasADi's bundled OpenBLAS on one thread unless the user chose
(planner.solve.nlp_solvers.one_blas_thread), without touching the environment at import."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import ctypes, json, os
import casadi
import planner.solve.nlp_solvers as nlp_solvers
from planner.optimize import plan
from planner.scenario import load_scenario
env_after_import = os.environ.get("OMP_NUM_THREADS")
plan(load_scenario("configs/reach_avoid.yaml", vehicles=1))
lib = ctypes.CDLL(os.path.join(os.path.dirname(casadi.__file__), "libcasadi-tp-openblas.so.0"))
print(json.dumps({"env": env_after_import, "threads": lib.openblas_get_num_threads(),
                  "set": nlp_solvers.one_blas_thread()}))
"""


def _probe(**env: str) -> dict[str, object]:
    import json

    clean = {
        k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")
    }
    out = subprocess.run(
        [sys.executable, "-c", PROBE], cwd=ROOT, env={**clean, **env},
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


pytestmark = pytest.mark.skipif(
    not Path(__import__("casadi").__file__).with_name("libcasadi-tp-openblas.so.0").exists(),
    reason="this CasADi ships no OpenBLAS of its own",
)


@pytest.mark.slow
def test_the_solver_blas_runs_one_thread_and_the_environment_is_left_alone() -> None:
    got = _probe()
    assert got == {"env": None, "threads": 1, "set": True}


@pytest.mark.slow
def test_a_thread_count_the_user_chose_is_kept() -> None:
    got = _probe(OPENBLAS_NUM_THREADS="2")
    assert got["set"] is False and got["threads"] == 2
