"""Shared helpers of the ``px4`` profile's offline tests (test_mock_px4*.py).

A fleet stepped offline (:meth:`MockFleet.advance`: simulated time, no sockets), spoken to
in MAVLink bytes through :meth:`MockVehicle.receive`: commands, offboard setpoints, and the
parameter sets that quieten the estimator or the ground-effect creep.  A module of its own
because both the control/estimator tests and the navigator tests fly with them.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import MockFleet, Px4Mode
from mavlink.mock.vehicle import MockVehicle

QUIET = {
    "MOCK_EST_SLOW_B": 0.0,
    "MOCK_EST_P_N": 0.0,
    "MOCK_EST_V_N": 0.0,
    "MOCK_EST_VB": 0.0,
    "MOCK_EST_YAW_V": 0.0,
}
NO_CREEP = {"MOCK_GE_RATE": 0.0}


def fleet(n: int = 1, seed: int = 0, profile: str = "px4", **params: float) -> MockFleet:
    f = MockFleet(n=n, seed=seed, profile=profile, params=params or None, ready_after_s=0.0)
    f.offline_links()
    return f


def cmd(v: MockVehicle, command: int, *p: float) -> None:
    params = [*p, *([0.0] * (7 - len(p)))]
    v.receive(mavlink2.MAVLink_command_long_message(v.sysid, 1, command, 0, *params))


def offboard_hover(f: MockFleet, v: MockVehicle, down_m: float = -3.0) -> None:
    """Arm, stream a hover setpoint for 1.2 s, switch to offboard and settle 8 s."""
    assert v.arm() == mavlink2.MAV_RESULT_ACCEPTED
    for _ in range(120):
        stream(v, (0.0, 0.0, down_m))
        f.advance(0.01)
    assert v.request_mode(Px4Mode.OFFBOARD) == mavlink2.MAV_RESULT_ACCEPTED
    for _ in range(800):
        stream(v, (0.0, 0.0, down_m))
        f.advance(0.01)


def stream(v: MockVehicle, pos, vel=(0.0, 0.0, 0.0), acc=(0.0, 0.0, 0.0), yaw: float = 0.0) -> None:  # type: ignore[no-untyped-def]  # fmt: skip
    v.receive(
        mavlink2.MAVLink_set_position_target_local_ned_message(
            0,
            v.sysid,
            1,
            mavlink2.MAV_FRAME_LOCAL_NED,
            0b0000_1000_0000_0000,
            *pos,
            *vel,
            *acc,
            yaw,
            0.0,
        )
    )
