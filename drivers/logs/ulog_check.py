"""A ULog's structure checked before pyulog parses it, so that no file can make it loop or run out of
memory.

pyulog trusts a file's definitions: a format nested in itself, or nested formats whose arrays
multiply, expanded a 163-byte file to 2.67 GB in two minutes; a file cut inside its definitions
kept it reading for minutes; a topic without a ``timestamp`` field reached the reader as a
``KeyError``. Here the file is walked once (the ULog format, https://docs.px4.io/main/en/dev_log/ulog_file_format.html:
a 16-byte header, then messages of ``uint16 size, uint8 type, payload``), and the format definitions
(``F`` messages, ``name:type field;...``) are resolved with every bound checked before anything is
expanded: nesting depth, a format's size (a message's payload is at most 65535 bytes), array
lengths, unknown and recursive types. pyulog then reads only what passed:

* a file whose definitions are cut, or whose formats cannot be resolved within the bounds, is
  refused in one line (its data could not be read right anyway);
* a file whose data section ends inside a message is handed to pyulog up to its last whole
  message, and the cut is reported as damage;
* topics whose format has no ``timestamp`` are left out of the tables, counted.

Nothing in pyulog exposes its definitions before it parses the data (``ULog(path)`` does both), which
is why this walk is written here.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

#: the header: "ULog" 0x01 0x12 0x35, a version byte, a uint64 start time
HEADER = 16
#: ULog's basic types and their sizes
BASIC = {
    "int8_t": 1,
    "uint8_t": 1,
    "int16_t": 2,
    "uint16_t": 2,
    "int32_t": 4,
    "uint32_t": 4,
    "int64_t": 8,
    "uint64_t": 8,
    "float": 4,
    "double": 8,
    "bool": 1,
    "char": 1,
}
#: bounds: formats nested deeper than this, or a format larger than a message can carry, are refused
MAX_DEPTH = 8
MAX_SIZE = 65535
#: the messages of the definitions section (flag bits, format, info, multi info, parameter, default)
DEFINITIONS = frozenset(b"BFIMPQ")
_FIELD = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d{1,5})\])?$")


class ULogStructureError(ValueError):
    """The file's structure cannot be read within bounds (one line, without the file's name)."""


@dataclass
class Checked:
    """What the walk found: where the last whole message ends, the formats (name -> size, fields),
    and which have no timestamp."""

    end: int  #: the offset just past the last whole message
    cut: bool  #: the file ends inside a message (of the data section)
    sizes: dict[str, int] = field(default_factory=dict)
    untimed: set[str] = field(default_factory=set)


def check(data: bytes) -> Checked:
    """Walk ``data`` (a whole ULog file): raise :class:`ULogStructureError` where it cannot be read
    within bounds, else say how far it can be read and what its formats are."""
    n = len(data)
    if n < HEADER:
        raise ULogStructureError("shorter than a ULog header")
    pos = HEADER
    formats: dict[str, str] = {}
    in_definitions = True
    cut = False
    while pos + 3 <= n:
        size = data[pos] | (data[pos + 1] << 8)
        kind = data[pos + 2]
        if pos + 3 + size > n:
            if in_definitions:
                raise ULogStructureError(f"cut inside its definitions at offset {pos}")
            cut = True
            break
        if in_definitions and kind not in DEFINITIONS:
            in_definitions = False
        if kind == ord("F"):
            text = data[pos + 3 : pos + 3 + size].decode("latin-1")
            name, sep, body = text.partition(":")
            if not sep or not name:
                raise ULogStructureError(f"a format definition without a name at offset {pos}")
            formats[name] = body
        pos += 3 + size
    if pos < n and not cut:
        cut = True
    if in_definitions and pos < n:
        raise ULogStructureError("cut inside its definitions")
    sizes: dict[str, int] = {}
    untimed = set()
    for name in formats:
        sizes[name] = _size(name, formats, sizes, ())
        if not any(f.split()[-1] == "timestamp" for f in formats[name].split(";") if f.strip()):
            untimed.add(name)
    return Checked(pos, cut, sizes, untimed)


def _size(name: str, formats: dict[str, str], sizes: dict[str, int], path: tuple[str, ...]) -> int:
    """A format's size in bytes, its nested formats resolved within :data:`MAX_DEPTH` and :data:`MAX_SIZE`."""
    if name in sizes:
        return sizes[name]
    if name in path:
        raise ULogStructureError(f"format {name!r} contains itself")
    if len(path) >= MAX_DEPTH:
        raise ULogStructureError(f"formats nested deeper than {MAX_DEPTH} ({' > '.join(path)})")
    total = 0
    for item in formats[name].split(";"):
        item = item.strip()
        if not item:
            continue
        parts = item.split()
        if len(parts) != 2:
            raise ULogStructureError(f"format {name!r}: field {item[:40]!r} is not 'type name'")
        typ, _ = parts
        m = _FIELD.match(typ)
        if m is None:
            raise ULogStructureError(f"format {name!r}: type {typ[:40]!r} is not a type")
        base, count = m.group(1), int(m.group(2) or 1)
        if base in BASIC:
            one = BASIC[base]
        elif base in formats:
            one = _size(base, formats, sizes, (*path, name))
        else:
            raise ULogStructureError(f"format {name!r}: unknown type {base!r}")
        total += one * count
        if total > MAX_SIZE:
            raise ULogStructureError(f"format {name!r} is larger than a message can carry ({MAX_SIZE} bytes)")
    sizes[name] = total
    return total
