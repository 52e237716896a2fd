"""``gcs fly`` end to end on real files and real MAVLink over loopback UDP.

The plan is made by ``gcs plan`` from configs/reach_avoid.yaml (2 drones), checked by
``gcs verify``, exported, and flown with ``--dry-run`` (mock PX4 vehicles in-process, MAVSDK
on the GCS side). The flight is judged on the telemetry the vehicles sent: the tracks the
command reports, and independently the ``.tlog`` bytes re-read with pymavlink.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from gcs.cli import main
from gcs.flight.dryrun import free_udp_ports
from gcs.flight.evaluation import plan_formula
from gcs.telemetry import load_images, load_telemetry
from mavlink.tlog import tracks_from_tlog
from planner.planfile import load_plan
from tests.procutil import interruptible

pytestmark = pytest.mark.slow  # flights or transfers over UDP (make test-fast skips)

REPO = Path(__file__).resolve().parents[2]
SCENARIO = REPO / "configs" / "reach_avoid.yaml"


@pytest.fixture(scope="module")
def plan_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 2-drone reach-avoid plan written by ``gcs plan``."""
    path = tmp_path_factory.mktemp("fly") / "reach_avoid.json"
    assert main(["plan", str(SCENARIO), "--vehicles", "2", "-o", str(path), "--json"]) == 0
    return path


@pytest.mark.parametrize("profile", ["ideal"])
def test_plan_verify_export_and_dry_run_flight_satisfy_the_spec(
    plan_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], profile: str
) -> None:
    assert main(["verify", str(plan_file)]) == 0
    qgc = tmp_path / "qgc"
    assert main(["export", str(plan_file), "--format", "qgc", "-o", str(qgc)]) == 0
    assert sorted(p.name for p in qgc.iterdir()) == [
        "reach_avoid-d1.plan",
        "reach_avoid-d2.plan",
    ]
    capsys.readouterr()

    log = tmp_path / "log"
    rc = main(
        ["fly", str(plan_file), "--dry-run", "--profile", profile, "--log", str(log), "--json"]
    )
    out, err = capsys.readouterr()
    assert rc == 0, err
    res = json.loads(out)
    assert res["completed"] and not res["interrupted"] and res["safety_event"] is None
    assert res["final_modes"] == {"d1": "AUTO.LOITER", "d2": "AUTO.LOITER"}
    plan = load_plan(plan_file)
    assert res["planned_robustness"] == pytest.approx(plan.robustness, abs=1e-9)
    assert res["flown_robustness"] > 0
    # Every setpoint of the 6 s plan (20 Hz) plus the 1 s hold was due and sent.
    for s in res["stream"].values():
        assert s["failed"] == 0 and s["sent"] + s["skipped"] == 6 * 20 + 1 + 20
    # Progress went to stderr as plain lines (not a terminal), with the clause values.
    assert "d1 OFFBOARD" in err and " rho +" in err

    # Independent of the command's own tracks: the .tlog bytes through pymavlink.
    names = {1: "d1", 2: "d2"}
    tlog_tracks = tracks_from_tlog(log / "flight.tlog", names, plan.origin, res["t0_unix_s"])
    phi = plan_formula(plan)
    dt = plan.check_dt_s
    signals = {n: tr.resample(dt, plan.horizon_s) for n, tr in tlog_tracks.items()}
    assert phi.robustness(signals, dt) == pytest.approx(res["flown_robustness"], abs=0.02)
    kinds = set()
    reader = mavutil.mavlink_connection(str(log / "flight.tlog"), dialect="common")
    while (m := reader.recv_match()) is not None:
        kinds.add((m.get_srcSystem(), m.get_type()))
    assert {(1, "HEARTBEAT"), (2, "HEARTBEAT"), (1, "LOCAL_POSITION_NED")} <= kinds
    # The CSV holds the same flight, in the mission frame, close to the plan.
    csv_tracks = load_telemetry(log / "flight.csv").vehicles
    for v in plan.vehicles:
        tr = csv_tracks[v.name]
        inside = (tr.t_s >= 0) & (tr.t_s <= plan.horizon_s)
        err_m = np.linalg.norm(tr.pos_enu_m[inside] - v.trajectory.position(tr.t_s[inside]), axis=1)
        assert err_m.max() < 0.2, f"{v.name} strays {err_m.max():.3f} m from its plan"
    report = (log / "report.md").read_text(encoding="utf-8")
    assert "flown robustness" in report and "d1" in report
    # MAVSDK's own lines are in the flight directory, not on the terminal.
    assert res["files"]["mavsdk_log"] == str(log / "mavsdk.log")
    assert "INFO MAVSDK version" in (log / "mavsdk.log").read_text(encoding="utf-8")
    assert "MAVSDK" not in err and "Dropping" not in err


#: ``gcs fly`` whose .tlog recorder falls behind for its first 200 messages (2 s): MAVSDK's
#: callback queue fills and MAVSDK says "Dropping subscription callbacks", which the user of
#: the flight can do nothing about.
LAGGING_GCS = """
import itertools, sys, time
from gcs.cli import main
from mavlink.tlog import TlogRecorder
calls, record = itertools.count(), TlogRecorder._on_message
def lagging(self, msg, ud):
    if next(calls) < 200:
        time.sleep(0.01)
    record(self, msg, ud)
TlogRecorder._on_message = lagging
sys.exit(main(sys.argv[1:]))
"""


def test_a_mavsdk_callback_backlog_in_flight_is_logged_in_the_flight_directory_not_shown(
    plan_file: Path, tmp_path: Path
) -> None:
    # a child process: the terminal as the user has it, without pytest's log handlers
    log = tmp_path / "log"
    fly = ["fly", str(plan_file), "--dry-run", "--profile", "ideal", "--log", str(log)]
    proc = subprocess.run(
        [sys.executable, "-c", LAGGING_GCS, *fly],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "flight completed" in proc.stdout
    said = (log / "mavsdk.log").read_text(encoding="utf-8")
    assert "ERROR Dropping subscription callbacks" in said, said
    shown = proc.stdout + proc.stderr
    assert "Dropping" not in shown and "MAVSDK" not in shown


def test_reach_avoid_starts_too_low_for_px4_to_take_off_are_refused_before_arming(
    plan_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The reach-avoid plan starts 0.75 m up: PX4 counts a take-off within NAV_MC_ALT_RAD
    # (0.8 m) as reached on the ground, and its altitude estimate creeps up in ground
    # effect; PX4 SITL's vehicles stayed on the ground. Refused, one line, nothing armed.
    # (The check is PX4's own, on the vehicle's altitude estimate: here an EKF origin within
    # 0.2 m of the ground, so that no vehicle believes itself lower than 0.2 m.)
    origin = ["--mock-param", "MOCK_ORG_Z_MIN=0.0", "--mock-param", "MOCK_ORG_Z_MAX=0.2"]
    for mode in ("offboard", "mission"):
        capsys.readouterr()
        rc = main(["fly", str(plan_file), "--dry-run", "--mode", mode, "--force", *origin])
        _out, err = capsys.readouterr()
        assert rc == 1, err
        line = err.strip().splitlines()[-1]
        assert line.startswith("gcs fly: vehicle d") and "PX4 takes off only" in line, err
        assert "NAV_MC_ALT_RAD = 0.8 m" in line and "Traceback" not in err


def _edited(plan_file: Path, tmp_path: Path) -> Path:
    data = json.loads(plan_file.read_text(encoding="utf-8"))
    data["vehicles"][0]["limits"]["v_max_m_s"] = [0.2, 0.2, 0.2]  # the plan flies faster
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


def test_plan_that_fails_verification_is_refused_before_connecting(
    plan_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    edited = _edited(plan_file, tmp_path)
    assert main(["verify", str(edited)]) == 1
    capsys.readouterr()
    assert main(["fly", str(edited), "--dry-run"]) == 1
    out, err = capsys.readouterr()
    assert out == ""  # no mock started, nothing flown
    assert err.count("\n") == 1
    assert "refused: the plan fails verification: d1 velocity / v_max" in err
    assert "--force" in err

    # --force passes the interlock and goes on to connect (here: nobody answers -> exit 2).
    port = free_udp_ports(1)[0]
    url = f"udpin://127.0.0.1:{port}"
    args = ["fly", str(edited), "--force", "--timeout", "0.5"]
    rc = main([*args, "--connection", url, "--connection", f"udpin://127.0.0.1:{port + 1}"])
    out, err = capsys.readouterr()
    assert rc == 2 and "refused" not in err


def test_unreachable_connection_is_bad_input_in_one_line(
    plan_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    p1, p2 = free_udp_ports(2)
    url = f"udpin://127.0.0.1:{p1}"
    rc = main(
        [
            "fly",
            str(plan_file),
            "--timeout",
            "0.5",
            "--connection",
            url,
            "--connection",
            f"udpin://127.0.0.1:{p2}",
        ]
    )
    _, err = capsys.readouterr()
    assert rc == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"gcs fly: error: vehicle d1 ({url}): no heartbeat from system id 1")
    # A wrong number of URLs is bad input too, before anything is opened.
    assert main(["fly", str(plan_file), "--connection", url]) == 2
    _, err = capsys.readouterr()
    assert "1 URL(s) given for 2 vehicle(s)" in err


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("FOO=1", "--mock-param 'FOO=1': the mock vehicle has no parameter 'FOO'"),
        ("SIH_KDV=9", "--mock-param 'SIH_KDV=9': SIH_KDV must be in [0, 2]"),
        ("SIH_KDV", "--mock-param 'SIH_KDV': expected NAME=VALUE"),
        ("SIH_KDV=x", "--mock-param 'SIH_KDV=x': VALUE must be a number"),
    ],
)
def test_bad_mock_parameter_is_bad_input_in_one_line(
    plan_file: Path, capsys: pytest.CaptureFixture[str], item: str, message: str
) -> None:
    capsys.readouterr()
    assert main(["fly", str(plan_file), "--dry-run", "--mock-param", item]) == 2
    _, err = capsys.readouterr()
    assert err == f"gcs fly: error: {message}\n"


@pytest.mark.parametrize(
    ("argv", "env", "message"),
    [
        (["--speed", "3"], None, "--speed: only for --dry-run (real vehicles fly in real time)"),
        (
            ["--dry-run", "--speed", "50"],
            None,
            "--speed: must be in (0, 20] times real time, got 50",
        ),
        (["--dry-run", "--speed", "0"], None, "--speed: must be in (0, 20] times real time, got 0"),
        (["--dry-run"], "fast", "$STL_GCS_SIM_SPEED: 'fast' is not a number (times real time)"),
        (["--dry-run"], "-2", "$STL_GCS_SIM_SPEED: must be in (0, 20] times real time, got -2"),
    ],
)
def test_a_bad_dry_run_speed_is_bad_input_in_one_line(
    plan_file: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    argv: list[str],
    env: str | None,
    message: str,
) -> None:
    if env is not None:
        monkeypatch.setenv("STL_GCS_SIM_SPEED", env)
    capsys.readouterr()
    assert main(["fly", str(plan_file), *argv]) == 2
    _, err = capsys.readouterr()
    assert err == f"gcs fly: error: {message}\n"


def test_ctrl_c_commands_every_vehicle_to_hold_and_exits_cleanly(plan_file: Path) -> None:
    proc = subprocess.Popen(
        # the ideal vehicle: what is tested is the GCS's interrupt, on a flight under way
        [sys.executable, "-m", "gcs.cli", "fly", str(plan_file), "--dry-run", "--profile", "ideal"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        preexec_fn=interruptible,
    )
    assert proc.stdout is not None
    seen = []
    for line in proc.stdout:
        seen.append(line)
        if line.startswith("t ") and "OFFBOARD" in line:  # flying the plan
            proc.send_signal(signal.SIGINT)
            break
    rest, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, (seen, rest, err)
    assert "Traceback" not in err
    assert "interrupted: every vehicle was commanded to hold" in rest
    assert "modes now: d1 AUTO.LOITER, d2 AUTO.LOITER" in rest


LINK_PLAN = REPO / "tests" / "mavlink" / "data" / "reach_avoid_2.plan.json"


def test_mission_mode_on_px4_is_predicted_refused_and_with_force_flown_as_predicted(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # A 6 s reach-avoid plan (starts 1.5 m up) as PX4 missions: PX4's acceleration limits and
    # stops make the missions late, so the predicted robustness is below epsilon: refused.
    rc = main(["fly", str(LINK_PLAN), "--dry-run", "--mode", "mission"])
    out, err = capsys.readouterr()
    assert rc == 1 and "refused: PX4 is predicted to fly these missions with robustness" in err
    assert "Traceback" not in err and "mission" not in out.split("refused")[0].lower()
    # --force flies it: one shared start, tracks judged on that clock, against the prediction.
    rc = main(["fly", str(LINK_PLAN), "--dry-run", "--mode", "mission", "--force", "--json"])
    out, err = capsys.readouterr()
    res = json.loads(out)
    assert res["mode"] == "mission" and res["completed"], (
        err,
        {k: v for k, v in res.items() if k not in ("tracks",)},
    )
    pred = res["mission_prediction"]
    assert pred["acceptance_auto"] and pred["acceptance_m"] >= 0.6
    assert res["flown_robustness"] is not None and res["coverage_problem"] is None
    # The prediction is what PX4's navigator (here the px4 mock's) flies, on a quiet
    # estimator: the flown robustness is within 0.3 of it, plus what the estimate's own
    # error can move a robustness (a distance between two vehicles moves by both errors:
    # twice the largest (horizontal, vertical) position accuracy the vehicles reported).
    est = max(math.hypot(*acc) for acc in res["estimator_accuracy_m"].values())
    assert est > 0.2  # PX4's estimator, not the truth
    assert abs(res["flown_robustness"] - pred["predicted_robustness"]) < 0.3 + 2 * est, res
    assert rc == (0 if res["flown_robustness"] >= 0 else 1)
    plan = load_plan(LINK_PLAN)
    for pv in plan.vehicles:
        m = res["missions"][pv.name]
        assert m["finished"] and 0 <= m["late_s"] < 10.0  # PX4 is late, never early
        # With the estimator quiet the flight finishes as predicted (within 0.01 s); its
        # noise and biases move the arrivals inside the acceptance circles (+0.5..+0.7 s at
        # the default seed). The finish is the last item's reached report, which PX4 sends
        # when the mission ends, not MAVSDK's verdict, which waits up to 1 s more for PX4's
        # once-a-second MISSION_CURRENT.
        assert abs(m["late_s"] - pred["predicted_late_s"][pv.name]) < 1.5
        assert abs(m["start_skew_s"]) < 0.5  # one shared release
    assert all(t["samples"] > 100 for t in res["tracking"])


def test_mission_mode_flies_the_uploaded_missions_over_the_whole_horizon(
    plan_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The exact vehicle, whose 0.75 m starts fly (the prediction is PX4's, which would be
    # late on this 6 s plan: --force).
    argv = ["fly", str(plan_file), "--dry-run", "--profile", "ideal", "--mode", "mission"]
    rc = main([*argv, "--force", "--json"])
    out, err = capsys.readouterr()
    res = json.loads(out)
    assert res["mode"] == "mission" and res["completed"], (
        err,
        {k: v for k, v in res.items() if k not in ("tracks",)},
    )
    for m in res["missions"].values():
        assert m["finished"] and abs(m["start_skew_s"]) < 0.5
    # Plan time 0 is the shared release at the start waypoints; the recording covers the
    # horizon, so the flown data is judged.
    assert res["flown_robustness"] is not None and res["coverage_problem"] is None
    assert len(res["tracking"]) == 2 and all(t["samples"] > 100 for t in res["tracking"])
    assert rc == (0 if res["flown_robustness"] >= 0 else 1)


def test_evaluation_finds_the_delay_of_a_late_track_and_judges_it_exactly() -> None:
    from gcs.flight.evaluation import evaluate_flight
    from mavlink.tracks import FlownTrack

    plan = load_plan(
        Path(__file__).resolve().parents[1] / "mavlink" / "data" / "reach_avoid_2.plan.json"
    )
    delay_s, t = 0.3, np.arange(-0.5, plan.horizon_s + 0.5, 0.02)  # 50 Hz telemetry
    tracks = {}
    for v in plan.vehicles:
        pos = v.trajectory.position(np.clip(t - delay_s, 0.0, plan.horizon_s))
        tracks[v.name] = FlownTrack(v.name, t, pos, np.zeros_like(pos), pos.copy())
    ev = evaluate_flight(plan, tracks)
    for te in ev.tracking:
        assert te.lag_s == pytest.approx(delay_s, abs=0.011)
        assert te.rms_at_lag_m < 0.01 < te.rms_m
    # Reference: the spec on the delayed positions sampled directly on the check grid.
    dt = plan.check_dt_s
    grid = np.arange(round(plan.horizon_s / dt) + 1) * dt
    ref = {
        v.name: v.trajectory.position(np.clip(grid - delay_s, 0.0, plan.horizon_s))
        for v in plan.vehicles
    }
    assert ev.flown_robustness == pytest.approx(plan_formula(plan).robustness(ref, dt), abs=2e-4)
    assert ev.planned_robustness == pytest.approx(plan.robustness, abs=1e-9)


def test_a_vehicle_falling_behind_its_plan_is_warned_about_then_held(
    plan_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # PX4 limits offboard speed to MPC_XY_VEL_MAX: at 0.3 m/s the vehicles fall behind a
    # 0.75 m/s plan. Past the plan's margin each is warned about once; past --max-off-plan
    # every vehicle is held and the flight is reported as stopped, exit 1.
    plan = load_plan(plan_file)
    capsys.readouterr()
    argv = ["fly", str(plan_file), "--dry-run", "--profile", "ideal", "--max-off-plan", "0.6",
            "--mock-param", "MPC_XY_VEL_MAX=0.3"]  # fmt: skip
    rc = main(argv)
    out, err = capsys.readouterr()
    assert rc == 1, out + err
    warned = [ln for ln in out.splitlines() if ln.startswith("warning: d")]
    assert warned and all(f"the plan's margin {plan.robustness:.2f} m" in ln for ln in warned)
    assert len({ln.split()[1] for ln in warned}) == len(warned)  # once per vehicle
    stop = next(ln for ln in out.splitlines() if ln.startswith("safety stop:"))
    assert "off its plan" in stop and "more than the bound 0.6 m" in stop
    assert "commanded hold to all vehicles" in stop
    assert "(WARNING: more than the plan's margin" in out
    # the bound can be switched off: the same flight then runs to its end
    capsys.readouterr()
    assert main([*argv[:6], "0", *argv[7:], "--json"]) == 1  # flown, but the spec fails
    res = json.loads(capsys.readouterr().out)
    assert res["safety_event"] is None
    assert max(res["monitor"]["off_plan_max_m"].values()) > 0.6


@pytest.fixture(scope="module")
def face_plan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A plan whose spec asks d1 to face pole1 while it hovers in insp1 (``gcs plan``)."""
    from tests.gcs.face_plan import write_face_plan

    return write_face_plan(tmp_path_factory.mktemp("face"))


def _aim_error_deg(plan, track, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """Where the track is inside insp1, and its heading's angle off the bearing to pole1's
    axis (independently of the planner's ``face``: the geometry from the regions)."""
    p, yaw = track.position(t), track.yaw(t)
    c = plan.region("pole1").center_enu_m
    bearing = np.arctan2(c[1] - p[:, 1], c[0] - p[:, 0])
    return plan.region("insp1").contains(p), np.degrees(np.abs(np.angle(np.exp(1j * (yaw - bearing)))))  # fmt: skip


def _check_pictures(plan, log: Path, res: dict, capsys, *, offboard: bool) -> None:  # type: ignore[no-untyped-def]
    """The flight pictured pole1 as planned: every picture in a capture span (offboard: on
    the plan's clock; a mission: while the vehicle held in insp1), from where the track was,
    looking where the vehicle headed with the gimbal's pitch; gcs verify --images agrees."""
    from gcs.flight.payload import capture_spans

    (span,) = capture_spans(plan)["d1"]
    cov = res["coverage"]
    assert cov["covered"] == 1 and cov["targets"] == 1
    (row,) = cov["by_target"]
    (images,) = load_images(log / "images.csv").values()
    assert row["images"] == len(images) == res["images"]["d1"] >= 3
    if offboard:
        assert len(images) == row["planned"]
    else:  # the STOP item ends it when the mission's clock (PX4's legs) has got there
        assert row["planned"] - 1 <= len(images) <= row["planned"]
    track = load_telemetry(log / "flight.csv").vehicles["d1"]
    t = np.array([im.t_s for im in images])
    assert np.all(np.diff(t) > 0) and [im.index for im in images] == list(range(len(images)))
    if offboard:  # sent on the plan's clock: the first at once, then one per interval
        assert t[0] == pytest.approx(span.t_start_s, abs=0.3)
        np.testing.assert_allclose(np.diff(t), span.interval_s, atol=0.15)
        assert t[-1] <= span.t_end_s + 0.3
    inside = plan.region("insp1").margin(track.position(t)) > -0.1
    assert inside.all(), t[~inside]
    for im, at in zip(images, track.position(t), strict=True):
        np.testing.assert_allclose(im.position_enu_m(plan.origin), at, atol=0.35)
        heading, pitch = im.yaw_pitch_deg()  # compass, from the camera's attitude
        flown = 90.0 - np.degrees(track.yaw(np.array([im.t_s]))[0])
        assert abs((heading - flown + 180.0) % 360.0 - 180.0) < 3.0
        assert pitch == pytest.approx(span.gimbal_pitch_deg, abs=1.0)
    assert main(["verify", str(log.parent / "none"), "--images", str(log / "images.csv")]) == 2
    capsys.readouterr()


def test_a_face_spec_flown_offboard_is_judged_on_the_recorded_heading(
    face_plan: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from tests.gcs.face_plan import FACE_CLAUSE

    plan = load_plan(face_plan)
    log = tmp_path / "log"
    capsys.readouterr()
    rc = main(["fly", str(face_plan), "--dry-run", "--profile", "ideal", "--log", str(log),
               "--json"])  # fmt: skip
    out, err = capsys.readouterr()
    assert rc == 0, err
    res = json.loads(out)
    assert res["completed"] and res["coverage_problem"] is None
    (face,) = [c for c in res["clauses"] if c["text"] == FACE_CLAUSE]
    assert face["flown"] > 0 and res["flown_robustness"] > 0
    # The flight's CSV carries the heading of every sample (ATTITUDE.yaw, mission frame)
    track = load_telemetry(log / "flight.csv").vehicles["d1"]
    assert track.has_heading and track.heading_t_s.size == track.t_s.size
    t = np.arange(0.0, plan.horizon_s, 0.05)
    inside, aim = _aim_error_deg(plan, track, t)
    assert inside.sum() >= 40  # the 2 s hover
    assert aim[inside].max() < 15.0  # facing the pole while it inspected it
    # the vehicle turned with its plan's yaw schedule (the mock's own heading, not the plan's)
    plan_yaw = plan.vehicles[0].trajectory.yaw_rad(t)
    off = np.degrees(np.abs(np.angle(np.exp(1j * (track.yaw(t) - plan_yaw)))))
    assert off.max() < 15.0 and off.max() > 0.1
    # face's value on the flown samples, from the recorded heading, is the clause's
    from planner.spec.predicates import face_margin

    margin = face_margin(track.signal(t, heading=True), plan.region("pole1"))
    assert margin[inside].min() > 0.0

    # The .tlog alone rebuilds the same heading (ATTITUDE) and verify judges it
    tl = tracks_from_tlog(log / "flight.tlog", {1: "d1"}, plan.origin, res["t0_unix_s"])["d1"]
    same = np.degrees(np.abs(np.angle(np.exp(1j * (tl.yaw(t) - track.yaw(t))))))
    assert same.max() < 1.0
    argv = ["verify", str(face_plan), "--telemetry", str(log / "flight.tlog"), "--t0",
            repr(res["t0_unix_s"]), "--json"]  # fmt: skip
    assert main(argv) == 0
    checks = {c["name"]: c for c in json.loads(capsys.readouterr().out)["checks"]}
    assert checks[f"flown spec: {FACE_CLAUSE}"]["value"] == pytest.approx(face["flown"], abs=0.05)

    # The same CSV without its heading column (an older file): verify says what is missing
    rows = (log / "flight.csv").read_text(encoding="utf-8").splitlines()
    old = tmp_path / "old.csv"
    old.write_text("\n".join(r.rsplit(",", 1)[0] for r in rows) + "\n", encoding="utf-8")
    assert main(["verify", str(face_plan), "--telemetry", str(old)]) == 1
    out, err = capsys.readouterr()
    assert "FAIL flown d1 heading: 0 (bound 1) the telemetry has no heading" in out
    assert "Traceback" not in out + err

    # The camera pictured the pole as planned, and the image log says so to gcs verify
    _check_pictures(plan, log, res, capsys, offboard=True)
    assert main(["verify", str(face_plan), "--images", str(log / "images.csv"), "--json"]) == 0
    checks = {c["name"]: c for c in json.loads(capsys.readouterr().out)["checks"]}
    assert checks["pictures of pole1"]["ok"]


def test_a_face_spec_flown_as_a_mission_faces_the_pole_on_the_waypoints_yaw(
    face_plan: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The mission carries the plan's heading in its waypoints' yaw (param4), which PX4 (and
    # the mock) flies from the moment each waypoint is current.
    from tests.gcs.face_plan import FACE_CLAUSE

    plan = load_plan(face_plan)
    log = tmp_path / "log"
    capsys.readouterr()
    argv = ["fly", str(face_plan), "--dry-run", "--profile", "ideal", "--mode", "mission",
            "--force", "--log", str(log), "--json"]  # fmt: skip
    rc = main(argv)
    out, err = capsys.readouterr()
    res = json.loads(out)
    assert res["completed"], err
    (face,) = [c for c in res["clauses"] if c["text"] == FACE_CLAUSE]
    assert face["flown"] is not None and rc == (0 if res["flown_robustness"] >= 0 else 1)
    track = load_telemetry(log / "flight.csv").vehicles["d1"]
    assert track.has_heading
    inside, aim = _aim_error_deg(plan, track, np.arange(0.0, plan.horizon_s, 0.05))
    assert inside.sum() >= 10 and aim[inside].max() < 15.0
    # the mission's camera items took the pictures during the hover
    _check_pictures(plan, log, res, capsys, offboard=False)
