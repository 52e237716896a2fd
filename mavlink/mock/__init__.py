"""The mock PX4 vehicle endpoint (vehicle side of MAVLink), for offline runs and tests.

A :class:`MockFleet` simulates ``n`` PX4 quad-rotors in one process: real
MAVLink 2 bytes (pymavlink, common dialect) over real UDP sockets, with PX4's
ports and system ids (vehicle ``i``: sysid ``i + 1``, listens on ``14580 + i``,
sends to ``14540 + i``), so MAVSDK, QGroundControl and MAVProxy treat each one
as a PX4 autopilot.  See docs/architecture.md, "The mock vehicle" for what it implements.

By default the vehicles behave like PX4 v1.17 SITL with its SIH quad-rotor (the ``px4``
profile: drag, PX4's cascade on a biased estimate, PX4's take-off, navigator, mission
storage and predictive geofence); ``profile="ideal"`` gives the exact vehicle
(:mod:`mavlink.mock.sim.profiles`).  Each vehicle carries a MAVLink camera (component 100) on
a gimbal the autopilot manages (device 154) unless ``camera=False``.  Modules: ``navigator``
(missions, RTL, geofence), ``mission`` (the mission protocol and storage), ``telemetry``,
``payload`` (the camera and the gimbal), ``vehicle`` (one MAVLink endpoint), ``fleet``; what
the vehicle does apart from the link is the simulation, :mod:`mavlink.mock.sim` (physics,
estimator, PX4's modes and parameters, profiles, disturbances, simulated time, the batch
simulator, PX4 SITL's figures), which speaks no MAVLink.

Public API::

    from mavlink.mock import MockFleet, MockVehicleConfig, FaultConfig, Outage
    async with MockFleet(n=4, origin=GeodeticPoint(...), seed=0) as fleet: ...
    with MockFleet(n=1).running_in_thread() as fleet: fleet.vehicles[0].state
    fleet = MockFleet(n=2, profile="ideal"); fleet.advance(5.0)   # offline, no sockets
    fleet.truth_enu_m()                                            # ground truth, (n, 3)

Errors (one tree)::

    MockError(Exception)
      MockConfigError(MockError, ValueError)   a bad configuration value (names it)
      MockStartError(MockError, OSError)       a UDP port could not be bound

Client mistakes on the link are not exceptions: they get PX4's MAVLink answers
(COMMAND_ACK results, MISSION_ACK errors, STATUSTEXT).
"""

from __future__ import annotations

from mavlink.mock.fleet import DEFAULT_ORIGIN, MockFleet
from mavlink.mock.mission import MissionItem
from mavlink.mock.sim.config import (
    CameraSpec,
    FaultConfig,
    GimbalSpec,
    MockVehicleConfig,
    NoiseConfig,
    Outage,
    WindConfig,
)
from mavlink.mock.sim.errors import MockConfigError, MockError, MockStartError
from mavlink.mock.sim.profiles import DEFAULT_PROFILE, PROFILES
from mavlink.mock.sim.px4 import Px4Mode
from mavlink.mock.vehicle import MockVehicle, VehicleState

__all__ = [
    "DEFAULT_ORIGIN",
    "DEFAULT_PROFILE",
    "PROFILES",
    "CameraSpec",
    "FaultConfig",
    "GimbalSpec",
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
