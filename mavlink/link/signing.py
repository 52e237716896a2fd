"""MAVLink 2 message signing for the GCS link: keys, raw-frame signing and a signing UDP proxy.

MAVSDK 4.1 (the ``mavsdk`` package's C library) has no message-signing API, so
the GCS signs through a local proxy between MAVSDK and the vehicle::

    vehicle  <--- signed --->  SigningProxy  <--- unsigned --->  MAVSDK (Fleet)
    (14580+i)               listens 14540+i               udpin://127.0.0.1:<inner>

* Uplink (MAVSDK -> vehicle): every MAVLink 2 frame MAVSDK sends is signed with
  the shared key (SHA-256 signature of key + frame + link id + timestamp,
  truncated to 6 bytes, as the MAVLink 2 signing spec and pymavlink's
  ``MAVLink_message.sign_packet``), the ``incompat_flags`` signed bit set and
  the CRC recomputed; MAVLink 1 frames cannot be signed and are dropped
  (counted).
* Downlink (vehicle -> MAVSDK): frames are checked with pymavlink's signing
  (``MAVLink.signing.secret_key``): unsigned frames, wrong signatures and
  replays (a timestamp not newer than the last on the same link id / system /
  component, or older than a minute before the newest seen) are dropped and
  counted; valid frames pass unchanged (MAVSDK ignores the signature).

From a shell (one proxy per vehicle, PX4 SITL ports; Ctrl-C stops)::

    python -m mavlink.link.signing --key fleet.key -n 2      # vehicle i: 14540+i <-> 14640+i
    gcs fly plan.json --connection udpin://127.0.0.1:14640 --connection udpin://127.0.0.1:14641

Use :func:`load_key` for a key file: 64 hexadecimal characters (32 bytes; the
MAVLink key length) or exactly 32 raw bytes.  Point the vehicle's GCS port at
the proxy's ``listen_port`` and the :class:`~mavlink.link.fleet.Fleet` at
``udpin://127.0.0.1:{proxy.inner_port}``.

Errors (under :class:`mavlink.errors.LinkError`, so the CLI prints one line)::

    SigningError(LinkError)    a bad key file or key
"""

from __future__ import annotations

import asyncio
import hashlib
import struct
import time
from dataclasses import dataclass
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink2
from pymavlink.generator.mavcrc import x25crc

from mavlink.errors import LinkError

KEY_LEN = 32
#: MAVLink signing epoch: 2015-01-01 00:00:00 UTC (Unix seconds).
SIGNING_EPOCH_UNIX_S = 1_420_070_400
_SIGNED = 0x01


class SigningError(LinkError):
    """A bad signing key or key file."""


def load_key(path: str | Path) -> bytes:
    """Read a 32-byte signing key from ``path`` (64 hex characters, or 32 raw bytes).

    Raises:
        SigningError: unreadable file or wrong format (naming the file).
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise SigningError(f"{p}: cannot read signing key: {exc.strerror or exc}") from None
    text = raw.strip()
    if len(text) == 2 * KEY_LEN:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    if len(raw) == KEY_LEN:
        return raw
    raise SigningError(
        f"{p}: signing key must be {2 * KEY_LEN} hexadecimal characters or {KEY_LEN} raw "
        f"bytes, got {len(raw)} bytes"
    )


def check_key(key: bytes) -> bytes:
    """``key`` if it is a 32-byte string (raises :class:`SigningError` otherwise)."""
    if not isinstance(key, bytes | bytearray) or len(key) != KEY_LEN:
        raise SigningError(f"signing key must be {KEY_LEN} bytes")
    return bytes(key)


def signing_timestamp(unix_s: float | None = None) -> int:
    """MAVLink signing timestamp (10 microsecond units since 2015-01-01 UTC)."""
    t = time.time() if unix_s is None else unix_s
    return int((t - SIGNING_EPOCH_UNIX_S) * 100_000)


def _crc(header_tail: bytes, payload: bytes, crc_extra: int) -> int:
    crc = x25crc(header_tail + payload)
    crc.accumulate(bytes([crc_extra]))
    return int(crc.crc)


def _crc_extra(msgid: int, header_tail: bytes, payload: bytes, crc: int) -> int | None:
    cls = mavlink2.mavlink_map.get(msgid)
    if cls is not None:
        return int(cls.crc_extra)
    # A message the common dialect does not know: find the CRC_EXTRA its checksum implies.
    for extra in range(256):
        if _crc(header_tail, payload, extra) == crc:
            return extra
    return None


def sign_frame(frame: bytes, key: bytes, link_id: int, timestamp: int) -> bytes | None:
    """Sign one unsigned MAVLink 2 frame (header, payload, CRC); ``None`` if it cannot be.

    ``timestamp`` is in :func:`signing_timestamp` units; the caller keeps it
    increasing.  A frame that is not MAVLink 2, is already signed or has a bad
    checksum is not signed.
    """
    if len(frame) < 12 or frame[0] != 0xFD or frame[2] & _SIGNED:
        return None
    n = frame[1]
    if len(frame) != 12 + n:
        return None
    header, payload = frame[:10], frame[10 : 10 + n]
    (crc,) = struct.unpack_from("<H", frame, 10 + n)
    msgid = header[7] | header[8] << 8 | header[9] << 16
    extra = _crc_extra(msgid, header[1:], payload, crc)
    if extra is None or _crc(header[1:], payload, extra) != crc:
        return None
    new_header = bytes([0xFD, n, header[2] | _SIGNED]) + header[3:]
    body = new_header + payload + struct.pack("<H", _crc(new_header[1:], payload, extra))
    tail = struct.pack("<BQ", link_id, timestamp)[:7]
    sig = hashlib.sha256(key + body + tail).digest()[:6]
    return body + tail + sig


def verifier(key: bytes, now_ts: int | None = None) -> mavlink2.MAVLink:
    """A pymavlink parser that accepts only frames signed with ``key`` (no unsigned, no replays).

    Its signing clock starts at ``now_ts`` (default: now), so a frame signed
    more than a minute before that is refused even on a new stream.
    """
    mav = mavlink2.MAVLink(None)
    mav.robust_parsing = True
    mav.signing.secret_key = check_key(key)
    mav.signing.sign_outgoing = False
    mav.signing.timestamp = signing_timestamp() if now_ts is None else now_ts
    mav.signing.allow_unsigned_callback = _refuse_unsigned
    return mav


def _refuse_unsigned(_mav: mavlink2.MAVLink, _msg_id: int) -> bool:
    return False


def parse_datagram(parser: mavlink2.MAVLink, data: bytes) -> list[mavlink2.MAVLink_message]:
    """Decode one datagram on its own (no bytes carried into the next); bad frames included."""
    msgs = parser.parse_buffer(data) or []
    if parser.buf_len():
        parser.buf = bytearray()
        parser.buf_index = 0
        parser.expected_length = mavlink2.HEADER_LEN_V1 + 2
    return msgs


@dataclass(slots=True)
class ProxyStats:
    """Datagram and frame counters of a :class:`SigningProxy`."""

    up_signed: int = 0
    up_dropped: int = 0
    down_accepted: int = 0
    down_rejected: int = 0


class _Side(asyncio.DatagramProtocol):
    def __init__(self, on_datagram) -> None:
        self.on_datagram = on_datagram

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.on_datagram(data, addr)


class SigningProxy:
    """A signing UDP proxy between MAVSDK and one vehicle (see the module docstring).

    Args:
        key: the 32-byte shared secret.
        listen_port: where the vehicle sends (the GCS port, ``14540 + i`` for PX4 SITL).
        vehicle_addr: where to send to the vehicle before it has been heard
            (``None``: wait for its first valid frame, then answer its address).
        inner_port: the local port MAVSDK listens on (``udpin://127.0.0.1:<inner_port>``).
        link_id: the MAVLink signing link id of the GCS's frames.
        host: the loopback/interface address to bind.
    """

    def __init__(
        self,
        key: bytes,
        listen_port: int,
        inner_port: int,
        *,
        vehicle_addr: tuple[str, int] | None = None,
        link_id: int = 0,
        host: str = "127.0.0.1",
    ) -> None:
        self.key = check_key(key)
        self.listen_port = listen_port
        self.inner_port = inner_port
        self.vehicle_addr = vehicle_addr
        self.link_id = link_id & 0xFF
        self.host = host
        self.stats = ProxyStats()
        self._verifier = verifier(self.key)
        self._splitter = mavlink2.MAVLink(None)
        self._splitter.robust_parsing = True
        self._timestamp = signing_timestamp()
        self._outer: asyncio.DatagramTransport | None = None
        self._inner: asyncio.DatagramTransport | None = None

    async def start(self) -> None:
        """Bind both sockets."""
        loop = asyncio.get_running_loop()
        try:
            self._outer, _ = await loop.create_datagram_endpoint(
                lambda: _Side(self._from_vehicle), local_addr=(self.host, self.listen_port)
            )
            self._inner, _ = await loop.create_datagram_endpoint(
                lambda: _Side(self._from_gcs), local_addr=(self.host, 0)
            )
        except OSError as exc:
            self.close()
            raise LinkError(
                f"signing proxy: cannot bind {self.host}:{self.listen_port}: {exc.strerror or exc}"
            ) from None

    @property
    def own_inner_port(self) -> int | None:
        """The proxy's own port on MAVSDK's side, where the ground station's frames arrive
        (``None`` before :meth:`start`)."""
        if self._inner is None:
            return None
        return int(self._inner.get_extra_info("sockname")[1])

    def close(self) -> None:
        """Close both sockets."""
        for t in (self._outer, self._inner):
            if t is not None:
                t.close()
        self._outer = self._inner = None

    async def __aenter__(self) -> SigningProxy:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()

    def _from_vehicle(self, data: bytes, addr: tuple[str, int]) -> None:
        good = [m for m in parse_datagram(self._verifier, data) if m.get_type() != "BAD_DATA"]
        rejected = len(parse_datagram(self._splitter, data)) - len(good)
        self.stats.down_rejected += max(rejected, 0)
        if not good or self._inner is None:
            return
        self.vehicle_addr = addr
        self.stats.down_accepted += len(good)
        self._inner.sendto(
            b"".join(bytes(m.get_msgbuf()) for m in good), (self.host, self.inner_port)
        )

    def _from_gcs(self, data: bytes, _addr: tuple[str, int]) -> None:
        out = []
        for m in parse_datagram(self._splitter, data):
            if m.get_type() == "BAD_DATA":
                continue
            now = signing_timestamp()
            self._timestamp = max(self._timestamp + 1, now)
            signed = sign_frame(bytes(m.get_msgbuf()), self.key, self.link_id, self._timestamp)
            if signed is None:
                self.stats.up_dropped += 1
                continue
            out.append(signed)
        if out and self._outer is not None and self.vehicle_addr is not None:
            self.stats.up_signed += len(out)
            for frame in out:
                self._outer.sendto(frame, self.vehicle_addr)


async def run_proxies(
    key: bytes,
    n: int,
    *,
    listen_base: int = 14540,
    inner_base: int = 14640,
    vehicle_host: str = "127.0.0.1",
    vehicle_base: int = 14580,
    stop: asyncio.Event | None = None,
) -> list[ProxyStats]:
    """Run one :class:`SigningProxy` per vehicle ``i`` (PX4 SITL ports) until ``stop`` is set.

    Vehicle ``i`` sends to ``listen_base + i`` and listens on ``vehicle_base + i``
    at ``vehicle_host``; MAVSDK reaches it at ``udpin://127.0.0.1:{inner_base + i}``.
    """
    proxies = [
        SigningProxy(
            key, listen_base + i, inner_base + i, vehicle_addr=(vehicle_host, vehicle_base + i)
        )
        for i in range(n)
    ]
    started: list[SigningProxy] = []
    try:
        for p in proxies:
            await p.start()
            started.append(p)
        print(
            "signing proxy: "
            + ", ".join(
                f"vehicle {i} -> udpin://127.0.0.1:{p.inner_port}" for i, p in enumerate(proxies)
            ),
            flush=True,
        )
        await (stop or asyncio.Event()).wait()
    finally:
        for p in started:
            p.close()
    return [p.stats for p in proxies]


def main(argv: list[str] | None = None) -> int:
    """``python -m mavlink.link.signing --key FILE [-n N]``: signing proxies for a signed fleet.

    Then fly with ``gcs fly PLAN --connection udpin://127.0.0.1:<inner_base + i> ...``.
    Exit 0 on Ctrl-C/SIGTERM, 2 on a bad key or a busy port (one line).
    """
    import argparse
    import signal
    import sys

    ap = argparse.ArgumentParser(prog="python -m mavlink.link.signing", description=main.__doc__)
    ap.add_argument("--key", required=True, metavar="FILE", help="signing key file")
    ap.add_argument("-n", "--vehicles", type=int, default=1)
    ap.add_argument("--listen-base", type=int, default=14540, help="vehicles send here (+i)")
    ap.add_argument("--inner-base", type=int, default=14640, help="MAVSDK listens here (+i)")
    ap.add_argument("--vehicle-host", default="127.0.0.1")
    ap.add_argument("--vehicle-base", type=int, default=14580, help="vehicles listen here (+i)")
    args = ap.parse_args(argv)

    async def serve() -> list[ProxyStats]:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        return await run_proxies(
            load_key(args.key),
            args.vehicles,
            listen_base=args.listen_base,
            inner_base=args.inner_base,
            vehicle_host=args.vehicle_host,
            vehicle_base=args.vehicle_base,
            stop=stop,
        )

    try:
        stats = asyncio.run(serve())
    except LinkError as exc:
        print(f"signing proxy: error: {exc}", file=sys.stderr)
        return 2
    for i, st in enumerate(stats):
        print(f"vehicle {i}: {st}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
