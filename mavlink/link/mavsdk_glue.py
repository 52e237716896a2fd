"""The bridge between MAVSDK's callback API and asyncio, shared by every MAVSDK user here.

MAVSDK 4 is the native (ctypes) binding: every plugin call exists in a
blocking form and an ``*_async(callback)`` form. This module bridges the
callback forms to asyncio futures (:func:`mavsdk_call`), so N vehicles can
wait on N commands without N threads, and telemetry callbacks update each
vehicle's state directly on MAVSDK's callback thread under a lock. (The
``mavsdk.asyncio`` wrappers instead run every call, setpoints included, in
the default thread pool; ``benchmarks/bench_stream.py`` measures both.)

A room of its own because the vehicle (:mod:`mavlink.link.vehicle`), the fleet, the
offboard flight, the monitor and the missions all await MAVSDK calls the same way;
it also routes MAVSDK's own log lines (:func:`route_mavsdk_logs`, :func:`mavsdk_log_file`)
and names COMMAND_ACK results (:data:`MAV_RESULT_NAMES`).

MAVSDK's log lines (MAVSDK 4 is a library in this process: it has no server process of its
own, and it prints nothing itself once its log is routed) go to the ``mavlink.mavsdk``
logger. Whoever flies sees only MAVSDK's errors they can act on (a connection that cannot be
opened, a message that cannot be sent), on stderr, prefixed ``MAVSDK:``; its warnings and
information, and its complaints about its own callback machinery (MAVSDK 4.1 logs a full
callback queue - "Dropping subscription callbacks ... a subscriber is not keeping up" - as an
error), go to the flight's log file (:func:`mavsdk_log_file`: ``mavsdk.log`` in the flight
directory of ``gcs fly --log``), and to any handler the application gives the logger.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TextIO

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


#: The logger MAVSDK's own log lines go to (:func:`route_mavsdk_logs`).
MAVSDK_LOG = logging.getLogger("mavlink.mavsdk")

#: MAVSDK's log levels as logging's.
_LEVELS = {
    LogLevel.DEBUG: logging.DEBUG,
    LogLevel.INFO: logging.INFO,
    LogLevel.WARN: logging.WARNING,
    LogLevel.ERROR: logging.ERROR,
}

#: How MAVSDK's lines about its own callback thread begin (queue full, callbacks dropped, a
#: slow callback), and its failed sends, whatever their level: nothing the user of a flight
#: can do about them (a lost link is reported by the flight), so they go to the flight's log,
#: not the terminal.
_LIBRARY_INTERNAL = (
    "Dropping subscription callbacks",
    "User callback queue",
    "Callback took more than",
    "Callback called from",
    # a datagram to a vehicle that does not answer (its link lost: the flight reports that
    # itself, once; MAVSDK says this on every heartbeat it sends there)
    "Sending message failed",
)

_logs_routed = threading.Lock()
_routed = False


#: MAVSDK instances open in this process (:func:`mavsdk_instance_opened`).
_open_instances = 0
_open_lock = threading.Lock()


def mavsdk_instance_opened(opened: bool) -> None:
    """Count a MAVSDK instance opened (``True``) or destroyed (``False``): MAVSDK's errors
    reach stderr only while one is open. Its log callback names no instance, and an instance
    being torn down (or one a finished command left to the garbage collector) may still
    report, seconds later, a heartbeat it could not send: nothing the user can act on, and
    on another command's stderr."""
    global _open_instances
    with _open_lock:
        _open_instances = max(0, _open_instances + (1 if opened else -1))


class _ActionableErrors(logging.StreamHandler):
    """MAVSDK's errors the user can act on, on the stderr of the moment (``sys.stderr`` when
    the line is written, as :data:`logging.lastResort` does), while a MAVSDK instance is open."""

    def __init__(self) -> None:
        logging.Handler.__init__(self, logging.ERROR)
        self.setFormatter(logging.Formatter("MAVSDK: %(message)s"))
        self.addFilter(
            lambda record: _open_instances > 0 and not getattr(record, "mavsdk_internal", False)
        )

    @property
    def stream(self) -> TextIO:
        return sys.stderr


def forward_mavsdk_line(level: LogLevel, message: str, file: str | None, line: int) -> bool:
    """MAVSDK's log callback: one line to :data:`MAVSDK_LOG` (the record's ``mavsdk_internal``
    says whether it is about MAVSDK's own callback machinery); ``True`` keeps MAVSDK from
    printing it itself."""
    MAVSDK_LOG.log(
        _LEVELS.get(level, logging.INFO),
        "%s (%s:%d)",
        message,
        file,
        line,
        extra={"mavsdk_internal": message.startswith(_LIBRARY_INTERNAL)},
    )
    return True


def route_mavsdk_logs() -> None:
    """Send MAVSDK's own log lines to :data:`MAVSDK_LOG` instead of MAVSDK's stdout print,
    showing on stderr only the errors the user can act on (module docstring). Idempotent."""
    global _routed
    with _logs_routed:
        if _routed:
            return
        # A handler of its own also keeps logging's last resort (which prints every warning
        # of a logger without handlers to stderr) away from MAVSDK's lines.
        MAVSDK_LOG.addHandler(_ActionableErrors())
        log_subscribe(forward_mavsdk_line)
        _routed = True


@contextlib.contextmanager
def mavsdk_log_file(path: Path) -> Iterator[Path]:
    """Write every MAVSDK log line, debug up, time-stamped, to ``path`` (created, or
    truncated) while inside; the actionable errors still show on stderr.

    MAVSDK's log is process-wide: two flights at once in one process share their lines.
    Inside, the lines do not propagate to the root logger (the file is their place).

    Raises:
        OSError: ``path`` cannot be written.
    """
    route_mavsdk_logs()
    handler = logging.FileHandler(path, mode="w", encoding="utf-8")
    handler.setFormatter(
        logging.Formatter("%(asctime)s.%(msecs)03d %(levelname)s %(message)s", "%Y-%m-%d %H:%M:%S")
    )
    level, propagate = MAVSDK_LOG.level, MAVSDK_LOG.propagate
    MAVSDK_LOG.addHandler(handler)
    MAVSDK_LOG.setLevel(logging.DEBUG)
    MAVSDK_LOG.propagate = False
    try:
        yield path
    finally:
        MAVSDK_LOG.removeHandler(handler)
        MAVSDK_LOG.setLevel(level)
        MAVSDK_LOG.propagate = propagate
        handler.close()


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
    answered = threading.Event()

    def callback(*values: Any) -> None:
        if answered.is_set():
            return
        answered.set()
        _call_answered()
        out = values[:-1]
        with contextlib.suppress(RuntimeError):  # the loop closed since: nobody waits
            loop.call_soon_threadsafe(resolve_future, fut, out[0] if len(out) == 1 else out)

    _call_started()
    try:
        start(*args, callback)
    except BaseException:
        if not answered.is_set():
            answered.set()
            _call_answered()
        raise
    return await asyncio.wait_for(fut, timeout_s)


# MAVSDK 4.1 keeps each ``*_async`` call's ctypes trampoline in its plugin only until the
# plugin is destroyed, but answers a call still under way (an upload cancelled because its
# budget ran out, a command to a silent vehicle) from its callback thread later, also after
# that: the answer then jumps into freed memory and the process dies (a segmentation fault
# seen in the suite, in ``mission_raw``'s callback while a fleet closed). So the calls under
# way are counted here, and a fleet waits for their answers before it destroys MAVSDK
# (:func:`calls_settled`).
_calls = 0
_calls_done = threading.Condition()


def _call_started() -> None:
    global _calls
    with _calls_done:
        _calls += 1


def _call_answered() -> None:
    global _calls
    with _calls_done:
        _calls = max(0, _calls - 1)
        if _calls == 0:
            _calls_done.notify_all()


def calls_under_way() -> int:
    """MAVSDK ``*_async`` calls of :func:`mavsdk_call` not yet answered, in this process."""
    with _calls_done:
        return _calls


def calls_settled(timeout_s: float) -> bool:
    """Block until every MAVSDK call of :func:`mavsdk_call` in this process has had its
    answer (MAVSDK answers a cancelled or timed-out call itself, on its callback thread), at
    most ``timeout_s``; whether they all have."""
    with _calls_done:
        return _calls_done.wait_for(lambda: _calls == 0, timeout_s)
