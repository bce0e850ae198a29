"""Bytes in, measurements out: the one MAVLink receive path.

Live links and replays both push bytes through a :class:`MavlinkReceiver`, so a
recording plays through exactly the code a live vehicle exercises. Framing and
CRC checking are pymavlink's (``parse_buffer`` with ``robust_parsing``, CRC in C
through ``fastcrc``); this module adds the per-link counters, the recording tap
and the raw-message hook.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundstation.measurement import Measurement

from .decode import MavlinkDecoder

# pymavlink gives both of these the base class's id (0, HEARTBEAT's), so they
# are told apart by class.
_BAD_DATA = mavlink.MAVLink_bad_data
_UNKNOWN = mavlink.MAVLink_unknown


@dataclass
class LinkCounters:
    """What a link has seen, for the dashboard and for tests."""

    bytes: int = 0
    messages: int = 0
    by_type: Counter = field(default_factory=Counter)
    crc_errors: int = 0
    bad_data: int = 0          # garbage bytes, bad prefixes, bad lengths (not CRC)
    unknown: int = 0           # message ids not in the dialect (CRC unverifiable)
    seq_lost: int = 0          # frames missing by sequence number
    mavlink1: int = 0
    mavlink2: int = 0
    dropped: int = 0           # measurements dropped because a consumer fell behind
    #: (sysid, compid) -> [frames received, frames lost by sequence number]
    per_source: dict = field(default_factory=dict)

    def loss_percent_of(self, sysid: int) -> float:
        """Loss of one system's frames (the vehicle's, not the radio's or the GCS's)."""
        rx = sum(v[0] for k, v in self.per_source.items() if k[0] == sysid)
        lost = sum(v[1] for k, v in self.per_source.items() if k[0] == sysid)
        return 100.0 * lost / (rx + lost) if rx + lost else 0.0

    @property
    def loss_percent(self) -> float:
        total = self.messages + self.seq_lost
        return 100.0 * self.seq_lost / total if total else 0.0

    def as_dict(self) -> dict:
        return {
            "bytes": self.bytes, "messages": self.messages, "crc_errors": self.crc_errors,
            "bad_data": self.bad_data, "unknown": self.unknown, "seq_lost": self.seq_lost,
            "loss_percent": round(self.loss_percent, 3), "mavlink1": self.mavlink1,
            "mavlink2": self.mavlink2, "dropped": self.dropped, "by_type": dict(self.by_type),
        }


class MavlinkReceiver:
    """Feed bytes with :meth:`feed`; get measurements back.

    ``on_frame(raw_frame_bytes, t_rx)`` sees every frame that passed its CRC
    (and unknown-id frames, whose CRC cannot be checked): the recorder uses it.
    ``on_message(msg, t_rx)`` is the raw-message hook: every decoded pymavlink
    message, including those no measurement comes from.
    """

    def __init__(self, link_name: str = "mav", *,
                 on_frame: Callable[[bytes, float], None] | None = None,
                 on_message: Callable[[object, float], None] | None = None) -> None:
        self.mav = mavlink.MAVLink(None)
        self.mav.robust_parsing = True
        self.decoder = MavlinkDecoder(link_name)
        self.counters = LinkCounters()
        self.on_frame = on_frame
        self.on_message = on_message
        self._last_seq: dict[tuple[int, int], int] = {}
        #: (sysid, compid) -> True if that peer speaks MAVLink 1 only so far
        self.peer_mavlink1: dict[tuple[int, int], bool] = {}

    def feed(self, data: bytes, t_rx: float) -> list[Measurement]:
        c = self.counters
        c.bytes += len(data)
        msgs = self.mav.parse_buffer(data)
        if not msgs:
            return []
        out: list[Measurement] = []
        decode = self.decoder.decode
        for m in msgs:
            cls = type(m)
            if cls is _BAD_DATA:
                if "CRC" in m.reason:
                    c.crc_errors += 1
                else:
                    c.bad_data += 1
                continue
            buf = m._msgbuf
            if cls is _UNKNOWN:
                c.unknown += 1
                c.by_type[m.get_type()] += 1
                self._track(buf, c)
                if self.on_frame is not None:
                    self.on_frame(bytes(buf), t_rx)
                if self.on_message is not None:
                    self.on_message(m, t_rx)
                continue
            c.messages += 1
            c.by_type[m._type] += 1
            self._track(buf, c)
            if self.on_frame is not None:
                self.on_frame(bytes(buf), t_rx)
            if self.on_message is not None:
                self.on_message(m, t_rx)
            out.extend(decode(m, t_rx))
        return out

    def _track(self, buf, c: LinkCounters) -> None:
        """Sequence-gap counting per (system, component), and protocol version."""
        if buf[0] == 0xFD:
            c.mavlink2 += 1
            seq, key = buf[4], (buf[5], buf[6])
            self.peer_mavlink1[key] = False
        else:
            c.mavlink1 += 1
            seq, key = buf[2], (buf[3], buf[4])
            self.peer_mavlink1.setdefault(key, True)
        stats = c.per_source.get(key)
        if stats is None:
            stats = c.per_source[key] = [0, 0]
        stats[0] += 1
        last = self._last_seq.get(key)
        if last is not None:
            gap = (seq - last - 1) & 0xFF
            # A gap of 255 is a duplicate/reordered frame, not 255 lost ones;
            # gaps above 128 are counted as restarts of the peer's counter.
            if gap < 128:
                c.seq_lost += gap
                stats[1] += gap
        self._last_seq[key] = seq
