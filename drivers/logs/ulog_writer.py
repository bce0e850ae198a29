"""Writing PX4's ULog (``.ulg``): a simulated flight as PX4's logger would keep it.

The format is PX4's (docs.px4.io, "ULog File Format"): a 16-byte header (the magic ``ULog``, 0x01
0x12 0x35, the version, the start time in microseconds), then messages of ``uint16 size, uint8
type`` and a body: the flag bits (``B``), each topic's format (``F``: ``name:type field;...``), the
system's info (``I``) and parameters (``P``), then each topic subscribed (``A``: its id and
instance) and its samples (``D``: the id and the fields packed little-endian in the format's order,
without padding). pyulog reads ULog but writes none, so the writing is here; pyulog is what the
tests read it back with.
"""

from __future__ import annotations

import struct
from typing import BinaryIO

MAGIC = b"ULog\x01\x12\x35"
VERSION = 1
#: a format's field types and their struct codes
TYPES = {
    "int8_t": "b",
    "uint8_t": "B",
    "int16_t": "h",
    "uint16_t": "H",
    "int32_t": "i",
    "uint32_t": "I",
    "int64_t": "q",
    "uint64_t": "Q",
    "float": "f",
    "double": "d",
    "bool": "?",
    "char": "c",
}


def _struct_of(fields: list[tuple[str, str]]) -> str:
    """``fields`` ((type, name), ``float[3]`` for an array) as a little-endian struct format."""
    out = "<"
    for typ, _ in fields:
        base, _, n = typ.partition("[")
        code = TYPES.get(base)
        if code is None:
            raise ValueError(f"ULog field type {typ!r} is not one of {sorted(TYPES)}")
        out += (n.rstrip("]") if n else "") + code
    return out


class UlogWriter:
    """Messages to a ULog stream: :meth:`define` a topic's fields, :meth:`info` and :meth:`parameter`
    before the first sample, :meth:`add` an instance of a topic, then :meth:`write` its samples (the
    fields in the order defined, each array's elements one by one; the first is ``timestamp`` [us])."""

    def __init__(self, out: BinaryIO, start_us: int = 0) -> None:
        self.out = out
        self._formats: dict[str, struct.Struct] = {}
        self._ids: dict[tuple[str, int], tuple[int, struct.Struct]] = {}
        self._data_begun = False
        out.write(MAGIC + bytes((VERSION,)) + struct.pack("<Q", start_us))
        self._message(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))  # no flags: nothing appended

    def _message(self, kind: bytes, body: bytes) -> None:
        if len(body) > 0xFFFF:
            raise ValueError(f"a ULog message holds at most 65535 bytes, not {len(body)}")
        self.out.write(struct.pack("<HB", len(body), kind[0]) + body)

    def _definitions(self, what: str) -> None:
        if self._data_begun:
            raise ValueError(f"a ULog's {what} come before its first sample")

    def define(self, name: str, fields: str) -> None:
        """A topic's format, ``fields`` as PX4 writes them: ``"uint64_t timestamp;float[3] gyro_rad"``."""
        self._definitions("formats")
        pairs = [tuple(f.split()) for f in fields.strip(";").split(";")]
        if not pairs or pairs[0] != ("uint64_t", "timestamp") or any(len(p) != 2 for p in pairs):
            raise ValueError(f"ULog topic {name}: fields begin with 'uint64_t timestamp', each 'type name'")
        self._formats[name] = struct.Struct(_struct_of(pairs))  # type: ignore[arg-type]
        self._message(b"F", f"{name}:{fields.strip(';')};".encode())

    def info(self, key: str, value: str | int) -> None:
        """The system's info: a string (``sys_name``) or a ``uint32_t`` (``ver_sw_release``)."""
        self._definitions("info")
        if isinstance(value, str):
            v = value.encode()
            k = f"char[{len(v)}] {key}".encode()
        else:
            v, k = struct.pack("<I", value), f"uint32_t {key}".encode()
        self._message(b"I", bytes((len(k),)) + k + v)

    def parameter(self, name: str, value: float | int) -> None:
        """A parameter: an ``int32_t`` for an int, else a ``float``."""
        self._definitions("parameters")
        if isinstance(value, int):
            k, v = f"int32_t {name}".encode(), struct.pack("<i", value)
        else:
            k, v = f"float {name}".encode(), struct.pack("<f", value)
        self._message(b"P", bytes((len(k),)) + k + v)

    def add(self, name: str, instance: int = 0) -> None:
        """Subscribe instance ``instance`` of topic ``name`` (defined before)."""
        if name not in self._formats:
            raise ValueError(f"ULog topic {name} added before it was defined")
        if (name, instance) in self._ids:
            raise ValueError(f"ULog topic {name} instance {instance} added twice")
        msg_id = len(self._ids)
        self._ids[(name, instance)] = (msg_id, self._formats[name])
        self._data_begun = True
        self._message(b"A", struct.pack("<BH", instance, msg_id) + name.encode())

    def write(self, name: str, *values: float | int, instance: int = 0) -> None:
        """One sample of a topic added before."""
        got = self._ids.get((name, instance))
        if got is None:
            raise ValueError(f"ULog topic {name} instance {instance} written before it was added")
        msg_id, st = got
        self._message(b"D", struct.pack("<H", msg_id) + st.pack(*values))

    def log(self, level: int, timestamp_us: int, text: str) -> None:
        """A logged message (``L``), its level as syslog's (6: info), written as its digit (``'6'``)."""
        if not 0 <= level <= 7:
            raise ValueError(f"a ULog message's level is 0 to 7, not {level}")
        self._data_begun = True
        self._message(b"L", struct.pack("<BQ", ord("0") + level, timestamp_us) + text.encode())
