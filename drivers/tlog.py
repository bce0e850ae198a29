"""The ``.tlog`` telemetry log, as MAVProxy and QGroundControl write it.

Each record is an 8-byte big-endian timestamp (microseconds since the UNIX
epoch, the receive time) followed by one raw MAVLink 1 or 2 frame. Files we
write open in MAVProxy, QGroundControl and pymavlink's ``mavlogfile``; theirs
open here.

:class:`TlogWriter` is crash-safe: it hands its buffer to the operating system
at least every ``flush_s`` (a SIGKILLed process then loses at most that much).
:class:`TlogIndex` scans a file once into arrays of record timestamps and
offsets, so a replay can seek by *time* (bisection on the timestamps), not by
byte fraction, which breaks across recording gaps. Corrupt stretches are
skipped by resynchronising on the next plausible record and counted; a
truncated last record is tolerated and reported.

The index maps the file rather than reading it: its bytes stay the kernel's page cache, and a
reader that has passed a stretch gives those pages back (:meth:`TlogIndex.release`), so that
a 1-hour log's 0.3 GB are not held in the process beside what is read from them.
"""

from __future__ import annotations

import mmap
import os
import struct
import time
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from pymavlink.generator.mavcrc import x25crc


def mcrf4xx(b: bytes) -> int:
    return x25crc(b).crc


_TS = struct.Struct(">Q")
#: Timestamps outside 2000-01-01 .. 2100-01-01 cannot be a tlog's.
_TS_MIN_US = 946_684_800_000_000
_TS_MAX_US = 4_102_444_800_000_000
#: A resynchronised record must lie within this of the last good timestamp.
_RESYNC_WINDOW_US = 86_400_000_000


class TlogError(ValueError):
    """The file is not a readable tlog (one-line message naming file and offset)."""


class TlogWriter:
    """Append-only tlog writer, flushed to the OS at least every ``flush_s``.

    A write error (a full disk, a file over the size limit, a device pulled) stops the recording,
    never its caller: it writes inside a live link's receive path, and telemetry, estimation and
    the dashboard must go on. :attr:`error` then says why, in one line, and ``on_error`` is
    called with it once; what was written before stays in the file.
    """

    def __init__(
        self, path: str | os.PathLike, flush_s: float = 0.5, on_error: Callable[[str], None] | None = None
    ) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f: BinaryIO | None = open(self.path, "ab", buffering=1 << 16)
        self.flush_s = flush_s
        self._last_flush = time.monotonic()
        self.records = 0
        self.error: str | None = None
        self.on_error = on_error

    def write(self, frame: bytes, t_unix: float) -> None:
        f = self._f
        if f is None:
            return
        try:
            f.write(_TS.pack(int(t_unix * 1e6)) + frame)  # one write: a record is whole or absent
            self.records += 1
            now = time.monotonic()
            if now - self._last_flush >= self.flush_s:
                f.flush()
                self._last_flush = now
        except (OSError, ValueError, OverflowError) as e:
            self._stop(e)

    def flush(self) -> None:
        """Hand buffered records to the OS (called by a timer while idle, too)."""
        if self._f is not None:
            try:
                self._f.flush()
            except OSError as e:
                self._stop(e)
            self._last_flush = time.monotonic()

    def _stop(self, e: Exception) -> None:
        """Stop recording after a write error: close what can be closed, say why once."""
        f, self._f = self._f, None
        if f is not None:
            try:
                f.close()
            except OSError:
                pass  # the buffer's last records cannot be written either
        reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        self.error = f"recording to {self.path} stopped after {self.records} records: {reason}"
        if self.on_error is not None:
            self.on_error(self.error)

    def close(self) -> None:
        if self._f is not None:
            try:
                self._f.flush()
                os.fsync(self._f.fileno())
                self._f.close()
            except OSError as e:
                self._stop(e)
            self._f = None

    @property
    def closed(self) -> bool:
        return self._f is None


def _mapped(p: Path) -> bytes | mmap.mmap:
    """The file's bytes, mapped read-only (an empty file: ``b""``, which cannot be mapped); a
    one-line :class:`TlogError` if it cannot be read."""
    try:
        with open(p, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
    except (OSError, ValueError) as e:
        raise TlogError(f"{p}: cannot read: {getattr(e, 'strerror', None) or e}") from None


def _frame_length(data, pos: int) -> int:
    """Length of the MAVLink frame starting at ``pos`` (0 if no frame starts there)."""
    if pos + 3 > len(data):
        return 0 if pos >= len(data) or data[pos] not in (0xFD, 0xFE) else 10**9  # cut short: truncated
    magic = data[pos]
    if magic == 0xFE:
        return 8 + data[pos + 1]
    if magic == 0xFD:
        return 12 + data[pos + 1] + (13 if data[pos + 2] & 0x01 else 0)
    return 0


@dataclass
class TlogIndex:
    """Record timestamps and offsets of one tlog file, and what was skipped."""

    path: Path
    data: bytes | mmap.mmap  # the file, mapped read-only (bytes for an empty one)
    t: np.ndarray  # receive time of each record [s since epoch]
    offset: np.ndarray  # byte offset of each record's timestamp
    length: np.ndarray  # frame length of each record
    skipped: list[tuple[int, int]] = field(default_factory=list)  # (offset, bytes) resynced over
    truncated_at: int | None = None  # offset of an incomplete last record
    clock_steps: list[int] = field(default_factory=list)  # offsets where the recorder's clock stepped
    mended_times: int = 0  # records whose lone damaged timestamp was given the one before's

    def __len__(self) -> int:
        return len(self.t)

    @property
    def start(self) -> float:
        return float(self.t[0]) if len(self.t) else 0.0

    @property
    def duration(self) -> float:
        return float(self._t_mono[-1] - self.t[0]) if len(self.t) else 0.0

    @property
    def _t_mono(self) -> np.ndarray:
        # The recorder's clock may step back; seeking uses the running maximum.
        return np.maximum.accumulate(self.t)

    def seek(self, t_rel: float) -> int:
        """Index of the first record at or after ``t_rel`` seconds into the file."""
        return int(np.searchsorted(self._t_mono, self.start + t_rel, side="left"))

    def frame(self, i: int) -> bytes:
        o = int(self.offset[i]) + 8
        return self.data[o : o + int(self.length[i])]

    def release(self, end: int | None = None) -> None:
        """Give the mapped file's pages before byte ``end`` (all by default) back to the page
        cache: a reader calls it once it has passed them. Read again, they are mapped again."""
        data = self.data
        if not isinstance(data, mmap.mmap):
            return
        stop = len(data) if end is None else min(int(end), len(data))
        stop -= stop % mmap.PAGESIZE  # whole pages
        if stop > 0:
            data.madvise(mmap.MADV_DONTNEED, 0, stop)

    @classmethod
    def scan(cls, path: str | os.PathLike) -> TlogIndex:
        p = Path(path)
        data = _mapped(p)
        n = len(data)
        # typed arrays, not lists: 8 bytes a record instead of a Python int's 36 (a 1-hour 1 kHz log
        # has 4 million records)
        ts_list = array("q")
        off_list = array("q")
        len_list = array("q")
        skipped: list[tuple[int, int]] = []
        truncated_at = None
        clock_steps: list[int] = []
        unpack = _TS.unpack_from
        pos = 0
        last_ts = None
        while pos + 9 <= n:
            ts = unpack(data, pos)[0]
            if pos + 11 <= n and last_ts is not None and abs(ts - last_ts) <= _RESYNC_WINDOW_US:
                # Fast path (nearly every record): a frame follows, and so does the next record.
                magic = data[pos + 8]
                flen = (
                    8 + data[pos + 9]
                    if magic == 0xFE
                    else 12 + data[pos + 9] + (13 if data[pos + 10] & 0x01 else 0)
                    if magic == 0xFD
                    else 0
                )
                nxt = pos + 8 + flen
                if flen and nxt + 11 <= n:
                    nm = data[nxt + 8]
                    if (nm == 0xFE or nm == 0xFD) and abs(unpack(data, nxt)[0] - ts) <= _RESYNC_WINDOW_US:
                        ts_list.append(ts)
                        off_list.append(pos)
                        len_list.append(flen)
                        last_ts = ts
                        pos = nxt
                        continue
            flen = _frame_length(data, pos + 8)
            ok = flen and _TS_MIN_US <= ts <= _TS_MAX_US and (last_ts is None or abs(ts - last_ts) <= _RESYNC_WINDOW_US)
            if ok and pos + 8 + flen > n:
                truncated_at = pos
                break
            if ok:
                # A record is trusted when the next one also looks like a record
                # (guards against a corrupted length byte) or the file ends here.
                nxt = pos + 8 + flen
                if nxt + 9 <= n:
                    nts = unpack(data, nxt)[0]
                    ok = (_frame_length(data, nxt + 8) and abs(nts - ts) <= _RESYNC_WINDOW_US) or _frame_crc_ok(
                        data, pos + 8, flen
                    )  # damage follows a good frame
                elif nxt != n:
                    ok = nxt + 8 >= n  # trailing partial timestamp: truncated next record
                    if ok:
                        truncated_at = nxt
            if ok:
                ts_list.append(ts)
                off_list.append(pos)
                len_list.append(flen)
                last_ts = ts
                pos += 8 + flen
                if truncated_at is not None:
                    break
                continue
            if not ts_list and pos > 4096:
                raise TlogError(f"{p}: not a MAVLink tlog (no valid record in the first 4096 bytes)")
            start = pos
            pos = _resync(data, pos + 1, last_ts)
            if pos < 0:
                if not ts_list:
                    raise TlogError(f"{p}: not a MAVLink tlog (no valid record found)")
                skipped.append((start, n - start))
                pos = n
                break
            if last_ts is not None and abs(unpack(data, pos)[0] - last_ts) > _RESYNC_WINDOW_US:
                last_ts = None  # the recorder's clock stepped: a new segment starts here
                clock_steps.append(pos)
            if pos > start:
                skipped.append((start, pos - start))
        else:
            if 0 < n - pos < 9 and ts_list:
                truncated_at = pos
        if not ts_list:
            raise TlogError(f"{p}: not a MAVLink tlog (no valid record found)")
        t = np.frombuffer(ts_list, dtype=np.int64) * 1e-6
        mended = _mend_lone_times(t)
        offsets = np.frombuffer(off_list, dtype=np.int64)
        for step in clock_steps:
            # the recording goes on where it left off: the step itself is not time that passed
            i = int(np.searchsorted(offsets, step))
            if 0 < i < len(t):
                t[i:] -= t[i] - t[i - 1]
        index = cls(
            p,
            data,
            t,
            offsets,
            np.frombuffer(len_list, dtype=np.int64),
            skipped,
            truncated_at,
            clock_steps,
            mended,
        )
        index.release()  # scanned: the pages are the page cache's again
        return index


#: [s] a record this far from both its neighbours, while they agree, has a damaged timestamp
_LONE_TIME_S = 10.0


def _mend_lone_times(t: np.ndarray) -> int:
    """Give each record whose timestamp alone is far from both neighbours' (a bit flipped in it,
    within the day a resync trusts) the time of the record before it, in place; returns how many.
    Left as it was, one such record 1.2 hours ahead made a 28 s log last 72 minutes, and seeking
    in it wrong. A run of two or more is left alone: that is a recorder's clock, not one record."""
    if len(t) < 3:
        return 0
    far = _LONE_TIME_S
    lone = np.flatnonzero(
        (np.abs(t[1:-1] - t[:-2]) > far) & (np.abs(t[2:] - t[1:-1]) > far) & (np.abs(t[2:] - t[:-2]) <= far)
    )
    t[lone + 1] = t[lone]
    return len(lone)


def _frame_crc_ok(data: bytes | mmap.mmap, pos: int, flen: int) -> bool:
    """True if the frame at ``pos`` is a known message whose CRC checks out."""
    if data[pos] == 0xFE:
        hlen, msgid = 6, data[pos + 5]
    else:
        hlen, msgid = 10, data[pos + 7] | data[pos + 8] << 8 | data[pos + 9] << 16
    cls = mavlink.mavlink_map.get(msgid)
    plen = data[pos + 1]
    if cls is None or pos + hlen + plen + 2 > len(data):
        return False
    crc = mcrf4xx(bytes(data[pos + 1 : pos + hlen + plen]) + bytes([cls.crc_extra]))
    return crc == (data[pos + hlen + plen] | data[pos + hlen + plen + 1] << 8)


def _resync(data: bytes | mmap.mmap, pos: int, last_ts: int | None) -> int:
    """Next offset >= pos where a plausible record starts, or -1.

    A plausible record has a timestamp within a day of the last one; or, where the recorder's clock
    stepped (set by hand, a GPS fix after boot), a checked frame followed by another record within
    a day of it: the rest of the file is a new segment, not damage. Each magic byte's next offset is
    searched for once and kept until passed, so a long run of candidates (a stretch of 0xFD bytes)
    costs one pass, not one search per byte."""
    n = len(data)
    unpack = _TS.unpack_from
    next_fe = next_fd = -2
    while True:
        # the next magic byte 8 bytes after a candidate record start
        if next_fe != -1 and next_fe < pos + 8:
            next_fe = data.find(b"\xfe", pos + 8)
        if next_fd != -1 and next_fd < pos + 8:
            next_fd = data.find(b"\xfd", pos + 8)
        cand = min(x for x in (next_fe, next_fd, n) if x >= 0)
        if cand >= n:
            return -1
        start = cand - 8
        ts = unpack(data, start)[0]
        if _TS_MIN_US <= ts <= _TS_MAX_US:
            if last_ts is None or abs(ts - last_ts) <= _RESYNC_WINDOW_US or _starts_segment(data, start, ts):
                return start
        pos = start + 1


def _starts_segment(data: bytes | mmap.mmap, start: int, ts: int) -> bool:
    """A record at ``start`` whose frame checks out and which is followed by another record within a
    day of it: a new stretch of recording after the recorder's clock stepped."""
    flen = _frame_length(data, start + 8)
    nxt = start + 8 + flen
    if not flen or nxt + 9 > len(data) or not _frame_crc_ok(data, start + 8, flen):
        return False
    return bool(_frame_length(data, nxt + 8)) and abs(_TS.unpack_from(data, nxt)[0] - ts) <= _RESYNC_WINDOW_US
