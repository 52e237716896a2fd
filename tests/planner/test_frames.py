"""planner.frames: mission ENU <-> vehicle NED <-> geodetic, yaw conventions."""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest

from planner.frames import (
    FrameError,
    GeodeticPoint,
    enu_to_geodetic,
    enu_to_ned,
    enu_vector_to_ned,
    geodetic_to_enu,
    ned_to_enu,
    ned_vector_to_enu,
    yaw_enu_to_ned,
    yaw_ned_to_enu,
)

MISSION = GeodeticPoint(47.3977, 8.5456, 488.0)
# A vehicle spawned ~60 m north-east and 3 m higher than the mission origin.
VEHICLE = GeodeticPoint(47.39812, 8.54625, 491.0)


def _points(n: int = 500, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [rng.uniform(-800, 800, n), rng.uniform(-800, 800, n), rng.uniform(0, 120, n)]
    )


def test_enu_ned_round_trip_to_millimetres() -> None:
    p = _points()
    ned = enu_to_ned(p, MISSION, VEHICLE)
    assert ned.shape == p.shape
    assert np.max(np.abs(ned_to_enu(ned, MISSION, VEHICLE) - p)) < 1e-3


def test_enu_geodetic_round_trip_to_millimetres() -> None:
    p = _points(seed=1)
    lat, lon, alt = enu_to_geodetic(p, MISSION)
    assert lat.shape == lon.shape == alt.shape == (p.shape[0],)
    assert np.max(np.abs(geodetic_to_enu(lat, lon, alt, MISSION) - p)) < 1e-3
    one = enu_to_geodetic(p[0], MISSION)
    assert all(isinstance(x, float) for x in one)
    assert one == (lat[0], lon[0], alt[0])


def test_vehicle_origin_maps_to_ned_zero_and_axes_are_ned() -> None:
    origin_in_mission = geodetic_to_enu(VEHICLE.lat_deg, VEHICLE.lon_deg, VEHICLE.alt_m, MISSION)[0]
    assert np.max(np.abs(enu_to_ned(origin_in_mission, MISSION, VEHICLE))) < 1e-6
    # 10 m north, 5 m east, 2 m up of the vehicle's origin (in mission ENU, ignoring the
    # tiny tangent-plane rotation over ~60 m) is NED (10, 5, -2) for the vehicle.
    ned = enu_to_ned(origin_in_mission + np.array([5.0, 10.0, 2.0]), MISSION, VEHICLE)
    np.testing.assert_allclose(ned, [10.0, 5.0, -2.0], atol=5e-3)
    # Same origin: a pure axis swap, exactly.
    assert enu_to_ned([1.0, 2.0, 3.0], MISSION, MISSION).tolist() == [2.0, 1.0, -3.0]


def test_conversion_goes_through_geodetic_not_an_axis_shift() -> None:
    """Independent check with pymap3d's ECEF functions directly."""
    p = _points(20, seed=2)
    x, y, z = pymap3d.enu2ecef(
        p[:, 0], p[:, 1], p[:, 2], MISSION.lat_deg, MISSION.lon_deg, MISSION.alt_m
    )
    n, e, d = pymap3d.ecef2ned(x, y, z, VEHICLE.lat_deg, VEHICLE.lon_deg, VEHICLE.alt_m)
    np.testing.assert_allclose(
        enu_to_ned(p, MISSION, VEHICLE), np.column_stack([n, e, d]), atol=1e-6
    )


def test_vectors_rotate_without_translation() -> None:
    v = _points(50, seed=3) / 100.0
    ned = enu_vector_to_ned(v, MISSION, VEHICLE)
    np.testing.assert_allclose(np.linalg.norm(ned, axis=1), np.linalg.norm(v, axis=1), rtol=1e-12)
    np.testing.assert_allclose(ned_vector_to_enu(ned, MISSION, VEHICLE), v, atol=1e-12)
    # Nearly a pure axis swap for nearby origins (rotation ~1e-5 rad).
    np.testing.assert_allclose(ned, np.column_stack([v[:, 1], v[:, 0], -v[:, 2]]), atol=5e-4)


def test_yaw_conventions() -> None:
    assert yaw_enu_to_ned(0.0) == pytest.approx(math.pi / 2)  # facing east
    assert yaw_enu_to_ned(math.pi / 2) == pytest.approx(0.0)  # facing north
    assert yaw_enu_to_ned(math.pi) == pytest.approx(-math.pi / 2)  # facing west
    y = np.random.default_rng(4).uniform(-10, 10, 200)
    back = yaw_ned_to_enu(yaw_enu_to_ned(y, MISSION, VEHICLE), MISSION, VEHICLE)
    assert np.max(np.abs(np.angle(np.exp(1j * (back - y))))) < 1e-12
    out = yaw_enu_to_ned(y)
    assert np.all((out > -math.pi) & (out <= math.pi))


def test_bad_input_is_rejected_with_the_field_name() -> None:
    with pytest.raises(FrameError, match="lat_deg"):
        GeodeticPoint(95.0, 0.0, 0.0)
    with pytest.raises(FrameError, match="alt_m"):
        GeodeticPoint(0.0, 0.0, float("nan"))
    with pytest.raises(FrameError, match=r"pos_enu_m must have shape \(3,\) or \(n, 3\)"):
        enu_to_ned(np.zeros((4, 2)), MISSION, VEHICLE)
    with pytest.raises(FrameError, match="finite"):
        enu_to_geodetic([0.0, np.inf, 0.0], MISSION)
