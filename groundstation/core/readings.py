"""A log's readings held as columns, each :class:`~.measurement.Measurement` record made as it is
read: :class:`Readings`.

A record is a tuple, two floats and an array view: some 400 bytes, and a 1-hour log has 1.2 million
of them (0.5 GB, more than the file itself). :class:`Readings` keeps one column each of time, receive
time and samples, and per reading which of its *streams* holds its value and in which row; a stream
is the readings of one kind, source, instance and value layout, its values one read-only (n, dim)
array. That is 28 bytes a reading besides its values. It is a
:class:`~collections.abc.Sequence` of records: iterating, indexing and slicing give records equal
field by field to those put in (the same floats, the same values as read-only views of the stream's
array), made as they are asked for (under a microsecond each), so that code written for a list of
records reads it unchanged; and the operations a diagnosis does on a whole log (keeping some kinds,
a time window, a shift in time, a change of one kind's values, a sort by time) are done on the
columns, without a record made.

Written here because no columnar library at hand (numpy's record arrays, pandas) holds readings of
different widths in one time order and gives back the records the estimators take.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import overload

import numpy as np

from .measurement import Kind, Measurement

#: readings made into records at a time (each column's ``tolist`` a chunk at a time)
_CHUNK = 1 << 14

_new_record = tuple.__new__


@dataclass(frozen=True)
class Stream:
    """The readings of one kind, source and instance with one value layout: their values (and
    variances, where they have one) as read-only (n, dim) arrays."""

    kind: Kind
    source: str
    instance: int
    values: np.ndarray
    variance: np.ndarray | None = None


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


class Readings(Sequence[Measurement]):
    """Readings as columns (see the module docstring). ``t``, ``t_rx``, ``samples``: each reading's;
    ``stream``, ``row``: where its value lies, ``streams[stream][row]``."""

    __slots__ = ("t", "t_rx", "samples", "stream", "row", "streams")

    def __init__(
        self,
        t: np.ndarray,
        t_rx: np.ndarray,
        samples: np.ndarray,
        stream: np.ndarray,
        row: np.ndarray,
        streams: Sequence[Stream],
    ) -> None:
        self.t, self.t_rx, self.samples, self.stream, self.row = t, t_rx, samples, stream, row
        self.streams = tuple(streams)

    # -- made from records ------------------------------------------------------------------------
    @classmethod
    def of(cls, ms: Iterable[Measurement]) -> Readings:
        """``ms`` as columns (itself when it already is)."""
        if isinstance(ms, Readings):
            return ms
        b = ReadingsBuilder()
        b.extend(ms)
        return b.build()

    @classmethod
    def empty(cls) -> Readings:
        z = np.zeros(0)
        return cls(z, z, np.zeros(0, dtype=np.int32), np.zeros(0, dtype=np.int32), np.zeros(0, dtype=np.int32), ())

    # -- a sequence of records ----------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.t)

    def _record(self, i: int) -> Measurement:
        s = self.streams[int(self.stream[i])]
        r = int(self.row[i])
        var = None if s.variance is None else s.variance[r]
        return _new_record(
            Measurement,
            (
                float(self.t[i]),
                s.kind,
                s.values[r],
                s.source,
                float(self.t_rx[i]),
                var,
                s.instance,
                int(self.samples[i]),
            ),
        )

    @overload
    def __getitem__(self, i: int) -> Measurement: ...

    @overload
    def __getitem__(self, i: slice) -> Readings: ...

    def __getitem__(self, i: int | slice) -> Measurement | Readings:
        if isinstance(i, slice):
            return Readings(self.t[i], self.t_rx[i], self.samples[i], self.stream[i], self.row[i], self.streams)
        n = len(self.t)
        if not -n <= i < n:
            raise IndexError("readings index out of range")
        return self._record(i % n)

    def __iter__(self) -> Iterator[Measurement]:
        per = [(s.kind, s.values, s.source, s.variance, s.instance) for s in self.streams]
        new, M = _new_record, Measurement
        for a in range(0, len(self.t), _CHUNK):
            b = a + _CHUNK
            for t, t_rx, n, s, r in zip(
                self.t[a:b].tolist(),
                self.t_rx[a:b].tolist(),
                self.samples[a:b].tolist(),
                self.stream[a:b].tolist(),
                self.row[a:b].tolist(),
            ):
                kind, values, source, var, inst = per[s]
                yield new(M, (t, kind, values[r], source, t_rx, None if var is None else var[r], inst, n))

    def __repr__(self) -> str:
        return f"Readings({len(self)} readings in {len(self.streams)} streams)"

    # -- whole-log operations on the columns -------------------------------------------------------
    def kinds(self) -> set[Kind]:
        """The kinds present."""
        return {self.streams[s].kind for s in np.unique(self.stream).tolist()}

    def is_kind(self, kinds: Collection[Kind]) -> np.ndarray:
        """Per reading: is its kind one of ``kinds``."""
        hit = np.array([s.kind in kinds for s in self.streams], dtype=bool)
        return hit[self.stream] if len(self.streams) else np.zeros(len(self), dtype=bool)

    def where(self, keep: np.ndarray) -> Readings:
        """The readings where ``keep`` (a boolean mask or indices), in that order."""
        return Readings(
            self.t[keep], self.t_rx[keep], self.samples[keep], self.stream[keep], self.row[keep], self.streams
        )

    def only(self, kinds: Collection[Kind]) -> Readings:
        """The readings of ``kinds``, in their order."""
        return self.where(self.is_kind(kinds))

    def without(self, kinds: Collection[Kind]) -> Readings:
        """The readings of other kinds than ``kinds``, in their order."""
        return self.where(~self.is_kind(kinds))

    def __add__(self, other: Iterable[Measurement]) -> Readings:
        """These readings, then ``other``'s."""
        o = Readings.of(other)
        k = len(self.streams)
        return Readings(
            np.concatenate([self.t, o.t]),
            np.concatenate([self.t_rx, o.t_rx]),
            np.concatenate([self.samples, o.samples]),
            np.concatenate([self.stream, o.stream + k]).astype(np.int32),
            np.concatenate([self.row, o.row]),
            self.streams + o.streams,
        )

    def in_time_order(self, first: Collection[Kind] = ()) -> Readings:
        """Sorted by time and, at equal times, the kinds ``first`` before the others, otherwise in
        their order (as a stable sort by ``(m.t, m.kind not in first)``). A reading without a time
        (NaN) goes last."""
        later = ~self.is_kind(first) if first else np.zeros(len(self), dtype=bool)
        return self.where(np.lexsort((later, self.t)))

    def shifted(self, kinds: Collection[Kind], d: float) -> Readings:
        """The readings of ``kinds`` taken as of ``t - d``, the others as they are (not re-sorted)."""
        hit = self.is_kind(kinds)
        t = np.where(hit, self.t - d, self.t)
        return Readings(t, self.t_rx, self.samples, self.stream, self.row, self.streams)

    def with_values(self, kind: Kind, change: Callable[[np.ndarray], np.ndarray]) -> Readings:
        """The readings of ``kind`` with their values ``change(values)`` (a stream's (n, dim) array at
        once: an elementwise change gives each reading what it gives its value), the others as they are."""
        streams = [
            Stream(s.kind, s.source, s.instance, _read_only(np.asarray(change(s.values))), s.variance)
            if s.kind is kind
            else s
            for s in self.streams
        ]
        return Readings(self.t, self.t_rx, self.samples, self.stream, self.row, streams)

    def before(self, t_end: float) -> Readings:
        """The readings before ``t_end``, in their order."""
        return self.where(self.t < t_end)

    def columns(self, kinds: Kind | Collection[Kind]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The readings of a kind (or of several) in their order as columns: their times, their times
        of receipt, and their values as one (n, width) array, width the widest stream's (a narrower
        stream's missing components NaN). What a loop over the records would read, without a record
        made for each."""
        kinds = (kinds,) if isinstance(kinds, Kind) else kinds
        idx = np.flatnonzero(self.is_kind(kinds))
        stream, row = self.stream[idx], self.row[idx]
        of_kind = [i for i, s in enumerate(self.streams) if s.kind in kinds]
        values = np.full((len(idx), max((self.streams[i].values.shape[1] for i in of_kind), default=0)), np.nan)
        for i in of_kind:
            sel = stream == i
            v = self.streams[i].values
            values[sel, : v.shape[1]] = v[row[sel]]
        return self.t[idx], self.t_rx[idx], values


class ReadingsBuilder:
    """Records gathered into :class:`Readings` a chunk at a time, so that no more than a chunk of
    them is held as records at once."""

    def __init__(self, chunk: int = 1 << 16) -> None:
        self._chunk = chunk
        self._pending: list[Measurement] = []
        self._ids: dict[tuple, int] = {}  # a stream's key -> its index
        self._keys: list[tuple] = []
        self._values: list[list[np.ndarray]] = []  # per stream, its parts
        self._variance: list[list[np.ndarray]] = []
        self._rows: list[int] = []  # per stream, its rows so far
        self._cols: list[tuple[np.ndarray, ...]] = []  # per chunk: t, t_rx, samples, stream, row

    def append(self, m: Measurement) -> None:
        self._pending.append(m)
        if len(self._pending) >= self._chunk:
            self._flush()

    def extend(self, ms: Iterable[Measurement]) -> None:
        for m in ms:
            self.append(m)

    def __len__(self) -> int:
        return sum(len(c[0]) for c in self._cols) + len(self._pending)

    def _flush(self) -> None:
        ms, self._pending = self._pending, []
        if not ms:
            return
        ids, keys = self._ids, self._keys
        stream = np.empty(len(ms), dtype=np.int32)
        row = np.empty(len(ms), dtype=np.int32)
        grouped: dict[int, list[int]] = {}
        for i, m in enumerate(ms):
            v, var = m.value, m.variance
            key = (
                m.kind,
                m.source,
                m.instance,
                v.shape,
                v.dtype.str,
                None if var is None else (var.shape, var.dtype.str),
            )
            j = ids.get(key)
            if j is None:
                j = ids[key] = len(keys)
                keys.append(key)
                self._values.append([])
                self._variance.append([])
                self._rows.append(0)
            stream[i] = j
            grouped.setdefault(j, []).append(i)
        for j, idx in grouped.items():
            row[idx] = np.arange(self._rows[j], self._rows[j] + len(idx))
            self._rows[j] += len(idx)
            self._values[j].append(np.array([ms[i].value for i in idx], dtype=keys[j][4]))
            if keys[j][5] is not None:
                self._variance[j].append(np.array([ms[i].variance for i in idx], dtype=keys[j][5][1]))
        self._cols.append(
            (
                np.array([m.t for m in ms], dtype=float),
                np.array([m.t_rx for m in ms], dtype=float),
                np.array([m.samples for m in ms], dtype=np.int32),
                stream,
                row,
            )
        )

    def build(self) -> Readings:
        """The readings appended, in their order (the builder is empty afterwards)."""
        self._flush()
        if not self._cols:
            return Readings.empty()
        t, t_rx, samples, stream, row = (np.concatenate([c[j] for c in self._cols]) for j in range(5))
        self._cols = []
        streams = []
        for j, key in enumerate(self._keys):
            kind, source, instance, shape, dtype, var = key
            values = np.concatenate(self._values[j]) if self._values[j] else np.zeros((0, *shape), dtype=dtype)
            variance = np.concatenate(self._variance[j]) if var is not None else None
            self._values[j] = self._variance[j] = []
            streams.append(
                Stream(kind, source, instance, _read_only(values), None if variance is None else _read_only(variance))
            )
        self._ids, self._keys, self._values, self._variance, self._rows = {}, [], [], [], []
        return Readings(t, t_rx, samples, stream, row, streams)
