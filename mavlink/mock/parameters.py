"""Parameters of the mock vehicle: PX4's parameter protocol and what the values set.

Mixed into :class:`mavlink.mock.vehicle.MockVehicle`.  PARAM_REQUEST_LIST,
PARAM_REQUEST_READ and PARAM_SET are answered with PARAM_VALUE as PX4 does (values
encoded by type, :func:`mavlink.mock.px4.encode_param_value`; unknown names and
out-of-range values get a STATUSTEXT warning); every accepted value is applied at once
to the vehicle's row of the physics (controller gains, drag, attitude and thrust lags,
the estimator) and to the speed and acceleration limits of the current mode.  A room
of its own because it is the one place where parameters become behaviour.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple, TypeAlias

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import px4
from mavlink.mock.errors import MockConfigError
from mavlink.mock.estimator import EstimatorParams
from mavlink.mock.parts import VehicleParts
from mavlink.mock.physics import GRAVITY_M_S2, FleetPhysics
from mavlink.mock.profiles import profile_params
from mavlink.mock.px4 import Px4Mode

#: A pymavlink message (its fields are per message type: untyped to mypy).
Msg: TypeAlias = Any
#: Rows of the fleet's physics: one index, a slice or an index array.
Rows: TypeAlias = int | slice | np.ndarray


class ModeLimits(NamedTuple):
    """The speed, acceleration and yaw-rate limits PX4's controller applies in one mode."""

    vel_xy_max_m_s: float
    vel_up_max_m_s: float
    vel_dn_max_m_s: float
    acc_xy_max_m_s2: float
    acc_up_max_m_s2: float
    acc_dn_max_m_s2: float
    yaw_rate_max_rad_s: float


def vehicle_params(profile: str, overrides: Mapping[str, float] | None) -> dict[str, float]:
    """Every PX4 parameter of a mock vehicle: PX4's defaults, the profile's, the overrides.

    Raises:
        MockConfigError: an unknown profile or parameter, or a value outside its range.
    """
    prm = {p.name: float(p.default) for p in px4.PARAM_SPECS}
    prm.update(profile_params(profile))
    specs = {p.name: p for p in px4.PARAM_SPECS}
    for name, value in (overrides or {}).items():
        spec = specs.get(name)
        if spec is None:
            raise MockConfigError(f"unknown parameter {name!r}")
        if not spec.accepts(float(value)):
            raise MockConfigError(
                f"parameter {name} = {value!r} outside [{spec.min:g}, {spec.max:g}]"
            )
        prm[name] = float(value)
    return prm


def mode_limits(prm: Mapping[str, float], mode: Px4Mode, cruise_speed_m_s: float) -> ModeLimits:
    """The limits of ``mode`` from a vehicle's parameters (``cruise_speed_m_s``: the auto
    modes' cruise speed, DO_CHANGE_SPEED's or MPC_XY_CRUISE)."""
    auto = mode.value[0] == 4
    px4_nav = prm["MOCK_PX4_NAV"] >= 0.5
    if px4_nav:
        # PX4's position controller limits the acceleration only by the tilt; the
        # trajectory generators of the auto modes respect MPC_ACC_HOR themselves
        acc_xy = GRAVITY_M_S2 * math.tan(math.radians(prm["MPC_TILTMAX_AIR"]))
    else:
        acc_xy = prm["MPC_ACC_HOR"] if auto else prm["MPC_ACC_HOR_MAX"]
    yaw_max = prm["MC_YAWRATE_MAX"] if mode is Px4Mode.OFFBOARD else prm["MPC_YAWRAUTO_MAX"]
    return ModeLimits(
        vel_xy_max_m_s=min(cruise_speed_m_s, prm["MPC_XY_VEL_MAX"])
        if auto
        else prm["MPC_XY_VEL_MAX"],
        vel_up_max_m_s=(
            prm["MPC_TKO_SPEED"] if mode is Px4Mode.AUTO_TAKEOFF else prm["MPC_Z_VEL_MAX_UP"]
        ),
        vel_dn_max_m_s=prm["MPC_Z_VEL_MAX_DN"],
        acc_xy_max_m_s2=acc_xy,
        acc_up_max_m_s2=prm["MPC_ACC_UP_MAX"],
        acc_dn_max_m_s2=prm["MPC_ACC_DOWN_MAX"],
        yaw_rate_max_rad_s=math.radians(yaw_max),
    )


def apply_limits(
    phys: FleetPhysics, rows: Rows, limits: ModeLimits, scale: float | np.ndarray = 1.0
) -> None:
    """Write ``limits`` into the physics rows ``rows`` (an index, a slice or an index array),
    the speed and acceleration limits times ``scale`` (one factor, or one per row: a vehicle
    derated to that fraction of its limits; the yaw rate is not scaled)."""
    phys.vel_xy_max_m_s[rows] = limits.vel_xy_max_m_s * scale
    phys.vel_up_max_m_s[rows] = limits.vel_up_max_m_s * scale
    phys.vel_dn_max_m_s[rows] = limits.vel_dn_max_m_s * scale
    phys.acc_xy_max_m_s2[rows] = limits.acc_xy_max_m_s2 * scale
    phys.acc_up_max_m_s2[rows] = limits.acc_up_max_m_s2 * scale
    phys.acc_dn_max_m_s2[rows] = limits.acc_dn_max_m_s2 * scale
    phys.yaw_rate_max_rad_s[rows] = limits.yaw_rate_max_rad_s


def apply_controller_params(phys: FleetPhysics, rows: Rows, prm: Mapping[str, float]) -> None:
    """What a vehicle's parameters make of its physics rows ``rows``: the controller's gains,
    SIH's drag, the attitude and thrust lags (not the estimator, not the mode's limits).

    The one place where PX4's parameter values become the vehicle model, for the real-time
    mock vehicle (one row) and the batch simulator (:mod:`mavlink.mock.batch`, many rows).
    """
    phys.kp_pos[rows] = (prm["MPC_XY_P"], prm["MPC_XY_P"], prm["MPC_Z_P"])
    phys.kp_vel[rows] = (prm["MPC_XY_VEL_P_ACC"], prm["MPC_XY_VEL_P_ACC"], prm["MPC_Z_VEL_P_ACC"])
    phys.ki_vel[rows] = (prm["MPC_XY_VEL_I_ACC"], prm["MPC_XY_VEL_I_ACC"], prm["MPC_Z_VEL_I_ACC"])
    phys.kd_vel[rows] = (prm["MPC_XY_VEL_D_ACC"], prm["MPC_XY_VEL_D_ACC"], prm["MPC_Z_VEL_D_ACC"])
    phys.kdv_per_s[rows] = prm["SIH_KDV"] / prm["SIH_MASS"]  # SIH: force per m/s over mass
    phys.yaw_p[rows] = prm["MC_YAW_P"]
    # the tilt follows PX4's attitude loop (1 / MC_ROLL_P, MC_PITCH_P: the slower one)
    gain = min(prm["MC_ROLL_P"], prm["MC_PITCH_P"])
    phys.att_tau_s[rows] = 1.0 / gain if prm["MOCK_ATT_DYN"] >= 0.5 and gain > 0.0 else 0.0
    phys.set_thrust_tau(rows, prm["SIH_T_TAU"])


class ParametersMixin(VehicleParts):
    """Parameter protocol and parameter effects of :class:`~mavlink.mock.vehicle.MockVehicle`."""

    def _apply_params(self) -> None:
        i, p, prm = self.index, self.phys, self.params
        apply_controller_params(p, i, prm)
        p.estimator.configure(i, EstimatorParams.from_params(prm), new_boot=False)
        self._apply_limits()

    @property
    def px4_nav(self) -> bool:
        """True when PX4 v1.17's navigator, take-off and storage are modelled (MOCK_PX4_NAV)."""
        return self.params["MOCK_PX4_NAV"] >= 0.5

    def _apply_limits(self) -> None:
        """Speed/acceleration limits of the current mode from the parameters."""
        limits = mode_limits(self.params, self.mode, self.cruise_speed_m_s)
        self._vel_up_base = limits.vel_up_max_m_s
        apply_limits(self.phys, self.index, limits)

    def _param_value_msg(self, name: str) -> Msg:
        spec = self._param_specs[name]
        return mavlink2.MAVLink_param_value_message(
            name.encode("ascii"),
            px4.encode_param_value(self.params[name], spec.type),
            int(spec.type),
            len(self._param_names),
            self._param_names.index(name),
        )

    def _on_param_request_list(self, msg: Msg) -> None:
        if self._for_me(msg):
            for name in self._param_names:
                self.send(self._param_value_msg(name))

    def _on_param_request_read(self, msg: Msg) -> None:
        if not self._for_me(msg):
            return
        if msg.param_index >= 0:
            if msg.param_index < len(self._param_names):
                self.send(self._param_value_msg(self._param_names[msg.param_index]))
            return
        name = _param_name(msg.param_id)
        if name in self.params:
            self.send(self._param_value_msg(name))
        else:
            self.statustext(mavlink2.MAV_SEVERITY_WARNING, f"Parameter {name} not found")

    def _on_param_set(self, msg: Msg) -> None:
        if not self._for_me(msg):
            return
        name = _param_name(msg.param_id)
        spec = self._param_specs.get(name)
        if spec is None:
            self.statustext(mavlink2.MAV_SEVERITY_WARNING, f"Parameter {name} not found")
            return
        value = px4.decode_param_value(msg.param_value, spec.type)
        if not spec.accepts(value):
            self.statustext(
                mavlink2.MAV_SEVERITY_WARNING, f"Parameter {name}: {value:g} out of range"
            )
        else:
            self.params[name] = value
            if name == "MPC_XY_CRUISE":
                self.cruise_speed_m_s = value
            self._apply_params()
        self.send(self._param_value_msg(name))


def _param_name(raw: str | bytes) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return raw.split("\x00", 1)[0]
