"""A plan as PX4 missions that keep the plan's clock, and what PX4 will make of them.

:func:`mavlink.mission.trajectory_to_mission` turns a trajectory into straight legs, each
commanded at its average speed. PX4 does not fly those at constant speed: it accelerates
and brakes within MPC_ACC_HOR / MPC_JERK_AUTO, slows for corners and stops before holds,
lags its own setpoint by the drag (docs/px4-sitl.md), and (what made the power line's missions
5-16 m late on PX4 SITL) it looks one waypoint ahead only: the speed at a waypoint is at most
the speed from which it could stop at the next one (PX4's ``TrajectoryConstraints.hpp``), so a
waypoint every 2 s segment, 7.5 m apart, holds a 3.75 m/s plan to about 3.6 m/s at every one.

:func:`convert_plan` searches for missions PX4 is predicted to fly on the plan's clock:

1. candidates: the waypoints simplified (:func:`mavlink.mission.keep_waypoints`: those a
   leg flown straight at constant speed may skip while it stays within a quarter, then a
   half, of the plan's margin at every instant; every hover and every waypoint where pictures
   are taken stays), then every waypoint; each with PX4's NAV_ACC_RAD, the radius chosen from
   the plan's speeds (:func:`auto_acceptance_m`) and 1.5 NAV_ACC_RAD (not where pictures are
   taken: a larger radius cuts corners);
2. each candidate is predicted with the mock's PX4 vehicle (:mod:`mavlink.mock.predict`: PX4's
   navigator laws and the drag, no estimator noise) and the spec's exact robustness computed
   on the predicted tracks;
3. and re-timed (:func:`_retimed`), up to :data:`ITERATIONS` predictions: each leg's speed is
   scaled by how long PX4 took for it against the time that puts the vehicle on the clock
   (legs into a hover aim :data:`ARRIVE_EARLY_S` early); each hold, the synchronisation point,
   is lengthened where PX4 is predicted to leave it early (never shorter than the plan's
   hover), so a vehicle that arrives early waits;
4. the search stops at the first candidate predicted :data:`GOOD_ENOUGH_M` above epsilon (what
   the prediction may miss PX4 by: docs/px4-sitl.md), or
   when :data:`BUDGET_S` is spent, and keeps the best: its predicted robustness (the honest
   "mission robustness"), each vehicle's finish against the plan's, and the straight-leg
   figure, which assumes constant leg speeds.
"""

from __future__ import annotations

import asyncio
import math
import pickle
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from gcs.flight.evaluation import plan_formula
from gcs.flight.landing import landing_targets
from gcs.flight.tuning import PX4_GAINS, drag_lag_s
from mavlink.mission import (
    MissionEnd,
    braking_distance_m,
    fence_zones,
    geofence_items,
    path_robustness,
    trajectory_to_mission,
)
from mavlink.mock.predict import predict_missions
from planner.spec.timing import time_tolerance as clause_tolerance

if TYPE_CHECKING:
    from mavlink.mission import CaptureSpan, MissionEnd, MissionPlan
    from mavlink.mock.predict import PredictedMissions
    from planner.planfile import Plan

#: PX4 v1.17 defaults the conversion assumes where the vehicle's own are not known.
PX4_DEFAULTS = {"NAV_ACC_RAD": 2.0, "MPC_XY_VEL_MAX": 12.0}
#: Cross-track error PX4 (SIH) showed per m/s of cruise: 0.3-0.5 m at 3.4 m/s (R = 0.3 m
#: was missed, 1.0 m never); twice this is the smallest radius the conversion picks.
XTRACK_S = 0.15
MIN_ACCEPTANCE_M = 0.6
#: A leg is never commanded faster than this multiple of its average speed (a
#: minimum-jerk segment peaks at 1.875 times its average).
MAX_SPEEDUP = 2.0
#: Seconds flown after the plan's horizon in a prediction (late missions are seen finishing).
PREDICT_EXTRA_S = 20.0
#: Predictions per candidate conversion at most.
ITERATIONS = 6
#: A hold is moved by this fraction of its predicted departure's error per prediction (the
#: legs before it are re-timed in the same step).
HOLD_GAIN = 0.5
#: The legs into a hover aim to arrive this early (s): the hold waits for the plan's clock.
ARRIVE_EARLY_S = 1.0
#: The largest timing error (s) :func:`time_tolerance` looks for.
TOLERANCE_MAX_S = 3.0
#: PX4 SITL kept a mission's clock to about this (s) between two vehicles of the power line
#: (docs/px4-sitl.md); a clause that tolerates less is named in the report.
KEEPS_CLOCK_S = 0.5
#: CPU seconds of predictions a conversion may spend.
BUDGET_S = 20.0
#: A candidate whose first prediction is this far below the best so far is not re-timed (m).
HOPELESS_M = 1.0
#: The search stops at the first candidate predicted this far above epsilon (m).
GOOD_ENOUGH_M = 0.3


@dataclass(frozen=True, slots=True, eq=False)
class MissionConversion:
    """The missions of a plan and their predicted flight.

    Attributes:
        missions: per vehicle the mission (items, waypoints, planned times, leg speeds).
        acceptance_m: the acceptance radius used (param2 of every waypoint).
        acceptance_auto: chosen by :func:`auto_acceptance_m` (not given by the user).
        prediction: the predicted flight of the chosen conversion (t = 0 at the release).
        predicted_robustness: the spec's exact robustness on the predicted tracks.
        straight_leg_robustness: on the constant-speed straight legs (the plan's clock).
        late_s: per vehicle, predicted finish minus the plan's last arrival (s; ``inf``
            when the prediction did not see it finish).
        iterations: predictions run.
        retimed: the leg speeds and holds were changed from the legs' average speeds and
            the plan's hovers (a re-timed prediction was the best).
        simplify_m: the tolerance of the waypoints dropped (0: a waypoint at every
            segment's end; :func:`mavlink.mission.keep_waypoints`).
        weakest: the spec's weakest clause on the predicted tracks, with its robustness.
        tolerance_s: per top-level clause, the seconds of timing error (one vehicle early or
            late, or two off the opposite ways) it tolerates on the predicted flight
            (:func:`time_tolerance`).
    """

    missions: dict[str, MissionPlan]
    acceptance_m: float
    acceptance_auto: bool
    prediction: PredictedMissions
    predicted_robustness: float
    straight_leg_robustness: float
    late_s: dict[str, float]
    iterations: int
    retimed: bool
    simplify_m: float = 0.0
    weakest: str = ""
    tolerance_s: dict[str, float] = field(default_factory=dict)

    def tolerance_warning(self) -> str:
        """One line when a clause tolerates less timing error than PX4 keeps (else "")."""
        least = self.least_tolerant()
        if least is None or least[1] >= KEEPS_CLOCK_S:
            return ""
        clause, d = least
        return (
            f"warning: on PX4's predicted flight {clause} tolerates only {d:.2f} s of timing "
            f"error (a vehicle early or late, two off the opposite ways); PX4 kept missions' "
            f"clocks to about {KEEPS_CLOCK_S:g} s between vehicles on SITL, so the safety "
            "monitor may stop the flight there (fly offboard to keep the plan's clock)"
        )

    def least_tolerant(self) -> tuple[str, float] | None:
        """The clause that tolerates the least timing error, and how much (s)."""
        if not self.tolerance_s:
            return None
        return min(self.tolerance_s.items(), key=lambda kv: kv[1])


def auto_acceptance_m(plan: Plan, nav_acc_rad_m: float = PX4_DEFAULTS["NAV_ACC_RAD"]) -> float:
    """The waypoint acceptance radius for ``plan`` on PX4 (m).

    Large enough that PX4 does not miss the circle at the plan's fastest leg (twice the
    cross-track error PX4 showed, :data:`XTRACK_S` per m/s, at least
    :data:`MIN_ACCEPTANCE_M`: a missed circle costs 18-35 s), and no larger than
    NAV_ACC_RAD, PX4's own default radius. Corner cutting that a larger radius brings is
    judged by the prediction, not here.
    """

    fastest = 0.0
    for pv in plan.vehicles:
        m = trajectory_to_mission(pv.trajectory, plan.origin, acceptance_radius_m=0.05)
        if m.leg_speed_m_s.size:
            fastest = max(fastest, float(m.leg_speed_m_s.max()))
    return float(min(nav_acc_rad_m, max(MIN_ACCEPTANCE_M, 2.0 * XTRACK_S * fastest)))


def expected_lag_s(params: Mapping[str, float]) -> float:
    """The lag of a vehicle with PX4 parameters ``params`` behind its setpoint (s):
    :func:`gcs.flight.tuning.drag_lag_s` of SIH_KDV (the drag the prediction flies with) and the
    position/velocity gains, PX4's defaults where absent."""

    return drag_lag_s(
        params.get("SIH_KDV", 1.0),
        params.get("MPC_XY_P", PX4_GAINS["MPC_XY_P"]),
        params.get("MPC_XY_VEL_P_ACC", PX4_GAINS["MPC_XY_VEL_P_ACC"]),
    )


def convert_plan(
    plan: Plan,
    *,
    end: MissionEnd,
    acceptance_m: float | None = None,
    params: Mapping[str, float] | None = None,
    iterations: int = ITERATIONS,
    retime: bool = True,
    captures: Mapping[str, Sequence[CaptureSpan]] | None = None,
    budget_s: float = BUDGET_S,
) -> MissionConversion:
    """Missions for every vehicle of ``plan``, timed so PX4 keeps the plan's clock.

    Args:
        end: what each mission ends with.
        acceptance_m: waypoint acceptance radius; ``None`` chooses it
            (:func:`auto_acceptance_m` with the vehicles' NAV_ACC_RAD), and tries the larger
            radii of :func:`radius_candidates` too.
        params: the vehicles' PX4 parameters where known (NAV_ACC_RAD, MPC_XY_CRUISE,
            MPC_ACC_HOR, SIH_KDV ...), used by the prediction.
        iterations: predictions per candidate at most (1: as ``retime=False``).
        retime: re-time the legs and holds and try the candidates (False: the legs' average
            speeds, every waypoint, the chosen radius, predicted once).
        captures: where each vehicle's camera takes pictures (:func:`gcs.flight.payload.capture_spans`;
            ``None``: nowhere): camera and gimbal items in its mission.
        budget_s: no new prediction starts after this many seconds of CPU time of this
            process (the best so far is kept; at least one is always made): a busy machine
            makes the same search, only later.
    """

    prm = dict(params or {})
    auto = acceptance_m is None
    nav_rad = prm.get("NAV_ACC_RAD", PX4_DEFAULTS["NAV_ACC_RAD"])
    radius0 = auto_acceptance_m(plan, nav_rad) if acceptance_m is None else float(acceptance_m)
    lag_s = expected_lag_s(prm)
    v_max = prm.get("MPC_XY_VEL_MAX", PX4_DEFAULTS["MPC_XY_VEL_MAX"])
    dt = plan.check_dt_s
    t = np.arange(round(plan.horizon_s / dt) + 1) * dt
    starts = {pv.name: tuple(float(x) for x in pv.start_enu_m) for pv in plan.vehicles}
    land_at = landing_targets(plan) if end is MissionEnd.LAND else {}
    phi = plan_formula(plan)

    def build(
        radius: float,
        simplify: float,
        speeds: Mapping[str, np.ndarray] | None = None,
        holds: Mapping[str, np.ndarray] | None = None,
    ) -> dict[str, MissionPlan]:
        return {
            pv.name: trajectory_to_mission(
                pv.trajectory,
                plan.origin,
                acceptance_radius_m=radius,
                end=end,
                name=pv.name,
                leg_speed_m_s=None if speeds is None else speeds[pv.name],
                pass_lag_s=lag_s,
                land_at_enu_m=land_at.get(pv.name),
                captures=(captures or {}).get(pv.name, ()),
                simplify_m=simplify,
                hold_time_s=None if holds is None else holds[pv.name],
            )
            for pv in plan.vehicles
        }

    def predict(missions: Mapping[str, MissionPlan]) -> tuple[float, PredictedMissions]:
        pred = predict_missions(
            {n: m.items for n, m in missions.items()},
            starts,
            plan.origin,
            duration_s=plan.horizon_s + PREDICT_EXTRA_S,
            min_duration_s=plan.horizon_s,
            start_yaw_deg={n: float(m.items[1].param4) for n, m in missions.items()},
            params=prm,
            sample_dt_s=dt if dt >= 0.02 else 0.02,
            terrain=plan.terrain,
        )
        return float(phi.robustness({n: pred.signal(n, t) for n in missions}, dt)), pred

    plain = build(radius0, 0.0)
    straight = path_robustness(phi, {n: m.path for n, m in plain.items()}, dt, plan.horizon_s)
    best: _Candidate | None = None
    runs = 0
    shots = any(captures.values()) if captures else False
    candidates = (
        [(radius0, 0.0)]
        if not retime or iterations <= 1
        else [
            (r, s)
            for s in simplify_candidates(plan)
            # a larger radius cuts corners: not where pictures are taken
            for r in (radius_candidates(radius0, nav_rad) if auto and not shots else (radius0,))
        ]
    )
    deadline = time.process_time() + budget_s
    tried: set[str] = set()
    for radius, simplify in candidates:
        if best is not None and time.process_time() > deadline:
            break
        missions = plain if (radius, simplify) == (radius0, 0.0) else build(radius, simplify)
        if _scheduled(missions) < _scheduled(plain):
            continue  # a capture span without a waypoint left in it: no pictures there
        key = repr(sorted((n, m.items) for n, m in missions.items()))
        if key in tried:
            continue  # the same missions as a candidate already tried (a small plan)
        tried.add(key)
        base = {n: m.leg_speed_m_s.copy() for n, m in missions.items()}
        speeds = {n: s.copy() for n, s in base.items()}
        holds = {n: m.hold_s.copy() for n, m in missions.items()}
        mine = -math.inf  # this candidate's best
        stale = 0
        for k in range(max(1, iterations if retime else 1)):
            rho, pred = predict(missions)
            runs += 1
            if best is None or rho > best.robustness:
                # past the first prediction the legs and holds are the re-timed ones
                best = _Candidate(rho, missions, pred, radius, simplify, retimed=k > 0)
            stale = 0 if rho > mine + 0.01 else stale + 1
            mine = max(mine, rho)
            if k + 1 >= iterations or not retime or stale >= 2 or time.process_time() > deadline:
                break
            if k == 0 and rho < best.robustness - HOPELESS_M:
                break  # re-timing has not made up that much on any plan tried
            changed = False
            for name, m in missions.items():
                new_speed, new_hold = _retimed(
                    m, pred, speeds[name], holds[name], base[name], v_max
                )
                if not (
                    np.allclose(new_speed, speeds[name], rtol=0.01)
                    and np.allclose(new_hold, holds[name], atol=0.05)
                ):
                    changed = True
                speeds[name], holds[name] = new_speed, new_hold
            if not changed:
                break
            missions = build(radius, simplify, speeds, holds)
        if best is not None and best.robustness >= plan.epsilon + GOOD_ENOUGH_M:
            break
    assert best is not None
    late = {}
    for name, m in best.missions.items():
        fin = best.prediction.finished_s[name]
        late[name] = math.inf if fin is None else fin - float(m.arrival_t_s[-1] + m.hold_s[-1])
    return MissionConversion(
        missions=best.missions,
        acceptance_m=best.radius,
        acceptance_auto=auto,
        prediction=best.prediction,
        predicted_robustness=best.robustness,
        straight_leg_robustness=float(straight),
        late_s=late,
        iterations=runs,
        retimed=best.retimed,
        simplify_m=best.simplify,
        weakest=_weakest(phi, best.prediction, t, dt),
        tolerance_s=time_tolerance(phi, best.prediction, t, dt, epsilon=plan.epsilon),
    )


def _weakest(phi: Any, pred: PredictedMissions, t: np.ndarray, dt: float) -> str:
    """The spec's weakest top-level clause on the predicted tracks, with its robustness."""
    sig = {n: pred.signal(n, t) for n in pred.pos_enu_m}
    rho, clause = min(((float(c.robustness(sig, dt)), c) for c in phi.clauses), key=lambda x: x[0])
    return f"{clause} {rho:+.3f}"


def time_tolerance(
    phi: Any,
    pred: PredictedMissions,
    t: np.ndarray,
    dt: float,
    *,
    epsilon: float = 0.0,
    up_to_s: float = TOLERANCE_MAX_S,
) -> dict[str, float]:
    """Per top-level clause, how many seconds of timing error it tolerates on the predicted
    flight (:func:`planner.spec.timing.time_tolerance`: any one of its vehicles early or late,
    or two off the opposite ways; to 0.05 s, at most ``up_to_s``; 0 for a clause already
    below ``epsilon``)."""
    names = list(pred.pos_enu_m)
    return {
        str(clause): clause_tolerance(
            clause, pred.signal, names, t, dt, epsilon=epsilon, up_to_s=up_to_s
        )
        for clause in phi.clauses
    }


def timing_summary(late_s: Mapping[str, float]) -> str:
    """How late the missions are predicted to finish, in words."""
    worst = max(late_s.values(), default=0.0)
    if not math.isfinite(worst):
        return "a mission not finished within the prediction"
    if worst > 0.05:
        return f"up to {worst:.1f} s late"
    return f"on time (each finishing {max(0.0, -worst):.1f} s early or more)"


@dataclass(frozen=True, slots=True, eq=False)
class _Candidate:
    robustness: float
    missions: dict[str, MissionPlan]
    prediction: PredictedMissions
    radius: float
    simplify: float
    retimed: bool


def _scheduled(missions: Mapping[str, MissionPlan]) -> int:
    """How many capture spans the missions take pictures in."""
    return sum(1 for m in missions.values() for c in m.captures if c.start_s is not None)


def radius_candidates(radius_m: float, nav_acc_rad_m: float) -> tuple[float, ...]:
    """The acceptance radii a conversion tries, in order: NAV_ACC_RAD (PX4's own), the
    chosen one (:func:`auto_acceptance_m`) where smaller, and 1.5 times NAV_ACC_RAD. PX4's
    corner speed grows with the square root of the radius
    (``sqrt(MPC_XY_TRAJ_P * MPC_ACC_HOR * R * tan(alpha / 2))``), and it cuts the corner by
    about the radius: the prediction judges the trade."""
    out = [float(max(radius_m, nav_acc_rad_m))]
    if radius_m < out[0] - 0.05:
        out.append(float(radius_m))
    out.append(1.5 * out[0])
    return tuple(out)


def simplify_candidates(plan: Plan) -> tuple[float, ...]:
    """The tolerances (m) of :func:`mavlink.mission.keep_waypoints` a conversion tries, in
    order: a quarter and a half of the plan's margin (its robustness; at least 0.1 m), then
    every waypoint."""
    margin = max(0.1, float(plan.robustness))
    return (0.25 * margin, 0.5 * margin, 0.0)


def _retimed(
    m: MissionPlan,
    pred: PredictedMissions,
    speeds: np.ndarray,
    holds: np.ndarray,
    base: np.ndarray,
    v_max: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The next leg speeds and holds of one mission from its predicted flight.

    A hold is lengthened by how early PX4 is predicted to leave it (:data:`HOLD_GAIN` of it a
    step), and shortened again no further than the plan's hover: the holds are where a vehicle
    that arrives early waits for the plan's clock. A leg's speed is scaled by its predicted
    duration against the duration that puts the vehicle back on the clock: the plan's, less
    half the lateness it starts with that no hold before it absorbs, and less
    :data:`ARRIVE_EARLY_S` on the first leg after a hold (the lead the legs keep into the next
    hover: lateness there cannot be made up). At most by 0.7-1.6 a step, :data:`MAX_SPEEDUP`
    times the leg's average speed and MPC_XY_VEL_MAX in all.
    """
    left = pred.left_s[m.name]
    seqs = [int(q) for q in m.waypoint_seq]
    dep_plan = m.arrival_t_s + m.hold_s
    new_hold = holds.copy()
    carry = 0.0  # lateness carried into the next leg
    new_speed = speeds.copy()
    for j, seq in enumerate(seqs):
        t_left = left.get(seq)
        if j > 0:
            t_dep = left.get(seqs[j - 1])
            planned = float(m.arrival_t_s[j] - dep_plan[j - 1])
            if t_dep is not None and t_left is not None and planned > 0:
                flown = (t_left - float(holds[j])) - t_dep
                # the first leg after a hold gains the lead the chain keeps to its hover
                lead = ARRIVE_EARLY_S if j == 1 or m.hold_s[j - 1] > 0 else 0.0
                want = max(0.5 * planned, planned - lead - 0.5 * carry)
                if flown > 0:
                    ratio = min(1.6, max(0.7, flown / want))
                    new_speed[j - 1] = min(speeds[j - 1] * ratio, MAX_SPEEDUP * base[j - 1], v_max)
        if t_left is None:
            carry = 0.0
            continue
        late = t_left - float(dep_plan[j])
        if j > 0 and m.hold_s[j] <= 0:
            late += ARRIVE_EARLY_S  # against the lead
        if 0 < j < len(seqs) - 1 and m.hold_s[j] > 0:
            # never shorter than the plan's hover: a hover is what an inspection clause needs
            # (shortened holds lost d2's 1 s in its first inspection box on the power line)
            floor = float(m.hold_s[j])
            new_hold[j] = max(floor, float(holds[j]) - HOLD_GAIN * late)
            late = max(0.0, late - (float(holds[j]) - floor))  # what the hold cannot absorb
        carry = late
    return new_speed, new_hold


@dataclass(frozen=True, slots=True, eq=False)
class FencePlan:
    """The geofence for a plan on PX4 (``gcs upload --fence``).

    Attributes:
        items: the FENCE items.
        inflate_m: how far the workspace polygon lies beyond the workspace.
        notes: one line per thing the operator should know (regions left unfenced, places
            where PX4's predictive fence may fire on the plan itself).
    """

    items: tuple[Any, ...]
    inflate_m: float
    notes: tuple[str, ...]


def fence_plan(plan: Plan, *, acc_hor_m_s2: float = 3.0, allowance_m: float = 0.5) -> FencePlan:
    """The workspace (inflated) and full-height stay-out regions as PX4 fence polygons and
    circles (:func:`mavlink.mission.fence_zones`: boxes and prisms as polygons, cylinders as
    circles).

    PX4's fence is predictive: it fires when the braking distance at the current speed
    (:func:`mavlink.mission.braking_distance_m`) would cross it. The workspace polygon is
    therefore moved out by the braking distance at the plan's peak speed plus
    ``allowance_m`` (tracking and estimator error); exclusions stay exact, and where the
    plan itself comes closer to one than its braking distance, a note says where and when.
    """

    t = np.arange(0.0, plan.horizon_s + 1e-9, plan.check_dt_s)
    peak = 0.0
    tracks = {}
    for pv in plan.vehicles:
        pos = pv.trajectory.position(t)
        speed = np.linalg.norm(pv.trajectory.velocity(t)[:, :2], axis=1)
        tracks[pv.name] = (pos, speed)
        peak = max(peak, float(speed.max()))
    inflate = braking_distance_m(peak, acc_hor_m_s2) + allowance_m
    zones = fence_zones(plan.workspace, plan.regions, inflate_m=inflate)
    notes = [
        f"fence: the workspace polygon lies {inflate:.2f} m outside the workspace (PX4's "
        f"braking distance at the plan's peak {peak:.2f} m/s, plus {allowance_m:g} m)"
    ]
    fenced = {z.name for z in zones}
    for r in plan.regions:
        if r.kind.value in ("obstacle", "no_fly", "pole") and r.name not in fenced:
            notes.append(
                f"fence: {r.name} is not fenced: it does not span the workspace's height, and "
                "PX4's fence polygons and circles have no floor or ceiling (the plan's own "
                "checks keep it)"
            )
    for zone in zones:
        if zone.inclusion:
            continue
        for name, (pos, speed) in tracks.items():
            dist = zone.distance_m(pos[:, :2])  # to the zone's true footprint (0 inside)
            gap = dist - np.array([braking_distance_m(v, acc_hor_m_s2) for v in speed])
            k = int(np.argmin(gap))
            if gap[k] < 0:
                notes.append(
                    f"fence: PX4's predictive fence may stop {name} near {zone.name} at t = "
                    f"{t[k]:.1f} s ({dist[k]:.2f} m from it at {speed[k]:.1f} "
                    f"m/s, braking distance {braking_distance_m(speed[k], acc_hor_m_s2):.2f} m)"
                )
    return FencePlan(geofence_items(zones, plan.origin), inflate, tuple(notes))


async def convert_plan_apart(plan: Plan, **kwargs: Any) -> MissionConversion:
    """:func:`convert_plan` in a child Python process, awaited.

    The prediction is seconds of pure Python; on a thread of a process that is also
    talking to vehicles it holds the GIL and MAVSDK drops telemetry callbacks meanwhile
    (seen on PX4 SITL: thousands during a 4-vehicle conversion). The child gets the plan and
    the arguments pickled on stdin and answers the conversion pickled on stdout.

    Raises:
        RuntimeError: the child failed (its last line of stderr).
    """

    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "gcs.flight.missions",
        stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    out, err = await proc.communicate(pickle.dumps((plan, kwargs)))
    if proc.returncode != 0:
        lines = err.decode(errors="replace").strip().splitlines()
        raise RuntimeError(f"mission conversion failed: {lines[-1] if lines else proc.returncode}")
    result: MissionConversion = pickle.loads(out)
    return result


def _child() -> None:
    """``python -m gcs.flight.missions``: the child of :func:`convert_plan_apart`."""

    plan, kwargs = pickle.loads(sys.stdin.buffer.read())
    sys.stdout.buffer.write(pickle.dumps(convert_plan(plan, **kwargs)))


if __name__ == "__main__":
    # Through the imported module, so that what is pickled names gcs.flight.missions, not __main__.
    from gcs.flight.missions import _child as child

    child()
