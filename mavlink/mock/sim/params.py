"""What a PX4 vehicle's parameters make of the simulated vehicle: the parameters of a
vehicle (PX4's defaults, its profile's, the user's), the speed and acceleration limits of a
flight mode, and the controller's gains, drag and lags written into the physics rows.

The one place where PX4's parameter values become the vehicle model, for the real-time mock
vehicle (one row; its PARAM protocol: :mod:`mavlink.mock.parameters`) and the batch simulator
(:mod:`mavlink.mock.sim.batch`, many rows).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import NamedTuple, TypeAlias

import numpy as np

from mavlink.mock.sim.errors import MockConfigError
from mavlink.mock.sim.physics import GRAVITY_M_S2, FleetPhysics
from mavlink.mock.sim.profiles import profile_params
from mavlink.mock.sim.px4 import PARAM_SPECS, Px4Mode

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
    prm = {p.name: float(p.default) for p in PARAM_SPECS}
    prm.update(profile_params(profile))
    specs = {p.name: p for p in PARAM_SPECS}
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
    mock vehicle (one row) and the batch simulator (:mod:`mavlink.mock.sim.batch`, many rows).
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
