"""Writing ArduPilot's binary DataFlash format (``.bin``): what a simulated vehicle keeps of a flight.

A ``.bin`` is self-describing: each record is ``A3 95 <type>`` and the type's fields, packed
little-endian as an FMT record (type 128, itself described by the first FMT) declared them. The
field codes and their multipliers (``c``/``C``/``e``/``E`` hundredths, ``L`` 1e-7 degrees) are
pymavlink's :data:`DFReader.FORMAT_TO_STRUCT`, used here through :class:`DFReader.DFFormat` so the
writer and every reader agree on them. pymavlink reads DataFlash but writes only a record it has
read (``DFMessage.get_msgbuf``), so the writing is here: values are given in the units the reader
returns (degrees, metres), and divided by the field's multiplier and rounded on the way in.
"""

from __future__ import annotations

import struct
from typing import BinaryIO

from pymavlink import DFReader

HEAD = b"\xa3\x95"
FMT_TYPE = 128
FMT_FORMAT, FMT_COLUMNS = "BBnNZ", "Type,Length,Name,Format,Columns"
MAX_TYPES = 255 - FMT_TYPE  # type ids 129..255 (a byte)


class _Record:
    __slots__ = ("fmt", "pack", "mults", "strings")

    def __init__(self, fmt: DFReader.DFFormat) -> None:
        self.fmt = fmt
        self.pack = struct.Struct(fmt.msg_struct).pack
        self.mults = [None if m is None else 1.0 / m for m in fmt.msg_mults]
        self.strings = [c in "nNZa" for c in fmt.format]


class DataFlashWriter:
    """Records to a binary DataFlash stream: ``define`` a record's name, format and columns
    (ArduPilot's codes), then ``write`` rows of it. ``out`` is a file opened for binary writing or a
    ``bytearray`` (a vehicle's log kept in memory)."""

    def __init__(self, out: BinaryIO | bytearray) -> None:
        self.out = out
        self._records: dict[str, tuple[int, _Record]] = {}
        self.size = 0
        self._emit(FMT_TYPE, _fmt_record(FMT_TYPE, "FMT", FMT_FORMAT, FMT_COLUMNS))

    def _emit(self, type_id: int, body: bytes) -> None:
        data = HEAD + bytes((type_id,)) + body
        if isinstance(self.out, bytearray):
            self.out += data
        else:
            self.out.write(data)
        self.size += len(data)

    def define(self, name: str, format: str, columns: str) -> None:
        """Declare a record (an FMT record); its rows then follow with :meth:`write`."""
        if name in self._records:
            raise ValueError(f"DataFlash record {name} defined twice")
        if len(self._records) >= MAX_TYPES:
            raise ValueError("a DataFlash log holds at most 127 record types")
        if len(name) > 4 or len(format) > 16 or len(columns) > 64 or len(format) != len(columns.split(",")):
            raise ValueError(f"DataFlash record {name}: a name of ≤ 4, a format of ≤ 16 and one column a code")
        type_id = FMT_TYPE + 1 + len(self._records)
        fmt = DFReader.DFFormat(type_id, name, 0, format, columns)
        fmt.len = 3 + struct.calcsize(fmt.msg_struct)
        self._records[name] = (type_id, _Record(fmt))
        self._emit(FMT_TYPE, _fmt_record(type_id, name, format, columns, fmt.len))

    def write(self, name: str, *values) -> None:
        """One row: the values in the columns' order, in the reader's units."""
        type_id, rec = self._records[name]
        out: list = []
        for v, inv, is_str in zip(values, rec.mults, rec.strings, strict=True):
            if is_str:
                out.append(v.encode("ascii", "replace") if isinstance(v, str) else bytes(v))
            elif inv is not None:
                out.append(int(round(v * inv)))
            else:
                out.append(v)
        self._emit(type_id, rec.pack(*out))

    @property
    def names(self) -> set[str]:
        return set(self._records)


def _fmt_record(type_id: int, name: str, format: str, columns: str, length: int | None = None) -> bytes:
    if length is None:  # the FMT record's own: 3 + 1 + 1 + 4 + 16 + 64
        length = 3 + struct.calcsize("<BB4s16s64s")
    return struct.pack("<BB4s16s64s", type_id, length, name.encode(), format.encode(), columns.encode())
