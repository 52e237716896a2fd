"""Who answers on the ground station's UDP ports: system ids, the addresses they send from, and
whose clock they carry.

MAVSDK hides the sender's address. Two vehicles configured with the same MAV_SYS_ID that send
to the ground station merge into one system in MAVSDK: telemetry from both, and every command
goes to whichever spoke last. :func:`scan_udpin` listens on the ``udpin`` URLs for a moment
*before* MAVSDK opens them and records, per system id, every address its autopilot
(component 1) sends from, with the boot instant its ``time_boot_ms`` implies.
:func:`duplicates` then tells two vehicles (two addresses, two clocks more than
``clock_tolerance_s`` apart, or no clock to tell them by) from one vehicle heard over two of its
MAVLink instances (two addresses, one clock).
"""

from __future__ import annotations

import asyncio
import functools
import socket
import struct
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from mavlink.link.urls import ConnectionUrl, Scheme

#: Messages whose payload starts with ``time_boot_ms`` (uint32): ATTITUDE, LOCAL_POSITION_NED,
#: GLOBAL_POSITION_INT; SYSTEM_TIME has it after its uint64 ``time_unix_usec``.
_BOOT_MS_AT = {30: 0, 32: 0, 33: 0, 2: 8}
#: Boot instants of one autopilot agree to this (s): arrival jitter, not two clocks.
CLOCK_TOLERANCE_S = 0.5


@dataclass(slots=True)
class Sender:
    """One address a system id was heard from.

    Attributes:
        address: ``(host, port)``.
        url: the udpin URL it was heard on.
        boot_s: ``time.monotonic()`` at which its autopilot booted, as its latest
            ``time_boot_ms`` implies (``None``: no message with a clock heard).
        autopilot: the MAV_AUTOPILOT of its HEARTBEAT (``None``: no heartbeat heard).
    """

    address: tuple[str, int]
    url: str
    boot_s: float | None = None
    autopilot: int | None = None


@dataclass(slots=True)
class Heard:
    """Every autopilot heard during a scan: system id -> its senders by address; and the
    URLs whose port could not be bound (URL -> the reason)."""

    senders: dict[int, dict[tuple[str, int], Sender]] = field(default_factory=dict)
    busy: dict[str, str] = field(default_factory=dict)

    def sysids_on(self, url: str) -> set[int]:
        """The system ids heard on ``url``."""
        return {i for i, by in self.senders.items() if any(s.url == url for s in by.values())}


def parse_frame(data: bytes) -> tuple[int, int, int, bytes] | None:
    """``(sysid, compid, msgid, payload)`` of the first MAVLink 1 or 2 frame in ``data``."""
    if len(data) >= 10 and data[0] == 0xFD:
        n = data[1]
        return data[5], data[6], int.from_bytes(data[7:10], "little"), data[10 : 10 + n]
    if len(data) >= 6 and data[0] == 0xFE:
        n = data[1]
        return data[3], data[4], data[5], data[6 : 6 + n]
    return None


class _Listener(asyncio.DatagramProtocol):
    def __init__(self, url: str, heard: Heard) -> None:
        self.url = url
        self.heard = heard

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        frame = parse_frame(data)
        if frame is None:
            return
        sysid, compid, msgid, payload = frame
        if compid != 1:  # autopilots only
            return
        address = (str(addr[0]), int(addr[1]))
        sender = self.heard.senders.setdefault(sysid, {}).setdefault(
            address, Sender(address, self.url)
        )
        if msgid == 0:  # HEARTBEAT: custom_mode (uint32), type, autopilot, ...
            sender.autopilot = payload.ljust(6, b"\0")[5]
        at = _BOOT_MS_AT.get(msgid)
        if at is not None:
            raw = payload.ljust(at + 4, b"\0")
            boot_ms = struct.unpack_from("<I", raw, at)[0]
            if boot_ms:
                sender.boot_s = time.monotonic() - boot_ms / 1e3


async def scan_udpin(
    urls: Sequence[ConnectionUrl],
    window_s: float,
    *,
    expect: Iterable[int] = (),
    min_s: float = 0.4,
) -> Heard:
    """Listen on every ``udpin`` URL of ``urls`` for up to ``window_s`` seconds (others are
    skipped: nothing arrives on them unasked); after ``min_s`` stop as soon as every system
    id of ``expect`` has been heard with its clock (PX4 streams attitude and position many
    times a second, so a second autopilot on the same id has been heard by then too). A port
    that cannot be bound is skipped and recorded in :attr:`Heard.busy`."""
    wanted = set(expect)
    heard = Heard()
    loop = asyncio.get_running_loop()
    transports = []
    for url in dict.fromkeys(u for u in urls if u.scheme is Scheme.UDPIN):
        family = socket.AF_INET6 if ":" in url.host else socket.AF_INET
        try:
            transport, _ = await loop.create_datagram_endpoint(
                functools.partial(_Listener, str(url), heard),
                local_addr=(url.host, url.port),
                family=family,
            )
        except OSError as exc:
            heard.busy[str(url)] = exc.strerror or str(exc)
            continue
        transports.append(transport)
    try:
        t0 = time.monotonic()
        while transports and time.monotonic() - t0 < window_s:
            await asyncio.sleep(0.05)
            if (
                time.monotonic() - t0 >= min_s
                and wanted
                and all(
                    any(snd.boot_s is not None for snd in heard.senders.get(i, {}).values())
                    for i in wanted
                )
            ):
                break
    finally:
        for t in transports:
            t.close()
        # asyncio closes the sockets on its next iteration: let it, so MAVSDK can bind the
        # ports right after
        while any(t.get_extra_info("socket") is not None and not _released(t) for t in transports):
            await asyncio.sleep(0)
    return heard


def _released(transport: asyncio.BaseTransport) -> bool:
    sock = transport.get_extra_info("socket")
    try:
        return sock.fileno() == -1
    except (AttributeError, OSError):
        return True


@dataclass(frozen=True, slots=True)
class Duplicate:
    """A system id that more than one autopilot answers as.

    Attributes:
        sysid: the system id.
        senders: the addresses (and URLs) it was heard from.
        why: how they were told apart.
    """

    sysid: int
    senders: tuple[Sender, ...]
    why: str

    def describe(self) -> str:
        where = " and ".join(f"{h}:{p} (on {s.url})" for s in self.senders for h, p in [s.address])
        return (
            f"two vehicles answer as system id {self.sysid}: from {where}; {self.why}; "
            "give each vehicle its own MAV_SYS_ID"
        )


def duplicates(
    heard: Heard, sysids: Iterable[int], *, clock_tolerance_s: float = CLOCK_TOLERANCE_S
) -> list[Duplicate]:
    """The system ids of ``sysids`` heard from more than one autopilot (module docstring)."""
    out = []
    for sysid in sorted(set(sysids)):
        senders = list(heard.senders.get(sysid, {}).values())
        if len(senders) < 2:
            continue
        boots = [s.boot_s for s in senders]
        if any(b is None for b in boots):
            why = "no clock (time_boot_ms) heard from every address to tell one vehicle from two"
        else:
            spread = max(boots) - min(boots)  # type: ignore[type-var, operator]
            if spread <= clock_tolerance_s:
                continue  # one autopilot heard over two of its MAVLink instances
            why = f"their clocks say they booted {spread:.1f} s apart"
        out.append(Duplicate(sysid, tuple(senders), why))
    return out
