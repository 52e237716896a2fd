"""What PX4 will fly for a mission: the mock's ``px4`` vehicle as a timing model.

A PX4 mission is not flown at the legs' constant speeds: the vehicle accelerates and brakes
within MPC_ACC_HOR and MPC_JERK_AUTO, takes corners at PX4's corner speed, brakes to a stop
before holds and where the next waypoint lies within the acceptance radius, and lags its own
trajectory setpoint by SIH's drag (docs/px4-behaviour.md).  The mock's ``px4`` profile implements
those laws (:mod:`mavlink.mock.navigator`, :mod:`mavlink.mock.sim.physics`), so the honest
prediction of a mission is the mock flying it: offline, in simulated time, with the
estimator's errors switched off (the prediction is the expected flight, not one draw).

:func:`predict_missions` flies the missions the way ``gcs fly --mode mission`` does: each
vehicle takes off to its start and is moved onto it, then all are released into their
missions at one instant (t = 0), from the start waypoint (``start_seq``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock.fleet import MockFleet
from mavlink.mock.sim.physics import Ground
from mavlink.mock.sim.px4 import Px4Mode
from mavlink.mock.telemetry import DEFAULT_RATES_HZ
from mavlink.tracks import wrap_pi
from planner.frames import GeodeticPoint, yaw_ned_to_enu

#: Parameters that make the px4 vehicle's estimate its truth: the expected flight.
QUIET_ESTIMATOR = {
    "MOCK_EST_SLOW_B": 0.0,
    "MOCK_EST_P_N": 0.0,
    "MOCK_EST_V_N": 0.0,
    "MOCK_EST_VB": 0.0,
    "MOCK_EST_YAW_V": 0.0,
    "MOCK_ORG_XY_MIN": 0.0,
    "MOCK_ORG_XY_MAX": 0.0,
    "MOCK_ORG_Z_MIN": 0.0,
    "MOCK_ORG_Z_MAX": 0.0,
    "MOCK_GE_RATE": 0.0,
    "MOCK_MIS_RDY_T": 0.0,
}

_SETTLE_SPEED_M_S = 0.05
_SETTLE_DIST_M = 0.05


@dataclass(frozen=True, slots=True, eq=False)
class PredictedMissions:
    """The predicted flight of every vehicle from the shared release (t = 0).

    Attributes:
        t_s: ``(m,)`` sample times, s.
        pos_enu_m: per vehicle ``(m, 3)`` mission-frame positions (the simulated truth).
        left_s: per vehicle, item seq -> when the vehicle moved past it (MISSION_CURRENT).
        finished_s: per vehicle, when its mission finished (``None``: not within the run).
        yaw_enu_rad: per vehicle ``(m,)`` its heading, mission-frame ENU yaw (rad, unwrapped).
    """

    t_s: np.ndarray
    pos_enu_m: dict[str, np.ndarray]
    left_s: dict[str, dict[int, float]]
    finished_s: dict[str, float | None]
    yaw_enu_rad: dict[str, np.ndarray] = field(default_factory=dict)

    def position(self, name: str, t_s: np.ndarray) -> np.ndarray:
        """``(n, 3)`` predicted positions of ``name`` at ``t_s`` (held outside the run)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        p = self.pos_enu_m[name]
        return np.column_stack([np.interp(t, self.t_s, p[:, a]) for a in range(3)])

    def signal(self, name: str, t_s: np.ndarray) -> np.ndarray:
        """The STL signal of ``name`` at ``t_s``: positions with the heading (wrapped to
        ``(-pi, pi]``) as a fourth column, ``(n, 4)``; ``(n, 3)`` without a heading."""
        pos = self.position(name, t_s)
        yaw = self.yaw_enu_rad.get(name)
        if yaw is None:
            return pos
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        y = np.interp(t, self.t_s, yaw)
        return np.column_stack([pos, wrap_pi(y)])


def _command_int(v: Any, command: int, *p: float, lat_e7: int = 0, lon_e7: int = 0,
                 alt: float = 0.0) -> None:  # fmt: skip
    params = [*p, *([0.0] * (4 - len(p)))]
    v.receive(
        mavlink2.MAVLink_command_int_message(
            v.sysid, 1, mavlink2.MAV_FRAME_GLOBAL, command, 0, 0, *params, lat_e7, lon_e7, alt
        )
    )


def predict_missions(
    missions: Mapping[str, Sequence[Any]],
    starts_enu_m: Mapping[str, Sequence[float]],
    origin: Any,
    *,
    duration_s: float,
    start_seq: int = 1,
    start_yaw_deg: Mapping[str, float] | None = None,
    params: Mapping[str, float] | None = None,
    sample_dt_s: float = 0.01,
    settle_s: float = 30.0,
    min_duration_s: float | None = None,
    terrain: Ground | None = None,
) -> PredictedMissions:
    """Fly ``missions`` (name -> items with MISSION_ITEM_INT's fields) on offline px4 mocks.

    Every vehicle stands on the ground below its start (``starts_enu_m``, mission frame),
    arms, takes off to the start's altitude, is repositioned onto the start (and its
    heading, ``start_yaw_deg`` NED), and once all have settled they switch to AUTO.MISSION
    together at item ``start_seq``. The run lasts ``duration_s`` after that release.

    Args:
        params: PX4 parameters over the px4 profile (e.g. the vehicles' own NAV_ACC_RAD,
            MPC_XY_CRUISE, SIH_KDV); the estimator stays quiet (:data:`QUIET_ESTIMATOR`).
        min_duration_s: stop early once this much has been flown and every mission has
            finished (positions are held after the run); default: fly ``duration_s``.
        terrain: the ground the vehicles stand, take off and land on (the plan's), else flat
            at the mission frame's ``z = 0``.
    """
    if min_duration_s is None:
        min_duration_s = duration_s
    names = list(missions)
    prm = dict(params or {})
    prm.update(QUIET_ESTIMATOR)
    xy = np.array([[starts_enu_m[n][0], starts_enu_m[n][1]] for n in names], dtype=float)
    ground = np.zeros(len(names)) if terrain is None else terrain.ground(xy)
    spawns = [(float(p[0]), float(p[1]), float(g)) for p, g in zip(xy, ground, strict=True)]
    # no payload: the cameras' traffic would only cost time (the missions' camera and gimbal
    # items are still issued, as PX4's navigator issues them without a camera)
    fleet = MockFleet(
        n=len(names), origin=origin, spawns_enu_m=spawns, params=prm, ready_after_s=0.0,
        camera=False, terrain=terrain,
    )  # fmt: skip
    fleet.offline_links()
    vs = fleet.vehicles
    for v in vs:
        # nobody reads the telemetry of a prediction (its samples are the simulation's state):
        # every stream off, as a ground station turns one off (SET_MESSAGE_INTERVAL -1), which
        # leaves the vehicle's behaviour as it is and saves a fifth of the prediction's time
        for msg_id in DEFAULT_RATES_HZ:
            _command_int(v, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, float(msg_id), -1.0)
    for name, v in zip(names, vs, strict=True):
        alt = _geodetic(fleet, starts_enu_m[name])[2]
        yaw = (start_yaw_deg or {}).get(name, math.nan)
        v.arm(force=True)
        _command_int(v, mavlink2.MAV_CMD_NAV_TAKEOFF, 0.0, 0.0, 0.0, yaw, alt=alt)
        v.store_plan(missions[name])
    # Wait for the take-offs, then move each onto its start.
    _settle(fleet, names, starts_enu_m, settle_s, reposition=True, yaw=start_yaw_deg or {})
    for v in vs:
        v.set_mission_current(start_seq)
        v.request_mode(Px4Mode.AUTO_MISSION)
    steps = math.ceil(duration_s / sample_dt_s)
    t = np.arange(steps + 1) * sample_dt_s
    ned = np.empty((steps + 1, len(names), 3))  # the physics' (spawn) frame: cheap to copy
    ned[0] = fleet.physics.true_pos_ned_m
    heading = np.empty((steps + 1, len(names)))  # the true yaw, NED at each spawn
    heading[0] = fleet.physics.yaw_rad
    seq_prev = [v.mission_seq for v in vs]
    left: dict[str, dict[int, float]] = {n: {} for n in names}
    finished: dict[str, float | None] = dict.fromkeys(names)
    last = steps
    k = 0
    for k in range(1, steps + 1):
        fleet.advance(sample_dt_s)
        ned[k] = fleet.physics.true_pos_ned_m
        heading[k] = fleet.physics.yaw_rad
        for j, v in enumerate(vs):
            seq = v.mission_seq
            if seq > seq_prev[j]:
                for s in range(seq_prev[j], seq):
                    left[names[j]].setdefault(s, float(t[k]))
                seq_prev[j] = seq
            if v.mission_finished and finished[names[j]] is None:
                finished[names[j]] = float(t[k])
                left[names[j]].setdefault(seq, float(t[k]))
        done = t[k] >= min_duration_s and all(f is not None for f in finished.values())
        if done and last == steps:
            last = min(steps, k + round(1.0 / sample_dt_s))  # a second more, then held
        if k >= last:
            break
    stop = k
    pos = fleet.spawn_ned_to_enu(ned[: stop + 1])
    t = t[: stop + 1]
    return PredictedMissions(
        t_s=t,
        pos_enu_m={n: pos[:, j] for j, n in enumerate(names)},
        left_s=left,
        finished_s=finished,
        yaw_enu_rad={
            n: np.unwrap(
                yaw_ned_to_enu(
                    heading[: stop + 1, j], fleet.origin, GeodeticPoint(*vs[j].spawn_lla)
                )
            )
            for j, n in enumerate(names)
        },
    )


def _geodetic(fleet: MockFleet, enu: Sequence[float]) -> tuple[float, float, float]:
    import pymap3d

    o = fleet.origin
    lat, lon, alt = pymap3d.enu2geodetic(
        float(enu[0]), float(enu[1]), float(enu[2]), o.lat_deg, o.lon_deg, o.alt_m
    )
    return float(lat), float(lon), float(alt)


def _settle(
    fleet: MockFleet,
    names: Sequence[str],
    starts_enu_m: Mapping[str, Sequence[float]],
    timeout_s: float,
    *,
    reposition: bool,
    yaw: Mapping[str, float],
) -> None:
    """Advance until every vehicle is in the air; reposition onto the starts; settle."""
    vs = fleet.vehicles
    goal = np.array([[float(x) for x in starts_enu_m[n]] for n in names])
    t = 0.0
    moved = not reposition
    while t < timeout_s:
        fleet.advance(0.1)
        t += 0.1
        up = all(v.mode is Px4Mode.AUTO_LOITER and not v.landed for v in vs)
        if up and not moved:
            for name, v in zip(names, vs, strict=True):
                lat, lon, alt = _geodetic(fleet, starts_enu_m[name])
                _command_int(
                    v,
                    mavlink2.MAV_CMD_DO_REPOSITION,
                    -1.0,
                    1.0,
                    0.0,
                    # radians, as MAVSDK's goto_location sends it and PX4 reads it (the
                    # flight repositions with Vehicle.goto; see mock commands' reposition)
                    math.radians(yaw.get(name, math.nan)),
                    lat_e7=round(lat * 1e7),
                    lon_e7=round(lon * 1e7),
                    alt=alt,
                )
            moved = True
            continue
        if moved:
            d = np.linalg.norm(fleet.truth_enu_m() - goal, axis=1)
            speed = np.linalg.norm(fleet.physics.true_vel_ned_m_s, axis=1)
            if np.all(d < _SETTLE_DIST_M) and np.all(speed < _SETTLE_SPEED_M_S):
                return
