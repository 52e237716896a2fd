"""planner.trajectory: exact evaluation, hold, sampling, yaw, lossless serialisation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from planner.dynamics import MinimumJerkChain
from planner.trajectory import Setpoints, Trajectory, TrajectoryError, YawMode, YawPolicy


def _random_trajectory(seed: int = 0, yaw: YawPolicy | None = None) -> Trajectory:
    rng = np.random.default_rng(seed)
    model = MinimumJerkChain(horizon_s=5.0, segment_s=1.25, sample_dt_s=0.05, yaw_policy=yaw)
    Z = np.empty((model.n_dec, 3))
    Z[model.pos_rows] = np.cumsum(rng.normal(0, 2, (model.n_segments, 3)), axis=0)
    Z[model.vel_rows] = rng.normal(0, 1, (model.n_segments, 3))
    Z[model.vel_rows][-1] = 0.0
    X0 = np.vstack([rng.normal(0, 1, 3), np.zeros(3), np.zeros(3)])
    return model.trajectory(Z, X0, "d1")


def _reference(traj: Trajectory, t: float, order: int) -> np.ndarray:
    """Scalar evaluation through numpy.polynomial (independent of the vectorised Horner)."""
    s = int(np.searchsorted(traj.segment_t0_s, t, side="right") - 1)
    s = min(max(s, 0), traj.n_segments - 1)
    tau = t - traj.segment_t0_s[s]
    return np.array(
        [np.polynomial.Polynomial(traj.coeffs[s, a]).deriv(order)(tau) for a in range(3)]
    )


def test_evaluation_matches_independent_polynomials() -> None:
    traj = _random_trajectory(1)
    t = np.random.default_rng(2).uniform(0, traj.duration_s, 200)
    for order, fn in enumerate((traj.position, traj.velocity, traj.acceleration, traj.jerk)):
        got = fn(t)
        assert got.shape == (200, 3)
        ref = np.array([_reference(traj, ti, order) for ti in t])
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-10)
    assert traj.duration_s == pytest.approx(5.0)
    assert traj.name == "d1" and traj.degree == 5 and traj.n_segments == 4


def test_end_state_is_exact_and_held_as_hover_after_the_end() -> None:
    traj = _random_trajectory(3)
    end = traj.duration_s
    last = traj.n_segments - 1
    T = traj.segment_duration_s[last]
    exact_end = np.array([np.polyval(traj.coeffs[last, a][::-1], T) for a in range(3)])
    np.testing.assert_allclose(traj.position([end])[0], exact_end, rtol=0, atol=1e-12)
    after = np.array([end + 1e-6, end + 10.0])
    np.testing.assert_allclose(traj.position(after), np.vstack([exact_end, exact_end]), atol=1e-12)
    assert np.all(traj.velocity(after) == 0.0)
    assert np.all(traj.acceleration(after) == 0.0)
    before = traj.position([-3.0])[0]
    np.testing.assert_allclose(before, traj.position([0.0])[0])
    assert np.all(traj.velocity([-3.0]) == 0.0)


def test_sample_covers_the_whole_trajectory_at_the_rate() -> None:
    traj = _random_trajectory(4)
    sp = traj.sample(20.0)
    assert isinstance(sp, Setpoints)
    assert len(sp) == 101  # 0 .. 5 s at 20 Hz
    np.testing.assert_allclose(np.diff(sp.t_s), 0.05)
    assert sp.t_s[-1] >= traj.duration_s - 1e-12
    np.testing.assert_allclose(sp.pos_enu_m, traj.position(sp.t_s))
    np.testing.assert_allclose(sp.vel_enu_m_s, traj.velocity(sp.t_s))
    np.testing.assert_allclose(sp.acc_enu_m_s2, traj.acceleration(sp.t_s))
    assert sp.yaw_rad.shape == (101,)
    sp3 = traj.sample(2.3)  # 5 s is not a multiple of 1/2.3 s: one sample after the end
    assert sp3.t_s[-1] == pytest.approx(12 / 2.3) and sp3.t_s[-2] < traj.duration_s
    np.testing.assert_allclose(sp3.pos_enu_m[-1], traj.position([traj.duration_s])[0])
    with pytest.raises(TrajectoryError, match="rate_hz"):
        traj.sample(0.0)


def test_segments_round_trip_through_json_exactly() -> None:
    for yaw in (YawPolicy(), YawPolicy(YawMode.VELOCITY, 0.3, 0.2)):
        traj = _random_trajectory(5, yaw)
        text = json.dumps(traj.to_segments())
        back = Trajectory.from_segments(json.loads(text), name="d1")
        assert np.array_equal(back.coeffs, traj.coeffs)
        assert np.array_equal(back.segment_t0_s, traj.segment_t0_s)
        assert np.array_equal(back.segment_duration_s, traj.segment_duration_s)
        assert back.yaw_policy == traj.yaw_policy and back.name == "d1"
        t = np.linspace(-1, 6, 301)
        assert np.array_equal(back.position(t), traj.position(t))
        assert np.array_equal(back.yaw(t), traj.yaw(t))
        assert back.to_segments() == traj.to_segments()


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda s: s.__setitem__(1, "x"), r"segments\[1\]: expected an object"),
        (lambda s: s[2].pop("coeffs"), r"segments\[2\]: missing field 'coeffs'"),
        (lambda s: s[0]["coeffs"][1].__setitem__(3, "a"), r"segments\[0\]\.coeffs\[1\]\[3\]"),
        (lambda s: s[1]["coeffs"].pop(), r"segments\[1\]\.coeffs: expected 3 lists"),
        (lambda s: s[1]["coeffs"][0].pop(), r"segments\[1\]\.coeffs: all axes"),
        (lambda s: s[3].__setitem__("t0_s", 9.0), r"segments\[3\]: t0_s=9\.0 does not follow"),
        (lambda s: s[2].__setitem__("duration_s", -1.0), r"segments\[2\]: .*duration > 0"),
        (lambda s: s[1]["yaw"].__setitem__("mode", "spin"), r"segments\[1\]\.yaw\.mode"),
        (lambda s: s[1]["yaw"].__setitem__("yaw_rad", 1.0), r"segments\[1\]\.yaw: differs"),
        (lambda s: s[0].__setitem__("t0_s", float("nan")), r"segments\[0\]\.t0_s: must be finite"),
    ],
)
def test_bad_segments_name_the_position(mutate, message: str) -> None:
    segs = _random_trajectory(6).to_segments()
    mutate(segs)
    with pytest.raises(TrajectoryError, match=message):
        Trajectory.from_segments(segs)


def test_empty_or_non_list_segments_are_rejected() -> None:
    with pytest.raises(TrajectoryError, match="at least one"):
        Trajectory.from_segments([])
    with pytest.raises(TrajectoryError, match="expected a list"):
        Trajectory.from_segments({"t0_s": 0})


def test_constant_yaw_is_the_default() -> None:
    traj = _random_trajectory(7)
    assert traj.yaw_policy.mode is YawMode.CONSTANT
    assert np.all(traj.yaw([0.0, 2.0, 9.0]) == 0.0)
    traj2 = Trajectory.from_segments(
        [{**s, "yaw": {"mode": "constant", "yaw_rad": 4.0}} for s in traj.to_segments()]
    )
    np.testing.assert_allclose(traj2.yaw([1.0]), [4.0 - 2 * np.pi])  # wrapped to (-pi, pi]


def test_velocity_yaw_faces_travel_and_holds_heading_when_slow() -> None:
    # 1-D east-west motion: accelerate east, stop, return west, stop.
    s = np.array([0.0, 0.0, 0.0, 10.0, -15.0, 6.0])  # 10 u^3 - 15 u^4 + 6 u^5 over 1 s
    zero = np.zeros(6)
    seg0 = np.stack([s, zero, zero])
    # Segment 1 over 2 s: 10 - 10 s(tau / 2).
    seg1 = np.stack([np.array([10.0, 0.0, 0.0, -100 / 8, 150 / 16, -60 / 32]), zero, zero])
    policy = YawPolicy(YawMode.VELOCITY, yaw_rad=1.0, min_speed_m_s=0.5)
    traj = Trajectory([0.0, 1.0], [1.0, 2.0], np.stack([seg0, seg1]), yaw_policy=policy)
    # Before moving: the initial heading.
    assert traj.yaw([0.0])[0] == pytest.approx(1.0)
    # Moving east fast: 0 rad; moving west fast: pi.
    assert traj.yaw([0.5])[0] == pytest.approx(0.0, abs=1e-12)
    assert abs(traj.yaw([2.0])[0]) == pytest.approx(np.pi)
    # Slow near the turn-around (t = 1 s): keeps heading east (last fast direction).
    v_turn = traj.velocity([1.0])[0]
    assert np.linalg.norm(v_turn[:2]) < 0.5
    assert traj.yaw([1.0])[0] == pytest.approx(0.0, abs=1e-12)
    # Slow at the end: keeps facing west; after the end likewise.
    assert abs(traj.yaw([3.0, 5.0])).tolist() == pytest.approx([np.pi, np.pi])
    # Same values whatever else is queried (exact event times, no history in the query).
    t = np.linspace(0, 3, 301)
    all_at_once = traj.yaw(t)
    one_by_one = np.array([traj.yaw([ti])[0] for ti in t])
    assert np.array_equal(all_at_once, one_by_one)


def test_constructor_validates_shapes() -> None:
    with pytest.raises(TrajectoryError, match="coeffs must have shape"):
        Trajectory([0.0], [1.0], np.zeros((1, 2, 6)))
    with pytest.raises(TrajectoryError, match="segment 0: t0_s must be 0"):
        Trajectory([1.0], [1.0], np.zeros((1, 3, 6)))
    traj = Trajectory([0.0], [1.0], np.zeros((1, 3, 2)))  # any degree works
    assert traj.jerk([0.5]).tolist() == [[0.0, 0.0, 0.0]]
    with pytest.raises(TrajectoryError, match="finite"):
        traj.position([np.nan])


def test_velocity_yaw_without_a_threshold_crossing() -> None:
    # Always fast (1 m/s east) or always slow (hovering): no crossing event exists.
    zero = np.zeros(6)
    east = np.stack([np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0]), zero, zero])
    policy = YawPolicy(YawMode.VELOCITY, yaw_rad=1.0, min_speed_m_s=0.1)
    moving = Trajectory([0.0], [2.0], east[None], yaw_policy=policy)
    assert moving.yaw_rad([0.5, 1.5]).tolist() == pytest.approx([0.0, 0.0], abs=1e-12)
    hover = Trajectory([0.0], [2.0], np.zeros((1, 3, 6)), yaw_policy=policy)
    assert hover.yaw_rad([0.0, 1.0, 3.0]).tolist() == pytest.approx([1.0, 1.0, 1.0])
