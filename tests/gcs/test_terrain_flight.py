"""A plan over a ridge flown on the mock (``gcs fly --dry-run``): the vehicle stands and takes
off on the elevation model's ground, crosses the ridge above ``min_agl_m`` in its flown
telemetry, and the exports put home on that ground."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gcs.assess import evaluate_batch
from gcs.cli import main
from mavlink.mock.sim.batch import prepare, run_seed, simulate
from mavlink.mock.sim.disturbances import parse_disturbances
from mavlink.tlog import tracks_from_tlog
from planner.optimize import plan
from planner.planfile import load_plan, save_plan
from planner.scenario import load_scenario
from tests.terrain_support import ridge_scenario, utm_raster


@pytest.mark.slow
def test_a_plan_over_a_ridge_flies_above_the_ground_from_a_take_off_on_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scenario = ridge_scenario(tmp_path)
    plan_path = tmp_path / "ridge.plan.json"
    assert main(["plan", str(scenario), "-o", str(plan_path), "--json"]) == 0
    plan = load_plan(plan_path)
    terrain = plan.terrain
    assert terrain is not None
    capsys.readouterr()

    log = tmp_path / "log"
    rc = main(["fly", str(plan_path), "--dry-run", "--log", str(log), "--json"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    res = json.loads(out)
    assert res["completed"] and res["safety_event"] is None
    assert res["flown_robustness"] > 0  # the spec, floor included, held in flight

    # from the .tlog (everything the vehicle said, from before its take-off)
    track = tracks_from_tlog(log / "flight.tlog", {1: "d1"}, plan.origin, res["t0_unix_s"])["d1"]
    agl = track.pos_enu_m[:, 2] - terrain.ground(track.pos_enu_m[:, :2])
    first = track.t_s < track.t_s[0] + 0.5  # standing, before the take-off
    # on the ridge's foot (z = -2), not at z = 0, within the px4 estimate's error on the ground
    assert np.all(np.abs(agl[first]) < 0.6)
    assert np.all(np.abs(track.pos_enu_m[first, 2] + 2.0) < 0.6)
    flown = (track.t_s >= 0.0) & (track.t_s <= plan.horizon_s)
    assert agl[flown].min() >= 3.0 - 0.1  # min_agl_m, within the px4 vehicle's tracking
    assert track.pos_enu_m[flown, 2].max() > 12.0 - 2.0 + 3.0  # over the crest

    # the QGC export and the SITL homes stand on the same ground
    qgc = tmp_path / "qgc"
    assert main(["export", str(plan_path), "--format", "qgc", "-o", str(qgc)]) == 0
    home = json.loads(next(qgc.iterdir()).read_text())["mission"]["plannedHomePosition"]
    ground_amsl = plan.origin.alt_m + float(terrain.ground(plan.vehicles[0].start_enu_m[:2])[0])
    assert home[2] == pytest.approx(ground_amsl, abs=0.05)
    homes = tmp_path / "homes.txt"
    assert main(["export", str(plan_path), "--format", "homes", "-o", str(homes)]) == 0
    line = homes.read_text().splitlines()[1]
    assert float(line.split("PX4_HOME_ALT=")[1]) == pytest.approx(ground_amsl, abs=0.01)


def test_assessment_runs_fly_down_into_a_valley_below_where_they_took_off(tmp_path: Path) -> None:
    """``gcs assess``'s batch simulator stands each vehicle on the terrain: a goal in a valley
    13 m below the take-off is reached (on flat ground at the take-off's height the vehicle
    would stop there), and the floor holds on the true positions."""
    utm_raster(tmp_path / "valley.tif", lambda e, n: 490.0 - 0.25 * e)  # falls eastward
    scenario = ridge_scenario(
        tmp_path,
        terrain={"file": "valley.tif", "min_agl_m": 3},
        workspace={"min": [-20, -20, -25], "max": [80, 20, 20]},
        regions={"goal": {"kind": "goal", "min": [56, -3, -10], "max": [64, 3, -6]}},
    )
    problem = load_scenario(scenario)
    res = plan(problem)
    assert res.success, res.status
    save_plan(tmp_path / "valley.plan.json", res, str(scenario))
    valley = load_plan(tmp_path / "valley.plan.json")
    flights = simulate(prepare(valley), [run_seed(3, r) for r in range(3)], parse_disturbances({}))
    assert valley.terrain is not None
    pos = flights.true_enu_m[:, 0]  # (runs, samples, 3), the one vehicle
    start_ground = float(valley.terrain.ground([0.0, 0.0])[0])
    assert np.all(pos[:, -1, 2] < start_ground - 8.0)  # well below where it took off
    agl = pos[..., 2] - valley.terrain.ground(pos[..., :2].reshape(-1, 2)).reshape(pos.shape[:2])
    assert agl.min() >= 3.0 - 0.5  # the floor, within the px4 vehicle's tracking
    true, _rep, _ct, _cr = evaluate_batch(valley, flights)
    assert np.all(true > 0)  # every run meets the spec on its true positions
