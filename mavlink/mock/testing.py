"""A minimal synchronous pymavlink GCS endpoint for protocol tests and benchmarks of the mock.

It speaks to one vehicle the way a ground station does over UDP: it binds its
own port (the vehicle's ``gcs_port``), sends to the vehicle's port, and waits
for messages with a deadline.  It is deliberately small: MAVSDK is the real
client; this exists to send what MAVSDK never sends (out-of-order items,
legacy messages, setpoint gaps).
"""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Callable, Iterator
from typing import Any, TypeAlias

from pymavlink.dialects.v20 import common as mavlink2

#: A pymavlink message (its fields are per message type: untyped to mypy).
Msg: TypeAlias = Any


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port that was free a moment ago (bind port 0 and release it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def free_udp_ports(n: int, host: str = "127.0.0.1") -> list[int]:
    """``n`` distinct UDP ports that were free a moment ago (all bound at once, then released)."""
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
    try:
        for s in socks:
            s.bind((host, 0))
        return [int(s.getsockname()[1]) for s in socks]
    finally:
        for s in socks:
            s.close()


class GcsEndpoint:
    """A GCS socket bound on ``127.0.0.1:<free port>`` talking to ``vehicle_port``.

    Use :attr:`port` as the fleet's ``gcs_ports`` entry for that vehicle.
    """

    def __init__(
        self,
        vehicle_port: int | None = None,
        sysid: int = 255,
        compid: int = 190,
        target_system: int = 1,
    ) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", 0))
        self.port = int(self.sock.getsockname()[1])
        self.vehicle_port = vehicle_port
        self.mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.mav.robust_parsing = True
        self.target_system = target_system
        self.received: list[Msg] = []

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()

    def __enter__(self) -> GcsEndpoint:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def send(self, msg: Msg) -> None:
        """Encode and send one message to the vehicle."""
        if self.vehicle_port is None:
            raise RuntimeError("vehicle_port is not set")
        buf = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) & 0xFF
        self.sock.sendto(buf, ("127.0.0.1", self.vehicle_port))

    def messages(self, timeout_s: float) -> Iterator[Msg]:
        """Yield received messages until ``timeout_s`` has passed."""
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return
            self.sock.settimeout(left)
            try:
                data, _ = self.sock.recvfrom(65535)
            except TimeoutError:
                return
            for msg in self.mav.parse_buffer(data) or []:
                if msg.get_type() == "BAD_DATA":
                    continue
                self.received.append(msg)
                yield msg

    def recv(
        self,
        kind: str | tuple[str, ...],
        timeout_s: float = 3.0,
        where: Callable[[Msg], bool] | None = None,
    ) -> Msg | None:
        """The first message of type ``kind`` (satisfying ``where``) within ``timeout_s``."""
        kinds = (kind,) if isinstance(kind, str) else kind
        for msg in self.messages(timeout_s):
            if msg.get_type() in kinds and (where is None or where(msg)):
                return msg
        return None

    def drain(self) -> None:
        """Discard everything already queued on the socket."""
        self.sock.setblocking(False)
        with contextlib.suppress(BlockingIOError):
            while True:
                self.sock.recvfrom(65535)
        self.sock.setblocking(True)

    def command(self, command: int, *params: float, timeout_s: float = 3.0) -> Msg | None:
        """Send COMMAND_LONG (params padded with 0) and wait for its COMMAND_ACK."""
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        # telemetry queued while the caller was busy could hide the ACK behind a full buffer
        self.drain()
        self.send(mavlink2.MAVLink_command_long_message(self.target_system, 1, command, 0, *p))
        return self.recv("COMMAND_ACK", timeout_s, lambda m: m.command == command)

    def set_mode(self, main: int, sub: int = 0, timeout_s: float = 3.0) -> Msg | None:
        """MAV_CMD_DO_SET_MODE with PX4 main/sub mode; returns the COMMAND_ACK."""
        return self.command(
            mavlink2.MAV_CMD_DO_SET_MODE,
            mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
            main,
            sub,
            timeout_s=timeout_s,
        )

    def position_setpoint(self, north_m: float, east_m: float, down_m: float) -> None:
        """One SET_POSITION_TARGET_LOCAL_NED with a position only (type_mask 0xDF8)."""
        self.send(
            mavlink2.MAVLink_set_position_target_local_ned_message(
                0,
                self.target_system,
                1,
                mavlink2.MAV_FRAME_LOCAL_NED,
                0x0DF8,
                north_m,
                east_m,
                down_m,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
            )
        )
