"""PX4-like limits (horizontal-norm speed and acceleration, different bounds up and down):
read from scenarios and plan files, encoded soundly for the planner, checked on the plan, and
flown by the mock vehicle, which clamps its setpoints as PX4 does (MPC_Z_VEL_MAX_DN).

References: brute-force geometry of the disc and the polygon; linear programs (scipy's HiGHS)
that push a trajectory onto the constraints, sampled densely; the mock PX4's own limits.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.optimize import linprog

from planner.checks import check_trajectories
from planner.dynamics import MinimumJerkChain
from planner.dynamics.limits import NORM_DIRECTIONS, NORM_SIDES, Bounds, vehicle_bounds
from planner.planfile import PlanFileError, load_plan, save_plan
from planner.problem import Vehicle
from planner.scenario import parse_scenario
from planner.scenario.sections import ScenarioError
from planner.solve.nlp import two_sided_rows, vehicle_limit_bounds

# ------------------------------------------------------------------------------ geometry


def _rows_hold(b: float, p: np.ndarray) -> np.ndarray:
    """The planner's rows for a norm bound (axes and NORM_DIRECTIONS, all at ``b``)."""
    normals = np.vstack([[1.0, 0.0], [0.0, 1.0], NORM_DIRECTIONS])
    return np.all(np.abs(p @ normals.T) <= b * (1 + 1e-12), axis=1)


def test_the_polygon_lies_in_the_disc_and_holds_all_but_3_percent_of_it() -> None:
    r = 4.0
    lo, hi, b = Bounds((-9.0, -9.0, -2.0), (9.0, 9.0, 3.0), xy=r).linear()
    assert b == pytest.approx(r * math.cos(math.pi / NORM_SIDES))
    assert list(hi[:2]) == [b, b] and list(lo[:2]) == [-b, -b]  # axes lowered to the polygon
    assert (lo[2], hi[2]) == (-2.0, 3.0)  # vertical untouched
    g = np.linspace(-1.2 * r, 1.2 * r, 801)
    p = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    inside = _rows_hold(b, p)
    norm = np.hypot(p[:, 0], p[:, 1])
    assert norm[inside].max() <= r  # sound: every point the rows allow is within the disc
    assert norm[inside].max() > 0.995 * r  # and the polygon's vertices reach it
    assert inside[norm <= 0.9659 * r].all()  # 1 - cos(15 deg) = 3.4 %: all of the rest holds


def test_the_guess_box_is_inside_the_polygon_and_the_bounds_ratio_is_the_worst_excess() -> None:
    bd = Bounds((-9.0, -1.0, -1.5), (9.0, 1.0, 3.0), xy=2.0)
    lo, hi = bd.box()
    _, _, b = bd.linear()
    corners = np.array([[x, y] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])
    assert _rows_hold(b, corners).all() and hi[1] == 1.0  # y keeps its own tighter bound
    rng = np.random.default_rng(3)
    x = rng.normal(0.0, 1.5, (500, 3))
    brute = max(
        max(abs(v[2]) / (3.0 if v[2] > 0 else 1.5), abs(v[1]) / 1.0, abs(v[0]) / 9.0,
            math.hypot(v[0], v[1]) / 2.0)
        for v in x
    )  # fmt: skip
    assert bd.ratio(x) == pytest.approx(brute)


def _vehicle(**kw: Any) -> Vehicle:
    base: dict[str, Any] = dict(
        name="d1", sysid=1, start_enu_m=(0.0, 0.0, 5.0), v_max_m_s=(5, 5, 3), a_max_m_s2=(3, 3, 4)
    )
    return Vehicle(**{**base, **kw})


def test_vehicle_bounds_combine_per_axis_caps_with_px4_like_ones() -> None:
    vel, acc = vehicle_bounds(_vehicle(v_down_max_m_s=1.5, v_xy_max_m_s=4, a_up_max_m_s2=2))
    assert (vel.lo, vel.hi, vel.xy) == ((-5, -5, -1.5), (5, 5, 3), 4.0)
    assert (acc.lo, acc.hi, acc.xy) == ((-3, -3, -4), (3, 3, 2), math.inf)
    plain, _ = vehicle_bounds(_vehicle())
    assert (plain.lo, plain.hi, plain.has_norm) == ((-5, -5, -3), (5, 5, 3), False)


# --------------------------------------------------------------------- the linear rows


def _push(model: MinimumJerkChain, vehicle: Vehicle, k: int, direction: np.ndarray, order: int):
    """Z maximising ``direction . (velocity or acceleration)`` at sample ``k`` subject to the
    vehicle's limit rows laid out as the NLP has them (per axis, then the norm rows), from
    rest at the origin: an LP over the x, y, z columns (HiGHS)."""
    cons = model.limit_constraints(np.ones(3), np.ones(3))
    half = two_sided_rows(cons)
    lo, hi = vehicle_limit_bounds(model, vehicle, half, norm_rows=True)
    G = cons.G[:half]
    n = model.n_dec
    blocks = [np.kron(np.eye(3), G)]  # vec(G Z) column after column
    for c, s in NORM_DIRECTIONS:
        blocks.append(np.hstack([c * G, s * G, np.zeros_like(G)]))
    A = np.vstack(blocks)
    finite = np.isfinite(hi)
    A_ub = np.vstack([A[finite], -A[np.isfinite(lo)]])
    b_ub = np.concatenate([hi[finite], -lo[np.isfinite(lo)]])
    M = (model.Mv if order == 1 else model.Ma)[k]
    c = -np.concatenate([d * M for d in direction])
    res = linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=[(-1e3, 1e3)] * (3 * n), method="highs")
    assert res.status == 0, res.message
    return res.x.reshape((n, 3), order="F")


@pytest.mark.parametrize("order", [1, 2])
def test_the_rows_keep_the_trajectory_within_norm_and_up_down_bounds_between_samples(
    order: int,
) -> None:
    model = MinimumJerkChain(horizon_s=6.0, segment_s=1.0, sample_dt_s=0.1, explicit_acc=True)
    vehicle = _vehicle(
        v_xy_max_m_s=4.0, v_up_max_m_s=2.5, v_down_max_m_s=1.5, a_xy_max_m_s2=2.0,
        a_up_max_m_s2=3.0, a_down_max_m_s2=1.0,
    )  # fmt: skip
    bound = vehicle_bounds(vehicle)[order - 1]
    t = np.linspace(0.0, 6.0, 6001)
    X0 = np.zeros((model.n_init, 3))
    reached = {}
    for name, d in {
        "up": (0, 0, 1), "down": (0, 0, -1), "east": (1, 0, 0),
        "15 deg (a vertex)": (math.cos(math.pi / 12), math.sin(math.pi / 12), 0),
        "30 deg (a normal)": (math.cos(math.pi / 6), math.sin(math.pi / 6), 0),
        "NE and up": (0.6, 0.6, 0.5),
    }.items():  # fmt: skip
        Z = _push(model, vehicle, 30, np.asarray(d, dtype=float), order)
        tr = model.trajectory(Z, X0)
        x = tr.velocity(t) if order == 1 else tr.acceleration(t)
        assert bound.ratio(x) <= 1 + 1e-9, name  # sound, densely sampled
        reached[name] = bound.ratio(x)
    # and not much tighter than the limits: the Bernstein hull and the polygon give up a few
    # per cent (the vertex direction reaches the disc; a normal direction cos(15 deg) of it)
    assert min(reached.values()) > 0.85, reached
    assert reached["15 deg (a vertex)"] > reached["30 deg (a normal)"] - 1e-9


# --------------------------------------------------------------------------- scenarios

_SCENARIO: dict[str, Any] = {
    "name": "px4_limits",
    "origin": {"lat": 47.397742, "lon": 8.545594, "alt": 488.0},
    "workspace": {"min": [-5, -5, 0.5], "max": [45, 45, 25]},
    "regions": {"goal": {"kind": "goal", "center": [30, 30, 3], "half_size": 1}},
    "limits": {
        "v_xy_max_m_s": 3,
        "v_up_max_m_s": 3,
        "v_down_max_m_s": 1,
        "a_xy_max_m_s2": 2,
        "a_up_max_m_s2": 2,
        "a_down_max_m_s2": 1,
    },
    "vehicles": [{"name": "d1", "start": [0, 0, 17]}],
    "timing": {"horizon_s": 19, "segment_s": 1, "Ts_s": 0.25, "check_dt_s": 0.05},
    "epsilon": 0.01,
    "model": "minimum_jerk",
    "spec": ["eventually[0, 16] always[0, 2] inside(d1, goal)"],
}


def test_px4_like_keys_alone_make_the_per_axis_caps_and_partial_ones_are_named() -> None:
    v = parse_scenario(copy.deepcopy(_SCENARIO), "x.yaml").vehicles[0]
    assert v.v_max_m_s == (3, 3, 3) and v.a_max_m_s2 == (2, 2, 2)
    assert (v.v_xy_max_m_s, v.v_down_max_m_s, v.a_down_max_m_s2) == (3, 1, 1)
    data = copy.deepcopy(_SCENARIO)
    del data["limits"]["v_up_max_m_s"]
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(data, "x.yaml")
    assert str(exc.value).startswith("x.yaml: vehicles[0].limits: v_max_m_s missing")
    assert "missing: v_up_max_m_s" in str(exc.value)
    data["limits"]["v_max_m_s"] = [4, 4, 2]  # per axis given: the PX4-like ones only add
    v = parse_scenario(data, "x.yaml").vehicles[0]
    assert vehicle_bounds(v)[0] == Bounds((-4, -4, -1), (4, 4, 2), 3.0)
    data["vehicles"][0]["limits"] = {"v_down_max_m_s": -1}
    with pytest.raises(ScenarioError, match=r"vehicles\[0\]\.limits\.v_down_max_m_s: must be > 0"):
        parse_scenario(data, "x.yaml")


def test_a_target_beyond_the_descent_limit_is_refused_at_load_naming_the_limit() -> None:
    data = copy.deepcopy(_SCENARIO)
    data["spec"] = ["eventually[0, 10] always[0, 2] inside(d1, goal)"]  # 13 m down at 1 m/s
    data["regions"]["goal"]["center"] = [0, 0, 3]
    with pytest.raises(ScenarioError, match=r"goal is 13 m below d1's start .* \(limits 1 m/s"):
        parse_scenario(data, "x.yaml")
    # 33 m east and 33 m north in 14 s: within reach per axis at 3 m/s (39.75 m), not
    # at 3 m/s in norm (46.67 m diagonally)
    data["spec"] = ["eventually[0, 14] always[0, 2] inside(d1, goal)"]
    data["regions"]["goal"]["center"] = [34, 34, 19]
    with pytest.raises(
        ScenarioError, match=r"goal is 46.67 m horizontally from d1's start .* at most 39.75 m"
    ):
        parse_scenario(data, "x.yaml")


@pytest.fixture(scope="module")
def px4_plan():
    from planner.optimize import plan

    return plan(parse_scenario(copy.deepcopy(_SCENARIO), "px4_limits.yaml"))


@pytest.mark.slow
def test_a_plan_that_must_fly_at_the_limits_keeps_within_the_norm_and_the_descent_rate(
    px4_plan,
) -> None:
    # To the goal's centre 42.4 m diagonally at <= 3 m/s (2 m/s^2) and 14 m down at <= 1 m/s
    # (1 m/s^2), both from rest, in 16 s (15.6 s and 15 s as trapezoids): both limits must be
    # nearly reached (per axis, 3 m/s east and north would be 4.2 m/s)
    res = px4_plan
    assert res.success, res.status
    tr = res.trajectories[0]
    t = np.linspace(0.0, 19.0, 19001)
    vel, acc = tr.velocity(t), tr.acceleration(t)
    speed_xy = np.hypot(vel[:, 0], vel[:, 1])
    assert speed_xy.max() <= 3.0 + 1e-9 and speed_xy.max() > 2.9
    assert vel[:, 2].min() >= -1.0 - 1e-9 and vel[:, 2].min() < -0.93
    assert np.hypot(acc[:, 0], acc[:, 1]).max() <= 2.0 + 1e-9
    assert acc[:, 2].min() >= -1.0 - 1e-9 and acc[:, 2].max() <= 2.0 + 1e-9
    lim = res.limits[0]
    assert lim.ok and 0.97 < lim.v_ratio <= 1.0


def test_plan_files_keep_px4_like_limits_and_verify_checks_them(px4_plan, tmp_path: Path) -> None:
    path = tmp_path / "p.plan.json"
    save_plan(path, px4_plan)
    plan = load_plan(path)
    v = plan.vehicles[0]
    assert (v.v_xy_max_m_s, v.v_down_max_m_s, v.a_xy_max_m_s2) == (3.0, 1.0, 2.0)
    ok = check_trajectories(px4_plan.problem, [v.trajectory], [v], 0.01, 19.0)[0]
    assert ok.ok
    # the same trajectory against a vehicle that descends at 0.8 m/s at most fails the check
    data = json.loads(path.read_text())
    data["vehicles"][0]["limits"]["v_down_max_m_s"] = 0.8
    path.write_text(json.dumps(data))
    slow = load_plan(path).vehicles[0]
    rep = check_trajectories(px4_plan.problem, [slow.trajectory], [slow], 0.01, 19.0)[0]
    assert not rep.ok and rep.v_ratio > 1.1
    data["vehicles"][0]["limits"]["v_xy_max_m_s"] = "fast"
    path.write_text(json.dumps(data))
    with pytest.raises(
        PlanFileError,
        match=r"vehicles\[0\]\.limits\.v_xy_max_m_s: expected a number, got str 'fast'",
    ):
        load_plan(path)


@pytest.mark.slow
def test_the_mock_px4_tracks_a_plan_within_its_descent_limit_and_lags_one_beyond_it(
    px4_plan,
) -> None:
    # The case: a plan descending faster than MPC_Z_VEL_MAX_DN (1.5 m/s) falls behind
    # on PX4, whose position controller clamps the velocity setpoint. Flown in the batch
    # simulator (the mock vehicle's model) without disturbances.
    from mavlink.mock.sim.batch import prepare, run_seed, simulate
    from mavlink.mock.sim.disturbances import parse_disturbances
    from planner.optimize import plan

    quiet = parse_disturbances(
        {k: "0" for k in ("wind_m_s", "gust_m_s", "estimator", "ekf_origin", "start_error_m",
                          "latency_s", "jitter_s", "loss")}
    )  # fmt: skip
    errors = {}
    for label, limits, deadline in (
        ("px4-like", {"v_down_max_m_s": 1.5}, 13),
        ("per-axis", {}, 10),
    ):
        data = copy.deepcopy(_SCENARIO)
        data["limits"] = {"v_max_m_s": [3, 3, 2.5], "a_max_m_s2": [2, 2, 1.5], **limits}
        data["regions"]["goal"]["center"] = [5, 0, 3]
        data["spec"] = [f"eventually[0, {deadline}] always[0, 2] inside(d1, goal)"]
        # the plan the initial guess leads to: the subject is PX4's tracking of a plan within
        # its limits (the combinatorial stage's timing flies this one harder: 0.51 m)
        data["solver"] = {**data.get("solver", {}), "coarse_s": 0}
        res = plan(parse_scenario(data, "descent.yaml"))
        assert res.success, (label, res.status)
        v_dn = -res.trajectories[0].velocity(np.linspace(0, 19, 1901))[:, 2].min()
        flights = simulate(prepare(res.to_plan(), params={"MPC_Z_VEL_MAX_DN": 1.5}),
                           [run_seed(0, 0)], quiet)  # fmt: skip
        planned = res.trajectories[0].position(flights.t_s)
        errors[label] = (
            v_dn,
            float(np.linalg.norm(flights.true_enu_m[0, 0] - planned, axis=-1).max()),
        )
    assert errors["px4-like"][0] <= 1.5 + 1e-9 and errors["per-axis"][0] > 1.8, errors
    assert errors["px4-like"][1] < 0.5 < 1.0 < errors["per-axis"][1], errors
