"""The vehicle's side of MAVLink's log protocol: listing, sending and erasing its onboard logs.

As ArduPilot's ``AP_Logger_MAVLinkLogTransfer``:

* ``LOG_REQUEST_LIST(start, end)``: a ``LOG_ENTRY`` (id, num_logs, last_log_num, time_utc, size)
  for each log numbered from ``start`` to ``end``; with no logs, one entry of id 0 and num_logs 0.
* ``LOG_REQUEST_DATA(id, ofs, count)``: ``LOG_DATA`` of 90 bytes at a time from ``ofs``, ``count``
  bytes (0xFFFFFFFF: to the end), paced at :data:`BYTES_PER_S`; at or past the end, one
  ``LOG_DATA`` with count 0. A new request replaces the one being served.
* ``LOG_REQUEST_END`` stops sending; ``LOG_ERASE`` removes every finished log.

The logs themselves are :class:`~sim_bridge.flight_log.FlightLogs`.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from .flight_log import FlightLogs
from .mavlink_out import FramePacker

CHUNK = 90  # bytes a LOG_DATA carries
#: [bytes/s] the pace of a download (a 5 MB ten-minute flight in about 10 s)
BYTES_PER_S = 500_000
MAX_FRAMES_A_PUMP = 200  # frames sent at once after a stall at most


class LogServer:
    def __init__(self, logs: FlightLogs, packer: FramePacker, send: Callable[[bytes], None], sysid: int) -> None:
        self.logs = logs
        self.packer = packer
        self.send = send
        self.sysid = sysid
        self._serving: tuple[int, int, int] | None = None  # log id, next offset, end offset
        self._last_pump = time.monotonic()
        self._credit = 0.0  # [frames] the pace allows now
        self.data_sent = 0  # LOG_DATA frames

    def _for_me(self, m) -> bool:
        return getattr(m, "target_system", 0) in (0, self.sysid)

    def on_log_request_list(self, m) -> None:
        if not self._for_me(m):
            return
        logs = self.logs.logs
        if not logs:
            self.send(self.packer.pack("LOG_ENTRY", id=0, num_logs=0, last_log_num=0, time_utc=0, size=0))
            return
        last = max(logs)
        for n in sorted(logs):
            if m.start <= n <= m.end:
                lg = logs[n]
                self.send(
                    self.packer.pack(
                        "LOG_ENTRY",
                        id=n,
                        num_logs=len(logs),
                        last_log_num=last,
                        time_utc=int(lg.time_utc),
                        size=lg.size,
                    )
                )

    def on_log_request_data(self, m) -> None:
        if not self._for_me(m):
            return
        log = self.logs.logs.get(int(m.id))
        if log is None:
            self._serving = None
            return
        ofs = int(m.ofs)
        end = log.size if m.count == 0xFFFFFFFF else min(log.size, ofs + int(m.count))
        if ofs >= end:
            self._data(int(m.id), ofs, b"")  # nothing there: the end, as ArduPilot answers it
            self._serving = None
            return
        self._serving = (int(m.id), ofs, end)

    def on_log_request_end(self, m) -> None:
        if self._for_me(m):
            self._serving = None

    def on_log_erase(self, m) -> None:
        if self._for_me(m):
            self.logs.erase()
            self._serving = None

    def pump(self) -> None:
        """Send what the pace allows of the download being served (the bridge calls it each tick)."""
        now = time.monotonic()
        self._credit = min(MAX_FRAMES_A_PUMP, self._credit + (now - self._last_pump) * BYTES_PER_S / CHUNK)
        self._last_pump = now
        while self._serving is not None and self._credit >= 1.0:
            n, ofs, end = self._serving
            log = self.logs.logs.get(n)
            if log is None:
                self._serving = None
                return
            piece = bytes(log.data[ofs : min(end, ofs + CHUNK)])
            self._data(n, ofs, piece)
            self._credit -= 1.0
            ofs += len(piece)
            self._serving = (n, ofs, end) if ofs < end and piece else None

    def _data(self, n: int, ofs: int, piece: bytes) -> None:
        self.send(self.packer.pack("LOG_DATA", id=n, ofs=ofs, count=len(piece), data=list(piece.ljust(CHUNK, b"\0"))))
        self.data_sent += 1
