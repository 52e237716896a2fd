"""The mock PX4 vehicle endpoint (vehicle side of MAVLink), for offline runs and tests.

A :class:`MockFleet` simulates ``n`` PX4 quad-rotors in one process: real
MAVLink 2 bytes (pymavlink, common dialect) over real UDP sockets, with PX4's
ports and system ids (vehicle ``i``: sysid ``i + 1``, listens on ``14580 + i``,
sends to ``14540 + i``), so MAVSDK, QGroundControl and MAVProxy treat each one
as a PX4 autopilot.  See DESIGN.md section 8 for what it implements.

Public API::

    from mavlink.mock import MockFleet, MockVehicleConfig, FaultConfig, Outage
    async with MockFleet(n=4, origin=GeodeticPoint(...), seed=0) as fleet: ...
    with MockFleet(n=1).running_in_thread() as fleet: fleet.vehicles[0].state

Errors (one tree)::

    MockError(Exception)
      MockConfigError(MockError, ValueError)   a bad configuration value (names it)
      MockStartError(MockError, OSError)       a UDP port could not be bound

Client mistakes on the link are not exceptions: they get PX4's MAVLink answers
(COMMAND_ACK results, MISSION_ACK errors, STATUSTEXT).
"""

from __future__ import annotations

from mavlink.mock.config import FaultConfig, MockVehicleConfig, NoiseConfig, Outage, WindConfig
from mavlink.mock.errors import MockConfigError, MockError, MockStartError
from mavlink.mock.fleet import DEFAULT_ORIGIN, MockFleet
from mavlink.mock.mission import MissionItem
from mavlink.mock.px4 import Px4Mode
from mavlink.mock.vehicle import MockVehicle, VehicleState

__all__ = [
    "DEFAULT_ORIGIN",
    "FaultConfig",
    "MissionItem",
    "MockConfigError",
    "MockError",
    "MockFleet",
    "MockStartError",
    "MockVehicle",
    "MockVehicleConfig",
    "NoiseConfig",
    "Outage",
    "Px4Mode",
    "VehicleState",
    "WindConfig",
]
