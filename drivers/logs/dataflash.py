"""ArduPilot DataFlash logs (binary ``.bin`` and text ``.log``) to measurements.

Parsing is pymavlink's ``DFReader`` (it reads the self-describing FMT records);
this module maps channels to measurements and fixes the time base.

Time: ``TimeUS`` [us] or ``TimeMS`` [ms] where a record has one. Old text logs
(``underpowered.log``) have no time field at all and DFReader makes up a clock;
there, as the data README says, time is the row count of the 10 Hz control
loop: ``t = (CTUN records so far) / 10`` for every record.

=========  =====================================  ====================================
record     fields                                 measurement
=========  =====================================  ====================================
IMU, IMU2  AccX/Y/Z [m/s^2], GyrX/Y/Z [rad/s]     ACCEL, GYRO (FRD already); IMU2 or I -> instance
BARO       Alt [m], Press [Pa], Temp [degC]       BARO_ALTITUDE, BARO_PRESSURE, TEMPERATURE [K]; I
CTUN       ThrOut/ThO (0..1000 old, 0..1 new),    THROTTLE [0..1]; BarAlt/BAlt -> BARO_ALTITUDE
           BarAlt/BAlt [m], SonAlt/SAlt [m]       (only in logs without BARO); SonAlt -> RANGE (only in
                                                  logs without RFND; inside the limits, see below)
RFND       Dist [m] (3.x: Dist1 [cm]), Stat,      RANGE, downward (Orient 25) and good (Stat 4) only;
           Orient, Instance                       inside the limits
CURR       Volt, Curr (V x 100, A x 100 in old)   BATTERY_VOLTAGE [V], BATTERY_CURRENT [A] (0: not connected)
BAT        Volt [V], Curr [A], Inst               BATTERY_VOLTAGE, BATTERY_CURRENT
MAG        MagX/Y/Z [milligauss], I               MAG [T]
ATT        Roll, Pitch, Yaw [deg]                 ATTITUDE [rad]
GPS        Lat, Lng [deg], Alt [m], Status, I     GPS (3-D fix only)
           Spd [m/s], GCrs [deg], VZ [m/s]        VELOCITY_NED (vn, ve from the ground speed and
                                                  course; vd = VZ, NED), with the fix; VZ
                                                  alone as GPS_VD, the fix's own
RCOU       C1..C14 [us]                           ACTUATOR, (us - 1000) / 1000
PARM, MSG  FRAME_CLASS, "Frame: HEXA/X"           VEHICLE_STATUS's mav_type, at the first sample
                                                  (:mod:`.frame`: which outputs are motors)
=========  =====================================  ====================================

Every record, these and the rest (ERR, EV, MODE, MSG, VIBE, XKF*, NKF*, EKF*, ...), is also kept
as columns in :attr:`DataFlashLog.tables` (:mod:`.tables`), with the log's parameters.

The rangefinder's limits come from the log's own parameters (PARM), as the MAVLink driver takes
DISTANCE_SENSOR's ``min_distance``/``max_distance``: ``RNGFND_MIN_CM``/``RNGFND_MAX_CM`` (or
``RNGFND1_*``) where the log has them, else ArduCopter 3.0-3.1's ``SONAR_TYPE`` with the
limits its MaxBotix driver sets (``AP_RangeFinder_MaxsonarXL.h``). A reading at or beyond a
limit is the sensor's clamp, not a distance: an analog sonar reads its floor for anything closer
and its maximum when no echo comes back. ``underpowered.log`` (SONAR_TYPE 0, an XL-EZ0: 20-765 cm)
holds 304 readings of exactly 0.20 m and 260 of exactly 7.65 m, most of them on the ground, where
a replay had shown the vehicle 7.65 m up before it took off. They are skipped and counted
(``range_out_of_bounds``).
"""

from __future__ import annotations

import contextlib
import math
from array import array
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink import DFReader
from pymavlink.dialects.v20 import common as mavlink

from groundstation.core.imu import ImuColumns, ImuSeries
from groundstation.core.measurement import Kind, Measurement

from .bulk import DataFlashWalk, dataflash_dtype, dataflash_values, fmt_length_ok, struct_dtype, walk_dataflash
from .dataflash_text import TextReader
from .frame import frame_status, mav_type_of_params, mav_type_of_text
from .quiet import quiet
from .scratch import scratch_copy
from .tables import FIRMWARE, LogTables, Table

CONTROL_RATE = 10.0  # CTUN's rate in logs without a clock [Hz]
_FMT_RECORD = 128  # the FMT record's own type id

#: ArduCopter 3.0-3.1's SONAR_TYPE: (min, max) [cm] of its MaxBotix driver
#: (libraries/AP_RangeFinder/AP_RangeFinder_MaxsonarXL.h: XL-EZ0, LV-EZ0, XL-EZL0; HRLV-EZ4)
SONAR_TYPE_LIMITS_CM = {0: (20.0, 765.0), 1: (15.0, 645.0), 2: (20.0, 1068.0), 3: (30.0, 500.0)}


class DataFlashError(ValueError):
    """Not a readable DataFlash log (one line naming the file)."""


def is_dataflash(path: str | Path) -> bool:
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return False
    # binary: the record header 0xA3 0x95; text: FMT lines near the top (after a banner)
    return head[:2] == b"\xa3\x95" or b"\nFMT," in b"\n" + head


@dataclass
class DataFlashLog:
    path: Path
    measurements: list[Measurement]
    counts: Counter = field(default_factory=Counter)
    skipped: Counter = field(default_factory=Counter)
    clock: str = "TimeUS/TimeMS"
    damage: str = ""  # one line naming the file and the offsets of damage, or ''
    range_limits: tuple[float, float] | None = None  # [m], from the log's parameters, if it has them
    #: every record type as columns on the measurements' clock, and the parameters (for triage)
    tables: LogTables = field(default_factory=LogTables)
    #: with ``imu_columns``, where the log allows (:func:`read_dataflash`): the IMU records' readings as
    #: columns, not among :attr:`measurements`
    imu: ImuColumns | None = None

    @property
    def duration(self) -> float:
        ts = [self.measurements[0].t, self.measurements[-1].t] if self.measurements else []
        for series in self.imu.series.values() if self.imu is not None else ():  # read as columns
            if len(series):
                ts += [float(series.t[0]), float(series.t[-1])]
        return max(ts) - min(ts) if ts else 0.0


def read_dataflash(
    path: str | Path, source: str = "df/1.1", *, tables: bool = True, imu_columns: bool = False
) -> DataFlashLog:
    """The log's measurements and, with ``tables``, every record as columns (:attr:`DataFlashLog.tables`;
    a third of the reading time, which a caller of the measurements alone does not pay). ``imu_columns``:
    the IMU records' readings as columns (:attr:`DataFlashLog.imu`) where the log allows
    (:func:`_imu_records`), read as arrays, not through DFReader a record at a time: they are most of
    a log's records, and most of its reading time."""
    p = Path(path)
    if not p.exists():
        raise DataFlashError(f"{p}: cannot read: no such file")
    if not is_dataflash(p):
        raise DataFlashError(f"{p}: not a DataFlash log (no FMT record in the first 4096 bytes)")
    data = p.read_bytes()
    binary = data[:2] == b"\xa3\x95"
    walk = walk_dataflash(data) if binary else None
    damage = walk.damage(p) if walk is not None else ""
    cleaned = None
    if walk is not None:
        clean_bin, bad_fmts = clean_binary_formats(data, walk)
        if bad_fmts:
            damage = "; ".join(x for x in (damage, f"{p}: {bad_fmts} damaged FMT record(s) skipped") if x)
            cleaned = clean_bin
    else:
        # DFReader reads a text log whole, and one damaged line (a byte that is not text, a field
        # that does not read as its format says) rejected all of it: those lines are dropped first
        clean, dropped = clean_text_log(data)
        if dropped:
            damage = f"{p}: {dropped} damaged line(s) skipped"
            cleaned = clean
    banner = "" if binary else _text_banner(data)
    imu = None
    if imu_columns and walk is not None and cleaned is None and not damage:
        with contextlib.suppress(ValueError, KeyError, TypeError):  # formats it cannot view: record by record
            imu = _imu_records(data, walk, source, tables)
    del data, walk  # DFReader maps the file itself
    with contextlib.ExitStack() as stack:
        read_from = p if cleaned is None else stack.enter_context(scratch_copy(cleaned, ".bin" if binary else ".log"))
        del cleaned
        log = _read(p, read_from, binary, damage, source, tables, imu)
    log.tables.firmware = _firmware(log.tables) or banner
    return log


#: DFReader's format characters by how a text log writes them (pymavlink.DFReader.FORMAT_TO_STRUCT)
_INT_FORMATS = set("bBhHiIMqQ")
_FLOAT_FORMATS = set("gfcCeELd")
_KNOWN_FORMATS = _INT_FORMATS | _FLOAT_FORMATS | set("anNZ")


def clean_binary_formats(data: bytes, walk: DataFlashWalk) -> tuple[bytes, int]:
    """A binary DataFlash log with its damaged FMT records (a format character DFReader does not
    know, a name that is not a name, columns that do not match the format, a length that is not the
    format's: DFReader steps by it, and a 0 never leaves the record) unmade: their header
    bytes zeroed, so that DFReader resyncs over them and skips that type's records instead of
    rejecting the whole log.

    An FMT header's three bytes inside a record the log's ``walk`` stepped over are
    that record's data, not an FMT (a 5.9 MB log of another generator's had them once, in a float):
    only the FMT records the walk found and what lies in its damaged stretches, where DFReader
    resyncs byte by byte, are looked at. Read as an FMT, the payload's two bytes would be zeroed and
    a whole log read record by record, said to be damaged."""
    out: bytearray | None = None
    bad = 0
    walked = set(walk.offsets.get(_FMT_RECORD, ()))
    pos = data.find(b"\xa3\x95\x80")
    while pos >= 0 and pos + 89 <= len(data):
        if pos not in walked and not _in_damage(walk, pos):
            pos = data.find(b"\xa3\x95\x80", pos + 3)
            continue
        name = data[pos + 5 : pos + 9].rstrip(b"\0")
        fmt = data[pos + 9 : pos + 25].rstrip(b"\0")
        cols = data[pos + 25 : pos + 89].rstrip(b"\0").split(b",")
        ok = (
            name.isalnum()
            and bool(fmt)
            and all(chr(c) in _KNOWN_FORMATS for c in fmt)
            and len(cols) == len(fmt)
            and fmt_length_ok(data[pos + 4], fmt.decode("ascii"))
        )
        if not ok:
            if out is None:
                out = bytearray(data)
            out[pos : pos + 2] = b"\0\0"
            bad += 1
        pos = data.find(b"\xa3\x95\x80", pos + 3)
    return (bytes(out) if out is not None else data), bad


def _in_damage(walk: DataFlashWalk, pos: int) -> bool:
    """``pos`` lies in bytes the walk resynced over, or past where it found the log cut."""
    if walk.truncated_at is not None and pos >= walk.truncated_at:
        return True
    return any(start <= pos < start + n for start, n in walk.skipped)


def clean_text_log(data: bytes) -> tuple[bytes, int]:
    """A text DataFlash log with the lines DFReader would fail on dropped: bytes that are not text,
    an FMT line that does not define a format, a record of a known format whose fields do not read
    as that format says. Returns the kept text and how many lines were dropped."""
    formats: dict[str, str] = {}
    kept, dropped = [], 0
    for raw in data.split(b"\n"):
        if not raw.strip():
            kept.append(raw)
            continue
        if max(raw) >= 0x80:
            dropped += 1
            continue
        fields = [f.strip() for f in raw.decode("ascii").rstrip("\r").split(",")]
        name = fields[0]
        if name == "FMT":
            ok = len(fields) >= 5 and fields[1].isdigit() and fields[2].isdigit() and fields[3].isidentifier()
            ok = ok and set(fields[4]) <= _KNOWN_FORMATS and len(fields) - 5 == len(fields[4])
            if not ok:
                dropped += 1
                continue
            formats[fields[3]] = fields[4]
        elif name in formats and not _fields_read(formats[name], fields[1:]):
            dropped += 1
            continue
        kept.append(raw)
    return b"\n".join(kept), dropped


def _fields_read(fmt: str, values: list[str]) -> bool:
    if len(values) < len(fmt):
        return False
    try:
        for ch, v in zip(fmt, values):
            if ch == "M" and not v.lstrip("-").isdigit():
                continue  # a flight mode: a text log writes its name (STABILIZE), a binary one its number
            if ch in _INT_FORMATS:
                int(v)
            elif ch in _FLOAT_FORMATS:
                float(v)
    except ValueError:
        return False
    return True


def _read(
    p: Path, read_from: Path, binary: bool, damage: str, source: str, tables: bool, imu: _ImuRecords | None = None
) -> DataFlashLog:
    """One pass over DFReader's messages, each converted and tabled as it comes and let go: held as
    a list, a 10 MB log of tiny records took 1.6 GB. What the conversion needs to know of the whole
    log first (its parameters, which sensors it has, whether its records carry a clock) comes from
    DFReader's own index and formats and a pass over the PARM records alone. With ``imu``, the IMU
    records read already: DFReader is taken to every other record, and passes over those."""
    # DFReader (and its compiled indexer, at the file-descriptor level) prints a
    # line per bad byte while it resyncs; the walk above has already located the
    # damage, so that chatter is dropped.
    with quiet():
        try:
            r = DFReader.DFReader_binary(str(read_from)) if binary else _text_reader(read_from)
            params = _parameters(r)
        except Exception as e:  # DFReader raises assorted errors on foreign data
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise DataFlashError(f"{p}: not a readable DataFlash log: {first}") from None
        present = _record_counts(r)
        columns = {f.name: set(f.columns) for f in r.formats.values()}
        timed = any(present[t] and columns.get(t, set()) & {"TimeUS", "TimeMS"} for t in ("CTUN", "IMU", "ATT"))
        log = DataFlashLog(p, [], Counter(), damage=damage, range_limits=rangefinder_limits(params))
        log.tables = LogTables(params=params, fmt="dataflash", autopilot="ardupilot")
        if not timed:
            log.clock = f"row count of CTUN / {CONTROL_RATE:g} Hz"
        has_baro, has_rfnd = present["BARO"] > 0, present["RFND"] > 0
        mav_type = mav_type_of_params(params)
        rows: dict[str, _Columns] = {}
        n_ctun = 0
        # DFReader's clock minus the records' own (TimeUS/TimeMS): a record without a time field
        # (ERR, EV, MODE, old GPS) is put on the same clock as the records around it
        offset: float | None = None
        first_stamp: float | None = None
        out = log.measurements
        others = iter(imu.others.tolist()) if imu is not None else None
        #: with records read as arrays: each measurement's record offset, the tie-break of the sort by
        #: time (the file's order, as the stable sort of the records read one by one keeps it)
        at_offset = array("q")
        merged = imu is not None and bool(imu.measured)
        here = 0
        while True:
            if others is not None:
                at = next(others, None)
                if at is None:
                    break
                # the next record not read already (DFReader's own cursor, as its skip_to_type sets it)
                r.offset = here = at
            try:
                m = r.recv_msg()
            except Exception as e:  # damage after this point: keep what came before
                log.skipped["damage"] += 1
                log.damage = "; ".join(
                    x for x in (log.damage, f"{p}: unreadable after record {sum(log.counts.values())}: {e}") if x
                )
                break
            if m is None:
                break
            typ = m.get_type()
            log.counts[typ] += 1
            if mav_type is None and typ == "MSG":
                mav_type = mav_type_of_text(str(getattr(m, "Message", "")))
            if typ == "CTUN":
                n_ctun += 1
            stamp = getattr(m, "_timestamp", None)
            if first_stamp is None and stamp is not None:
                first_stamp = stamp
            try:
                if timed:
                    if hasattr(m, "TimeUS"):
                        t = m.TimeUS * 1e-6
                    elif hasattr(m, "TimeMS") and typ != "GPS":  # GPS TimeMS is GPS time of week
                        t = m.TimeMS * 1e-3
                    elif typ == "GPS" and hasattr(m, "T"):  # ArduCopter 3.x: T is the boot time [ms]
                        t = m.T * 1e-3
                    elif stamp is not None:
                        t = stamp - (offset if offset is not None else first_stamp)
                    else:
                        t = math.nan
                    if stamp is not None and (hasattr(m, "TimeUS") or (hasattr(m, "TimeMS") and typ != "GPS")):
                        offset = stamp - t
                else:
                    t = n_ctun / CONTROL_RATE
                if tables and typ not in _NOT_TABLED:  # (first: a record the conversion cannot use is still one)
                    cols = rows.get(typ)
                    if cols is None:
                        cols = rows[typ] = _Columns()
                    cols.add(t, m.to_dict())
                _convert(typ, m, t, source, has_baro, has_rfnd, log.range_limits, out, log.skipped)
            except (ValueError, TypeError, AttributeError, IndexError, OverflowError):
                # a record whose fields do not read as their format says (a damaged line or block):
                # skipped and counted, the rest of the log kept
                log.skipped["damaged_record"] += 1
            if merged:
                at_offset.extend([here] * (len(out) - len(at_offset)))
    if imu is not None and merged:
        out.extend(imu.measured)
        at_offset.extend(imu.measured_at.tolist())
        order = np.lexsort((np.frombuffer(at_offset, dtype=np.int64), np.array([m.t for m in out])))
        log.measurements = out = [out[i] for i in order.tolist()]
    else:
        out.sort(key=lambda x: x.t)
    if mav_type is not None and out:
        # the frame the log states, as the HEARTBEAT a tlog would carry: from the log's first sample
        t0 = min(out[0].t, imu.columns.start) if imu is not None else out[0].t
        out.insert(0, frame_status(t0, mav_type, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, source))
    log.tables.tables = {typ: cols.table() for typ, cols in rows.items()}
    if imu is not None:
        log.imu = imu.columns
        log.counts.update(imu.counts)
        log.tables.tables.update(imu.tables)
    return log


#: the records :func:`_convert` reads the IMU from, and the format characters their fast read takes:
#: numbers DFReader gives as they are stored (no multiplier, no text)
_IMU_RECORDS = ("IMU", "IMU2")
_PLAIN_NUMBERS = set("bBhHiIqQfd")
#: the attitude's record, read as arrays beside the IMU where its fields allow: Copter 4.x logs it at
#: the IMU's rate (400 Hz), and record by record it is most of the reading the IMU's arrays leave (2.0
#: of a 5.9 MB log's 2.7 s); and the format characters that read takes besides the plain numbers:
#: DFReader's scaled integers (centi-units, 1e-7 degrees), scaled as DFReader scales them
#: (:func:`.bulk.dataflash_values`)
_ATTITUDE = "ATT"
_SCALED_NUMBERS = set("cCeEL")


@dataclass
class _ImuRecords:
    """A binary log's IMU records read as arrays (:func:`_imu_records`)."""

    columns: ImuColumns
    tables: dict[str, Table]
    counts: Counter
    others: np.ndarray  #: every other record's offset, in the file's order
    #: the attitude's measurements where read as arrays (:data:`_ATTITUDE`), and their records' offsets
    measured: list[Measurement] = field(default_factory=list)
    measured_at: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


def _imu_records(data: bytes, walk: DataFlashWalk, source: str, tables: bool) -> _ImuRecords | None:
    """The IMU records' readings as columns, the same numbers, times and order as :func:`_convert`'s
    records of them (``ImuColumns.split``) and the same tables, read per record type as arrays; and
    the attitude's measurements, the same as :func:`_convert`'s, where its fields allow (:data:`_ATTITUDE`).
    None where the log does not allow it: every record but the formats' own must carry ``TimeUS``
    (a record's time is then its own, whatever DFReader reads before it: see :func:`_read`), and the
    IMU's fields must be plain numbers (:data:`_PLAIN_NUMBERS`)."""
    u8 = np.frombuffer(data, dtype=np.uint8)
    imu_types: dict[int, str] = {}
    att_type = None
    for typ, (name, fmt, cols) in walk.fmts.items():
        if typ not in walk.offsets or not len(walk.offsets[typ]):
            continue
        if "TimeUS" not in cols and name not in ("FMT", "FMTU", "UNIT", "MULT"):
            return None
        if name in _IMU_RECORDS:
            plain = set(fmt) <= _PLAIN_NUMBERS and len(fmt) == len(cols) == len(set(cols))
            if not plain or not {"AccX", "AccY", "AccZ", "GyrX", "GyrY", "GyrZ"} <= set(cols):
                return None
            imu_types[typ] = name
        elif name == _ATTITUDE and set(fmt) <= _PLAIN_NUMBERS | _SCALED_NUMBERS:
            distinct = len(fmt) == len(cols) == len(set(cols))
            att_type = typ if distinct and {"Roll", "Pitch"} <= set(cols) else None
    if not imu_types or any(typ not in walk.fmts for typ in walk.offsets if typ != _FMT_RECORD):
        return None
    growing: dict[tuple[Kind, int], list] = {}
    out_tables: dict[str, Table] = {}
    counts: Counter = Counter()
    for typ, name in imu_types.items():
        _, fmt, cols = walk.fmts[typ]
        offs = np.frombuffer(walk.offsets[typ], dtype=np.int64)
        width = walk.length[typ] - 3
        rows = np.lib.stride_tricks.sliding_window_view(u8, width)[offs + 3]
        f = np.frombuffer(np.ascontiguousarray(rows).tobytes(), dtype=struct_dtype("".join(fmt), cols))
        t = f["TimeUS"].astype(np.float64) * 1e-6
        inst = f["I"].astype(np.int64) if "I" in cols else np.full(len(f), 1 if name == "IMU2" else 0)
        counts[name] += len(f)
        if tables:
            out_tables[name] = Table(t, {c: f[c].astype(np.float64) for c in cols})
        for k in np.unique(inst).tolist():
            mine = inst == k
            for kind, axes in ((Kind.ACCEL, ("AccX", "AccY", "AccZ")), (Kind.GYRO, ("GyrX", "GyrY", "GyrZ"))):
                v = np.stack([f[a][mine].astype(np.float64) for a in axes], axis=1)
                growing.setdefault((kind, int(k)), []).append((t[mine], v))
    series = {}
    for key, parts in growing.items():
        t = np.concatenate([p[0] for p in parts])
        v = np.concatenate([p[1] for p in parts])
        order = np.argsort(t, kind="stable")
        series[key] = ImuSeries(source, t[order], t[order], v[order], np.ones(len(t), dtype=np.int32))
    measured: list[Measurement] = []
    measured_at = np.zeros(0, dtype=np.int64)
    if att_type is not None:
        _, fmt, cols = walk.fmts[att_type]
        measured_at = np.frombuffer(walk.offsets[att_type], dtype=np.int64)
        width = walk.length[att_type] - 3
        rows = np.lib.stride_tricks.sliding_window_view(u8, width)[measured_at + 3]
        raw = np.frombuffer(np.ascontiguousarray(rows).tobytes(), dtype=dataflash_dtype(fmt, cols))
        values = {c: dataflash_values(raw[c], ch) for c, ch in zip(cols, fmt)}
        t = raw["TimeUS"].astype(np.float64) * 1e-6
        counts[_ATTITUDE] += len(raw)
        if tables:
            out_tables[_ATTITUDE] = Table(t, values)
        yaw = values.get("Yaw", np.full(len(t), math.nan))
        angles = np.radians(np.stack([values["Roll"], values["Pitch"], yaw], axis=1))
        measured = [Measurement(tk, Kind.ATTITUDE, a, source, tk, None, 0) for tk, a in zip(t.tolist(), angles)]
    skip = {*imu_types, att_type}
    others = np.sort(
        np.concatenate([np.frombuffer(o, dtype=np.int64) for typ, o in walk.offsets.items() if typ not in skip])
    )
    return _ImuRecords(ImuColumns(series), out_tables, counts, others, measured, measured_at)


def _text_reader(path: Path):
    """pymavlink's text reader, or the project's where pymavlink's cannot set up its clock
    (:mod:`.dataflash_text`: ArduCopter 3.0's GPS records without a week)."""
    try:
        return DFReader.DFReader_text(str(path))
    except (TypeError, ValueError, AttributeError, KeyError, ZeroDivisionError):
        return TextReader(path)


def _parameters(r) -> dict[str, float]:
    """The log's PARM records (the last value of each), read ahead of the rest: the rangefinder's
    limits the conversion checks readings against are among them. The reader is rewound after."""
    params: dict[str, float] = {}
    while True:
        try:
            m = r.recv_match(type="PARM")
        except Exception:  # damage: the parameters before it are kept, the main pass says where
            break
        if m is None:
            break
        with contextlib.suppress(ValueError, TypeError, AttributeError):
            params[str(m.Name)] = float(m.Value)
    r.rewind()
    return params


def _record_counts(r) -> Counter:
    """Records per type name, from DFReader's index (a list by type id in a binary log, a dict by
    name in a text one)."""
    if isinstance(r.counts, dict):
        return Counter({str(k): int(c) for k, c in r.counts.items() if c})
    return Counter({r.id_to_name[i]: int(c) for i, c in enumerate(r.counts) if c and i in r.id_to_name})


class _Columns:
    """One record type's rows gathered as columns as they come: 8 bytes a number (a row as a dict
    was some 300 bytes), text as a list. A field a row lacks is NaN (numbers) or '' (text), as
    :func:`~.tables.table_from_rows` makes them."""

    def __init__(self) -> None:
        self.t = array("d")
        self.cols: dict[str, array | list] = {}

    def add(self, t: float, row: dict) -> None:
        n = len(self.t)
        for k, v in row.items():
            if k == "mavpackettype":
                continue
            col = self.cols.get(k)
            number = isinstance(v, (int, float)) and not isinstance(v, bool)
            if col is None:
                col = self.cols[k] = array("d", [math.nan]) * n if number or v is None else [""] * n
            elif len(col) < n:  # a field the rows before this one lacked
                col.extend(array("d", [math.nan]) * (n - len(col)) if isinstance(col, array) else [""] * (n - len(col)))
            if isinstance(col, array):
                if number:
                    col.append(v)
                    continue
                if v is None:
                    col.append(math.nan)
                    continue
                col = self.cols[k] = [_as_text(x) for x in col]  # a text value in a number's column
            col.append("" if v is None else _as_text(v))
        self.t.append(t)

    def table(self) -> Table:
        n = len(self.t)
        out: dict[str, np.ndarray] = {}
        for k, col in self.cols.items():
            if isinstance(col, array):
                a = np.frombuffer(col, dtype=float) if len(col) else np.zeros(0)
                out[k] = np.concatenate([a, np.full(n - len(a), math.nan)]) if len(a) < n else a
            else:
                out[k] = np.array(col + [""] * (n - len(col)), dtype=object)
        return Table(np.frombuffer(self.t, dtype=float) if n else np.zeros(0), out)


def _as_text(v) -> str:
    """A value of a text column, as :func:`~.tables.table_from_rows` writes it."""
    return v.split(b"\0", 1)[0].decode("latin-1") if isinstance(v, bytes) else str(v)


#: record types that describe the log itself (formats, units, parameters: read above), not the flight
_NOT_TABLED = frozenset({"FMT", "FMTU", "UNIT", "MULT", "PARM"})


def _text_banner(data: bytes) -> str:
    """A text log's firmware banner: a line of its own before the records ("ArduCopter V3.0.1"),
    which DFReader passes over."""
    for line in data[:65536].splitlines():
        text = line.decode("latin-1", "replace").strip()
        if FIRMWARE.match(text):
            return text
    return ""


def _firmware(tables: LogTables) -> str:
    """The firmware's banner among the records: VER's FWS (ArduPilot 4.x) or the first MSG that is one."""
    ver = tables.get("VER")
    if ver is not None and "FWS" in ver and len(ver["FWS"]) and str(ver["FWS"][0]):
        return str(ver["FWS"][0])
    msg = tables.get("MSG")
    if msg is not None and "Message" in msg:
        return next((str(x) for x in msg["Message"] if FIRMWARE.match(str(x))), "")
    return ""


def rangefinder_limits(params: dict[str, float]) -> tuple[float, float] | None:
    """The first rangefinder's (min, max) [m] from a log's parameters, or None if it does not say."""
    for prefix in ("RNGFND1_", "RNGFND_"):
        lo, hi = params.get(prefix + "MIN_CM"), params.get(prefix + "MAX_CM")
        if lo is not None and hi is not None and 0 <= lo < hi:
            return lo / 100.0, hi / 100.0
    if params.get("SONAR_ENABLE") and int(params.get("SONAR_TYPE", -1)) in SONAR_TYPE_LIMITS_CM:
        lo, hi = SONAR_TYPE_LIMITS_CM[int(params["SONAR_TYPE"])]
        return lo / 100.0, hi / 100.0
    return None


def _convert(typ, m, t, s, has_baro, has_rfnd, range_limits, out, skipped) -> None:
    def add(kind, value, instance=0):
        out.append(Measurement(t, kind, np.asarray(value, dtype=float), s, t, None, instance))

    if typ in ("IMU", "IMU2"):
        inst = getattr(m, "I", 1 if typ == "IMU2" else 0)
        add(Kind.ACCEL, [m.AccX, m.AccY, m.AccZ], inst)
        add(Kind.GYRO, [m.GyrX, m.GyrY, m.GyrZ], inst)
    elif typ == "BARO":
        inst = int(getattr(m, "I", 0))
        add(Kind.BARO_ALTITUDE, [m.Alt], inst)
        add(Kind.BARO_PRESSURE, [m.Press], inst)
        add(Kind.TEMPERATURE, [m.Temp + 273.15], inst)
    elif typ == "CTUN":
        thr = getattr(m, "ThrOut", getattr(m, "ThO", None))
        if thr is not None:
            add(Kind.THROTTLE, [thr / 1000.0 if thr > 1.5 else thr])
        bar = getattr(m, "BarAlt", getattr(m, "BAlt", None))
        if not has_baro and bar is not None:
            add(Kind.BARO_ALTITUDE, [bar])
        if has_rfnd:  # the rangefinder's own records carry it (RFND), with its status
            return
        son = getattr(m, "SonAlt", getattr(m, "SAlt", None))
        if son is None:
            return  # no sonar column: this CTUN says nothing of a range
        if not son or son <= 0:
            skipped["range_invalid"] += 1
        elif range_limits is not None and not range_limits[0] < son < range_limits[1]:
            skipped["range_out_of_bounds"] += 1  # the sensor's clamp (see the module's docstring)
        else:
            add(Kind.RANGE, [son])
    elif typ == "CURR":
        v, i = m.Volt, m.Curr
        if v > 100:  # old logs: volts x 100, amps x 100
            v, i = v / 100.0, i / 100.0
        if v > 0:
            add(Kind.BATTERY_VOLTAGE, [v])
            add(Kind.BATTERY_CURRENT, [i])
        else:
            skipped["battery_not_connected"] += 1
    elif typ == "ATT":
        add(Kind.ATTITUDE, np.radians([m.Roll, m.Pitch, getattr(m, "Yaw", math.nan)]))
    elif typ == "GPS":
        if getattr(m, "Status", 0) >= 3:
            instance = int(getattr(m, "I", 0))
            add(Kind.GPS, [m.Lat, m.Lng, m.Alt], instance)
            vz = getattr(m, "VZ", None)
            if vz is not None and math.isfinite(vz):  # the fix's own vertical velocity (down)
                add(Kind.GPS_VD, [vz], instance)
            spd, crs = getattr(m, "Spd", None), getattr(m, "GCrs", None)
            if spd is not None and crs is not None and math.isfinite(spd) and math.isfinite(crs):
                c = math.radians(crs)
                add(Kind.VELOCITY_NED, [spd * math.cos(c), spd * math.sin(c), getattr(m, "VZ", math.nan)], instance)
        else:
            skipped["gps_no_3d_fix"] += 1
    elif typ == "RFND":
        # ArduPilot 4.x: Dist [m], Stat (4: good), Orient (25: down); 3.x: Dist1 [cm]
        dist = getattr(m, "Dist", None)
        if dist is None and hasattr(m, "Dist1"):
            dist = m.Dist1 / 100.0
        if dist is None or getattr(m, "Orient", 25) != 25:
            return
        if getattr(m, "Stat", 4) != 4:
            skipped["range_not_good"] += 1
        elif range_limits is not None and not range_limits[0] < dist < range_limits[1]:
            skipped["range_out_of_bounds"] += 1
        else:
            add(Kind.RANGE, [dist], int(getattr(m, "Instance", 0)))
    elif typ == "BAT":
        v, i = getattr(m, "Volt", 0.0), getattr(m, "Curr", 0.0)
        if v > 0:
            inst = int(getattr(m, "Inst", getattr(m, "Instance", 0)))
            add(Kind.BATTERY_VOLTAGE, [v], inst)
            add(Kind.BATTERY_CURRENT, [i], inst)
        else:
            skipped["battery_not_connected"] += 1
    elif typ == "MAG" and hasattr(m, "MagX"):
        if m.MagX == m.MagY == m.MagZ == 0:
            skipped["mag_not_connected"] += 1
        else:  # milligauss -> tesla
            add(Kind.MAG, [m.MagX * 1e-7, m.MagY * 1e-7, m.MagZ * 1e-7], int(getattr(m, "I", 0)))
    elif typ == "RCOU":
        # every output the record has: which of them are motors is the frame's to say (a hexacopter's
        # six), and :mod:`.frame` states it as a vehicle status
        outputs: list[float] = []
        for k in range(1, 15):
            us = getattr(m, f"C{k}", None)
            if us is None:
                us = getattr(m, f"Ch{k}", None)
            if us is None:
                break
            outputs.append((us - 1000.0) / 1000.0 if us else math.nan)
        add(Kind.ACTUATOR, outputs)
