"""Faults injected into one mock vehicle on its plan's clock (``gcs fly --dry-run --mock-fault
VEHICLE:KIND@T``): a component of :class:`mavlink.mock.vehicle.MockVehicle`, ticked with it.

The clock is the flight's plan clock: :meth:`PlanFaults.start` gives it the plan's start on the
simulation's clock (the ground station's shared start, the stream's or the missions' release:
a dry run passes it on through :meth:`mavlink.mock.MockFleet.plan_started`). ``T`` seconds
later:

* ``lost``: the vehicle's link goes silent for good in both directions (a radio out of range,
  a dead telemetry module). PX4 flies on: in offboard its offboard-loss failsafe takes over
  after ``COM_OF_LOSS_T`` (``COM_OBL_RC_ACT``: Hold by default), a mission goes on (the
  data-link-loss failsafe, ``NAV_DLL_ACT``, is off by default in PX4 v1.17).
* ``failsafe``: a failsafe the plan did not foresee (a sensor, the RC link) switches the
  vehicle to Return, announced "Failsafe activated", as PX4's failsafes that cannot be
  deferred do (the mock's geofence breach the same way).
* ``battery``: the battery's charge falls to 6 %, below PX4's critical threshold
  (``BAT_CRIT_THR`` 7 %, above ``BAT_EMERGEN_THR`` 5 %): BATTERY_STATUS says so
  (``MAV_BATTERY_CHARGE_STATE_CRITICAL``), PX4 logs "Critical battery", and acts as
  ``COM_LOW_BAT_ACT`` says: 0 (PX4 v1.17's default) a warning only, 2 Land, 3 Return; a
  Land or Return after holding for ``COM_FAIL_ACT_T`` (5 s) first, for the pilot to react
  (PX4 v1.17: ``commander/failsafe/failsafe.cpp``, ``commander_params.c``,
  ``lib/battery/module.yaml``).

What fired and when (plan time) is kept in :attr:`PlanFaults.fired`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock.sim.config import Outage
from mavlink.mock.sim.errors import MockConfigError
from mavlink.mock.sim.px4 import Px4Mode

if TYPE_CHECKING:
    from mavlink.mock.vehicle import MockVehicle

__all__ = ["CRITICAL_PCT", "FAULT_KINDS", "PlanFaults", "VehicleFault"]

#: The kinds of fault (module docstring).
FAULT_KINDS = ("lost", "failsafe", "battery")
#: The battery's charge after a ``battery`` fault (%): below BAT_CRIT_THR, above
#: BAT_EMERGEN_THR.
CRITICAL_PCT = 6.0
#: COM_LOW_BAT_ACT values that act (2 Land, 3 Return at critical level).
_BATTERY_ACTIONS = {2: Px4Mode.AUTO_LAND, 3: Px4Mode.AUTO_RTL}


@dataclass(frozen=True, slots=True)
class VehicleFault:
    """``kind`` (:data:`FAULT_KINDS`) at ``at_s`` seconds of the vehicle's plan."""

    kind: str
    at_s: float

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise MockConfigError(f"unknown fault {self.kind!r} (choose {', '.join(FAULT_KINDS)})")
        if not (math.isfinite(self.at_s) and self.at_s >= 0.0):
            raise MockConfigError(
                f"a fault's time must be a number of seconds >= 0, got {self.at_s!r}"
            )


class PlanFaults:
    """The faults of one vehicle, fired on its plan's clock (module docstring)."""

    def __init__(self, faults: Sequence[VehicleFault] = ()) -> None:
        self.pending = sorted(faults, key=lambda f: f.at_s)
        #: simulation time the plan started (None: not yet)
        self.t0_s: float | None = None
        #: (fault, plan time it fired at)
        self.fired: list[tuple[VehicleFault, float]] = []
        self._later: list[tuple[float, Callable[[], None]]] = []

    def add(self, fault: VehicleFault) -> None:
        self.pending = sorted([*self.pending, fault], key=lambda f: f.at_s)

    def start(self, t0_s: float) -> None:
        """The plan started at ``t0_s`` (simulation time); the first call counts."""
        if self.t0_s is None:
            self.t0_s = t0_s

    def tick(self, v: MockVehicle, now: float) -> None:
        if (not self.pending and not self._later) or self.t0_s is None:
            return
        while self.pending and now >= self.t0_s + self.pending[0].at_s:
            fault = self.pending.pop(0)
            self.fired.append((fault, now - self.t0_s))
            self._fire(v, fault, now)
        due = [a for t, a in self._later if t <= now]
        self._later = [(t, a) for t, a in self._later if t > now]
        for action in due:
            action()

    def _fire(self, v: MockVehicle, fault: VehicleFault, now: float) -> None:
        if fault.kind == "lost":
            faults = v.config.faults
            silent = Outage(now, math.inf)
            v.fleet.configure_links(v, replace(faults, outages=(*faults.outages, silent)))
        elif fault.kind == "failsafe":
            if not v.armed:  # on the ground already: nothing to return from
                return
            v.failsafe = True
            v.statustext(mavlink2.MAV_SEVERITY_CRITICAL, "Failsafe activated")
            v.set_mode(Px4Mode.AUTO_RTL)
        else:
            v.battery_override_pct = CRITICAL_PCT
            v.statustext(mavlink2.MAV_SEVERITY_CRITICAL, "Critical battery")
            mode = _BATTERY_ACTIONS.get(int(v.params.get("COM_LOW_BAT_ACT", 0)))
            if mode is None or not v.armed:
                return
            v.failsafe = True
            v.statustext(mavlink2.MAV_SEVERITY_CRITICAL, "Failsafe activated")
            wait = float(v.params.get("COM_FAIL_ACT_T", 5.0))
            if wait <= 0.0:
                v.set_mode(mode)
                return
            v.set_mode(Px4Mode.AUTO_LOITER)

            def act() -> None:
                if v.armed and v.failsafe and v.mode is Px4Mode.AUTO_LOITER:
                    v.set_mode(mode)

            self._later.append((now + wait, act))
