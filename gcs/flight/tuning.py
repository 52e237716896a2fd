"""What the ground station knows of each vehicle's tracking: drag, lag, estimator accuracy.

PX4's position controller does not model aerodynamic drag, so a vehicle settles
``c / (MPC_XY_P * MPC_XY_VEL_P_ACC)`` seconds behind a moving setpoint (0.585 s for SIH's
quad, ``c`` = 1/s: docs/px4-behaviour.md). Adding ``c * v`` to the acceleration feed-forward
removes that lag (:func:`mavlink.plan_setpoints.plan_setpoints_ned`). ``c`` comes from, in order:
the user (``--drag``), the simulator's own parameters (SIH_KDV / SIH_MASS, when the vehicle
has them), or nothing (0). After a flight, :func:`drag_from_lag` turns the lag each vehicle
really showed into the drag that would have removed it, which is what to pass as ``--drag``.

The estimator's own error is not removable: ESTIMATOR_STATUS reports its accuracy, and the
margins a plan needs are judged against that and the expected tracking error
(:func:`margin_warnings`).
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from mavlink.link.fleet import Fleet
    from mavlink.link.vehicle import Vehicle
    from planner.planfile import Plan

#: PX4 v1.17 defaults, used where a vehicle does not report its parameters.
PX4_GAINS = {"MPC_XY_P": 0.95, "MPC_XY_VEL_P_ACC": 1.8}
#: Lag left after the drag feed-forward that is not worth re-tuning for (s).
LAG_NOISE_S = 0.08
#: The estimator accuracy assumed when the vehicle reports none (PX4 on SIH: 0.1-0.6 m).
DEFAULT_ACCURACY_M = 0.3


@dataclass(frozen=True, slots=True)
class VehicleTuning:
    """One vehicle's tracking model.

    Attributes:
        vehicle: name.
        drag_per_s: the drag per unit mass used for the feed-forward (1/s).
        drag_source: where it came from (``"--drag"``, ``"SIH_KDV/SIH_MASS"``, ``"none"``).
        xy_p, vel_p: MPC_XY_P and MPC_XY_VEL_P_ACC (the vehicle's, or PX4's defaults).
        accuracy_m: the estimator's reported horizontal position accuracy (m), if any.
    """

    vehicle: str
    drag_per_s: float
    drag_source: str
    xy_p: float
    vel_p: float
    accuracy_m: float | None = None

    @property
    def expected_lag_s(self) -> float:
        """Lag from the drag the vehicle really has, were it not fed forward (s)."""
        return drag_lag_s(self.drag_per_s, self.xy_p, self.vel_p)


def drag_lag_s(drag_per_s: float, xy_p: float, vel_p: float) -> float:
    """PX4's steady lag behind a moving setpoint from drag: ``c / (MPC_XY_P *
    MPC_XY_VEL_P_ACC)`` (0.585 s for SIH's quad); 0 for non-positive gains."""
    return float(drag_per_s / (xy_p * vel_p)) if xy_p > 0 and vel_p > 0 else 0.0


def drag_from_lag(lag_s: float, tuning: VehicleTuning) -> float:
    """The drag (1/s) that would have removed a measured steady lag: what was fed forward
    plus ``lag * MPC_XY_P * MPC_XY_VEL_P_ACC`` (PX4's steady-state lag, inverted)."""
    return max(0.0, tuning.drag_per_s + lag_s * tuning.xy_p * tuning.vel_p)


async def _one(v: Vehicle, drag_per_s: float | None) -> VehicleTuning:
    p, d = await asyncio.gather(
        v.param("MPC_XY_P", timeout_s=0.5, retries=2),
        v.param("MPC_XY_VEL_P_ACC", timeout_s=0.5, retries=2),
    )
    xy_p = p if p is not None and p > 0 else PX4_GAINS["MPC_XY_P"]
    vel_p = d if d is not None and d > 0 else PX4_GAINS["MPC_XY_VEL_P_ACC"]
    acc = v.position_accuracy_m
    accuracy = acc[0] if acc is not None and math.isfinite(acc[0]) else None
    if drag_per_s is not None:
        return VehicleTuning(v.name, float(drag_per_s), "--drag", xy_p, vel_p, accuracy)
    kdv = await v.param("SIH_KDV", timeout_s=0.5, retries=2)
    if kdv is None:
        return VehicleTuning(v.name, 0.0, "none", xy_p, vel_p, accuracy)
    mass = await v.param("SIH_MASS", timeout_s=0.5, retries=2)
    mass = mass if mass is not None and mass > 0 else 1.0
    return VehicleTuning(v.name, kdv / mass, "SIH_KDV/SIH_MASS", xy_p, vel_p, accuracy)


async def read_tuning(
    fleet: Fleet, names: Sequence[str], drag_per_s: float | None
) -> dict[str, VehicleTuning]:
    """Each vehicle's tracking model (module docstring); ``drag_per_s`` from the user wins."""
    rows = await asyncio.gather(*(_one(fleet[n], drag_per_s) for n in names))
    return {t.vehicle: t for t in rows}


def peak_speed_m_s(plan: Plan) -> dict[str, float]:
    """Each vehicle's fastest planned speed (m/s), on the plan's check grid."""

    out = {}
    for pv in plan.vehicles:
        t = np.arange(0.0, pv.trajectory.duration_s + 1e-9, plan.check_dt_s)
        out[pv.name] = float(np.linalg.norm(pv.trajectory.velocity(t), axis=1).max())
    return out


def expected_error_m(
    plan: Plan, tuning: Mapping[str, VehicleTuning], *, fed_forward: bool
) -> dict[str, float]:
    """Expected worst position error per vehicle (m): the estimator's accuracy plus the
    drag lag's distance at the peak speed when the drag is not fed forward (with it, a
    residual of :data:`LAG_NOISE_S` at that speed)."""
    speed = peak_speed_m_s(plan)
    out = {}
    for name, tu in tuning.items():
        lag = LAG_NOISE_S if fed_forward and tu.drag_per_s > 0 else tu.expected_lag_s
        acc = tu.accuracy_m if tu.accuracy_m is not None else DEFAULT_ACCURACY_M
        out[name] = acc + max(lag, LAG_NOISE_S) * speed.get(name, 0.0)
    return out


def margin_warnings(plan: Plan, expected_m: Mapping[str, float]) -> list[str]:
    """One line per vehicle whose expected error exceeds the plan's margin (its robustness)."""
    out = []
    for name, err in expected_m.items():
        if err > plan.robustness:
            out.append(
                f"warning: {name}: expected position error {err:.2f} m (estimator accuracy "
                f"and tracking lag) exceeds the plan's margin {plan.robustness:+.2f} m: the "
                "flight can violate the spec while flying the plan correctly"
            )
    return out


#: NAV_MC_ALT_RAD (PX4 default) plus the margin the ground station keeps for a take-off.
TAKEOFF_MIN_M = 0.8 + 0.2  # mavlink.preflight.TAKEOFF_MARGIN_M


def px4_notes(plan: Plan) -> list[str]:
    """What to expect of ``plan`` on PX4 before any vehicle is known (``gcs plan``): the
    margin against PX4-on-SIH's position errors with the drag fed forward, and starts too
    low for PX4's take-off from the ground (the mission frame's z = 0, or the plan's
    terrain)."""
    speed = peak_speed_m_s(plan)
    notes = []
    worst = max(speed, key=lambda n: speed[n])
    err = DEFAULT_ACCURACY_M + LAG_NOISE_S * speed[worst]
    if err > plan.robustness:
        notes.append(
            f"note: on PX4 expect position errors of about {err:.2f} m (estimator ~"
            f"{DEFAULT_ACCURACY_M:g} m, residual lag at {speed[worst]:.1f} m/s), more than the "
            f"plan's margin {plan.robustness:+.3f} m: a flight can violate the spec while "
            "tracking the plan"
        )
    where = "z = 0" if plan.terrain is None else "the ground"
    low = [
        pv.name
        for pv, ground in zip(plan.vehicles, plan.ground_spawns(), strict=True)
        if pv.start_enu_m[2] - ground[2] <= TAKEOFF_MIN_M
    ]
    if low:
        notes.append(
            f"note: {', '.join(low)} start at or below {TAKEOFF_MIN_M:g} m above {where}: PX4 "
            "takes off only to more than NAV_MC_ALT_RAD (0.8 m) above the vehicle, so from the "
            "ground there gcs fly / upload --start refuse them (start in the air, or higher)"
        )
    return notes
