"""Whole logs into numpy arrays, one structured array per message type.

For analysis a log is wanted as columns, not as a stream of objects: ``bulk["HIGHRES_IMU"]["xacc"]``.
pymavlink builds one Python object per message (``mavutil`` ``recv_match``,
``DFReader``), which is the slow part. Here the per-record Python work is only
the walk from one record to the next (the record lengths chain, so the walk is
sequential); everything else is done per message *type* on whole arrays:

* the frames of one (type, length) are gathered into a 2-D byte array;
* MAVLink's CRC-16/MCRF4XX (with the type's CRC_EXTRA) is computed column by
  column for all of them at once (:func:`crc_mcrf4xx_rows`, the same polynomial
  step as pymavlink's ``x25crc``; no library does it across rows);
* the payloads (MAVLink 2 zero-truncated ones padded back) are viewed through a
  numpy structured dtype built from pymavlink's own ``struct`` format and field
  names (MAVLink) or from the log's FMT records and DFReader's
  ``FORMAT_TO_STRUCT`` (DataFlash), multipliers applied.

The values are those pymavlink gives (checked field by field in the tests); the
speed is in ``bench/bulk.py``. Units are the message's own: this is the raw
analysis view; :mod:`drivers.mavlink.decode` does the SI conversion for the
measurement stream.

Damage: a tlog is indexed by :class:`drivers.tlog.TlogIndex` (resync over
garbage, truncated last record); frames that fail the CRC are dropped and
counted per type. A DataFlash binary log with a bad record header is resynced
on the next header, and each skipped stretch is kept with its offset.
"""

from __future__ import annotations

import re
import struct
from array import array
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink import DFReader
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.tlog import TlogIndex

_STRUCT_TO_NUMPY = {
    "b": "i1",
    "B": "u1",
    "h": "<i2",
    "H": "<u2",
    "i": "<i4",
    "I": "<u4",
    "q": "<i8",
    "Q": "<u8",
    "f": "<f4",
    "d": "<f8",
    "e": "<f2",
    "c": "S1",
}


@dataclass
class MessageArrays:
    """All messages of one type: ``fields`` (structured array) and per-record metadata."""

    name: str
    fields: np.ndarray  # structured, one row per message, field names as in the definition
    t: np.ndarray  # tlog: receive time [s, UNIX]; DataFlash: TimeUS/TimeMS [s] or NaN
    sysid: np.ndarray | None = None
    compid: np.ndarray | None = None
    record: np.ndarray | None = None  # tlog: each message's record number in the file's index

    def __len__(self) -> int:
        return len(self.fields)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.fields[name]

    @property
    def names(self) -> tuple[str, ...]:
        return self.fields.dtype.names or ()


@dataclass
class BulkLog:
    path: Path
    messages: dict[str, MessageArrays]
    crc_errors: dict[str, int] = field(default_factory=dict)
    unknown: int = 0  # frames of ids outside the dialect
    undecodable: dict[str, int] = field(default_factory=dict)  # DataFlash types whose FMT we cannot decode
    skipped: list[tuple[int, int]] = field(default_factory=list)  # (offset, bytes) resynced over
    truncated_at: int | None = None

    def __getitem__(self, name: str) -> MessageArrays:
        return self.messages[name]

    def __contains__(self, name: str) -> bool:
        return name in self.messages

    @property
    def count(self) -> int:
        return sum(len(m) for m in self.messages.values())

    def damage_summary(self) -> str:
        parts = []
        if self.crc_errors:
            parts.append(f"{sum(self.crc_errors.values())} bad CRC")
        if self.skipped:
            parts.append(
                f"{sum(n for _, n in self.skipped)} bytes skipped at offset {self.skipped[0][0]}"
                + (f" and {len(self.skipped) - 1} more places" if len(self.skipped) > 1 else "")
            )
        if self.truncated_at is not None:
            parts.append(f"truncated at offset {self.truncated_at}")
        if self.undecodable:
            parts.append(f"records of undecodable formats skipped: {dict(self.undecodable)}")
        return "; ".join(parts)


def struct_dtype(fmt: str, names, scale=None) -> np.dtype:
    """A packed little-endian numpy dtype for a ``struct`` format and its field names."""
    tokens = re.findall(r"(\d*)([a-zA-Z])", fmt.lstrip("<>=!"))
    if len(tokens) != len(names):
        raise ValueError(f"format {fmt!r} has {len(tokens)} fields, names {len(names)}")
    out: list[tuple] = []
    for name, (count, ch) in zip(names, tokens):
        n = int(count) if count else 1
        if ch == "s":
            out.append((name, f"S{n}"))
        elif n > 1:
            out.append((name, _STRUCT_TO_NUMPY[ch], (n,)))
        else:
            out.append((name, _STRUCT_TO_NUMPY[ch]))
    return np.dtype(out)


def crc_mcrf4xx_rows(rows: np.ndarray, extra: int | None = None) -> np.ndarray:
    """CRC-16/MCRF4XX (MAVLink's X.25) of every row of a 2-D uint8 array, vectorised over rows.

    The per-byte step is pymavlink's ``x25crc.accumulate``:
    ``tmp = b ^ (crc & 0xff); tmp ^= tmp << 4 (8 bit); crc = crc>>8 ^ tmp<<8 ^ tmp<<3 ^ tmp>>4``.
    """
    n = rows.shape[0]
    cols = np.empty((rows.shape[1] + (extra is not None), n), dtype=np.uint16)  # byte columns, contiguous
    cols[: rows.shape[1]] = rows.T
    if extra is not None:
        cols[-1] = extra
    crc = np.full(n, 0xFFFF, dtype=np.uint16)
    for b in cols:
        tmp = (b ^ crc) & 0xFF
        tmp ^= (tmp << 4) & 0xFF
        crc = (crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)
    return crc


def _gather(u8: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """The ``width`` bytes from each of ``starts``, as rows (through a strided view: no index matrix
    of 8 bytes per byte gathered)."""
    return np.lib.stride_tricks.sliding_window_view(u8, width)[starts]


# ------------------------------------------------------------------ tlog
_MAV_DTYPES: dict[int, np.dtype] = {}


def _mav_dtype(cls) -> np.dtype:
    dt = _MAV_DTYPES.get(cls.id)
    if dt is None:
        dt = _MAV_DTYPES[cls.id] = struct_dtype(cls.unpacker.format, cls.ordered_fieldnames)
    return dt


#: frames framed and checked at once: the per-frame index arrays (a dozen of 8 bytes) and the gathered
#: rows exist for one chunk at a time, not for the whole file (a 1-hour 1 kHz tlog has 4 million frames)
TLOG_CHUNK = 1 << 16


def load_tlog(
    path: str | Path, *, index: TlogIndex | None = None, only: tuple[str, ...] = (), without: tuple[str, ...] = ()
) -> BulkLog:
    """Every valid message of a tlog as arrays per type (raises :class:`drivers.tlog.TlogError`);
    ``only``: just these types; ``without``: not these. ``index``: the file's index if it is
    already scanned."""
    ix = index if index is not None else TlogIndex.scan(path)
    u8 = np.frombuffer(ix.data, dtype=np.uint8)
    log = BulkLog(Path(path), {}, skipped=list(ix.skipped), truncated_at=ix.truncated_at)
    per_type: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]] = {}

    def ids(names: tuple[str, ...]) -> np.ndarray:
        return np.array([getattr(mavlink, f"MAVLINK_MSG_ID_{n}") for n in names], dtype=np.int64)

    wanted, unwanted = ids(only), ids(without)
    for i0 in range(0, len(ix.offset), TLOG_CHUNK):
        fo = ix.offset[i0 : i0 + TLOG_CHUNK] + 8
        if only or without:
            ids_here = _msgid(u8, fo)
            keep = np.isin(ids_here, wanted) if only else ~np.isin(ids_here, unwanted)
            rec = i0 + np.flatnonzero(keep)
            _frames(u8, ix.offset[rec] + 8, rec, log, per_type)
        else:
            _frames(u8, fo, i0 + np.arange(len(fo)), log, per_type)
        ix.release(int(fo[-1]))  # the chunk's frames are copied out: its pages are passed
    ix.release()
    for mid, parts in per_type.items():
        cls = mavlink.mavlink_map[mid]
        idx = np.concatenate([q[0] for q in parts])
        pay = np.concatenate([q[1] for q in parts])
        sysid = np.concatenate([q[2] for q in parts])
        compid = np.concatenate([q[3] for q in parts])
        del parts[:]
        if len(idx) > 1 and not bool((np.diff(idx) > 0).all()):
            srt = np.argsort(idx, kind="stable")  # back to file order
            idx, pay, sysid, compid = idx[srt], pay[srt], sysid[srt], compid[srt]
        fields = pay.view(_mav_dtype(cls)).reshape(-1)  # the rows as records, no copy
        log.messages[cls.msgname] = MessageArrays(cls.msgname, fields, ix.t[idx], sysid, compid, idx)
    return log


def _msgid(u8: np.ndarray, fo: np.ndarray) -> np.ndarray:
    """The message id of the frames at offsets ``fo`` (MAVLink 1 or 2)."""
    last = len(u8) - 1
    return np.where(
        u8[fo] == 0xFD,
        u8[np.minimum(fo + 7, last)].astype(np.int64)
        | (u8[np.minimum(fo + 8, last)].astype(np.int64) << 8)
        | (u8[np.minimum(fo + 9, last)].astype(np.int64) << 16),
        u8[np.minimum(fo + 5, last)].astype(np.int64),
    )


def _frames(u8: np.ndarray, fo: np.ndarray, rec: np.ndarray, log: BulkLog, per_type: dict) -> None:
    """The frames at offsets ``fo`` (the index's records ``rec``): each checked against its CRC and its
    payload cut out, per (message, version, length), into ``per_type``; the damage counted in ``log``."""
    if not len(fo):
        return
    last = len(u8) - 1
    magic = u8[fo]
    plen = u8[fo + 1].astype(np.int64)
    v2 = magic == 0xFD
    msgid = _msgid(u8, fo)
    sysid = np.where(v2, u8[np.minimum(fo + 5, last)], u8[fo + 3])
    compid = np.where(v2, u8[np.minimum(fo + 6, last)], u8[fo + 4])
    # One group per (msgid, version, payload length): fixed-width rows.
    key = (msgid << 10) | (v2.astype(np.int64) << 9) | plen
    order = np.argsort(key, kind="stable")
    bounds = np.flatnonzero(np.diff(key[order])) + 1
    for grp in np.split(order, bounds):
        g0 = int(grp[0])
        mid, L, h = int(msgid[g0]), int(plen[g0]), 10 if v2[g0] else 6
        cls = mavlink.mavlink_map.get(mid)
        if cls is None:
            log.unknown += len(grp)
            continue
        rows = _gather(u8, fo[grp] + 1, h - 1 + L + 2)  # header after magic, payload, CRC
        crc = crc_mcrf4xx_rows(rows[:, : h - 1 + L], cls.crc_extra)
        got = rows[:, h - 1 + L].astype(np.uint16) | (rows[:, h + L].astype(np.uint16) << 8)
        ok = crc == got
        if not ok.all():
            log.crc_errors[cls.msgname] = log.crc_errors.get(cls.msgname, 0) + int((~ok).sum())
        dt = _mav_dtype(cls)
        if not ok.any():
            continue
        if L > dt.itemsize:  # longer than the definition: not this message
            log.crc_errors[cls.msgname] = log.crc_errors.get(cls.msgname, 0) + int(ok.sum())
            continue
        payload = np.zeros((int(ok.sum()), dt.itemsize), dtype=np.uint8)  # zero-padded (MAVLink 2 trim)
        payload[:, :L] = rows[ok, h - 1 : h - 1 + L]
        g = grp[ok]
        per_type.setdefault(mid, []).append((rec[g], payload, sysid[g], compid[g]))


# ------------------------------------------------------------------ DataFlash binary
_DF_HEAD = b"\xa3\x95"
_FMT_TYPE = 128


class BulkError(ValueError):
    """Not a log this loader reads (one line naming the file)."""


@dataclass
class DataFlashWalk:
    """Where every record of a binary DataFlash log starts, and where the damage is."""

    length: dict[int, int]  # record length per type id (header included)
    fmts: dict[int, tuple[str, str, list[str]]]  # type id -> (name, format, columns)
    offsets: dict[int, array]  # type id -> record offsets (8 bytes each, not a Python int's 32), the FMT's too
    skipped: list[tuple[int, int]]  # (offset, bytes) of bad headers resynced over
    truncated_at: int | None  # offset of an incomplete last record

    def damage(self, path) -> str:
        """One line naming file and offsets, or ''."""
        parts = []
        if self.skipped:
            off, nb = self.skipped[0]
            parts.append(
                f"{nb} bytes with bad record headers skipped at offset {off}"
                + (
                    f" (and {len(self.skipped) - 1} more places, {sum(b for _, b in self.skipped)} bytes in all)"
                    if len(self.skipped) > 1
                    else ""
                )
            )
        if self.truncated_at is not None:
            parts.append(f"last record truncated at offset {self.truncated_at}")
        return f"{path}: " + "; ".join(parts) if parts else ""


def fmt_length_ok(length: int, fmt: str) -> bool:
    """An FMT record's declared length is its record's: the 3-byte header and the fields its format
    string packs (DFReader's ``FORMAT_TO_STRUCT``). A length that is not (a damaged byte, a crafted
    0) would walk the log in steps that are not its records: 0 never leaves the first one."""
    try:
        size = struct.calcsize("<" + "".join(DFReader.FORMAT_TO_STRUCT[c][0] for c in fmt))
    except (KeyError, struct.error):
        return False
    return bool(fmt) and length == 3 + size


def walk_dataflash(data: bytes) -> DataFlashWalk:
    """Walk the records (lengths from the FMT records as they come); resync on the next header. An
    FMT whose length is not its format's (:func:`fmt_length_ok`) defines nothing: its type's records
    are resynced over as damage."""
    n = len(data)
    length = {_FMT_TYPE: 89}
    fmts: dict[int, tuple[str, str, list[str]]] = {}
    offsets: dict[int, array] = {}
    skipped: list[tuple[int, int]] = []
    truncated_at = None
    pos = 0
    find = data.find
    while pos + 3 <= n:
        if data[pos] != 0xA3 or data[pos + 1] != 0x95 or data[pos + 2] not in length:
            nxt = find(_DF_HEAD, pos + 1)
            while nxt >= 0 and nxt + 2 < n and data[nxt + 2] not in length:
                nxt = find(_DF_HEAD, nxt + 1)
            skipped.append((pos, (nxt if nxt >= 0 else n) - pos))
            if nxt < 0:
                break
            pos = nxt
            continue
        typ = data[pos + 2]
        L = length[typ]
        if pos + L > n:
            truncated_at = pos
            break
        if typ == _FMT_TYPE:
            t2, l2 = data[pos + 3], data[pos + 4]
            name = data[pos + 5 : pos + 9].rstrip(b"\0").decode("ascii", "replace")
            fmt = data[pos + 9 : pos + 25].rstrip(b"\0").decode("ascii", "replace")
            cols = data[pos + 25 : pos + 89].rstrip(b"\0").decode("ascii", "replace").split(",")
            if t2 != _FMT_TYPE and fmt_length_ok(l2, fmt):
                length[t2] = l2
                fmts[t2] = (name, fmt, cols)
        lst = offsets.get(typ)
        if lst is None:
            lst = offsets[typ] = array("q")
        lst.append(pos)
        pos += L
    else:
        if pos < n:
            truncated_at = pos
    return DataFlashWalk(length, fmts, offsets, skipped, truncated_at)


def load_dataflash_bin(path: str | Path) -> BulkLog:
    """Every record of a binary DataFlash log as arrays per type, multipliers applied.

    Time ``t`` is ``TimeUS`` x 1e-6 or ``TimeMS`` x 1e-3 when the type has one, else NaN.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise BulkError(f"{p}: cannot read: {e.strerror or e}") from None
    if data[:2] != _DF_HEAD:
        raise BulkError(f"{p}: not a binary DataFlash log (no record header at offset 0)")
    walk = walk_dataflash(data)
    length, fmts, offsets = walk.length, walk.fmts, walk.offsets
    u8 = np.frombuffer(data, dtype=np.uint8)
    log = BulkLog(p, {}, skipped=walk.skipped, truncated_at=walk.truncated_at)
    for typ, offs in offsets.items():
        if typ not in fmts:
            continue
        name, fmt, cols = fmts[typ]
        try:
            fields = _df_fields(u8, np.frombuffer(offs, dtype=np.int64), length[typ], fmt, cols)
        except (KeyError, ValueError):
            log.undecodable[name] = len(offs)  # an FMT we cannot decode: counted, not guessed
            continue
        if "TimeUS" in cols:
            t = fields["TimeUS"].astype(np.float64) * 1e-6
        elif "TimeMS" in cols and name != "GPS":  # GPS TimeMS is GPS time of week
            t = fields["TimeMS"].astype(np.float64) * 1e-3
        else:
            t = np.full(len(fields), np.nan)
        log.messages[name] = MessageArrays(name, fields, t)
    return log


def dataflash_dtype(fmt: str, cols) -> np.dtype:
    """The packed numpy dtype of a record of DataFlash format ``fmt`` (DFReader's struct characters)."""
    return struct_dtype("".join(DFReader.FORMAT_TO_STRUCT[ch][0] for ch in fmt), cols)


def dataflash_values(raw: np.ndarray, ch: str) -> np.ndarray:
    """A field's values of format character ``ch`` as doubles, as DFReader gives them: a scaled integer
    (``c``: centi-units, ``L``: 1e-7 degrees) divided by the inverse of its multiplier, the operation
    DFReader performs (it divides for accuracy), so that the numbers are the same to the bit."""
    v = raw.astype(np.float64)
    mult = DFReader.FORMAT_TO_STRUCT[ch][1]
    if mult is None:
        return v
    return v / (1 / mult) if 0.0 < mult < 1.0 else v * mult


def _df_fields(u8, offs, L, fmt, cols) -> np.ndarray:
    raw_dt = dataflash_dtype(fmt, cols)
    if raw_dt.itemsize != L - 3:
        raise ValueError("FMT length disagrees with its format")
    rows = np.ascontiguousarray(_gather(u8, offs + 3, L - 3))
    raw = np.frombuffer(rows.tobytes(), dtype=raw_dt)
    mults = {c: DFReader.FORMAT_TO_STRUCT[ch][1] for c, ch in zip(cols, fmt)}
    if not any(mults.values()):
        return raw
    out_dt = np.dtype([(c, "<f8") if mults[c] else (c, raw_dt[c]) for c in cols])
    out = np.empty(len(raw), dtype=out_dt)
    for c, ch in zip(cols, fmt):
        out[c] = dataflash_values(raw[c], ch) if mults[c] else raw[c]
    return out


def load(path: str | Path) -> BulkLog:
    """A tlog or a binary DataFlash log, by content."""
    p = Path(path)
    try:
        with open(p, "rb") as f:
            head = f.read(2)
    except OSError as e:
        raise BulkError(f"{p}: cannot read: {e.strerror or e}") from None
    return load_dataflash_bin(p) if head == _DF_HEAD else load_tlog(p)
