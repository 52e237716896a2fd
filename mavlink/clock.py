"""The clock a flight runs on: the wall clock against real vehicles, the simulation's against
the mock.

The ground station measures what the vehicles do on one :class:`Clock`: the age of their
heartbeats and positions, the instants of its telemetry track, its setpoint deadlines, its
waits for a mode or a position, the flight's start and the camera's spans. Against PX4 that is
the wall clock (:data:`WALL`). Against the mock it is the simulation's own
(:meth:`mavlink.mock.MockFleet.clock`), which may run faster than real time (``speed``, as PX4
SITL's ``PX4_SIM_SPEED_FACTOR``) and slows down with the simulation when the machine is busy,
so a flight in a dry run keeps its timing whatever the load: a setpoint due at plan time
``t`` is sent when the simulated vehicles are at ``t``, not when a wall clock says so.

What concerns the transport rather than the vehicle stays on the wall clock: MAVSDK's own
timeouts and retries (it runs in its own process), the time allowed to connect, and the
budgets of mission transfers and parameter reads.
"""

from __future__ import annotations

import asyncio
import time
from typing import Protocol, runtime_checkable

__all__ = ["WALL", "Clock", "WallClock"]


@runtime_checkable
class Clock(Protocol):
    """A monotonic time in seconds, the UTC that goes with it, and a way to wait on it."""

    def monotonic(self) -> float:
        """Seconds on this clock (any origin; only differences mean something)."""
        ...

    def unix_offset(self) -> float:
        """Seconds to add to :meth:`monotonic` for UTC (seconds since the Unix epoch)."""
        ...

    async def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` on this clock (at least one pass of the event loop)."""
        ...


class WallClock:
    """The machine's clock: :func:`time.monotonic` and :func:`asyncio.sleep`."""

    def monotonic(self) -> float:
        return time.monotonic()

    def unix_offset(self) -> float:
        return time.time() - time.monotonic()

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(max(0.0, seconds))

    def __repr__(self) -> str:
        return "WallClock()"


#: The wall clock, the default of every flight.
WALL: Clock = WallClock()
