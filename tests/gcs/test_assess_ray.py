"""``gcs assess`` on Ray: a local Ray with 2 CPUs gives the campaign exactly as one process does,
the safety monitor's flights included (slow: Ray's start-up takes seconds)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gcs.assess import AssessOptions, assess
from planner.planfile import load_plan

pytestmark = pytest.mark.slow

PLAN = Path(__file__).resolve().parents[1] / "mavlink" / "data" / "reach_avoid_2.plan.json"


def test_a_campaign_on_a_local_ray_equals_the_same_campaign_in_one_process() -> None:
    plan = load_plan(PLAN)
    dist = {"wind_m_s": "uniform(0, 9)", "loss": "uniform(0, 0.3)"}
    seen = []
    on_ray = assess(
        plan,
        AssessOptions(runs=40, seed=11, disturbances=dist, workers=2, batch_size=9, monitor=True),
        on_batch=seen.append,
    )
    here = assess(plan, AssessOptions(runs=40, seed=11, disturbances=dist, workers=0, monitor=True))
    assert on_ray.engine.startswith("Ray (1 node, 2 CPUs)")
    assert here.engine == "this process"
    # results streamed back batch by batch, in whatever order they finished: four batches of
    # 9 and one of 4, counted up to 40 (the short batch may finish before a full one)
    done = [p.done for p in seen]
    steps = np.diff([0, *done]).tolist()
    assert sorted(steps) == [4, 9, 9, 9, 9] and done[-1] == 40, done
    for name in here.runs_table.dtype.names or ():
        np.testing.assert_array_equal(on_ray.runs_table[name], here.runs_table[name])
    assert (on_ray.p, on_ray.ci, on_ray.clauses) == (here.p, here.ci, here.clauses)
    # the safety monitor's runs too (the second flight of each run, in the same task)
    assert on_ray.monitor == here.monitor and here.monitor is not None and here.monitor.stops > 0
