"""A plan over a ridge flown on the mock (``gcs fly --dry-run``): the vehicle stands and takes
off on the elevation model's ground, crosses the ridge above ``min_agl_m`` in its flown
telemetry, and the exports put home on that ground."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gcs.cli import main
from mavlink.tlog import tracks_from_tlog
from planner.planfile import load_plan
from tests.terrain_support import ridge_scenario


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
