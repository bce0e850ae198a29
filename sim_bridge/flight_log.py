"""The simulated vehicle's onboard logs: a DataFlash ``.bin`` of each flight, as ArduPilot keeps them.

ArduPilot (``LOG_DISARMED`` 0) opens a new log when it arms and closes it when it disarms; the
logs are numbered from 1 and stay on the card until erased, the oldest removed when it is full.
:class:`FlightLogs` does the same with the simulator's samples, in ArduPilot 4.x's records and
units, so a log downloaded from the simulated vehicle (:mod:`.log_server`) reads, triages and
diagnoses as a real one does:

=========  ================================================  ==========================
record     columns                                           from the sample
=========  ================================================  ==========================
IMU        TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ            imu (FRD, rad/s, m/s²)
BARO       TimeUS,I,Alt,Press,Temp                           baro (Alt from the pressure,
                                                             zero where the vehicle booted)
GPS        TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,   gps (3-D fix)
           Spd,GCrs,VZ,U
RFND       TimeUS,Instance,Dist,Stat,Orient                  range (downward, good)
BAT        TimeUS,Inst,Volt,Curr                             battery
RCOU       TimeUS,C1..Cn                                     actuators (1000 + 1000·u µs)
CTUN       TimeUS,ThO(,Alt,BAlt)                             actuators (the throttle); the
                                                             autopilot's height estimate and
                                                             its corrected baro height, where
                                                             it makes one
ATT        TimeUS,Roll,Pitch,Yaw                             attitude (the autopilot's
                                                             estimate, degrees)
PARM       TimeUS,Name,Value                                 the vehicle's parameters at
                                                             arming
MSG, MODE  the firmware's banner; the flight mode            the vehicle's protocol
=========  ================================================  ==========================

The time is the vehicle's clock (``TimeUS``, from boot), as ArduPilot's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from drivers.logs.dataflash_writer import DataFlashWriter
from groundstation.core.atmosphere import altitude_at

from .simulator import Sample

FIRMWARE = "ArduCopter V4.5.7 (simulated)"
#: [bytes] the card: past it, the oldest finished logs are removed (as ArduPilot's ``LOG_FILE_MB_FREE``)
CARD_BYTES = 256 * 1024 * 1024
#: [s] GPS time (1980-01-06) to the Unix epoch, and its leap seconds since
GPS_EPOCH_UNIX, GPS_LEAP_S = 315_964_800.0, 18
RANGE_LIMITS_CM = (5, 400)  # the simulated rangefinder's (as DISTANCE_SENSOR says)

RECORDS = {
    "IMU": ("QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
    "BARO": ("QBfff", "TimeUS,I,Alt,Press,Temp"),
    "GPS": ("QBBIHBcLLeffffB", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U"),
    "RFND": ("QBCBB", "TimeUS,Instance,Dist,Stat,Orient"),
    "BAT": ("QBff", "TimeUS,Inst,Volt,Curr"),
    "ATT": ("Qfff", "TimeUS,Roll,Pitch,Yaw"),
    "PARM": ("QNf", "TimeUS,Name,Value"),
    "MSG": ("QZ", "TimeUS,Message"),
    "MODE": ("QMB", "TimeUS,Mode,ModeNum"),
}


def collective(vehicle: str, actuators) -> float:
    """The throttle the simulated autopilot commands, as its logs keep it (DataFlash's CTUN.ThO,
    PX4's collective thrust): a quad's four outputs carry it alike, a coax's two rotors' mean."""
    return float(actuators[0]) if vehicle == "quad" else float(sum(actuators[:2]) / 2)


@dataclass
class FlightLog:
    """One log: its number, when it began (Unix seconds, for LOG_ENTRY) and its bytes."""

    number: int
    time_utc: float
    data: bytearray = field(default_factory=bytearray)
    open: bool = True

    @property
    def size(self) -> int:
        return len(self.data)


class FlightLogs:
    """The logs of a simulated vehicle's flights. Call :meth:`step` with each step's samples and
    whether the vehicle is armed; ``parameters()`` gives the (name, value) pairs written at each
    arming, ``mode()`` the flight mode number."""

    def __init__(
        self,
        vehicle: str,
        epoch: float,
        parameters: Callable[[], Iterable[tuple[str, float]]],
        mode: Callable[[], int],
        *,
        height: Callable[[], tuple[float, float]] | None = None,
        card_bytes: int = CARD_BYTES,
        log_disarmed: bool = False,
    ) -> None:
        """``height``: the autopilot's height estimate and its baro's height [m] (CTUN.Alt, .BAlt).
        ``log_disarmed``: one log from boot, armed or not (ArduPilot's ``LOG_DISARMED`` 1)."""
        self.vehicle = vehicle
        self.epoch = epoch
        self.parameters = parameters
        self.mode = mode
        self.height = height
        self.card_bytes = card_bytes
        self.log_disarmed = log_disarmed
        self.logs: dict[int, FlightLog] = {}
        self._next = 1
        self._writer: DataFlashWriter | None = None
        self._current: FlightLog | None = None
        self._baro_zero: float | None = None  # [m] the pressure altitude where it booted
        self._mode: int | None = None
        self.removed = 0  # logs removed to make room on the card

    @property
    def current(self) -> FlightLog | None:
        return self._current

    def step(self, t: float, samples: Iterable[Sample], armed: bool) -> None:
        armed = armed or self.log_disarmed
        if armed and self._current is None:
            self._begin(t)
        elif not armed and self._current is not None:
            self._end()
        for s in samples:
            if s.sensor == "baro" and self._baro_zero is None:
                self._baro_zero = float(altitude_at(s.values[0]))
            if self._writer is not None:
                self._write(s)
        if self._writer is not None:
            mode = self.mode()
            if mode != self._mode:
                self._mode = mode
                self._writer.write("MODE", _us(t), mode, mode)

    def erase(self) -> None:
        """LOG_ERASE: every log but the one being written."""
        self.logs = {n: lg for n, lg in self.logs.items() if lg.open}

    def close(self) -> None:
        if self._current is not None:
            self._end()

    # -- writing --------------------------------------------------------------------------------
    def _begin(self, t: float) -> None:
        log = FlightLog(self._next, self.epoch + t)
        self._next += 1
        self.logs[log.number] = log
        self._current = log
        w = self._writer = DataFlashWriter(log.data)
        for name, (fmt, cols) in RECORDS.items():
            w.define(name, fmt, cols)
        if self.height is not None:  # the autopilot's estimate, where it makes one
            w.define("CTUN", "Qfff", "TimeUS,ThO,Alt,BAlt")
        else:
            w.define("CTUN", "Qf", "TimeUS,ThO")
        w.write("MSG", _us(t), FIRMWARE)
        w.write("MSG", _us(t), f"Frame: {self.vehicle.upper()}")
        lo, hi = RANGE_LIMITS_CM
        for name, value in [*self.parameters(), ("RNGFND1_MIN_CM", lo), ("RNGFND1_MAX_CM", hi),
                            ("RNGFND1_ORIENT", 25.0), ("LOG_DISARMED", float(self.log_disarmed))]:  # fmt: skip
            w.write("PARM", _us(t), name, float(value))
        self._mode = None
        self._make_room()

    def _end(self) -> None:
        if self._current is not None:
            self._current.open = False
        self._current = None
        self._writer = None
        self._make_room()

    def _make_room(self) -> None:
        while sum(lg.size for lg in self.logs.values()) > self.card_bytes:
            done = [n for n, lg in self.logs.items() if not lg.open]
            if not done:
                return
            del self.logs[min(done)]
            self.removed += 1

    def _write(self, s: Sample) -> None:
        w, v, us = self._writer, s.values, _us(s.t)
        assert w is not None
        if s.sensor == "imu":
            w.write("IMU", us, 0, v[3], v[4], v[5], v[0], v[1], v[2])
        elif s.sensor == "baro":
            p, temp = v
            alt = float(altitude_at(p)) - (self._baro_zero or 0.0)
            w.write("BARO", us, 0, alt, p, temp - 273.15)
        elif s.sensor == "gps":
            lat, lon, alt, vn, ve, vd, _h_acc, _v_acc = v
            gps_s = self.epoch + s.t - GPS_EPOCH_UNIX + GPS_LEAP_S
            week, ms = int(gps_s // 604800), int(round(gps_s % 604800 * 1000))
            course = math.degrees(math.atan2(ve, vn)) % 360
            w.write("GPS", us, 0, 3, ms, week, 12, 0.8, lat, lon, alt, math.hypot(vn, ve), course, vd, 0.0, 1)
        elif s.sensor == "range":
            d = v[0]
            lo, hi = RANGE_LIMITS_CM
            status = 2 if d <= lo / 100 else 3 if d >= hi / 100 else 4  # out of range low, high; good
            w.write("RFND", us, 0, min(max(d, 0.0), 655.35), status, 25)
        elif s.sensor == "battery":
            w.write("BAT", us, 0, v[0], v[1])
        elif s.sensor == "actuators":
            self._actuators(us, v)
        elif s.sensor == "attitude":
            w.write("ATT", us, *(math.degrees(a) for a in v[:3]))

    def _actuators(self, us: int, v) -> None:
        w = self._writer
        assert w is not None
        if "RCOU" not in w.names:  # as many outputs as the vehicle has (a quad's four)
            n = min(len(v), 14)
            w.define("RCOU", "Q" + "H" * n, "TimeUS," + ",".join(f"C{k}" for k in range(1, n + 1)))
        w.write("RCOU", us, *(int(round(1000 + 1000 * min(1.0, max(0.0, u)))) for u in v[:14]))
        thr = collective(self.vehicle, v)
        if self.height is not None:
            w.write("CTUN", us, min(1.0, max(0.0, thr)), *self.height())
        else:
            w.write("CTUN", us, min(1.0, max(0.0, thr)))


def _us(t: float) -> int:
    return max(0, int(round(t * 1e6)))
