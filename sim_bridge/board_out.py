"""The simulated sensor boards' side: binary frames and NMEA sentences.

Written from the protocol's specification (README, ``drivers/board_protocol``),
as a microcontroller's firmware would be; the tests check both sides against
hand-computed frames.
"""

from __future__ import annotations

import datetime as dt
import math
import struct

from fastcrc import crc16

from .simulator import Sample

_HDR = struct.Struct("<2sBBBB")
_CRC = struct.Struct("<H")
_IMU = struct.Struct("<I6f")
_ENC = struct.Struct("<I3iH")
_POWER = struct.Struct("<I2f")
_BARO = struct.Struct("<I2f")
_RANGE = struct.Struct("<IfB")
#: [s] between the 3-DOF board's supply readings (50 Hz, whatever the rate the motors are set at)
POWER_EVERY_S = 0.02


class BinaryFramer:
    def __init__(self) -> None:
        self.seq = 0

    def frame(self, msg_id: int, payload: bytes) -> bytes:
        head = _HDR.pack(b"\xa5\x5a", 1, msg_id, self.seq, len(payload))
        self.seq = (self.seq + 1) & 0xFF
        body = head[2:] + payload
        return head[:2] + body + _CRC.pack(crc16.ibm_3740(body))


class BoardEncoder:
    """Samples -> board bytes: binary frames for lab boards, NMEA for a GPS receiver."""

    def __init__(self, vehicle: str, epoch: float, counts_per_rev: int = 4096) -> None:
        self.vehicle = vehicle
        self.framer = BinaryFramer()
        self.epoch = epoch
        self.cpr = counts_per_rev
        self._next_power = 0.0

    def _t_us(self, t: float) -> int:
        return int(round(t * 1e6)) & 0xFFFFFFFF

    def encode(self, s: Sample) -> list[bytes]:
        f, tu = self.framer.frame, self._t_us(s.t)
        if self.vehicle == "heli3dof":
            if s.sensor == "imu":
                return [f(0x01, _IMU.pack(tu, *s.values[:6]))]
            if s.sensor == "encoders":
                counts = [int(round(a / (2 * math.pi) * self.cpr)) for a in s.values]
                return [f(0x04, _ENC.pack(tu, *counts, self.cpr))]
            if s.sensor == "actuators" and s.t >= self._next_power:  # the board measures the motor supply
                self._next_power = s.t + POWER_EVERY_S - 1e-6
                return [f(0x05, _POWER.pack(tu, 12.0, 0.0))]
            return []
        if s.sensor == "gps":
            return self.nmea(s)
        return []

    def nmea(self, s: Sample) -> list[bytes]:
        lat, lon, alt, vn, ve, vd, h_acc, _ = s.values
        when = dt.datetime.fromtimestamp(self.epoch + s.t, dt.UTC)
        hms = when.strftime("%H%M%S") + f".{when.microsecond // 10000:02d}"
        la = f"{int(abs(lat)):02d}{(abs(lat) % 1) * 60:07.4f},{'N' if lat >= 0 else 'S'}"
        lo = f"{int(abs(lon)):03d}{(abs(lon) % 1) * 60:07.4f},{'E' if lon >= 0 else 'W'}"
        hdop = h_acc / 2.5
        gga = f"GPGGA,{hms},{la},{lo},1,12,{hdop:.1f},{alt:.1f},M,47.0,M,,"
        sog = math.hypot(vn, ve) / 0.514444
        cog = math.degrees(math.atan2(ve, vn)) % 360
        rmc = f"GPRMC,{hms},A,{la},{lo},{sog:.2f},{cog:.1f},{when:%d%m%y},,,A"
        return [_sentence(gga), _sentence(rmc)]


def _sentence(body: str) -> bytes:
    x = 0
    for ch in body.encode():
        x ^= ch
    return f"${body}*{x:02X}\r\n".encode()
