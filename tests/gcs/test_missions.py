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

from gcs.flight.evaluation import plan_formula
from gcs.flight.missions import (
    MIN_ACCEPTANCE_M,
    TOLERANCE_MAX_S,
    auto_acceptance_m,
    convert_plan,
    radius_candidates,
    time_tolerance,
)
from mavlink.errors import MissionError
from mavlink.mission import (
    CaptureSpan,
    Cmd,
    MissionEnd,
    MissionPlan,
    keep_waypoints,
    path_deviation,
    trajectory_to_mission,
)
from mavlink.mock.predict import PredictedMissions, predict_missions
from planner.frames import GeodeticPoint
from planner.planfile import load_plan
from planner.stl import FunctionRegistry, parse
from planner.trajectory import Trajectory
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
    chosen = max(MIN_ACCEPTANCE_M, 0.3 * fastest)
    assert plain.acceptance_m == pytest.approx(chosen)
    # the search tries PX4's NAV_ACC_RAD (2 m) and 1.5 times it too
    assert any(timed.acceptance_m == pytest.approx(r) for r in radius_candidates(chosen, 2.0))
    assert auto_acceptance_m(plan, nav_acc_rad_m=0.4) == pytest.approx(0.4)  # NAV_ACC_RAD caps
    assert all(math.isfinite(x) for x in timed.late_s.values())


def _constant_speed(points: list[tuple[float, float, float]], seg_s: float) -> Trajectory:
    """Straight segments flown at constant velocity, one per pair of points (no stops)."""
    w = np.asarray(points, dtype=float)
    n = len(w) - 1
    c = np.zeros((n, 3, 6))
    for s in range(n):
        c[s, :, 0] = w[s]
        c[s, :, 1] = (w[s + 1] - w[s]) / seg_s
    return Trajectory(np.arange(n) * seg_s, np.full(n, seg_s), c, name="d1")


def test_simplified_waypoints_keep_the_plan_within_the_tolerance_at_every_instant() -> None:
    plan = load_plan(LINK_PLAN)
    for pv in plan.vehicles:
        every = trajectory_to_mission(pv.trajectory, plan.origin, acceptance_radius_m=0.3)
        counts = []
        for tol in (0.05, 0.2, 0.5):
            mp = trajectory_to_mission(
                pv.trajectory, plan.origin, acceptance_radius_m=0.3, simplify_m=tol
            )
            # every leg, flown straight at constant speed from one waypoint's departure to
            # the next one's arrival, against the plan at the same instants, ten times finer
            # than keep_waypoints samples (a hover's own drift is the plain mission's too)
            # (a leg that is one of the plan's segments is the plain mission's, as it was)
            dep = mp.arrival_t_s + mp.hold_s
            kept = [int(np.argmin(np.abs(every.arrival_t_s - a))) for a in mp.arrival_t_s]
            for j in range(1, len(mp.arrival_t_s)):
                if kept[j] == kept[j - 1] + 1:
                    continue
                t = np.linspace(dep[j - 1], mp.arrival_t_s[j], 400)
                u = ((t - t[0]) / (t[-1] - t[0]))[:, None]
                chord = (1 - u) * mp.waypoints_enu_m[j - 1] + u * mp.waypoints_enu_m[j]
                err = np.linalg.norm(pv.trajectory.position(t) - chord, axis=1)
                assert err.max() <= tol * 1.02 + 1e-3, (pv.name, tol, j, err.max())
            assert path_deviation(pv.trajectory, mp.path).max_m <= max(
                tol * 1.02 + 1e-3, path_deviation(pv.trajectory, every.path).max_m
            )
            # the waypoints kept are the plan's, with their times, and every hover stays
            assert np.allclose(every.waypoints_enu_m[kept], mp.waypoints_enu_m)
            assert np.allclose(every.hold_s[kept], mp.hold_s)
            assert set(np.flatnonzero(every.hold_s > 0)) <= set(kept)
            counts.append(len(kept))
        assert counts == sorted(counts, reverse=True) and counts[-1] < len(every.arrival_t_s)


def test_a_straight_run_at_constant_speed_is_one_leg_and_a_corner_stays() -> None:
    line = _constant_speed([(0, 0, 5), (5, 0, 5), (10, 0, 5), (15, 0, 5), (20, 0, 5)], 2.0)
    assert keep_waypoints(line, [0.0, 2.0, 4.0, 6.0, 8.0], [0.0] * 5, 0.01) == [0, 4]
    mp = trajectory_to_mission(line, ORIGIN, acceptance_radius_m=1.0, simplify_m=0.01)
    assert mp.leg_speed_m_s.tolist() == pytest.approx([2.5])
    bent = _constant_speed([(0, 0, 5), (5, 0, 5), (10, 0, 5), (10, 5, 5), (10, 10, 5)], 2.0)
    # the corner is 2.5 m off the chord at its instant: kept; the points beside it are not
    assert keep_waypoints(bent, [0.0, 2.0, 4.0, 6.0, 8.0], [0.0] * 5, 0.5) == [0, 2, 4]
    # a hover is always kept, whatever the tolerance
    assert keep_waypoints(line, [0.0, 2.0, 4.0, 6.0, 8.0], [0, 0, 1.0, 0, 0], 100.0) == [0, 2, 4]


def test_a_short_final_approach_ends_the_leg_where_the_plan_hovers() -> None:
    # 10 m, then 0.8 m (under the 1 m radius) slowly, then a hover: the hover is at 10.8 m
    traj = min_jerk([(0, 0, 5), (10, 0, 5), (10.8, 0, 5), (10.8, 0, 5)], 2.0)
    mp = trajectory_to_mission(traj, ORIGIN, acceptance_radius_m=1.0, end=MissionEnd.HOLD)
    assert mp.waypoints_enu_m[-1] == pytest.approx([10.8, 0.0, 5.0])
    assert mp.arrival_t_s.tolist() == [0.0, 4.0] and mp.hold_s.tolist() == [0.0, 2.0]
    assert mp.leg_speed_m_s.tolist() == pytest.approx([10.8 / 4.0])
    # a drift under half the radius is part of the hover, as before
    drift = min_jerk([(0, 0, 5), (10, 0, 5), (10.3, 0, 5), (10.3, 0, 5)], 2.0)
    mp = trajectory_to_mission(drift, ORIGIN, acceptance_radius_m=1.0, end=MissionEnd.HOLD)
    assert mp.waypoints_enu_m[-1] == pytest.approx([10.0, 0.0, 5.0])
    assert mp.hold_s.tolist() == [0.0, 4.0]


def test_a_commanded_hold_replaces_the_hover_and_pictures_keep_their_time_to_departure() -> None:
    traj = min_jerk([(0, 0, 5), (10, 0, 5), (10, 0, 5), (10, 0, 5), (20, 0, 5)], 2.0)
    span = CaptureSpan(t_start_s=4.0, t_end_s=8.0, gimbal_pitch_deg=0.0, interval_s=1.0)
    plain = trajectory_to_mission(traj, ORIGIN, end=MissionEnd.HOLD, captures=[span])
    assert plain.hold_s.tolist() == [0.0, 4.0, 0.0]

    def hold_items(mp: MissionPlan) -> list[float]:
        # the NAV_WAYPOINTs at the hover (the waypoint 10 m east), their holds
        at = mp.items[int(mp.waypoint_seq[1])]
        return [
            it.param1
            for it in mp.items
            if it.command == Cmd.NAV_WAYPOINT and (it.x, it.y) == (at.x, at.y)
        ]

    # the hover split where the pictures start: 2 s before, 2 s after
    assert hold_items(plain) == pytest.approx([2.0, 2.0])
    longer = trajectory_to_mission(
        traj, ORIGIN, end=MissionEnd.HOLD, captures=[span], hold_time_s=[0.0, 5.5, 0.0]
    )
    # an early arrival waits first, then the pictures, as long as planned before departure
    assert hold_items(longer) == pytest.approx([3.5, 2.0])
    shorter = trajectory_to_mission(
        traj, ORIGIN, end=MissionEnd.HOLD, captures=[span], hold_time_s=[0.0, 2.5, 0.0]
    )
    assert hold_items(shorter) == pytest.approx([0.5, 2.0])
    # the plan's own times and path stay
    assert longer.hold_s.tolist() == shorter.hold_s.tolist() == [0.0, 4.0, 0.0]
    for bad in ([0.0, 1.0], [0.0, -1.0, 0.0], [0.0, math.nan, 0.0]):
        with pytest.raises(MissionError, match="hold_time_s"):
            trajectory_to_mission(traj, ORIGIN, hold_time_s=bad)


@pytest.fixture(scope="module")
def powerline(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from gcs.cli import main

    path = tmp_path_factory.mktemp("plans") / "powerline.json"
    scenario = Path(__file__).resolve().parents[2] / "configs" / "powerline_inspection.yaml"
    assert main(["plan", str(scenario), "-o", str(path), "--json"]) == 0
    return path


@pytest.mark.slow
def test_the_power_line_converts_to_missions_px4_is_predicted_to_fly_on_its_clock(
    powerline: Path,
) -> None:
    plan = load_plan(powerline)
    prm = {"SIH_KDV": 1.0, "SIH_MASS": 1.0}  # the px4 mock's own drag
    plain = convert_plan(plan, end=MissionEnd.HOLD, iterations=1, params=prm)
    conv = convert_plan(plan, end=MissionEnd.HOLD, params=prm)
    # one waypoint per segment at average speeds: PX4 brakes at every waypoint for the next
    # (it can stop at the next one), seconds late and far below zero
    assert plain.predicted_robustness < -5.0 and min(plain.late_s.values()) > 2.0
    assert conv.predicted_robustness >= plan.epsilon + 0.1, conv.predicted_robustness
    # never late; early by up to a couple of seconds (the legs into a hover aim early, and
    # the last hover has no departure to keep)
    assert all(-2.5 <= x <= 0.5 for x in conv.late_s.values()), conv.late_s
    assert conv.simplify_m > 0 and conv.retimed
    for name, m in conv.missions.items():
        assert len(m.waypoints_enu_m) < len(plain.missions[name].waypoints_enu_m)
        assert np.all(m.leg_speed_m_s <= 12.0)  # MPC_XY_VEL_MAX
    # the prediction is the px4 mock's own flight: judged again from its tracks
    phi = plan_formula(plan)
    t = np.arange(round(plan.horizon_s / plan.check_dt_s) + 1) * plan.check_dt_s
    sig = {n: conv.prediction.signal(n, t) for n in conv.missions}
    assert float(phi.robustness(sig, plan.check_dt_s)) == pytest.approx(conv.predicted_robustness)


def test_the_time_tolerance_of_a_clause_is_what_the_geometry_and_speeds_allow() -> None:
    # a flies along x at 4 m/s and b 3 m ahead of it; they must stay 1.5 m apart, and a must
    # pass x = 20 m by t = 6 s (it does at 5 s). Opposite timing errors of d close the gap by
    # 2 * 4 * d: tolerated up to (3 - 1.5) / 8 = 0.1875 s; a late by d passes at 5 + d: 1 s.
    t = np.arange(0.0, 10.0 + 1e-9, 0.01)
    a = np.column_stack([4.0 * t, np.zeros_like(t), np.full_like(t, 5.0)])
    pred = PredictedMissions(
        t_s=t, pos_enu_m={"a": a, "b": a + np.array([3.0, 0.0, 0.0])}, left_s={}, finished_s={}
    )
    reg = FunctionRegistry()
    reg.register(
        "dist", 2, lambda args, s: np.linalg.norm(s[args[0]] - s[args[1]], axis=1),
        lambda args, s: None, signal_args=(0, 1),
    )  # fmt: skip
    reg.register("x", 1, lambda args, s: s[args[0]][:, 0], lambda args, s: None, signal_args=(0,))
    phi = parse("always[0, 8] (dist(a, b) >= 1.5) and eventually[0, 6] (x(a) >= 20)", reg)
    grid = np.arange(0.0, 10.0 + 1e-9, 0.05)
    tol = time_tolerance(phi, pred, grid, 0.05)
    sep, reach = (tol[str(c)] for c in phi.clauses)
    assert 0.1875 - 0.05 <= sep <= 0.1875, tol
    assert 1.0 - 0.05 <= reach <= 1.0, tol
    # a clause already failing tolerates nothing; one that cannot fail, the whole range
    assert time_tolerance(parse("always[0, 8] (dist(a, b) >= 4)", reg), pred, grid, 0.05) == {
        "always[0,8] (dist(a, b) >= 4)": 0.0
    }
    far = time_tolerance(parse("always[0, 8] (dist(a, b) >= 0)", reg), pred, grid, 0.05)
    assert list(far.values()) == [TOLERANCE_MAX_S]


@pytest.mark.slow
def test_upload_start_refuses_missions_whose_clock_tolerance_is_below_what_px4_keeps(
    powerline: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The power line's missions are predicted above epsilon (+0.345), but d1 follows d2 3.3 m
    # behind at 5 m/s: their separation tolerates 0.14 s of timing error where PX4 keeps
    # vehicles to about 0.5 s (on PX4 SITL it broke by 1.3 m in one of three released
    # flights). Released missions fly without the monitor: refused before anything is sent.
    from gcs.cli import main
    from gcs.flight.dryrun import mock_vehicles

    plan = load_plan(powerline)
    with mock_vehicles(plan, seed=0) as dry:
        conns = [arg for url in dry.urls for arg in ("--connection", url)]
        capsys.readouterr()
        assert main(["upload", str(powerline), "--start", *conns]) == 1
        err = capsys.readouterr().err
        assert "refused to start: on PX4's predicted flight always[0,30] (dist(d1, d2)" in err
        assert "tolerates only 0.1" in err and "fly them with gcs fly --mode mission" in err
        assert all(not v.mission_items(0) and not v.state.armed for v in dry.mock.vehicles)
