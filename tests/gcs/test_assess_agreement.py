"""The batch simulator against the real-time mock: a run of ``gcs assess`` and the same run's
disturbances flown by ``gcs assess --replay SEED --realtime`` (``gcs fly --dry-run``'s path:
mock PX4 vehicles over MAVLink on UDP, MAVSDK, take-off, arrival gate, offboard at 20 Hz) fly
the plan alike.

The disturbances are the deterministic ones (mean wind from any direction, setpoint latency,
derated limits): random realisations (gusts, estimator noise, jitter, loss) are drawn by the
real-time mock from its own generator on its own clock and cannot be the same flight.  Slow:
each real-time flight takes its seconds (``benchmarks/bench_assess.py --agreement N`` measures
the same on the 30 s power-line plan).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gcs.assess import AssessOptions, evaluate_batch, replay
from gcs.assess.rerun import fly_realtime
from mavlink.monitor_findings import Verdict
from planner.planfile import load_plan

pytestmark = pytest.mark.slow

PLAN = Path(__file__).resolve().parents[1] / "mavlink" / "data" / "reach_avoid_2.plan.json"
DETERMINISTIC = {
    "wind_m_s": "uniform(0, 4)",
    "latency_s": "uniform(0.005, 0.05)",
    "derate": "uniform(0.8, 1)",
    "gust_m_s": "0",
    "estimator": "0",
    "ekf_origin": "0",
    "start_error_m": "0",
    "jitter_s": "0",
    "loss": "0",
}


def test_a_run_and_its_real_time_flight_agree_within_3_cm() -> None:
    plan = load_plan(PLAN)
    opts = AssessOptions(runs=1, workers=0, disturbances=DETERMINISTIC)
    diffs = []
    for seed in (101, 303):  # two real-time flights (15 s each) of the suite's 600 s
        flights = replay(plan, opts, seed)
        sim = float(evaluate_batch(plan, flights)[1][0])
        outcome = fly_realtime(plan, opts, flights, seed=seed)
        assert outcome.completed
        assert outcome.evaluation is not None
        real = outcome.evaluation.flown_robustness
        assert real is not None
        diffs.append(abs(sim - real))
    # measured 0.009 and 0.016 m (and 0.002 for seed 202): each within 3 cm
    assert max(diffs) < 0.03, diffs


def test_a_run_that_lost_a_vehicle_loses_it_at_the_same_plan_time_in_real_time() -> None:
    # issue 43: the disturbance `lost` in the batch simulator, and the same run flown again on
    # the real-time mock (`--replay SEED --realtime`): the vehicle is lost at the run's time
    # there too, and the ground station stops on its lost link
    plan = load_plan(PLAN)
    opts = AssessOptions(runs=1, workers=0, disturbances={**DETERMINISTIC, "lost": "0.5"})
    seed, flights = next(
        (s, f)
        for s in range(1000, 1100)
        if np.isfinite((f := replay(plan, opts, s)).lost_s).sum() == 1 and f.lost_s.min() < 3.5
    )
    v = int(np.argmin(flights.lost_s[0]))
    name = plan.vehicles[v].name
    outcome = fly_realtime(plan, opts, flights, seed=seed)
    assert not outcome.completed
    ev = outcome.safety_event
    assert ev is not None and ev.verdict is Verdict.LINK_LOST and ev.vehicles == (name,)
    # its record ends where its link went silent (telemetry at 20 Hz)
    t_end = float(outcome.tracks[name].t_s[-1])
    assert abs(t_end - float(flights.lost_s[0, v])) < 0.15, (t_end, flights.lost_s)
