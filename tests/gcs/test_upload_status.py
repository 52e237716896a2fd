"""``gcs upload`` and ``gcs status`` against mock PX4 vehicles over loopback UDP.

The references are on the vehicle side: what the mock vehicles stored from the mission
protocol (not what MAVSDK read back), their true state and their configured spawn points.
"""

from __future__ import annotations

import contextlib
import json
import math
import re
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pymap3d
import pytest

from gcs.cli import main
from gcs.flight.dryrun import free_udp_ports, sim_speed
from gcs.flight.missions import fence_plan
from mavlink.mission import trajectory_to_mission
from mavlink.mock import MockFleet, Px4Mode
from planner.frames import enu_to_geodetic
from planner.planfile import load_plan

pytestmark = pytest.mark.slow  # flights or transfers over UDP (make test-fast skips)

DATA = Path(__file__).resolve().parents[1] / "mavlink" / "data"
PLAN = DATA / "reach_avoid_2.plan.json"


@contextlib.contextmanager
def _running_mock(
    profile: str = "px4", params: dict[str, float] | None = None
) -> Iterator[tuple[MockFleet, list[str]]]:
    """Two mock vehicles on the ground below the stored plan's starts, and their URLs."""
    plan = load_plan(PLAN)
    ports = free_udp_ports(4)
    fleet = MockFleet(
        speed=sim_speed(),
        n=2,
        origin=plan.origin,
        spawns_enu_m=plan.ground_spawns(),
        gcs_ports=ports[:2],
        vehicle_ports=ports[2:],
        profile=profile,
        params=params,
    )
    with fleet.running_in_thread():
        yield fleet, [f"udpin://127.0.0.1:{p}" for p in ports[:2]]


@pytest.fixture
def mock(request: pytest.FixtureRequest) -> Iterator[tuple[MockFleet, list[str]]]:
    """:func:`_running_mock`: the px4 profile unless a test says
    ``@pytest.mark.parametrize("mock", ["ideal"], indirect=True)``.
    """
    with _running_mock(getattr(request, "param", "px4")) as running:
        yield running


def _connections(urls: list[str]) -> list[str]:
    return [arg for url in urls for arg in ("--connection", url)]


def _wire(items) -> list[tuple]:  # type: ignore[no-untyped-def]
    """Items as MISSION_ITEM_INT carries them (float32 params and altitude)."""
    f32 = np.float32
    return [
        (
            i.seq,
            i.frame,
            i.command,
            i.autocontinue,
            f32(i.param1).tobytes(),
            f32(i.param2).tobytes(),
            f32(i.param3).tobytes(),
            f32(i.param4).tobytes(),
            i.x,
            i.y,
            f32(i.z).tobytes(),
            i.mission_type,
        )
        for i in items
    ]


@pytest.mark.parametrize("mock", ["ideal", "px4"], indirect=True)
def test_upload_stores_the_mission_and_fence_on_each_vehicle_and_starts_them(
    mock: tuple[MockFleet, list[str]], capsys: pytest.CaptureFixture[str]
) -> None:
    fleet, urls = mock
    plan = load_plan(PLAN)
    # This 6 s plan's missions are predicted late on PX4 (its acceleration limits and stops):
    # the start is refused before anything is sent.
    rc = main(["upload", str(PLAN), "--fence", "--start", *_connections(urls)])
    _out, err = capsys.readouterr()
    assert rc == 1 and "refused to start: PX4 is predicted to fly these missions" in err, err
    assert all(not v.mission_items(0) and not v.mission_items(1) for v in fleet.vehicles)
    argv = ["upload", str(PLAN), "--fence", "--fence-action", "land", "--start", "--force"]
    rc = main([*argv, "--json", *_connections(urls)])
    out, err = capsys.readouterr()
    assert rc == 0, err
    res = json.loads(out)
    assert res["ok"] and [r["vehicle"] for r in res["vehicles"]] == ["d1", "d2"]
    assert res["acceptance_auto"] and res["acceptance_m"] >= 0.6
    fence = fence_plan(plan).items  # the workspace moved out by PX4's braking distance
    assert res["fence_inflate_m"] > 2.0 and any("obstacle" in n for n in res["fence_notes"])
    for i, pv in enumerate(plan.vehicles):
        mission = trajectory_to_mission(
            pv.trajectory, plan.origin, name=pv.name, acceptance_radius_m=res["acceptance_m"]
        )
        row = res["vehicles"][i]
        assert row["verified"] and row["started"]
        # Attempts and time per vehicle; the progress of each went to standard error.
        assert row["mission_attempts"] >= 1 and row["fence_attempts"] >= 1
        assert row["transfer_s"] > 0
        assert f"gcs upload: {pv.name}: mission attempt 1: uploading" in err
        assert f"gcs upload: {pv.name}: fence attempt" in err
        assert f"{len(mission.items)} items read back as sent" in err
        assert row["mission_items"] == len(mission.items) and row["fence_items"] == len(fence)
        stored = fleet.vehicles[i].mission_items(0)
        # The conversion's items and positions; its radii and leg speeds are its own timing.
        f32 = np.float32
        assert [(s.command, s.x, s.y, f32(s.z), f32(s.param1)) for s in stored] == [
            (m.command, m.x, m.y, f32(m.z), f32(m.param1)) for m in mission.items
        ]
        radii = [s.param2 for s in stored if s.command == 16]
        assert min(radii) >= f32(res["acceptance_m"]) - 1e-6
        speeds = [s.param2 for s in stored if s.command == 178]
        assert all(
            0 < a <= 2 * b + 1e-5 for a, b in zip(speeds, mission.leg_speed_m_s, strict=True)
        )
        assert _wire(fleet.vehicles[i].mission_items(1)) == _wire(fence)
        # The mission path stays close to the plan: straight legs between its waypoints.
        assert 0 < row["max_deviation_m"] < 0.5
        state = fleet.vehicles[i].state
        assert state.armed and state.mode is Px4Mode.AUTO_MISSION
        assert fleet.vehicles[i].params["GF_ACTION"] == 5  # land, read back from the vehicle
        # Released as gcs fly --mode mission releases: taken off and brought onto the start
        # first, then into the mission at its start waypoint (its take-off item skipped)
        assert state.mission_seq >= 1 and not state.landed
    # ... all at one instant, the plan's t = 0, reported to align what they fly with the plan
    assert res["t0_unix_s"] is not None and abs(res["t0_unix_s"] - time.time()) < 60.0
    assert all(r["start_detail"] == "AUTO.MISSION" for r in res["vehicles"])
    # Along the straight legs on time the spec would hold; PX4 cannot fly them on time.
    assert 0 < res["mission_path_robustness"] <= plan.robustness + 0.05
    assert res["predicted_mission_robustness"] < plan.epsilon


def test_upload_start_refuses_a_start_too_low_for_px4_to_take_off_to(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # The plan starts 1.5 m above the ground; with NAV_MC_ALT_RAD 2 m PX4 would treat the
    # mission's take-off as reached on the ground and auto-disarm: refused before arming.
    with _running_mock(params={"NAV_MC_ALT_RAD": 2.0}) as (fleet, urls):
        rc = main(["upload", str(PLAN), "--start", *_connections(urls)])
        _out, err = capsys.readouterr()
        assert rc == 1
        assert "above the vehicle; PX4 takes off only" in err and "NAV_MC_ALT_RAD = 2 m" in err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
        assert not any(v.state.armed for v in fleet.vehicles)


def test_status_shows_each_vehicle_as_it_is(
    mock: tuple[MockFleet, list[str]], capsys: pytest.CaptureFixture[str]
) -> None:
    fleet, urls = mock
    plan = load_plan(PLAN)
    # What each vehicle believes, polled while the command runs: its estimate drifts (a
    # slowly varying bias), and on a loaded machine the command's reading and a reading
    # after it were 0.11 m apart; the status must report a value the estimate took.
    believed: list[list[tuple[float, float, float]]] = [[] for _ in fleet.vehicles]
    done = threading.Event()

    def watch() -> None:
        while not done.is_set():
            for i, v in enumerate(fleet.vehicles):
                believed[i].append(tuple(v.ned_to_global(np.array(v.state.est_pos_ned_m))))
            time.sleep(0.005)

    watcher = threading.Thread(target=watch)
    watcher.start()
    try:
        assert main(["status", "--json", *_connections(urls)]) == 0
    finally:
        done.set()
        watcher.join()
    rows = json.loads(capsys.readouterr().out)["vehicles"]
    lat, lon, alt = enu_to_geodetic(np.array(plan.ground_spawns()), plan.origin)
    for i, r in enumerate(rows):
        assert r["sysid"] == i + 1 and r["url"] == urls[i]
        assert (r["autopilot"], r["type"]) == ("PX4", "QUADROTOR")
        assert fleet.vehicles[i].state.mode is Px4Mode.AUTO_LOITER
        assert r["mode"] == "AUTO.LOITER"
        assert r["armed"] is False and r["in_air"] is False
        # What the vehicle believes (its EKF estimate, telemetry noise ~1 cm), which on PX4
        # is off its true spawn point by the EKF origin's error: 0.2-0.4 m horizontally,
        # 0.1-0.6 m vertically, plus a slowly varying bias.
        est = np.array(believed[i])  # lat, lon, alt the estimate took during the command
        slack = np.array([1e-6, 1e-6, 0.1])  # telemetry's rounding and noise
        lo, hi = est.min(axis=0) - slack, est.max(axis=0) + slack
        got = np.array([r["lat_deg"], r["lon_deg"], r["alt_amsl_m"]])
        assert np.all((lo <= got) & (got <= hi)), (got, lo, hi)
        n, e, d = pymap3d.geodetic2ned(
            r["lat_deg"], r["lon_deg"], r["alt_amsl_m"], lat[i], lon[i], alt[i]
        )
        assert 0.05 < math.hypot(n, e) < 0.7 and abs(d) < 1.0
        assert 0.9 <= r["battery_remaining"] <= 1.0 and r["battery_voltage_v"] > 10

    assert main(["status", *_connections(urls)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3 and lines[0].split()[:3] == ["sysid", "url", "autopilot"]
    assert lines[1].split()[:5] == ["1", urls[0], "PX4", "QUADROTOR", "AUTO.LOITER"]


def test_status_of_a_connection_that_never_answers_names_it(
    capsys: pytest.CaptureFixture[str],
) -> None:
    url = f"udpin://127.0.0.1:{free_udp_ports(1)[0]}"
    assert main(["status", "--connection", url, "--timeout", "0.5"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert url in err and "no heartbeat from system id 1 within 0.5 s" in err
    assert main(["status", "--connection", "udp://nowhere"]) == 2
    assert "bad connection URL 'udp://nowhere'" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["-5", "0", "abc", "nan", "inf"])
def test_upload_timeout_must_be_a_positive_number_of_seconds(
    value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    # Checked before anything is read or connected: one line, exit 2, no traceback.
    assert main(["upload", str(PLAN), f"--timeout={value}"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"--timeout: must be a number of seconds > 0, got '{value}'" in err


def _edited_plan(tmp_path: Path, **changes: object) -> Path:
    data = json.loads(PLAN.read_text(encoding="utf-8"))
    data.update(changes)
    out = tmp_path / "edited.plan.json"
    out.write_text(json.dumps(data), encoding="utf-8")
    return out


def test_upload_refuses_a_plan_that_fails_verification_and_sends_nothing(
    mock: tuple[MockFleet, list[str]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fleet, urls = mock
    data = json.loads(PLAN.read_text(encoding="utf-8"))
    data["vehicles"][0]["limits"]["v_max_m_s"] = [0.2, 0.2, 0.2]  # the plan flies faster
    bad = tmp_path / "fast.plan.json"
    bad.write_text(json.dumps(data), encoding="utf-8")
    assert main(["upload", str(bad), "--start", *_connections(urls)]) == 1
    err = capsys.readouterr().err
    assert "refused: the plan fails verification: d1 velocity / v_max" in err
    assert all(not v.mission_items(0) and not v.state.armed for v in fleet.vehicles)


def test_upload_start_refuses_a_mission_predicted_below_epsilon_unless_forced(
    mock: tuple[MockFleet, list[str]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The plan meets epsilon 0.51 (+0.538); PX4 is predicted to fly its missions late, far
    # below it (and even on time the straight legs would miss it: +0.484).
    fleet, urls = mock
    edited = _edited_plan(tmp_path, epsilon=0.51)
    assert main(["upload", str(edited), "--start", *_connections(urls)]) == 1
    err = capsys.readouterr().err
    assert "refused to start: PX4 is predicted to fly these missions with robustness" in err
    assert "< epsilon 0.51" in err and "straight legs +0.4844" in err
    # what fails on the prediction, and the timing (late, or on time: then the path is why)
    assert re.search(r"weakest: .+ [+-]\d\.\d{3}; (up to \d+\.\d s late|on time)", err), err
    assert all(not v.mission_items(0) and not v.state.armed for v in fleet.vehicles)
    # Without --start the upload is only stored (nothing moves); --force starts it anyway.
    assert main(["upload", str(edited), *_connections(urls)]) == 0
    assert main(["upload", str(edited), "--start", "--force", *_connections(urls)]) == 0
    assert all(v.state.armed for v in fleet.vehicles)


def _free_run_of_ports(n: int) -> int:
    """A base port with ``n`` consecutive free UDP ports (clear of PX4 SITL's 14540-14599)."""
    import random
    import socket

    rng = random.Random()
    for _ in range(200):
        base = rng.randrange(20000, 60000)
        socks = []
        try:
            for i in range(n):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind(("0.0.0.0", base + i))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise RuntimeError("no run of free ports")


def test_status_finds_vehicles_on_other_ports_by_base_port(
    capsys: pytest.CaptureFixture[str],
) -> None:
    base = _free_run_of_ports(2)
    with MockFleet(
        speed=sim_speed(), n=2, gcs_ports=[base, base + 1], vehicle_ports=free_udp_ports(2)
    ).running_in_thread():
        assert main(["status", "--base-port", str(base), "--vehicles", "2", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["vehicles"]
    assert [(r["sysid"], r["url"]) for r in rows] == [
        (1, f"udpin://0.0.0.0:{base}"),
        (2, f"udpin://0.0.0.0:{base + 1}"),
    ]
    # a port another program holds: one line naming it and the way out, exit 2
    import socket

    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.bind(("0.0.0.0", base))
    try:
        assert main(["status", "--base-port", str(base), "--vehicles", "1"]) == 2
    finally:
        holder.close()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"port {base} cannot be opened" in err and "--base-port" in err
