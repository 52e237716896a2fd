"""``timing.end``: every vehicle ends at rest (the default, flyable), or the end state is left
free (stlpy's benchmarks assume it). Checked against the closed-form reach of a double
integrator: from rest within |v| <= 3 m/s and |a| <= 3 m/s^2, 4 s cover 9 m if the vehicle
must stop at the end, 10.5 m if it may arrive at full speed."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest

from gcs.checks import verify_plan
from planner.optimize import plan
from planner.scenario import parse_scenario
from planner.scenario.sections import ScenarioError

_DASH: dict[str, Any] = {
    "name": "dash",
    "origin": {"lat": 47.397742, "lon": 8.545594, "alt": 488.0},
    "workspace": {"min": [-1, -1, 0.5], "max": [12, 1, 1.5]},
    "regions": {},
    "limits": {"v_max_m_s": 3, "a_max_m_s2": 3},
    "vehicles": [{"name": "d1", "start": [0, 0, 1]}],
    "timing": {"horizon_s": 4, "segment_s": 0.5, "Ts_s": 0.5, "check_dt_s": 0.01},
    "epsilon": 0.01,
    "model": "double_integrator",
    "spec": ["eventually[0, 4] x(d1) >= 9.5"],
}


def _dash(end: str | None) -> Any:
    data = copy.deepcopy(_DASH)
    if end is not None:
        data["timing"]["end"] = end
    return parse_scenario(data, "dash.yaml")


@pytest.mark.parametrize(("end", "best"), [(None, -0.5), ("rest", -0.5), ("free", 1.0)])
def test_the_end_state_decides_how_far_a_vehicle_gets(end: str | None, best: float) -> None:
    res = plan(_dash(end))
    assert res.robustness == pytest.approx(best, abs=0.02)
    v_end = res.trajectories[0].velocity(np.array([4.0]))[0]
    if end == "free":
        assert res.success and v_end[0] == pytest.approx(3.0, abs=0.05)
        # gcs verify (and so gcs fly's interlock) refuses a plan that ends moving
        end_check = [c for c in verify_plan(res.to_plan()) if "speed at the end" in c.name]
        assert [c.ok for c in end_check] == [False]
        assert "coast on" in end_check[0].detail
    else:
        assert not res.success and np.abs(v_end).max() < 1e-6
        end_check = [c for c in verify_plan(res.to_plan()) if "speed at the end" in c.name]
        assert [c.ok for c in end_check] == [True]


def test_a_bad_end_names_the_key() -> None:
    with pytest.raises(ScenarioError, match=r"dash.yaml: timing.end: expected 'rest' or 'free'"):
        _dash("stop")
