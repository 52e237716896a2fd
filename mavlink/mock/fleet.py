"""A fleet of mock PX4 vehicles in one asyncio event loop.

Vehicle ``i`` binds UDP ``bind_host:vehicle_ports[i]`` (default 14580 + i) and
sends to ``gcs_host:gcs_ports[i]`` (default 14540 + i) until it hears from a
client, then to the address it last heard from, exactly as PX4 SITL's MAVLink
instance does.  One task advances the vectorised physics at ``physics_rate_hz``
against absolute deadlines (no drift) and lets each vehicle run its mode logic and
telemetry. A stall of the process (a busy machine) is not made up: past
:data:`MAX_BEHIND_TICKS` ticks late the pace starts again from where the simulation is,
so simulated time stops while the process does, as in a lockstep simulator, rather than
running a burst of steps the ground station (in the same process, behind the same
interpreter lock) has no chance to see; :attr:`MockFleet.real_time_factor` then drops
below 1. A machine that cannot keep the pace at all runs the steps back to back.

Usage::

    async with MockFleet(n=4, seed=1) as fleet:
        ...                                   # MAVSDK at udpin://0.0.0.0:14540..14543
    with MockFleet(n=1).running_in_thread() as fleet:
        fleet.vehicles[0].state               # from synchronous code
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import errno
import functools
import heapq
import itertools
import random
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np
import pymap3d

from mavlink.mock.sim.clock import TICK_SLACK_S, SimClock
from mavlink.mock.sim.config import FaultConfig, MockVehicleConfig, NoiseConfig, WindConfig
from mavlink.mock.sim.errors import MockConfigError, MockStartError
from mavlink.mock.sim.faults import FaultyChannel
from mavlink.mock.sim.physics import FleetPhysics, Ground, terrain_ground
from mavlink.mock.sim.profiles import DEFAULT_PROFILE, profile_params
from mavlink.mock.vehicle import MockVehicle
from planner.frames import GeodeticPoint, enu_to_geodetic

#: PX4 SITL's default home (Zurich, the Gazebo/jMAVSim worlds).
DEFAULT_ORIGIN = GeodeticPoint(47.397742, 8.545594, 488.0)
GCS_BASE_PORT = 14540
VEHICLE_BASE_PORT = 14580
#: How far behind its pace the simulation may fall and still catch up (ticks): a delay of the
#: event loop's timer; past it the pace starts again (:meth:`MockFleet._run`).
MAX_BEHIND_TICKS = 2


class _VehicleProtocol(asyncio.DatagramProtocol):
    def __init__(self, vehicle: MockVehicle) -> None:
        self.vehicle = vehicle
        self.send_errors = 0

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.vehicle.datagram_received(data, addr)

    def error_received(self, exc: Exception) -> None:
        # ICMP "port unreachable" while no client listens yet: PX4 keeps sending too.
        self.send_errors += 1


class MockFleet:
    """``n`` mock PX4 quad-rotors sharing one event loop and one physics model.

    Parameters
    ----------
    n : number of vehicles (system ids 1..n).
    origin : mission origin (``GeodeticPoint`` or ``(lat, lon, alt_amsl)``); the
        spawn points are ENU offsets from it.
    spawns_enu_m : ``n`` spawn points (x east, y north, z up, m); default a
        line along x with 2 m spacing (``(2 i, 0, 0)``).
    gcs_host, gcs_ports, vehicle_ports, bind_host : addresses, PX4 SITL defaults.
    seed : seeds wind, noise and link faults (a run is reproducible for a seed).
    faults : one ``FaultConfig`` for every vehicle, a sequence of ``n``, or a
        mapping ``index -> FaultConfig``.
    params : PX4 parameter overrides for every vehicle (``{"COM_OF_LOSS_T": 0.5}``).
    vehicle_configs : full per-vehicle configurations (override spawns/faults/params).
    wind, noise : environment; noise only affects reported telemetry.
    physics_rate_hz : simulation step rate (100 Hz like PX4's position controller).
    ready_after_s : simulated GPS/EKF convergence time before arming is allowed.
    signing_key : 32-byte MAVLink 2 signing secret: vehicles sign what they send
        and drop unsigned (except RADIO_STATUS), wrongly signed and replayed
        frames (counted in ``MockVehicle.signing_rejected``).
    profile : ``"px4"`` (default: PX4 v1.17 with SIH, drag, estimator, PX4's
        navigator) or ``"ideal"`` (the exact vehicle); see :mod:`mavlink.mock.sim.profiles`.
        ``params`` apply on top of it.
    camera : every vehicle carries a MAVLink camera on a gimbal (:mod:`mavlink.mock.payload`;
        per vehicle: ``MockVehicleConfig.camera``).
    utc_start_s : the UTC time (s since the Unix epoch) at simulation time 0, the cameras'
        clock for ``CAMERA_IMAGE_CAPTURED.time_utc``; default: the wall clock at creation.
    speed : simulated seconds per wall-clock second (1: real time; PX4 SITL's
        ``PX4_SIM_SPEED_FACTOR``). A ground station that waits on :attr:`clock` keeps the
        flight's timing at any speed; one on the wall clock does not.
    terrain : the ground under the mission frame (:class:`planner.spec.terrain.Terrain`):
        every vehicle stands, lands and takes off on it (a spawn above it stands on a
        platform there); None: flat ground at each spawn's height.
    """

    def __init__(
        self,
        n: int = 1,
        origin: GeodeticPoint | tuple[float, float, float] | None = None,
        spawns_enu_m: Sequence[Sequence[float]] | None = None,
        gcs_host: str = "127.0.0.1",
        gcs_ports: Sequence[int] | None = None,
        vehicle_ports: Sequence[int] | None = None,
        bind_host: str = "127.0.0.1",
        seed: int = 0,
        faults: FaultConfig | Sequence[FaultConfig] | Mapping[int, FaultConfig] | None = None,
        params: Mapping[str, float] | None = None,
        vehicle_configs: Sequence[MockVehicleConfig] | None = None,
        wind: WindConfig | None = None,
        noise: NoiseConfig | None = None,
        physics_rate_hz: float = 100.0,
        ready_after_s: float = 0.5,
        signing_key: bytes | None = None,
        profile: str = DEFAULT_PROFILE,
        camera: bool = True,
        utc_start_s: float | None = None,
        speed: float = 1.0,
        terrain: Ground | None = None,
    ) -> None:
        if not isinstance(n, int) or n < 1 or n > 254:
            raise MockConfigError(f"n must be an integer in 1..254, got {n!r}")
        if not (isinstance(speed, int | float) and 0.0 < speed <= 100.0):
            raise MockConfigError(f"speed must be in (0, 100] (times real time), got {speed!r}")
        if not (physics_rate_hz > 0):
            raise MockConfigError(f"physics_rate_hz must be > 0, got {physics_rate_hz!r}")
        self.n = n
        if signing_key is not None and (
            not isinstance(signing_key, bytes | bytearray) or len(signing_key) != 32
        ):
            raise MockConfigError("signing_key must be 32 bytes (the MAVLink 2 key length)")
        #: MAVLink 2 signing: with a key every vehicle signs what it sends and accepts
        #: only frames signed with it (see :meth:`MockVehicle._new_parser`).
        self.signing_key: bytes | None = None if signing_key is None else bytes(signing_key)
        if origin is None:
            origin = DEFAULT_ORIGIN
        elif not isinstance(origin, GeodeticPoint):
            try:
                origin = GeodeticPoint(*(float(v) for v in origin))
            except (TypeError, ValueError) as exc:
                raise MockConfigError(f"origin must be (lat, lon, alt): {exc}") from None
        self.origin: GeodeticPoint = origin
        self.gcs_host = gcs_host
        self.bind_host = bind_host
        self.gcs_ports = self._ports(gcs_ports, GCS_BASE_PORT, "gcs_ports")
        self.vehicle_ports = self._ports(vehicle_ports, VEHICLE_BASE_PORT, "vehicle_ports")
        self.seed = seed
        self.dt_s = 1.0 / physics_rate_hz
        self.time_s = 0.0
        #: simulated seconds per wall-clock second the fleet aims at (PX4 SITL's
        #: PX4_SIM_SPEED_FACTOR); a busy machine may hold it below (:attr:`real_time_factor`)
        self.speed = float(speed)
        #: the simulated time as the ground station's clock (:mod:`mavlink.mock.sim.clock`)
        self.clock = SimClock(self)
        #: UTC (s since the epoch) at simulation time 0: the payloads' wall clock
        self.utc_start_s = time.time() if utc_start_s is None else float(utc_start_s)
        profile_params(profile)
        self.profile = profile
        self.configs = self._configs(
            n, spawns_enu_m, faults, params, vehicle_configs, ready_after_s, profile, camera
        )
        seeds = np.random.SeedSequence(seed)
        phys_seed, link_seed = seeds.spawn(2)
        self.physics = FleetPhysics(n, self.dt_s, np.random.default_rng(phys_seed), wind, noise)
        self._link_seed = int(link_seed.generate_state(1)[0])
        spawns = np.array([c.spawn_enu_m for c in self.configs])
        if terrain is not None:
            self.physics.ground_of = terrain_ground(terrain, spawns)
            self.physics.ground_d_m = self.physics.ground_of(np.zeros((n, 3)))
        lat, lon, alt = enu_to_geodetic(spawns, self.origin)
        self.vehicles: list[MockVehicle] = []
        for i, cfg in enumerate(self.configs):
            uid = (0x5354_4C00_0000_0000 | (seed & 0xFFFF) << 8 | (i + 1)) & 0xFFFF_FFFF_FFFF_FFFF
            spawn_lla = (float(lat[i]), float(lon[i]), float(alt[i]))
            self.vehicles.append(MockVehicle(self, i, cfg, spawn_lla, uid))
        self._origins_np()
        self._geo_tick = -1
        self._geo: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._ticks = 0
        self._timers: list[tuple[float, int, Callable[..., None], tuple[Any, ...]]] = []
        self._timer_seq = itertools.count()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._task: asyncio.Task[None] | None = None
        self._transports: list[asyncio.DatagramTransport] = []
        self._protocols: list[_VehicleProtocol] = []
        self._t0_wall = 0.0

    # ---------------------------------------------------------------- set-up
    def _ports(self, ports: Sequence[int] | None, base: int, name: str) -> list[int]:
        if ports is None:
            return [base + i for i in range(self.n)]
        ports = [int(p) for p in ports]
        if len(ports) != self.n:
            raise MockConfigError(f"{name}: expected {self.n} ports, got {len(ports)}")
        for p in ports:
            if not 0 <= p <= 65535:
                raise MockConfigError(f"{name}: port {p} out of range")
        return ports

    @staticmethod
    def _configs(
        n: int,
        spawns: Sequence[Sequence[float]] | None,
        faults: Any,
        params: Mapping[str, float] | None,
        vehicle_configs: Sequence[MockVehicleConfig] | None,
        ready_after_s: float,
        profile: str,
        camera: bool,
    ) -> list[MockVehicleConfig]:
        if vehicle_configs is not None:
            if len(vehicle_configs) != n:
                raise MockConfigError(
                    f"vehicle_configs: expected {n} configurations, got {len(vehicle_configs)}"
                )
            return list(vehicle_configs)
        if spawns is None:
            spawns = [(2.0 * i, 0.0, 0.0) for i in range(n)]
        if len(spawns) != n:
            raise MockConfigError(f"spawns_enu_m: expected {n} points, got {len(spawns)}")
        per_vehicle: list[FaultConfig]
        if faults is None:
            per_vehicle = [FaultConfig()] * n
        elif isinstance(faults, FaultConfig):
            per_vehicle = [faults] * n
        elif isinstance(faults, Mapping):
            bad = [k for k in faults if not (isinstance(k, int) and 0 <= k < n)]
            if bad:
                raise MockConfigError(f"faults: vehicle index {bad[0]!r} not in 0..{n - 1}")
            per_vehicle = [faults.get(i, FaultConfig()) for i in range(n)]
        else:
            per_vehicle = list(faults)
            if len(per_vehicle) != n:
                raise MockConfigError(
                    f"faults: expected {n} configurations, got {len(per_vehicle)}"
                )
        prm = tuple((params or {}).items())
        return [
            MockVehicleConfig(
                spawn_enu_m=tuple(spawns[i]),  # type: ignore[arg-type]
                faults=per_vehicle[i],
                params=prm,
                ready_after_s=ready_after_s,
                profile=profile,
                camera=camera,
            )
            for i in range(n)
        ]

    def _origins_np(self) -> None:
        s = np.array([v.spawn_lla for v in self.vehicles])
        self._spawn_lat, self._spawn_lon, self._spawn_h = s[:, 0], s[:, 1], s[:, 2]
        o = np.array([v.origin_lla for v in self.vehicles])
        self._lat0, self._lon0, self._h0 = o[:, 0], o[:, 1], o[:, 2]

    def origins_changed(self) -> None:
        """A vehicle moved its EKF origin (SET_GPS_GLOBAL_ORIGIN): refresh the cache."""
        self._origins_np()
        self._geo_tick = -1

    def geodetic(self, i: int) -> tuple[float, float, float]:
        """Reported (lat_deg, lon_deg, alt_m AMSL) of vehicle ``i`` this tick (with noise).

        Computed for the whole fleet at once, at most once per tick.
        """
        if self._geo_tick != self._ticks or self._geo is None:
            p = self.physics.pos_ned_m + self.physics.noise_pos_m
            lat, lon, alt = pymap3d.ned2geodetic(
                p[:, 0], p[:, 1], p[:, 2], self._lat0, self._lon0, self._h0
            )
            self._geo = (np.asarray(lat), np.asarray(lon), np.asarray(alt))
            self._geo_tick = self._ticks
        lat, lon, alt = self._geo
        return float(lat[i]), float(lon[i]), float(alt[i])

    def truth_enu_m(self) -> np.ndarray:
        """(n, 3) true positions in the fleet's mission ENU frame (m): what really happened.

        The vehicles report (and fly on) their estimates; this is the simulator's ground
        truth, for tests and assessments that compare the two.
        """
        return self.spawn_ned_to_enu(self.physics.true_pos_ned_m)

    def spawn_ned_to_enu(self, p: np.ndarray) -> np.ndarray:
        """Positions in each vehicle's spawn NED frame (the physics' frame), ``(..., n, 3)``,
        as mission-frame ENU, same shape (vectorised over any leading axes)."""
        shape = p.shape
        q = p.reshape(-1, self.n, 3)
        lat0 = np.broadcast_to(self._spawn_lat, q.shape[:2])
        lon0 = np.broadcast_to(self._spawn_lon, q.shape[:2])
        h0 = np.broadcast_to(self._spawn_h, q.shape[:2])
        lat, lon, alt = pymap3d.ned2geodetic(q[..., 0], q[..., 1], q[..., 2], lat0, lon0, h0)
        o = self.origin
        e, n, u = pymap3d.geodetic2enu(lat, lon, alt, o.lat_deg, o.lon_deg, o.alt_m)
        return np.stack([e, n, u], axis=-1).reshape(shape)

    def plan_started(self, t0_s: float) -> None:
        """The flight's plan started at ``t0_s`` (simulation time): the vehicles' injected
        faults (:mod:`mavlink.mock.vehicle_faults`) are timed from it. Safe from any thread."""
        for v in self.vehicles:
            v.plan_faults.start(t0_s)

    def configure_links(self, vehicle: MockVehicle, faults: FaultConfig) -> None:
        """(Re)build the fault channels of ``vehicle``; usable before or while running."""
        if self._loop is None:
            vehicle.config = _replace_faults(vehicle.config, faults)
            return
        seed = self._link_seed + 1000 * vehicle.index
        vehicle.uplink = FaultyChannel(
            faults, faults.loss_to_vehicle, random.Random(seed), self.call_later,
            vehicle._deliver_up, lambda: self.time_s,
        )  # fmt: skip
        vehicle.downlink = FaultyChannel(
            faults, faults.loss_to_gcs, random.Random(seed + 1), self.call_later,
            vehicle._deliver_down, lambda: self.time_s,
        )  # fmt: skip
        vehicle.config = _replace_faults(vehicle.config, faults)

    # ---------------------------------------------------------------- running
    async def start(self) -> None:
        """Bind every vehicle's socket and start the simulation task."""
        if self._task is not None:
            raise MockConfigError("the fleet is already running")
        if self._ticks:
            raise MockConfigError("a MockFleet runs once: create a new one to run again")
        loop = asyncio.get_running_loop()
        self._loop = loop
        try:
            for v in self.vehicles:
                self.configure_links(v, v.config.faults)
                port = self.vehicle_ports[v.index]
                try:
                    transport, protocol = await loop.create_datagram_endpoint(
                        functools.partial(_VehicleProtocol, v), local_addr=(self.bind_host, port)
                    )
                except OSError as exc:
                    hint = (
                        ": another program (PX4 SITL, another gcs mock) holds it; choose "
                        "other ports with --vehicle-base-port (and --base-port for the ground "
                        "station's)"
                        if exc.errno == errno.EADDRINUSE
                        else ""
                    )
                    raise MockStartError(
                        f"vehicle {v.index} (sysid {v.sysid}): cannot bind UDP "
                        f"{self.bind_host}:{port}: {exc.strerror or exc}{hint}"
                    ) from exc
                self._transports.append(transport)
                self._protocols.append(protocol)
                v._transport_send = transport.sendto
        except BaseException:
            self._close_transports()
            raise
        self._t0_wall = loop.time()
        self.clock.started()
        self._task = loop.create_task(self._run(), name="mock-fleet-physics")

    async def stop(self) -> None:
        """Stop the simulation and close the sockets."""
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self.clock.stopped()
        self._close_transports()

    def _close_transports(self) -> None:
        for t in self._transports:
            t.close()
        self._transports.clear()
        for v in self.vehicles:
            v._transport_send = None

    async def __aenter__(self) -> MockFleet:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        dt = self.dt_s / self.speed  # wall seconds per tick
        # the pace: tick k is due at anchor + (k - k_anchor) * dt on the wall clock
        anchor, k_anchor = self._t0_wall, 0
        late_max = MAX_BEHIND_TICKS * dt
        sleep = asyncio.sleep
        while True:
            self._tick()
            now = loop.time()
            delay = anchor + (self._ticks - k_anchor) * dt - now
            if delay < -late_max:  # a stall is not made up: the pace starts again from here
                anchor, k_anchor, delay = now, self._ticks, 0.0
            await sleep(delay if delay > 0.0 else 0.0)

    def _tick(self) -> None:
        """One physics step, the datagrams due, then every vehicle's mode logic, protocol
        timers and telemetry, then the ground station's alarms due."""
        self.physics.step()
        self._ticks += 1
        now = self._ticks * self.dt_s
        self.time_s = now
        timers = self._timers
        while timers and timers[0][0] <= now + TICK_SLACK_S:
            _, _, fn, args = heapq.heappop(timers)
            fn(*args)
        for v in self.vehicles:
            v.tick(now)
        self.clock.wake_due(now)

    def call_later(self, delay_s: float, fn: Callable[..., None], *args: Any) -> None:
        """Call ``fn(*args)`` ``delay_s`` simulated seconds from now, on the first tick at or
        after it (in the fleet's thread; e.g. a delayed datagram's delivery)."""
        heapq.heappush(self._timers, (self.time_s + delay_s, next(self._timer_seq), fn, args))

    def advance(self, seconds: float) -> None:
        """Simulate ``seconds`` as fast as the CPU goes, without sockets or an event loop.

        For tests and batch simulations of the vehicle model: the fleet must not be
        running.  Nothing goes on the wire; what each vehicle sends is kept as MAVLink
        bytes and decoded by :meth:`MockVehicle.sent_messages`.  Commands reach the
        vehicles through their Python API (``arm``, ``request_mode``, ...) or
        :meth:`MockVehicle.receive`.
        """
        if self.running:
            raise MockConfigError("advance() is for a fleet that is not running")
        self.offline_links()
        for _ in range(round(seconds / self.dt_s)):
            self._tick()

    def offline_links(self) -> None:
        """Give every vehicle in-memory links (no sockets), for :meth:`advance`."""
        for v in self.vehicles:
            if not isinstance(v.downlink, _OfflineLink):
                v.downlink = _OfflineLink()
                v.uplink = _OfflineUplink(v)

    @property
    def running(self) -> bool:
        """True while the simulation task runs."""
        return self._task is not None and not self._task.done()

    @property
    def wall_elapsed_s(self) -> float:
        """Wall-clock seconds since :meth:`start`."""
        if self._loop is None:
            return 0.0
        return self._loop.time() - self._t0_wall

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second since start (1.0 = keeping up)."""
        wall = self.wall_elapsed_s
        return self.time_s / wall if wall > 0 else 0.0

    @contextlib.contextmanager
    def running_in_thread(self, start_timeout_s: float = 10.0) -> Iterator[MockFleet]:
        """Run the fleet in its own event loop on a background thread.

        For synchronous callers (tests, the CLI)::

            with MockFleet(n=2).running_in_thread() as fleet:
                ...

        Errors at start-up (a port in use) are raised here; the thread is
        stopped and joined on exit.
        """
        started = threading.Event()
        box: dict[str, Any] = {}

        async def main() -> None:
            stop = asyncio.Event()
            box["loop"] = asyncio.get_running_loop()
            box["stop"] = stop
            try:
                await self.start()
            except BaseException as exc:
                box["error"] = exc
                started.set()
                return
            started.set()
            try:
                await stop.wait()
            finally:
                await self.stop()

        def target() -> None:
            try:
                asyncio.run(main())
            except BaseException as exc:  # reported to the caller via box
                box.setdefault("error", exc)
                started.set()

        thread = threading.Thread(target=target, name="mock-fleet", daemon=True)
        thread.start()
        if not started.wait(start_timeout_s):
            raise MockStartError("the mock fleet did not start in time")
        if "error" in box:
            thread.join()
            raise box["error"]
        try:
            yield self
        finally:
            loop: asyncio.AbstractEventLoop = box["loop"]
            loop.call_soon_threadsafe(box["stop"].set)
            thread.join()

    def call_soon(self, fn: Any, *args: Any) -> None:
        """Run ``fn(*args)`` in the fleet's loop (thread-safe)."""
        if self._loop is None:
            raise MockConfigError("the fleet is not running")
        self._loop.call_soon_threadsafe(fn, *args)

    def link_stats(self) -> list[dict[str, Any]]:
        """Datagram counters per vehicle: uplink/downlink offered, dropped, ..."""
        out = []
        protocols: list[_VehicleProtocol | None] = [*self._protocols] or [None] * self.n
        for v, proto in zip(self.vehicles, protocols, strict=False):
            out.append(
                {
                    "sysid": v.sysid,
                    # offline links (advance() without sockets) keep no counters
                    "uplink": v.uplink.stats if isinstance(v.uplink, FaultyChannel) else None,
                    "downlink": (
                        v.downlink.stats if isinstance(v.downlink, FaultyChannel) else None
                    ),
                    "send_errors": proto.send_errors if proto else 0,
                }
            )
        return out


class _OfflineLink:
    """Downlink of an offline fleet (:meth:`MockFleet.advance`): keeps the bytes sent."""

    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def push(self, data: bytes) -> None:
        self.sent.append(data)


class _OfflineUplink:
    """Uplink of an offline fleet: hands datagrams straight to the vehicle's parser."""

    def __init__(self, vehicle: MockVehicle) -> None:
        self._vehicle = vehicle

    def push(self, data: bytes) -> None:
        self._vehicle._deliver_up(data)


def _replace_faults(cfg: MockVehicleConfig, faults: FaultConfig) -> MockVehicleConfig:
    return dataclasses.replace(cfg, faults=faults)
