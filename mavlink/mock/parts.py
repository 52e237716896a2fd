"""What the mock vehicle's mixins read from the vehicle, declared once for the type checker.

:class:`~mavlink.mock.vehicle.MockVehicle` is put together from
:class:`~mavlink.mock.commands.CommandsMixin` (commands, arming, modes),
:class:`~mavlink.mock.offboard.OffboardMixin` (offboard setpoints),
:class:`~mavlink.mock.parameters.ParametersMixin` (parameter protocol and effects),
:class:`~mavlink.mock.origin.OriginMixin` (local frame, EKF origin),
:class:`~mavlink.mock.navigator.NavigatorMixin` (missions, RTL, geofence),
:class:`~mavlink.mock.telemetry.TelemetryMixin` (message builders) and
:class:`~mavlink.mock.payload.PayloadMixin` (camera, gimbal); each reads the vehicle's
state and calls methods of the vehicle or of the other mixins.  :class:`VehicleParts`, their
common base, names those attributes with their types and the methods' signatures (the
latter for the type checker only), so each mixin is checked against what the vehicle really
provides.  At run time it adds nothing: annotations without values create no attributes.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from mavlink.mock.mission import MissionServer
    from mavlink.mock.offboard import Setpoint
    from mavlink.mock.sim.config import MockVehicleConfig
    from mavlink.mock.sim.navigation import AutoTrajectory, Geofence
    from mavlink.mock.sim.payload_state import CameraState, GimbalState
    from mavlink.mock.sim.physics import FleetPhysics
    from mavlink.mock.sim.px4 import ParamSpec, Px4Mode
    from mavlink.mock.telemetry import Stream
    from mavlink.mock.vehicle import FleetSide, Link


class VehicleParts:
    """The state and methods of a mock vehicle that its mixins use (module docstring)."""

    fleet: FleetSide
    index: int
    sysid: int
    uid: int
    config: MockVehicleConfig
    spawn_lla: tuple[float, float, float]
    origin_lla: tuple[float, float, float]
    phys: FleetPhysics
    params: dict[str, float]
    _param_specs: dict[str, ParamSpec]
    _param_names: list[str]
    missions: MissionServer
    armed: bool
    landed: bool
    failsafe: bool
    mode: Px4Mode
    home_ned_m: np.ndarray
    cruise_speed_m_s: float
    mission_seq: int
    mission_finished: bool
    _armed_at_s: float
    _fence_breached: bool
    _fence: Geofence
    #: PX4's trajectory setpoint in the auto modes (:mod:`mavlink.mock.sim.navigation`)
    traj: AutoTrajectory
    _rtl_phase: str
    _jump_counts: dict[int, int]
    _seq_reached: int
    _mis_reached_sent: int
    _reached_resends: int
    _reached_next_s: float
    _mc_rng: random.Random
    _mission_valid_s: float
    # offboard: the last setpoint, when setpoints last came and since when they stream
    _sp: Setpoint | None
    _sp_last_s: float
    _sp_stream_start_s: float
    _frame_warned: set[int]
    # telemetry streams, and (due time, action) run by tick
    _builders: dict[int, Callable[[], Any]]
    _streams: dict[int, Stream]
    _deferred: list[tuple[float, Callable[[], None]]]
    # the battery's charge (%) a fault set (mavlink.mock.vehicle_faults), None: it drains
    battery_override_pct: float | None
    downlink: Link | None
    # the command being answered: (MAV_CMD, sender's sysid, sender's compid)
    _cmd_partner: tuple[int, int, int]
    # payload: the camera and the gimbal (None without), the navigator's ROI (local NED),
    # whether the navigator started an interval capture, when it levels the gimbal
    camera: CameraState | None
    gimbal: GimbalState | None
    _roi_ned_m: np.ndarray | None
    _nav_capturing: bool
    _neutral_due_s: float

    if TYPE_CHECKING:

        @property
        def px4_nav(self) -> bool: ...

        def _now(self) -> float: ...

        def _boot_ms(self) -> int: ...

        def _usec(self) -> int: ...

        def send(self, msg: Any) -> None: ...

        def _for_me(self, msg: Any) -> bool: ...

        def statustext(self, severity: int, text: str) -> None: ...

        def set_mode(self, mode: Px4Mode, takeoff_down_m: float | None = None) -> None: ...

        def ned_to_global(self, pos_ned_m: np.ndarray) -> tuple[float, float, float]: ...

        def global_to_ned(self, lat_deg: float, lon_deg: float, alt_m: float) -> np.ndarray: ...

        def home_alt_amsl(self) -> float: ...

        def _item_target_ned(
            self, frame: int, x_e7: int, y_e7: int, z_m: float, default: np.ndarray
        ) -> np.ndarray: ...

        def _alt_to_down(self, frame: int, alt_m: float) -> float: ...

        def _msg_home_position(self) -> Any: ...

        def _msg_autopilot_version(self) -> Any: ...

        def _apply_limits(self) -> None: ...

        def _do_disarm(self, why: str) -> None: ...

        def _start_descent(self) -> None: ...

        def _land_speed_m_s(self) -> float: ...

        def _msg_mission_current(self) -> Any: ...

        def _msg_gps_global_origin(self) -> Any: ...

        def _stream_ok(self) -> bool: ...

        def _apply_setpoint(self) -> None: ...

        def _rtl_start(self) -> None: ...

        def _mission_start_item(self, seq: int) -> None: ...

        def _announce_current(self, *, set_by_client: bool = False) -> None: ...

        def _payload_command(self, msg: Any, p: tuple[float, ...]) -> None: ...

        def _payload_mode_change(self, old: Px4Mode, new: Px4Mode) -> None: ...

        def _mission_payload_item(self, item: Any) -> None: ...
