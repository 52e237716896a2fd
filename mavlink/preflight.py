"""The checks before a plan starts, shared by the offboard and the mission flights.

:func:`check_start` refuses a vehicle too far from its planned start,
:func:`check_takeoff_height` a take-off PX4 would not leave the ground for
(:data:`TAKEOFF_MARGIN_M`), and :func:`wait_settled` is the arrival gate: the plan starts
once the vehicle has settled on its start. Each raises :class:`PreflightError` naming the
vehicle.

A room of its own because both :func:`mavlink.offboard.fly_offboard` and the mission
flight (``gcs.flight.mission``) run these checks, before anything is armed or streamed.
"""

from __future__ import annotations

import math

import numpy as np

from mavlink.errors import LinkLostError, PreflightError
from mavlink.link.vehicle import Vehicle
from mavlink.link.vehicle_status import VehicleStatus
from planner.frames import GeodeticPoint, ned_to_enu

#: How far above NAV_MC_ALT_RAD a start must be for a take-off from the ground (m): PX4
#: counts a take-off within NAV_MC_ALT_RAD as reached at once (docs/px4-behaviour.md).
TAKEOFF_MARGIN_M = 0.2


def _vec(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:.2f}" for x in np.ravel(p)) + ")"


def check_start(
    st: VehicleStatus,
    start_ned_m: np.ndarray,
    *,
    tolerance_m: float,
    on_ground: bool,
    mission_origin: GeodeticPoint,
    vehicle_origin: GeodeticPoint,
) -> None:
    """Refuse a vehicle that is too far from its planned start.

    On the ground only the horizontal distance counts (it will climb
    vertically to the start); in the air the 3-D distance.

    Raises:
        PreflightError: naming the vehicle, both positions in the mission
            frame, the distance and the tolerance.
    """
    if st.pos_ned_m is None:
        raise PreflightError("no local position reported", vehicle=st.name, url=st.url)
    here = np.asarray(st.pos_ned_m)
    delta = here - start_ned_m
    dist = float(np.linalg.norm(delta[:2] if on_ground else delta))
    if dist > tolerance_m:
        here_enu = ned_to_enu(here, mission_origin, vehicle_origin)
        start_enu = ned_to_enu(start_ned_m, mission_origin, vehicle_origin)
        what = "horizontally " if on_ground else ""
        raise PreflightError(
            f"refused: it is {dist:.2f} m {what}from its planned start "
            f"(tolerance {tolerance_m:.2f} m): at ENU {_vec(here_enu)} m, "
            f"plan starts at ENU {_vec(start_enu)} m (mission frame)",
            vehicle=st.name,
            url=st.url,
        )


async def check_takeoff_height(v: Vehicle, start_alt_amsl_m: float, margin_m: float) -> None:
    """Refuse a take-off to a start PX4 would not leave the ground for.

    PX4 counts a take-off (and a mission's take-off item: ``MissionBase::checkClimbRequired``)
    within NAV_MC_ALT_RAD of the vehicle as reached at once, and below about 1 m its altitude
    estimate creeps up in ground effect while the vehicle sits on the ground
    (docs/px4-behaviour.md: such starts stayed on the ground, then were auto-disarmed).

    Raises:
        PreflightError: the start is less than NAV_MC_ALT_RAD + ``margin_m`` above the
            vehicle (its altitude estimate), naming both figures.
    """
    st = await v.wait_for(lambda s: s.position is not None, "global position", timeout_s=5.0)
    assert st.position is not None
    alt_rad = await v.param("NAV_MC_ALT_RAD")
    said = "" if alt_rad is not None else " (PX4's default; the vehicle did not report it)"
    alt_rad = 0.8 if alt_rad is None else alt_rad
    above = start_alt_amsl_m - st.position.alt_m
    if above <= alt_rad + margin_m:
        raise PreflightError(
            f"refused: the plan starts {above:.2f} m above the vehicle; PX4 takes off only "
            f"to a first waypoint more than NAV_MC_ALT_RAD = {alt_rad:g} m{said} above it "
            f"(this check keeps {margin_m:g} m more): plan a higher start, or take off by "
            "hand and fly from the air",
            vehicle=v.name,
            url=v.url,
        )


def _heading_error_deg(st: VehicleStatus, yaw_deg: float) -> float:
    if not math.isfinite(yaw_deg):
        return 0.0
    if st.heading_deg is None:
        return math.inf
    return abs((st.heading_deg - yaw_deg + 180.0) % 360.0 - 180.0)


async def wait_settled(
    v: Vehicle,
    target_ned_m: np.ndarray,
    *,
    arrive_m: float,
    settle_speed_m_s: float,
    dwell_s: float,
    timeout_s: float,
    yaw_deg: float = math.nan,
    yaw_tolerance_deg: float = 10.0,
    poll_s: float = 0.05,
) -> VehicleStatus:
    """Wait until ``v`` has settled on ``target_ned_m``: the arrival gate of a start.

    Settled means, over the last ``dwell_s``: the mean of its position estimate within
    ``arrive_m`` of the target (3-D), the mean velocity below ``settle_speed_m_s``, no
    sample farther than ``arrive_m`` + 0.3 m, and the heading on ``yaw_deg`` (NED, if
    finite). Means, because PX4's estimate is noisy (velocity noise of 0.1-0.3 m/s on SIH):
    a vehicle holding its start still jitters around it.

    Raises:
        PreflightError: not settled within ``timeout_s`` (names the distance, speed, heading).
        LinkLostError: the link was lost meanwhile.
    """
    t_end = v.clock.monotonic() + timeout_s
    window: list[tuple[float, np.ndarray, np.ndarray]] = []
    dist = speed = math.inf
    yaw_err = 0.0
    while True:
        st = v.status()
        if st.heartbeat_age_s is not None and not st.connected:
            raise LinkLostError("link lost while waiting at the start", vehicle=v.name, url=v.url)
        now = v.clock.monotonic()
        if st.pos_ned_m is not None and st.vel_ned_m_s is not None:
            window.append((now, np.asarray(st.pos_ned_m, float), np.asarray(st.vel_ned_m_s, float)))
            while window and window[0][0] < now - dwell_s:
                window.pop(0)
            pos = np.array([w[1] for w in window])
            vel = np.array([w[2] for w in window])
            dist = float(np.linalg.norm(pos.mean(axis=0) - target_ned_m))
            speed = float(np.linalg.norm(vel.mean(axis=0)))
            worst = float(np.linalg.norm(pos - target_ned_m, axis=1).max())
            yaw_err = _heading_error_deg(st, yaw_deg)
            spans = now - window[0][0] >= dwell_s * 0.9 or dwell_s == 0.0
            if (
                spans
                and dist <= arrive_m
                and worst <= arrive_m + 0.3
                and speed <= settle_speed_m_s
                and yaw_err <= yaw_tolerance_deg
            ):
                return st
        if now >= t_end:
            raise PreflightError(
                f"did not settle at its start in {timeout_s:.0f} s: {dist:.2f} m away on average "
                f"(gate {arrive_m:.2f} m), {speed:.2f} m/s, heading off by {yaw_err:.0f} deg",
                vehicle=v.name,
                url=v.url,
            )
        await v.clock.sleep(poll_s)
