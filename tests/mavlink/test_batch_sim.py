"""The batch simulator of ``gcs assess``: the mock vehicle's model for many runs at once.

Checked against independent references: the plan itself (an ideal vehicle with no disturbance
flies it), PX4's offboard-loss rule (COM_OF_LOSS_T), the run seeds (a run flies the same in
any batch), and the distributions' own definitions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mavlink.mock.sim.batch import prepare, run_seed, simulate
from mavlink.mock.sim.disturbances import DISTURBANCES, Distribution, parse_disturbances
from mavlink.mock.sim.errors import MockConfigError
from mavlink.mock.sim.params import vehicle_params
from planner.planfile import load_plan

DATA = Path(__file__).resolve().parent / "data"
QUIET = {
    "wind_m_s": "0",
    "gust_m_s": "0",
    "estimator": "0",
    "ekf_origin": "0",
    "start_error_m": "0",
    "latency_s": "0",
    "jitter_s": "0",
    "loss": "0",
}


@pytest.fixture(scope="module")
def plan():  # type: ignore[no-untyped-def]
    return load_plan(DATA / "reach_avoid_2.plan.json")


def _plan_positions(plan, t):  # type: ignore[no-untyped-def]
    return np.stack([v.trajectory.position(t) for v in plan.vehicles])


def test_an_ideal_vehicle_without_disturbances_flies_the_plan(plan) -> None:  # type: ignore[no-untyped-def]
    setup = prepare(plan, profile="ideal")
    flights = simulate(setup, [run_seed(0, 0)], parse_disturbances(QUIET))
    planned = _plan_positions(plan, flights.t_s)
    err = np.linalg.norm(flights.true_enu_m[0] - planned, axis=-1)
    # the ideal vehicle follows position, velocity and acceleration; what remains is the
    # 20 Hz setpoints held between samples and the rotors' 0.05 s lag
    assert err.max() < 0.08, err.max()
    # without estimator errors the report is the truth, as gcs fly sees it: sampled at the
    # telemetry rate (20 Hz) and interpolated linearly on the check grid (np.interp here)
    every = round(1.0 / (setup.telemetry_hz * plan.check_dt_s))
    t_tel = flights.t_s[::every]
    for v in range(len(plan.vehicles)):
        for a in range(3):
            expect = np.interp(flights.t_s, t_tel, flights.true_enu_m[0, v, ::every, a])
            np.testing.assert_allclose(flights.reported_enu_m[0, v, :, a], expect, atol=1e-9)
    assert np.isnan(flights.failsafe_s).all()


def test_the_px4_vehicle_lags_and_its_estimate_differs_from_the_truth(plan) -> None:  # type: ignore[no-untyped-def]
    setup = prepare(plan)  # px4 profile, calm-day defaults
    flights = simulate(setup, [run_seed(0, r) for r in range(4)], parse_disturbances({}))
    planned = _plan_positions(plan, flights.t_s)
    rep_err = np.linalg.norm(flights.reported_enu_m - planned[None], axis=-1)
    true_off = np.linalg.norm(flights.true_enu_m - flights.reported_enu_m, axis=-1)
    assert 0.05 < rep_err.max() < 2.0
    # the EKF origin is 0.2-0.4 m off horizontally and 0.1-0.6 m vertically (px4 profile)
    assert (np.median(true_off, axis=-1) > 0.15).all()


def test_a_run_flies_the_same_in_any_batch(plan) -> None:  # type: ignore[no-untyped-def]
    setup = prepare(plan)
    dists = parse_disturbances({"gust_m_s": "uniform(0, 1)", "loss": "0.05"})
    seeds = [run_seed(7, r) for r in range(5)]
    whole = simulate(setup, seeds, dists)
    parts = [simulate(setup, seeds[:2], dists), simulate(setup, seeds[2:], dists)]
    np.testing.assert_array_equal(whole.true_enu_m, np.concatenate([p.true_enu_m for p in parts]))
    np.testing.assert_array_equal(
        whole.reported_enu_m, np.concatenate([p.reported_enu_m for p in parts])
    )
    alone = simulate(setup, [seeds[3]], dists)
    np.testing.assert_array_equal(alone.true_enu_m[0], whole.true_enu_m[3])
    for name in DISTURBANCES:
        np.testing.assert_array_equal(alone.draws[name][0], whole.draws[name][3])


def test_run_seeds_do_not_depend_on_the_campaign_size() -> None:
    assert [run_seed(3, r) for r in range(4)] == [run_seed(3, r) for r in range(10)][:4]
    assert len({run_seed(3, r) for r in range(1000)}) == 1000
    assert run_seed(3, 0) != run_seed(4, 0)


def test_a_lost_stream_triggers_px4s_failsafe_after_com_of_loss_t(plan) -> None:  # type: ignore[no-untyped-def]
    setup = prepare(plan, params={"COM_OF_LOSS_T": 0.5})
    quiet_lossy = dict(QUIET, loss="1")  # every setpoint after the first is lost
    flights = simulate(setup, [run_seed(0, 0)], parse_disturbances(quiet_lossy))
    # the stream's last setpoint arrived at the start of settling (-settle_s)
    np.testing.assert_allclose(flights.failsafe_s, -setup.settle_s + 0.5 + setup.dt_s, atol=1e-9)
    # Hold: the vehicles stay where they were, at their starts
    starts = np.array([v.start_enu_m for v in plan.vehicles])
    drift = np.linalg.norm(flights.true_enu_m[0] - starts[:, None, :], axis=-1)
    assert drift.max() < 0.1


def test_a_late_link_delays_the_flight_by_its_latency(plan) -> None:  # type: ignore[no-untyped-def]
    setup = prepare(plan, profile="ideal")
    on_time = simulate(setup, [run_seed(0, 0)], parse_disturbances(QUIET))
    late = simulate(setup, [run_seed(0, 0)], parse_disturbances(dict(QUIET, latency_s="0.3")))
    # flown(t) late ~ flown(t - 0.3) on time
    shift = round(0.3 / plan.check_dt_s)
    d = np.linalg.norm(late.true_enu_m[0][:, shift:] - on_time.true_enu_m[0][:, :-shift], axis=-1)
    assert d.max() < 0.06
    assert np.isnan(late.failsafe_s).all()  # 0.3 s < COM_OF_LOSS_T


def test_distributions_parse_sample_and_refuse_nonsense() -> None:
    rng = np.random.default_rng(0)
    assert Distribution.parse("2.5").sample(rng, 3).tolist() == [2.5, 2.5, 2.5]
    u = Distribution.parse("uniform(1, 2)").sample(rng, 10_000)
    assert u.min() >= 1.0 and u.max() <= 2.0 and abs(u.mean() - 1.5) < 0.02
    n = Distribution.parse("normal(0, 2)").sample(rng, 10_000)
    assert abs(n.std() - 2.0) < 0.1
    t = Distribution.parse("triangular(0, 0, 3)").sample(rng, 10_000)
    assert abs(t.mean() - 1.0) < 0.05
    for text, words in (
        ("gamma(1, 2)", "unknown distribution 'gamma'"),
        ("uniform(3, 1)", "A <= B"),
        ("normal(0, -1)", "SD >= 0"),
        ("uniform(1)", "takes 2"),
        ("uniform(a, b)", "must be numbers"),
        ("nan", "not a finite number"),
    ):
        with pytest.raises(MockConfigError, match=words.replace("(", r"\(")):
            parse_disturbances({"wind_m_s": text})
    with pytest.raises(MockConfigError, match="unknown disturbance 'wnd'"):
        parse_disturbances({"wnd": "1"})
    with pytest.raises(MockConfigError, match="outside"):
        parse_disturbances({"loss": "uniform(2, 3)"})


def test_draws_are_clipped_to_each_disturbances_range(plan) -> None:  # type: ignore[no-untyped-def]
    setup = prepare(plan)
    flights = simulate(
        setup, [run_seed(0, r) for r in range(20)], parse_disturbances({"loss": "normal(0, 1)"})
    )
    assert flights.draws["loss"].min() >= 0.0 and flights.draws["loss"].max() <= 1.0


def test_bad_vehicles_are_refused(plan) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(MockConfigError, match="unknown parameter 'NOPE'"):
        vehicle_params("px4", {"NOPE": 1.0})
    with pytest.raises(MockConfigError, match="AUTO_RTL"):
        prepare(plan, params={"COM_OBL_RC_ACT": 3})
    with pytest.raises(MockConfigError, match="setpoint rate"):
        prepare(plan, rate_hz=1.0)


def test_a_lost_vehicle_flies_no_setpoint_sent_after_its_loss_and_fails_safe_then(plan) -> None:  # type: ignore[no-untyped-def]
    # issue 43's random vehicle loss: with probability 1 each vehicle's link goes silent for
    # good at a time uniform over the plan; PX4's offboard-loss failsafe takes it
    # COM_OF_LOSS_T after the last setpoint that arrived (the ideal link: no loss, no delay)
    setup = prepare(plan, profile="ideal", params={"COM_OF_LOSS_T": 0.5})
    seeds = [run_seed(5, r) for r in range(6)]
    flights = simulate(setup, seeds, parse_disturbances(dict(QUIET, lost="1")))
    horizon = flights.t_s[-1]
    assert np.all((flights.lost_s >= 0.0) & (flights.lost_s < horizon))
    # the last setpoint sent before the loss arrived; its successors never did
    period = 1.0 / setup.rate_hz
    last_sent = np.floor(flights.lost_s / period - 1e-9) * period
    expect = last_sent + 0.5 + setup.dt_s
    took = expect < horizon - setup.dt_s
    np.testing.assert_allclose(flights.failsafe_s[took], expect[took], atol=setup.dt_s + 1e-9)
    # a run without the disturbance set draws what it drew before (const(0): no draw at all)
    calm = simulate(setup, seeds, parse_disturbances(QUIET))
    again = simulate(setup, seeds, parse_disturbances(dict(QUIET, lost="0")))
    np.testing.assert_array_equal(calm.true_enu_m, again.true_enu_m)
    assert np.isinf(calm.lost_s).all() and np.isnan(calm.failsafe_s).all()
    # at most the plan's setpoints up to the loss: the lost vehicle holds where it was
    lost_v = np.isfinite(flights.failsafe_s)
    assert lost_v.any()
    r, v = np.argwhere(lost_v)[0]
    after = flights.t_s > flights.failsafe_s[r, v] + 1.0
    if after.any():
        moved = np.linalg.norm(np.diff(flights.true_enu_m[r, v, after], axis=0), axis=-1).sum()
        assert moved < 0.5
