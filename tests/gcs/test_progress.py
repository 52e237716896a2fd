"""The live robustness of ``gcs fly``'s progress view against its definition, evaluated from
scratch: flown positions up to now, the plan after, every clause of the vehicle."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from gcs.flight.evaluation import plan_formula
from gcs.flight.progress import FlightProgress
from planner.planfile import load_plan

REPO = Path(__file__).resolve().parents[2]
PLANS = REPO / "tests" / "mavlink" / "data"


def definition(view: FlightProgress, samples, t_now: float) -> dict[str, float]:  # type: ignore[no-untyped-def]
    plan = view.plan
    phi = plan_formula(plan)
    signals = {}
    for v in plan.vehicles:
        sig = v.trajectory.position(view.t_grid)
        rows = np.asarray(samples[v.name])
        if rows.size:
            done = view.t_grid <= min(t_now, rows[-1, 0])
            for ax in range(3):
                sig[done, ax] = np.interp(view.t_grid[done], rows[:, 0], rows[:, ax + 1])
        signals[v.name] = sig
    out = {}
    for v in plan.vehicles:
        vals = [c.robustness(signals, view.dt_s) for c in phi.clauses if v.name in c.signal_names()]
        out[v.name] = min(vals) if vals else math.nan
    return out


def test_the_incremental_view_gives_the_definition_at_every_update() -> None:
    plan = load_plan(PLANS / "reach_avoid_4.plan.json")
    view = FlightProgress(plan, tty=False)
    rng = np.random.default_rng(3)
    samples: dict[str, list] = {v.name: [] for v in plan.vehicles}
    t = 0.0
    checked = 0
    while t < plan.horizon_s + 0.5:
        t += float(rng.uniform(0.05, 0.15))  # telemetry at ~10 Hz, irregular
        for v in plan.vehicles:
            if rng.random() < 0.9:  # now and then a sample is missing
                p = v.trajectory.position([t])[0] + rng.normal(0.0, 0.2, 3)
                view.record(v.name, t, p)
                samples[v.name].append((t, *p))
        if rng.random() < 0.3:  # an update now and then, as the view does
            got = view.so_far(t)
            want = definition(view, samples, t)
            assert got.keys() == want.keys()
            for name in want:
                assert got[name] == want[name], (t, name)
            checked += 1
    assert checked > 10


def test_after_a_replan_the_view_judges_the_new_plan_and_shows_who_left() -> None:
    plan = load_plan(PLANS / "reach_avoid_4.plan.json")
    view = FlightProgress(plan, tty=False)
    samples: dict[str, list] = {v.name: [] for v in plan.vehicles}
    for k in range(1, 31):  # 3 s of telemetry, 0.3 m off the plan
        t = 0.1 * k
        for v in plan.vehicles:
            p = v.trajectory.position([t])[0] + 0.3
            view.record(v.name, t, p)
            samples[v.name].append((t, *p))
    view.so_far(3.0)
    # d2 left: the plan of the others, without the clauses that read d2
    kept = [str(c) for c in plan_formula(plan).clauses if "d2" not in c.signal_names()]
    amended = dataclasses.replace(
        plan,
        vehicles=tuple(v for v in plan.vehicles if v.name != "d2"),
        spec=" and\n".join(f"({c})" for c in kept),
    )
    view.replanned(amended, {"d2": "link lost"})
    got = view.so_far(3.0)
    want = definition(view, samples, 3.0)
    assert got == want and set(got) == {"d1", "d3", "d4"}
    assert view.order == ["d1", "d2", "d3", "d4"] and view.left == {"d2": "link lost"}


@pytest.mark.slow
def test_checking_and_flying_a_plan_never_loads_casadi_or_the_optimiser() -> None:
    # exact semantics and dense checks are numpy only: gcs verify (and the modules gcs fly
    # runs) start without CasADi and planner.optimize
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from gcs.cli import main\n"
        "import gcs.flight, gcs.flight.missions, gcs.flight.mission, mavlink.offboard\n"
        f"rc = main(['verify', {str(PLANS / 'reach_avoid_2.plan.json')!r}])\n"
        "print(rc, 'casadi' in sys.modules, 'planner.optimize' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.splitlines()[-1] == "0 False False", out.stdout[-500:]
