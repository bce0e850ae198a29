"""The asyncio estimation loop: measurements in, state and covariance out.

* Any number of sources (links, boards, replays, the simulator) are merged and
  processed in vehicle-time order: a short reorder window (``reorder_s``)
  absorbs late arrivals; anything later than that is counted and dropped.
* Source clocks are aligned: each source's offset to the receive clock is
  estimated (least-delayed sample), and sources are mapped onto the first
  source's clock. Sources of one vehicle (``mav/1.1``, ``mav/1.100``) share a clock.
* Truth never reaches an estimator: it goes to :attr:`EstimationLoop.truth`.
* After every measurement update a :class:`Snapshot` (state, covariance,
  innovation) is published on :attr:`snapshots`; subscribers (dashboard,
  exporter, recorder) take what they need at their own pace and fall behind
  independently. Processing never waits for them.
"""
from __future__ import annotations

import asyncio
import heapq
import math
import time
from dataclasses import dataclass, field

import numpy as np

from .broadcast import Broadcast
from .estimator import KalmanEstimator
from .filters import InnovationRecord
from .measurement import Measurement


@dataclass(frozen=True)
class Snapshot:
    t: float
    estimator: str
    states: tuple[str, ...]
    x: np.ndarray
    P: np.ndarray
    innovation: InnovationRecord | None
    wall: float                   # when it was published (time.monotonic)

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.P), 0.0, None))

    def as_dict(self) -> dict[str, float]:
        d = {"t": self.t}
        d.update(zip(self.states, map(float, self.x)))
        d.update({f"sigma_{s}": float(v) for s, v in zip(self.states, self.sigma)})
        return d


class ClockAligner:
    """Maps each source's clock onto the reference (first) source's clock."""

    def __init__(self) -> None:
        self.offsets: dict[str, float] = {}     # source clock key -> max(t - t_rx)
        self.reference: str | None = None

    @staticmethod
    def key(source: str) -> str:
        return source.rsplit(".", 1)[0]

    def align(self, m: Measurement) -> float:
        k = self.key(m.source)
        if self.reference is None:
            self.reference = k
        if m.t_rx != m.t_rx:
            return m.t
        off = m.t - m.t_rx
        prev = self.offsets.get(k)
        if prev is None or off > prev or abs(off - prev) > 1.0:
            self.offsets[k] = off
        if k == self.reference:
            return m.t
        return m.t - self.offsets[k] + self.offsets[self.reference]


@dataclass
class LoopCounters:
    processed: int = 0
    late: int = 0
    truth: int = 0
    by_estimator: dict = field(default_factory=dict)


class EstimationLoop:
    def __init__(self, estimators: list[KalmanEstimator], *, reorder_s: float = 0.05,
                 align_clocks: bool = True) -> None:
        self.estimators = estimators
        self.reorder_s = reorder_s
        self.clocks = ClockAligner() if align_clocks else None
        self.snapshots: Broadcast[Snapshot] = Broadcast(200_000)
        self.truth: Broadcast[Measurement] = Broadcast(100_000)
        self.counters = LoopCounters()
        self._heap: list = []
        self._seq = 0
        self._latest = -math.inf
        self._released = -math.inf
        self._tasks: list[asyncio.Task] = []
        self.latest: dict[str, Snapshot] = {}

    # -- synchronous core (replays, tests, benchmarks) --------------------------------------
    def push(self, m: Measurement) -> None:
        if m.kind.is_truth:
            self.counters.truth += 1
            self.truth.publish(m)
            return
        t = self.clocks.align(m) if self.clocks is not None else m.t
        if t != t:
            return
        if t < self._released:
            if t < self._released - 1.0:      # a clock jump, not a late sample: start over
                self._released = -math.inf
                self._latest = -math.inf
            else:
                self.counters.late += 1
                return
        if t != m.t:
            m = m._replace(t=t)
        self._seq += 1
        heapq.heappush(self._heap, (t, self._seq, m))
        if t > self._latest:
            self._latest = t
        horizon = self._latest - self.reorder_s
        while self._heap and self._heap[0][0] <= horizon:
            self._process(heapq.heappop(self._heap)[2])

    def flush(self) -> None:
        while self._heap:
            self._process(heapq.heappop(self._heap)[2])

    def _process(self, m: Measurement) -> None:
        self._released = m.t
        self.counters.processed += 1
        for est in self.estimators:
            rec = est.handle(m)
            if rec is not None:
                f = est.filter
                snap = Snapshot(f.t, est.name, tuple(est.model.states), f.x.copy(), f.P.copy(), rec,
                                time.monotonic())
                self.latest[est.name] = snap
                self.snapshots.publish(snap)

    # -- asyncio -----------------------------------------------------------------------------
    def attach(self, subscription) -> None:
        """Consume an ``async for`` stream of measurements (a link's, a replay's)."""
        async def pump():
            async for m in subscription:
                self.push(m)
        self._tasks.append(asyncio.get_running_loop().create_task(pump()))

    async def wait(self) -> None:
        """Until every attached stream has ended; then flush the reorder window."""
        await asyncio.gather(*self._tasks)
        self.flush()
        self.snapshots.close()

    async def stop(self) -> None:
        for t in self._tasks:
            t.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self.flush()
        self.snapshots.close()
