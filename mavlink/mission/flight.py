"""PX4 missions flown together, on one clock: mission mode for :func:`mavlink.flight.fly`.

:class:`MissionDriver` supplies what is particular to missions in the engine's phases:

- the start is the mission's start waypoint (item 1, after the take-off) and the plan's
  heading there;
- before anything is armed, each vehicle's mission is uploaded and read back (retried as a
  whole on a bad link until read back as sent, within :class:`mavlink.mission.RetryPolicy`'s
  default budget);
- onto the starts: each vehicle is sent to its start in Hold (DO_REPOSITION) and must pass
  the arrival gate;
- release: every mission's current item is set to the start waypoint, and all vehicles are
  switched to AUTO.MISSION at one instant; each start is confirmed (heartbeat in
  AUTO.MISSION; a TEMPORARILY_REJECTED start is retried), and the median of the confirmed
  starts is the plan's t = 0 for all, each vehicle's skew from it recorded;
- flight: progress is read from MISSION_CURRENT (PX4 reports reached items only as the last
  one processed), and the vehicles are recorded until the plan's horizon is covered, so the
  flown data is judged on the shared clock; the monitor expects AUTO.MISSION, and a vehicle
  on its last item may be in the mode PX4 ends a mission in (Hold, Return, Land). A mission
  carries its own end, so nothing is commanded after it.
"""

from __future__ import annotations

import asyncio
from collections.abc import Mapping, Sequence

import numpy as np

from mavlink.errors import PreflightError
from mavlink.flight import DriverReport, StartGate, StartPoint, gather_or_raise, start_point
from mavlink.link.fleet import Fleet
from mavlink.link.vehicle import Vehicle
from mavlink.mission.items import MissionItem
from mavlink.mission.retries import upload_with_retries
from mavlink.mission.run import (
    MissionFollower,
    MissionRun,
    MissionStart,
    start_mission_confirmed,
)
from mavlink.monitor_findings import SafetyEvent
from mavlink.preflight import wait_settled
from mavlink.px4_modes import Px4Mode
from planner.frames import GeodeticPoint
from planner.trajectory import Trajectory

__all__ = ["MISSION_SLACK_S", "MissionDriver"]

#: Seconds after the plan's horizon a mission may still take before it is given up.
MISSION_SLACK_S = 30.0

#: The start waypoint's index in a converted mission (after the take-off item).
START_ITEM = 1


class MissionDriver:
    """Mission mode for :func:`mavlink.flight.fly` (the module docstring).

    Args:
        starts_enu_m: each vehicle's start in the mission frame (ENU, m), in plan order.
        yaw_deg: the plan's heading at each start (degrees from north).
        mission_origin: the mission frame's geodetic origin.
        horizon_s: the plan's horizon: the vehicles are recorded until it is covered.
        gate: the arrival gate at the starts.
        items: each vehicle's mission, its start waypoint at :data:`START_ITEM`, uploaded
            and read back before anything is armed; ``None``: the missions are on the
            vehicles already (``gcs upload`` sent them).

    Attributes:
        confirmed: after the release, each vehicle's confirmed start.
    """

    expected_mode = Px4Mode.AUTO_MISSION
    # PX4 takes a moment to report AUTO.MISSION after the start
    mode_grace_s = 1.5
    plans: Mapping[str, Trajectory] | None = None
    on_board = True

    def __init__(
        self,
        starts_enu_m: Mapping[str, np.ndarray],
        yaw_deg: Mapping[str, float],
        mission_origin: GeodeticPoint,
        horizon_s: float,
        gate: StartGate,
        *,
        items: Mapping[str, Sequence[MissionItem]] | None = None,
    ) -> None:
        self.names: Sequence[str] = list(starts_enu_m)
        self.items = items
        self.starts_enu_m = starts_enu_m
        self.yaw_deg = yaw_deg
        self.mission_origin = mission_origin
        self.horizon_s = horizon_s
        self.gate = gate
        self.confirmed: dict[str, MissionStart] = {}
        self._follower: MissionFollower | None = None
        self._done: dict[str, float] = {}

    def starts(self, origins: Mapping[str, GeodeticPoint]) -> dict[str, StartPoint]:
        return {
            n: start_point(self.starts_enu_m[n], self.yaw_deg[n], self.mission_origin, origins[n])
            for n in self.names
        }

    async def prepare(self, fleet: Fleet, vehicles: Sequence[Vehicle]) -> None:
        items = self.items
        if items is None:
            return
        # retried as a whole on a bad link, within the default budget, until read back as sent
        await asyncio.gather(*(upload_with_retries(v, items[v.name]) for v in vehicles))

    async def approach(
        self, fleet: Fleet, vehicles: Sequence[Vehicle], starts: Mapping[str, StartPoint]
    ) -> None:
        gate = self.gate

        async def to_start(v: Vehicle) -> None:
            s = starts[v.name]
            await v.goto(s.lat_deg, s.lon_deg, s.alt_amsl_m, s.yaw_deg)
            await wait_settled(
                v,
                s.ned_m,
                arrive_m=gate.arrive_m,
                settle_speed_m_s=gate.settle_speed_m_s,
                dwell_s=gate.dwell_s,
                timeout_s=gate.arrive_timeout_s,
                yaw_deg=s.yaw_deg,
                yaw_tolerance_deg=gate.yaw_tolerance_deg,
            )

        await gather_or_raise(to_start(v) for v in vehicles)

    async def release(self, fleet: Fleet, vehicles: Sequence[Vehicle]) -> float:
        """The start waypoint current everywhere, then AUTO.MISSION for all at one instant."""
        await asyncio.gather(*(v.set_current_item(START_ITEM) for v in vehicles))
        follower = MissionFollower(vehicles)
        follower.attach()
        self._follower = follower
        await fleet.clock.sleep(0.2)
        follower.t_start = fleet.clock.monotonic()
        started = await asyncio.gather(
            *(start_mission_confirmed(v, climb_m=None) for v in vehicles)
        )
        self.confirmed = {s.vehicle: s for s in started}
        refused = [s for s in started if not s.started]
        if refused:
            s = refused[0]
            raise PreflightError(
                f"mission start did not take effect: {s.detail}", vehicle=s.vehicle
            )
        t0 = float(np.median([s.t_accepted_monotonic_s for s in started]))
        follower.t_start = t0
        return t0

    async def abort(self) -> None:
        if self._follower is not None:
            self._follower.detach()
            self._follower = None

    def done(self, name: str) -> bool:
        # PX4 leaves AUTO.MISSION itself at the end: AUTO.RTL on a return item, AUTO.LOITER
        # where a mission without a landing ends
        return self._follower is not None and self._follower.at_end(name)

    async def run(
        self, fleet: Fleet, vehicles: Sequence[Vehicle], t0: float, stop: asyncio.Event
    ) -> None:
        assert self._follower is not None
        clock = fleet.clock
        self._done = await self._follower.until_finished(
            timeout_s=self.horizon_s + MISSION_SLACK_S - (clock.monotonic() - t0), stop=stop
        )
        # Keep recording until the horizon is covered (a mission may end before it).
        t_end = t0 + self.horizon_s + 0.5
        while clock.monotonic() < t_end and not stop.is_set():
            await clock.sleep(0.1)

    async def finish(
        self, fleet: Fleet, vehicles: Sequence[Vehicle], t0: float, event: SafetyEvent | None
    ) -> DriverReport:
        assert self._follower is not None
        self._follower.detach()
        now = fleet.clock.monotonic() - t0
        runs: dict[str, MissionRun] = {
            n: self._follower.run(n, finished=n in self._done, duration_s=self._done.get(n, now))
            for n in self.names
        }
        return DriverReport(
            completed=bool(runs) and all(r.finished for r in runs.values()),
            runs=runs,
            start_skew_s={n: s.t_accepted_monotonic_s - t0 for n, s in self.confirmed.items()},
        )
