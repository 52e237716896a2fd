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

from typing import Any, TypeAlias

from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import px4
from mavlink.mock.parts import VehicleParts
from mavlink.mock.sim.estimator import EstimatorParams
from mavlink.mock.sim.params import (
    apply_controller_params,
    apply_limits,
    mode_limits,
)

#: A pymavlink message (its fields are per message type: untyped to mypy).
Msg: TypeAlias = Any


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
