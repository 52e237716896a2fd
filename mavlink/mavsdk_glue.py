"""The bridge between MAVSDK's callback API and asyncio, shared by every MAVSDK user here.

MAVSDK 4 is the native (ctypes) binding: every plugin call exists in a
blocking form and an ``*_async(callback)`` form. This module bridges the
callback forms to asyncio futures (:func:`mavsdk_call`), so N vehicles can
wait on N commands without N threads, and telemetry callbacks update each
vehicle's state directly on MAVSDK's callback thread under a lock. (The
``mavsdk.asyncio`` wrappers instead run every call, setpoints included, in
the default thread pool; ``benchmarks/bench_stream.py`` measures both.)

A room of its own because the vehicle (:mod:`mavlink.vehicle`), the fleet, the
offboard flight, the monitor and the missions all await MAVSDK calls the same way;
it also routes MAVSDK's own log lines (:func:`route_mavsdk_logs`) and names
COMMAND_ACK results (:data:`MAV_RESULT_NAMES`).
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Callable
from typing import Any

from mavsdk import LogLevel, log_subscribe

#: MAV_RESULT names, for COMMAND_ACK results reported through mavlink_direct.
MAV_RESULT_NAMES = {
    0: "ACCEPTED",
    1: "TEMPORARILY_REJECTED",
    2: "DENIED",
    3: "UNSUPPORTED",
    4: "FAILED",
    5: "IN_PROGRESS",
    6: "CANCELLED",
}


_logs_routed = threading.Lock()
_routed = False


def route_mavsdk_logs() -> None:
    """Send MAVSDK's own log lines to the ``mavlink.mavsdk`` logger (not stderr)."""
    global _routed
    with _logs_routed:
        if _routed:
            return
        mlog = logging.getLogger("mavlink.mavsdk")
        levels = {
            LogLevel.DEBUG: logging.DEBUG,
            LogLevel.INFO: logging.INFO,
            LogLevel.WARN: logging.WARNING,
            LogLevel.ERROR: logging.ERROR,
        }

        def forward(level: LogLevel, message: str, file: str | None, line: int) -> bool:
            mlog.log(levels.get(level, logging.INFO), "%s (%s:%d)", message, file, line)
            return True

        log_subscribe(forward)
        _routed = True


def resolve_future(fut: asyncio.Future[Any], value: Any) -> None:
    if not fut.done():
        fut.set_result(value)


async def mavsdk_call(start: Callable[..., None], *args: Any, timeout_s: float = 10.0) -> Any:
    """Await one MAVSDK ``*_async`` call.

    Args:
        start: a bound MAVSDK method taking ``(*args, callback)``; the
            callback gets ``(result, [data,] user_data)``.
        args: its arguments before the callback.
        timeout_s: give up after this long (MAVSDK's own timeouts normally
            answer first).

    Returns:
        The callback's arguments without ``user_data``: the result alone, or
        ``(result, data)``.

    Raises:
        TimeoutError: no callback within ``timeout_s``.
    """
    loop = asyncio.get_running_loop()
    fut: asyncio.Future[Any] = loop.create_future()

    def callback(*values: Any) -> None:
        out = values[:-1]
        loop.call_soon_threadsafe(resolve_future, fut, out[0] if len(out) == 1 else out)

    start(*args, callback)
    return await asyncio.wait_for(fut, timeout_s)
