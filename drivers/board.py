"""Serial sensor boards: the binary frame protocol and NMEA-0183 GPS receivers.

Both receivers take bytes as they come off the serial line (any chunking) and
return :class:`Measurement` records; damage is counted, never fatal.
:class:`BoardLink` runs either on a serial device through pyserial (reconnecting
when the device returns) as an ``async for`` stream, like the MAVLink link.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import math
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from drivers import board_protocol as bp
from groundstation.core.broadcast import Broadcast, Subscription
from groundstation.core.measurement import Kind, Measurement

from .connection import Endpoint, parse_connection
from .link_state import LinkEvent, LinkState
from .transports import Transport, open_transport


@dataclass
class BoardCounters:
    bytes: int = 0
    frames: int = 0
    by_type: Counter = field(default_factory=Counter)
    crc_errors: int = 0
    garbage_bytes: int = 0
    unknown: int = 0  # unknown version or message id
    seq_lost: int = 0
    no_fix: int = 0  # NMEA fixes marked invalid (counted, not passed on)


class BinaryBoardReceiver:
    """The binary frame protocol of :mod:`drivers.board_protocol` -> measurements."""

    def __init__(self, name: str = "board") -> None:
        self.source = name
        self.counters = BoardCounters()
        self._buf = b""
        self._last_seq: int | None = None
        self._t_last_raw: int | None = None
        self._t_wraps = 0

    def _time(self, t_us: int) -> float:
        """Unwrap the board's uint32 microsecond clock."""
        if self._t_last_raw is not None and t_us < self._t_last_raw - (1 << 31):
            self._t_wraps += 1
        self._t_last_raw = t_us
        return (t_us + (self._t_wraps << 32)) * 1e-6

    def feed(self, data: bytes, t_rx: float) -> list[Measurement]:
        c = self.counters
        c.bytes += len(data)
        buf = self._buf + data
        out: list[Measurement] = []
        pos, n = 0, len(buf)
        while True:
            i = buf.find(bp.SYNC, pos)
            if i < 0:
                keep = 1 if buf.endswith(bp.SYNC[:1]) else 0
                c.garbage_bytes += n - pos - keep
                pos = n - keep
                break
            c.garbage_bytes += i - pos
            pos = i
            if n - pos < 6:
                break
            ver, mid, seq, plen = buf[pos + 2], buf[pos + 3], buf[pos + 4], buf[pos + 5]
            if plen > bp.MAX_PAYLOAD:
                c.garbage_bytes += 1
                pos += 1
                continue
            end = pos + 6 + plen + 2
            if end > n:
                break
            crc = buf[end - 2] | buf[end - 1] << 8
            if bp.crc16_ccitt(buf[pos + 2 : end - 2]) != crc:
                c.crc_errors += 1
                pos += 1  # the length byte itself may be what was damaged
                continue
            if self._last_seq is not None:
                gap = (seq - self._last_seq - 1) & 0xFF
                if gap < 128:
                    c.seq_lost += gap
            self._last_seq = seq
            spec = bp.PAYLOADS.get(mid)
            if ver != bp.VERSION or spec is None or plen != spec[1].size:
                c.unknown += 1
                pos = end
                continue
            c.frames += 1
            c.by_type[spec[0]] += 1
            self._decode(mid, spec[1].unpack(buf[pos + 6 : end - 2]), t_rx, out)
            pos = end
        self._buf = buf[pos:]
        return out

    def _decode(self, mid: int, v: tuple, t_rx: float, out: list) -> None:
        t = self._time(v[0])
        s = self.source
        if mid == bp.IMU:
            out.append(Measurement(t, Kind.ACCEL, np.array(v[1:4]), s, t_rx))
            out.append(Measurement(t, Kind.GYRO, np.array(v[4:7]), s, t_rx))
        elif mid == bp.BARO:
            out.append(Measurement(t, Kind.BARO_PRESSURE, np.array([v[1]]), s, t_rx))
            out.append(Measurement(t, Kind.TEMPERATURE, np.array([v[2]]), s, t_rx))
        elif mid == bp.RANGE:
            if v[2] == 0:
                out.append(Measurement(t, Kind.RANGE, np.array([v[1]]), s, t_rx))
        elif mid == bp.ENCODERS:
            cpr = v[4] or 1
            out.append(Measurement(t, Kind.ENCODERS, np.array(v[1:4], dtype=float) * (2 * math.pi / cpr), s, t_rx))
        elif mid == bp.POWER:
            out.append(Measurement(t, Kind.BATTERY_VOLTAGE, np.array([v[1]]), s, t_rx))
            out.append(Measurement(t, Kind.BATTERY_CURRENT, np.array([v[2]]), s, t_rx))
        elif mid == bp.MOTORS:
            out.append(Measurement(t, Kind.MOTOR_VOLTAGE, np.array(v[1:3]), s, t_rx))


_KNOTS = 0.514444


class NmeaReceiver:
    """NMEA-0183 GGA (position, altitude) and RMC (speed, course, date) -> measurements.

    Vehicle time for a GPS receiver is its UTC time (UNIX seconds): the date
    from the last RMC, or from the receive clock until one has arrived.
    GGA: ``GPS`` [lat, lon, alt MSL] with the variance of ``(hdop * uere)^2``
    (uere = 2.5 m) in the value's units. RMC: ``VELOCITY_NED`` [vn, ve, nan]
    from speed over ground and course (NMEA has no vertical speed).
    """

    UERE = 2.5

    def __init__(self, name: str = "gps") -> None:
        self.source = name
        self.counters = BoardCounters()
        self._buf = b""
        self._date: dt.date | None = None

    def feed(self, data: bytes, t_rx: float) -> list[Measurement]:
        c = self.counters
        c.bytes += len(data)
        buf = self._buf + data
        out: list[Measurement] = []
        while True:
            start = buf.find(b"$")
            if start < 0:
                c.garbage_bytes += len(buf)
                buf = b""
                break
            c.garbage_bytes += start
            end = buf.find(b"\n", start)
            if end < 0:
                if len(buf) - start > 100:  # NMEA lines are at most 82 characters
                    c.garbage_bytes += len(buf) - start
                    buf = b""
                else:
                    buf = buf[start:]
                break
            line = buf[start:end].strip()
            buf = buf[end + 1 :]
            self._line(line, t_rx, out)
        self._buf = buf
        return out

    def _line(self, line: bytes, t_rx: float, out: list) -> None:
        c = self.counters
        body, star, cs = line[1:].partition(b"*")
        try:
            text = body.decode("ascii")
            ok = star and int(cs[:2], 16) == _xor(body)
        except (UnicodeDecodeError, ValueError):
            ok = False
        if not ok:
            c.crc_errors += 1
            return
        f = text.split(",")
        kind = f[0][2:]
        try:
            if kind == "GGA":
                self._gga(f, t_rx, out)
            elif kind == "RMC":
                self._rmc(f, t_rx, out)
            else:
                c.unknown += 1
                return
        except (ValueError, IndexError):
            c.crc_errors += 1
            return
        c.frames += 1
        c.by_type[kind] += 1

    def _utc(self, hhmmss: str, t_rx: float) -> float:
        date = self._date or dt.datetime.fromtimestamp(t_rx, dt.UTC).date()
        h, m, s = int(hhmmss[0:2]), int(hhmmss[2:4]), float(hhmmss[4:])
        t = dt.datetime(date.year, date.month, date.day, tzinfo=dt.UTC).timestamp() + h * 3600 + m * 60 + s
        if self._date is None and t - t_rx > 43200:  # receive clock past midnight, GPS not yet
            t -= 86400
        return t

    def _gga(self, f, t_rx, out):
        if f[6] in ("", "0"):  # no fix
            self.counters.no_fix += 1
            return
        lat, lon = _deg(f[2], f[3]), _deg(f[4], f[5])
        alt = float(f[9])
        hdop = float(f[8]) if f[8] else 1.0
        s_m = hdop * self.UERE
        s_deg = s_m / 111_320.0
        var = np.array([s_deg**2, (s_deg / max(math.cos(math.radians(lat)), 1e-6)) ** 2, (1.5 * s_m) ** 2])
        out.append(Measurement(self._utc(f[1], t_rx), Kind.GPS, np.array([lat, lon, alt]), self.source, t_rx, var))

    def _rmc(self, f, t_rx, out):
        if f[9]:
            d = f[9]
            yy = int(d[4:6])  # two-digit year: 80-99 are the 1900s (NMEA's own convention)
            self._date = dt.date((1900 if yy >= 80 else 2000) + yy, int(d[2:4]), int(d[0:2]))
        if f[2] != "A":
            return
        sog = float(f[7] or 0) * _KNOTS
        cog = math.radians(float(f[8] or 0))
        out.append(
            Measurement(
                self._utc(f[1], t_rx),
                Kind.VELOCITY_NED,
                np.array([sog * math.cos(cog), sog * math.sin(cog), math.nan]),
                self.source,
                t_rx,
            )
        )


def _xor(body: bytes) -> int:
    x = 0
    for b in body:
        x ^= b
    return x


def _deg(value: str, hemi: str) -> float:
    """NMEA ddmm.mmmm / dddmm.mmmm to signed degrees."""
    dot = value.index(".")
    deg = float(value[: dot - 2]) + float(value[dot - 2 :]) / 60.0
    return -deg if hemi in ("S", "W") else deg


class BoardLink:
    """A sensor board on a serial port: ``async for m in board.measurements()``.

    ``protocol`` is ``"binary"`` or ``"nmea"``. Reconnects when the device
    returns; ``lost_after`` seconds without a valid frame make it lost.
    """

    def __init__(
        self, url: str | Endpoint, protocol: str = "binary", *, name: str | None = None, lost_after: float = 1.0
    ) -> None:
        self.endpoint = url if isinstance(url, Endpoint) else parse_connection(url)
        if protocol not in ("binary", "nmea"):
            raise ValueError(f"unknown board protocol {protocol!r}; use binary or nmea")
        self.receiver = (BinaryBoardReceiver if protocol == "binary" else NmeaReceiver)(name or protocol)
        self.lost_after = lost_after
        self.transport: Transport | None = None
        self.state = LinkState.CLOSED
        self._measurements: Broadcast[Measurement] = Broadcast(100_000)
        self._events: Broadcast[LinkEvent] = Broadcast(1000)
        self._last_valid = 0.0
        self._watchdog: asyncio.Task | None = None

    @property
    def counters(self) -> BoardCounters:
        return self.receiver.counters

    def measurements(self, maxlen: int | None = None) -> Subscription[Measurement]:
        return self._measurements.subscribe(maxlen)

    def events(self) -> Subscription[LinkEvent]:
        return self._events.subscribe()

    def send(self, data: bytes) -> None:
        if self.transport is not None:
            self.transport.send(data)

    def _set(self, state: LinkState, reason: str) -> None:
        if state is not self.state:
            self.state = state
            self._events.publish(LinkEvent(state, time.time(), reason))

    def _data(self, data: bytes, t_rx: float) -> None:
        before = self.counters.frames
        out = self.receiver.feed(data, t_rx)
        if self.counters.frames != before:
            self._last_valid = time.monotonic()
            self._set(LinkState.ALIVE, "valid frame received")
        if out:
            self._measurements.publish_many(out)

    async def open(self) -> None:
        tr = open_transport(self.endpoint)
        tr.on_data = self._data
        tr.on_disconnect = lambda reason: self._set(LinkState.LOST, reason)
        tr.on_connect = lambda reason: self._set(LinkState.CONNECTING, reason)
        await tr.open()
        self.transport = tr
        self._set(LinkState.CONNECTING, f"opened {self.endpoint}")
        self._watchdog = asyncio.get_running_loop().create_task(self._watch())

    async def _watch(self) -> None:
        while True:
            await asyncio.sleep(self.lost_after / 5)
            if self.state is LinkState.ALIVE and time.monotonic() - self._last_valid > self.lost_after:
                self._set(LinkState.LOST, f"no valid frame for {self.lost_after:g} s")

    async def close(self) -> None:
        if self._watchdog is not None:
            self._watchdog.cancel()
        if self.transport is not None:
            await self.transport.close()
        self._set(LinkState.CLOSED, "closed")
        self._measurements.close()
        self._events.close()
