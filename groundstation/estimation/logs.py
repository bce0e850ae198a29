"""Any supported log in, measurements out: a tlog through the live receive path, an ArduPilot
DataFlash log, a PX4 ULog or a Crazyflie uSD log through their readers (the Crazyflie's tilt
derived from its gyro, :mod:`.derived`). Recognised by content, not by extension.

:func:`load_log` also gives the log's other records as tables (:mod:`drivers.logs.tables`:
events, modes, vibration, motors, the autopilot's own filter, parameters) for the triage."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from drivers.logs.crazyflie import is_crazyflie_log, read_crazyflie
from drivers.logs.crazyflie import measurements as cf_measurements
from drivers.logs.dataflash import is_dataflash, read_dataflash
from drivers.logs.tables import LogTables, tables_from_tlog
from drivers.logs.tlog_reader import IMU_MESSAGES, read_tlog
from drivers.logs.ulog import is_ulog, read_ulog
from drivers.mavlink.link import GCS_SYSTEM_ID
from drivers.replay import Replay
from groundstation.core.counts import counted
from groundstation.core.imu import ImuColumns, block_means
from groundstation.core.measurement import Kind, Measurement, source_system
from groundstation.core.readings import Readings

from .derived import with_attitude
from .stated import GROUND_KINDS, STATED_TABLES, RangeClearance, clearance_effect, range_clearance


def _reader_skipped(skipped) -> str:
    """The reader's counted skips of readings (not the streams it does not convert)."""
    text = counted({k: n for k, n in skipped.items() if not k.startswith("not_converted:")})
    return f"; the reader skipped {text}" if text else ""


@dataclass
class LoadedLog:
    #: in time order; with ``imu_columns`` held as columns (:class:`~groundstation.core.readings.Readings`)
    measurements: Sequence[Measurement]
    description: str  # one line: format, duration, damage, skips
    vehicle: str | None  # the vehicle configuration the log implies, if any
    tables: LogTables = field(default_factory=LogTables)
    #: with ``imu_columns``: the raw accelerometer and gyro as columns, not among ``measurements``
    imu: ImuColumns | None = None
    damage: str = ""  #: a tlog's damage, one line (also in ``description``)
    ground_stations: frozenset[int] = frozenset()  #: a tlog's system ids of ground stations


def load_log(path: Path, *, tables: bool | tuple[str, ...] = True, imu_columns: bool = False) -> LoadedLog:
    """Any supported log -> its measurements, a description, the vehicle it implies, and (with
    ``tables``) its other records as tables: all of them, or a tuple of the message types wanted (a
    tlog's others are then not read; the other formats' readers make every table or none, and a
    ULog's are made in any case). ``imu_columns``: the raw IMU as columns
    (:class:`~groundstation.core.imu.ImuColumns`) instead of records, a tenth of the memory of a
    1 kHz log's (a tlog's are never held as records, and its IMU frames are converted as columns:
    :mod:`drivers.logs.tlog_reader`), and the other readings as
    :class:`~groundstation.core.readings.Readings`."""

    def split(ms):
        if not imu_columns:
            return list(ms), None
        rest, imu = ImuColumns.split(ms)
        return Readings.of(rest), imu

    if is_crazyflie_log(path):
        log = read_crazyflie(path)
        ms, imu = split(with_attitude(cf_measurements(log)))
        desc = f"Crazyflie uSD log, {log.duration:.1f} s, {len(ms) + len(imu or ())} measurements" + (
            f"; {log.damage}" if log.damage else ""
        )
        return LoadedLog(ms, desc + _reader_skipped(log.skipped), "crazyflie", LogTables(fmt="crazyflie"), imu)
    if is_dataflash(path):
        df = read_dataflash(path, tables=bool(tables), imu_columns=imu_columns)
        n = len(df.measurements) + (len(df.imu) if df.imu is not None else 0)
        desc = (
            f"ArduPilot DataFlash log, {df.duration:.1f} s, {n} measurements (clock: {df.clock})"
            + (f"; {df.damage}" if df.damage else "")
            + _reader_skipped(df.skipped)
        )
        if df.imu is not None:  # read as columns already
            return LoadedLog(Readings.of(df.measurements), desc, None, df.tables, df.imu)
        ms, imu = split(df.measurements)
        return LoadedLog(ms, desc, None, df.tables, imu)
    if is_ulog(path):
        ul = read_ulog(path, imu_columns=imu_columns)
        desc = (
            f"PX4 ULog{f' ({ul.hardware})' if ul.hardware else ''}, {ul.duration:.1f} s, "
            f"{len(ul.measurements) + (len(ul.imu) if ul.imu is not None else 0)} measurements"
            + (f"; {ul.damage}" if ul.damage else "")
            + _reader_skipped(ul.skipped)
        )
        if ul.imu is not None:  # read as columns already
            return LoadedLog(Readings.of(ul.measurements), desc, None, ul.tables, ul.imu)
        ms, imu = split(ul.measurements)
        return LoadedLog(ms, desc, None, ul.tables, imu)
    if imu_columns:
        tl = read_tlog(path)
        desc = f"MAVLink tlog, {tl.duration:.1f} s" + (f"; {tl.damage}" if tl.damage else "")
        # without the IMU's own messages: their samples are the columns
        if isinstance(tables, tuple):
            tab = tables_from_tlog(path, index=tl.index, only=tables)
        elif tables:
            tab = tables_from_tlog(path, index=tl.index, without=IMU_MESSAGES)
        else:
            tab = LogTables(fmt="tlog", clock="recording")
        return LoadedLog(tl.measurements, desc, None, tab, tl.imu, tl.damage, tl.ground_stations)
    rp = Replay(path)  # every reading a record, as the live receive path gives them
    ms = list(rp.iter_measurements())
    damage = rp.skipped_summary()
    desc = f"MAVLink tlog, {rp.duration:.1f} s" + (f"; {damage}" if damage else "")
    del rp  # the file's bytes and index, before the tables read them again
    if isinstance(tables, tuple):
        tab = tables_from_tlog(path, only=tables)
    else:
        tab = tables_from_tlog(path) if tables else LogTables(fmt="tlog", clock="recording")
    return LoadedLog(ms, desc, None, tab, None, damage)


def load_measurements(path: Path) -> tuple[list[Measurement], str, str | None]:
    """Any supported log -> (measurements in time order, a one-line description,
    the vehicle configuration it implies)."""
    log = load_log(path, tables=False)  # the measurements alone: the records' tables are not built
    return list(log.measurements), log.description, log.vehicle


#: [s] the IMU's block for a run over a whole log (the diagnosis's runs take the same)
IMU_BLOCK_S = 0.01


@dataclass
class BlockedLog:
    """A log made ready for one estimator run over all of it (:func:`load_blocked`)."""

    measurements: list[Measurement]  #: every reading, the IMU's as block means, in time order
    readings: int  #: the readings these stand for (each IMU sample one)
    description: str
    vehicle: str | None
    damage: str
    ground_stations: frozenset[int]
    #: the downward rangefinder's reading on the ground, as the log states it (:mod:`.stated`)
    clearance: RangeClearance | None = None

    @property
    def stated(self) -> list[dict]:
        """What the log states of its sensors, as effects an estimator is built with
        (:func:`~groundstation.estimation.registry.build_estimator`'s ``stated``)."""
        return [clearance_effect(self.clearance)] if self.clearance is not None else []


def load_blocked(path: Path, imu_dt: float = IMU_BLOCK_S) -> BlockedLog | None:
    """Any supported log with its IMU as ``imu_dt`` block means, for a run of an estimator over the
    whole of it: a 1 kHz IMU's log is a fifth of the records to estimate, read as columns (a
    10-minute log replays in 16 s instead of 56). None for a log of more than one vehicle (its IMU
    columns are kept per kind and instance, not per vehicle).

    A block's mean is held as the input over exactly the interval it averages
    (:func:`~groundstation.core.imu.block_means`), as a live loop under load and the diagnosis's
    runs take it. For the altitude filter a prediction over the block's mean and ten over its
    samples differ by the samples' spread times dt^2: well under a millimetre.
    Readings are in the order of their vehicle time (the order a live loop restores within its
    reorder window), at equal times in the file's; one with no vehicle time (a message whose clock
    never came), which an estimation loop passes over, is left out."""
    log = load_log(path, tables=STATED_TABLES, imu_columns=True)
    imu = log.imu if log.imu is not None else ImuColumns()
    every = Readings.of(log.measurements)
    sources = {s.source for s in every.streams} | {s.source for s in imu.series.values()}
    systems = {source_system(s) for s in sources}
    systems -= {None, GCS_SYSTEM_ID, *log.ground_stations}  # a ground station's own commands are no vehicle's
    if len(systems) > 1:
        return None
    for (kind, inst), s in imu.series.items():
        every = every + block_means(s, kind, inst, imu_dt).readings
    clearance = range_clearance(log.tables, every.only(GROUND_KINDS)) if Kind.RANGE in every.kinds() else None
    if clearance is not None and not clearance.metres:
        clearance = None  # a range that reads 0 on its gear has no offset to take (as the diagnosis's setup)
    ms = list(every.where(every.t == every.t).in_time_order())
    return BlockedLog(
        ms, len(log.measurements) + len(imu), log.description, log.vehicle, log.damage, log.ground_stations, clearance
    )
