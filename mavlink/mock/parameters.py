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
from typing import Any, TypeAlias

from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import px4
from mavlink.mock.estimator import EstimatorParams
from mavlink.mock.parts import VehicleParts
from mavlink.mock.physics import GRAVITY_M_S2
from mavlink.mock.px4 import Px4Mode

#: A pymavlink message (its fields are per message type: untyped to mypy).
Msg: TypeAlias = Any


class ParametersMixin(VehicleParts):
    """Parameter protocol and parameter effects of :class:`~mavlink.mock.vehicle.MockVehicle`."""

    def _apply_params(self) -> None:
        i, p, prm = self.index, self.phys, self.params
        p.kp_pos[i] = (prm["MPC_XY_P"], prm["MPC_XY_P"], prm["MPC_Z_P"])
        p.kp_vel[i] = (prm["MPC_XY_VEL_P_ACC"], prm["MPC_XY_VEL_P_ACC"], prm["MPC_Z_VEL_P_ACC"])
        p.ki_vel[i] = (prm["MPC_XY_VEL_I_ACC"], prm["MPC_XY_VEL_I_ACC"], prm["MPC_Z_VEL_I_ACC"])
        p.kd_vel[i] = (prm["MPC_XY_VEL_D_ACC"], prm["MPC_XY_VEL_D_ACC"], prm["MPC_Z_VEL_D_ACC"])
        p.kdv_per_s[i] = prm["SIH_KDV"] / prm["SIH_MASS"]  # SIH: force per m/s over mass
        p.yaw_p[i] = prm["MC_YAW_P"]
        # the tilt follows PX4's attitude loop (1 / MC_ROLL_P, MC_PITCH_P: the slower one)
        gain = min(prm["MC_ROLL_P"], prm["MC_PITCH_P"])
        p.att_tau_s[i] = 1.0 / gain if prm["MOCK_ATT_DYN"] >= 0.5 and gain > 0.0 else 0.0
        p.set_thrust_tau(i, prm["SIH_T_TAU"])
        p.estimator.configure(i, EstimatorParams.from_params(prm), new_boot=False)
        self._apply_limits()

    @property
    def px4_nav(self) -> bool:
        """True when PX4 v1.17's navigator, take-off and storage are modelled (MOCK_PX4_NAV)."""
        return self.params["MOCK_PX4_NAV"] >= 0.5

    def _apply_limits(self) -> None:
        """Speed/acceleration limits of the current mode from the parameters."""
        i, p, prm = self.index, self.phys, self.params
        auto = self.mode.value[0] == 4
        p.vel_xy_max_m_s[i] = (
            min(self.cruise_speed_m_s, prm["MPC_XY_VEL_MAX"]) if auto else prm["MPC_XY_VEL_MAX"]
        )
        self._vel_up_base = (
            prm["MPC_TKO_SPEED"] if self.mode is Px4Mode.AUTO_TAKEOFF else prm["MPC_Z_VEL_MAX_UP"]
        )
        p.vel_up_max_m_s[i] = self._vel_up_base
        p.vel_dn_max_m_s[i] = prm["MPC_Z_VEL_MAX_DN"]
        if self.px4_nav:
            # PX4's position controller limits the acceleration only by the tilt; the
            # trajectory generators of the auto modes respect MPC_ACC_HOR themselves
            p.acc_xy_max_m_s2[i] = GRAVITY_M_S2 * math.tan(math.radians(prm["MPC_TILTMAX_AIR"]))
        else:
            p.acc_xy_max_m_s2[i] = prm["MPC_ACC_HOR"] if auto else prm["MPC_ACC_HOR_MAX"]
        p.acc_up_max_m_s2[i] = prm["MPC_ACC_UP_MAX"]
        p.acc_dn_max_m_s2[i] = prm["MPC_ACC_DOWN_MAX"]
        yaw_max = (
            prm["MC_YAWRATE_MAX"] if self.mode is Px4Mode.OFFBOARD else prm["MPC_YAWRAUTO_MAX"]
        )
        p.yaw_rate_max_rad_s[i] = math.radians(yaw_max)

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
