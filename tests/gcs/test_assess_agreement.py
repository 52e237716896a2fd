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

import pytest

from gcs.assess import AssessOptions, evaluate_batch, replay
from gcs.assess.rerun import fly_realtime
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
