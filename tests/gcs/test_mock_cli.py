"""``gcs mock``: options, errors, real vehicles on the requested ports, clean Ctrl-C."""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pymap3d
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from gcs.cli import main
from mavlink.mock.testing import free_udp_port
from tests.procutil import interruptible

REPO = Path(__file__).resolve().parents[2]


def bound_block(n: int) -> tuple[int, list[socket.socket]]:
    """``n`` consecutive UDP ports bound on loopback (the GCS side), and their sockets."""
    for _ in range(50):
        base = free_udp_port()
        socks: list[socket.socket] = []
        try:
            for i in range(n):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind(("127.0.0.1", base + i))
        except OSError:
            for s in socks:
                s.close()
            continue
        return base, socks
    raise RuntimeError("no block of free UDP ports")


def free_block(n: int) -> int:
    base, socks = bound_block(n)
    for s in socks:
        s.close()
    return base


def first_heartbeat(
    sock: socket.socket, timeout_s: float = 5.0
) -> mavlink2.MAVLink_heartbeat_message:
    mav = mavlink2.MAVLink(None)
    sock.settimeout(timeout_s)
    while True:
        data, _ = sock.recvfrom(65535)
        for msg in mav.parse_buffer(data) or []:
            if msg.get_type() == "HEARTBEAT":
                return msg


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--origin", "1,2"], "--origin"),
        (["--origin", "95,8,400"], "lat_deg"),
        (["-n", "2", "--spawn", "0,0,0"], "--spawn"),
        (["--spawn", "0,x,0"], "--spawn"),
        (["--loss-in", "1.5"], "loss_to_vehicle"),
        (["--param", "NOT_A_PARAM=1"], "NOT_A_PARAM"),
        (["--param", "MPC_XY_VEL_MAX"], "NAME=VALUE"),
        (["--fault-vehicles", "3", "--loss-in", "0.1"], "--fault-vehicles"),
        (["--outage", "5"], "START:END"),
        (["--scenario", "does/not/exist.yaml"], "exist.yaml"),
    ],
)
def test_bad_options_are_one_line_errors_with_status_2(argv, needle, capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["mock", *argv, "--duration", "0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gcs mock: error:") and needle in err and "\n" not in err


def test_options_reach_the_fleet() -> None:
    from gcs.cli import build_parser
    from gcs.commands.mock import build_fleet

    args = build_parser().parse_args(
        ["mock", "-n", "3", "--wind", "3,-1", "--gust", "0.5", "--param", "MPC_XY_VEL_MAX=4",
         "--loss-in", "0.1", "--latency-ms", "20", "--outage", "5:7", "--fault-vehicles", "0,2",
         "--seed", "9"]
    )  # fmt: skip
    fleet = build_fleet(args)
    assert (
        fleet.physics.wind.mean_ne_m_s == (3.0, -1.0) and fleet.physics.wind.gust_sigma_m_s == 0.5
    )
    assert [v.params["MPC_XY_VEL_MAX"] for v in fleet.vehicles] == [4.0] * 3
    faults = [v.config.faults for v in fleet.vehicles]
    assert faults[1].is_clean and not faults[0].is_clean and faults[0] == faults[2]
    assert faults[0].loss_to_vehicle == 0.1 and faults[0].latency_s == pytest.approx(0.02)
    assert faults[0].in_outage(6.0) and not faults[0].in_outage(7.0)
    assert fleet.gcs_ports == [14540, 14541, 14542] and fleet.vehicle_ports == [14580, 14581, 14582]
    assert fleet.seed == 9


def test_port_in_use_is_a_user_error(capsys) -> None:  # type: ignore[no-untyped-def]
    vbase, socks = bound_block(1)
    try:
        rc = main(["mock", "--vehicle-base-port", str(vbase), "--base-port", str(free_block(1)), "--duration", "0.1"])  # fmt: skip
    finally:
        for s in socks:
            s.close()
    assert rc == 2
    assert f"127.0.0.1:{vbase}" in capsys.readouterr().err


@pytest.mark.slow
def test_vehicles_run_on_px4_style_ports_with_spawns(capsys) -> None:  # type: ignore[no-untyped-def]
    gbase, gcs = bound_block(2)
    vbase = free_block(2)
    argv = ["mock", "-n", "2", "--base-port", str(gbase), "--vehicle-base-port", str(vbase)]
    argv += ["--spawn", "0,0,0", "--spawn", "5,-3,0", "--origin", "46.5,7.25,600", "--json"]
    argv += ["--duration", "1.5", "--loss-out", "0.2", "--fault-vehicles", "1", "--seed", "3"]
    argv += ["--wind", "3,-1", "--gust", "0.5", "--param", "MPC_XY_VEL_MAX=4"]
    result: dict[str, int] = {}
    runner = threading.Thread(target=lambda: result.setdefault("rc", main(argv)))
    runner.start()
    try:
        beats = [first_heartbeat(s) for s in gcs]
    finally:
        runner.join()
        for s in gcs:
            s.close()
    assert result["rc"] == 0
    assert [b.get_srcSystem() for b in beats] == [1, 2]
    assert all(b.autopilot == mavlink2.MAV_AUTOPILOT_PX4 for b in beats)
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    table, summary = lines[0]["vehicles"], lines[1]["summary"]
    assert [r["listen"] for r in table] == [f"127.0.0.1:{vbase}", f"127.0.0.1:{vbase + 1}"]
    assert [r["gcs"] for r in table] == [f"127.0.0.1:{gbase}", f"127.0.0.1:{gbase + 1}"]
    assert table[1]["spawn_enu_m"] == [5.0, -3.0, 0.0]
    assert table[0]["spawn"] == pytest.approx({"lat": 46.5, "lon": 7.25, "alt": 600.0}, abs=1e-6)
    assert table[1]["spawn"]["lon"] > 7.25 and table[1]["spawn"]["lat"] < 46.5
    # the px4 profile: each EKF origin is a noisy first fix, 0.2-0.4 m beside and 0.1-0.6 m
    # below the spawn
    for row in table:
        n, e, d = pymap3d.geodetic2ned(*row["origin"].values(), *row["spawn"].values())
        assert 0.2 - 1e-6 <= math.hypot(n, e) <= 0.4 + 1e-6 and 0.1 - 1e-6 <= d <= 0.6 + 1e-6
    assert summary["sim_time_s"] >= 1.0


SCENARIO = """\
name: mock_cli_test
origin: {lat: 46.9, lon: 7.4, alt: 540.0}
workspace: {min: [-10, -10, 0], max: [10, 10, 5]}
regions:
  goal: {kind: goal, center: [5, 5, 2], half_size: 0.5}
limits: {v_max_m_s: 2.0, a_max_m_s2: 2.0}
vehicles:
  - {name: d1, start: [0, 0, 0]}
  - {name: d2, start: [3, -2, 1]}
timing: {horizon_s: 6, segment_s: 1, Ts_s: 0.1}
separation_m: 0.5
epsilon: 0.01
spec:
  - each: d in all
    formula: eventually[0, $horizon] inside(d, goal)
"""


def test_scenario_gives_origin_and_starts(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    import pymap3d

    path = tmp_path / "scenario.yaml"
    path.write_text(SCENARIO, encoding="utf-8")
    gbase, vbase = free_block(2), free_block(2)
    argv = ["mock", "--scenario", str(path), "--base-port", str(gbase)]
    argv += ["--vehicle-base-port", str(vbase), "--duration", "0.2", "--json"]
    assert main(argv) == 0
    table = json.loads(capsys.readouterr().out.splitlines()[0])["vehicles"]
    assert [r["spawn_enu_m"] for r in table] == [[0.0, 0.0, 0.0], [3.0, -2.0, 1.0]]
    for row in table:
        lat, lon, alt = pymap3d.enu2geodetic(*row["spawn_enu_m"], 46.9, 7.4, 540.0)
        assert row["spawn"] == pytest.approx({"lat": lat, "lon": lon, "alt": alt}, abs=1e-6)
    # --profile ideal: the EKF origin exactly at the spawn (px4 scatters it per boot)
    assert main([*argv, "--profile", "ideal"]) == 0
    table = json.loads(capsys.readouterr().out.splitlines()[0])["vehicles"]
    for row in table:
        assert row["origin"] == pytest.approx(row["spawn"], abs=1e-9)
    # --ground-spawn puts the airborne start on the ground below it
    assert main([*argv, "--ground-spawn"]) == 0
    table = json.loads(capsys.readouterr().out.splitlines()[0])["vehicles"]
    assert table[1]["spawn_enu_m"] == [3.0, -2.0, 0.0]


def test_ctrl_c_stops_cleanly() -> None:
    gbase, vbase = free_block(1), free_block(1)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "gcs.cli",
            "mock",
            "--base-port",
            str(gbase),
            "--vehicle-base-port",
            str(vbase),
        ],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=interruptible,
    )
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if "Ctrl-C to stop" in line:
                break
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert "stopped after" in out and "Traceback" not in err


def test_ground_spawn_stands_on_a_scenarios_terrain(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    from planner.scenario import load_scenario
    from tests.terrain_support import ridge_scenario

    scenario = ridge_scenario(tmp_path)  # d1 starts 4 m above the ridge's foot at z = -2
    gbase, vbase = free_block(1), free_block(1)
    argv = ["mock", "--scenario", str(scenario), "--base-port", str(gbase)]
    argv += ["--vehicle-base-port", str(vbase), "--duration", "0.2", "--json", "--ground-spawn"]
    assert main(argv) == 0
    table = json.loads(capsys.readouterr().out.splitlines()[0])["vehicles"]
    terrain = load_scenario(scenario).terrain
    assert terrain is not None
    ground = float(terrain.ground([0.0, 0.0])[0])
    assert table[0]["spawn_enu_m"] == pytest.approx([0.0, 0.0, ground], abs=1e-9)
    assert ground == pytest.approx(-2.0, abs=0.01)
