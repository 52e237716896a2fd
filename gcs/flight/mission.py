"""``gcs fly --mode mission``: PX4 missions flown together, on one clock, under the monitor.

The plan becomes PX4 missions timed by PX4's own laws (:func:`gcs.flight.missions.convert_plan`:
acceptance radius from the vehicle, legs re-timed against the predicted flight), which are
uploaded and read back (retried as a whole on a bad link until read back as sent, within
:class:`mavlink.mission.RetryPolicy`'s default budget). Then, in order:

1. the predicted mission robustness is checked against the plan's epsilon (refused below it
   unless ``--force``: the missions would not satisfy the spec even if flown as predicted);
2. every vehicle on the ground takes off to its start's altitude on the plan's heading
   (refused before arming if the start is too low for PX4's take-off); every vehicle is then
   sent onto its start (DO_REPOSITION) and must pass the arrival gate (within a fraction of
   the plan's margin, still, on heading, for a dwell time);
3. every mission's current item is set to the start waypoint and all vehicles are switched
   to AUTO.MISSION at one instant; each start is confirmed (heartbeat in AUTO.MISSION; a
   TEMPORARILY_REJECTED start is retried) and that instant is the plan's t = 0 for all, with
   each vehicle's skew (its confirmed start, its departure from the start waypoint against
   the prediction) reported;
4. the safety monitor of the spec's always-clauses runs as in offboard flights (expected
   mode AUTO.MISSION); progress is read from MISSION_CURRENT (PX4 reports reached items only
   as the last one processed), and the vehicles are recorded until the plan's horizon is
   covered, so the flown data is judged on the shared clock. A vehicle whose link is lost is
   not a stop: its mission flies on board, its clauses go unchecked until it is heard again,
   and the report says for how long (:attr:`mavlink.monitor_findings.MonitorStats.unheard`,
   the telemetry's gaps in :class:`gcs.flight.evaluation.FlownEvaluation`).
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from gcs.errors import GcsError

if TYPE_CHECKING:
    from gcs.flight import FlyOptions
    from gcs.flight.missions import MissionConversion
    from gcs.flight.progress import PlanStarts
    from gcs.flight.tuning import VehicleTuning
    from mavlink.link.fleet import Fleet
    from mavlink.mission import CaptureSpan, MissionRun
    from mavlink.monitor_findings import MonitorStats, SafetyEvent
    from planner.planfile import Plan

#: Seconds after the plan's horizon a mission may still take before it is given up.
MISSION_SLACK_S = 30.0


@dataclass(frozen=True, slots=True, eq=False)
class MissionFlight:
    """What mission mode did (beside the tracks, which :func:`gcs.flight.fly_plan` keeps).

    Attributes:
        conversion: the missions and their predicted flight.
        runs: per vehicle what it reported (MISSION_CURRENT, reached items, finished).
        t0_monotonic_s: the shared start (plan t = 0).
        start_skew_s: per vehicle, its confirmed start minus the shared one.
        departure_skew_s: per vehicle, when it left the start waypoint minus when the
            prediction left it (``None``: never left).
        late_s: per vehicle, its finish minus the plan's last arrival (``inf``: unfinished).
        safety_event: what the monitor stopped, if it did.
        monitor: what the monitor did (evaluations, vehicles checked on their prediction).
    """

    conversion: MissionConversion
    runs: dict[str, MissionRun]
    t0_monotonic_s: float
    start_skew_s: dict[str, float]
    departure_skew_s: dict[str, float | None]
    late_s: dict[str, float]
    safety_event: SafetyEvent | None = None
    monitor: MonitorStats | None = None
    notes: list[str] = field(default_factory=list)


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


async def fly_mission_plan(
    fleet: Fleet,
    plan: Plan,
    opts: FlyOptions,
    starts: PlanStarts,
    tuning: dict[str, VehicleTuning],
    spans: Mapping[str, Sequence[CaptureSpan]],
    note: Callable[[str], None] | None = None,
) -> MissionFlight:
    """Mission mode (module docstring); ``spans``: where each vehicle's camera takes pictures
    (:func:`gcs.flight.payload.capture_spans`), camera items in its mission; ``note``: one
    line for the operator (a link lost and ridden out, heard again).

    Raises:
        MissionRefused: predicted robustness below epsilon without ``force``.
        mavlink.errors.PreflightError: a vehicle too far from its start, too low to take
            off, not settling at its start, or refusing its mission start.
        mavlink.errors.LinkError: a transfer or link failure before the flight.
    """
    from gcs.flight.evaluation import reads_heading
    from gcs.flight.missions import convert_plan_apart, timing_summary
    from mavlink.errors import PreflightError
    from mavlink.mission import (
        MissionEnd,
        MissionFollower,
        start_mission_confirmed,
        upload_with_retries,
    )
    from mavlink.monitor import SafetyMonitor, safe_stop
    from mavlink.monitor_findings import SafetyAction, always_clauses
    from mavlink.preflight import (
        TAKEOFF_MARGIN_M,
        check_start,
        check_takeoff_height,
        wait_settled,
    )
    from mavlink.px4_modes import Px4Mode
    from planner.frames import enu_to_geodetic, enu_to_ned

    names = [v.name for v in plan.vehicles]
    vehicles = [fleet[n] for n in names]
    origins = await fleet.origins()
    await asyncio.gather(
        *(
            v.wait_for(
                lambda s: (
                    s.pos_ned_m is not None and s.armed is not None and s.position is not None
                ),
                "local and global position",
                timeout_s=5.0,
            )
            for v in vehicles
        )
    )
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
    start_enu = {pv.name: np.asarray(pv.start_enu_m, dtype=float) for pv in plan.vehicles}
    start_ned = {n: enu_to_ned(start_enu[n], plan.origin, origins[n]) for n in names}
    yaw0 = {n: float(conv.missions[n].items[1].param4) for n in names}
    # Refuse before anything is armed.
    on_ground = []
    for v in vehicles:
        st = v.status()
        airborne = bool(st.armed and st.in_air)
        check_start(
            st,
            start_ned[v.name],
            tolerance_m=opts.tolerance_m,
            on_ground=not airborne,
            mission_origin=plan.origin,
            vehicle_origin=origins[v.name],
        )
        if not airborne:
            alt = float(np.ravel(enu_to_geodetic(start_enu[v.name], plan.origin)[2])[0])
            await check_takeoff_height(v, alt, TAKEOFF_MARGIN_M)
            on_ground.append(v)
    # retried as a whole on a bad link, within the default budget, until read back as sent
    await asyncio.gather(*(upload_with_retries(v, conv.missions[v.name].items) for v in vehicles))

    async def to_start(v: Any) -> None:
        lat, lon, alt = (
            float(np.ravel(x)[0]) for x in enu_to_geodetic(start_enu[v.name], plan.origin)
        )
        if v in on_ground:
            await v.arm()
            await v.takeoff_to(alt, yaw0[v.name])
            await v.wait_for(
                lambda s: (
                    bool(s.in_air)
                    and s.mode is Px4Mode.AUTO_LOITER
                    and s.pos_ned_m is not None
                    and abs(s.pos_ned_m[2] - start_ned[v.name][2]) <= 1.0
                ),
                "airborne near the start altitude after takeoff",
                timeout_s=30.0,
            )
        await v.goto(lat, lon, alt, yaw0[v.name])
        await wait_settled(
            v,
            start_ned[v.name],
            arrive_m=opts.arrive_m or arrive_gate_m(plan),
            settle_speed_m_s=0.3,
            dwell_s=1.0,
            timeout_s=30.0,
            yaw_deg=yaw0[v.name],
        )

    results = await asyncio.gather(*(to_start(v) for v in vehicles), return_exceptions=True)
    errors = [r for r in results if isinstance(r, BaseException)]
    if errors:
        await fleet.for_each(lambda v: safe_stop(v, SafetyAction.HOLD), vehicles)
        for other in errors[1:]:
            errors[0].add_note(f"also: {other}")
        raise errors[0]

    # Release: the start waypoint is current; all switch to AUTO.MISSION at one instant.
    # (The tracks start before it, so they cover the plan's t = 0.)
    for v in vehicles:
        v.start_track()
    await asyncio.gather(*(v.set_current_item(1) for v in vehicles))
    follower = MissionFollower(vehicles)
    follower.attach()
    await fleet.clock.sleep(0.2)
    t_release = fleet.clock.monotonic()
    follower.t_start = t_release
    started = await asyncio.gather(*(start_mission_confirmed(v, climb_m=None) for v in vehicles))
    refused = [s for s in started if not s.started]
    if refused:
        follower.detach()
        await fleet.for_each(lambda v: safe_stop(v, SafetyAction.HOLD), vehicles)
        s = refused[0]
        raise PreflightError(f"mission start did not take effect: {s.detail}", vehicle=s.vehicle)
    t_ok = {s.vehicle: s.t_accepted_monotonic_s for s in started}
    t0 = float(np.median(list(t_ok.values())))
    follower.t_start = t0
    starts.t0_monotonic_s.update(dict.fromkeys(names, t0))
    stop = asyncio.Event()
    clauses = always_clauses(_formula(plan), names, reads_heading) if opts.monitor else ()
    # A lost link is ridden out: the missions fly on board (PX4's NAV_DLL_ACT 0, its default:
    # no data-link failsafe), the ground station checks the others meanwhile and judges the
    # whole flight from what it heard (the report says what it missed).
    monitor = SafetyMonitor(
        clauses, horizon_s=0.5 if opts.monitor else 0.0, ride_out_link_loss=True, on_warning=note
    )
    mon_task = asyncio.create_task(
        monitor.run(
            fleet,
            vehicles,
            t0_monotonic_s=t0,
            mission_origin=plan.origin,
            origins=origins,
            stop=stop,
            plans=None,
            expected_mode=Px4Mode.AUTO_MISSION,
            mode_grace_s=1.5,
            # PX4 leaves AUTO.MISSION itself at the end: AUTO.RTL on a return item,
            # AUTO.LOITER where a mission without a landing ends
            done=follower.at_end,
        )
    )
    try:
        done = await follower.until_finished(
            timeout_s=plan.horizon_s + MISSION_SLACK_S - (fleet.clock.monotonic() - t0), stop=stop
        )
        # Keep recording until the horizon is covered (a mission may end before it).
        t_end = t0 + plan.horizon_s + 0.5
        while fleet.clock.monotonic() < t_end and not stop.is_set():
            await fleet.clock.sleep(0.1)
    finally:
        stop.set()
        event = await mon_task
        follower.detach()
    now = fleet.clock.monotonic() - t0
    runs = {n: follower.run(n, finished=n in done, duration_s=done.get(n, now)) for n in names}
    pred = conv.prediction
    dep = {}
    late = {}
    for n in names:
        left = runs[n].left_s(1)
        want = pred.left_s[n].get(1)
        dep[n] = None if left is None or want is None else left - want
        m = conv.missions[n]
        late[n] = done[n] - float(m.arrival_t_s[-1] + m.hold_s[-1]) if n in done else math.inf
    return MissionFlight(
        conversion=conv,
        runs=runs,
        t0_monotonic_s=t0,
        start_skew_s={n: t_ok[n] - t0 for n in names},
        departure_skew_s=dep,
        late_s=late,
        safety_event=event,
        monitor=monitor.stats,
    )


def arrive_gate_m(plan: Plan) -> float:
    """The arrival gate for the starts: half the plan's margin, within [0.1, 0.3] m."""
    return float(min(0.3, max(0.1, 0.5 * plan.robustness)))


def _formula(plan: Plan) -> Any:
    from gcs.flight.evaluation import plan_formula

    return plan_formula(plan)
