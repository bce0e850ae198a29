"""A log's raw IMU as columns: the accelerometer's and gyro's samples, not one record each.

An IMU at 1 kHz is nine tenths of a log's readings. As :class:`~.measurement.Measurement` records
(a tuple and an array each) a 10-minute flight's 1.2 million of them took about 600 MB and most
of the time it took to read, triage and prepare the log; the estimators of a diagnosis take them
averaged over 10 ms blocks anyway. :class:`ImuColumns` keeps them as arrays (some 30 to 50 bytes
a sample with its times, not 500) for whatever reads the raw samples (the triage's vibration and
clipping, the notch's spectrum) and for the block means (:func:`block_means`).

The values are float64, or float32 where the log sent float32 (a tlog's HIGHRES_IMU): widened, they
are the receiver's float64 exactly, so whatever computes with them widens them first
(:meth:`ImuSeries.values`) and gets the same numbers.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from .measurement import Kind, Measurement
from .readings import Readings, Stream

#: the kinds kept as columns
IMU_KINDS = (Kind.ACCEL, Kind.GYRO)


@dataclass
class ImuSeries:
    """One sensor's samples (one kind, one instance), in time order."""

    source: str
    t: np.ndarray  #: [s] vehicle clock, float64
    t_rx: np.ndarray  #: [s] receive time (UNIX), float64
    value: np.ndarray  #: (N, 3) SI, float64 or the log's own float32 (module docstring)
    samples: np.ndarray  #: (N,) raw samples each reading stands for (1, or a block mean's count)

    def __len__(self) -> int:
        return len(self.t)

    def values(self, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """``value[rows]`` as float64, to compute with (a float32 column widened exactly)."""
        return self.value[rows].astype(np.float64, copy=False)

    def masked(self, keep: np.ndarray) -> ImuSeries:
        return ImuSeries(self.source, self.t[keep], self.t_rx[keep], self.value[keep], self.samples[keep])

    def records(self, kind: Kind, instance: int) -> list[Measurement]:
        """The samples as measurement records (for a reader that wants them one by one)."""
        return [
            Measurement(float(t), kind, v.astype(np.float64), self.source, float(r), None, instance, int(n))
            for t, r, v, n in zip(self.t, self.t_rx, self.value, self.samples)
        ]


class _Growing:
    """A series being collected, in typed arrays (8 bytes a float, not a Python object's 24)."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.t, self.t_rx, self.v, self.n = array("d"), array("d"), array("d"), array("i")

    def add(self, m: Measurement) -> None:
        self.t.append(m.t)
        self.t_rx.append(m.t_rx)
        self.v.extend(m.value[:3].tolist())
        self.n.append(m.samples)

    def done(self) -> ImuSeries:
        t = np.frombuffer(self.t, dtype=float)
        order = np.argsort(t, kind="stable")
        v = np.frombuffer(self.v, dtype=float).reshape(-1, 3)
        return ImuSeries(
            self.source,
            t[order],
            np.frombuffer(self.t_rx, dtype=float)[order],
            v[order],
            np.frombuffer(self.n, dtype=np.int32)[order],
        )


@dataclass
class ImuColumns:
    """Every IMU series of a log, by (kind, instance)."""

    series: dict[tuple[Kind, int], ImuSeries] = field(default_factory=dict)

    def __len__(self) -> int:
        return sum(len(s) for s in self.series.values())

    @property
    def start(self) -> float:
        """The first sample's time (inf with none)."""
        return min((float(s.t[0]) for s in self.series.values() if len(s)), default=math.inf)

    def get(self, kind: Kind, instance: int = 0) -> ImuSeries | None:
        return self.series.get((kind, instance))

    @property
    def kinds(self) -> set[Kind]:
        return {k for k, _ in self.series if len(self.series[(k, _)])}

    @classmethod
    def split(cls, ms: Iterable[Measurement]) -> tuple[list[Measurement], ImuColumns]:
        """``ms`` without its IMU readings (a list), and those as columns. ``ms`` may be a stream:
        the IMU's records are not kept."""
        rest: list[Measurement] = []
        growing: dict[tuple[Kind, int], _Growing] = {}
        for m in ms:
            if m.kind in IMU_KINDS and len(m.value) >= 3:
                g = growing.get((m.kind, m.instance))
                if g is None:
                    g = growing[(m.kind, m.instance)] = _Growing(m.source)
                g.add(m)
            else:
                rest.append(m)
        return rest, cls({k: g.done() for k, g in growing.items()})

    def masked(self, keep: Callable[[ImuSeries], np.ndarray]) -> ImuColumns:
        """Each series with the samples ``keep(series)`` (a boolean array) keeps. Series that share
        their times (a frame's accelerometer and gyro) still share them where they keep the same."""
        out: dict[tuple[Kind, int], ImuSeries] = {}
        done: dict[tuple[int, int, int], tuple[np.ndarray, ImuSeries]] = {}  # the times' arrays -> kept, series
        for k, s in self.series.items():
            kept = keep(s)
            key = (id(s.t), id(s.t_rx), id(s.samples))
            same = done.get(key)
            if same is not None and np.array_equal(same[0], kept):
                out[k] = ImuSeries(s.source, same[1].t, same[1].t_rx, s.value[kept], same[1].samples)
            else:
                out[k] = s.masked(kept)
                done[key] = (kept, out[k])
        return ImuColumns(out)

    def records(self) -> list[Measurement]:
        return [m for (kind, inst), s in self.series.items() for m in s.records(kind, inst)]

    def on_receive_clock(self, origin: float) -> ImuColumns:
        """The samples timed by their receive time since ``origin`` (a tlog's recording clock),
        in that time's order."""
        out = {}
        times: dict[int, np.ndarray] = {}  # one array for the series that share their receive times
        for k, s in self.series.items():
            t = times.get(id(s.t_rx))
            if t is None:
                t = times[id(s.t_rx)] = s.t_rx - origin
            if len(t) < 2 or bool(np.all(t[1:] >= t[:-1])):  # already in order (a tlog's, nearly always)
                out[k] = ImuSeries(s.source, t, s.t_rx, s.value, s.samples)
                continue
            order = np.argsort(t, kind="stable")
            out[k] = ImuSeries(s.source, t[order], s.t_rx[order], s.value[order], s.samples[order])
        return ImuColumns(out)


@dataclass
class Blocks:
    """One series averaged over blocks: each block's mean as readings (columns: a 1-hour 1 kHz
    log's accelerometer is 0.36 million blocks, 0.14 GB as records), and (for a block of three
    samples or more) the spread of the reading's magnitude within it."""

    readings: Readings
    spread_t: np.ndarray
    spread: np.ndarray


def block_starts(t: np.ndarray, dt: float) -> np.ndarray:
    """The indices where blocks start: each at the first sample at least ``dt`` after the start of
    the one before, with a microsecond's slack (a 500 Hz sample 10 ms after a block's first can read
    0.00999999 s after it from a log's microsecond stamps; without the slack such blocks take a
    sixth sample and the grid moves)."""
    starts = [0]
    n, i = len(t), 0
    while True:
        i = int(np.searchsorted(t, t[i] + dt - 1e-6, side="left"))
        if i >= n:
            break
        starts.append(i)
    return np.asarray(starts, dtype=int)


#: IMU blocks averaged at once by :func:`block_means`
_BLOCKS_AT_ONCE = 1 << 15


def block_means(s: ImuSeries, kind: Kind, instance: int, dt: float) -> Blocks:
    """The series over ``dt`` blocks (:func:`block_starts`). A block's mean is stamped where it
    starts to act: a sample stands for the interval that ends at its stamp (an integrating IMU's
    delta-velocity), so one sample period before the block's first stamp, the period being the
    block's own; it carries the raw samples it stands for (``Measurement.samples``)."""
    if not len(s):
        return Blocks(Readings.empty(), np.zeros(0), np.zeros(0))
    starts = block_starts(s.t, dt)
    ends = np.r_[starts[1:], len(s.t)]
    count = ends - starts
    mean, s1, s2 = np.empty((len(starts), 3)), np.empty(len(starts)), np.empty(len(starts))
    raw = bool(np.all(s.samples == 1))
    # a few thousand blocks at a time: each block's sums are its own, so the numbers are those of
    # the whole series at once, without its float64 copies (a 1-hour 1 kHz log's are 86 MB each)
    for b0 in range(0, len(starts), _BLOCKS_AT_ONCE):
        b1 = min(b0 + _BLOCKS_AT_ONCE, len(starts))
        rows = slice(int(starts[b0]), int(ends[b1 - 1]))
        at = starts[b0:b1] - starts[b0]
        w = s.samples[rows].astype(float)
        v = s.values(rows)
        # raw samples (each one) need no weights: v * 1.0 is v
        weighted = v if raw else v * w[:, None]
        mean[b0:b1] = np.add.reduceat(weighted, at, axis=0) / np.add.reduceat(w, at)[:, None]
        # the magnitude's spread within each block of three or more (the rotors' vibration)
        mag = np.sqrt(np.sum(v * v, axis=1))
        s1[b0:b1], s2[b0:b1] = np.add.reduceat(mag, at), np.add.reduceat(mag * mag, at)
    t_first, t_last = s.t[starts], s.t[ends - 1]
    period = np.where(count > 1, (t_last - t_first) / np.maximum(count - 1, 1), 0.0)
    stamp = t_first - period
    n_raw = np.add.reduceat(s.samples, starts)
    mean.flags.writeable = False
    n = len(starts)
    blocks = Readings(
        stamp,
        s.t_rx[starts].astype(float),
        n_raw.astype(np.int32),
        np.zeros(n, dtype=np.int32),
        np.arange(n, dtype=np.int32),
        [Stream(kind, s.source, instance, mean)],
    )
    var = np.maximum(s2 / count - (s1 / count) ** 2, 0.0)
    big = count > 2
    return Blocks(blocks, t_first[big], np.sqrt(var[big]))


def block_mean(first: Measurement, t_last: float, values: list) -> Measurement:
    """One block's mean as :func:`block_means` gives it, for a stream averaged as it comes (a live
    session's buffer): the mean of an IMU block, stamped where it starts to act. An IMU sample stands for the
    interval that ends at its stamp (an integrating IMU's delta-velocity; the simulator's specific
    force over its last step), so held from one sample period before the first stamp, the mean
    acts over the very interval it averages. (Stamped at the first sample, the range readings
    of simulated flights looked 2-3 ms early against the height.) It carries its sample count: a
    model whose R is one sample's variance (``MeasurementModel.per_sample``) divides it by that."""
    period = (t_last - first.t) / (len(values) - 1) if len(values) > 1 else 0.0
    return first._replace(t=first.t - period, value=np.mean(values, axis=0), samples=len(values))


def starts_block(t_first: float, t: float, block_dt: float) -> bool:
    """Whether an IMU sample at ``t`` starts a new block after the one opened at ``t_first``
    (:func:`block_starts`, for a stream). With a microsecond's slack: from a log's microsecond
    stamps, a 500 Hz sample 10 ms after a block's first can read 0.00999999 s after it; without the
    slack such blocks take a sixth sample (12 ms) and move the grid (1301 of 1740 blocks on a 20 s
    simulated flight)."""
    return t - t_first >= block_dt - 1e-6
