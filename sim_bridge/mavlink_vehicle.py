"""The vehicle's end of a MAVLink link: real frames, real sequence numbers.

It speaks over a real UDP socket (sending to the ground station's port, like
a flight controller configured with a GCS address) or a real pseudo-terminal
(:class:`~sim_bridge.pty_port.PtyPort`), and behaves like an autopilot towards
the ground station: it sends HEARTBEATs, answers SET_MESSAGE_INTERVAL with
COMMAND_ACK (or refuses or ignores it, to exercise the ground station's
fallback), and keeps what the ground station sent.

What it *says* is up to the caller (:meth:`send`); the physics that decide it
live in the simulator's vehicle models.
"""

from __future__ import annotations

import asyncio
import socket
from collections import Counter

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.transports import close_watched_socket

from .pty_port import PtyPort


class MavlinkVehicle:
    """``ack``: 'accept', 'deny' or 'ignore' SET_MESSAGE_INTERVAL commands."""

    def __init__(
        self,
        *,
        udp_to: tuple[str, int] | None = None,
        udp_listen: tuple[str, int] | None = None,
        pty: PtyPort | None = None,
        sysid: int = 1,
        compid: int = 1,
        mavlink1: bool = False,
        ack: str = "accept",
    ) -> None:
        if sum(x is not None for x in (udp_to, udp_listen, pty)) != 1:
            raise ValueError("give exactly one of udp_to, udp_listen or pty")
        #: listen on this address and answer whoever wrote last (a vehicle the
        #: ground station reaches with ``udpout:``)
        self.udp_listen = udp_listen
        self.mav = mavlink.MAVLink(None, sysid, compid)
        self.mav.robust_parsing = True
        self.mavlink1 = mavlink1
        self.ack = ack
        self.udp_to = udp_to
        self.pty = pty
        self._sock: socket.socket | None = None
        self.received: list = []
        self.received_types: Counter = Counter()
        self.message_intervals: dict[int, float] = {}  # msg id -> interval [us]
        self.data_stream_requests: list[tuple[int, int]] = []
        self.frames_sent = 0
        self.send_errors = 0
        self._got = asyncio.Event()
        self._hb_task: asyncio.Task | None = None

    async def open(self) -> None:
        loop = asyncio.get_running_loop()
        self._got = asyncio.Event()
        if self.udp_to is not None or self.udp_listen is not None:
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(self.udp_listen or ("127.0.0.1", 0))
            s.setblocking(False)
            self._sock = s
            loop.add_reader(s.fileno(), self._udp_readable)
        elif self.pty is not None:
            self.pty.on_data = self._incoming
            if self.pty.master is None:
                self.pty.plug()
        else:
            raise ValueError("a simulated vehicle needs a UDP address or a pty")

    def start_heartbeat(self, hz: float = 1.0) -> None:
        """Send HEARTBEAT periodically, as every autopilot does."""

        async def beat():
            while True:
                self.heartbeat()
                await asyncio.sleep(1.0 / hz)

        if self._hb_task is None:
            self._hb_task = asyncio.get_running_loop().create_task(beat())

    def stop_heartbeat(self) -> None:
        if self._hb_task is not None:
            self._hb_task.cancel()
            self._hb_task = None

    @property
    def port(self) -> int | None:
        return self._sock.getsockname()[1] if self._sock is not None else None

    def close(self) -> None:
        self.stop_heartbeat()
        close_watched_socket(self._sock)
        self._sock = None
        if self.pty is not None:
            self.pty.close()

    # -- sending ---------------------------------------------------------------------
    def encode(self, msg) -> bytes:
        buf = msg.pack(self.mav, force_mavlink1=self.mavlink1)
        self.mav.seq = (self.mav.seq + 1) % 256
        return bytes(buf)

    def send_bytes(self, data: bytes) -> None:
        if self._sock is not None:
            if self.udp_to is None:
                return  # listening, and nobody has written yet
            try:
                self._sock.sendto(data, self.udp_to)
            except OSError:  # no listener yet (ICMP refused) or buffer full: counted
                self.send_errors += 1
        elif self.pty is not None:
            self.pty.write(data)

    def send(self, msg) -> bytes:
        data = self.encode(msg)
        self.send_bytes(data)
        self.frames_sent += 1
        return data

    def heartbeat(self) -> bytes:
        return self.send(
            mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_QUADROTOR,
                mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                0,
                mavlink.MAV_STATE_STANDBY,
                3,
            )
        )

    # -- receiving ---------------------------------------------------------------------
    def _udp_readable(self) -> None:
        if self._sock is None:
            return
        try:
            data, addr = self._sock.recvfrom(65536)
        except (BlockingIOError, OSError):
            return
        if self.udp_listen is not None:
            self.udp_to = addr
        self._incoming(data)

    def _incoming(self, data: bytes) -> None:
        for m in self.mav.parse_buffer(data) or ():
            if m.get_type() == "BAD_DATA":
                continue
            self.received.append(m)
            self.received_types[m.get_type()] += 1
            if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
                self._set_message_interval(m)
            elif m.get_type() == "REQUEST_DATA_STREAM":
                self.data_stream_requests.append((m.req_stream_id, m.req_message_rate))
        self._got.set()

    def _set_message_interval(self, m) -> None:
        if self.ack == "ignore":
            return
        if self.ack == "accept":
            self.message_intervals[int(m.param1)] = m.param2
            result = mavlink.MAV_RESULT_ACCEPTED
        else:
            result = mavlink.MAV_RESULT_DENIED
        self.send(mavlink.MAVLink_command_ack_message(m.command, result))

    async def wait_for(self, mtype: str, count: int = 1, timeout: float = 5.0) -> None:
        """Wait until ``count`` messages of ``mtype`` have come from the ground station."""

        async def _wait():
            while self.received_types[mtype] < count:
                self._got.clear()
                await self._got.wait()

        await asyncio.wait_for(_wait(), timeout)
