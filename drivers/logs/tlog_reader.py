"""A whole tlog into measurements, its high-rate IMU as columns and the rest as
:class:`~groundstation.core.readings.Readings`: the replay's records, in a fraction of its time and
memory.

:class:`~drivers.replay.Replay` feeds every frame through the live receive path, which costs some
30 µs a frame in Python; a 1 kHz IMU is nine frames in ten of a log. Here the IMU's HIGHRES_IMU
frames are framed, CRC-checked and unpacked for the whole file at once (:func:`.bulk.load_tlog`,
the vectorised framing) and converted as whole columns, with the same arithmetic as
:class:`~drivers.mavlink.decode.MavlinkDecoder` (the time field in seconds; the float32 values kept
as sent, which widened are the decoder's float64: ``ImuSeries.values``); the other frames still
go through the receiver, in file order. Each IMU frame taken this
way is still shown to its vehicle's clock (:class:`~drivers.mavlink.clock.VehicleClock`) where it
lies in the file, since the untimed messages after it are stamped by that clock. The result equals
the replay's, record for record (``tests/test_tlog_reader.py``).

A HIGHRES_IMU frame goes through the receiver instead where the columns would not say what the
receiver says: one that carries more than the accelerometer and gyro (``fields_updated``), one
without a vehicle time (zero, or a UNIX time), one longer than its definition, one whose CRC fails
(the receiver counts it), and any while the receiver holds a partial frame or untimed messages of
its vehicle waiting for their clock. The receiver's sequence-loss counters see only the frames it is fed (a
log's loss is the triage's, from the tables).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.mavlink.clock import EPOCH_THRESHOLD_US, VehicleClock
from drivers.mavlink.receiver import MavlinkReceiver
from drivers.replay import damage_summary
from drivers.tlog import TlogIndex
from groundstation.core.imu import IMU_KINDS, ImuColumns, ImuSeries
from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings, ReadingsBuilder

from .bulk import load_tlog

#: the messages whose accelerometer and gyro readings are the columns (the rest of a HIGHRES_IMU's, its
#: magnetometer and pressures, only where the receiver reads the frame: see the module docstring)
IMU_MESSAGES = ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")

#: HIGHRES_IMU's fields_updated bits for the accelerometer and the gyro (MAVLink
#: HIGHRES_IMU_UPDATED_FLAGS); any other bit set sends the frame through the receiver
_ACC, _GYRO = 0x7, 0x38


@dataclass
class TlogRead:
    """A tlog's measurements: the IMU's as columns, the rest as records in file order."""

    measurements: Readings  # in file order, as columns (a 1-hour log's 1.2 million records are 0.5 GB)
    imu: ImuColumns
    index: TlogIndex  # the file's bytes and record index (the tables read them again)
    damage: str  # one line, as :meth:`Replay.skipped_summary`, or ''
    ground_stations: frozenset[int] = frozenset()  #: system ids heard with a ground station's heartbeat

    @property
    def duration(self) -> float:
        return self.index.duration


@dataclass
class _Columns:
    """The HIGHRES_IMU frames the columns take: per frame its record, vehicle time, and of its
    fields those the columns read (not the whole rows: a 1-hour 1 kHz log's are 0.2 GB)."""

    record: np.ndarray  # record numbers, increasing
    t: np.ndarray  # [s] vehicle time
    sysid: np.ndarray
    compid: np.ndarray
    updated: np.ndarray  # fields_updated
    instance: np.ndarray  # id
    acc: np.ndarray  # (N, 3) float32 as sent [m/s^2]
    gyro: np.ndarray  # (N, 3) float32 as sent [rad/s]


#: records the receiver reads between two gives of the file's pages back (:meth:`TlogIndex.release`)
_RELEASE_EVERY = 1 << 16

#: a sensor's values once :func:`_add_columns` has taken them
_NONE = np.zeros((0, 3), dtype=np.float32)


def _of(f: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    """The structured rows' fields ``names`` as one (N, len(names)) array of their own type."""
    return np.column_stack([f[n] for n in names]) if len(f) else np.zeros((0, len(names)), dtype=np.float32)


def _imu_frames(ix: TlogIndex, path: Path) -> _Columns:
    hr = load_tlog(path, index=ix, only=("HIGHRES_IMU",)).messages.get("HIGHRES_IMU")
    if hr is None or hr.record is None or hr.sysid is None or hr.compid is None:
        e, v = np.zeros(0, dtype=np.int64), np.zeros((0, 3), dtype=np.float32)
        return _Columns(e, np.zeros(0), e, e, e, e, v, v)
    f = hr.fields
    raw = f["time_usec"]
    upd = f["fields_updated"].astype(np.int64)
    L = np.frombuffer(ix.data, dtype=np.uint8)[ix.offset[hr.record] + 9]  # each frame's payload length
    ix.release()  # (reading those lengths maps every page of the file again)
    # a frame the receiver would read otherwise: see the module docstring
    ok = (raw != 0) & (raw <= EPOCH_THRESHOLD_US) & (upd != 0) & ((upd & ~(_ACC | _GYRO)) == 0)
    ok &= L <= f.dtype.itemsize
    sel = slice(None) if ok.all() else np.flatnonzero(ok)  # the usual case: all, no copy of the rows
    return _Columns(
        hr.record[sel],
        raw[sel].astype(np.float64) * 1e-6,
        hr.sysid[sel],
        hr.compid[sel],
        f["fields_updated"][sel].copy(),  # (copies, not views: a view would hold every row)
        f["id"][sel].copy(),
        _of(f[sel], ("xacc", "yacc", "zacc")),
        _of(f[sel], ("xgyro", "ygyro", "zgyro")),
    )


def read_tlog(path: str | Path, link_name: str = "replay") -> TlogRead:
    """Every measurement of a tlog, as :meth:`Replay.iter_measurements` gives them, its IMU as
    columns (raises :class:`drivers.tlog.TlogError` with a one-line message)."""
    path = Path(path)
    ix = TlogIndex.scan(path)
    cols = _imu_frames(ix, path)
    rx = MavlinkReceiver(link_name)
    clocks = rx.decoder.clocks
    feed, frame, t_rec = rx.feed, ix.frame, ix.t
    rest = ReadingsBuilder()  # gathered into columns as they come
    slow_imu: list[tuple[int, Measurement]] = []  # (record, IMU reading) from the receiver

    def take(i: int) -> None:
        for m in feed(frame(i), float(t_rec[i])):
            if m.kind in IMU_KINDS and len(m.value) >= 3:
                slow_imu.append((i, m))
            else:
                rest.append(m)

    taken = np.zeros(len(cols.record), dtype=bool)
    rec = cols.record
    # the runs of column frames in consecutive records, [first, end) into ``rec``
    brk = np.flatnonzero(np.diff(rec) != 1) + 1
    firsts = np.r_[0, brk] if len(rec) else np.zeros(0, dtype=np.int64)
    ends = np.r_[brk, len(rec)] if len(rec) else firsts
    i = 0  # the next record to read
    passed = _RELEASE_EVERY  # records read before the pages behind them are given back
    for k, end, r0 in zip(firsts.tolist(), ends.tolist(), rec[firsts].tolist()):
        if r0 >= passed:
            ix.release(int(ix.offset[r0]))
            passed = r0 + _RELEASE_EVERY
        while i < r0:
            take(i)
            i += 1
        while k < end and not rx.idle_for(cols.sysid[k:end]):
            take(i)  # the receiver reads it (it may end its vehicle's wait)
            i, k = i + 1, k + 1
        if k == end:
            continue
        # each shown to its vehicle's clock, where it lies in the file
        for sysid, tv, tr in zip(cols.sysid[k:end].tolist(), cols.t[k:end].tolist(), t_rec[rec[k:end]].tolist()):
            clock = clocks.get(sysid)
            if clock is None:
                clock = clocks[sysid] = VehicleClock()
            clock.observe(tv, tr)
        taken[k:end] = True
        i += end - k
    while i < len(ix):
        take(i)
        i += 1
    ix.release()
    imu = _columns(cols, taken, t_rec, slow_imu, link_name)
    return TlogRead(rest.build(), imu, ix, damage_summary(ix, rx.counters), frozenset(rx.decoder.ground_stations))


def _columns(
    cols: _Columns, taken: np.ndarray, t_rec: np.ndarray, slow: list[tuple[int, Measurement]], link_name: str
) -> ImuColumns:
    """The IMU columns from the frames taken as columns and the receiver's readings, each series in
    time order and, at equal times, in file order (as :meth:`ImuColumns.split` orders a stream)."""
    parts: dict[tuple[Kind, int], list[tuple[np.ndarray, ...]]] = {}
    first: dict[tuple[Kind, int], tuple[int, str]] = {}  # the record and source of each series' first
    if taken.any():
        _add_columns(cols, taken, t_rec, link_name, parts, first)
    grouped: dict[tuple[Kind, int], list[tuple[int, Measurement]]] = {}
    for r0, m in slow:
        grouped.setdefault((m.kind, m.instance), []).append((r0, m))
    for key, rm in grouped.items():
        parts.setdefault(key, []).append(
            (
                np.array([r0 for r0, _ in rm], dtype=np.int64),
                np.array([m.t for _, m in rm]),
                np.array([m.t_rx for _, m in rm]),
                np.array([m.value[:3] for _, m in rm], dtype=float).reshape(-1, 3),
            )
        )
        if key not in first or rm[0][0] < first[key][0]:
            first[key] = (rm[0][0], rm[0][1].source)
    out: dict[tuple[Kind, int], ImuSeries] = {}
    # in the order the series first appear in the file (a frame's accelerometer before its gyro)
    for key in sorted(parts, key=lambda k: (first[k][0], k[0] is not Kind.ACCEL)):
        # each series' parts let go as it is made, and copied only where they must be (a 1-hour 1 kHz
        # log's IMU columns are 0.3 GB): its parts joined in the file's order are most often already
        # in time order (the receiver's few readings before the vehicle's clock came, then the columns)
        ps = _one_type(sorted(parts.pop(key), key=lambda p: int(p[0][0])))
        r, t, t_rx, v = ps[0] if len(ps) == 1 else (np.concatenate([p[j] for p in ps]) for j in range(4))
        del ps
        dt = np.diff(t)
        if not (np.all(dt >= 0.0) and np.all((dt > 0.0) | (np.diff(r) > 0))):
            order = np.lexsort((r, t))  # by time, then by place in the file
            t, t_rx, v = t[order], t_rx[order], v[order]
        out[key] = _sharing_times(ImuSeries(first[key][1], t, t_rx, v, np.ones(len(r), dtype=np.int32)), out)
    return ImuColumns(out)


def _sharing_times(s: ImuSeries, made: dict[tuple[Kind, int], ImuSeries]) -> ImuSeries:
    """``s`` with the times, receive times and sample counts of a series ``made`` before it where they
    are the same (a frame's accelerometer and gyro: 86 MB for a 1-hour 1 kHz log), not a copy."""
    for o in made.values():
        if len(o) == len(s) and np.array_equal(o.t, s.t) and np.array_equal(o.t_rx, s.t_rx):
            samples = o.samples if np.array_equal(o.samples, s.samples) else s.samples
            return ImuSeries(s.source, o.t, o.t_rx, s.value, samples)
    return s


def _one_type(ps: list[tuple[np.ndarray, ...]]) -> list[tuple[np.ndarray, ...]]:
    """A series' parts with their values of one type: float32 where each is (the columns', as
    sent; the receiver's readings of a HIGHRES_IMU, widened from those), else float64."""
    if all(p[3].dtype == np.float32 for p in ps):
        return ps
    if all(p[3].dtype == np.float32 or np.array_equal(p[3].astype(np.float32), p[3]) for p in ps):
        return [(*p[:3], p[3].astype(np.float32)) for p in ps]
    return [(*p[:3], p[3].astype(np.float64)) for p in ps]


def _add_columns(
    cols: _Columns,
    taken: np.ndarray,
    t_rec: np.ndarray,
    link_name: str,
    parts: dict[tuple[Kind, int], list[tuple[np.ndarray, ...]]],
    first: dict[tuple[Kind, int], tuple[int, str]],
) -> None:
    """The accelerometer's and gyro's columns of the frames ``taken``, per (kind, instance)."""
    upd, inst = cols.updated, cols.instance
    for kind, bits in ((Kind.ACCEL, _ACC), (Kind.GYRO, _GYRO)):
        # taken out of the frames' columns, so that they are let go of once cut into the series'
        # parts (a 1-hour 1 kHz log's are 86 MB a sensor)
        if kind is Kind.ACCEL:
            values, cols.acc = cols.acc, _NONE
        else:
            values, cols.gyro = cols.gyro, _NONE
        has = taken & ((upd & bits) != 0)
        for i in np.unique(inst[has]).tolist():
            sel = has & (inst == i)
            v = values[sel]  # float32 as sent: the receiver's float64 of them exactly
            r = cols.record[sel]
            parts.setdefault((kind, i), []).append((r, cols.t[sel], t_rec[r], v))
            k0 = int(np.argmax(sel))
            first[(kind, i)] = (int(r[0]), f"{link_name}/{int(cols.sysid[k0])}.{int(cols.compid[k0])}")
        del values
