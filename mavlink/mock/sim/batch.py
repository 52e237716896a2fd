"""Many offboard flights of one plan at once, faster than real time: the batch simulator.

``gcs assess`` flies a plan hundreds or thousands of times under drawn disturbances
(:mod:`mavlink.mock.sim.disturbances`).  Here every run and every vehicle is one row of one
:class:`~mavlink.mock.sim.physics.FleetPhysics`, stepped together as numpy arrays at the physics
rate, with no UDP, no asyncio and no MAVLink: the *same* physics, controller and estimator
code as the real-time mock vehicle (``gcs mock``, ``gcs fly --dry-run``), set up from the same
PX4 parameters by the same functions (:func:`mavlink.mock.sim.params.apply_controller_params`,
:func:`~mavlink.mock.sim.params.mode_limits`, :meth:`FleetEstimator.configure`).

What a run flies is what ``gcs fly`` streams in offboard mode (docs/architecture.md, "The MAVLink side"): the plan
sampled at ``rate_hz`` into local-NED setpoints by :func:`mavlink.plan_setpoints.plan_setpoints_ned`
(position, velocity and acceleration with the drag fed forward, yaw), preceded by the start
setpoint for ``settle_s`` (the pre-stream and the arrival gate).  The setpoint link is modelled
per setpoint: it arrives ``latency + U(0, jitter)`` after it was sent, or never (``loss``); the
vehicle flies the last one that arrived; and when none has arrived for ``COM_OF_LOSS_T`` it
leaves offboard for good, as PX4 does (``COM_OBL_RC_ACT``: Hold, Land or disarm).

A run starts hovering at equilibrium in its wind, ``start_error_m`` from its start; it is
recorded on the plan's check grid ``t = 0, check_dt, ..., horizon``: its *true* position at
every sample, and the position it *reported* (its estimate, in the mission frame through its
EKF origin) as ``gcs fly`` sees it: sampled at the telemetry rate and interpolated linearly
onto the grid, as ``gcs fly`` resamples its telemetry before judging the flight (judged at
every physics step instead, the estimate's noise would count several times more often and
read systematically lower robustness than the flight reports).

Reproducibility: a run is determined by its seed alone (with the plan, the distributions and
the vehicle profile).  Its disturbances, its gusts, its estimator noise and its link each draw
from a generator of their own, spawned from the run's seed; the physics draws its noise per
row from those per-run generators (:class:`_RowStreams`), so a run flies the same whichever
batch it is in and wherever that batch runs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from mavlink.mock.sim import px4
from mavlink.mock.sim.config import NoiseConfig
from mavlink.mock.sim.disturbances import Distribution, draw_disturbances
from mavlink.mock.sim.errors import MockConfigError
from mavlink.mock.sim.estimator import EstimatorParams
from mavlink.mock.sim.params import (
    ModeLimits,
    apply_controller_params,
    apply_limits,
    mode_limits,
    vehicle_params,
)
from mavlink.mock.sim.physics import FleetPhysics, terrain_ground
from mavlink.mock.sim.profiles import DEFAULT_PROFILE
from mavlink.mock.sim.px4 import Px4Mode
from mavlink.plan_setpoints import plan_setpoints_ned
from mavlink.tracks import wrap_pi

if TYPE_CHECKING:
    from mavlink.monitor import SafetyMonitor
    from mavlink.monitor_findings import RunFindings
    from planner.frames import GeodeticPoint, NedToEnuMap
    from planner.trajectory import Trajectory


class PlannedVehicleLike(Protocol):
    """What the simulator reads of a planned vehicle (:class:`planner.planfile.PlannedVehicle`)."""

    @property
    def name(self) -> str: ...
    @property
    def start_enu_m(self) -> Any: ...
    @property
    def trajectory(self) -> Trajectory: ...


class PlanLike(Protocol):
    """What the simulator reads of a plan (:class:`planner.planfile.Plan`; the link layer
    does not import the plan file, docs/architecture.md, "The parts and their direction")."""

    @property
    def origin(self) -> GeodeticPoint: ...
    @property
    def horizon_s(self) -> float: ...
    @property
    def check_dt_s(self) -> float: ...
    @property
    def vehicles(self) -> Sequence[PlannedVehicleLike]: ...
    @property
    def terrain(self) -> Any: ...
    def ground_spawns(self) -> list[tuple[float, float, float]]: ...


__all__ = [
    "BatchFlights",
    "SimSetup",
    "estimator_overrides",
    "prepare",
    "run_seed",
    "simulate",
]

#: How the offboard-loss failsafe ends a run's flight, by COM_OBL_RC_ACT.
_FAILSAFE_KIND = {Px4Mode.AUTO_LOITER: "hold", Px4Mode.AUTO_LAND: "land", None: "disarm"}


def run_seed(campaign_seed: int, run: int) -> int:
    """The seed of run ``run`` of a campaign: a 63-bit integer that alone reproduces the run
    (independent of how many runs the campaign has and how they are split)."""
    state = np.random.SeedSequence(campaign_seed, spawn_key=(run,)).generate_state(2, np.uint32)
    return (int(state[0]) << 31) ^ int(state[1])


class _RowStreams:
    """A stand-in for ``numpy.random.Generator`` that the physics and the estimator draw from:
    ``standard_normal((rows, k))`` gives each run's rows numbers from that run's own generator.

    Every run of a batch is asked for the same amount at the same time (``rows`` = runs x
    vehicles, run-major), so a shared cursor serves all; each run's numbers come from its own
    generator in blocks, so they do not depend on the batch.
    """

    def __init__(
        self, rngs: Sequence[np.random.Generator], per_run: int, k: int, block_ticks: int
    ) -> None:
        self._rngs = rngs
        self._need = per_run * k  # numbers per run and call (one call site per stream)
        self._k = k
        # float32 draws: twice as fast, and far finer than the noise they scale
        self._buf = np.empty((len(rngs), self._need * block_ticks), dtype=np.float32)
        self._cur = self._buf.shape[1]

    def standard_normal(self, shape: tuple[int, int]) -> np.ndarray:
        rows, k = shape
        if k != self._k:
            raise ValueError(f"this stream serves (rows, {self._k}), asked for {shape}")
        if self._cur + self._need > self._buf.shape[1]:
            for g, row in zip(self._rngs, self._buf, strict=True):
                g.standard_normal(out=row, dtype=np.float32)
            self._cur = 0
        out = self._buf[:, self._cur : self._cur + self._need].reshape(rows, k)
        self._cur += self._need
        return out


@dataclass(frozen=True, slots=True, eq=False)
class SimSetup:
    """What every run of a plan shares: the vehicle's parameters and the setpoint stream.

    Attributes:
        names: the vehicles, plan order.
        params: the vehicles' PX4 parameters (profile plus overrides).
        dt_s: physics step.
        rate_hz: setpoint rate.
        settle_s: how long the start setpoint is streamed before the plan's start.
        stride: physics steps per check-grid step.
        samples: check-grid samples (``horizon / check_dt + 1``).
        t_send_s: ``(K,)`` when each setpoint is sent (s from the plan's start; negative:
            the start setpoint before it).
        sp_pos_ned_m, sp_vel_ned_m_s, sp_acc_ned_m_s2: ``(V, K, 3)`` setpoints of each
            vehicle in its *spawn* frame (NED, origin at the true spawn point).
        sp_yaw_rad: ``(V, K)`` headings.
        to_mission: per vehicle, the spawn frame's NED -> mission ENU map.
        failsafe: what the offboard-loss failsafe does (``hold``, ``land``, ``disarm``).
        drag_per_s: the drag fed forward (1/s).
        plans: per vehicle, its planned trajectory (what the safety monitor predicts from).
        telemetry_hz: how often the reported position is sampled (``gcs fly`` asks each
            vehicle for 20 Hz, :class:`mavlink.link.fleet.Fleet`).
        spawns_enu_m: ``(V, 3)`` each vehicle's spawn (mission ENU: on the ground below its
            start); ground: the plan's terrain (:class:`planner.spec.terrain.Terrain`) the
            vehicles stand and land on, or None (flat at each spawn).
    """

    names: tuple[str, ...]
    params: Mapping[str, float]
    dt_s: float
    rate_hz: float
    settle_s: float
    stride: int
    samples: int
    t_send_s: np.ndarray
    sp_pos_ned_m: np.ndarray
    sp_vel_ned_m_s: np.ndarray
    sp_acc_ned_m_s2: np.ndarray
    sp_yaw_rad: np.ndarray
    to_mission: tuple[NedToEnuMap, ...]
    failsafe: str
    drag_per_s: float
    plans: Mapping[str, Trajectory]
    telemetry_hz: float
    spawns_enu_m: np.ndarray | None = None
    ground: Any = None

    @property
    def ticks(self) -> int:
        """Physics steps of a run: the settling and the plan's horizon."""
        return round(self.settle_s / self.dt_s) + (self.samples - 1) * self.stride


def prepare(
    plan: PlanLike,
    *,
    profile: str = DEFAULT_PROFILE,
    params: Mapping[str, float] | None = None,
    rate_hz: float = 20.0,
    drag_per_s: float | None = None,
    settle_s: float = 3.0,
    physics_rate_hz: float = 100.0,
    telemetry_hz: float = 20.0,
) -> SimSetup:
    """The shared part of a plan's runs (see :class:`SimSetup`).

    Each vehicle spawns on the ground below its planned start (as in a dry run,
    :meth:`planner.planfile.Plan.ground_spawns`); ``drag_per_s`` ``None`` feeds forward the vehicle's
    own drag (SIH_KDV / SIH_MASS), as ``gcs fly`` does after reading it from the vehicle.

    Raises:
        MockConfigError: bad parameters, a check step that is not a whole number of physics
            steps, or an offboard-loss action the simulator does not fly (Return).
    """
    from planner.frames import GeodeticPoint as Geo
    from planner.frames import NedToEnuMap, enu_to_geodetic

    prm = vehicle_params(profile, params)
    if not (2.0 < rate_hz <= 100.0):
        raise MockConfigError(f"setpoint rate {rate_hz!r} Hz outside (2, 100]")
    if not (math.isfinite(settle_s) and settle_s >= 1.0):
        raise MockConfigError(f"settle_s must be >= 1 s (PX4's pre-stream), got {settle_s!r}")
    dt = 1.0 / physics_rate_hz
    tel = 1.0 / (telemetry_hz * dt)
    if not (math.isfinite(tel) and tel >= 1.0 and abs(tel - round(tel)) < 1e-9):
        raise MockConfigError(
            f"telemetry at {telemetry_hz!r} Hz is not a whole number of physics steps ({dt:g} s)"
        )
    stride = round(plan.check_dt_s / dt)
    if stride < 1 or abs(stride * dt - plan.check_dt_s) > 1e-9:
        raise MockConfigError(
            f"the plan's check step {plan.check_dt_s:g} s is not a whole number of physics "
            f"steps ({dt:g} s)"
        )
    action = px4.OBL_ACTION_MODES.get(int(prm["COM_OBL_RC_ACT"]), Px4Mode.AUTO_LOITER)
    if action not in _FAILSAFE_KIND:
        what = action.name if action is not None else "?"
        raise MockConfigError(
            f"COM_OBL_RC_ACT = {int(prm['COM_OBL_RC_ACT'])} (offboard loss: {what}) is "
            "not simulated: choose Hold (0), Land (4) or Disarm (7)"
        )
    kdv = prm["SIH_KDV"] / prm["SIH_MASS"]
    drag = kdv if drag_per_s is None else float(drag_per_s)
    pre = round(settle_s * rate_hz)
    pos, vel, acc, yaw, maps = [], [], [], [], []
    spawns = np.array(plan.ground_spawns(), dtype=float).reshape(-1, 3)
    for v, spawn in zip(plan.vehicles, spawns, strict=True):
        lat, lon, alt = enu_to_geodetic(spawn, plan.origin)
        spawn_geo = Geo(float(lat), float(lon), float(alt))
        sp = plan_setpoints_ned(v.trajectory, rate_hz, plan.origin, spawn_geo, drag_per_s=drag)
        still = np.zeros((pre, 3))
        pos.append(np.vstack([np.repeat(sp.pos_ned_m[:1], pre, axis=0), sp.pos_ned_m]))
        vel.append(np.vstack([still, sp.vel_ned_m_s]))
        acc.append(np.vstack([still, sp.acc_ned_m_s2]))
        yaw.append(np.concatenate([np.repeat(sp.yaw_ned_rad[:1], pre), sp.yaw_ned_rad]))
        maps.append(NedToEnuMap.between(plan.origin, spawn_geo))
    k = min(len(p) for p in pos)
    t_send = (np.arange(k) - pre) / rate_hz
    return SimSetup(
        names=tuple(v.name for v in plan.vehicles),
        params=dict(prm),
        dt_s=dt,
        rate_hz=float(rate_hz),
        settle_s=pre / rate_hz,
        stride=stride,
        samples=round(plan.horizon_s / plan.check_dt_s) + 1,
        t_send_s=t_send,
        sp_pos_ned_m=np.stack([p[:k] for p in pos]),
        sp_vel_ned_m_s=np.stack([p[:k] for p in vel]),
        sp_acc_ned_m_s2=np.stack([p[:k] for p in acc]),
        sp_yaw_rad=np.stack([p[:k] for p in yaw]),
        to_mission=tuple(maps),
        failsafe=_FAILSAFE_KIND[action],
        drag_per_s=drag,
        plans={v.name: v.trajectory for v in plan.vehicles},
        telemetry_hz=float(telemetry_hz),
        spawns_enu_m=spawns,
        ground=plan.terrain,
    )


@dataclass(frozen=True, slots=True, eq=False)
class BatchFlights:
    """The recorded runs of one batch.

    Attributes:
        seeds: ``(R,)`` each run's seed.
        t_s: ``(S,)`` the check grid (s from the plan's start).
        reported_enu_m: ``(R, V, S, 3)`` what each vehicle reported (its estimate), mission ENU.
        true_enu_m: ``(R, V, S, 3)`` where it really was.
        failsafe_s: ``(R, V)`` when the offboard-loss failsafe took it (NaN: never).
        lost_s: ``(R, V)`` when the vehicle was lost (disturbance ``lost``; inf: never).
        draws: per disturbance, ``(R, 1)`` or ``(R, V)`` the values drawn.
        stop_s: ``(R,)`` with a safety monitor, when it stopped the run (s from the plan's
            start; NaN: never); ``None`` without a monitor.
        stop: with a safety monitor, what it found when it stopped each run.
        true_yaw_enu_rad: ``(R, V, S)`` each vehicle's heading (mission ENU yaw, rad, in
            ``(-pi, pi]``) on the check grid; ``None``: not recorded.
        reported_yaw_enu_rad: ``(R, V, S)`` the heading as ``gcs fly`` records it (ATTITUDE
            at the telemetry rate, interpolated along the shorter turn); the mock reports
            its true heading, so this differs from the truth by the sampling only.
    """

    seeds: np.ndarray
    t_s: np.ndarray
    reported_enu_m: np.ndarray
    true_enu_m: np.ndarray
    failsafe_s: np.ndarray
    lost_s: np.ndarray
    draws: dict[str, np.ndarray]
    stop_s: np.ndarray | None = None
    stop: RunFindings | None = None
    true_yaw_enu_rad: np.ndarray | None = None
    reported_yaw_enu_rad: np.ndarray | None = None


def estimator_overrides(prm: Mapping[str, float], noise: float, origin: float) -> dict[str, float]:
    """The ``MOCK_*`` estimator parameters of a run: the estimate's noise and biases scaled by
    ``noise``, the EKF origin's offset by ``origin`` (the disturbances ``estimator`` and
    ``ekf_origin``); the simulator and ``gcs assess --realtime``'s mock vehicles both use it."""
    out = {k: prm[k] * noise for k in ("MOCK_EST_SLOW_B", "MOCK_EST_P_N", "MOCK_EST_V_N",
                                       "MOCK_EST_VB", "MOCK_EST_YAW_V")}  # fmt: skip
    for k in ("MOCK_ORG_XY_MIN", "MOCK_ORG_XY_MAX", "MOCK_ORG_Z_MIN", "MOCK_ORG_Z_MAX"):
        out[k] = prm[k] * origin
    return out


def simulate(
    setup: SimSetup,
    seeds: Sequence[int],
    dists: Mapping[str, Distribution],
    *,
    monitor: SafetyMonitor | None = None,
    block_ticks: int = 250,
    excused: Sequence[str] = (),
) -> BatchFlights:
    """Fly one batch of runs (one per seed) of the plan in ``setup`` under ``dists``.

    With ``monitor``, the flight-time safety monitor of ``gcs fly`` watches every run as it
    would a real flight: at its rate (half a period after the setpoints), on the reported
    positions and velocities, it stops a run when a clause is violated or predicted to fail,
    a vehicle strays past its off-plan bound, or a vehicle's own failsafe took it (the mode
    left); every vehicle of a stopped run then gets the monitor's action (Hold or Land),
    arriving after its link latency, and flies no more setpoints.  Not modelled: telemetry
    delay and loss (the monitor reads each tick's state), the heartbeat that reports a mode
    change (seen at the next tick), and a lost vehicle's silence towards the ground station
    (disturbance ``lost``: its setpoints stop, but the monitor still reads its state and its
    reported track goes on; the stop comes when its failsafe takes it, COM_OF_LOSS_T after
    its last setpoint, about when ``gcs fly`` calls the link lost).  ``excused`` vehicles
    left the flight before it is flown again (``gcs assess --replan``): their failsafe or
    silence is no stop.
    """
    n_runs, n_veh = len(seeds), len(setup.names)
    rows = n_runs * n_veh
    dt = setup.dt_s
    children = [np.random.SeedSequence(int(s)).spawn(4) for s in seeds]
    draw_rngs = [np.random.default_rng(c[0]) for c in children]
    gusts = _RowStreams([np.random.default_rng(c[1]) for c in children], n_veh, 2, block_ticks)
    est_noise = _RowStreams([np.random.default_rng(c[2]) for c in children], n_veh, 11, block_ticks)
    link_rngs = [np.random.default_rng(c[3]) for c in children]

    phys = FleetPhysics(rows, dt, np.random.default_rng(0), noise=NoiseConfig(0.0, 0.0))
    phys.attitude = False  # no ATTITUDE telemetry here
    phys.rng = gusts  # type: ignore[assignment]
    est = phys.estimator
    prm = setup.params
    apply_controller_params(phys, slice(None), prm)
    veh_of = np.tile(np.arange(n_veh), n_runs)

    # ---- each run's disturbances, its EKF origins and biases (the mock's own draws)
    draws = [draw_disturbances(dists, g, n_veh) for g in draw_rngs]
    table = {
        name: np.stack([d[name] for d in draws]) for name in (draws[0] if draws else {})
    }  # (R, 1) or (R, V)

    def per_row(name: str) -> np.ndarray:
        a = table[name]
        return np.repeat(a[:, 0], n_veh) if a.shape[1] == 1 else a.reshape(-1)

    for r, g in enumerate(draw_rngs):
        est.rng = g
        over = estimator_overrides(
            prm, float(table["estimator"][r, 0]), float(table["ekf_origin"][r, 0])
        )
        prm_r = EstimatorParams.from_params({**prm, **over})
        for v in range(n_veh):
            est.configure(r * n_veh + v, prm_r, new_boot=True)
    est.rng = est_noise  # type: ignore[assignment]
    # the offboard mode's limits, derated per vehicle
    derate = per_row("derate")
    limits = mode_limits(prm, Px4Mode.OFFBOARD, prm["MPC_XY_CRUISE"])
    apply_limits(phys, slice(None), limits, derate)
    # wind: the mean from its compass direction (the air moves the other way), the gusts
    speed = per_row("wind_m_s")
    frm = np.radians(per_row("wind_from_deg"))
    phys.wind_mean_ne_m_s = np.column_stack([-speed * np.cos(frm), -speed * np.sin(frm)])
    phys.gust_sigma_m_s = per_row("gust_m_s")
    phys.gust_tau_s = per_row("gust_tau_s")

    # ---- the start: hovering at equilibrium in the wind, start_error_m off the start
    start_err = per_row("start_error_m")
    ang = (
        np.concatenate([g.uniform(0.0, 2.0 * np.pi, n_veh) for g in draw_rngs])
        if rows
        else np.zeros(0)
    )
    origin = est.origin_ned_m  # the EKF origins in the spawn frames
    if setup.ground is not None and setup.spawns_enu_m is not None:
        phys.ground_of = terrain_ground(setup.ground, setup.spawns_enu_m[veh_of])
    phys.true_pos_ned_m[:] = setup.sp_pos_ned_m[veh_of, 0]
    phys.true_pos_ned_m[:, 0] += start_err * np.cos(ang)
    phys.true_pos_ned_m[:, 1] += start_err * np.sin(ang)
    if phys.ground_of is not None:
        phys.ground_d_m = phys.ground_of(phys.true_pos_ned_m)
    phys.yaw_rad[:] = setup.sp_yaw_rad[veh_of, 0]
    phys.armed[:] = True
    phys.idle[:] = False
    kdv = phys.kdv_per_s
    wind_force = np.where(
        (kdv > 0.0)[:, None],
        kdv[:, None] * phys.wind_mean_ne_m_s,
        phys.wind.drag_per_s * phys.wind_mean_ne_m_s,
    )
    phys._vel_int[:, :2] = -wind_force
    phys._acc_tilt[:] = -wind_force
    phys.acc_ned_m_s2[:, :2] = -wind_force
    phys.update_estimate()

    # ---- the setpoint link: when each setpoint arrives at each row (-1: lost)
    n_sp = setup.t_send_s.size
    settle_ticks = round(setup.settle_s / dt)
    latency = per_row("latency_s")
    jitter = per_row("jitter_s")
    loss = per_row("loss")
    u_jit = (
        np.concatenate([g.random((n_veh, n_sp)) for g in link_rngs])
        if rows
        else np.zeros((0, n_sp))
    )
    u_loss = (
        np.concatenate([g.random((n_veh, n_sp)) for g in link_rngs])
        if rows
        else np.zeros((0, n_sp))
    )
    arrive_s = setup.t_send_s[None, :] + setup.settle_s + latency[:, None] + jitter[:, None] * u_jit
    arrive_tick = np.ceil(arrive_s / dt - 1e-9).astype(np.int64)
    arrive_tick[u_loss < loss[:, None]] = -1
    # a vehicle lost for good (disturbance ``lost``): nothing arrives from a time uniform over
    # the plan (drawn after the run's other link draws, so earlier campaigns stay as they were)
    horizon_s = (setup.samples - 1) * setup.stride * dt
    u_gone = np.concatenate([g.random(n_veh) for g in link_rngs]) if rows else np.zeros(0)
    t_gone = (
        np.concatenate([g.uniform(0.0, horizon_s, n_veh) for g in link_rngs])
        if rows
        else np.zeros(0)
    )
    lost_at_s = np.where(u_gone < per_row("lost"), t_gone, np.inf)
    arrive_tick[setup.t_send_s[None, :] >= lost_at_s[:, None]] = -1
    arrive_tick[:, 0] = 0  # the vehicle already flies the start setpoint
    ev_row, ev_k = np.nonzero(arrive_tick >= 0)
    ev_tick = arrive_tick[ev_row, ev_k]
    order = np.lexsort((ev_k, ev_tick))
    ev_row, ev_k, ev_tick = ev_row[order], ev_k[order], ev_tick[order]
    n_ticks = setup.ticks
    bounds = np.searchsorted(ev_tick, np.arange(n_ticks + 2))

    cur = np.zeros(rows, dtype=np.int64)
    last_arrival_s = np.zeros(rows)
    loss_t = prm["COM_OF_LOSS_T"]
    failed = np.zeros(rows, dtype=bool)  # the offboard-loss failsafe took it
    off = np.zeros(rows, dtype=bool)  # no longer flies setpoints (failsafe, or stopped)
    failsafe_s = np.full(rows, np.nan)
    watch = (
        _MonitorState(monitor, setup, n_runs, n_ticks, settle_ticks, latency, lost_at_s, excused)
        if monitor
        else None
    )
    auto_limits = mode_limits(prm, Px4Mode.AUTO_LOITER, prm["MPC_XY_CRUISE"])
    newest = np.full(rows, -1, dtype=np.int64)
    tel_stride = round(1.0 / (setup.telemetry_hz * dt))
    n_tel = (setup.samples - 1) * setup.stride // tel_stride + 1
    rec_rep = np.zeros((rows, n_tel, 3))  # the reported position, at the telemetry rate
    rec_true = np.zeros((rows, setup.samples, 3))
    yaw_rep = np.zeros((rows, n_tel))  # the heading (spawn NED): reported, and true
    yaw_true = np.zeros((rows, setup.samples))
    phys.m_pos[:] = 1.0
    phys.m_vel[:] = 1.0
    phys.m_acc[:] = 1.0
    phys.m_yaw[:] = True
    for n in range(n_ticks + 1):
        t_n = n * dt
        lo, hi = bounds[n], bounds[n + 1]
        if hi > lo:
            r_e, k_e = ev_row[lo:hi], ev_k[lo:hi]
            np.maximum.at(newest, r_e, k_e)  # two in one step: the later setpoint wins
            got = newest >= 0
            cur[got] = newest[got]
            last_arrival_s[got] = t_n
            newest[r_e] = -1
        lost = ~off & (t_n - last_arrival_s > loss_t)
        if lost.any():
            _failsafe(phys, lost, setup.failsafe, prm, auto_limits, derate)
            failed |= lost
            off |= lost
            failsafe_s[lost] = t_n - setup.settle_s
        if watch is not None:
            held = watch.tick(n, phys, origin, failed, off)
            if held is not None:
                _failsafe(phys, held, watch.action, prm, auto_limits, derate)
                off |= held
        if hi > lo or lost.any():  # else nothing new arrived: the setpoints stay
            fly: slice | np.ndarray = slice(None) if not off.any() else ~off
            idx, v_i = cur[fly], veh_of[fly]
            phys.sp_pos_ned_m[fly] = setup.sp_pos_ned_m[v_i, idx] - origin[fly]
            phys.sp_vel_ned_m_s[fly] = setup.sp_vel_ned_m_s[v_i, idx]
            phys.sp_acc_ned_m_s2[fly] = setup.sp_acc_ned_m_s2[v_i, idx]
            phys.sp_yaw_rad[fly] = setup.sp_yaw_rad[v_i, idx]
        if n >= settle_ticks:
            # the state at this instant, before the step that leaves it
            j, rem = divmod(n - settle_ticks, setup.stride)
            if rem == 0:
                rec_true[:, j] = phys.true_pos_ned_m
                yaw_true[:, j] = phys.yaw_rad
            j, rem = divmod(n - settle_ticks, tel_stride)
            if rem == 0 and j < n_tel:
                rec_rep[:, j] = phys.pos_ned_m + origin
                yaw_rep[:, j] = phys.yaw_rad
        if n < n_ticks:
            phys.step()

    # ---- the reported track on the check grid as gcs fly makes it from the telemetry: linear
    # interpolation (mavlink.tracks.FlownTrack.resample), the last sample held past the end
    u = np.arange(setup.samples) * setup.stride / tel_stride  # check grid, in telemetry samples
    i0 = np.minimum(np.floor(u + 1e-9).astype(np.int64), n_tel - 1)
    i1 = np.minimum(i0 + 1, n_tel - 1)
    w = np.clip(u - i0, 0.0, 1.0)[None, :, None]
    rec_rep = rec_rep[:, i0] * (1.0 - w) + rec_rep[:, i1] * w
    yaw_rep = np.unwrap(yaw_rep, axis=1)  # the shorter turn between samples
    yaw_rep = yaw_rep[:, i0] * (1.0 - w[..., 0]) + yaw_rep[:, i1] * w[..., 0]
    # ---- into the mission frame, per vehicle
    rep = np.empty((n_runs, n_veh, setup.samples, 3))
    true = np.empty_like(rep)
    by_run_rep = rec_rep.reshape(n_runs, n_veh, setup.samples, 3)
    by_run_true = rec_true.reshape(n_runs, n_veh, setup.samples, 3)
    rep_yaw = np.empty((n_runs, n_veh, setup.samples))
    true_yaw = np.empty_like(rep_yaw)
    by_run_rep_yaw = yaw_rep.reshape(n_runs, n_veh, setup.samples)
    by_run_true_yaw = yaw_true.reshape(n_runs, n_veh, setup.samples)
    for v, m in enumerate(setup.to_mission):
        rep[:, v] = m.position(by_run_rep[:, v])
        true[:, v] = m.position(by_run_true[:, v])
        rep_yaw[:, v] = _yaw_to_mission(m, by_run_rep_yaw[:, v])
        true_yaw[:, v] = _yaw_to_mission(m, by_run_true_yaw[:, v])
    return BatchFlights(
        seeds=np.asarray(seeds, dtype=np.int64),
        t_s=np.arange(setup.samples) * setup.stride * dt,
        reported_enu_m=rep,
        true_enu_m=true,
        failsafe_s=failsafe_s.reshape(n_runs, n_veh),
        lost_s=lost_at_s.reshape(n_runs, n_veh),
        draws=table,
        stop_s=None if watch is None else watch.stop_s,
        stop=None if watch is None else watch.found,
        true_yaw_enu_rad=true_yaw,
        reported_yaw_enu_rad=rep_yaw,
    )


def _yaw_to_mission(to_mission: NedToEnuMap, yaw_ned_rad: np.ndarray) -> np.ndarray:
    """Headings in a spawn's NED frame (rad, clockwise from north) as mission-frame ENU yaws
    in ``(-pi, pi]``: the heading's unit vector through the same rotation as the positions."""
    h = np.stack([np.cos(yaw_ned_rad), np.sin(yaw_ned_rad), np.zeros_like(yaw_ned_rad)], axis=-1)
    enu = to_mission.vector(h)
    return wrap_pi(np.arctan2(enu[..., 1], enu[..., 0]))


class _MonitorState:
    """The safety monitor over a batch's runs: when it ticks, what it found, which stop
    commands are on their way (see :func:`simulate`)."""

    def __init__(
        self,
        monitor: SafetyMonitor,
        setup: SimSetup,
        n_runs: int,
        n_ticks: int,
        settle_ticks: int,
        latency_s: np.ndarray,
        lost_at_s: np.ndarray,
        excused: Sequence[str] = (),
    ) -> None:
        from mavlink.monitor_findings import RunFindings, SafetyAction, Verdict

        self.monitor = monitor
        self.setup = setup
        self.n_runs = n_runs
        self.n_veh = len(setup.names)
        self.settle_ticks = settle_ticks
        self.action = "land" if monitor.action is SafetyAction.LAND else "hold"
        period = 1.0 / (monitor.rate_hz * setup.dt_s)  # physics ticks per evaluation
        k = np.arange(int(n_ticks / period) + 1)
        ticks = settle_ticks + np.floor((k + 0.5) * period + 1e-9).astype(np.int64)
        self.is_tick = np.zeros(n_ticks + 1, dtype=bool)
        self.is_tick[ticks[ticks <= n_ticks]] = True
        self.delay = np.ceil(latency_s / setup.dt_s - 1e-9).astype(np.int64)  # per row
        self.arrives = np.full(n_runs * self.n_veh, -1, dtype=np.int64)
        self.stopped = np.zeros(n_runs, dtype=bool)
        self.stop_s = np.full(n_runs, np.nan)
        self.found = RunFindings.none(n_runs)
        self._left = RunFindings.code_of(Verdict.LEFT_MODE)
        self._silent = RunFindings.code_of(Verdict.LINK_LOST)
        #: per row, when the vehicle's link went silent for good (inf: never)
        self.lost_at_s = lost_at_s
        #: per vehicle, whether its departure (failsafe, silence) is no stop (it left the
        #: flight before and the others fly on: ``gcs fly --replan``)
        self.counts = np.array([n not in excused for n in setup.names], dtype=bool)

    def tick(
        self, n: int, phys: FleetPhysics, origin: np.ndarray, failed: np.ndarray, off: np.ndarray
    ) -> np.ndarray | None:
        """Evaluate at physics tick ``n`` if it is a monitor tick; the rows whose stop
        command arrives now (``None``: none)."""
        if self.is_tick[n]:
            self._evaluate(n, phys, origin, failed)
        due = (self.arrives == n) & ~off
        return due if due.any() else None

    def _evaluate(self, n: int, phys: FleetPhysics, origin: np.ndarray, failed: np.ndarray) -> None:
        live = ~self.stopped
        if not live.any():
            return
        t_s = (n - self.settle_ticks) * self.setup.dt_s
        shape = (self.n_runs, self.n_veh, 3)
        pos = (phys.pos_ned_m + origin).reshape(shape)[live]
        vel = phys.vel_ned_m_s.reshape(shape)[live]
        pos_enu = np.empty_like(pos)
        vel_enu = np.empty_like(vel)
        for v, m in enumerate(self.setup.to_mission):
            pos_enu[:, v] = m.position(pos[:, v])
            vel_enu[:, v] = m.vector(vel[:, v])
        got = self.monitor.evaluate_runs(t_s, self.setup.names, pos_enu, vel_enu, self.setup.plans)
        # a vehicle that left offboard (its own failsafe) stops the flight first, as the
        # flight's mode check runs before the clauses; one whose link went silent is seen
        # as lost (gcs fly: no telemetry for longer than COM_OF_LOSS_T, as long as PX4 waits
        # before its offboard-loss failsafe)
        by_run = failed.reshape(self.n_runs, self.n_veh)[live] & self.counts[None, :]
        left = by_run.any(axis=1)
        silent = (by_run & (self.lost_at_s.reshape(self.n_runs, self.n_veh)[live] <= t_s)).any(
            axis=1
        )
        got.code[left] = self._left
        got.code[silent] = self._silent
        got.clause[left] = -1
        got.value[left] = np.nan
        hit = got.code != 0
        if not hit.any():
            return
        runs = np.flatnonzero(live)[hit]
        for name in ("code", "clause", "value", "ahead_s"):
            getattr(self.found, name)[runs] = getattr(got, name)[hit]
        self.stopped[runs] = True
        self.stop_s[runs] = t_s
        rows = (runs[:, None] * self.n_veh + np.arange(self.n_veh)).ravel()
        self.arrives[rows] = n + self.delay[rows]


def _failsafe(
    phys: FleetPhysics,
    rows: np.ndarray,
    kind: str,
    prm: Mapping[str, float],
    limits: ModeLimits,
    derate: np.ndarray,
) -> None:
    """PX4 leaves offboard for good on ``rows``: Hold where it is, Land, or disarm."""
    apply_limits(phys, rows, limits, derate[rows])
    phys.hold_here(rows)
    if kind == "land":
        phys.m_pos[rows, 2] = 0.0
        phys.m_vel[rows, 2] = 1.0
        phys.sp_vel_ned_m_s[rows, 2] = prm["MPC_LAND_SPEED"]
    elif kind == "disarm":
        phys.armed[rows] = False
