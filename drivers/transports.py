"""Byte transports on asyncio: UDP, TCP client/server, serial (pyserial).

pymavlink's ``mavutil`` connections block on reads, so they would need a thread
per link; these transports sit on the event loop instead and hand bytes to a
callback as they arrive. Any protocol (MAVLink, the sensor-board frames) runs
on top of them.

Serial and TCP-client transports reconnect on their own: when the device
disappears (a USB radio unplugged, a pty closed) or the peer closes, they
report ``on_disconnect`` and retry every ``retry_s`` until it is back. UDP has
no connection; it simply resumes when datagrams arrive again.
"""

from __future__ import annotations

import abc
import asyncio
import contextlib
import errno
import os
import socket
import struct
import sys
import time
from collections.abc import Callable

import serial

from .connection import Endpoint

OnData = Callable[[bytes, float], None]
OnEvent = Callable[[str], None]


class TransportError(OSError):
    """The transport could not be opened (one-line message)."""


def _nothing(*_a) -> None:
    return None


def close_watched_socket(sock: socket.socket | None) -> None:
    """Stop the event loop watching ``sock`` and close it (None: nothing to do)."""
    if sock is None:
        return
    fd = sock.fileno()
    try:
        loop = asyncio.get_running_loop()
    except RuntimeError:  # closed outside the event loop: nothing watches it
        loop = None
    if loop is not None and fd >= 0:
        loop.remove_reader(fd)
    sock.close()


class Transport(abc.ABC):
    """Base: ``on_data(bytes, t_rx)``, ``on_connect(text)``, ``on_disconnect(reason)``."""

    reconnects = False

    def __init__(self, endpoint: Endpoint) -> None:
        self.endpoint = endpoint
        self.on_data: OnData = _nothing
        self.on_connect: OnEvent = _nothing
        self.on_disconnect: OnEvent = _nothing
        self.connected = False

    @abc.abstractmethod
    async def open(self) -> None:
        """See the subclasses."""

    @abc.abstractmethod
    def send(self, data: bytes) -> None:
        """See the subclasses."""

    @abc.abstractmethod
    async def close(self) -> None:
        """See the subclasses."""

    @property
    def has_peer(self) -> bool:
        return self.connected

    @property
    def local_address(self) -> tuple[str, int] | None:
        return None


# --------------------------------------------------------------------- UDP
#: Linux socket options (``socket`` does not name them): the kernel's count of datagrams it
#: dropped on a full receive buffer, and its receive time of each datagram (UNIX time, ns)
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_CMSG_SPACE = socket.CMSG_SPACE(4) + socket.CMSG_SPACE(16)
_TIMESPEC = struct.Struct("qq")


class UdpTransport(Transport):
    """``udpin`` listens and answers the last sender (or one it names: :meth:`send_to`, :attr:`source`);
    ``udpout`` talks to one address.

    A plain non-blocking socket on ``loop.add_reader`` rather than asyncio's
    datagram transport, which reads one datagram per event-loop turn: under a
    burst that lets the kernel buffer overflow. Each wake-up drains the socket
    (up to ``drain`` datagrams), handing each on as it is read, then calls
    ``on_burst_end`` once: consumers work on the whole burst at a time.

    Each datagram's receive time is the kernel's (``SO_TIMESTAMPNS``), taken as
    it arrived, not when the event loop came to read it: a burst read after a
    20 ms stall keeps its real spacing (stamped as read, the messages without a
    time field of their own got stamps milliseconds ahead of the sensor
    readings sent after them, and each of those then rolled the estimators back).

    Read on the event loop, not on a thread of its own: CPython's GIL makes a
    reader thread wait up to its switch interval (5 ms) for every datagram
    while another thread computes (each ``recvmsg`` lets the GIL go), which
    measured worse on every count (``bench/load.py``). What keeps the kernel
    from dropping is the receive buffer (``rcvbuf``) and consumers that give
    the loop back within milliseconds.

    :attr:`kernel_drops` is the kernel's own count of datagrams it dropped on a
    full receive buffer (Linux ``SO_RXQ_OVFL``; 0 where there is no such count).
    """

    drain = 2000
    #: receive buffer asked for [bytes]: 0.4 s of 20,000 small datagrams a second. Linux grants up
    #: to ``net.core.rmem_max`` (twice that, counting its bookkeeping) unless the process may force it
    rcvbuf = 1 << 23

    def __init__(self, endpoint: Endpoint) -> None:
        super().__init__(endpoint)
        self._sock: socket.socket | None = None
        self.peer: tuple | None = None
        #: udpin: the address of the datagram being handed on (who sent what ``on_data`` is given)
        self.source: tuple | None = None
        self.send_errors = 0
        self.kernel_drops = 0
        self.on_burst_end: Callable[[], None] = _nothing

    async def open(self) -> None:
        ep = self.endpoint
        try:
            infos = socket.getaddrinfo(ep.host, ep.port, type=socket.SOCK_DGRAM)
            family, _, _, _, addr = infos[0]
            s = socket.socket(family, socket.SOCK_DGRAM)
            if ep.scheme == "udpin":
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                s.bind(addr)
            else:
                s.bind(("0.0.0.0", 0) if family == socket.AF_INET else ("::", 0))
                self.peer = addr
        except OSError as e:
            raise TransportError(f"cannot open {ep}: {e.strerror or e}") from None
        _ask_receive_buffer(s, self.rcvbuf)
        for option in (SO_RXQ_OVFL, SO_TIMESTAMPNS):
            try:
                s.setsockopt(socket.SOL_SOCKET, option, 1)
            except OSError:
                pass  # not Linux: no kernel drop count, the time it is read
        s.setblocking(False)
        self._sock = s
        asyncio.get_running_loop().add_reader(s.fileno(), self._readable)
        self.connected = True

    @property
    def receive_buffer(self) -> int:
        """The receive buffer the kernel granted [bytes]."""
        return self._sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) if self._sock else 0

    def _readable(self) -> None:
        sock = self._sock
        if sock is None:
            return
        on_data, udpin = self.on_data, self.endpoint.scheme == "udpin"
        try:
            for _ in range(self.drain):
                try:
                    data, anc, _flags, addr = sock.recvmsg(65536, _CMSG_SPACE)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:  # ICMP errors surface here on Linux: harmless
                    self.send_errors += 1
                    break
                t_rx = self._ancillary(anc) if anc else time.time()
                if udpin:
                    self.peer = self.source = addr
                # each datagram is handed on as it is read: a burst does not make its first frame
                # wait for its last
                on_data(data, t_rx)
                if self._sock is None:  # closed by a callback
                    break
        finally:
            self.on_burst_end()

    def _ancillary(self, anc: list) -> float:
        """The datagram's kernel receive time (now, if absent); the kernel's drop count noted."""
        t_rx = 0.0
        for level, kind, value in anc:
            if level != socket.SOL_SOCKET:
                continue
            if kind == SO_TIMESTAMPNS and len(value) >= 16:
                sec, ns = _TIMESPEC.unpack_from(value)
                t_rx = sec + ns * 1e-9
            elif kind == SO_RXQ_OVFL and len(value) >= 4:
                # cumulative, stamped on each datagram queued after a drop
                self.kernel_drops = max(self.kernel_drops, int.from_bytes(value[:4], sys.byteorder))
        return t_rx or time.time()

    def send(self, data: bytes) -> None:
        if self.peer is not None:
            self.send_to(data, self.peer)

    def send_to(self, data: bytes, addr: tuple) -> None:
        if self._sock is not None:
            try:
                self._sock.sendto(data, addr)
            except OSError:
                self.send_errors += 1

    @property
    def has_peer(self) -> bool:
        return self.peer is not None

    @property
    def local_address(self):
        return self._sock.getsockname()[:2] if self._sock else None

    async def close(self) -> None:
        close_watched_socket(self._sock)
        self._sock = None
        self.connected = False


def _ask_receive_buffer(s: socket.socket, size: int) -> None:
    """``size`` bytes of receive buffer: forced past ``net.core.rmem_max`` where the process may
    (Linux ``SO_RCVBUFFORCE``, with CAP_NET_ADMIN), else as much as the system allows. What was
    granted is :attr:`UdpTransport.receive_buffer`, which ``connect`` prints when it is short."""
    for option in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
        if option is None:
            continue
        with contextlib.suppress(OSError):  # not permitted: the next, or the system's default
            s.setsockopt(socket.SOL_SOCKET, option, size)
            return


# --------------------------------------------------------------------- TCP
class _Stream(asyncio.Protocol):
    def __init__(self, owner: TcpTransport) -> None:
        self.owner = owner
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport) -> None:
        self.transport = transport
        self.owner._peer_up(self)

    def data_received(self, data: bytes) -> None:
        self.owner.on_data(data, time.time())

    def connection_lost(self, exc) -> None:
        self.owner._peer_down(self, exc)


class TcpTransport(Transport):
    """``tcp`` (client, reconnecting) or ``tcpin`` (server, any number of peers)."""

    def __init__(self, endpoint: Endpoint, retry_s: float = 0.5) -> None:
        super().__init__(endpoint)
        self.reconnects = endpoint.scheme == "tcp"
        self.retry_s = retry_s
        self._peers: list[_Stream] = []
        self._server: asyncio.Server | None = None
        self._retry_task: asyncio.Task | None = None
        self._closing = False

    async def open(self) -> None:
        loop = asyncio.get_running_loop()
        ep = self.endpoint
        try:
            if ep.scheme == "tcpin":
                self._server = await loop.create_server(lambda: _Stream(self), ep.host, ep.port)
                self.connected = True
            else:
                await loop.create_connection(lambda: _Stream(self), ep.host, ep.port)
        except OSError as e:
            raise TransportError(f"cannot open {ep}: {e.strerror or e}") from None

    def _peer_up(self, s: _Stream) -> None:
        self._peers.append(s)
        self.connected = True
        self.on_connect(f"{self.endpoint} connected")

    def _peer_down(self, s: _Stream, exc) -> None:
        if s in self._peers:
            self._peers.remove(s)
        if self._closing:
            return
        if self.endpoint.scheme == "tcp":
            self.connected = False
            self.on_disconnect(f"{self.endpoint}: peer closed" + (f" ({exc})" if exc else ""))
            self._retry_task = asyncio.get_running_loop().create_task(self._reconnect())
        elif not self._peers:
            self.on_disconnect(f"{self.endpoint}: last client left")

    async def _reconnect(self) -> None:
        loop = asyncio.get_running_loop()
        while not self._closing and not self._peers:
            await asyncio.sleep(self.retry_s)
            try:
                await loop.create_connection(lambda: _Stream(self), self.endpoint.host, self.endpoint.port)
            except OSError:
                continue

    def send(self, data: bytes) -> None:
        for p in self._peers:
            if p.transport is not None and not p.transport.is_closing():
                p.transport.write(data)

    @property
    def has_peer(self) -> bool:
        return bool(self._peers)

    @property
    def local_address(self):
        if self._server is not None and self._server.sockets:
            return self._server.sockets[0].getsockname()[:2]
        return None

    async def close(self) -> None:
        self._closing = True
        if self._retry_task is not None:
            self._retry_task.cancel()
        for p in list(self._peers):
            if p.transport is not None:
                p.transport.close()
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
        self.connected = False


# ------------------------------------------------------------------ serial
class SerialTransport(Transport):
    """A serial device through pyserial, read from the event loop (no thread).

    Reconnects when the device path exists again (a USB radio replugged: its
    ``/dev/serial/by-id`` link comes back). The device is polled for every
    ``retry_s``: the kernel offers no portable event for a device appearing.
    """

    reconnects = True

    def __init__(self, endpoint: Endpoint, retry_s: float = 0.25) -> None:
        super().__init__(endpoint)
        self.retry_s = retry_s
        self._ser: serial.Serial | None = None
        self._fd: int | None = None
        self._retry_task: asyncio.Task | None = None
        self._closing = False

    def _open_port(self) -> None:
        ep = self.endpoint
        try:
            ser = serial.Serial(ep.device, ep.baud, timeout=0, write_timeout=0, exclusive=False)
        except (serial.SerialException, OSError, ValueError) as e:
            msg = str(e)
            if isinstance(e, OSError) or "No such file" in msg or "could not open" in msg:
                if not os.path.exists(ep.device):
                    raise TransportError(f"cannot open {ep.device}: no such device") from None
            raise TransportError(f"cannot open {ep.device}: {msg.splitlines()[0] if msg else e}") from None
        self._ser = ser
        self._fd = ser.fileno()
        asyncio.get_running_loop().add_reader(self._fd, self._readable)
        self.connected = True

    async def open(self) -> None:
        self._open_port()

    def _readable(self) -> None:
        ser = self._ser
        if ser is None:
            return
        if self._fd is None:
            return
        try:
            data = os.read(self._fd, 65536)
        except BlockingIOError:
            return
        except OSError as e:
            self._lost(f"{self.endpoint.device}: {os.strerror(e.errno) if e.errno else e}")
            return
        if not data:
            self._lost(f"{self.endpoint.device}: device closed")
            return
        self.on_data(data, time.time())

    def _lost(self, reason: str) -> None:
        self._drop_port()
        if self._closing:
            return
        self.on_disconnect(reason)
        self._retry_task = asyncio.get_running_loop().create_task(self._reconnect())

    def _drop_port(self) -> None:
        if self._fd is not None:
            try:
                asyncio.get_running_loop().remove_reader(self._fd)
            except (RuntimeError, ValueError):
                pass
        if self._ser is not None:
            try:
                self._ser.close()
            except (OSError, serial.SerialException):
                pass
        self._ser, self._fd = None, None
        self.connected = False

    async def _reconnect(self) -> None:
        while not self._closing:
            await asyncio.sleep(self.retry_s)
            try:
                self._open_port()
            except TransportError:
                continue
            self.on_connect(f"{self.endpoint.device} reconnected")
            return

    def send(self, data: bytes) -> None:
        if self._fd is None:
            return
        try:
            os.write(self._fd, data)
        except BlockingIOError:
            pass  # output buffer full: drop, as a radio would
        except OSError as e:
            if e.errno in (errno.EIO, errno.ENXIO, errno.EBADF):
                self._lost(f"{self.endpoint.device}: {os.strerror(e.errno)}")

    async def close(self) -> None:
        self._closing = True
        if self._retry_task is not None:
            self._retry_task.cancel()
        self._drop_port()


def open_transport(endpoint: Endpoint) -> Transport:
    if endpoint.scheme in ("udpin", "udpout"):
        return UdpTransport(endpoint)
    if endpoint.scheme in ("tcp", "tcpin"):
        return TcpTransport(endpoint)
    return SerialTransport(endpoint)
