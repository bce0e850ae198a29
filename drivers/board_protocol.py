"""The sensor-board binary frame protocol, version 1 (the receiving side).

A small protocol a microcontroller can speak over USB serial. Every frame::

    offset  size  field
    0       2     sync 0xA5 0x5A
    2       1     protocol version (1)
    3       1     message id
    4       1     sequence number (0..255, +1 per frame; gaps are loss)
    5       1     payload length N (0..64)
    6       N     payload, little-endian
    6+N     2     CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection,
                  no final xor) over bytes 2 .. 5+N (version to payload),
                  little-endian

Payloads start with ``t_us``, a uint32 of the board's microsecond clock (it
wraps every 71.6 minutes; the driver unwraps it). Values are SI:

====  ===========  =====================================================  =====
id    name         payload after t_us                                     bytes
====  ===========  =====================================================  =====
0x01  IMU          ax ay az [m/s^2], gx gy gz [rad/s]: float32 x 6, FRD   28
0x02  BARO         pressure [Pa], temperature [K]: float32 x 2            12
0x03  RANGE        distance [m]: float32; status: uint8 (0 = valid)        9
0x04  ENCODERS     counts: int32 x 3; counts per revolution: uint16       18
0x05  POWER        voltage [V], current [A]: float32 x 2                  12
0x10  MOTORS       (ground -> board) voltages [V]: float32 x 2            12
====  ===========  =====================================================  =====

Receivers resynchronise after garbage by searching for the next sync pair; a
frame whose CRC fails is skipped one byte at a time (its length byte may be the
damaged one). Unknown versions and message ids are counted, never fatal.
"""

from __future__ import annotations

import struct

from fastcrc import crc16

SYNC = b"\xa5\x5a"
VERSION = 1
MAX_PAYLOAD = 64

IMU, BARO, RANGE, ENCODERS, POWER, MOTORS = 0x01, 0x02, 0x03, 0x04, 0x05, 0x10

#: message id -> (name, struct of the payload including t_us)
PAYLOADS: dict[int, tuple[str, struct.Struct]] = {
    IMU: ("IMU", struct.Struct("<I6f")),
    BARO: ("BARO", struct.Struct("<I2f")),
    RANGE: ("RANGE", struct.Struct("<IfB")),
    ENCODERS: ("ENCODERS", struct.Struct("<I3iH")),
    POWER: ("POWER", struct.Struct("<I2f")),
    MOTORS: ("MOTORS", struct.Struct("<I2f")),
}


def crc16_ccitt(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (``fastcrc``'s ibm_3740; check value 0x29B1 for b"123456789")."""
    return crc16.ibm_3740(data)


def frame(msg_id: int, seq: int, payload: bytes) -> bytes:
    """One frame (ground -> board commands; the boards' own framing lives in their firmware)."""
    body = struct.pack("<BBBB", VERSION, msg_id, seq & 0xFF, len(payload)) + payload
    return SYNC + body + struct.pack("<H", crc16_ccitt(body))
