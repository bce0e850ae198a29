"""MAVLink's log protocol from the ground station's side: a vehicle's onboard logs listed and
downloaded, whole, over a lossy link.

The list: ``LOG_REQUEST_LIST`` for all, answered by a ``LOG_ENTRY`` per log (``num_logs`` says how
many to expect); the numbers still missing are asked for one by one. A download: one
``LOG_REQUEST_DATA`` for the whole log, answered by ``LOG_DATA`` of 90 bytes each with its offset;
once the stretch asked for has been served (or the stream goes quiet), the first stretch still
missing is asked for (the offsets are multiples of 90, so a block is either there or not), until
the log is complete or nothing comes for :data:`RETRIES` rounds and :data:`GIVE_UP_S`; then ``LOG_REQUEST_END``
(ArduPilot holds its logging while a transfer is open). The vehicle serves one request at a time,
so the gaps are asked for one after the other, those close together as one. This is MAVProxy's
``log`` module's method; pymavlink has the messages but no transfer, so the loop is here.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from .exchange import Exchange

CHUNK = 90
ALL = 0xFFFFFFFF
RETRIES = 5
#: [s] without a LOG_DATA before what is missing is asked for again: three round trips as measured
#: (a request to its first block), within these bounds (this long before the first is measured)
QUIET_S, MIN_QUIET_S = 0.5, 0.02
#: [s] the least silence since the last LOG_DATA before a download is given up, however short the
#: rounds: at a round trip of 5 ms five rounds are 0.1 s, and a vehicle that stalls that long (its
#: logging busy, its process not scheduled) would lose a transfer with 96 % of the log in hand. After
#: :data:`RETRIES` short rounds the rounds are :data:`QUIET_S` long: a stalled vehicle is asked again
#: a few times, not flooded with requests
GIVE_UP_S = RETRIES * QUIET_S
#: missing blocks this close together are asked for as one stretch (resending the few between costs
#: less than a round trip each)
MERGE_BLOCKS = 16


class LogTransferError(RuntimeError):
    """A list or download that did not complete (one line: what, and how far it got); ``partial``:
    a download's bytes up to its first missing block."""

    def __init__(self, message: str, partial: bytes = b"") -> None:
        super().__init__(message)
        self.partial = partial


@dataclass(frozen=True)
class LogEntry:
    """A log on the vehicle: its number, when it began (Unix seconds; 0: unknown) and size [bytes]."""

    id: int
    time_utc: int
    size: int


class LogClient(Exchange):
    """The logs of one vehicle over a :class:`~drivers.mavlink.link.MavlinkLink`."""

    def __init__(self, link, sysid: int, compid: int = 1, *, timeout: float = 1.0) -> None:
        self.entries: dict[int, LogEntry] = {}
        self.num_logs: int | None = None
        self.last_log_num = 0
        self._download: _Download | None = None
        super().__init__(link, sysid, compid, timeout=timeout)

    def _on_message(self, m, _t_rx: float) -> None:
        t = m.get_type()
        if t not in ("LOG_ENTRY", "LOG_DATA") or m._header.srcSystem != self.sysid:
            return
        if t == "LOG_ENTRY":
            self.num_logs, self.last_log_num = int(m.num_logs), int(m.last_log_num)
            if m.num_logs and m.id:
                self.entries[int(m.id)] = LogEntry(int(m.id), int(m.time_utc), int(m.size))
        elif self._download is not None:
            self._download.take(m)
        self._changed_now()

    # -- the list --------------------------------------------------------------------------------
    async def list(self) -> list[LogEntry]:
        """The vehicle's logs, by number; LogTransferError if the vehicle never answers."""
        self.entries.clear()
        self.num_logs = None
        self._send_list(0, 0xFFFF)
        quiet = 0
        while quiet < RETRIES:
            if self.num_logs is not None and len(self.entries) >= self.num_logs:
                break
            if await self._wait_change(self.timeout):
                quiet = 0
                continue
            quiet += 1
            if self.num_logs is None:
                self._send_list(0, 0xFFFF)
            else:  # the logs are numbered on from the oldest kept to the last: those not seen
                first = self.last_log_num - self.num_logs + 1
                for n in range(max(first, 1), self.last_log_num + 1):
                    if n not in self.entries:
                        self._send_list(n, n)
        if self.num_logs is None:
            raise LogTransferError("logs: the vehicle did not answer LOG_REQUEST_LIST (does it log?)")
        return [self.entries[n] for n in sorted(self.entries)]

    def _send_list(self, start: int, end: int) -> None:
        self.link.send(mavlink.MAVLink_log_request_list_message(self.sysid, self.compid, start, end))

    # -- a download --------------------------------------------------------------------------------
    async def download(self, entry: LogEntry, progress: Callable[[int, int], None] | None = None) -> bytes:
        """The log's bytes, complete; LogTransferError (with the bytes up to the first gap as its
        ``partial``) if it cannot be completed."""
        d = self._download = _Download(entry.id, entry.size)
        try:
            if entry.size == 0:
                return b""
            loop = asyncio.get_running_loop()
            rtt: float | None = None  # [s] from a request to its first block: how long silence means loss
            self._ask(d, 0, d.size)
            asked_at, idle = loop.time(), 0
            heard = asked_at  # the last LOG_DATA (or the first request)
            while not d.complete():
                if rtt is None or idle >= RETRIES:
                    quiet = QUIET_S
                else:
                    quiet = min(QUIET_S, max(MIN_QUIET_S, 3.0 * rtt))
                if await self._wait_change(quiet):
                    idle, heard = 0, loop.time()
                    if d.replied and math.isfinite(asked_at):  # the first block since the request
                        sample = loop.time() - asked_at
                        rtt = sample if rtt is None else 0.8 * rtt + 0.2 * sample
                        asked_at = math.inf  # (one sample a request)
                    if progress is not None:
                        progress(d.received, d.size)
                    if not d.served():
                        continue  # the stretch asked for is still coming
                else:
                    idle += 1
                    if idle > RETRIES and loop.time() - heard >= GIVE_UP_S:
                        break
                self._ask(d, *d.next_stretch())
                asked_at = loop.time()
            if not d.complete():
                raise LogTransferError(
                    f"log {entry.id}: {d.received} of {d.size} bytes received; the rest never came", d.contiguous()
                )
            if progress is not None:
                progress(d.size, d.size)
            return bytes(d.data)
        finally:
            self._download = None
            self.link.send(mavlink.MAVLink_log_request_end_message(self.sysid, self.compid))

    def _ask(self, d: _Download, ofs: int, count: int) -> None:
        d.asked(ofs, count)
        self.link.send(mavlink.MAVLink_log_request_data_message(self.sysid, self.compid, d.id, ofs, count))

    async def erase(self) -> None:
        self.link.send(mavlink.MAVLink_log_erase_message(self.sysid, self.compid))


class _Download:
    """The blocks of one log as they come: 90 bytes at offsets that are multiples of 90. The vehicle
    serves one request at a time, in order (a new one replaces it), so the stretch asked for is done
    once its last block, or one past it, has come."""

    def __init__(self, log_id: int, size: int) -> None:
        self.id, self.size = log_id, size
        self.data = bytearray(size)
        self.blocks = (size + CHUNK - 1) // CHUNK
        self.have = bytearray(self.blocks)
        self.received = 0  # [bytes]
        self.refused = 0  # LOG_DATA that cannot be this log's (a bad offset or count)
        self._asked_end = 0  # [bytes] the end of the stretch asked for
        self._served = False
        self.replied = False  # a block has come since the last request (the round trip's end)

    def asked(self, ofs: int, count: int) -> None:
        self._asked_end = min(self.size, ofs + count)
        self._served = False
        self.replied = False

    def served(self) -> bool:
        return self._served

    def take(self, m) -> None:
        if int(m.id) != self.id:
            return
        ofs, count = int(m.ofs), int(m.count)
        if count == 0 or ofs >= self.size:
            self._served = True  # the vehicle's end of the log
            return
        if ofs % CHUNK or count > CHUNK or ofs + count > self.size or (count < CHUNK and ofs + count != self.size):
            self.refused += 1
            return
        self.replied = True
        if ofs + count >= self._asked_end:
            self._served = True
        k = ofs // CHUNK
        if self.have[k]:
            return
        self.data[ofs : ofs + count] = bytes(m.data[:count])
        self.have[k] = 1
        self.received += count

    def complete(self) -> bool:
        return self.received >= self.size

    def next_stretch(self) -> tuple[int, int]:
        """(offset, count) [bytes] from the first missing block on, through the missing blocks
        that follow it closer than :data:`MERGE_BLOCKS` (sent again rather than asked for apart)."""
        k = self.have.find(0)
        if k == -1:
            return self.size, 0
        end = k
        while True:
            got = self.have.find(1, end)
            if got == -1:
                end = self.blocks
                break
            nxt = self.have.find(0, got)
            if nxt == -1 or nxt - got > MERGE_BLOCKS:
                end = got
                break
            end = nxt
        return k * CHUNK, min(self.size, end * CHUNK) - k * CHUNK

    def contiguous(self) -> bytes:
        """The log up to its first missing block (what can be read of a log cut short)."""
        k = self.have.find(0)
        return bytes(self.data[: self.size if k == -1 else k * CHUNK])
