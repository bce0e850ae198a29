"""MAVLink framing with a fast path for high-rate sensor messages.

pymavlink's ``parse_buffer`` builds a full message object per frame, byte-state
machine and all, which costs more than everything the ground station does with
a sensor reading afterwards. This framer does what the C library does:

* find the start marker (0xFE v1, 0xFD v2), read the header, wait for the
  whole frame;
* check the CRC-16/MCRF4XX with the message's CRC_EXTRA (``fastcrc``, the C
  accelerator pymavlink itself uses);
* for the high-rate sensor messages (:data:`FAST_TYPES`), unpack the payload
  with pymavlink's own ``struct`` unpacker into a plain tuple of its fields in
  wire order (pymavlink's ``ordered_fieldnames``; an array field is a tuple
  within it); MAVLink 2 zero-truncated payloads are padded back. Not a
  namedtuple, nor a message object: building one and reading its fields by
  name costs 6 % more instructions a message (``bench/ingest.py --instructions``);
* for every other known message, hand the verified frame to pymavlink's
  ``MAVLink.decode`` for a full message object (hooks, HEARTBEAT, ACKs);
* frames with an id outside the dialect become ``MAVLink_unknown`` objects.

Damage is handled as pymavlink's robust parser handles it (so counts agree
with ``mavutil`` on the same file): a frame whose CRC fails is skipped whole
and counted; a stretch of bytes before a start marker is one ``bad_data``.
Message definitions, unpackers and CRC_EXTRA all come from pymavlink; only the
frame walk is ours.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import TYPE_CHECKING

from fastcrc import crc16
from pymavlink.dialects.v20 import ardupilotmega as mavlink

if TYPE_CHECKING:
    from .signing import SignatureCheck

_crc = crc16.mcrf4xx

#: Sensor messages that take the fast path (the high-rate ones).
FAST_TYPES = (
    "HIGHRES_IMU",
    "SCALED_IMU",
    "SCALED_IMU2",
    "SCALED_IMU3",
    "RAW_IMU",
    "SCALED_PRESSURE",
    "SCALED_PRESSURE2",
    "SCALED_PRESSURE3",
    "ATTITUDE",
    "ATTITUDE_QUATERNION",
    "LOCAL_POSITION_NED",
    "GLOBAL_POSITION_INT",
    "GPS_RAW_INT",
    "VFR_HUD",
    "SERVO_OUTPUT_RAW",
    "RC_CHANNELS",
    "SYS_STATUS",
    "DISTANCE_SENSOR",
    "ATT_POS_MOCAP",
    "MANUAL_CONTROL",
)

_V1_HDR = struct.Struct("<BBBBBB")  # magic len seq sys comp msgid
_V2_HDR = struct.Struct("<BBBBBBBHB")  # magic len incompat compat seq sys comp msgid(lo16) msgid(hi8)
_v1_hdr, _v2_hdr = _V1_HDR.unpack_from, _V2_HDR.unpack_from


class FastSpec:
    """How to turn one message type's payload into the tuple of its fields (wire order)."""

    __slots__ = ("cls", "name", "unpack", "unpack_from", "size", "zeros", "group")

    def __init__(self, cls) -> None:
        self.cls = cls
        self.name = cls.msgname
        self.unpack = cls.unpacker.unpack
        self.unpack_from = cls.unpacker.unpack_from
        self.size = cls.unpacker.size
        self.zeros = bytes(self.size)
        # Array fields come out of struct as several values: group them back.
        self.group = tuple(cls.lengths) if any(n > 1 for n in cls.lengths) else None

    def make(self, buf: bytes, start: int, length: int) -> tuple:
        """The fields of the payload of ``length`` bytes at ``buf[start:]``, in wire order."""
        if length >= self.size:  # read in place (a longer payload: a newer dialect's extensions)
            vals = self.unpack_from(buf, start)
        else:  # MAVLink 2 trims trailing zeros: put them back
            vals = self.unpack(buf[start : start + length] + self.zeros[length:])
        if self.group is not None:
            out, k = [], 0
            for n in self.group:
                out.append(vals[k] if n == 1 else vals[k : k + n])
                k += n
            return tuple(out)
        return vals


class Framer:
    """Walks a byte stream into frames; calls back per frame.

    ``on_fast(spec, fields, sysid, compid, seq, frame)``: a fast-path message, its fields a tuple in
    wire order (:meth:`FastSpec.make`).
    ``on_object(msg, sysid, compid, seq, frame)``: any other valid or unknown frame.
    ``on_crc_error()`` / ``on_garbage()``: damage.
    """

    def __init__(
        self, on_fast: Callable, on_object: Callable, on_crc_error: Callable[[], None], on_garbage: Callable[[], None]
    ) -> None:
        self._buf = b""
        self.on_fast = on_fast
        self.on_object = on_object
        self.on_crc_error = on_crc_error
        self.on_garbage = on_garbage
        self._mav = mavlink.MAVLink(None)  # pymavlink's full decoder for the rest
        #: set to check MAVLink 2 signatures (drivers.mavlink.signing); refused frames go to on_refused
        self.signing: SignatureCheck | None = None
        self.on_refused: Callable[[], None] = lambda: None
        self._crc_extra: dict[int, bytes] = {}
        self._fast: dict[int, FastSpec] = {}
        for msgid, cls in mavlink.mavlink_map.items():
            self._crc_extra[msgid] = bytes([cls.crc_extra])
            if cls.msgname in FAST_TYPES:
                self._fast[msgid] = FastSpec(cls)

    @property
    def pending(self) -> bool:
        """Whether a partial frame (or bytes that may start one) waits for the next feed."""
        return bool(self._buf)

    def reset(self) -> None:
        """Forget a partial frame (after a seek)."""
        self._buf = b""

    def feed(self, data: bytes) -> None:
        buf = self._buf + data if self._buf else data
        n = len(buf)
        pos = 0
        crc_extra = self._crc_extra
        fast = self._fast
        on_fast = self.on_fast
        signing = self.signing
        while pos < n:
            c = buf[pos]
            if c != 0xFD and c != 0xFE:
                a = buf.find(b"\xfd", pos)
                b = buf.find(b"\xfe", pos)
                nxt = a if b < 0 else b if a < 0 else min(a, b)
                self.on_garbage()
                if nxt < 0:
                    pos = n
                    break
                pos = nxt
                continue
            if n - pos < 3:
                break
            plen = buf[pos + 1]
            if c == 0xFD:
                incompat = buf[pos + 2]
                if incompat & ~0x01:  # an incompatibility we do not know
                    self.on_garbage()
                    pos += 1
                    continue
                hlen = 10
                flen = 12 + plen + (13 if incompat else 0)
            else:
                hlen = 6
                flen = 8 + plen
            if n - pos < flen:
                break
            end_crc = pos + hlen + plen
            if c == 0xFD:
                _, _, _, _, seq, sysid, compid, lo, hi = _v2_hdr(buf, pos)
                msgid = lo | hi << 16
            else:
                _, _, seq, sysid, compid, msgid = _v1_hdr(buf, pos)
            frame = buf[pos : pos + flen]
            extra = crc_extra.get(msgid)
            if extra is None:
                # an id this dialect does not know: no CRC to check, but a signature all the same
                if signing is not None and not signing.accept(frame, msgid, sysid, compid):
                    self.on_refused()
                else:
                    self.on_object(mavlink.MAVLink_unknown(msgid, frame), sysid, compid, seq, frame)
                pos += flen
                continue
            crc = _crc(extra, _crc(buf[pos + 1 : end_crc]))
            if crc != (buf[end_crc] | buf[end_crc + 1] << 8):
                self.on_crc_error()
                pos += flen
                continue
            if signing is not None and not signing.accept(frame, msgid, sysid, compid):
                self.on_refused()
                pos += flen
                continue
            spec = fast.get(msgid)
            if spec is not None:
                on_fast(spec, spec.make(buf, pos + hlen, plen), sysid, compid, seq, frame)
            else:
                try:
                    m = self._mav.decode(bytearray(frame))
                except mavlink.MAVError:
                    self.on_crc_error()  # payload that does not unpack: as damaged
                else:
                    self.on_object(m, sysid, compid, seq, frame)
            pos += flen
        self._buf = buf[pos:] if pos < n else b""
