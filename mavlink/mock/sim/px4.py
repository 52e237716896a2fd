"""PX4 facts the simulated vehicle reproduces: flight modes and the parameter table.

PX4's flight mode is the pair (main mode, sub mode) of ``px4_custom_mode.h``; the MAVLink
endpoint packs it into ``HEARTBEAT.custom_mode`` as ``(main << 16) | (sub << 24)``
(:attr:`Px4Mode.custom_mode`) and reads it from ``MAV_CMD_DO_SET_MODE``.

The parameter table is a small subset of a PX4 v1.17 multicopter (SITL SIH
``sihsim_quadx`` airframe) with PX4's defaults, plus the mock's own ``MOCK_*``
parameters (the estimator's error magnitudes and which PX4 behaviours are
modelled; :mod:`mavlink.mock.sim.profiles` sets them per profile).  How values travel on the
link (PX4's byte-wise encoding of integers) is the endpoint's (:mod:`mavlink.mock.px4`).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass


class MainMode(enum.IntEnum):
    """PX4 main modes (``PX4_CUSTOM_MAIN_MODE_*``)."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7


class AutoSubMode(enum.IntEnum):
    """PX4 AUTO sub modes (``PX4_CUSTOM_SUB_MODE_AUTO_*``)."""

    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6


class Px4Mode(enum.Enum):
    """A PX4 flight mode as the (main, sub) pair of its custom mode.

    Kept apart from the ground station's :class:`mavlink.px4_modes.Px4Mode` on purpose (the
    vehicle's side shares only the wire with the client it tests); a test checks that the two
    encode every mode alike.
    """

    MANUAL = (1, 0)
    ALTCTL = (2, 0)
    POSCTL = (3, 0)
    AUTO_READY = (4, 1)
    AUTO_TAKEOFF = (4, 2)
    AUTO_LOITER = (4, 3)
    AUTO_MISSION = (4, 4)
    AUTO_RTL = (4, 5)
    AUTO_LAND = (4, 6)
    ACRO = (5, 0)
    OFFBOARD = (6, 0)
    STABILIZED = (7, 0)

    @property
    def custom_mode(self) -> int:
        """``HEARTBEAT.custom_mode`` of this mode."""
        main, sub = self.value
        return (main << 16) | (sub << 24)

    @property
    def needs_manual_control(self) -> bool:
        """True for the modes PX4 cannot enter without an RC / joystick input."""
        return self.value[0] in (1, 2, 3, 5, 7)

    @classmethod
    def from_main_sub(cls, main: int, sub: int) -> Px4Mode | None:
        """The mode for a (main, sub) pair, or None if PX4 has no such mode.

        A sub mode of 0 with main AUTO means "keep AUTO, sub unspecified" and is
        answered with AUTO.LOITER as PX4 does.
        """
        if main == 4 and sub == 0:
            return cls.AUTO_LOITER
        if main != 4:
            sub = 0
        for mode in cls:
            if mode.value == (main, sub):
                return mode
        return None

    @classmethod
    def from_custom_mode(cls, custom_mode: int) -> Px4Mode | None:
        """Decode ``HEARTBEAT.custom_mode``; None for an unknown pair."""
        return cls.from_main_sub((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)


class ParamType(enum.IntEnum):
    """The two ``MAV_PARAM_TYPE`` values PX4 uses (MAVLink's numbers: a test checks them)."""

    INT32 = 6  # MAV_PARAM_TYPE_INT32
    REAL32 = 9  # MAV_PARAM_TYPE_REAL32


@dataclass(frozen=True, slots=True)
class ParamSpec:
    """One parameter: name (<= 16 chars), type, PX4 default and, where the mock needs one to
    stay stable, the range a set must fall in (PX4's metadata range where PX4 has one)."""

    name: str
    type: ParamType
    default: float
    min: float = -math.inf
    max: float = math.inf

    def accepts(self, value: float) -> bool:
        """True if ``value`` is finite and within ``[min, max]``."""
        return math.isfinite(value) and self.min <= value <= self.max


#: The parameters the mock exposes, with PX4 v1.17 multicopter (SIH quad) defaults; these
#: defaults are the ``px4`` profile.  ``MOCK_*`` parameters are the mock's own.
PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("COM_DISARM_LAND", ParamType.REAL32, 2.0),
    ParamSpec("COM_DISARM_PRFLT", ParamType.REAL32, 10.0),
    ParamSpec("COM_FAIL_ACT_T", ParamType.REAL32, 5.0, 0.0, 25.0),
    ParamSpec("COM_LOW_BAT_ACT", ParamType.INT32, 0, 0.0, 3.0),
    ParamSpec("COM_OBL_RC_ACT", ParamType.INT32, 0),
    ParamSpec("COM_OF_LOSS_T", ParamType.REAL32, 1.0),
    ParamSpec("COM_RC_IN_MODE", ParamType.INT32, 3),
    ParamSpec("GF_ACTION", ParamType.INT32, 2),
    ParamSpec("GF_PREDICT", ParamType.INT32, 1, 0.0, 1.0),
    ParamSpec("LNDMC_TRIG_TIME", ParamType.REAL32, 1.0, 0.1, 10.0),
    ParamSpec("MC_PITCH_P", ParamType.REAL32, 4.0, 0.0, 12.0),
    ParamSpec("MC_ROLL_P", ParamType.REAL32, 4.0, 0.0, 12.0),
    ParamSpec("MC_YAWRATE_MAX", ParamType.REAL32, 200.0, 0.0, 1800.0),
    ParamSpec("MC_YAW_P", ParamType.REAL32, 2.8, 0.0, 5.0),
    ParamSpec("MIS_COMMAND_TOUT", ParamType.REAL32, 0.0, 0.0, 60.0),
    ParamSpec("MIS_MNT_YAW_CTL", ParamType.INT32, 0, 0.0, 1.0),
    ParamSpec("MIS_TAKEOFF_ALT", ParamType.REAL32, 2.5),
    ParamSpec("MPC_ACC_DOWN_MAX", ParamType.REAL32, 3.0),
    ParamSpec("MPC_ACC_HOR", ParamType.REAL32, 3.0, 2.0, 15.0),
    ParamSpec("MPC_ACC_HOR_MAX", ParamType.REAL32, 5.0),
    ParamSpec("MPC_ACC_UP_MAX", ParamType.REAL32, 4.0),
    ParamSpec("MPC_JERK_AUTO", ParamType.REAL32, 4.0, 1.0, 80.0),
    ParamSpec("MPC_LAND_ALT1", ParamType.REAL32, 10.0),
    ParamSpec("MPC_LAND_ALT2", ParamType.REAL32, 5.0),
    ParamSpec("MPC_LAND_SPEED", ParamType.REAL32, 0.7),
    ParamSpec("MPC_THR_HOVER", ParamType.REAL32, 0.5),
    ParamSpec("MPC_TILTMAX_AIR", ParamType.REAL32, 45.0, 20.0, 89.0),
    ParamSpec("MPC_TKO_RAMP_T", ParamType.REAL32, 3.0, 0.0, 10.0),
    ParamSpec("MPC_TKO_SPEED", ParamType.REAL32, 1.5),
    ParamSpec("MPC_XY_CRUISE", ParamType.REAL32, 5.0),
    ParamSpec("MPC_XY_ERR_MAX", ParamType.REAL32, 2.0, 0.1, 10.0),
    ParamSpec("MPC_XY_P", ParamType.REAL32, 0.95),
    ParamSpec("MPC_XY_TRAJ_P", ParamType.REAL32, 0.5, 0.1, 1.0),
    ParamSpec("MPC_XY_VEL_D_ACC", ParamType.REAL32, 0.2, 0.0, 2.0),
    ParamSpec("MPC_XY_VEL_I_ACC", ParamType.REAL32, 0.4),
    ParamSpec("MPC_XY_VEL_MAX", ParamType.REAL32, 12.0),
    ParamSpec("MPC_XY_VEL_P_ACC", ParamType.REAL32, 1.8),
    ParamSpec("MPC_YAWRAUTO_MAX", ParamType.REAL32, 45.0),
    ParamSpec("MPC_Z_P", ParamType.REAL32, 1.0),
    ParamSpec("MPC_Z_VEL_D_ACC", ParamType.REAL32, 0.0, 0.0, 2.0),
    ParamSpec("MPC_Z_VEL_I_ACC", ParamType.REAL32, 2.0),
    ParamSpec("MPC_Z_VEL_MAX_DN", ParamType.REAL32, 1.5),
    ParamSpec("MPC_Z_VEL_MAX_UP", ParamType.REAL32, 3.0),
    ParamSpec("MPC_Z_VEL_P_ACC", ParamType.REAL32, 4.0),
    ParamSpec("NAV_ACC_RAD", ParamType.REAL32, 2.0),
    ParamSpec("NAV_MC_ALT_RAD", ParamType.REAL32, 0.8),
    ParamSpec("RTL_RETURN_ALT", ParamType.REAL32, 60.0),
    ParamSpec("SIH_KDV", ParamType.REAL32, 1.0, 0.0, 2.0),
    ParamSpec("SIH_MASS", ParamType.REAL32, 1.0, 0.1, 100.0),
    ParamSpec("SIH_T_TAU", ParamType.REAL32, 0.05, 0.005, 1.0),
    ParamSpec("SYS_AUTOSTART", ParamType.INT32, 10040),
    # --- the mock's own: estimator error magnitudes (mavlink.mock.sim.estimator) ---
    ParamSpec("MOCK_ORG_XY_MIN", ParamType.REAL32, 0.2, 0.0, 5.0),
    ParamSpec("MOCK_ORG_XY_MAX", ParamType.REAL32, 0.4, 0.0, 5.0),
    ParamSpec("MOCK_ORG_Z_MIN", ParamType.REAL32, 0.1, 0.0, 5.0),
    ParamSpec("MOCK_ORG_Z_MAX", ParamType.REAL32, 0.6, 0.0, 5.0),
    ParamSpec("MOCK_EST_SLOW_B", ParamType.REAL32, 0.08, 0.0, 5.0),
    ParamSpec("MOCK_EST_B_TAU", ParamType.REAL32, 20.0, 0.1, 1000.0),
    ParamSpec("MOCK_EST_P_N", ParamType.REAL32, 0.02, 0.0, 1.0),
    ParamSpec("MOCK_EST_V_N", ParamType.REAL32, 0.12, 0.0, 2.0),
    ParamSpec("MOCK_EST_V_TAU", ParamType.REAL32, 0.3, 0.01, 10.0),
    ParamSpec("MOCK_EST_VB", ParamType.REAL32, 0.1, 0.0, 2.0),
    ParamSpec("MOCK_EST_VB_TAU", ParamType.REAL32, 30.0, 0.1, 1000.0),
    ParamSpec("MOCK_EST_YAW_V", ParamType.REAL32, 0.05, 0.0, 2.0),
    ParamSpec("MOCK_GE_HGT", ParamType.REAL32, 1.0, 0.0, 5.0),
    ParamSpec("MOCK_GE_RATE", ParamType.REAL32, 0.25, 0.0, 5.0),
    ParamSpec("MOCK_GE_MIN", ParamType.REAL32, 0.5, 0.0, 5.0),
    ParamSpec("MOCK_GE_MAX", ParamType.REAL32, 1.2, 0.0, 5.0),
    # --- the mock's own: which PX4 v1.17 behaviours are modelled (1) or idealised (0) ---
    ParamSpec("MOCK_PX4_NAV", ParamType.INT32, 1, 0.0, 1.0),
    # the tilt follows PX4's attitude loop (1 / MC_ROLL_P) rather than at once
    ParamSpec("MOCK_ATT_DYN", ParamType.INT32, 1, 0.0, 1.0),
    ParamSpec("MOCK_MIS_RDY_T", ParamType.REAL32, 0.09, 0.0, 5.0),
    ParamSpec("MOCK_MC_NOW", ParamType.REAL32, 0.06, 0.0, 1.0),
)

#: COM_OBL_RC_ACT values (offboard loss action).  Without an RC link the
#: manual modes (0 position, 1 altitude, 2 manual) fall back to Hold, as PX4's
#: failsafe state machine does.
OBL_ACTION_MODES: dict[int, Px4Mode | None] = {
    0: Px4Mode.AUTO_LOITER,
    1: Px4Mode.AUTO_LOITER,
    2: Px4Mode.AUTO_LOITER,
    3: Px4Mode.AUTO_RTL,
    4: Px4Mode.AUTO_LAND,
    5: Px4Mode.AUTO_LOITER,
    6: None,  # terminate: disarm in the air
    7: None,  # disarm
}

#: GF_ACTION values (geofence breach action): 0 none, 1 warning, 2 hold,
#: 3 return, 4 terminate, 5 land.
GF_ACTION_MODES: dict[int, Px4Mode | None] = {
    2: Px4Mode.AUTO_LOITER,
    3: Px4Mode.AUTO_RTL,
    5: Px4Mode.AUTO_LAND,
}
