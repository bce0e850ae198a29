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
IMU, IMU2  AccX/Y/Z [m/s^2], GyrX/Y/Z [rad/s]     ACCEL, GYRO (FRD already); IMU2 -> 1
BARO       Alt [m], Press [Pa], Temp [degC]       BARO_ALTITUDE, BARO_PRESSURE, TEMPERATURE [K]
CTUN       ThrOut (0..1000 old, 0..1 new),         THROTTLE [0..1]; BarAlt -> BARO_ALTITUDE
           BarAlt [m], SonAlt [m]                 (only in logs without BARO); SonAlt -> RANGE (inside
                                                  the rangefinder's limits, see below)
CURR       Volt, Curr (V x 100, A x 100 in old)   BATTERY_VOLTAGE [V], BATTERY_CURRENT [A] (0: not connected)
ATT        Roll, Pitch, Yaw [deg]                 ATTITUDE [rad]
GPS        Lat, Lng [deg], Alt [m], Status        GPS (3-D fix only)
RCOU       C1..C4 [us]                            ACTUATOR, (us - 1000) / 1000
=========  =====================================  ====================================

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
import io
import math
import os
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink import DFReader

from groundstation.core.measurement import Kind, Measurement

from .bulk import walk_dataflash

CONTROL_RATE = 10.0  # CTUN's rate in logs without a clock [Hz]

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

    @property
    def duration(self) -> float:
        return self.measurements[-1].t - self.measurements[0].t if self.measurements else 0.0


@contextlib.contextmanager
def _quiet():
    """Silence stdout and stderr, Python's and the C level's (fds 1 and 2)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


def read_dataflash(path: str | Path, source: str = "df/1.1") -> DataFlashLog:
    p = Path(path)
    if not p.exists():
        raise DataFlashError(f"{p}: cannot read: no such file")
    if not is_dataflash(p):
        raise DataFlashError(f"{p}: not a DataFlash log (no FMT record in the first 4096 bytes)")
    data = p.read_bytes()
    binary = data[:2] == b"\xa3\x95"
    damage = walk_dataflash(data).damage(p) if binary else ""
    del data  # DFReader maps the file itself
    msgs: list = []  # DFReader's messages, then a ("__damage__", why) where it stopped
    # DFReader (and its compiled indexer, at the file-descriptor level) prints a
    # line per bad byte while it resyncs; the walk above has already located the
    # damage, so that chatter is dropped.
    with _quiet():
        try:
            r = DFReader.DFReader_binary(str(p)) if binary else DFReader.DFReader_text(str(p))
        except Exception as e:  # DFReader raises assorted errors on foreign data
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise DataFlashError(f"{p}: not a readable DataFlash log: {first}") from None
        while True:
            try:
                m = r.recv_msg()
            except Exception as e:  # damage after this point: keep what came before
                msgs.append(("__damage__", f"{p}: unreadable after record {len(msgs)}: {e}"))
                break
            if m is None:
                break
            msgs.append(m)
    if msgs and isinstance(msgs[-1], tuple):
        damage = "; ".join(x for x in (damage, msgs[-1][1]) if x)
    types = Counter(m.get_type() for m in msgs if not isinstance(m, tuple))
    has_baro = types["BARO"] > 0
    params = {m.Name: m.Value for m in msgs if not isinstance(m, tuple) and m.get_type() == "PARM"}
    log = DataFlashLog(p, [], types, damage=damage, range_limits=rangefinder_limits(params))
    timed = any(
        hasattr(m, "TimeUS") or hasattr(m, "TimeMS")
        for m in msgs
        if not isinstance(m, tuple) and m.get_type() in ("CTUN", "IMU", "ATT")
    )
    if not timed:
        log.clock = f"row count of CTUN / {CONTROL_RATE:g} Hz"
    n_ctun = 0
    out = log.measurements
    for m in msgs:
        if isinstance(m, tuple):
            log.skipped["damage"] += 1
            continue
        typ = m.get_type()
        if typ == "CTUN":
            n_ctun += 1
        if timed:
            if hasattr(m, "TimeUS"):
                t = m.TimeUS * 1e-6
            elif hasattr(m, "TimeMS") and typ != "GPS":  # GPS TimeMS is GPS time of week
                t = m.TimeMS * 1e-3
            else:
                t = m._timestamp - msgs[0]._timestamp if hasattr(m, "_timestamp") else math.nan
        else:
            t = n_ctun / CONTROL_RATE
        _convert(typ, m, t, source, has_baro, log.range_limits, out, log.skipped)
    out.sort(key=lambda x: x.t)
    return log


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


def _convert(typ, m, t, s, has_baro, range_limits, out, skipped) -> None:
    def add(kind, value, instance=0):
        out.append(Measurement(t, kind, np.asarray(value, dtype=float), s, t, None, instance))

    if typ in ("IMU", "IMU2"):
        inst = getattr(m, "I", 1 if typ == "IMU2" else 0)
        add(Kind.ACCEL, [m.AccX, m.AccY, m.AccZ], inst)
        add(Kind.GYRO, [m.GyrX, m.GyrY, m.GyrZ], inst)
    elif typ == "BARO":
        add(Kind.BARO_ALTITUDE, [m.Alt])
        add(Kind.BARO_PRESSURE, [m.Press])
        add(Kind.TEMPERATURE, [m.Temp + 273.15])
    elif typ == "CTUN":
        thr = getattr(m, "ThrOut", None)
        if thr is not None:
            add(Kind.THROTTLE, [thr / 1000.0 if thr > 1.5 else thr])
        if not has_baro and hasattr(m, "BarAlt"):
            add(Kind.BARO_ALTITUDE, [m.BarAlt])
        son = getattr(m, "SonAlt", getattr(m, "SAlt", 0.0))
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
        add(Kind.ATTITUDE, np.radians([m.Roll, m.Pitch, m.Yaw]))
    elif typ == "GPS":
        if getattr(m, "Status", 0) >= 3:
            add(Kind.GPS, [m.Lat, m.Lng, m.Alt])
        else:
            skipped["gps_no_3d_fix"] += 1
    elif typ == "RCOU":
        ch = [getattr(m, f"C{k}", 0) or getattr(m, f"Ch{k}", 0) for k in range(1, 5)]
        add(Kind.ACTUATOR, [(c - 1000.0) / 1000.0 if c else math.nan for c in ch])
