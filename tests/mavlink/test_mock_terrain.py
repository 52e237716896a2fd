"""The mock's ground follows a terrain: a vehicle flies down into a valley below its spawn,
lands where the ground is, and cannot sink into a slope above it (offline, simulated time)."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import MockFleet, Px4Mode
from planner.spec.terrain import Terrain
from tests.mavlink.mock_px4_helpers import NO_CREEP, QUIET, cmd, offboard_hover, stream

# the ground falls 1 m per 4 m eastward (mission frame), flat north-south
XS = np.arange(-60.0, 60.0 + 1e-9, 5.0)
YS = np.arange(-20.0, 20.0 + 1e-9, 5.0)
SLOPE = Terrain(-60.0, -20.0, 5.0, np.repeat((-0.25 * XS)[:, None], len(YS), axis=1))


def _fleet(spawn: tuple[float, float, float]) -> MockFleet:
    f = MockFleet(
        n=1,
        seed=3,
        spawns_enu_m=[spawn],
        params={**QUIET, **NO_CREEP},
        ready_after_s=0.0,
        camera=False,
        terrain=SLOPE,
    )
    f.offline_links()
    return f


def _fly_to(f: MockFleet, north: float, east: float, down: float, seconds: float) -> None:
    v = f.vehicles[0]
    for _ in range(round(seconds / 0.05)):
        stream(v, (north, east, down))
        f.advance(0.05)


@pytest.mark.slow
def test_a_vehicle_flies_into_a_valley_below_its_spawn_and_lands_on_the_ground_there() -> None:
    f = _fleet((0.0, 0.0, 0.0))
    v = f.vehicles[0]
    assert f.physics.ground_d_m[0] == pytest.approx(0.0)  # standing on its ground
    offboard_hover(f, v, -3.0)
    # 40 m east the ground is 10 m lower: 3 m above it is 7 m below the spawn
    _fly_to(f, 0.0, 40.0, 7.0, 40.0)
    x, y, z = f.truth_enu_m()[0]
    assert (x, y, z) == pytest.approx((40.0, 0.0, -7.0), abs=0.3)
    assert not v.state.landed
    cmd(v, mavlink2.MAV_CMD_NAV_LAND)
    for _ in range(600):
        f.advance(0.05)
        if v.state.landed:
            break
    assert v.state.mode is Px4Mode.AUTO_LAND and v.state.landed
    x, y, z = f.truth_enu_m()[0]
    assert z == pytest.approx(float(SLOPE.ground([x, y])[0]), abs=0.02)  # on the valley floor
    assert z == pytest.approx(-10.0, abs=0.2)


@pytest.mark.slow
def test_a_setpoint_under_a_rising_slope_leaves_the_vehicle_on_the_ground_not_in_it() -> None:
    f = _fleet((0.0, 0.0, 0.0))
    v = f.vehicles[0]
    offboard_hover(f, v, -3.0)
    # 40 m west the ground is 10 m higher; a setpoint 5 m above the spawn is 5 m under it
    _fly_to(f, 0.0, -40.0, -5.0, 40.0)
    x, y, z = f.truth_enu_m()[0]
    ground = float(SLOPE.ground([x, y])[0])
    assert z >= ground - 1e-9  # never under the ground
    assert x < -15.0  # it climbed the slope as far as the setpoint's height allowed
    assert z == pytest.approx(ground, abs=0.05)


def test_a_spawn_above_the_terrain_stands_on_a_platform_and_flat_ground_is_unchanged() -> None:
    f = _fleet((10.0, 0.0, 1.0))  # the ground there is at -2.5: a 3.5 m platform
    assert f.physics.ground_d_m[0] == pytest.approx(0.0)
    f.advance(2.0)
    assert f.truth_enu_m()[0][2] == pytest.approx(1.0, abs=1e-6)  # it stays on it
    flat = MockFleet(n=1, seed=3, ready_after_s=0.0, camera=False)
    assert flat.physics.ground_of is None and flat.physics.ground_d_m[0] == 0.0
