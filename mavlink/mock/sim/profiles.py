"""Profiles of the mock vehicle: which vehicle it pretends to be, as a table of parameters.

A profile is nothing but parameter values on top of the defaults of
:data:`mavlink.mock.sim.px4.PARAM_SPECS`, so every aspect of it can be overridden one
parameter at a time (``MockFleet(params=...)``, ``gcs mock --param NAME=VALUE``) and read
or set by any client through the MAVLink parameter protocol.

``px4`` (the default)
    PX4 v1.17 SITL with its SIH quad-rotor, as observed in ``docs/px4-behaviour.md``:
    PX4's attitude loop between the acceleration asked and the one flown (the tilt
    follows at 1 / MC_ROLL_P = 0.25 s, then the rotors at SIH_T_TAU = 0.05 s);
    linear drag (SIH_KDV 1/s) that PX4's position controller does not compensate, so
    the vehicle trails its setpoints by KDV / (MPC_XY_P * MPC_XY_VEL_P_ACC) = 0.585 s
    until the velocity integrator catches up; the loops closed on a biased, noisy
    estimate (a slow velocity bias holds the hover ``bias / MPC_XY_P`` off its setpoint)
    with a per-boot EKF origin (``mavlink.mock.sim.estimator``) and a ground-effect
    altitude creep; yaw at MC_YAW_P; PX4's take-off (spool-up only when a climb is
    wanted, ramp MPC_TKO_RAMP_T, "reached" within NAV_MC_ALT_RAD); PX4's mission
    navigator and storage (``MOCK_PX4_NAV``): corner speeds, MISSION_ITEM_REACHED and
    MISSION_CURRENT as PX4 emits them on the API link, items normalised on download, the take-off skip, the
    mission-start rejection window (``MOCK_MIS_RDY_T``) and the predictive geofence
    (GF_PREDICT).
``ideal``
    The exact textbook vehicle of the first version: no drag, the truth as its
    estimate, an exact origin at the spawn, every waypoint reported once, items stored
    as sent, a fence that fires only on a breach.  For tests that need exactness.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

from mavlink.mock.sim.errors import MockConfigError

_IDEAL: dict[str, float] = {
    "SIH_KDV": 0.0,
    "MPC_XY_VEL_D_ACC": 0.0,
    "MPC_TKO_RAMP_T": 0.0,
    "MC_YAW_P": 2.0,
    "MC_YAWRATE_MAX": 45.0,
    "GF_PREDICT": 0,
    "MOCK_ORG_XY_MIN": 0.0,
    "MOCK_ORG_XY_MAX": 0.0,
    "MOCK_ORG_Z_MIN": 0.0,
    "MOCK_ORG_Z_MAX": 0.0,
    "MOCK_EST_SLOW_B": 0.0,
    "MOCK_EST_P_N": 0.0,
    "MOCK_EST_V_N": 0.0,
    "MOCK_EST_VB": 0.0,
    "MOCK_EST_YAW_V": 0.0,
    "MOCK_GE_HGT": 0.0,
    "MOCK_GE_RATE": 0.0,
    "MOCK_GE_MIN": 0.0,
    "MOCK_GE_MAX": 0.0,
    "MOCK_PX4_NAV": 0,
    "MOCK_ATT_DYN": 0,
    "MOCK_MIS_RDY_T": 0.0,
    "SYS_AUTOSTART": 4001,
    # takes off exactly to any height: take-offs count as reached 0.2 m from the target
    "NAV_MC_ALT_RAD": 0.2,
}

#: Profile name -> parameter values over the PX4 defaults.
PROFILES: Mapping[str, Mapping[str, float]] = MappingProxyType(
    {"px4": MappingProxyType({}), "ideal": MappingProxyType(_IDEAL)}
)
DEFAULT_PROFILE = "px4"


def profile_params(name: str) -> Mapping[str, float]:
    """The parameter values of profile ``name``; :class:`MockConfigError` names the choices."""
    try:
        return PROFILES[name]
    except KeyError:
        raise MockConfigError(
            f"unknown mock profile {name!r}: choose one of {', '.join(PROFILES)}"
        ) from None
