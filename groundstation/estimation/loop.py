"""The asyncio estimation loop: measurements in, state and covariance out.

* Any number of sources (links, boards, replays, the simulator) are merged and
  processed in vehicle-time order, each measurement the moment it arrives (no
  hold-back delay). A measurement that arrives late, but within ``reorder_s``
  of the newest one, rolls the estimators back to a checkpoint before it and
  re-runs the buffered measurements in order; anything later than that is
  counted and dropped. Late by less than a timestamp's resolution
  (:data:`~groundstation.estimation.estimator.TIME_RESOLUTION_S`: a
  millisecond-stamped ATTITUDE after the microsecond-stamped IMU reading of the
  same instant) is on time, processed in place: rolling back for it made every
  such message cost a re-run. Live estimates thus cost no latency for ordering,
  and replays give the result of a perfectly ordered stream.
* Under load, a live link's batches (:meth:`EstimationLoop.push_many`) are
  decimated rather than queued (:mod:`~groundstation.estimation.shedding`).
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

import bisect
import math
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from groundstation.core.broadcast import Broadcast
from groundstation.core.measurement import Measurement

from .estimator import TIME_RESOLUTION_S, KalmanEstimator
from .filters import InnovationRecord
from .shedding import LoadShedder, decimate


@dataclass(frozen=True)
class Snapshot:
    t: float
    estimator: str
    states: tuple[str, ...]
    x: np.ndarray
    P: np.ndarray
    innovation: InnovationRecord | None
    wall: float  # when it was published (time.monotonic)

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
        self.offsets: dict[str, float] = {}  # source clock key -> max(t - t_rx)
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
    late: int = 0  # later than the reorder window: dropped
    rollbacks: int = 0  # late within the window: re-run in order
    truth: int = 0
    shed: int = 0  # readings merged into block means or thinned out under load


#: a checkpoint of every estimator at most this often (vehicle time) [s]
CHECKPOINT_EVERY = 0.01


class EstimationLoop:
    """Measurements in (:meth:`push`, or :meth:`push_many` for a live link's batches), snapshots
    out. ``latency_s``: how old a live reading may be when its estimate is published; beyond it
    :meth:`push_many` sheds load."""

    def __init__(
        self,
        estimators: list[KalmanEstimator],
        *,
        reorder_s: float = 0.05,
        align_clocks: bool = True,
        latency_s: float = 0.015,
    ) -> None:
        self.estimators = estimators
        self.reorder_s = reorder_s
        self.shedder = LoadShedder(latency_s)
        self.clocks = ClockAligner() if align_clocks else None
        self.snapshots: Broadcast[Snapshot] = Broadcast(200_000)
        self.truth: Broadcast[Measurement] = Broadcast(100_000)
        self.counters = LoopCounters()
        self._latest = -math.inf
        self.latest: dict[str, Snapshot] = {}
        #: kinds some estimator consumes; the rest are not processed at all
        self.kinds = set().union(*(e.kinds for e in estimators)) if estimators else set()
        # the last reorder_s of processed measurements, and checkpoints to roll back to
        self._history: deque[tuple[float, int, Measurement]] = deque()
        self._checkpoints: deque[tuple[float, int, list]] = deque()
        self._seq = 0

    # -- synchronous core (replays, tests, benchmarks) --------------------------------------
    def push(self, m: Measurement) -> None:
        if m.kind not in self.kinds:
            if m.kind.is_truth:
                self.counters.truth += 1
                self.truth.publish(m)
            return
        t = self.clocks.align(m) if self.clocks is not None else m.t
        if t != t:
            return
        if t != m.t:
            m = m._replace(t=t)
        if t >= self._latest - TIME_RESOLUTION_S:
            self._latest = max(t, self._latest)
            self._process(m, publish=True)
        elif t < self._latest - 1.0:
            # a clock jump (reboot, seek), not a late sample: start the history over
            self._history.clear()
            self._checkpoints.clear()
            self._latest = t
            self._process(m, publish=True)
        elif t >= self._latest - self.reorder_s and self._rollback(m):
            self.counters.rollbacks += 1
        else:
            self.counters.late += 1

    def _checkpoint_if_due(self, t: float) -> None:
        """A checkpoint before a measurement at ``t``, every :data:`CHECKPOINT_EVERY`; also while a
        rollback re-runs (with none taken then, the next late measurement went back to the same old
        checkpoint, and the one after further still)."""
        if not self._checkpoints or t - self._checkpoints[-1][0] >= CHECKPOINT_EVERY:
            self._checkpoints.append((t, self._seq, [e.checkpoint() for e in self.estimators]))

    def _record(self, m: Measurement) -> None:
        """Keep ``m`` for re-runs; forget checkpoints older than the window, and the measurements
        processed before the oldest one kept. Everything after it must stay: cut by time alone while
        an older checkpoint survives, a rollback to it loses what lies between (a MAVLink stream's
        untimed SERVO_OUTPUT_RAW, stamped a fraction of a microsecond before the ATTITUDE of the same
        instant, rolls back at every message, and the throttle outputs and barometer readings so
        lost put alpha 2 m/s^2 off)."""
        self._seq += 1
        self._history.append((m.t, self._seq, m))
        horizon = m.t - self.reorder_s - CHECKPOINT_EVERY
        while len(self._checkpoints) > 1 and self._checkpoints[1][0] < horizon:
            self._checkpoints.popleft()
        oldest = self._checkpoints[0][1]  # one is taken before every record
        while self._history and self._history[0][1] <= oldest:
            self._history.popleft()

    def _process(self, m: Measurement, publish: bool) -> None:
        if self.reorder_s > 0.0:  # (none: a log in time order, where nothing is ever rolled back)
            self._checkpoint_if_due(m.t)
            self._record(m)
        self.counters.processed += 1
        for est in self.estimators:
            rec = est.handle(m)
            if rec is not None and publish:
                self._publish(est, rec)

    def _rollback(self, m: Measurement) -> bool:
        """Re-run from the last checkpoint before ``m`` with ``m`` in its place."""
        i = bisect.bisect_right([c[0] for c in self._checkpoints], m.t) - 1
        if i < 0:
            if not self._checkpoints or self._checkpoints[0][1] != 0:
                return False
            i = 0  # before the stream's first measurement: its state holds for any earlier time
        t_cp, seq_cp, states = self._checkpoints[i]
        for est, cp in zip(self.estimators, states):
            est.restore(cp)
        # measurements processed at or after the checkpoint, plus the late one, in time order; at
        # equal times in arrival order (VFR_HUD's throttle and SERVO_OUTPUT_RAW share a stamp)
        redo = sorted([h for h in self._history if h[1] > seq_cp] + [(m.t, math.inf, m)], key=lambda h: (h[0], h[1]))
        while len(self._checkpoints) > i + 1:
            self._checkpoints.pop()
        self._history = deque(h for h in self._history if h[1] <= seq_cp)
        last: dict[str, InnovationRecord] = {}
        for _, _, mm in redo:
            self._process_quiet(mm, last)
        for est in self.estimators:
            if est.name in last:
                self._publish(est, last[est.name])
        return True

    def _process_quiet(self, m: Measurement, last: dict) -> None:
        self._checkpoint_if_due(m.t)
        self._record(m)
        for est in self.estimators:
            rec = est.handle(m)
            if rec is not None:
                last[est.name] = rec

    def _publish(self, est: KalmanEstimator, rec: InnovationRecord) -> None:
        f = est.filter
        snap = Snapshot(f.t, est.name, tuple(est.model.states), f.x.copy(), f.P.copy(), rec, time.monotonic())
        self.latest[est.name] = snap
        self.snapshots.publish(snap)

    def push_many(self, ms: list[Measurement]) -> None:
        """A batch as a live link delivered it, decimated as :attr:`shedder` decides when the
        estimators cannot keep up (see :mod:`~groundstation.estimation.shedding`): live estimates stay
        within ``latency_s`` of the vehicle at the cost of resolution, counted in ``counters.shed``."""
        used = [m for m in ms if m.kind in self.kinds or m.kind.is_truth]
        if not used:
            return
        oldest = used[0].t_rx
        k = self.shedder.factor(len(used), time.time() - oldest if oldest == oldest else 0.0)
        if k > 1:
            used, removed = decimate(used, k)
            self.counters.shed += removed
        t0 = time.perf_counter()
        for m in used:
            self.push(m)
        self.shedder.measured(len(used), time.perf_counter() - t0)

    # -- asyncio -----------------------------------------------------------------------------
    def attach_link(self, link) -> None:
        """Estimate inside the link's delivery to the event loop (lowest latency; never blocks)."""
        link.sinks.append(self.push_many)
