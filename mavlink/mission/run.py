"""A mission flown: its start, confirmed, and what the vehicles report while they fly it.

:func:`start_mission_confirmed` starts an uploaded mission and waits until the vehicle is
in AUTO.MISSION, armed (and climbing); :class:`MissionFollower` records MISSION_CURRENT and
MISSION_ITEM_REACHED as :class:`MissionRun`. :class:`mavlink.mission.flight.MissionDriver` uses both to fly
missions with the flight engine.

A room of its own because it acts on a plan already on the vehicles: it uploads nothing.
"""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from mavlink.clock import WALL, Clock
from mavlink.errors import CommandError
from mavlink.link.mavsdk_glue import MAV_RESULT_NAMES, mavsdk_call
from mavlink.px4_modes import Px4Mode

if TYPE_CHECKING:
    from mavlink.link.vehicle import Vehicle
    from mavlink.link.vehicle_status import VehicleStatus

#: MAV_CMD_DO_SET_MODE and MAV_CMD_MISSION_START: the commands a mission start is made of.
_START_COMMANDS = frozenset({176, 300})


@dataclass(frozen=True, slots=True)
class MissionStart:
    """What became of one vehicle's mission start (:func:`start_mission_confirmed`).

    Attributes:
        vehicle: name.
        started: the vehicle is in AUTO.MISSION, armed (and climbing, when asked).
        attempts: start commands sent.
        detail: what was seen: the confirmation, or why not (mode, acks, PX4's STATUSTEXT).
        t_accepted_monotonic_s: when the start that took effect was sent (``nan`` if none).
    """

    vehicle: str
    started: bool
    attempts: int
    detail: str
    t_accepted_monotonic_s: float = math.nan


async def start_mission_confirmed(
    v: Vehicle,
    *,
    timeout_s: float = 10.0,
    climb_m: float | None = 0.3,
    climb_timeout_s: float = 15.0,
    mode_wait_s: float = 1.6,
    retry_after_s: float = 0.3,
) -> MissionStart:
    """Start ``v``'s uploaded mission and confirm it took effect, retrying a refused start.

    PX4 acknowledges a mode change before its commander decides on it: right after an upload
    it answers ACCEPTED and ~12 ms later TEMPORARILY_REJECTED, and stays in its mode
    (docs/px4-behaviour.md). So a start counts only when the heartbeat shows AUTO.MISSION and
    armed; a late rejection or a mode that does not change within ``mode_wait_s`` (PX4
    heartbeats come at 1 Hz) is retried until ``timeout_s`` (re-arming a vehicle that
    disarmed meanwhile). A heartbeat after the start that shows AUTO.MISSION but disarmed is
    PX4 having taken the start and disarmed the vehicle on the ground: not started, and not
    retried. With ``climb_m`` the vehicle must also leave the ground: in air
    (EXTENDED_SYS_STATE) and ``climb_m`` above where it started, within ``climb_timeout_s``
    (PX4 skips the take-off of a mission whose first waypoint is within NAV_MC_ALT_RAD of the
    vehicle, and auto-disarms it on the ground).

    Never raises for a refusal: the result says what happened, with PX4's STATUSTEXTs.
    """

    t_begin = v.clock.monotonic()
    deadline = t_begin + timeout_s
    late: list[tuple[float, int]] = []

    def on_ack(msg: Any, _ud: Any) -> None:
        if msg.system_id != v.spec.sysid:
            return
        f = json.loads(msg.fields_json)
        if int(f.get("command", -1)) in _START_COMMANDS and int(f.get("result", 0)) != 0:
            late.append((v.clock.monotonic(), int(f["result"])))

    def texts() -> str:
        said = [t for sev, t in v.statustexts(t_begin) if sev <= 4]
        return f"; PX4 said: {' / '.join(dict.fromkeys(said))}" if said else ""

    st0 = v.status()
    alt0 = -st0.pos_ned_m[2] if st0.pos_ned_m is not None else math.nan
    handle = v.direct.subscribe_message("COMMAND_ACK", on_ack)
    attempts, why = 0, "no start command was accepted"
    t_ok = math.nan
    try:
        while v.clock.monotonic() < deadline:
            if attempts:
                await v.clock.sleep(retry_after_s)
            attempts += 1
            st = v.status()
            if not st.armed:
                try:
                    await v.arm()
                except CommandError as exc:
                    why = f"arm: {exc.result}"
                    continue
            t_cmd = v.clock.monotonic()
            try:
                result = await mavsdk_call(v.mission_raw.start_mission_async)
            except TimeoutError:
                result = "TIMEOUT"
            name = getattr(result, "name", str(result))
            if name != "SUCCESS":
                why = f"start refused: {name}"
                continue
            # Accepted: wait for the heartbeat's mode, or PX4's late rejection.
            t_wait = v.clock.monotonic() + mode_wait_s
            while v.clock.monotonic() < t_wait and not any(t >= t_cmd for t, _ in late):
                st = v.status()
                if st.mode is Px4Mode.AUTO_MISSION and (st.armed or _heard_since(v, st, t_cmd)):
                    break
                await v.clock.sleep(0.02)
            rejected = [r for t, r in late if t >= t_cmd]
            st = v.status()
            if st.mode is Px4Mode.AUTO_MISSION and st.armed and not rejected:
                t_ok = t_cmd
                break
            mode = st.mode.label if st.mode is not None else str(st.custom_mode)
            if st.mode is Px4Mode.AUTO_MISSION and not rejected and _heard_since(v, st, t_cmd):
                # PX4 took the start and disarmed the vehicle on the ground (the take-off it
                # skipped, then COM_DISARM_PRFLT) before its 1 Hz heartbeat showed it armed:
                # re-arming and starting again would be a second start nobody asked for.
                return MissionStart(
                    v.name,
                    False,
                    attempts,
                    f"AUTO.MISSION accepted but the vehicle never left the ground (PX4 "
                    f"disarmed it in {mode}){texts()}",
                )
            if rejected:
                why = (
                    f"start ACCEPTED, then {MAV_RESULT_NAMES.get(rejected[-1], rejected[-1])} "
                    f"(mode {mode}, armed {st.armed})"
                )
            else:
                why = f"start ACCEPTED but the vehicle stayed in {mode} (armed {st.armed})"
        else:
            return MissionStart(
                v.name, False, attempts, f"not started after {attempts} attempt(s): {why}{texts()}"
            )
    finally:
        v.direct.unsubscribe_message(handle)
    if climb_m is None:
        return MissionStart(v.name, True, attempts, "AUTO.MISSION", t_ok)

    def climbing(s: VehicleStatus) -> bool:
        up = -s.pos_ned_m[2] - alt0 if s.pos_ned_m is not None else -math.inf
        return bool(s.in_air and up >= climb_m)

    def gave_up(s: VehicleStatus) -> bool:
        return not s.armed or s.mode is not Px4Mode.AUTO_MISSION

    t_climb = v.clock.monotonic() + climb_timeout_s
    while v.clock.monotonic() < t_climb:
        s = v.status()
        if climbing(s):
            up = -s.pos_ned_m[2] - alt0 if s.pos_ned_m is not None else math.nan
            return MissionStart(
                v.name, True, attempts, f"AUTO.MISSION, climbing ({up:.1f} m up)", t_ok
            )
        if gave_up(s):
            mode = s.mode.label if s.mode is not None else str(s.custom_mode)
            return MissionStart(
                v.name,
                False,
                attempts,
                f"AUTO.MISSION accepted but the vehicle never left the ground (now {mode}, "
                f"armed {s.armed}){texts()}",
            )
        await v.clock.sleep(0.05)
    return MissionStart(
        v.name,
        False,
        attempts,
        f"AUTO.MISSION accepted but the vehicle did not climb {climb_m:.1f} m in "
        f"{climb_timeout_s:.0f} s{texts()}",
    )


def _heard_since(v: Vehicle, st: VehicleStatus, t: float) -> bool:
    """The heartbeat behind ``st`` (of ``v``) arrived after time ``t`` on its clock."""
    age = st.heartbeat_age_s
    return age is not None and v.clock.monotonic() - age > t


@dataclass(frozen=True, slots=True)
class MissionRun:
    """What a vehicle reported while flying its mission (PX4's way: docs/px4-behaviour.md).

    PX4 reports in MISSION_ITEM_REACHED the last item *processed* (a DO item that follows a
    waypoint overwrites the waypoint's report) and re-sends it about once a second; progress
    is therefore read from MISSION_CURRENT, and each reached seq is kept once.

    Attributes:
        vehicle: name.
        current: ``(seq, t_s)`` each time MISSION_CURRENT's seq changed, s from ``t_start``.
        reached: ``(seq, t_s)`` the first MISSION_ITEM_REACHED of each seq (re-sends dropped).
        finished: the vehicle reported the mission finished in time.
        duration_s: time from ``t_start`` to the end (or the timeout).
        start: the confirmed start (:func:`start_mission_confirmed`), if this call started it.
    """

    vehicle: str
    current: tuple[tuple[int, float], ...]
    reached: tuple[tuple[int, float], ...]
    finished: bool
    duration_s: float
    start: MissionStart | None = None

    def left_s(self, seq: int) -> float | None:
        """When the vehicle moved on past item ``seq`` (MISSION_CURRENT above it, or a reached
        report of a later item), seconds from ``t_start``; ``None`` if it never did."""
        times = [t for s, t in self.current if s > seq] + [t for s, t in self.reached if s > seq]
        return min(times) if times else None

    def passed(self, seqs: Sequence[int]) -> list[int]:
        """The items of ``seqs`` the vehicle has left behind or reached, in mission order."""
        done = {s for s, _ in self.reached}
        return [s for s in seqs if s in done or self.left_s(s) is not None]


def _seq_of(msg: Any, sysid: int) -> int | None:
    """The ``seq`` of a mavlink_direct MISSION_CURRENT / MISSION_ITEM_REACHED from ``sysid``
    (``None``: another system's)."""
    if msg.system_id != sysid:
        return None
    return int(json.loads(msg.fields_json)["seq"])


#: How long (s) a follower keeps listening after a vehicle reports its mission finished,
#: for the last MISSION_CURRENT progress update.
_FINISH_GRACE_S = 1.0


class MissionFollower:
    """Records MISSION_CURRENT and MISSION_ITEM_REACHED of some vehicles (see MissionRun).

    Subscribe with :meth:`attach` before the start, read with :meth:`runs`, :meth:`detach`
    at the end. Times are seconds from :attr:`t_start` (on the vehicles' clock, settable).
    """

    def __init__(self, vehicles: Sequence[Vehicle]) -> None:
        self.vehicles = list(vehicles)
        self.clock: Clock = self.vehicles[0].clock if self.vehicles else WALL
        self.t_start = self.clock.monotonic()
        self._reached: dict[str, dict[int, float]] = {v.name: {} for v in vehicles}
        self._current: dict[str, list[tuple[int, float]]] = {v.name: [] for v in vehicles}
        self.totals: dict[str, int] = {}
        self._progress: dict[str, int] = {}
        self._handles: list[tuple[Any, Any]] = []

    def attach(self) -> None:
        for v in self.vehicles:

            def on_reached(
                msg: Any, _ud: Any, name: str = v.name, sysid: int = v.spec.sysid
            ) -> None:
                seq = _seq_of(msg, sysid)
                if seq is not None:
                    self._reached[name].setdefault(seq, self.clock.monotonic() - self.t_start)

            def on_current(
                msg: Any, _ud: Any, name: str = v.name, sysid: int = v.spec.sysid
            ) -> None:
                # MISSION_CURRENT itself: MAVSDK's mission progress mixes in reached items
                seq = _seq_of(msg, sysid)
                cur = self._current[name]
                if seq is not None and (not cur or cur[-1][0] != seq):
                    cur.append((seq, self.clock.monotonic() - self.t_start))

            def on_progress(progress: Any, _ud: Any, name: str = v.name) -> None:
                self.totals[name] = int(progress.total)
                self._progress[name] = int(progress.current)

            self._handles.append(
                (
                    v.direct.unsubscribe_message,
                    v.direct.subscribe_message("MISSION_ITEM_REACHED", on_reached),
                )
            )
            self._handles.append(
                (
                    v.direct.unsubscribe_message,
                    v.direct.subscribe_message("MISSION_CURRENT", on_current),
                )
            )
            self._handles.append(
                (
                    v.mission_raw.unsubscribe_mission_progress,
                    v.mission_raw.subscribe_mission_progress(on_progress),
                )
            )

    def detach(self) -> None:
        handles, self._handles = self._handles, []
        for unsub, handle in handles:
            unsub(handle)

    def current_seq(self, name: str) -> int | None:
        cur = self._current[name]
        return cur[-1][0] if cur else None

    def run(self, name: str, *, finished: bool, duration_s: float) -> MissionRun:
        return MissionRun(
            vehicle=name,
            current=tuple(self._current[name]),
            reached=tuple(sorted(self._reached[name].items(), key=lambda kv: kv[1])),
            finished=finished,
            duration_s=duration_s,
        )

    def finished(self, name: str) -> bool:
        """Whether ``name``'s mission is over: PX4 reported its last item reached, or MAVSDK
        says so.  The report comes the moment PX4 completes the item (and PX4, a mission
        without a landing ended, switches to AUTO.LOITER in the same cycle); MAVSDK's verdict
        waits for the next MISSION_CURRENT, up to 1 s later (:meth:`_finish_s`).  Safe from any
        thread."""
        total = self.totals.get(name, 0)
        if total > 0 and self._reached[name].get(total - 1) is not None:
            return True
        v = next((v for v in self.vehicles if v.name == name), None)
        return v is not None and bool(v.mission_raw.is_mission_finished())

    def at_end(self, name: str) -> bool:
        """Whether ``name`` is on its mission's last item (MISSION_CURRENT), or done with it
        (:meth:`finished`): where PX4 itself leaves AUTO.MISSION, for AUTO.RTL on a return
        item and AUTO.LOITER once the last waypoint is done.  Safe from any thread."""
        total = self.totals.get(name, 0)
        cur = self._current[name]
        if total > 0 and cur and cur[-1][0] >= total - 1:
            return True
        return self.finished(name)

    def _finish_s(self, name: str, seen_s: float) -> float:
        """When ``name``'s mission finished, MAVSDK having seen it finished at ``seen_s``.

        PX4 reports the last item reached the moment it completes it (after its hold), and
        the mission is over in the same cycle; MAVSDK's verdict waits for MISSION_CURRENT,
        which on the API link mostly comes with PX4's once-a-second report (up to 1 s late).
        """
        total = self.totals.get(name, 0)
        t_last = self._reached[name].get(total - 1) if total > 0 else None
        return seen_s if t_last is None else min(seen_s, t_last)

    async def until_finished(
        self, *, timeout_s: float, poll_s: float = 0.1, stop: asyncio.Event | None = None
    ) -> dict[str, float]:
        """Wait until every vehicle reports its mission finished (MAVSDK), ``timeout_s`` from
        now or ``stop``; the finish time of each that did (s from :attr:`t_start`)."""
        done: dict[str, float] = {}
        t_end = self.clock.monotonic() + timeout_s
        while len(done) < len(self.vehicles) and self.clock.monotonic() < t_end:
            if stop is not None and stop.is_set():
                break
            await self.clock.sleep(poll_s)
            for v in self.vehicles:
                if v.name not in done and v.mission_raw.is_mission_finished():
                    done[v.name] = self._finish_s(v.name, self.clock.monotonic() - self.t_start)
        # MAVSDK can report the mission finished before its progress callback has delivered
        # the final current == total (seen under load): keep listening a moment for it.
        t_grace = self.clock.monotonic()
        while self.clock.monotonic() - t_grace < _FINISH_GRACE_S and any(
            self._progress.get(n, 0) < self.totals.get(n, 0) for n in done
        ):
            await self.clock.sleep(poll_s)
        return done
