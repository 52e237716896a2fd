"""``gcs fly --mode mission``: the plan as PX4 missions, checked before they fly.

The plan becomes PX4 missions timed by PX4's own laws (:func:`gcs.flight.missions.convert_plan`:
acceptance radius from the vehicle, legs re-timed against the predicted flight, in a child
process while the link's callbacks go on). Missions whose predicted robustness is below the
plan's epsilon are refused unless ``--force`` (they would not satisfy the spec even if flown
as predicted). The missions are then flown by the flight engine shared with offboard
(:func:`mavlink.flight.fly` with a :class:`mavlink.mission.flight.MissionDriver`: checks,
upload and read-back, take-off, the arrival gate at the starts, one release into
AUTO.MISSION, the monitor, the flown record); :func:`mission_record` says how each vehicle
kept the predicted clock.

A vehicle whose link is lost is not a stop: its mission flies on board, its clauses go
unchecked until it is heard again, and the report says for how long
(:attr:`mavlink.monitor_findings.MonitorStats.unheard`, the telemetry's gaps in
:class:`gcs.flight.evaluation.FlownEvaluation`).
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gcs.errors import GcsError
from gcs.flight.missions import convert_plan_apart, timing_summary
from mavlink.flight import StartGate
from mavlink.mission import MissionEnd
from mavlink.mission.flight import START_ITEM, MissionDriver
from planner.frames import yaw_enu_to_ned

if TYPE_CHECKING:
    from gcs.flight import FlyOptions
    from gcs.flight.missions import MissionConversion
    from gcs.flight.tuning import VehicleTuning
    from mavlink.flight import FlightResult, StartGate
    from mavlink.link.fleet import Fleet
    from mavlink.mission import CaptureSpan
    from mavlink.mission.flight import MissionDriver
    from planner.planfile import Plan


@dataclass(frozen=True, slots=True, eq=False)
class MissionFlight:
    """How mission mode kept the predicted clock (the rest is in the flight's result).

    Attributes:
        conversion: the missions and their predicted flight.
        start_skew_s: per vehicle, its confirmed start minus the shared one.
        departure_skew_s: per vehicle, when it left the start waypoint minus when the
            prediction left it (``None``: never left).
        late_s: per vehicle, its finish minus the plan's last arrival (``inf``: unfinished).
    """

    conversion: MissionConversion
    start_skew_s: dict[str, float]
    departure_skew_s: dict[str, float | None]
    late_s: dict[str, float]


class MissionRefused(GcsError):
    """The predicted mission robustness is below the plan's epsilon (no ``--force``)."""


def prediction_params(
    tuning: dict[str, VehicleTuning], known: dict[str, float]
) -> dict[str, float]:
    """PX4 parameters for the prediction: the vehicles' own where read, their drag as SIH's."""
    prm = dict(known)
    drags = [t.drag_per_s for t in tuning.values()]
    if drags:
        prm["SIH_KDV"] = float(np.mean(drags))
        prm["SIH_MASS"] = 1.0
        first = next(iter(tuning.values()))
        prm["MPC_XY_P"] = first.xy_p
        prm["MPC_XY_VEL_P_ACC"] = first.vel_p
    return prm


async def read_nav_params(fleet: Fleet, name: str) -> dict[str, float]:
    """The navigator parameters of one vehicle that the prediction uses (those it reports)."""
    names = ("NAV_ACC_RAD", "NAV_MC_ALT_RAD", "MPC_XY_CRUISE", "MPC_ACC_HOR", "MPC_JERK_AUTO",
             "MPC_XY_TRAJ_P", "MPC_Z_VEL_MAX_UP", "MPC_Z_VEL_MAX_DN")  # fmt: skip
    v = fleet[name]
    values = await asyncio.gather(*(v.param(n, timeout_s=0.5, retries=2) for n in names))
    return {n: float(x) for n, x in zip(names, values, strict=True) if x is not None}


def mission_gate(plan: Plan, tolerance_m: float, arrive_m: float | None = None) -> StartGate:
    """The start gate of a mission flight: refuse a vehicle farther than ``tolerance_m`` from
    its start; the arrival gate ``arrive_m`` (default :func:`arrive_gate_m`), with 30 s to
    get there (a reposition in Hold, at PX4's own speed)."""

    return StartGate(
        start_tolerance_m=tolerance_m,
        arrive_m=arrive_m or arrive_gate_m(plan),
        arrive_timeout_s=30.0,
    )


def missions_driver(
    plan: Plan, gate: StartGate, conv: MissionConversion | None = None
) -> MissionDriver:
    """The flight engine's driver for the plan's missions: ``conv``'s, uploaded first; without
    one, the missions are on the vehicles already (``gcs upload`` sent them). Each vehicle
    starts where its plan does, on the plan's heading there (the start waypoint's)."""

    return MissionDriver(
        starts_enu_m={pv.name: np.asarray(pv.start_enu_m, dtype=float) for pv in plan.vehicles},
        yaw_deg={
            pv.name: math.degrees(float(yaw_enu_to_ned(pv.trajectory.yaw_rad(np.zeros(1)))[0]))
            for pv in plan.vehicles
        },
        mission_origin=plan.origin,
        horizon_s=plan.horizon_s,
        gate=gate,
        items=None if conv is None else {n: m.items for n, m in conv.missions.items()},
    )


async def mission_driver(
    fleet: Fleet,
    plan: Plan,
    opts: FlyOptions,
    tuning: dict[str, VehicleTuning],
    spans: Mapping[str, Sequence[CaptureSpan]],
    note: Callable[[str], None] | None = None,
) -> tuple[MissionDriver, MissionConversion]:
    """The plan's missions, converted with the vehicles' parameters, ready to fly; ``spans``:
    where each vehicle's camera takes pictures (:func:`gcs.flight.payload.capture_spans`),
    camera items in its mission; ``note``: one line for the operator.

    Raises:
        MissionRefused: predicted robustness below epsilon without ``force``.
    """

    names = [v.name for v in plan.vehicles]
    known = await read_nav_params(fleet, names[0])
    end = MissionEnd(opts.end.value) if opts.end is not None else MissionEnd.HOLD
    # In a child process: the link's callbacks go on meanwhile.
    conv = await convert_plan_apart(
        plan,
        end=end,
        acceptance_m=opts.acceptance_m,
        params=prediction_params(tuning, known),
        captures=spans,
    )
    if conv.predicted_robustness < plan.epsilon and not opts.force:
        raise MissionRefused(
            f"refused: PX4 is predicted to fly these missions with robustness "
            f"{conv.predicted_robustness:+.3f} < epsilon {plan.epsilon:g} (plan "
            f"{plan.robustness:+.3f}; weakest: {conv.weakest}; "
            f"{timing_summary(conv.late_s)}); fly offboard (gcs fly), or --force"
        )
    if conv.tolerance_warning() and note is not None:
        note(conv.tolerance_warning())
    driver = missions_driver(plan, mission_gate(plan, opts.tolerance_m, opts.arrive_m), conv)
    return driver, conv


def mission_record(conv: MissionConversion, result: FlightResult) -> MissionFlight:
    """How each vehicle of a flown mission kept the predicted clock."""

    dep: dict[str, float | None] = {}
    late: dict[str, float] = {}
    for n, run in result.runs.items():
        left = run.left_s(START_ITEM)
        want = conv.prediction.left_s[n].get(START_ITEM)
        dep[n] = None if left is None or want is None else left - want
        m = conv.missions[n]
        end = float(m.arrival_t_s[-1] + m.hold_s[-1])
        late[n] = run.duration_s - end if run.finished else math.inf
    return MissionFlight(
        conversion=conv,
        start_skew_s=dict(result.start_skew_s),
        departure_skew_s=dep,
        late_s=late,
    )


def arrive_gate_m(plan: Plan) -> float:
    """The arrival gate for the starts: half the plan's margin, within [0.1, 0.3] m."""
    return float(min(0.3, max(0.1, 0.5 * plan.robustness)))
