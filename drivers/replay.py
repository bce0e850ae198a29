"""Play a recorded ``.tlog`` through the same receive path as a live link.

Each recorded frame is fed to a :class:`~drivers.mavlink.receiver.MavlinkReceiver`
with its recorded receive time, exactly as the live link feeds the bytes it
reads, so decoding, counters, vehicle-time alignment and everything downstream
are the live code.

Controls: ``speed`` from 0.1x to 100x or ``math.inf`` (as fast as the
consumers take it, lossless), :meth:`pause`/:meth:`resume`, :meth:`seek` to a
time (bisection on the recording's time index, so gaps in the recording do not
distort it), and ``loop``.

Logs of other formats (DataFlash, Crazyflie) are decoded whole by their
readers; ``Replay(path, measurements=...)`` paces those records by their
vehicle time with the same controls.
"""

from __future__ import annotations

import asyncio
import enum
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from groundstation.core.broadcast import Broadcast, Subscription
from groundstation.core.measurement import Measurement

from .mavlink.receiver import LinkCounters, MavlinkReceiver
from .speed import check_speed
from .tlog import TlogIndex

#: the mapped file's pages behind the playhead are given back every 65,536 records (``TlogIndex.release``)
_RELEASE_MASK = (1 << 16) - 1


class ReplayState(enum.Enum):
    PLAYING = "playing"
    PAUSED = "paused"
    ENDED = "ended"


@dataclass(frozen=True)
class ReplayStatus:
    state: ReplayState
    position: float  # seconds into the recording
    duration: float
    speed: float


class _MeasurementIndex:
    """A loaded log's measurements behind the interface of :class:`TlogIndex` (time, seek, item)."""

    skipped: list = []
    truncated_at = None
    clock_steps: list = []

    def __init__(self, ms: list[Measurement]) -> None:
        self.items = sorted(ms, key=lambda m: m.t)
        self.t = np.array([m.t for m in self.items], dtype=float)

    def __len__(self) -> int:
        return len(self.items)

    @property
    def start(self) -> float:
        return float(self.t[0]) if len(self.t) else 0.0

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0

    def seek(self, t_rel: float) -> int:
        return int(np.searchsorted(self.t, self.start + t_rel, side="left"))

    def frame(self, i: int) -> Measurement:
        return self.items[i]


class _PassThrough:
    """Stands where the MAVLink receiver stands for a tlog: counts, and hands the record on."""

    def __init__(self) -> None:
        self.counters = LinkCounters()

    def feed(self, m: Measurement, _t: float) -> list[Measurement]:
        self.counters.messages += 1
        self.counters.by_type[m.kind.value] += 1
        return [m]

    def reset(self) -> None:
        """Nothing to forget on a seek: each record is a whole measurement (the tlog
        receiver, in this place, drops a frame cut in half)."""


class Replay:
    """Paced playback of a tlog (through the live receive path) or of a loaded log's measurements."""

    def __init__(
        self,
        path: str | Path,
        *,
        speed: float = 1.0,
        loop: bool = False,
        start: float = 0.0,
        name: str = "replay",
        buffer: int = 100_000,
        measurements: list[Measurement] | None = None,
    ) -> None:
        self.index: TlogIndex | _MeasurementIndex
        self.receiver: Any  # MavlinkReceiver for a tlog's frames, _PassThrough for a read log's records
        if measurements is None:
            self.index = TlogIndex.scan(path)  # raises TlogError with a one-line message
            self.receiver = MavlinkReceiver(name)
        else:  # DataFlash, Crazyflie: already decoded by their reader
            self.index = _MeasurementIndex(measurements)
            self.receiver = _PassThrough()
        self.path = Path(path)
        self.speed = check_speed(speed)
        self.loop = loop
        self.name = name
        self._measurements: Broadcast[Measurement] = Broadcast(buffer)
        self._i = self.index.seek(start)
        self._playing = asyncio.Event()
        self._playing.set()
        self._state = ReplayState.PLAYING
        self._anchor: tuple[float, float] | None = None  # (wall clock, recording time)

    # -- information ---------------------------------------------------------------
    @property
    def duration(self) -> float:
        return self.index.duration

    @property
    def position(self) -> float:
        i = min(self._i, len(self.index) - 1)
        return float(self.index.t[i] - self.index.start) if len(self.index) else 0.0

    @property
    def status(self) -> ReplayStatus:
        return ReplayStatus(self._state, self.position, self.duration, self.speed)

    def measurements(self, maxlen: int | None = None, *, lossy: bool = False) -> Subscription[Measurement]:
        return self._measurements.subscribe(maxlen, lossy=lossy)

    # -- controls ------------------------------------------------------------------
    def pause(self) -> None:
        self._playing.clear()
        self._set_state(ReplayState.PAUSED)

    def resume(self) -> None:
        self._anchor = None
        if self._state is not ReplayState.ENDED:
            self._set_state(ReplayState.PLAYING)
        self._playing.set()

    def seek(self, t: float) -> None:
        """Jump to ``t`` seconds into the recording (clamped to the file)."""
        self._i = self.index.seek(max(0.0, min(t, self.duration)))
        self._anchor = None
        # Start framing afresh: a frame is never split across records.
        self.receiver.reset()
        if self._state is ReplayState.ENDED:
            self._set_state(ReplayState.PLAYING if self._playing.is_set() else ReplayState.PAUSED)

    def close(self) -> None:
        """End every subscriber's stream (after what it has buffered)."""
        self._measurements.close()

    def set_speed(self, speed: float) -> None:
        self.speed = check_speed(speed)
        self._anchor = None

    def _set_state(self, state: ReplayState) -> None:
        self._state = state

    # -- playing -------------------------------------------------------------------
    def iter_measurements(self) -> Iterator[Measurement]:
        """Everything from the current position to the end, synchronously (batch use)."""
        idx, feed = self.index, self.receiver.feed
        while self._i < len(idx):
            i = self._i
            self._i += 1
            if i & _RELEASE_MASK == 0:
                self._release_before(i)
            yield from feed(idx.frame(i), float(idx.t[i]))
        self._release_before(len(idx))

    async def run(self) -> None:
        """Play to the end (forever with ``loop``), honouring the controls."""
        idx = self.index
        feed = self.receiver.feed
        publish = self._measurements.publish_many
        needs_wait = self._measurements.needs_wait
        batch_budget = 0
        while True:
            while self._i < len(idx):
                if not self._playing.is_set():
                    await self._playing.wait()
                i = self._i
                t_rec = float(idx.t[i])
                if self.speed != math.inf:
                    now = time.monotonic()
                    if self._anchor is None:
                        self._anchor = (now, t_rec)
                    due = self._anchor[0] + (t_rec - self._anchor[1]) / self.speed
                    if due > now + 0.001:
                        await asyncio.sleep(due - now)
                        continue  # controls may have changed while waiting
                if needs_wait():  # a lossless consumer is behind: let it catch up
                    await self._measurements.wait_for_space()
                self._i += 1
                out = feed(idx.frame(i), t_rec)
                if out:
                    publish(out)
                batch_budget += 1
                if batch_budget >= 256:  # let consumers and controls run
                    batch_budget = 0
                    if i & _RELEASE_MASK < 256:
                        self._release_before(i)
                    await asyncio.sleep(0)
            if not self.loop:
                break
            self.seek(0.0)
        self._set_state(ReplayState.ENDED)
        self.close()

    def _release_before(self, i: int) -> None:
        """The mapped file's pages before record ``i`` given back (played; a seek maps them again)."""
        idx = self.index
        if isinstance(idx, TlogIndex) and len(idx):
            idx.release(int(idx.offset[i]) if i < len(idx) else None)

    def skipped_summary(self) -> str:
        """One line on what the file's damage cost (empty if nothing)."""
        return damage_summary(self.index, self.receiver.counters)


def damage_summary(index: TlogIndex | _MeasurementIndex, c: LinkCounters) -> str:
    """One line on what a tlog's damage cost, from its index and the receiver's counters (empty if
    nothing)."""
    parts = []
    if c.crc_errors:
        parts.append(f"{c.crc_errors} frames with bad CRC skipped")
    if c.bad_data:
        parts.append(f"{c.bad_data} garbage stretches skipped")
    if index.skipped:
        n = sum(b for _, b in index.skipped)
        parts.append(f"{len(index.skipped)} corrupt stretches ({n} bytes) resynchronised")
    if index.truncated_at is not None:
        parts.append(f"truncated last record at byte {index.truncated_at} ignored")
    mended = getattr(index, "mended_times", 0)
    if mended:
        parts.append(
            f"{mended} record{'s' if mended > 1 else ''} with a damaged timestamp given the time of the one before"
        )
    steps = index.clock_steps
    if steps:
        parts.append(f"the recorder's clock stepped {len(steps)} time(s) (at byte {steps[0]}): played on as one")
    if c.undecodable:
        parts.append(f"{c.undecodable} messages that could not be decoded skipped ({c.last_undecodable})")
    return "; ".join(parts)
