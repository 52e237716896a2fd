"""Connection URLs (docs/architecture.md, "The MAVLink side") and the multi-vehicle port convention.

Accepted forms, checked before anything is opened::

    udpin://HOST:PORT        listen on HOST:PORT (vehicle sends to us; PX4 SITL style)
    udpout://HOST:PORT       send to HOST:PORT first
    tcpin://HOST:PORT        accept one TCP connection
    tcpout://HOST:PORT       connect to a TCP server
    serial://DEVICE:BAUD     serial port, e.g. serial:///dev/ttyUSB0:57600

Vehicle instance ``i`` (0-based) of a plan, as in PX4 SITL, has system id
``i + 1``, sends to UDP port ``14540 + i`` on the GCS host and listens on
``14580 + i``; with no explicit URL it is reached at
``udpin://0.0.0.0:{14540 + i}`` (:func:`default_url`).
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass
from enum import Enum

from mavlink.errors import UrlError

#: First GCS-side UDP port of the PX4 SITL convention (vehicle i sends to 14540 + i).
GCS_BASE_PORT = 14540
#: First vehicle-side UDP port of the PX4 SITL convention (vehicle i listens on 14580 + i).
VEHICLE_BASE_PORT = 14580
#: Baud rates a serial URL may name.
SERIAL_BAUD_RATES = frozenset(
    {
        9600,
        19200,
        38400,
        57600,
        115200,
        230400,
        460800,
        500000,
        921600,
        1000000,
        1500000,
        2000000,
        3000000,
    }
)


class Scheme(Enum):
    """Transport named by a URL's scheme."""

    UDPIN = "udpin"
    UDPOUT = "udpout"
    TCPIN = "tcpin"
    TCPOUT = "tcpout"
    SERIAL = "serial"


@dataclass(frozen=True, slots=True)
class ConnectionUrl:
    """A validated connection URL.

    Attributes:
        scheme: the transport.
        host: IP address or host name (network schemes), else ``""``.
        port: UDP/TCP port 1..65535 (network schemes), else 0.
        device: serial device path (``/dev/ttyUSB0``), else ``""``.
        baud_rate: serial baud rate, else 0.
    """

    scheme: Scheme
    host: str = ""
    port: int = 0
    device: str = ""
    baud_rate: int = 0

    def __str__(self) -> str:
        if self.scheme is Scheme.SERIAL:
            return f"serial://{self.device}:{self.baud_rate}"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme.value}://{host}:{self.port}"

    @property
    def is_network(self) -> bool:
        """True for UDP and TCP URLs."""
        return self.scheme is not Scheme.SERIAL


_NET = re.compile(r"^(?P<host>\[[^\]]*\]|[^:/\[\]]*):(?P<port>[^:/]*)$")
_HOSTNAME = re.compile(
    r"^(?=.{1,253}$)([A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*$"
)


def parse_url(text: str, *, vehicle: str | None = None) -> ConnectionUrl:
    """Parse and validate a connection URL.

    Args:
        text: the URL, e.g. ``"udpin://0.0.0.0:14540"``.
        vehicle: the vehicle it is for, named in the error message.

    Returns:
        The :class:`ConnectionUrl`; ``str()`` of it is the canonical text
        MAVSDK accepts.

    Raises:
        UrlError: naming the URL and what is wrong with it.
    """

    def fail(why: str) -> UrlError:
        return UrlError(f"bad connection URL {text!r}: {why}", vehicle=vehicle)

    if not isinstance(text, str) or not text.strip():
        raise fail("empty")
    text = text.strip()
    scheme_text, sep, rest = text.partition("://")
    if not sep:
        raise fail("expected SCHEME://..., scheme one of " + ", ".join(s.value for s in Scheme))
    try:
        scheme = Scheme(scheme_text.lower())
    except ValueError:
        raise fail(
            f"unknown scheme {scheme_text!r}, expected one of " + ", ".join(s.value for s in Scheme)
        ) from None
    if scheme is Scheme.SERIAL:
        device, colon, baud_text = rest.rpartition(":")
        if not colon or not device:
            raise fail("expected serial://DEVICE:BAUD, e.g. serial:///dev/ttyUSB0:57600")
        if not baud_text.isdigit() or int(baud_text) not in SERIAL_BAUD_RATES:
            raise fail(
                f"baud rate {baud_text!r} is not one of "
                + ", ".join(str(b) for b in sorted(SERIAL_BAUD_RATES))
            )
        return ConnectionUrl(scheme, device=device, baud_rate=int(baud_text))
    match = _NET.match(rest)
    if match is None:
        raise fail(f"expected {scheme.value}://HOST:PORT")
    host, port_text = match["host"], match["port"]
    if host.startswith("["):
        host = host[1:-1]
    if not host:
        raise fail("missing host (use 0.0.0.0 to listen on all interfaces)")
    try:
        ipaddress.ip_address(host)
    except ValueError:
        if not _HOSTNAME.match(host):
            raise fail(f"host {host!r} is neither an IP address nor a host name") from None
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise fail(f"port {port_text!r} is not an integer in 1..65535")
    return ConnectionUrl(scheme, host=host, port=int(port_text))


def default_url(index: int, base_port: int = GCS_BASE_PORT) -> str:
    """URL of vehicle instance ``index`` (0-based) by the PX4 SITL convention:
    ``udpin://0.0.0.0:{base_port + index}`` (14540 + index by default)."""
    if index < 0 or not 1 <= base_port + index <= 65535:
        raise UrlError(f"vehicle index {index} has no port from base port {base_port}")
    return f"udpin://0.0.0.0:{base_port + index}"


def default_sysid(index: int) -> int:
    """MAVLink system id of vehicle instance ``index`` (0-based): ``index + 1``."""
    if not 0 <= index < 255:
        raise UrlError(f"vehicle index {index} has no MAVLink system id (1..255)")
    return index + 1


def default_vehicle_port(index: int) -> int:
    """UDP port vehicle instance ``index`` listens on: ``14580 + index``."""
    return VEHICLE_BASE_PORT + index
