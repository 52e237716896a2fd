"""The heading the spec asks for: ``face(d, target)`` exactly (against an independent angle
computation), yaw schedules (the shorter turn, files), and a plan whose inspection hovers
face their poles, verified from its plan file."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from planner.spec.heading import YAW_RATE_MAX_DEG_S, yaw_rate_needed
from planner.spec.predicates import FACE_TOLERANCE_DEG, face_margin
from planner.spec.regions import Cylinder, Region, RegionKind
from planner.stl import EvaluationError
from planner.trajectory import Trajectory, YawMode, YawPolicy

RNG = np.random.default_rng(21)
POLE = Region.of_shape("pole3", RegionKind.POLE, Cylinder((4.0, -2.0), 0.4, 0.0, 12.0))


def test_face_is_the_aim_slip_at_the_target_within_the_tolerance() -> None:
    p = RNG.uniform(-10, 10, (500, 3))
    yaw = RNG.uniform(-np.pi, np.pi, 500)
    m = face_margin(np.column_stack([p, yaw]), POLE)
    # independently: the angle between the heading and the direction to the axis (dot product)
    d = np.array([4.0, -2.0]) - p[:, :2]
    r = np.linalg.norm(d, axis=1)
    h = np.column_stack([np.cos(yaw), np.sin(yaw)])
    err = np.arccos(np.clip(np.einsum("ij,ij->i", h, d) / r, -1, 1))
    np.testing.assert_allclose(m, r * (math.radians(FACE_TOLERANCE_DEG) - err), atol=1e-9)
    assert np.array_equal(m > 0, np.degrees(err) < FACE_TOLERANCE_DEG)


def test_face_without_the_heading_says_what_it_needs() -> None:
    with pytest.raises(EvaluationError, match=r"face\(pole3\) needs the vehicle's heading"):
        face_margin(np.zeros((4, 3)), POLE)


def _line(duration_s: float = 10.0) -> Trajectory:
    coeffs = np.zeros((1, 3, 6))
    coeffs[0, 0, 1] = 1.0  # east at 1 m/s
    return Trajectory([0.0], [duration_s], coeffs, "d1")


def test_a_schedule_turns_the_shorter_way_and_holds_at_its_ends() -> None:
    pol = YawPolicy(
        YawMode.SCHEDULE,
        knots_t_s=(2.0, 4.0),
        knots_yaw_rad=(math.radians(170), math.radians(-170)),
    )
    tr = Trajectory(_line().segment_t0_s, _line().segment_duration_s, _line().coeffs, "d1", pol)
    y = np.degrees(tr.yaw_rad(np.array([0.0, 2.0, 3.0, 4.0, 9.0])))
    np.testing.assert_allclose(np.abs(y), [170, 170, 180, 170, 170], atol=1e-9)  # through 180
    assert yaw_rate_needed(tr) == pytest.approx(10.0)  # 20 deg in 2 s


def test_a_schedule_survives_the_plan_files_segments() -> None:
    pol = YawPolicy(YawMode.SCHEDULE, knots_t_s=(0.5, 1.5, 6.0), knots_yaw_rad=(0.1, 2.0, -3.0))
    tr = Trajectory(_line().segment_t0_s, _line().segment_duration_s, _line().coeffs, "d1", pol)
    back = Trajectory.from_segments(json.loads(json.dumps(tr.to_segments())), name="d1")
    assert back.yaw_policy == pol
    t = np.linspace(0, 10, 101)
    np.testing.assert_array_equal(back.yaw_rad(t), tr.yaw_rad(t))


@pytest.mark.parametrize(
    ("data", "says"),
    [
        ({"mode": "schedule", "knots_t_s": [0, 1], "knots_yaw_rad": [0]}, "as many"),
        ({"mode": "schedule", "knots_t_s": [1, 0], "knots_yaw_rad": [0, 1]}, "increasing"),
        ({"mode": "schedule", "knots_t_s": "x", "knots_yaw_rad": [0]}, r"yaw\.knots_t_s"),
    ],
)
def test_a_bad_schedule_is_refused_naming_its_field(data: dict, says: str) -> None:  # type: ignore[type-arg]
    from planner.trajectory import TrajectoryError

    with pytest.raises(TrajectoryError, match=says):
        YawPolicy.from_dict(data)


_SCENARIO = """
name: facing
origin: {lat: 47.397742, lon: 8.545594, alt: 488.0}
workspace: {min: [-40, -40, 0.5], max: [120, 120, 20]}
line:
  along: {start: [0, 0], bearing_deg: 37, span_m: 30, count: 3}
  pole: {radius_m: 0.4, height_m: 12}
  conductors: {half_width_m: 1.8, z: [9, 12], clearance_m: 1.0}
  inspection: {standoff_m: 1.5, depth_m: 2.2, length_m: 5, z: [9.5, 12.5], side: right}
vehicles:
  - {name: d1, start: [8, -10, 8]}
limits: {v_max_m_s: 5, a_max_m_s2: 3}
timing: {horizon_s: 40, segment_s: 2, Ts_s: 0.25}
separation_m: 1.5
spec:
  - formula: eventually[0, 20] always[0, 2] (inside(d1, insp1) and face(d1, pole1))
  - formula: eventually[0, 37] always[0, 2] (inside(d1, insp3) and face(d1, pole3))
  - each: [d in all, s in spans]
    formula: always[0, $horizon] outside(d, s)
  - each: [d in all, p in poles]
    formula: always[0, $horizon] outside(d, p)
"""


@pytest.mark.slow
def test_a_plan_faces_each_pole_while_it_inspects_it_and_verify_agrees(tmp_path: Path) -> None:
    from planner.optimize import plan
    from planner.planfile import load_plan, plan_to_json
    from planner.scenario import load_scenario

    path = tmp_path / "facing.yaml"
    path.write_text(_SCENARIO)
    problem = load_scenario(path)
    result = plan(problem)
    assert result.success, result.status
    tr = result.trajectories[0]
    assert tr.yaw_policy.mode is YawMode.SCHEDULE
    assert yaw_rate_needed(tr) <= YAW_RATE_MAX_DEG_S
    # wherever the vehicle is in an inspection box, it faces that box's pole (checked on its
    # own samples, independently of the planner's rules)
    t = np.arange(0, 40.0 + 1e-9, 0.05)
    pos, yaw = tr.position(t), tr.yaw_rad(t)
    seen = 0
    for i in (1, 3):
        inside = problem.region(f"insp{i}").contains(pos)
        c = problem.region(f"pole{i}").center_enu_m
        bearing = np.arctan2(c[1] - pos[:, 1], c[0] - pos[:, 0])
        err = np.degrees(np.abs(np.angle(np.exp(1j * (yaw - bearing)))))
        assert inside.sum() >= 40, i  # the 2 s hover at least
        # exact at the knots (every 0.25 s), linear between them as the vehicle drifts
        assert np.all(err[inside] < 0.5), (i, err[inside].max())
        seen += int(inside.sum())
    assert seen > 80
    # the face clauses' robustness is the inside margin (the aim is exact there)
    for c in result.clauses[:2]:
        assert c.robustness >= result.robustness - 1e-9
    # the capture windows are the two inspection hovers, facing their poles
    from planner.spec.captures import capture_windows
    from planner.stl import And

    formula = And(tuple(problem.formulas))
    windows = capture_windows(formula, problem, result.trajectories, 0.05, 40.0)
    assert [(w.vehicle, w.target) for w in windows] == [("d1", "pole1"), ("d1", "pole3")]
    for w in windows:
        assert w.duration_s >= 2.0 - 1e-9
        i = w.target[-1]
        tw = np.arange(w.t_start_s, w.t_end_s + 1e-9, 0.05)
        assert problem.region(f"insp{i}").contains(tr.position(tw)).all()
        assert 1.8 + 1.5 - 1e-6 <= w.range_m <= 1.8 + 1.5 + 2.2 + 1.5  # stand-off to far side
        assert abs(w.gimbal_pitch_deg) < 30.0
    # gcs verify's checks, from the plan file, see the same heading
    out = tmp_path / "facing.plan.json"
    out.write_text(json.dumps(plan_to_json(result.to_plan(str(path)))))
    from gcs.checks import verify_plan

    checks = verify_plan(load_plan(out))
    assert all(c.ok for c in checks), [c for c in checks if not c.ok]
    spec_checks = [c for c in checks if "face(d1, pole1)" in c.name]
    assert spec_checks and spec_checks[0].value == pytest.approx(
        result.clauses[0].robustness, abs=1e-6
    )


@pytest.mark.slow
def test_a_heading_schedule_faster_than_the_vehicle_turns_fails_the_plans_checks(
    tmp_path: Path,
) -> None:
    from planner.optimize import plan
    from planner.scenario import load_scenario

    path = tmp_path / "slow_yaw.yaml"
    path.write_text(
        _SCENARIO.replace(
            "limits: {v_max_m_s: 5, a_max_m_s2: 3}",
            "limits: {v_max_m_s: 5, a_max_m_s2: 3, yaw_rate_max_deg_s: 2}",
        )
    )
    problem = load_scenario(path)
    assert problem.vehicles[0].yaw_rate_max_deg_s == 2.0
    result = plan(problem)
    (lim,) = result.limits
    needed = yaw_rate_needed(result.trajectories[0])
    assert needed > 2.0 and lim.yaw_ratio == pytest.approx(needed / 2.0)
    assert not lim.ok and not result.success, result.status
    saved = result.to_plan(str(path))
    assert saved.vehicles[0].yaw_rate_max_deg_s == 2.0


def test_a_face_in_an_inspection_conjunction_leaves_the_place_the_guess_routes_to(
    tmp_path: Path,
) -> None:
    """``inside(d, insp) and face(d, pole)`` is the place ``insp`` to the initial guess (the
    heading asks nothing of the position); before the fix the conjunction was no place at
    all, and the 10-pole camera line planned from its start point to -0.12 in 120 s."""
    from planner.scenario import load_scenario
    from planner.spec.geometry import place
    from planner.stl import And

    path = tmp_path / "facing.yaml"
    path.write_text(_SCENARIO)
    problem = load_scenario(path)
    node = problem.formulas[0]  # eventually[0, 20] always[0, 2] (inside(..) and face(..))
    while not isinstance(node, And):
        node = node.child
    inside, face = node.operands
    assert str(inside) == "inside(d1, insp1)" and str(face) == "face(d1, pole1)"
    alone = place(inside, problem)
    assert alone is not None
    for node in (And((inside, face)), And((face, inside))):
        got = place(node, problem)
        assert got is not None and got.vehicle == "d1"
        np.testing.assert_array_equal(got.A, alone.A)
        np.testing.assert_array_equal(got.b, alone.b)
        np.testing.assert_allclose(got.point, alone.point)
    # a heading alone is no place, nor two of them
    assert place(face, problem) is None
    assert place(And((face, face)), problem) is None


@pytest.mark.slow
def test_the_face_tolerance_is_a_scenario_field_kept_in_the_plan_file(tmp_path: Path) -> None:
    """``face_tolerance_deg`` narrows (or widens) ``face`` in the exact semantics, the capture
    windows and the plan file; a bad one is one line naming the field."""
    from planner.optimize import plan
    from planner.planfile import load_plan, plan_formula, plan_to_json
    from planner.scenario import ScenarioError, load_scenario

    tight = _SCENARIO.replace("separation_m: 1.5\n", "separation_m: 1.5\nface_tolerance_deg: 5\n")
    path = tmp_path / "tight.yaml"
    path.write_text(tight)
    problem = load_scenario(path)
    assert problem.face_tolerance_deg == 5.0
    assert load_scenario(_write(tmp_path / "default.yaml", _SCENARIO)).face_tolerance_deg == 15.0
    # the plan file keeps it, and face's exact value reads it: r (5 deg - error)
    result = plan(problem)
    out = tmp_path / "tight.plan.json"
    out.write_text(json.dumps(plan_to_json(result.to_plan(str(path)))))
    stored = load_plan(out)
    assert stored.face_tolerance_deg == 5.0
    pole = stored.region("pole1")
    c = pole.center_enu_m
    at = np.array([[c[0] + 4.0, c[1], 10.0, math.pi + math.radians(3.0)]])  # 3 deg off, 4 m
    formula = plan_formula(stored)
    (face,) = [n for n in _atoms(formula) if str(n) == "face(d1, pole1)"]
    value = face.robustness_trace({"d1": at}, 1.0)[0]
    assert value == pytest.approx(4.0 * math.radians(5.0 - 3.0), abs=1e-9)
    # an older plan file without the field reads as 15 degrees
    data = json.loads(out.read_text())
    del data["face_tolerance_deg"]
    old = tmp_path / "old.plan.json"
    old.write_text(json.dumps(data))
    assert load_plan(old).face_tolerance_deg == 15.0
    for bad, says in ((0, "must be > 0"), (95, "below 90"), ("wide", "expected a number")):
        text = _SCENARIO.replace(
            "separation_m: 1.5\n", f"separation_m: 1.5\nface_tolerance_deg: {bad}\n"
        )
        with pytest.raises(ScenarioError, match=rf"face_tolerance_deg: .*{says}"):
            load_scenario(_write(tmp_path / "bad.yaml", text))


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _atoms(node):  # type: ignore[no-untyped-def]
    from planner.stl import Predicate

    if isinstance(node, Predicate):
        yield node
    for child in node.children:
        yield from _atoms(child)
