"""Bytes in, measurements out: the one MAVLink receive path.

Live links and replays both push bytes through a :class:`MavlinkReceiver`, so a
recording plays through exactly the code a live vehicle exercises. Framing and
CRC checking are done by :mod:`drivers.mavlink.framing` on pymavlink's message
definitions; this module adds the per-link counters, the recording tap and the
raw-message hook.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundstation.core.measurement import Measurement

from .decode import MavlinkDecoder
from .framing import Framer

_UNKNOWN = mavlink.MAVLink_unknown

#: what a message that passed its CRC but makes no sense raises in the decoder
_UNDECODABLE = (AttributeError, ValueError, TypeError, IndexError, OverflowError, ZeroDivisionError)
#: the largest sequence gap counted as lost frames; larger ones are a frame up to 15 places late
MAX_LOSS_GAP = 240
#: a sender silent this long [s] may have restarted its sequence counter
SILENCE_S = 2.0
#: a gap ending below this sequence number may be a restarted sender's counter starting over
RESET_SEQ = 32


@dataclass
class LinkCounters:
    """What a link has seen, for the dashboard and for tests."""

    bytes: int = 0
    messages: int = 0
    by_type: Counter = field(default_factory=Counter)
    crc_errors: int = 0
    bad_data: int = 0  # stretches of garbage before a start marker, bad headers
    unknown: int = 0  # message ids not in the dialect (CRC unverifiable)
    seq_lost: int = 0  # frames missing by sequence number (vehicle, radio and this machine's kernel)
    mavlink1: int = 0
    mavlink2: int = 0
    dropped: int = 0  # measurements dropped because a consumer fell behind
    kernel_dropped: int = 0  # datagrams this machine's kernel dropped on a full socket buffer (Linux)
    sink_errors: int = 0  # batches a synchronous consumer raised on (the link went on)
    undecodable: int = 0  # messages that passed their CRC but could not be converted (skipped)
    signature_refused: int = 0  # frames refused by MAVLink 2 signing (unsigned, another key, replayed)
    restarts: int = 0  # vehicles seen to restart (their clock went back): a new flight segment each
    last_undecodable: str = ""
    #: (sysid, compid) -> [frames received, frames lost by sequence number]
    per_source: dict = field(default_factory=dict)

    def loss_percent_of(self, sysid: int) -> float:
        """Loss of one system's frames (the vehicle's, not the radio's or the GCS's)."""
        rx = sum(v[0] for k, v in self.per_source.items() if k[0] == sysid)
        lost = sum(v[1] for k, v in self.per_source.items() if k[0] == sysid)
        return 100.0 * lost / (rx + lost) if rx + lost else 0.0

    @property
    def lost(self) -> int:
        """Frames lost, at least: by sequence numbers (anywhere on the way, but blind to a burst of
        more than 240) or by this machine's kernel count (exact, for its own drops), the larger."""
        return max(self.seq_lost, self.kernel_dropped)

    @property
    def loss_percent(self) -> float:
        total = self.messages + self.lost
        return 100.0 * self.lost / total if total else 0.0

    def as_dict(self) -> dict:
        return {
            "bytes": self.bytes,
            "messages": self.messages,
            "crc_errors": self.crc_errors,
            "bad_data": self.bad_data,
            "unknown": self.unknown,
            "seq_lost": self.seq_lost,
            "restarts": self.restarts,
            "loss_percent": round(self.loss_percent, 3),
            "mavlink1": self.mavlink1,
            "mavlink2": self.mavlink2,
            "dropped": self.dropped,
            "kernel_dropped": self.kernel_dropped,
            "by_type": dict(self.by_type),
        }


class MavlinkReceiver:
    """Feed bytes with :meth:`feed`; get measurements back.

    ``on_frame(raw_frame_bytes, t_rx)`` sees every frame that passed its CRC
    (and unknown-id frames, whose CRC cannot be checked): the recorder uses it.
    ``on_message(msg, t_rx)`` is the raw-message hook: every pymavlink message
    object, i.e. every message *not* on the framer's fast sensor path (which
    yields measurements instead), unknown ids included.
    """

    def __init__(
        self,
        link_name: str = "mav",
        *,
        on_frame: Callable[[bytes, float], None] | None = None,
        on_message: Callable[[object, float], None] | None = None,
    ) -> None:
        self.decoder = MavlinkDecoder(link_name)
        self.decoder.on_restart = self._restarted
        self.counters = LinkCounters()
        self.on_frame = on_frame
        self.on_message = on_message
        #: sysid << 8 | compid -> [its per_source counts, last sequence number (-1: none), its time,
        #: MAVLink 1 only so far]
        self._senders: dict[int, list] = {}
        #: (sysid, compid) -> a gap counted as loss where the sequence started over near 0: a
        #: restart's, if the sender's clock turns out to have gone back too (:meth:`_restarted`)
        self._reset_gap: dict[tuple[int, int], int] = {}
        #: (sysid, compid) -> True if that peer speaks MAVLink 1 only so far
        self.peer_mavlink1: dict[tuple[int, int], bool] = {}
        self._framer = Framer(self._fast, self._object, self._crc_error, self._garbage)
        self._framer.on_refused = self._refused
        self._convert_into = self.decoder.convert_into
        self._out: list[Measurement] = []
        self._names: list[str] = []  # the types of one read's messages, counted at its end
        self._t_rx = 0.0

    def require_signing(self, check) -> None:
        """Refuse every frame that ``check`` (a :class:`~drivers.mavlink.signing.SignatureCheck`) refuses."""
        self._framer.signing = check

    def _refused(self) -> None:
        self.counters.signature_refused += 1

    def reset(self) -> None:
        """Drop a partial frame and the sequence history (a replay seeking
        elsewhere: the jump in sequence numbers is not loss)."""
        self._framer.reset()
        for sender in self._senders.values():
            sender[1] = -1

    def idle_for(self, sysids: Iterable[int]) -> bool:
        """No partial frame waits for more bytes, and no untimed message of these systems for its
        clock: a timed message of theirs would change nothing here but that clock. (``sysids`` is
        read only while some system waits, which is seldom.)"""
        if self._framer.pending:
            return False
        dec = self.decoder
        return not dec.waiting or not any(dec.waiting_for(int(s)) for s in set(sysids))

    def feed(self, data: bytes, t_rx: float) -> list[Measurement]:
        c = self.counters
        c.bytes += len(data)
        self._t_rx = t_rx
        out = self._out = []
        names = self._names = []
        v1 = c.mavlink1
        try:
            self._framer.feed(data)
        finally:
            # counted once a read, not once a message (a C loop over the names)
            c.messages += len(names)
            c.mavlink2 += len(names) - (c.mavlink1 - v1)
            c.by_type.update(names)
        return out

    # -- framer callbacks ------------------------------------------------------------
    def _fast(self, spec, m, sysid, compid, seq, frame) -> None:
        self._names.append(spec.name)
        self._track(frame[0], seq, sysid, compid)
        if self.on_frame is not None:
            self.on_frame(frame, self._t_rx)
        try:
            self._convert_into(self._out, spec.cls, m, sysid, compid, self._t_rx)
        except _UNDECODABLE as e:
            self._undecodable(spec.cls, e)

    def _object(self, m, sysid, compid, seq, frame) -> None:
        if type(m) is _UNKNOWN:
            # an id this dialect does not know: its CRC cannot be checked, so its header says nothing
            # either (no sequence, no sign of life); recorded and passed on as it came
            self.counters.unknown += 1
            self.counters.by_type["UNKNOWN"] += 1  # one key: 600,000 distinct ids had grown the counter by 55 MB
            if self.on_frame is not None:
                self.on_frame(frame, self._t_rx)
            if self.on_message is not None:
                self.on_message(m, self._t_rx)
            return
        self._names.append(m.get_type())
        self._track(frame[0], seq, sysid, compid)
        if self.on_frame is not None:
            self.on_frame(frame, self._t_rx)
        if self.on_message is not None:
            self.on_message(m, self._t_rx)
        try:
            self._convert_into(self._out, type(m), m, sysid, compid, self._t_rx)
        except _UNDECODABLE as e:
            self._undecodable(type(m), e)

    def _undecodable(self, cls, e: Exception) -> None:
        """A message the decoder cannot convert (field values that pass the CRC but no sense: a
        channel count past its fields) is counted and skipped."""
        self.counters.undecodable += 1
        self.counters.last_undecodable = f"{cls.msgname}: {e}"

    def _crc_error(self) -> None:
        self.counters.crc_errors += 1

    def _garbage(self) -> None:
        self.counters.bad_data += 1

    def _track(self, magic: int, seq: int, sysid: int, compid: int) -> None:
        """Sequence-gap counting per (system, component), and protocol version.

        A frame 1..15 places behind the last (a gap of 241..255) was reordered or duplicated: no
        loss. Any shorter gap is loss, up to 240 frames at once (a busy link loses hundreds in one
        burst, so a gap over 128 is loss, not a restart of the sender's counter). After more
        than :data:`SILENCE_S` without a frame from that sender the gap says nothing (a reboot
        restarts the counter; an outage loses more than 256 frames): the link's state reports it.
        """
        sender = self._senders.get(sysid << 8 | compid)
        if sender is None:
            self._first_frame(magic, seq, sysid, compid)
            return
        sender[0][0] += 1
        if magic != 0xFD:
            self.counters.mavlink1 += 1
        elif sender[3]:
            sender[3] = self.peer_mavlink1[(sysid, compid)] = False
        last, t_last = sender[1], sender[2]
        t = sender[2] = self._t_rx
        sender[1] = seq
        if seq >= RESET_SEQ and self._reset_gap:
            self._reset_gap.pop((sysid, compid), None)  # well past a start of the counter: that gap was loss
        if last < 0 or t - t_last > SILENCE_S:  # (unknown receive times, NaN: every gap counts)
            return
        gap = (seq - last - 1) & 0xFF
        if gap and gap <= MAX_LOSS_GAP:
            self.counters.seq_lost += gap
            sender[0][1] += gap
            if seq < RESET_SEQ:
                self._reset_gap[(sysid, compid)] = gap

    def _first_frame(self, magic: int, seq: int, sysid: int, compid: int) -> None:
        """A sender heard for the first time: its counts and its sequence start here."""
        key = (sysid, compid)
        stats = self.counters.per_source[key] = [1, 0]
        self.peer_mavlink1[key] = magic != 0xFD
        self._senders[sysid << 8 | compid] = [stats, seq, self._t_rx, magic != 0xFD]
        if magic != 0xFD:
            self.counters.mavlink1 += 1

    def _restarted(self, sysid: int) -> None:
        """A vehicle's clock went back: it restarted, and its sequence numbers started over. The
        gap that start made is not loss; the restart is counted instead."""
        self.counters.restarts += 1
        for key in [k for k in self._reset_gap if k[0] == sysid]:
            gap = self._reset_gap.pop(key)
            self.counters.seq_lost -= gap
            self.counters.per_source[key][1] -= gap
