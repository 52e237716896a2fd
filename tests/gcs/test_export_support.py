"""Plans for the plot and export tests, built from exact trajectories (no solver run).

Holds no tests: the builders make a :class:`planner.planfile.Plan` from rest-to-rest quintic
segments (``p(s) = p0 + (p1 - p0)(10 s^3 - 15 s^4 + 6 s^5)``, ``s = tau / T``) through chosen
waypoints, so every quantity the tests compare is known in closed form, and write it with the
real plan-file writer (:func:`planner.planfile.save_plan`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from planner.frames import GeodeticPoint
from planner.planfile import Plan, PlannedVehicle, save_plan
from planner.spec.regions import Region, RegionKind
from planner.trajectory import Trajectory, YawMode, YawPolicy

ORIGIN = GeodeticPoint(lat_deg=47.397742, lon_deg=8.545594, alt_m=488.0)

SPEC = (
    "(eventually[0, 6] inside(d1, goal)) and\n"
    "(eventually[0, 6] inside(d2, goal)) and\n"
    "(always[0, 6] (outside(d1, obstacle) and inside(d1, workspace))) and\n"
    "(always[0, 6] (outside(d2, obstacle) and inside(d2, workspace))) and\n"
    "(always[0, 6] dist(d1, d2) >= 0.2)"
)


def quintic_trajectory(
    waypoints: Sequence[Sequence[float]],
    durations_s: Sequence[float],
    name: str,
    yaw: YawPolicy | None = None,
) -> Trajectory:
    """Rest-to-rest quintic segments through ``waypoints`` (k, 3), ``durations_s`` (k-1,)."""
    w = np.asarray(waypoints, dtype=float)
    d = np.asarray(durations_s, dtype=float)
    t0 = np.concatenate([[0.0], np.cumsum(d)[:-1]])
    coeffs = np.zeros((d.size, 3, 6))
    for s in range(d.size):
        delta = w[s + 1] - w[s]
        big_t = d[s]
        coeffs[s, :, 0] = w[s]
        coeffs[s, :, 3] = 10.0 * delta / big_t**3
        coeffs[s, :, 4] = -15.0 * delta / big_t**4
        coeffs[s, :, 5] = 6.0 * delta / big_t**5
    return Trajectory(t0, d, coeffs, name=name, yaw_policy=yaw)


def quintic_position(
    waypoints: Sequence[Sequence[float]], durations_s: Sequence[float], t_s: np.ndarray
) -> np.ndarray:
    """Reference positions (n, 3) of :func:`quintic_trajectory`, evaluated independently."""
    w = np.asarray(waypoints, dtype=float)
    ends = np.cumsum(durations_s)
    out = np.empty((t_s.size, 3))
    for i, t in enumerate(t_s):
        k = min(int(np.searchsorted(ends, t, side="right")), len(durations_s) - 1)
        start = 0.0 if k == 0 else ends[k - 1]
        s = min(max((t - start) / durations_s[k], 0.0), 1.0)
        out[i] = w[k] + (w[k + 1] - w[k]) * (10 * s**3 - 15 * s**4 + 6 * s**5)
    return out


#: Waypoints and segment durations of the two vehicles of :func:`reach_avoid_plan`.
D1 = ([[-1.5, -1.5, 0.5], [1.5, -1.5, 1.0], [1.75, 1.6, 0.75], [1.75, 1.6, 0.75]], [2.0, 2.0, 2.0])
D2 = ([[-1.5, -0.9, 0.5], [-1.5, 1.5, 1.0], [1.75, 1.9, 0.75], [1.75, 1.9, 0.75]], [2.0, 2.0, 2.0])


def reach_avoid_plan(spec: str = SPEC, *, velocity_yaw: bool = False) -> Plan:
    """Two vehicles around a central obstacle into a goal box, with every region kind."""
    yaw = YawPolicy(YawMode.VELOCITY, 0.3, 0.2) if velocity_yaw else YawPolicy(yaw_rad=0.5)
    vehicles = []
    for i, (name, (wps, durs)) in enumerate((("d1", D1), ("d2", D2))):
        vehicles.append(
            PlannedVehicle(
                name=name,
                sysid=i + 1,
                trajectory=quintic_trajectory(wps, durs, name, yaw),
                start_enu_m=(wps[0][0], wps[0][1], wps[0][2]),
                v_max_m_s=(3.5, 3.5, 2.0),
                a_max_m_s2=(5.0, 5.0, 3.0),
            )
        )
    regions = (
        Region("obstacle", RegionKind.OBSTACLE, (-1.0, -1.0, 0.0), (1.0, 1.0, 1.5)),
        Region("goal", RegionKind.GOAL, (1.5, 1.5, 0.5), (2.0, 2.0, 1.0)),
        Region("nofly", RegionKind.NO_FLY, (-2.0, 1.8, 0.0), (-1.8, 2.0, 2.0)),
        Region("pole1", RegionKind.POLE, (1.8, -2.0, 0.0), (2.0, -1.8, 2.0)),
        Region("line", RegionKind.CONDUCTOR, (-2.0, -2.0, 1.7), (2.0, -1.8, 1.9)),
        Region("insp1", RegionKind.INSPECTION, (0.0, -2.0, 1.2), (0.5, -1.6, 1.6)),
    )
    return Plan(
        scenario="configs/reach_avoid.yaml",
        origin=ORIGIN,
        spec=spec,
        robustness=0.05,
        smooth_robustness=0.04,
        status="Solve_Succeeded",
        success=True,
        solve_time_s=0.5,
        vehicles=tuple(vehicles),
        workspace=Region("workspace", RegionKind.WORKSPACE, (-2.0, -2.0, 0.0), (2.0, 2.0, 2.0)),
        regions=regions,
        separation_m=0.2,
        epsilon=0.01,
        horizon_s=6.0,
        sample_dt_s=0.05,
        check_dt_s=0.01,
    )


def write_plan(path: Path, plan: Plan | None = None) -> Path:
    """Save ``plan`` (default :func:`reach_avoid_plan`) with the plan-file writer."""
    return save_plan(path, plan if plan is not None else reach_avoid_plan())
