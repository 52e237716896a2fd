"""The flown heading in the ground station's judgements of a flight: which clauses read it,
the live monitor leaving them out, and a track without it named, never a heading assumed
(the flight's evaluation, the plot's clause curves, the live view)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gcs.flight.evaluation import evaluate_flight, heading_readers, reads_heading
from gcs.flight.progress import FlightProgress
from gcs.plot.traces import clause_traces
from gcs.telemetry import Telemetry
from mavlink.monitor_findings import always_clause_indices, always_clauses
from mavlink.tracks import FlownTrack
from planner.planfile import Plan, load_plan
from planner.scenario import load_scenario
from planner.spec.predicates import build_registry
from planner.stl import parse
from tests.gcs.face_plan import FACE_CLAUSE


@pytest.fixture(scope="module")
def face_plan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tests.gcs.face_plan import write_face_plan

    return write_face_plan(tmp_path_factory.mktemp("face"))


def _flown(plan: Plan, heading: bool) -> dict[str, FlownTrack]:
    (v,) = plan.vehicles
    t = np.arange(-0.5, plan.horizon_s + 0.5, 0.02)
    pos = v.trajectory.position(np.clip(t, 0.0, plan.horizon_s))
    yaw = v.trajectory.yaw_rad(np.clip(t, 0.0, plan.horizon_s)) if heading else None
    return {v.name: FlownTrack(v.name, t, pos, np.zeros_like(pos), pos.copy(), yaw)}


@pytest.mark.slow
def test_the_clauses_reading_a_heading_are_found_and_left_out_of_the_live_monitor(
    face_plan: Path,
) -> None:
    problem = load_scenario(face_plan.with_name("facing.yaml"))
    phi = parse(
        "always[0, 5] face(d1, pole1) and always[0, 5] outside(d1, pole1) "
        "and always[0, 5] (face(d1, pole2) + x(d1) >= 0) and eventually[0, 5] inside(d1, insp1)",
        build_registry(problem),
    )
    assert [sorted(heading_readers(c)) for c in phi.clauses] == [["d1"], [], ["d1"], []]
    # the monitor predicts positions only: it watches the positional invariant alone
    assert always_clause_indices(phi) == (0, 1, 2)
    assert always_clause_indices(phi, reads_heading) == (1,)
    (watched,) = always_clauses(phi, ["d1"], reads_heading)
    assert "outside(d1, pole1)" in watched.name


def test_a_flight_without_a_heading_leaves_its_face_clause_unjudged_and_says_why(
    face_plan: Path,
) -> None:
    plan = load_plan(face_plan)
    full = evaluate_flight(plan, _flown(plan, heading=True))
    assert full.coverage_problem == "" and full.flown_robustness is not None
    (face,) = [c for c in full.clauses if c.text == FACE_CLAUSE]
    assert face.flown == pytest.approx(face.planned, abs=0.02)  # flown as planned
    bare = evaluate_flight(plan, _flown(plan, heading=False))
    assert bare.flown_robustness is None
    assert bare.coverage_problem.startswith("vehicle d1: the telemetry has no heading")
    for c, ref in zip(bare.clauses, full.clauses, strict=True):
        # the face clause is not judged; the others are, as with the heading
        assert c.flown is None if c.text == FACE_CLAUSE else c.flown == ref.flown


def test_the_plots_flown_curves_read_the_heading_and_name_a_track_without_one(
    face_plan: Path,
) -> None:
    plan = load_plan(face_plan)
    with_heading = clause_traces(plan, Telemetry("flown", _flown(plan, heading=True)))
    without = clause_traces(plan, Telemetry("flown", _flown(plan, heading=False)))
    for a, b in zip(with_heading, without, strict=True):
        assert a.flown_robustness is not None and a.flown_problem == ""
        if a.text == FACE_CLAUSE:
            assert b.flown_robustness is None and b.flown_rho is None
            assert b.flown_problem.startswith("vehicle d1: the telemetry has no heading")
        else:
            assert b.flown_robustness == a.flown_robustness and b.flown_problem == ""


def test_the_live_view_judges_the_flown_heading_not_the_planned_one(face_plan: Path) -> None:
    import io

    plan = load_plan(face_plan)
    (v,) = plan.vehicles
    t = np.arange(0.0, plan.horizon_s + 1e-9, 0.05)
    pos = v.trajectory.position(t)
    yaw = v.trajectory.yaw_rad(t)

    def so_far(yaw_flown: np.ndarray) -> float:
        view = FlightProgress(plan, io.StringIO(), tty=False)
        for k in range(t.size):
            view.record("d1", float(t[k]), pos[k], float(yaw_flown[k]))
        return view.so_far(plan.horizon_s)["d1"]

    assert so_far(yaw) == pytest.approx(plan.robustness, abs=0.02)
    assert so_far(yaw + np.pi / 2) < 0.0  # looking away from the pole: face fails
    assert np.isnan(so_far(np.full(t.size, np.nan)))  # unknown is unknown, not the plan's


def test_an_assessment_judges_face_on_each_runs_simulated_heading(face_plan: Path) -> None:
    from gcs.assess import evaluate_batch
    from mavlink.mock.sim.batch import prepare, simulate
    from mavlink.mock.sim.disturbances import parse_disturbances
    from planner.planfile import plan_formula

    plan = load_plan(face_plan)
    flights = simulate(prepare(plan, profile="ideal"), [1, 2], parse_disturbances({}))
    assert flights.true_yaw_enu_rad is not None and flights.reported_yaw_enu_rad is not None
    # the simulated vehicle turns with the plan's yaw schedule, behind it by its yaw loop
    plan_yaw = plan.vehicles[0].trajectory.yaw_rad(flights.t_s)
    off = np.degrees(np.abs(np.angle(np.exp(1j * (flights.true_yaw_enu_rad[:, 0] - plan_yaw)))))
    assert 0.1 < off.max() < 15.0
    _, _, c_true, c_rep = evaluate_batch(plan, flights)
    clauses = plan_formula(plan).clauses
    (i,) = [k for k, c in enumerate(clauses) if str(c) == FACE_CLAUSE]
    dt = plan.check_dt_s
    for r in range(2):
        for got, pos, yaw in (
            (c_true, flights.true_enu_m, flights.true_yaw_enu_rad),
            (c_rep, flights.reported_enu_m, flights.reported_yaw_enu_rad),
        ):
            sig = {"d1": np.column_stack([pos[r, 0], yaw[r, 0]])}
            assert got[r, i] == pytest.approx(clauses[i].robustness(sig, dt), abs=1e-12)
        assert c_true[r, i] > 0.0  # the exact vehicle inspects facing the pole
