"""Connection strings, as pymavlink and MAVProxy users already type them.

=========================  =================================================
``udpin:0.0.0.0:14550``    listen for UDP; reply to whoever sent last
``udpout:host:14550``      send UDP to host:port (and read its replies)
``udp:...``                pymavlink's alias of ``udpin``
``tcp:host:5760``          TCP client; reconnects when the peer comes back
``tcpin:0.0.0.0:5760``     TCP server; accepts peers, talks to all of them
``/dev/ttyUSB0,57600``     serial through pyserial (also ``serial:/dev/x:57600``,
                           ``/dev/ttyUSB0`` with the default 57600 baud,
                           ``COM3,115200``); reconnects when the device returns
=========================  =================================================
"""

from __future__ import annotations

from dataclasses import dataclass

DEFAULT_BAUD = 57600


class ConnectionStringError(ValueError):
    """The connection string cannot be understood (one-line message)."""


@dataclass(frozen=True)
class Endpoint:
    scheme: str  # 'udpin' | 'udpout' | 'tcp' | 'tcpin' | 'serial'
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = DEFAULT_BAUD

    def __str__(self) -> str:
        if self.scheme == "serial":
            return f"{self.device},{self.baud}"
        return f"{self.scheme}:{self.host}:{self.port}"


def _host_port(rest: str, text: str) -> tuple[str, int]:
    host, sep, port = rest.rpartition(":")
    if not sep or not port.isdigit():
        raise ConnectionStringError(f"{text!r}: expected host:port after the scheme")
    p = int(port)
    if not 0 <= p <= 65535:
        raise ConnectionStringError(f"{text!r}: port {p} out of range")
    return host or "0.0.0.0", p


def parse_connection(text: str) -> Endpoint:
    """Parse a connection string into an :class:`Endpoint`."""
    s = text.strip()
    if not s:
        raise ConnectionStringError("empty connection string")
    scheme, sep, rest = s.partition(":")
    low = scheme.lower()
    if sep and low in ("udpin", "udp", "udpout", "tcp", "tcpin"):
        host, port = _host_port(rest, text)
        return Endpoint("udpin" if low == "udp" else low, host, port)
    if sep and low == "serial":
        dev, _, baud = rest.rpartition(":") if rest.count(":") else (rest, "", "")
        return _serial(dev or rest, baud, text)
    if s.startswith("/") or low.startswith("com"):
        dev, _, baud = s.partition(",")
        return _serial(dev, baud, text)
    raise ConnectionStringError(
        f"{text!r}: unknown connection; use udpin:HOST:PORT, udpout:HOST:PORT, "
        "tcp:HOST:PORT, tcpin:HOST:PORT or /dev/DEVICE,BAUD"
    )


def _serial(dev: str, baud: str, text: str) -> Endpoint:
    if baud and not baud.isdigit():
        raise ConnectionStringError(f"{text!r}: baud rate {baud!r} is not a number")
    return Endpoint("serial", device=dev, baud=int(baud) if baud else DEFAULT_BAUD)
