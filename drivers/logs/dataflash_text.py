"""A text DataFlash log read by the project itself, where pymavlink's ``DFReader_text`` cannot.

ArduCopter 3.0's text logs write GPS records with a ``Time`` field and no GPS week: DFReader's
clock, which it sets up from the GPS records before it reads anything, multiplies the missing week
(``unsupported operand type(s) for *: 'int' and 'NoneType'``), and the whole log is refused. A
fleet's archive of older flights holds such logs. The format is plain (``FMT`` lines naming each
type's format characters and columns, then one comma-separated line a record, the values written
as they read), so :class:`TextReader` parses it directly and offers the part of DFReader's interface
:func:`.dataflash._read` uses: ``recv_msg``, ``recv_match(type=...)``, ``rewind``, ``counts``,
``id_to_name`` and ``formats``. Each record's ``_timestamp`` is the time of the last record with a
clock of its own (``TimeUS``, ``TimeMS``; a GPS's ``T``), as DFReader interpolates between them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

#: format characters by how their values read (pymavlink's DFReader.FORMAT_TO_STRUCT)
INT_FORMATS = frozenset("bBhHiIMqQ")
FLOAT_FORMATS = frozenset("gfcCeELd")


@dataclass
class TextFormat:
    name: str
    type_id: int
    format: str
    columns: list[str]


class TextRecord:
    """One record, its fields as attributes (as DFReader's messages)."""

    def __init__(self, name: str, fields: dict, stamp: float | None) -> None:
        self.__dict__.update(fields)
        self._name = name
        self._fields = fields
        self._timestamp = stamp

    def get_type(self) -> str:
        return self._name

    def to_dict(self) -> dict:
        return {"mavpackettype": self._name, **self._fields}


def _value(ch: str, text: str):
    if ch in INT_FORMATS:
        try:
            return int(text)
        except ValueError:
            if ch == "M":
                return text  # a flight mode: a text log writes its name
            return int(float(text))
    if ch in FLOAT_FORMATS:
        return float(text)
    return text


class TextReader:
    """The records of a text DataFlash log (the module's docstring)."""

    def __init__(self, path: str | Path) -> None:
        self.formats: dict[str, TextFormat] = {}
        self.id_to_name: dict[int, str] = {}
        self.counts: dict[str, int] = {}
        self._records: list[tuple[str, list[str]]] = []
        for raw in Path(path).read_text(encoding="latin-1").splitlines():
            fields = [f.strip() for f in raw.split(",")]
            if len(fields) < 2:
                continue
            name = fields[0]
            if name == "FMT" and len(fields) >= 5 and fields[1].isdigit():
                fmt = TextFormat(fields[3], int(fields[1]), fields[4], fields[5 : 5 + len(fields[4])])
                self.formats[fmt.name] = fmt
                self.id_to_name[fmt.type_id] = fmt.name
            if name in self.formats:
                self._records.append((name, fields[1:]))
                self.counts[name] = self.counts.get(name, 0) + 1
        self._next = 0
        self._stamp: float | None = None

    def rewind(self) -> None:
        self._next = 0
        self._stamp = None

    def recv_msg(self) -> TextRecord | None:
        while self._next < len(self._records):
            name, values = self._records[self._next]
            self._next += 1
            fmt = self.formats[name]
            if name == "FMT":
                fields = dict(zip(("Type", "Length", "Name", "Format", "Columns"), values))
            else:
                fields = {c: _value(ch, v) for c, ch, v in zip(fmt.columns, fmt.format, values)}
            for key, scale in (("TimeUS", 1e-6), ("TimeMS", 1e-3), ("T", 1e-3)):
                v = fields.get(key)
                if isinstance(v, (int, float)) and not (key == "TimeMS" and name == "GPS") and math.isfinite(v):
                    self._stamp = v * scale
                    break
            return TextRecord(name, fields, self._stamp)
        return None

    def recv_match(self, type: str | set[str] | None = None) -> TextRecord | None:  # noqa: A002 - DFReader's
        wanted = {type} if isinstance(type, str) else type
        while True:
            m = self.recv_msg()
            if m is None or wanted is None or m.get_type() in wanted:
                return m
