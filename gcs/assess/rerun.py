"""One run of an assessment again: its tracks as CSV, or its disturbances flown in real time.

``gcs assess PLAN --replay SEED`` flies the run with that seed again in the batch simulator
(the same draws, the same noise, the same flight) and writes its true and reported tracks as
CSV that ``gcs verify --telemetry`` and ``gcs plot --telemetry`` read.  With ``--realtime`` it
flies the run's disturbances against the real-time mock vehicles as ``gcs fly --dry-run`` does
(MAVLink over UDP, MAVSDK, the safety monitor): the same mean wind and gust strength, the same
link latency, jitter and loss, the same estimator and EKF-origin magnitudes, the same derated
limits, a vehicle lost at the same plan time.  What cannot be the same there is the random *realisation* (the gusts' and the
estimate's noise, the EKF origin's direction, the start error), which the real-time mock draws
from its own seed on its own clock.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gcs.errors import UserError
from gcs.flight import FlyOptions, fly_plan, signed_links, vehicle_specs
from gcs.flight.dryrun import mock_vehicles
from gcs.flight.progress import FlightProgress
from mavlink.mock.sim.batch import estimator_overrides
from mavlink.mock.sim.config import FaultConfig, MockVehicleConfig, WindConfig
from mavlink.mock.sim.errors import MockConfigError
from mavlink.mock.sim.params import vehicle_params
from mavlink.mock.sim.px4 import PARAM_SPECS
from mavlink.mock.vehicle_faults import VehicleFault

if TYPE_CHECKING:
    from gcs.assess import AssessOptions
    from gcs.flight.outcome import FlightOutcome
    from mavlink.mock.sim.batch import BatchFlights
    from planner.planfile import Plan

__all__ = ["fly_realtime", "realtime_configs", "write_replay_csv"]


def write_replay_csv(flights: BatchFlights, names: tuple[str, ...], out_dir: Path) -> list[Path]:
    """``replay_SEED_true.csv`` and ``replay_SEED_reported.csv`` (columns ``t,vehicle,x,y,z``
    and, when recorded, ``yaw``: mission ENU, the heading as ENU yaw in rad, the plan's check
    grid) of the first run of ``flights``."""
    seed = int(flights.seeds[0])
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for what, arr, yaw in (
        ("true", flights.true_enu_m, flights.true_yaw_enu_rad),
        ("reported", flights.reported_enu_m, flights.reported_yaw_enu_rad),
    ):
        path = out_dir / f"replay_{seed}_{what}.csv"
        lines = ["t,vehicle,x,y,z" + (",yaw" if yaw is not None else "")]
        for v, name in enumerate(names):
            for k, (t, p) in enumerate(zip(flights.t_s, arr[0, v], strict=True)):
                row = f"{t:.3f},{name},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f}"
                lines.append(row + (f",{yaw[0, v, k]:.6f}" if yaw is not None else ""))
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
        paths.append(path)
    return paths


def _derated(prm: Mapping[str, float], d: float) -> dict[str, float]:
    """The limits ``derate`` scales, as PX4 parameters (the tilt through its tangent)."""
    out = {
        k: prm[k] * d
        for k in (
            "MPC_XY_VEL_MAX",
            "MPC_Z_VEL_MAX_UP",
            "MPC_Z_VEL_MAX_DN",
            "MPC_ACC_HOR",
            "MPC_ACC_HOR_MAX",
            "MPC_ACC_UP_MAX",
            "MPC_ACC_DOWN_MAX",
        )
    }
    tilt = math.radians(prm["MPC_TILTMAX_AIR"])
    out["MPC_TILTMAX_AIR"] = math.degrees(math.atan(d * math.tan(tilt)))
    return out


def realtime_configs(plan: Plan, opts: AssessOptions, flights: BatchFlights) -> tuple[Any, Any]:
    """The real-time mock's vehicle configurations and wind for the first run of ``flights``.

    Raises:
        UserError: a drawn value the real-time mock cannot take (a parameter out of range).
    """

    specs = {p.name: p for p in PARAM_SPECS}
    prm = vehicle_params(opts.profile, opts.params)
    d = {k: np.asarray(v)[0] for k, v in flights.draws.items()}

    def one(name: str, v: int) -> float:
        a = np.atleast_1d(d[name])
        return float(a[v] if a.size > 1 else a[0])

    configs = []
    try:
        for v, spawn in enumerate(plan.ground_spawns()):
            params = dict(opts.params)
            params.update(estimator_overrides(prm, one("estimator", v), one("ekf_origin", v)))
            params.update(_derated(prm, one("derate", v)))
            for k, value in params.items():
                spec = specs[k]
                if not spec.accepts(value):
                    raise UserError(
                        f"--realtime: {k} = {value:g} outside what the mock takes "
                        f"[{spec.min:g}, {spec.max:g}]"
                    )
            faults = FaultConfig(
                loss_to_vehicle=one("loss", v),
                latency_s=one("latency_s", v),
                jitter_s=one("jitter_s", v),
            )
            configs.append(
                MockVehicleConfig(
                    spawn_enu_m=spawn,
                    faults=faults,
                    params=tuple(params.items()),
                    profile=opts.profile,
                )
            )
        speed, frm = one("wind_m_s", 0), math.radians(one("wind_from_deg", 0))
        wind = WindConfig(
            mean_ne_m_s=(-speed * math.cos(frm), -speed * math.sin(frm)),
            gust_sigma_m_s=one("gust_m_s", 0),
            gust_tau_s=one("gust_tau_s", 0),
        )
    except MockConfigError as exc:
        raise UserError(f"--realtime: {exc}") from None
    return configs, wind


def fly_realtime(
    plan: Plan, opts: AssessOptions, flights: BatchFlights, *, seed: int, out: Any = None
) -> FlightOutcome:
    """Fly the first run's disturbances of ``flights`` on real-time mock vehicles
    (``gcs fly --dry-run``'s path: take-off, arrival gate, offboard at ``opts.rate_hz``)."""

    configs, wind = realtime_configs(plan, opts, flights)
    # a vehicle the run lost (disturbance ``lost``) is lost at the same plan time here
    lost = [
        (v, VehicleFault("lost", float(t)))
        for v, t in enumerate(np.asarray(flights.lost_s)[0])
        if math.isfinite(t)
    ]
    with mock_vehicles(
        plan,
        seed=seed % (2**32),
        profile=opts.profile,
        vehicle_configs=configs,
        wind=wind,
        faults=lost,
    ) as dry:
        options = FlyOptions(
            rate_hz=opts.rate_hz, drag_per_s=opts.drag_per_s, on_plan_start=dry.mock.plan_started
        )
        specs = vehicle_specs(plan, list(dry.urls))
        progress = FlightProgress(plan, out) if out is not None else None

        async def flight() -> FlightOutcome:
            async with signed_links(specs, None) as links:
                return await fly_plan(plan, links, options, progress=progress, clock=dry.clock)

        return asyncio.run(flight())
