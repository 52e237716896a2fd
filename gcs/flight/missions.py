"""A plan as PX4 missions that keep the plan's clock, and what PX4 will make of them.

:func:`mavlink.mission.trajectory_to_mission` turns a trajectory into straight legs, each
commanded at its average speed. PX4 does not fly those at constant speed: it accelerates
and brakes within MPC_ACC_HOR / MPC_JERK_AUTO, slows for corners and stops before holds,
and lags its own setpoint by the drag (docs/px4-behaviour.md: with a 1 m acceptance radius the
power-line missions finished 5.5-8.5 s late). :func:`convert_plan`

1. chooses the acceptance radius (:func:`auto_acceptance_m`) unless the user gave one;
2. predicts the flight with the mock's PX4 vehicle (:mod:`mavlink.mock.predict`: PX4's
   navigator laws and the drag, no estimator noise);
3. re-times the legs: each leg's commanded speed is scaled by how much longer PX4 took for
   it than the plan allows, and the prediction repeated (``iterations``), keeping the
   conversion whose predicted spec robustness is best;
4. reports the predicted flight: per vehicle the finish time against the plan's, and the
   spec's exact robustness on the predicted tracks (the honest "mission robustness"),
   next to the straight-leg figure, which assumes constant leg speeds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from mavlink.mission import CaptureSpan, MissionEnd, MissionPlan
    from mavlink.mock.predict import PredictedMissions
    from planner.planfile import Plan

#: PX4 v1.17 defaults the conversion assumes where the vehicle's own are not known.
PX4_DEFAULTS = {"NAV_ACC_RAD": 2.0}
#: Cross-track error PX4 (SIH) showed per m/s of cruise: 0.3-0.5 m at 3.4 m/s (R = 0.3 m
#: was missed, 1.0 m never); twice this is the smallest radius the conversion picks.
XTRACK_S = 0.15
MIN_ACCEPTANCE_M = 0.6
#: A leg is never commanded faster than this multiple of its average speed (a
#: minimum-jerk segment peaks at 1.875 times its average).
MAX_SPEEDUP = 2.0
#: Seconds flown after the plan's horizon in a prediction (late missions are seen finishing).
PREDICT_EXTRA_S = 20.0


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
        retimed: the leg speeds were changed from the legs' average speeds.
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


def auto_acceptance_m(plan: Plan, nav_acc_rad_m: float = PX4_DEFAULTS["NAV_ACC_RAD"]) -> float:
    """The waypoint acceptance radius for ``plan`` on PX4 (m).

    Large enough that PX4 does not miss the circle at the plan's fastest leg (twice the
    cross-track error PX4 showed, :data:`XTRACK_S` per m/s, at least
    :data:`MIN_ACCEPTANCE_M`: a missed circle costs 18-35 s), and no larger than
    NAV_ACC_RAD, PX4's own default radius. Corner cutting that a larger radius brings is
    judged by the prediction, not here.
    """
    from mavlink.mission import trajectory_to_mission

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
    from gcs.flight.tuning import PX4_GAINS, drag_lag_s

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
    iterations: int = 4,
    retime: bool = True,
    captures: Mapping[str, Sequence[CaptureSpan]] | None = None,
) -> MissionConversion:
    """Missions for every vehicle of ``plan``, timed so PX4 keeps the plan's clock.

    Args:
        end: what each mission ends with.
        acceptance_m: waypoint acceptance radius; ``None`` chooses it
            (:func:`auto_acceptance_m` with the vehicles' NAV_ACC_RAD).
        params: the vehicles' PX4 parameters where known (NAV_ACC_RAD, MPC_XY_CRUISE,
            MPC_ACC_HOR, SIH_KDV ...), used by the prediction.
        iterations: predictions at most (1: no re-timing, just the prediction).
        retime: re-time the legs (False: the legs' average speeds, predicted once).
        captures: where each vehicle's camera takes pictures (:func:`gcs.flight.payload.capture_spans`;
            ``None``: nowhere): camera and gimbal items in its mission.
    """
    from gcs.flight.evaluation import plan_formula
    from mavlink.mission import MissionEnd, path_robustness, trajectory_to_mission
    from mavlink.mock.predict import predict_missions

    prm = dict(params or {})
    auto = acceptance_m is None
    radius = (
        auto_acceptance_m(plan, prm.get("NAV_ACC_RAD", PX4_DEFAULTS["NAV_ACC_RAD"]))
        if acceptance_m is None
        else float(acceptance_m)
    )
    lag_s = expected_lag_s(prm)
    dt = plan.check_dt_s
    t = np.arange(round(plan.horizon_s / dt) + 1) * dt
    starts = {pv.name: tuple(float(x) for x in pv.start_enu_m) for pv in plan.vehicles}
    from gcs.flight.landing import landing_targets

    land_at = landing_targets(plan) if end is MissionEnd.LAND else {}

    def build(speeds: Mapping[str, np.ndarray] | None) -> dict[str, MissionPlan]:
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
            )
            for pv in plan.vehicles
        }

    missions = build(None)
    base = {n: m.leg_speed_m_s.copy() for n, m in missions.items()}
    phi = plan_formula(plan)
    straight = path_robustness(phi, {n: m.path for n, m in missions.items()}, dt, plan.horizon_s)
    best: tuple[float, dict[str, MissionPlan], PredictedMissions] | None = None
    speeds = {n: s.copy() for n, s in base.items()}
    runs = 0
    for k in range(max(1, iterations if retime else 1)):
        pred = predict_missions(
            {n: m.items for n, m in missions.items()},
            starts,
            plan.origin,
            duration_s=plan.horizon_s + PREDICT_EXTRA_S,
            min_duration_s=plan.horizon_s,
            start_yaw_deg={n: float(m.items[1].param4) for n, m in missions.items()},
            params=prm,
            sample_dt_s=dt if dt >= 0.02 else 0.02,
        )
        runs += 1
        rho = float(phi.robustness({n: pred.signal(n, t) for n in missions}, dt))
        if best is None or rho > best[0]:
            best = (rho, missions, pred)
        if k + 1 >= iterations or not retime:
            break
        changed = False
        for name, m in missions.items():
            # the plan's waypoints (a landing point's waypoint, if any, comes after them)
            wp_seqs = [int(q) for q in m.waypoint_seq]
            left = pred.left_s[name]
            new = speeds[name].copy()
            for j in range(1, len(wp_seqs)):
                t_dep = left.get(wp_seqs[j - 1])
                t_left = left.get(wp_seqs[j])
                if t_dep is None or t_left is None:
                    continue
                flown = (t_left - float(m.hold_s[j])) - t_dep
                planned = float(m.arrival_t_s[j]) - float(m.arrival_t_s[j - 1] + m.hold_s[j - 1])
                if planned <= 0 or flown <= 0:
                    continue
                ratio = min(1.6, max(0.7, flown / planned))
                new[j - 1] = min(new[j - 1] * ratio, MAX_SPEEDUP * base[name][j - 1])
            if not np.allclose(new, speeds[name], rtol=0.01):
                changed = True
            speeds[name] = new
        if not changed:
            break
        missions = build(speeds)
    assert best is not None
    rho, chosen, pred = best
    late = {}
    for name, m in chosen.items():
        fin = pred.finished_s[name]
        late[name] = math.inf if fin is None else fin - float(m.arrival_t_s[-1] + m.hold_s[-1])
    retimed = any(not np.allclose(chosen[n].leg_speed_m_s, base[n]) for n in chosen)
    return MissionConversion(
        missions=chosen,
        acceptance_m=radius,
        acceptance_auto=auto,
        prediction=pred,
        predicted_robustness=rho,
        straight_leg_robustness=float(straight),
        late_s=late,
        iterations=runs,
        retimed=retimed,
    )


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
    from mavlink.mission import braking_distance_m, fence_zones, geofence_items

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
    import asyncio
    import pickle
    import sys

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
    import pickle
    import sys

    plan, kwargs = pickle.loads(sys.stdin.buffer.read())
    sys.stdout.buffer.write(pickle.dumps(convert_plan(plan, **kwargs)))


if __name__ == "__main__":
    # Through the imported module, so that what is pickled names gcs.flight.missions, not __main__.
    from gcs.flight.missions import _child as child

    child()
