"""Flying a plan file: the orchestration shared by ``gcs fly`` and ``gcs demo``.

:func:`fly_plan` does, in order:

1. connects every vehicle of the plan (:class:`mavlink.fleet.Fleet`; vehicle ``i`` at the
   URL given for it, by default ``udpin://0.0.0.0:{14540+i}``, the PX4 SITL ports);
2. records everything the vehicles send to ``flight.tlog`` (:class:`mavlink.tlog.TlogRecorder`)
   when a log directory is given;
3. flies: in **offboard** mode :func:`mavlink.offboard.fly_offboard` (take-off to the plan's
   start, one shared start time, setpoints against absolute deadlines, the safety monitor of
   the spec's always-clauses), in **mission** mode the plan's PX4 mission conversion
   (:func:`mavlink.mission.trajectory_to_mission`: uploaded, read back and compared, then
   flown with :func:`mavlink.mission.fly_missions`);
4. shows progress while flying (:class:`FlightProgress`): per vehicle its mode, its distance
   to where the plan is at that instant, and the robustness of the clauses it takes part in
   *so far* (exact semantics of the flown prefix completed by the plan for the rest of the
   horizon, i.e. what the spec's value will be if the rest goes as planned);
5. on Ctrl-C (task cancellation) the flight's tasks end with it (structured in the link layer)
   and :meth:`mavlink.fleet.Fleet.flight` commands every vehicle
   to hold where it is (:func:`mavlink.monitor.safe_stop`), and reports the modes it then has;
6. writes the flown tracks (``flight.csv``, mission frame) and evaluates the flown data
   against the spec with the exact semantics (:func:`evaluate_flight`), next to the planned
   value, with per-vehicle tracking errors and the delay that best aligns flown and planned
   positions (the first thing to look at when flown robustness falls short).

The pre-flight interlock (:func:`preflight_interlock`) re-runs ``gcs verify``'s checks
(:func:`gcs.commands.verify.verify_plan`) and refuses a plan that fails one.

Dry runs (:func:`mock_vehicles`): mock PX4 vehicles (:class:`mavlink.mock.MockFleet`) in a
background thread of this process, on free loopback ports, each spawned **on the ground
directly below its planned start** (mission-frame ``z = 0``), as PX4 SITL spawns its vehicles;
the flight then arms, takes off to the start and flies, exactly as against SITL.

Errors::

    FlightRefused(Exception)   a check before the flight failed (exit status 1): .check names it
    (bad input is gcs.errors.UserError, planner.planfile.PlanFileError or
     mavlink.errors.LinkError, e.g. an unreachable connection: exit status 2)
"""

from __future__ import annotations

import asyncio
import bisect
import contextlib
import dataclasses
import math
import shutil
import socket
import sys
import threading
import time
from collections.abc import AsyncIterator, Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from gcs.errors import InputFileError, UserError

if TYPE_CHECKING:
    from gcs.checks import Check
    from gcs.mission_flight import MissionFlight
    from gcs.tuning import VehicleTuning
    from mavlink.fleet import Fleet, Vehicle, VehicleSpec
    from mavlink.mission import MissionRun
    from mavlink.mock import MockFleet
    from mavlink.monitor import MonitorStats, SafetyEvent
    from mavlink.offboard import EndAction
    from mavlink.stream import StreamStats
    from mavlink.tlog import FlownTrack, TlogStats
    from planner.frames import GeodeticPoint, NedToEnuMap
    from planner.planfile import Plan
    from planner.stl import Formula

__all__ = [
    "ClauseOutcome",
    "FlightClock",
    "FlightMode",
    "FlightOutcome",
    "FlightProgress",
    "FlightRefused",
    "FlownEvaluation",
    "FlyOptions",
    "TrackingError",
    "evaluate_flight",
    "fly_plan",
    "free_udp_ports",
    "ground_spawns",
    "mock_vehicles",
    "plan_formula",
    "preflight_interlock",
    "vehicle_specs",
]

#: Seconds allowed for every vehicle's first heartbeat.
DEFAULT_CONNECT_TIMEOUT_S = 10.0


class FlightRefused(Exception):
    """A check before the flight failed; nothing was armed.

    Attributes:
        check: the name of the (first) failed check.
        summary: what failed, without the advice of the message.
    """

    def __init__(self, check: str, detail: str, summary: str = "") -> None:
        self.check = check
        self.summary = summary or detail
        super().__init__(detail)


class FlightMode(Enum):
    """How the plan is flown."""

    OFFBOARD = "offboard"  # setpoint streaming of the exact trajectories
    MISSION = "mission"  # the PX4 mission conversion (straight legs, timed by speed changes)


@dataclass(frozen=True, slots=True)
class FlyOptions:
    """Settings of :func:`fly_plan`.

    Attributes:
        mode: offboard or mission.
        rate_hz: offboard setpoint rate (2 < rate <= 100).
        tolerance_m: refuse a vehicle farther than this from its planned start.
        end: what every vehicle does after the plan (hold, land, return).
        log_dir: write ``flight.tlog`` and ``flight.csv`` here (``None``: no files).
        connect_timeout_s: time allowed for every vehicle's first heartbeat.
        monitor: run the online safety monitor of the always-clauses.
        drag_per_s: the vehicles' drag per unit mass for the feed-forward (1/s); ``None``:
            the simulator's own (SIH_KDV / SIH_MASS) where the vehicle has it, else 0
            (:mod:`gcs.tuning`).
        arrive_m: the arrival gate at the starts (m); ``None``: from the plan's margin
            (:func:`gcs.mission_flight.arrive_gate_m`).
        acceptance_m: mission mode's waypoint acceptance radius; ``None``: chosen
            (:func:`gcs.missions.auto_acceptance_m`).
        force: fly missions whose predicted robustness is below epsilon.
        max_off_plan_m: offboard: hold every vehicle when one is farther than this from
            its plan (the monitor's tracking alarm; ``None``: never). Past the plan's margin
            (its robustness) a vehicle is warned about once, in flight and in the report.
    """

    mode: FlightMode = FlightMode.OFFBOARD
    rate_hz: float = 20.0
    tolerance_m: float = 1.0
    end: EndAction | None = None
    log_dir: Path | None = None
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S
    monitor: bool = True
    drag_per_s: float | None = None
    arrive_m: float | None = None
    acceptance_m: float | None = None
    force: bool = False
    max_off_plan_m: float | None = 3.0


# ---------------------------------------------------------------------------- before flight


def plan_formula(plan: Plan) -> Formula:
    """The plan's whole spec with the scenario's predicates (exact numpy semantics), checked
    against the plan: :func:`planner.planfile.plan_formula` (PlanFileError naming the plan file).
    """
    from planner.planfile import plan_formula as checked_formula

    return checked_formula(plan)


def preflight_interlock(plan: Plan, *, force: bool = False) -> tuple[Check, ...]:
    """``gcs verify``'s checks of ``plan``; refuse the flight if one fails (unless ``force``).

    Returns:
        Every check (failed ones included when ``force``).

    Raises:
        FlightRefused: naming the first failed check, its value and bound, and how many fail.
    """
    from gcs.checks import verify_plan

    checks = tuple(verify_plan(plan))
    failed = [c for c in checks if not c.ok]
    if failed and not force:
        c = failed[0]
        detail = f" ({c.detail})" if c.detail else ""
        summary = (
            f"the plan fails verification: {c.name}: {c.value:.4g} "
            f"(bound {c.bound:.4g}){detail}; {len(failed)} of {len(checks)} checks fail"
        )
        raise FlightRefused(
            c.name, f"refused: {summary} (gcs verify lists them; --force flies anyway)", summary
        )
    return checks


def vehicle_specs(
    plan: Plan, urls: Sequence[str] | None = None, base_port: int = 14540
) -> tuple[VehicleSpec, ...]:
    """How to reach each vehicle of ``plan``, in plan order.

    Vehicle ``i`` uses ``urls[i]`` or, with no URLs, ``udpin://0.0.0.0:{base_port+i}`` (PX4
    SITL: 14540 + i); its system id is the plan's (``i + 1`` for plans written by ``gcs plan``).

    Raises:
        UserError: a number of URLs other than the number of vehicles.
        mavlink.errors.UrlError: a malformed URL (names it and the vehicle).
    """
    from mavlink.fleet import VehicleSpec
    from mavlink.urls import default_url, parse_url

    n = len(plan.vehicles)
    if urls and len(urls) != n:
        raise UserError(
            f"--connection: {len(urls)} URL(s) given for {n} vehicle(s) "
            f"({', '.join(v.name for v in plan.vehicles)}); give one per vehicle in plan order, "
            "or none for the PX4 SITL defaults udpin://0.0.0.0:14540+i"
        )
    out = []
    for i, v in enumerate(plan.vehicles):
        url = urls[i] if urls else default_url(i, base_port)
        parse_url(url, vehicle=v.name)
        out.append(VehicleSpec(v.name, url, v.sysid))
    return tuple(out)


@contextlib.asynccontextmanager
async def signed_links(
    specs: Sequence[VehicleSpec], key_file: str | None
) -> AsyncIterator[tuple[VehicleSpec, ...]]:
    """Route every vehicle through a MAVLink 2 signing proxy when ``key_file`` is given.

    MAVSDK has no signing API: for each ``udpin://HOST:PORT`` connection a
    :class:`mavlink.signing.SigningProxy` takes the vehicle's traffic on ``HOST:PORT``
    (verifying its signatures), signs what the GCS sends, and MAVSDK is pointed at the proxy on
    a free loopback port. Yields the specs to connect with (the same specs without a key).

    Raises:
        UserError: a connection other than ``udpin://`` (the vehicle must send to the GCS).
        mavlink.signing.SigningError: a bad key file.
    """
    if key_file is None:
        yield tuple(specs)
        return
    from mavlink.fleet import VehicleSpec
    from mavlink.signing import SigningProxy, load_key
    from mavlink.urls import Scheme, parse_url

    key = load_key(key_file)
    proxies: list[SigningProxy] = []
    try:
        signed = []
        inner_ports = free_udp_ports(len(specs))
        for spec, inner in zip(specs, inner_ports, strict=True):
            url = parse_url(spec.url, vehicle=spec.name)
            if url.scheme is not Scheme.UDPIN:
                raise UserError(
                    f"--signing-key: vehicle {spec.name}: signing works with udpin:// "
                    f"connections only, got {spec.url}"
                )
            proxy = SigningProxy(key, url.port, inner, host=url.host)
            await proxy.start()
            proxies.append(proxy)
            signed.append(VehicleSpec(spec.name, f"udpin://127.0.0.1:{inner}", spec.sysid))
        yield tuple(signed)
    finally:
        for proxy in proxies:
            proxy.close()


def ground_spawns(plan: Plan) -> list[tuple[float, float, float]]:
    """Spawn points for a dry run: on the ground (mission ``z = 0``) below each planned start."""
    return [(float(v.start_enu_m[0]), float(v.start_enu_m[1]), 0.0) for v in plan.vehicles]


def free_udp_ports(k: int) -> list[int]:
    """``k`` distinct loopback UDP ports that were free a moment ago (bound to port 0)."""
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(k)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [int(s.getsockname()[1]) for s in socks]
    finally:
        for s in socks:
            s.close()


@dataclass(frozen=True, slots=True, eq=False)
class DryRun:
    """Mock vehicles running for a dry run: their fleet and the URL of each (plan order)."""

    mock: MockFleet
    urls: tuple[str, ...]
    sysids: tuple[int, ...]


@contextlib.contextmanager
def mock_vehicles(
    plan: Plan,
    *,
    seed: int = 0,
    profile: str = "px4",
    params: Mapping[str, float] | None = None,
) -> Iterator[DryRun]:
    """Mock PX4 vehicles on the ground below the plan's starts, in a background thread.

    Vehicle ``i`` has system id ``i + 1`` and sends to a free loopback port, reached at
    ``udpin://127.0.0.1:PORT`` (the URLs yielded, plan order).  ``profile`` and
    ``params`` choose the vehicle (:mod:`mavlink.mock.profiles`: ``px4`` by default).
    """
    from mavlink.mock import MockFleet

    n = len(plan.vehicles)
    ports = free_udp_ports(2 * n)
    mock = MockFleet(
        n=n,
        origin=plan.origin,
        spawns_enu_m=ground_spawns(plan),
        gcs_ports=ports[:n],
        vehicle_ports=ports[n:],
        seed=seed,
        profile=profile,
        params=params,
    )
    with mock.running_in_thread():
        yield DryRun(
            mock=mock,
            urls=tuple(f"udpin://127.0.0.1:{p}" for p in ports[:n]),
            sysids=tuple(range(1, n + 1)),
        )


# ---------------------------------------------------------------------------- evaluation


@dataclass(frozen=True, slots=True)
class ClauseOutcome:
    """One top-level clause: its text and its exact robustness planned and flown (m)."""

    text: str
    vehicles: tuple[str, ...]
    planned: float
    flown: float | None


@dataclass(frozen=True, slots=True)
class TrackingError:
    """How far one vehicle's reported positions were from its plan at the same instants.

    Attributes:
        vehicle: name.
        samples: telemetry samples inside the horizon.
        max_m, rms_m: largest and root-mean-square distance flown - planned (m).
        t_at_max_s: when the largest distance occurred (s from the plan's start).
        lag_s: the delay ``tau`` minimising the RMS distance between flown(t) and
            planned(t - tau), searched in [-0.5, 1.0] s (0: flown in step with the plan).
        rms_at_lag_m: that minimal RMS distance.
    """

    vehicle: str
    samples: int
    max_m: float
    rms_m: float
    t_at_max_s: float
    lag_s: float
    rms_at_lag_m: float


@dataclass(frozen=True, slots=True, eq=False)
class FlownEvaluation:
    """The flown data judged against the spec (exact semantics, the plan's check grid).

    Attributes:
        dt_s: grid step (the plan's ``check_dt_s``).
        planned_robustness: the spec's robustness on the planned trajectories.
        flown_robustness: on the flown tracks (``None`` when a track does not cover the
            horizon; ``coverage_problem`` says why).
        clauses: per top-level clause, planned and flown.
        tracking: per vehicle tracking error.
        coverage_problem: why flown robustness could not be evaluated, else ``""``.
    """

    dt_s: float
    planned_robustness: float
    flown_robustness: float | None
    clauses: tuple[ClauseOutcome, ...]
    tracking: tuple[TrackingError, ...]
    coverage_problem: str = ""

    @property
    def weakest_flown(self) -> ClauseOutcome | None:
        """The flown clause with the smallest robustness."""
        flown = [c for c in self.clauses if c.flown is not None]
        return min(flown, key=lambda c: c.flown or 0.0) if flown else None


def _tracking(
    name: str, track: FlownTrack, plan_pos: Any, horizon_s: float, lags_s: np.ndarray
) -> TrackingError:
    inside = (track.t_s >= 0.0) & (track.t_s <= horizon_s)
    t = track.t_s[inside]
    p = track.pos_enu_m[inside]
    if t.size == 0:
        nan = math.nan
        return TrackingError(name, 0, nan, nan, nan, nan, nan)
    d = np.linalg.norm(p - plan_pos(t), axis=1)
    i = int(np.argmax(d))
    # planned(t - tau) for every candidate delay at once: (lags, samples, 3).
    shifted = plan_pos(np.clip((t[None, :] - lags_s[:, None]).ravel(), 0.0, horizon_s))
    err = np.linalg.norm(shifted.reshape(lags_s.size, t.size, 3) - p[None], axis=2)
    rms = np.sqrt(np.mean(err**2, axis=1))
    j = int(np.argmin(rms))
    return TrackingError(
        vehicle=name,
        samples=int(t.size),
        max_m=float(d[i]),
        rms_m=float(np.sqrt(np.mean(d**2))),
        t_at_max_s=float(t[i]),
        lag_s=float(lags_s[j]),
        rms_at_lag_m=float(rms[j]),
    )


def evaluate_flight(plan: Plan, tracks: Mapping[str, FlownTrack]) -> FlownEvaluation:
    """Exact robustness of the flown tracks next to the plan's, per clause and overall.

    Flown positions are resampled on the plan's check grid ``t = 0, dt, ..., horizon`` by
    linear interpolation of the telemetry (:meth:`mavlink.tlog.FlownTrack.resample`, which
    refuses a track that does not cover the horizon).
    """
    from mavlink.errors import LinkError

    phi = plan_formula(plan)
    dt = plan.check_dt_s
    n = round(plan.horizon_s / dt) + 1
    t = np.arange(n) * dt
    planned = {v.name: v.trajectory.position(t) for v in plan.vehicles}
    flown: dict[str, np.ndarray] | None = {}
    problem = ""
    for v in plan.vehicles:
        tr = tracks.get(v.name)
        if tr is None:
            flown, problem = None, f"no telemetry from {v.name}"
            break
        try:
            flown[v.name] = tr.resample(dt, plan.horizon_s)  # type: ignore[index]
        except LinkError as exc:
            flown, problem = None, str(exc)
            break
    clauses = []
    for c in phi.clauses:
        clauses.append(
            ClauseOutcome(
                text=str(c),
                vehicles=tuple(sorted(c.signal_names() & planned.keys())),
                planned=float(c.robustness(planned, dt)),
                flown=None if flown is None else float(c.robustness(flown, dt)),
            )
        )
    lags = np.round(np.arange(-0.5, 1.0 + 1e-9, 0.01), 6)
    tracking = tuple(
        _tracking(v.name, tracks[v.name], v.trajectory.position, plan.horizon_s, lags)
        for v in plan.vehicles
        if v.name in tracks
    )
    return FlownEvaluation(
        dt_s=dt,
        planned_robustness=float(phi.robustness(planned, dt)),
        flown_robustness=None if flown is None else float(phi.robustness(flown, dt)),
        clauses=tuple(clauses),
        tracking=tracking,
        coverage_problem=problem,
    )


# ---------------------------------------------------------------------------- progress


@dataclass(slots=True)
class FlightClock:
    """The plan's start instant (``time.monotonic()``) per vehicle, once the flight has one."""

    t0_monotonic_s: dict[str, float] = field(default_factory=dict)

    def plan_time(self, name: str, now: float) -> float | None:
        """Seconds since ``name``'s plan start, or ``None`` before it."""
        t0 = self.t0_monotonic_s.get(name)
        return None if t0 is None else now - t0


class FlightProgress:
    """Live view of a flight: per vehicle mode, distance to the plan, robustness so far.

    On a terminal one status line is rewritten in place (4 times a second); otherwise a
    plain line is printed every ``plain_interval_s``. "Robustness so far" of a vehicle is
    the minimum over the clauses it appears in of their exact robustness on its flown
    positions up to now followed by the plan for the rest of the horizon.

    The work per update is bounded: the flown samples are written into the signals
    incrementally (only the grid steps since the last update), the clauses are evaluated
    per template (:class:`planner.stl.batch.ClauseBatch`), and :meth:`run` does that on a
    worker thread, so the setpoint stream on the event loop never waits for it.

    Args:
        plan: the plan being flown.
        stream: where to write (stdout, or stderr under ``--json``).
        tty: rewrite one line (default: ``stream.isatty()``).
        plain_interval_s: seconds between plain lines.
    """

    def __init__(
        self,
        plan: Plan,
        stream: TextIO | None = None,
        *,
        tty: bool | None = None,
        plain_interval_s: float = 2.0,
    ) -> None:
        from planner.stl.batch import ClauseBatch

        self.plan = plan
        self.stream = stream if stream is not None else sys.stdout
        self.tty = self.stream.isatty() if tty is None else tty
        self.plain_interval_s = plain_interval_s
        self.phi = plan_formula(plan)
        self.dt_s = max(plan.check_dt_s, 0.05)
        n = round(plan.horizon_s / self.dt_s) + 1
        self.t_grid = np.arange(n) * self.dt_s
        self.planned = {v.name: v.trajectory.position(self.t_grid) for v in plan.vehicles}
        names = [v.name for v in plan.vehicles]
        clauses = list(self.phi.clauses)
        self._batch = ClauseBatch(clauses)
        self._members = {
            name: np.array([i for i, c in enumerate(clauses) if name in c.signal_names()], int)
            for name in names
        }
        self._samples: dict[str, list[tuple[float, float, float, float]]] = {n: [] for n in names}
        # the signals: flown up to _filled[name] grid steps, planned after
        self._signals = {name: p.copy() for name, p in self.planned.items()}
        self._filled = dict.fromkeys(names, 0)
        self._lock = threading.Lock()  # record() and so_far() may run on different threads
        self._maps: dict[GeodeticPoint, NedToEnuMap] = {}  # per EKF origin
        self.lines = 0
        self.last_line = ""

    def _fill(self, name: str, t_now_s: float) -> None:
        """Write the flown positions into the grid steps up to ``t_now_s`` not yet written
        (steps before the last sample only: a later sample could still move them)."""
        with self._lock:
            rows = self._samples[name]
            if not rows:
                return
            t_last = rows[-1][0]
            k0 = self._filled[name]
            k1 = int(np.searchsorted(self.t_grid, min(t_now_s, t_last), side="right"))
            if k1 <= k0:
                return
            # the samples around steps k0..k1-1: from the last one at or before step k0
            t_first = self.t_grid[k0]
            j = max(0, bisect.bisect_right(rows, (t_first, math.inf, 0.0, 0.0)) - 1)
            a = np.asarray(rows[j:])
        sig = self._signals[name]
        for ax in range(3):
            sig[k0:k1, ax] = np.interp(self.t_grid[k0:k1], a[:, 0], a[:, ax + 1])
        self._filled[name] = k1

    def so_far(self, t_now_s: float) -> dict[str, float]:
        """Robustness so far per vehicle (see class docstring) at plan time ``t_now_s``."""
        for name in self._signals:
            self._fill(name, t_now_s)
        values = self._batch.values(self._signals, self.dt_s)
        return {
            name: float(values[idx].min()) if idx.size else math.nan
            for name, idx in self._members.items()
        }

    def record(self, name: str, t_s: float, pos_enu_m: np.ndarray) -> None:
        """Add a position sample of ``name`` at plan time ``t_s``."""
        with self._lock:
            rows = self._samples[name]
            if not rows or t_s > rows[-1][0]:
                rows.append((t_s, float(pos_enu_m[0]), float(pos_enu_m[1]), float(pos_enu_m[2])))

    def line(
        self,
        fleet: Fleet,
        clock: FlightClock,
        origins: Mapping[str, GeodeticPoint],
        *,
        with_robustness: bool = True,
    ) -> str:
        """One status line for the current instant (and record the positions it read).

        ``with_robustness=False`` only records (the robustness is the costly part).
        """
        from planner.frames import NedToEnuMap

        now = time.monotonic()
        parts = []
        t_plan: float | None = None
        for v in self.plan.vehicles:
            st = fleet[v.name].status(now)
            mode = st.mode.label if st.mode is not None else str(st.custom_mode)
            t = clock.plan_time(v.name, now)
            where = ""
            if st.pos_ned_m is not None and v.name in origins:
                origin = origins[v.name]
                fmap = self._maps.get(origin)
                if fmap is None:
                    fmap = self._maps[origin] = NedToEnuMap.between(self.plan.origin, origin)
                pos = fmap.position(st.pos_ned_m)
                ref_t = 0.0 if t is None else min(max(t, 0.0), v.trajectory.duration_s)
                ref = v.trajectory.position(np.array([ref_t]))[0]
                where = f" {float(np.linalg.norm(pos - ref)):5.2f} m"
                if t is not None and t >= 0.0:
                    self.record(v.name, t, pos)
                    t_plan = t if t_plan is None else max(t_plan, t)
            parts.append(f"{v.name} {mode}{where}")
        if t_plan is not None and with_robustness:
            rho = self.so_far(t_plan)
            parts = [
                f"{p} rho {rho[v.name]:+.3f}"
                for p, v in zip(parts, self.plan.vehicles, strict=True)
            ]
            head = f"t {min(t_plan, self.plan.horizon_s):5.1f}/{self.plan.horizon_s:g} s"
        else:
            head = "preparing (distance to start)"
        return head + " | " + " | ".join(parts)

    def show(self, text: str) -> None:
        """Write ``text``: rewrite the status line on a terminal, else a new line."""
        with self._lock:
            self.lines += 1
            if self.tty:
                width = shutil.get_terminal_size((120, 20)).columns
                self.last_line = text[: width - 1]
                self.stream.write("\r\033[K" + self.last_line)
            else:
                self.last_line = text
                self.stream.write(text + "\n")
            self.stream.flush()

    def note(self, text: str) -> None:
        """Write ``text`` on a line of its own (the status line, if any, is redrawn after it).

        Safe from any thread (the safety monitor's warnings come from its own).
        """
        with self._lock:
            if self.tty and self.lines:
                self.stream.write("\r\033[K" + text + "\n" + self.last_line)
            else:
                self.stream.write(text + "\n")
            self.stream.flush()

    def close(self) -> None:
        """End the status line (terminal)."""
        if self.tty and self.lines:
            self.stream.write("\n")
            self.stream.flush()

    async def run(
        self,
        fleet: Fleet,
        clock: FlightClock,
        origins: Mapping[str, GeodeticPoint],
        stop: asyncio.Event,
    ) -> None:
        """Sample positions every 0.1 s and show a line every 0.25 s (tty) or interval.

        Sampling and evaluation run on a worker thread (the event loop only waits for it),
        one at a time; only the writing is done here.
        """
        show_every = 0.25 if self.tty else self.plain_interval_s
        next_show = time.monotonic()
        while not stop.is_set():
            due = time.monotonic() >= next_show
            text = await asyncio.to_thread(self.line, fleet, clock, origins, with_robustness=due)
            if due:
                self.show(text)
                next_show += show_every
            await asyncio.sleep(0.1)  # no child task: an interruption cancels those


# ---------------------------------------------------------------------------- the flight


@dataclass(frozen=True, slots=True, eq=False)
class FlightOutcome:
    """What :func:`fly_plan` did.

    Attributes:
        mode: offboard or mission.
        completed: the whole plan was flown, no safety stop, no failed end action.
        interrupted: Ctrl-C stopped it (every vehicle was commanded to hold).
        connect_s: wall time to connect every vehicle and learn its origin.
        flight_s: wall time from then to the end action (take-off, flight, end).
        t0_unix_s: Unix time of the plan's start (offboard; the earliest vehicle in mission mode).
        tracks: flown tracks in the mission frame, times from each vehicle's plan start.
        evaluation: flown vs planned robustness (``None`` when no track was recorded).
        stats: offboard stream statistics per vehicle (empty in mission mode).
        missions: mission runs per vehicle (mission mode).
        safety_event: what the safety monitor stopped, if it did.
        monitor: what the safety monitor did (``None``: it did not run).
        end_failures: vehicles whose end action (or hold on Ctrl-C) failed, with the reason.
        final_modes: each vehicle's mode label at the end.
        tlog: the recording's statistics (with a log directory).
        files: what was written, by kind (``tlog``, ``csv``).
        mission: mission mode's conversion, prediction, clock skews and lateness.
        tuning: each vehicle's tracking model (drag fed forward, gains, estimator accuracy).
        warnings: margin warnings shown before the flight.
        accuracy_m: per vehicle the worst (horizontal, vertical) position accuracy its
            estimator reported during the flight (ESTIMATOR_STATUS, 1-sigma).
        flown_lower_bound: flown robustness minus twice the worst 3-D accuracy: what the
            spec is worth at least if every estimate was within its reported accuracy of
            the truth (flown robustness is computed on the estimates).
    """

    mode: FlightMode
    completed: bool
    interrupted: bool
    connect_s: float
    flight_s: float
    t0_unix_s: float | None
    tracks: dict[str, FlownTrack]
    evaluation: FlownEvaluation | None
    stats: dict[str, StreamStats] = field(default_factory=dict)
    missions: dict[str, MissionRun] = field(default_factory=dict)
    safety_event: SafetyEvent | None = None
    monitor: MonitorStats | None = None
    end_failures: dict[str, str] = field(default_factory=dict)
    final_modes: dict[str, str] = field(default_factory=dict)
    tlog: TlogStats | None = None
    files: dict[str, Path] = field(default_factory=dict)
    mission: MissionFlight | None = None
    tuning: dict[str, VehicleTuning] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    accuracy_m: dict[str, tuple[float, float]] = field(default_factory=dict)
    flown_lower_bound: float | None = None


def _make_log_dir(log_dir: Path | None) -> None:
    if log_dir is None:
        return
    try:
        log_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputFileError(f"--log {log_dir}: cannot create: {exc.strerror or exc}") from None


def _tracks_from_rows(
    rows: Mapping[str, np.ndarray],
    t0: Mapping[str, float],
    mission_origin: GeodeticPoint,
    origins: Mapping[str, GeodeticPoint],
) -> dict[str, FlownTrack]:
    """FlownTracks from :meth:`Vehicle.stop_track` rows ``(t, n, e, d, vn, ve, vd)``."""
    from mavlink.tlog import FlownTrack
    from planner.frames import ned_to_enu, ned_vector_to_enu

    out = {}
    for name, r in rows.items():
        if r.shape[0] == 0 or name not in t0:
            continue
        out[name] = FlownTrack(
            name=name,
            t_s=r[:, 0] - t0[name],
            pos_enu_m=ned_to_enu(r[:, 1:4], mission_origin, origins[name]),
            vel_enu_m_s=ned_vector_to_enu(r[:, 4:7], mission_origin, origins[name]),
            pos_ned_m=r[:, 1:4],
        )
    return out


#: The PX4 mode each end action leads to.
_END_MODE = {"hold": "AUTO.LOITER", "land": "AUTO.LAND", "return": "AUTO.RTL"}


def cfg_end(opts: FlyOptions) -> str:
    """The end action's name (``hold`` by default)."""
    return "hold" if opts.end is None else str(opts.end.value)


async def _show_mode(
    fleet: Fleet, label: str, skip: Mapping[str, str], timeout_s: float = 3.0
) -> None:
    """Wait (bounded) until the vehicles report ``label``: PX4 heartbeats come at 1 Hz.

    A vehicle that does not get there in time is reported by its final mode, not an error.
    """
    from mavlink.errors import LinkError

    async def one(v: Vehicle) -> None:
        with contextlib.suppress(LinkError):
            await v.wait_for(
                lambda s: s.mode is not None and s.mode.label == label, label, timeout_s=timeout_s
            )

    await asyncio.gather(*(one(v) for v in fleet if v.name not in skip))


async def _fly_offboard(
    fleet: Fleet,
    plan: Plan,
    opts: FlyOptions,
    clock: FlightClock,
    tuning: Mapping[str, VehicleTuning],
    note: Callable[[str], None],
) -> Any:
    from gcs.mission_flight import arrive_gate_m
    from mavlink.monitor import SafetyMonitor, always_clauses
    from mavlink.offboard import EndAction, OffboardConfig, fly_offboard

    names = [v.name for v in plan.vehicles]

    def started(t0_monotonic_s: float) -> None:
        """The shared start time, for the progress view."""
        clock.t0_monotonic_s.update(dict.fromkeys(names, t0_monotonic_s))

    clauses = always_clauses(plan_formula(plan), names) if opts.monitor else ()
    monitor = SafetyMonitor(
        clauses,
        horizon_s=0.5 if opts.monitor else 0.0,
        on_start=started,
        # the tracking alarm: warn past the plan's margin, hold past the bound
        warn_off_plan_m=plan.robustness if opts.monitor and plan.robustness > 0 else None,
        max_off_plan_m=opts.max_off_plan_m if opts.monitor else None,
        on_warning=note,
    )
    cfg = OffboardConfig(
        rate_hz=opts.rate_hz,
        start_tolerance_m=opts.tolerance_m,
        arrive_m=opts.arrive_m or arrive_gate_m(plan),
        end_action=opts.end or EndAction.HOLD,
        drag_per_s={n: t.drag_per_s for n, t in tuning.items()},
    )
    if cfg.end_action is EndAction.LAND:
        from gcs.landing import landing_targets
        from planner.frames import enu_to_geodetic

        land_at = {}
        for name, point in landing_targets(plan).items():
            lat, lon, alt = (float(np.ravel(x)[0]) for x in enu_to_geodetic(point, plan.origin))
            land_at[name] = (lat, lon, alt)
        cfg = dataclasses.replace(cfg, land_at=land_at)
    trajs = {v.name: v.trajectory for v in plan.vehicles}
    return await fly_offboard(fleet, trajs, plan.origin, cfg, monitor=monitor)


async def fly_plan(
    plan: Plan,
    specs: Sequence[VehicleSpec],
    options: FlyOptions | None = None,
    *,
    progress: FlightProgress | None = None,
) -> FlightOutcome:
    """Connect, fly, record and evaluate (module docstring); Ctrl-C holds every vehicle.

    Args:
        plan: a loaded plan (already through :func:`preflight_interlock`).
        specs: how to reach each vehicle (:func:`vehicle_specs`), plan order.
        options: :class:`FlyOptions`.
        progress: live view to run during the flight (``None``: silent).

    Returns:
        :class:`FlightOutcome`; a safety stop or an interruption is an outcome, not an error.

    Raises:
        mavlink.errors.ConnectTimeoutError: a vehicle never answered (names its URL).
        mavlink.errors.PreflightError: a vehicle too far from its start / cannot reach it.
        mavlink.errors.LinkError: other link failures before the flight.
    """
    from gcs.mission_flight import fly_mission_plan
    from gcs.tuning import expected_error_m, margin_warnings, read_tuning
    from mavlink.fleet import Fleet
    from mavlink.tlog import TlogRecorder, write_tracks_csv

    opts = options or FlyOptions()
    _make_log_dir(opts.log_dir)
    t_start = time.monotonic()
    files: dict[str, Path] = {}
    clock = FlightClock()
    async with Fleet(specs, connect_timeout_s=opts.connect_timeout_s) as fleet:
        origins = await fleet.origins()
        t_connected = time.monotonic()
        recorder = None
        if opts.log_dir is not None:
            files["tlog"] = opts.log_dir / "flight.tlog"
            recorder = TlogRecorder(fleet, files["tlog"])
            recorder.start()
        stop_view = asyncio.Event()
        view = (
            asyncio.create_task(progress.run(fleet, clock, origins, stop_view))
            if progress is not None
            else None
        )
        interrupted = False
        result: Any = None
        mission: MissionFlight | None = None
        end_failures: dict[str, str] = {}
        for v in fleet:
            v.start_track()
        names = [v.name for v in plan.vehicles]
        tuning = await read_tuning(fleet, names, opts.drag_per_s)
        # offboard feeds the drag forward; a mission's timing is judged by its prediction
        warnings = margin_warnings(plan, expected_error_m(plan, tuning, fed_forward=True))
        if progress is not None:
            for w in warnings:
                print(w, file=progress.stream, flush=True)
        guard = None

        def note(line: str) -> None:
            if progress is not None:
                progress.note(line)
            else:
                print(line, file=sys.stderr, flush=True)

        try:
            # the flight's own tasks end with it; leaving it abnormally holds every vehicle
            async with fleet.flight() as guard:
                if opts.mode is FlightMode.OFFBOARD:
                    result = await _fly_offboard(fleet, plan, opts, clock, tuning, note)
                else:
                    mission = await fly_mission_plan(fleet, plan, opts, clock, tuning)
        except asyncio.CancelledError:
            # Ctrl-C: asyncio.run cancelled us, and every vehicle was commanded to hold on the
            # way out of the flight. Take the cancellation back to report.
            task = asyncio.current_task()
            if task is not None:
                task.uncancel()
            interrupted = True
            end_failures = dict(guard.failures) if guard is not None else {}
        finally:
            accuracy = {v.name: v.track_accuracy_m for v in fleet}
            rows = {v.name: v.stop_track() for v in fleet}
            stop_view.set()
            if view is not None:
                await view
            if progress is not None:
                progress.close()
            tlog = recorder.stop() if recorder is not None else None
        safety_event = (
            result.safety_event
            if result is not None
            else (mission.safety_event if mission is not None else None)
        )
        if interrupted or safety_event is not None:
            await _show_mode(fleet, "AUTO.LOITER", end_failures)
        elif result is not None:
            await _show_mode(fleet, _END_MODE[cfg_end(opts)], end_failures)
        final_modes = {
            s.name: (s.mode.label if s.mode is not None else str(s.custom_mode))
            for s in fleet.statuses()
        }
    flight_s = time.monotonic() - t_connected
    connect_s = t_connected - t_start
    t0 = dict(clock.t0_monotonic_s)
    if result is not None:
        # fly_offboard recorded the tracks itself (from just before the shared start).
        tracks = dict(result.tracks)
    else:
        tracks = _tracks_from_rows(rows, t0, plan.origin, origins)
    if opts.log_dir is not None:
        files["csv"] = write_tracks_csv(opts.log_dir / "flight.csv", tracks)
    evaluation = evaluate_flight(plan, tracks) if tracks else None
    lower = None
    if evaluation is not None and evaluation.flown_robustness is not None:
        errs = [math.hypot(*a) for a in accuracy.values() if a is not None]
        if len(errs) == len(accuracy):
            # every predicate moves by at most its vehicles' position error (a distance
            # between two vehicles by both): flown - 2 * worst 3-D accuracy
            lower = evaluation.flown_robustness - 2.0 * max(errs)
    offset = time.time() - time.monotonic()
    t0_unix = min(t0.values()) + offset if t0 else None
    missions = dict(mission.runs) if mission is not None else {}
    if result is not None:
        end_failures = dict(result.end_failures)
        completed = bool(result.completed) and not end_failures
    else:
        completed = (
            not interrupted
            and safety_event is None
            and bool(missions)
            and all(r.finished for r in missions.values())
        )
    return FlightOutcome(
        mode=opts.mode,
        completed=completed and not interrupted,
        interrupted=interrupted,
        connect_s=connect_s,
        flight_s=flight_s,
        t0_unix_s=t0_unix,
        tracks=tracks,
        evaluation=evaluation,
        stats=dict(result.stats) if result is not None else {},
        missions=missions,
        safety_event=safety_event,
        monitor=(
            result.monitor
            if result is not None
            else (mission.monitor if mission is not None else None)
        ),
        end_failures=end_failures,
        final_modes=final_modes,
        tlog=tlog,
        files=files,
        mission=mission,
        tuning=tuning,
        warnings=tuple(warnings),
        accuracy_m={k: v for k, v in accuracy.items() if v is not None},
        flown_lower_bound=lower,
    )


# ---------------------------------------------------------------------------- text


def format_outcome(plan: Plan, outcome: FlightOutcome) -> str:
    """The end-of-flight summary for the operator (several lines)."""
    from mavlink.stream import STATS_HEADER

    lines = []
    if outcome.interrupted:
        lines.append("interrupted: every vehicle was commanded to hold")
    elif outcome.safety_event is not None:
        lines.append(f"safety stop: {outcome.safety_event.describe()}")
    if outcome.monitor is not None and outcome.monitor.stale:
        lines.append(f"monitor: {outcome.monitor.describe_stale()}")
    verdict = "completed" if outcome.completed else "NOT completed"
    lines.append(
        f"flight {verdict} in {outcome.flight_s:.1f} s ({outcome.mode.value}, "
        f"{len(plan.vehicles)} vehicle(s)); modes now: "
        + ", ".join(f"{k} {m}" for k, m in outcome.final_modes.items())
    )
    for name, why in outcome.end_failures.items():
        lines.append(f"  {name}: end action failed: {why}")
    ev = outcome.evaluation
    if ev is not None:
        flown = "n/a" if ev.flown_robustness is None else f"{ev.flown_robustness:+.4f}"
        lines.append(
            f"robustness (exact, dt {ev.dt_s:g} s): planned {ev.planned_robustness:+.4f}, "
            f"flown {flown}" + (f" ({ev.coverage_problem})" if ev.coverage_problem else "")
        )
        if outcome.flown_lower_bound is not None:
            acc = max(outcome.accuracy_m.values(), key=lambda a: math.hypot(*a))
            lines.append(
                f"  flown robustness is on the vehicles' estimates; at least "
                f"{outcome.flown_lower_bound:+.4f} if each was within the accuracy its "
                f"estimator reported (worst {acc[0]:.2f} m horizontal, {acc[1]:.2f} m vertical)"
            )
        w = ev.weakest_flown
        if w is not None:
            lines.append(
                f"  weakest flown clause {w.flown:+.4f} (planned {w.planned:+.4f}): {w.text}"
            )
        for te in ev.tracking:
            over = (
                f" (WARNING: more than the plan's margin {plan.robustness:.3f} m)"
                if plan.robustness > 0 and te.max_m > plan.robustness
                else ""
            )
            lines.append(
                f"  {te.vehicle}: tracking error max {te.max_m:.3f} m at t {te.t_at_max_s:.2f} s"
                f"{over}, rms {te.rms_m:.3f} m; best-fit delay {te.lag_s:+.2f} s (rms "
                f"{te.rms_at_lag_m:.3f} m)"
            )
    if outcome.stats:
        lines.append("setpoint stream (lateness of each send after its deadline):")
        lines.append("  " + STATS_HEADER)
        lines += ["  " + s.row() for s in outcome.stats.values()]
    lines += _tuning_lines(outcome)
    m = outcome.mission
    if m is not None:
        c = m.conversion
        how = "chosen" if c.acceptance_auto else "given"
        lines.append(
            f"missions: acceptance radius {c.acceptance_m:.2f} m ({how}), legs "
            f"{'re-timed' if c.retimed else 'at their average speeds'}; robustness predicted "
            f"{c.predicted_robustness:+.4f} (straight legs {c.straight_leg_robustness:+.4f})"
        )
    for name, run in outcome.missions.items():
        extra = ""
        if m is not None:
            late = m.late_s.get(name, math.inf)
            dep = m.departure_skew_s.get(name)
            extra = (
                f", {'+' if late >= 0 else ''}{late:.1f} s against the plan"
                if math.isfinite(late)
                else ""
            )
            extra += f"; start skew {m.start_skew_s.get(name, 0.0) * 1000:+.0f} ms"
            if dep is not None:
                extra += f", left the start waypoint {dep:+.2f} s off the prediction"
        items = len(m.conversion.missions[name].items) if m is not None else None
        lines.append(
            f"  {name}: mission {'finished' if run.finished else 'NOT finished'} in "
            f"{run.duration_s:.1f} s{extra}; "
            + (f"at item {run.current[-1][0]} of {items}" if run.current and items else "")
        )
    if outcome.tlog is not None:
        lines.append(f"telemetry: {outcome.tlog.path} ({outcome.tlog.messages} messages)")
    if "csv" in outcome.files:
        lines.append(f"tracks: {outcome.files['csv']}")
    return "\n".join(lines)


def _tuning_lines(outcome: FlightOutcome) -> list[str]:
    """Drag fed forward per vehicle, the lag it still showed, and the drag to set."""
    from gcs.tuning import LAG_NOISE_S, drag_from_lag

    ev = outcome.evaluation
    lags = {t.vehicle: t.lag_s for t in ev.tracking} if ev is not None else {}
    lines = []
    for name, tu in outcome.tuning.items():
        lag = lags.get(name, math.nan)
        acc = f", estimator accuracy {tu.accuracy_m:.2f} m" if tu.accuracy_m is not None else ""
        how = "fed forward" if outcome.mode is FlightMode.OFFBOARD else "in the prediction"
        text = f"  {name}: drag {tu.drag_per_s:.2f} /s {how} ({tu.drag_source}){acc}"
        if math.isfinite(lag) and outcome.mode is FlightMode.OFFBOARD:
            c = drag_from_lag(lag, tu)
            text += f"; flown lag {lag:+.2f} s -> drag {c:.2f} /s"
            if abs(lag) > LAG_NOISE_S:
                text += f" (set --drag {c:.2f})"
        lines.append(text)
    return lines


def outcome_json(plan: Plan, outcome: FlightOutcome) -> dict[str, Any]:
    """The outcome as a JSON-ready dict (``gcs fly --json``)."""
    ev = outcome.evaluation

    def num(x: float | None) -> float | None:
        return None if x is None or not math.isfinite(x) else float(x)

    return {
        "mode": outcome.mode.value,
        "completed": outcome.completed,
        "interrupted": outcome.interrupted,
        "connect_s": outcome.connect_s,
        "flight_s": outcome.flight_s,
        "t0_unix_s": outcome.t0_unix_s,
        "safety_event": None if outcome.safety_event is None else outcome.safety_event.describe(),
        "monitor": None if outcome.monitor is None else outcome.monitor.as_json(),
        "decision_latency_s": (
            None if outcome.safety_event is None else outcome.safety_event.latency_s
        ),
        "end_failures": outcome.end_failures,
        "final_modes": outcome.final_modes,
        "planned_robustness": None if ev is None else num(ev.planned_robustness),
        "flown_robustness": None if ev is None else num(ev.flown_robustness),
        "coverage_problem": None if ev is None else ev.coverage_problem or None,
        "clauses": []
        if ev is None
        else [
            {"text": c.text, "planned": num(c.planned), "flown": num(c.flown)} for c in ev.clauses
        ],
        "tracking": []
        if ev is None
        else [
            {
                "vehicle": t.vehicle,
                "samples": t.samples,
                "max_m": num(t.max_m),
                "rms_m": num(t.rms_m),
                "lag_s": num(t.lag_s),
                "rms_at_lag_m": num(t.rms_at_lag_m),
            }
            for t in ev.tracking
        ],
        "stream": {
            name: {
                "sent": s.sent,
                "skipped": s.skipped,
                "failed": s.failed,
                "late": s.late,
                "mean_lateness_s": num(s.mean_lateness_s),
                "p99_lateness_s": num(s.p99_lateness_s),
                "max_lateness_s": num(s.max_lateness_s),
                "rate_hz": s.rate_hz,
            }
            for name, s in outcome.stats.items()
        },
        "missions": {
            name: {
                "finished": r.finished,
                "duration_s": r.duration_s,
                "reached": len(r.reached),
                "late_s": None if outcome.mission is None else num(outcome.mission.late_s[name]),
                "start_skew_s": None
                if outcome.mission is None
                else num(outcome.mission.start_skew_s[name]),
                "departure_skew_s": None
                if outcome.mission is None
                else num(outcome.mission.departure_skew_s[name]),
            }
            for name, r in outcome.missions.items()
        },
        "mission_prediction": None
        if outcome.mission is None
        else {
            "acceptance_m": outcome.mission.conversion.acceptance_m,
            "acceptance_auto": outcome.mission.conversion.acceptance_auto,
            "retimed": outcome.mission.conversion.retimed,
            "predicted_robustness": num(outcome.mission.conversion.predicted_robustness),
            "straight_leg_robustness": num(outcome.mission.conversion.straight_leg_robustness),
            "predicted_late_s": {k: num(v) for k, v in outcome.mission.conversion.late_s.items()},
        },
        "tuning": {
            name: {
                "drag_per_s": t.drag_per_s,
                "drag_source": t.drag_source,
                "expected_lag_s": t.expected_lag_s,
                "accuracy_m": t.accuracy_m,
            }
            for name, t in outcome.tuning.items()
        },
        "warnings": list(outcome.warnings),
        "flown_lower_bound": num(outcome.flown_lower_bound),
        "estimator_accuracy_m": {k: list(v) for k, v in outcome.accuracy_m.items()},
        "tlog_messages": None if outcome.tlog is None else outcome.tlog.messages,
        "files": {k: str(p) for k, p in outcome.files.items()},
    }
