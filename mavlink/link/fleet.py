"""A fleet of PX4 vehicles reached through one in-process MAVSDK instance.

:class:`Fleet` connects N vehicles by URL (vehicle ``i`` defaults to
``udpin://0.0.0.0:{14540+i}`` with system id ``i+1``), waits for each one's
heartbeat with a timeout and keeps a live :class:`~mavlink.link.vehicle.VehicleStatus` per
vehicle: connected, armed, PX4 mode (decoded from ``HEARTBEAT.custom_mode`` with
:mod:`mavlink.px4_modes`), local NED and global position, home, EKF/GPS
global origin, battery.

One vehicle's link (its MAVSDK plugins, telemetry and commands) is a
:class:`~mavlink.link.vehicle.Vehicle`; MAVSDK's callback calls are bridged to asyncio by
:mod:`mavlink.link.mavsdk_glue`. This module keeps what makes and commands a fleet: the specs,
the connection (discovery, duplicate system ids, telemetry rates), :meth:`Fleet.flight`
and the all-at-once commands.

Example::

    specs = default_specs(["d1", "d2"])
    async with Fleet(specs, connect_timeout_s=10.0) as fleet:
        for status in fleet.statuses():
            print(status.name, status.mode, status.pos_ned_m)
        await fleet.hold_all()
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from mavsdk import ComponentType, Configuration, Mavsdk
from mavsdk.exceptions import MavsdkError

from mavlink.clock import WALL, Clock
from mavlink.errors import (
    ConnectTimeoutError,
    DuplicateSystemError,
    LinkError,
    LinkLostError,
)
from mavlink.link.mavsdk_glue import calls_settled, mavsdk_instance_opened, route_mavsdk_logs
from mavlink.link.urls import Scheme, default_sysid, default_url, parse_url
from mavlink.link.vehicle import Vehicle
from mavlink.link.vehicle_status import VehicleSpec, VehicleStatus
from planner.frames import GeodeticPoint

#: MAV_AUTOPILOT of PX4 in its HEARTBEAT.
MAV_AUTOPILOT_PX4 = 12
_AUTOPILOTS = {0: "generic", 3: "ArduPilot", 8: "invalid (not an autopilot)", 12: "PX4"}


def _autopilot_name(value: int) -> str:
    name = _AUTOPILOTS.get(value)
    return f", {name}" if name else ""


#: MAVSDK's system id as a ground station (component 190).
GCS_SYSID = 245


def default_specs(
    names: Sequence[str], urls: Sequence[str | None] | None = None
) -> tuple[VehicleSpec, ...]:
    """Specs by the PX4 SITL convention: vehicle ``i`` is system ``i+1`` at ``udpin://0.0.0.0:{14540+i}``.

    Args:
        names: vehicle names in plan order.
        urls: optional URL per vehicle (``None`` entries take the default).
    """
    if urls is not None and len(urls) != len(names):
        raise LinkError(f"{len(urls)} connection URLs given for {len(names)} vehicles")
    out = []
    for i, name in enumerate(names):
        url = urls[i] if urls is not None and urls[i] is not None else default_url(i)
        out.append(VehicleSpec(name=name, url=str(url), sysid=default_sysid(i)))
    return tuple(out)


# --------------------------------------------------------------------------
# The fleet
# --------------------------------------------------------------------------


@dataclass(slots=True)
class FlightGuard:
    """What :meth:`Fleet.flight` did on the way out.

    Attributes:
        action: ``"hold"`` or ``"land"``, what an abnormal exit commands.
        stopped: the scope was left by an exception or a cancellation and the vehicles
            were commanded.
        failures: vehicles that did not accept the command, with the reason.
    """

    action: str
    stopped: bool = False
    failures: dict[str, str] = field(default_factory=dict)


class Fleet:
    """N vehicles behind one MAVSDK instance (the GCS is system 245, component 190).

    Args:
        specs: one :class:`VehicleSpec` per vehicle (see :func:`default_specs`).
        connect_timeout_s: how long :meth:`connect` waits for all heartbeats.
        link_timeout_s: a vehicle whose last heartbeat is older is not connected.
        telemetry_rate_hz: ask each vehicle for local/global position at this
            rate (``None``: leave the vehicle's rates alone).
        clock: the clock the vehicles' telemetry and the flight run on (:mod:`mavlink.clock`:
            the wall clock, or a mock fleet's simulated time).

    Raises (from :meth:`connect`):
        UrlError: a URL is malformed (before anything is opened).
        LinkError: a URL cannot be opened (port in use, no such device).
        ConnectTimeoutError: a vehicle did not appear; names it, its URL and sysid.
        DuplicateSystemError: two autopilots answer as one vehicle's system id (a scan of
            the ``udpin`` ports before MAVSDK opens them, up to ``scan_s``: it names both
            addresses; MAVSDK would merge them into one system).
        CommandError: a vehicle refused the telemetry rate, or never answered the request
            within ``connect_timeout_s``.
    """

    def __init__(
        self,
        specs: Sequence[VehicleSpec],
        *,
        connect_timeout_s: float = 10.0,
        link_timeout_s: float = 2.0,
        telemetry_rate_hz: float | None = 20.0,
        scan_s: float = 1.0,
        clock: Clock = WALL,
    ) -> None:
        if not specs:
            raise LinkError("no vehicles to connect")
        names = [s.name for s in specs]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise LinkError(f"duplicate vehicle names: {', '.join(dup)}")
        sysids = [s.sysid for s in specs]
        for s in specs:
            if sysids.count(s.sysid) > 1:
                raise LinkError(
                    f"system id {s.sysid} used by more than one vehicle", vehicle=s.name, url=s.url
                )
            if not 1 <= s.sysid <= 255:
                raise LinkError(f"system id {s.sysid} outside 1..255", vehicle=s.name, url=s.url)
            if s.sysid == GCS_SYSID:
                raise LinkError(
                    f"system id {GCS_SYSID} is the ground station's own (MAVSDK)",
                    vehicle=s.name,
                    url=s.url,
                )
            parse_url(s.url, vehicle=s.name)
        self.specs = tuple(specs)
        self.connect_timeout_s = connect_timeout_s
        self.link_timeout_s = link_timeout_s
        self.telemetry_rate_hz = telemetry_rate_hz
        self.scan_s = scan_s
        self.clock = clock
        self._mavsdk: Mavsdk | None = None
        self._vehicles: dict[str, Vehicle] = {}

    # -- lifecycle ------------------------------------------------------

    async def __aenter__(self) -> Fleet:
        await self.connect()
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()

    async def connect(self) -> None:
        """Open every URL and wait until each vehicle's system id has been seen.

        On a lossy link discovery waits for a heartbeat that gets through (PX4 sends one a
        second) and the telemetry-rate requests are repeated while unanswered, each within
        ``connect_timeout_s``.
        """
        route_mavsdk_logs()
        if self.scan_s > 0:
            await self._refuse_duplicates()
        config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        self._mavsdk = Mavsdk(config)
        mavsdk_instance_opened(True)
        try:
            for spec in self.specs:
                url = str(parse_url(spec.url, vehicle=spec.name))
                try:
                    self._mavsdk.add_any_connection_with_handle(url)
                except MavsdkError as exc:
                    raise LinkError(
                        f"cannot open connection: {exc}", vehicle=spec.name, url=spec.url
                    ) from exc
            systems = await self._wait_for_systems()
            for spec in self.specs:
                self._vehicles[spec.name] = Vehicle(
                    spec, systems[spec.sysid], link_timeout_s=self.link_timeout_s, clock=self.clock
                )
            # Discovery by sysid sees any message; wait for a decoded heartbeat too.
            await asyncio.gather(*(self._first_heartbeat(v) for v in self._vehicles.values()))
            if self.telemetry_rate_hz is not None:
                rate, wait = self.telemetry_rate_hz, self.connect_timeout_s
                await asyncio.gather(
                    *(v.set_telemetry_rate(rate, retry_for_s=wait) for v in self._vehicles.values())
                )
        except BaseException:
            self.close()
            raise

    async def _refuse_duplicates(self) -> None:
        """DuplicateSystemError if two autopilots answer as one of the fleet's system ids on
        the udpin ports (:mod:`mavlink.link.scan`), before MAVSDK merges them."""
        from mavlink.link.scan import duplicates, scan_udpin

        urls = [parse_url(s.url, vehicle=s.name) for s in self.specs]
        sysids = [s.sysid for s in self.specs]
        heard = await scan_udpin(urls, self.scan_s, expect=sysids)
        for spec, url in zip(self.specs, urls, strict=True):
            why = heard.busy.get(str(url))
            if why is not None:
                raise LinkError(
                    f"port {url.port} cannot be opened ({why}): another program (a ground "
                    "station, QGroundControl, a MAVSDK server, another gcs) uses it; close it, "
                    "or choose other ports with --base-port or --connection",
                    vehicle=spec.name,
                    url=spec.url,
                )
        found = duplicates(heard, sysids)
        if found:
            spec = next(s for s in self.specs if s.sysid == found[0].sysid)
            raise DuplicateSystemError(found[0].describe(), vehicle=spec.name, url=spec.url)
        for spec, url in zip(self.specs, urls, strict=True):
            if url.scheme is not Scheme.UDPIN:
                continue
            expected = {s.sysid for s, u in zip(self.specs, urls, strict=True) if u == url}
            there = heard.sysids_on(str(url))
            if there and not there & expected:
                raise LinkError(
                    f"system id(s) {', '.join(map(str, sorted(there)))} answer on port "
                    f"{url.port}, not {spec.sysid}: another program's vehicle, or a vehicle "
                    f"configured with another MAV_SYS_ID (give --connection per vehicle, and "
                    "the plan's system ids)",
                    vehicle=spec.name,
                    url=spec.url,
                )
            kinds = {
                snd.autopilot
                for snd in heard.senders.get(spec.sysid, {}).values()
                if snd.url == str(url) and snd.autopilot is not None
            }
            if kinds and MAV_AUTOPILOT_PX4 not in kinds:
                raise LinkError(
                    f"system id {spec.sysid} on port {url.port} is not PX4 (its heartbeat says "
                    f"MAV_AUTOPILOT {min(kinds)}{_autopilot_name(min(kinds))}): stl-gcs flies "
                    "PX4 vehicles",
                    vehicle=spec.name,
                    url=spec.url,
                )

    async def _first_heartbeat(self, v: Vehicle) -> None:
        """Wait for ``v``'s first autopilot HEARTBEAT; ConnectTimeoutError naming it if none."""
        try:
            await v.wait_for(
                lambda st: st.heartbeat_age_s is not None,
                "first heartbeat",
                timeout_s=self.connect_timeout_s,
            )
        except LinkLostError:
            raise
        except LinkError as exc:
            raise ConnectTimeoutError(
                f"no autopilot heartbeat from system id {v.spec.sysid} within "
                f"{self.connect_timeout_s:.1f} s",
                vehicle=v.name,
                url=v.url,
            ) from exc

    async def _wait_for_systems(self) -> dict[int, Any]:
        assert self._mavsdk is not None
        loop = asyncio.get_running_loop()
        changed = asyncio.Event()
        handle = self._mavsdk.subscribe_on_new_system(
            lambda _ud: loop.call_soon_threadsafe(changed.set)
        )
        wanted = {s.sysid for s in self.specs}
        deadline = loop.time() + self.connect_timeout_s
        found: dict[int, Any] = {}
        try:
            while True:
                changed.clear()
                for system in self._mavsdk.get_systems():
                    sid = system.get_system_id()
                    if sid in wanted and sid not in found and system.has_autopilot():
                        found[sid] = system
                if wanted <= found.keys():
                    return found
                remaining = deadline - loop.time()
                if remaining <= 0:
                    break
                # Also re-check periodically: the autopilot component of an
                # already discovered system may show up without a new-system event.
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(changed.wait(), min(remaining, 0.1))
        finally:
            self._mavsdk.unsubscribe_on_new_system(handle)
        seen = sorted(s.get_system_id() for s in self._mavsdk.get_systems())
        missing = [s for s in self.specs if s.sysid not in found]
        first = missing[0]
        others = ""
        if len(missing) > 1:
            others = "; also missing: " + ", ".join(f"{s.name} ({s.url})" for s in missing[1:])
        raise ConnectTimeoutError(
            f"no heartbeat from system id {first.sysid} within {self.connect_timeout_s:.1f} s "
            f"(systems seen: {', '.join(map(str, seen)) or 'none'}){others}",
            vehicle=first.name,
            url=first.url,
        )

    def close(self) -> None:
        """Unsubscribe and destroy the MAVSDK instance (closes every connection), once the
        MAVSDK calls under way have had their answers (:func:`calls_settled`, at most
        :data:`SETTLE_S`; past that their callbacks are kept for the process's life)."""
        for v in self._vehicles.values():
            v.close()
        if self._mavsdk is not None and not calls_settled(SETTLE_S):
            for v in self._vehicles.values():
                _keep_callbacks(v)
        self._vehicles = {}
        if self._mavsdk is not None:
            self._mavsdk.destroy()
            self._mavsdk = None
            mavsdk_instance_opened(False)

    # -- access ---------------------------------------------------------

    @property
    def vehicles(self) -> tuple[Vehicle, ...]:
        """The vehicles in spec order."""
        return tuple(self._vehicles[s.name] for s in self.specs if s.name in self._vehicles)

    def __getitem__(self, name: str) -> Vehicle:
        try:
            return self._vehicles[name]
        except KeyError:
            raise LinkError(
                f"no vehicle named {name!r} (have {', '.join(self._vehicles) or 'none'})"
            ) from None

    def __iter__(self) -> Iterator[Vehicle]:
        return iter(self.vehicles)

    def __len__(self) -> int:
        return len(self._vehicles)

    def statuses(self) -> list[VehicleStatus]:
        """One :class:`VehicleStatus` per vehicle, taken at the same instant."""
        now = self.clock.monotonic()
        return [v.status(now) for v in self.vehicles]

    async def origins(self) -> dict[str, GeodeticPoint]:
        """Each vehicle's EKF origin (GPS_GLOBAL_ORIGIN), by name."""
        points = await asyncio.gather(*(v.request_origin() for v in self.vehicles))
        return {v.name: p for v, p in zip(self.vehicles, points, strict=True)}

    # -- all at once ----------------------------------------------------

    async def for_each(
        self,
        action: Callable[[Vehicle], Awaitable[None]],
        vehicles: Sequence[Vehicle] | None = None,
    ) -> dict[str, BaseException]:
        """Run ``action`` on the vehicles concurrently; failures by vehicle name.

        Every vehicle is attempted even if some fail (a safety stop must
        reach the ones that still answer); the caller decides what a failure
        means.
        """
        targets = list(self.vehicles if vehicles is None else vehicles)
        results = await asyncio.gather(*(action(v) for v in targets), return_exceptions=True)
        failures: dict[str, BaseException] = {}
        for v, r in zip(targets, results, strict=True):
            if isinstance(r, BaseException):
                if not isinstance(r, Exception):
                    raise r
                failures[v.name] = r
        return failures

    @contextlib.asynccontextmanager
    async def flight(
        self, vehicles: Sequence[Vehicle] | None = None, *, on_exit: str = "hold"
    ) -> AsyncIterator[FlightGuard]:
        """A flight scope: leaving it by an exception or a cancellation (Ctrl-C) first commands
        every vehicle (of ``vehicles``; default all) to hold where it is (``on_exit="land"``:
        to land), then lets the exception go on; a normal exit leaves them as they are.

        In the spirit of crazyflie-lib-python's ``MotionCommander``, whatever flies inside
        (``fly_offboard``, a mission flight) cannot leave the vehicles streaming to nobody::

            async with fleet.flight() as guard:
                result = await fly_offboard(fleet, trajectories, origin)

        The stop is MAVSDK's offboard stop (which holds) for a vehicle in offboard, Hold
        otherwise (:func:`mavlink.monitor.safe_stop`); every vehicle is attempted, and the
        guard records which did not accept it.
        """
        from mavlink.monitor import safe_stop
        from mavlink.monitor_findings import SafetyAction

        action = SafetyAction(on_exit)
        guard = FlightGuard(action=action.value)
        targets = list(self.vehicles if vehicles is None else vehicles)
        try:
            yield guard
        except BaseException:
            guard.stopped = True
            failed = await self.for_each(lambda v: safe_stop(v, action), targets)
            guard.failures = {k: str(e) for k, e in failed.items()}
            raise

    async def hold_all(self) -> dict[str, BaseException]:
        """Command Hold on every vehicle; returns the failures by name."""
        return await self.for_each(lambda v: v.hold())

    async def land_all(self) -> dict[str, BaseException]:
        """Command Land on every vehicle; returns the failures by name."""
        return await self.for_each(lambda v: v.land())


#: Seconds :meth:`Fleet.close` waits for the answers of MAVSDK calls under way (a cancelled
#: upload's comes at once; a command to a silent vehicle's after MAVSDK's own retries).
SETTLE_S = 3.0

#: The ctypes trampolines of MAVSDK calls still unanswered when their fleet closed
#: (:func:`_keep_callbacks`), kept so that a late answer finds live code.
_KEPT_CALLBACKS: list[object] = []


def _keep_callbacks(v: Vehicle) -> None:
    """Keep ``v``'s plugins' call trampolines alive past MAVSDK's destroy: MAVSDK 4.1's
    plugins drop them (their ``_callbacks`` list) when destroyed, though a call under way is
    answered later through them (:mod:`mavlink.link.mavsdk_glue`)."""
    for plugin in (v.action, v.telemetry, v.offboard, v.mission_raw, v.direct):
        _KEPT_CALLBACKS.extend(getattr(plugin, "_callbacks", ()))
