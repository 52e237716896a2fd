"""The mission timing model (mavlink.mock.predict) and the conversion that uses it (gcs.flight.missions).

References: PX4's kinematic limits (a rest-to-rest leg cannot beat its acceleration- and
jerk-limited profile, a hold is held), and the conversion's own promises (re-timing never
makes the predicted flight later or worse; the choice of radius follows the plan's speeds).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gcs.flight.missions import MIN_ACCEPTANCE_M, auto_acceptance_m, convert_plan
from mavlink.mission import Cmd, MissionEnd, trajectory_to_mission
from mavlink.mock.predict import predict_missions
from planner.frames import GeodeticPoint
from planner.planfile import load_plan
from tests.mavlink.test_link_mission import min_jerk

ORIGIN = GeodeticPoint(47.397742, 8.545594, 488.0)
LINK_PLAN = Path(__file__).resolve().parents[1] / "mavlink" / "data" / "reach_avoid_2.plan.json"


@pytest.mark.slow
def test_a_leg_takes_at_least_its_acceleration_limited_time_and_a_hold_is_held() -> None:
    # 10 m in 5 s (2 m/s average) then a 3 s hover at the end, then 10 m back.
    traj = min_jerk([(0, 0, 3), (10, 0, 3), (10, 0, 3), (10, 0, 3), (0, 0, 3)], 5.0)
    mp = trajectory_to_mission(traj, ORIGIN, acceptance_radius_m=0.6, end=MissionEnd.HOLD)
    wps = [i.seq for i in mp.items if i.command == Cmd.NAV_WAYPOINT]
    assert mp.hold_s.tolist() == [0.0, 10.0, 0.0]

    def predict(**params: float):  # type: ignore[no-untyped-def]
        return predict_missions(
            {"d1": mp.items}, {"d1": (0.0, 0.0, 3.0)}, ORIGIN, duration_s=40.0,
            sample_dt_s=0.02, params=params,
        )  # fmt: skip

    def leg_s(pred) -> float:  # type: ignore[no-untyped-def]
        left = pred.left_s["d1"]
        return float(left[wps[1]] - mp.hold_s[1] - left[wps[0]])

    # Leg 1 at 2 m/s cruise, MPC_ACC_HOR 3 m/s^2, without drag: no faster than L / v + v / a
    # (5.67 s), and not much slower (the jerk limit and the loops add under a second and a half).
    free = leg_s(predict(SIH_KDV=0.0))
    assert 10 / 2 + 2 / 3 - 0.05 <= free <= 10 / 2 + 2 / 3 + 1.5, free
    # With SIH's drag the vehicle trails its setpoint (0.585 s x 2 m/s before the integrator
    # catches up) and PX4's trajectory waits for it (PositionSmoothing's time stretch,
    # 1 - error / MPC_XY_ERR_MAX): at first the pair settles at 2 / (1 + 0.585 x 2 / 2)
    # = 1.26 m/s, so the leg takes longer, but less than at that speed throughout.
    pred = predict()
    leg = leg_s(pred)
    assert free + 0.5 <= leg <= 10 / 1.26 + 2 / 3, (free, leg)
    left = pred.left_s["d1"]
    # The 10 s hold (the plan's hover) is held, counted from the acceptance.
    arrive = left[wps[1]] - mp.hold_s[1]
    here = pred.position("d1", np.array([arrive + 1.0, arrive + 9.0]))
    assert np.all(np.linalg.norm(here - [10.0, 0.0, 3.0], axis=1) < 0.6)
    assert pred.finished_s["d1"] is not None and pred.finished_s["d1"] > left[wps[1]] + 5.0


@pytest.mark.slow
def test_conversion_of_the_stored_plan_is_retimed_no_worse_and_reproducible() -> None:
    plan = load_plan(LINK_PLAN)
    plain = convert_plan(plan, end=MissionEnd.HOLD, iterations=1)
    timed = convert_plan(plan, end=MissionEnd.HOLD)
    again = convert_plan(plan, end=MissionEnd.HOLD)
    assert not plain.retimed and plain.iterations == 1
    assert timed.predicted_robustness >= plain.predicted_robustness
    assert max(timed.late_s.values()) <= max(plain.late_s.values()) + 1e-9
    assert again.predicted_robustness == timed.predicted_robustness  # no randomness
    # Straight-leg robustness assumes constant leg speeds; PX4 cannot fly them on time.
    assert timed.predicted_robustness < timed.straight_leg_robustness
    # The radius follows the plan's fastest leg, at least MIN_ACCEPTANCE_M.
    fastest = max(
        float(trajectory_to_mission(pv.trajectory, plan.origin).leg_speed_m_s.max())
        for pv in plan.vehicles
    )
    assert timed.acceptance_m == pytest.approx(max(MIN_ACCEPTANCE_M, 0.3 * fastest))
    assert auto_acceptance_m(plan, nav_acc_rad_m=0.4) == pytest.approx(0.4)  # NAV_ACC_RAD caps
    assert all(math.isfinite(x) for x in timed.late_s.values())
