"""The mock fleet's simulated time as a :class:`mavlink.clock.Clock` for the ground station.

A dry run's ground station waits on the simulation, not on the wall: :meth:`SimClock.sleep`
sets an alarm at a simulated instant, and the fleet's physics task (in its own thread and
event loop, or the caller's) wakes the sleeper's event loop after the tick that reaches it.
So the flight keeps its timing at any :attr:`MockFleet.speed <mavlink.mock.MockFleet.speed>`
and on a busy machine, where the simulation falls behind its pace and the ground station's
clock with it. Before the fleet starts and after it stops, sleeps are on the wall clock,
scaled by the speed.
"""

from __future__ import annotations

import asyncio
import contextlib
import heapq
import itertools
import threading
from typing import Protocol

__all__ = ["TICK_SLACK_S", "SimClock", "SimulatedFleet"]


class SimulatedFleet(Protocol):
    """What the clock reads of the fleet whose time it keeps (:class:`mavlink.mock.MockFleet`)."""

    @property
    def time_s(self) -> float: ...

    @property
    def utc_start_s(self) -> float: ...

    @property
    def speed(self) -> float: ...


#: Rounding allowed when an instant is compared with a tick's (s): an instant that is a tick's,
#: summed another way, is due on that tick (the fleet's timers and the clock's alarms alike).
TICK_SLACK_S = 1e-9


_Alarm = tuple[float, int, asyncio.AbstractEventLoop, asyncio.Future[None]]


def _wake(fut: asyncio.Future[None]) -> None:
    if not fut.done():  # a cancelled sleep's alarm stays until due, and wakes nobody
        fut.set_result(None)


def _wake_all(alarms: list[_Alarm]) -> None:
    """Wake the sleepers of ``alarms``, each in its own event loop (from any thread)."""
    for _, _, loop, fut in alarms:
        with contextlib.suppress(RuntimeError):  # the sleeper's loop has closed
            loop.call_soon_threadsafe(_wake, fut)


class SimClock:
    """``fleet``'s simulated seconds (:attr:`MockFleet.time_s`) and UTC; sleeps wake on ticks.

    Safe to use from any thread's event loop while the fleet runs in another.
    """

    def __init__(self, fleet: SimulatedFleet) -> None:
        self._fleet = fleet
        self._lock = threading.Lock()
        self._alarms: list[_Alarm] = []
        self._seq = itertools.count()
        self._ticking = False

    def monotonic(self) -> float:
        return self._fleet.time_s

    def unix_offset(self) -> float:
        return self._fleet.utc_start_s

    async def sleep(self, seconds: float) -> None:
        if seconds <= 0.0:
            await asyncio.sleep(0)
            return
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[None] = loop.create_future()
        with self._lock:
            ticking = self._ticking
            if ticking:
                due = self._fleet.time_s + seconds
                heapq.heappush(self._alarms, (due, next(self._seq), loop, fut))
        if not ticking:
            await asyncio.sleep(seconds / self._fleet.speed)
            return
        await fut

    # -- the fleet's side -------------------------------------------------------------------

    def started(self) -> None:
        """The fleet's physics runs: sleeps wait for its ticks from now on."""
        with self._lock:
            self._ticking = True

    def wake_due(self, now_s: float) -> None:
        """Wake every sleeper whose instant ``now_s`` has reached (the fleet, after a tick)."""
        alarms = self._alarms
        now_s += TICK_SLACK_S
        if not alarms or alarms[0][0] > now_s:
            return
        with self._lock:
            due = []
            while alarms and alarms[0][0] <= now_s:
                due.append(heapq.heappop(alarms))
        _wake_all(due)

    def stopped(self) -> None:
        """The fleet has stopped: wake every sleeper; later sleeps are on the wall clock."""
        with self._lock:
            self._ticking = False
            due, self._alarms[:] = list(self._alarms), []
        _wake_all(due)

    def __repr__(self) -> str:
        return f"SimClock(t={self._fleet.time_s:.3f} s, speed={self._fleet.speed:g})"
