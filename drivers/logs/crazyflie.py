"""Crazyflie uSD event logs (version 2) to measurements.

Format (``../shared/data/real/README.md``): ``0xBC``, uint16 version, uint16
number of event types; per type a uint16 id, a NUL-terminated name, a uint16
count and NUL-terminated ``name(T)`` variables (``struct`` codes); then records
(uint16 id, uint64 microseconds since boot, packed values, no padding) up to a
trailing CRC-32 (``zlib.crc32``) of everything before it. Recognised by
content (the files have no extension).

Units and frames, converted here once: the Crazyflie's body frame is FLU
(x forward, y left, z up) and its world (and the Vicon's) is x forward, y left,
z up; MAVLink's are FRD and NED, so vectors become (x, -y, -z) and quaternions
(w, x, -y, -z) (a half turn about x).

==================  ===================================  =================================
event               variables                            measurement
==================  ===================================  =================================
estAcceleration     acc.x/y/z [g]                        ACCEL [m/s^2], FRD
estGyroscope        gyro.x/y/z [deg/s]                   GYRO [rad/s], FRD
estBarometer        baro.asl [m] (repeats at IMU rate;   BARO_ALTITUDE [m, up]; repeated
                    changes at ~25 Hz)                   values dropped (counted)
estTOF              range.zrange [mm]                    RANGE [m]; 0 and > 4 m skipped
estPose             locSrv.x/y/z [m], q (Vicon)          TRUTH_POSE (never to estimators)
others              (flow, UWB, sweep angles)            counted, not converted
==================  ===================================  =================================

Damage: a record with an unknown id, or one that runs past the data, ends the
reading there with a one-line error naming the file and offset in
``CrazyflieLog.damage``; everything before it is kept. A CRC mismatch is
reported the same way (the records may still be usable).
"""

from __future__ import annotations

import struct
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from groundstation.core.measurement import Kind, Measurement

MAGIC = 0xBC
#: struct codes a variable may have (the firmware logs integers and floats)
_NUMERIC_CODES = set("bBhHiIlLqQefd")
#: the events converted to measurements, with their number of variables
CONVERTED = {"estAcceleration": 3, "estGyroscope": 3, "estBarometer": 1, "estTOF": 1, "estPose": 7}
G0 = 9.80665
_FLU = np.array([1.0, -1.0, -1.0])


class CrazyflieLogError(ValueError):
    """Not a readable Crazyflie log (one line naming the file and offset)."""


@dataclass
class CrazyflieLog:
    path: Path
    events: dict[int, tuple[str, list[str], struct.Struct]]
    data: dict[str, tuple[np.ndarray, np.ndarray]]  # event name -> (t [s], values [n x k])
    crc_ok: bool
    damage: str | None = None
    skipped: Counter = field(default_factory=Counter)

    @property
    def duration(self) -> float:
        ts = [t[-1] for t, _ in self.data.values() if len(t)]
        t0 = [t[0] for t, _ in self.data.values() if len(t)]
        return max(ts) - min(t0) if ts else 0.0


def is_crazyflie_log(path: str | Path) -> bool:
    try:
        with open(path, "rb") as f:
            head = f.read(5)
    except OSError:
        return False
    return len(head) == 5 and head[0] == MAGIC and struct.unpack_from("<H", head, 1)[0] == 2


def read_crazyflie(path: str | Path) -> CrazyflieLog:
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise CrazyflieLogError(f"{p}: cannot read: {e.strerror or e}") from None
    if len(raw) < 9 or raw[0] != MAGIC:
        raise CrazyflieLogError(f"{p}: not a Crazyflie uSD log (no 0xBC header at offset 0)")
    version, n_types = struct.unpack_from("<HH", raw, 1)
    if version != 2:
        raise CrazyflieLogError(f"{p}: Crazyflie log version {version} at offset 1; only version 2 is known")
    crc_ok = zlib.crc32(raw[:-4]) == struct.unpack_from("<I", raw, len(raw) - 4)[0]
    pos = 5
    events: dict[int, tuple[str, list[str], struct.Struct]] = {}
    try:
        for _ in range(n_types):
            (eid,) = struct.unpack_from("<H", raw, pos)
            pos += 2
            end = raw.index(b"\0", pos)
            name = raw[pos:end].decode("ascii")
            pos = end + 1
            (n,) = struct.unpack_from("<H", raw, pos)
            pos += 2
            names, codes = [], ""
            for _ in range(n):
                end = raw.index(b"\0", pos)
                var = raw[pos:end].decode("ascii")
                pos = end + 1
                names.append(var[: var.index("(")])
                codes += var[var.index("(") + 1 : var.index(")")]
            if not set(codes) <= _NUMERIC_CODES:  # a definition's type that is no number: damaged
                raise ValueError(f"variable types {codes!r}")
            events[eid] = (name, names, struct.Struct("<HQ" + codes))
    except (struct.error, ValueError, UnicodeDecodeError):
        raise CrazyflieLogError(f"{p}: event definitions damaged near offset {pos}") from None
    end_data = len(raw) - 4
    rows: dict[int, list] = {eid: [] for eid in events}
    damage = None
    unpack_id = struct.Struct("<H").unpack_from
    while pos < end_data:
        (eid,) = unpack_id(raw, pos)
        ev = events.get(eid)
        if ev is None:
            damage = f"{p}: unknown event id {eid} at offset {pos}; {pos} bytes read"
            break
        st = ev[2]
        if pos + st.size > end_data:
            damage = f"{p}: truncated record at offset {pos}; {pos} bytes read"
            break
        rows[eid].append(st.unpack_from(raw, pos)[1:])
        pos += st.size
    if damage is None and not crc_ok:
        damage = f"{p}: CRC-32 mismatch (file damaged somewhere before offset {end_data})"
    data = {}
    skipped: Counter = Counter()
    for eid, rs in rows.items():
        if rs:
            name = events[eid][0]
            a = np.array(rs, dtype=float)
            expected = CONVERTED.get(name)
            if expected is not None and a.shape[1] - 1 != expected:
                # a definition whose variables are not the event's (a damaged header): not read as it
                skipped[f"damaged_definition:{name}"] = len(rs)
                continue
            data[name] = (a[:, 0] * 1e-6, a[:, 1:])
    return CrazyflieLog(p, events, data, crc_ok, damage, skipped)


def measurements(log: CrazyflieLog, source: str = "cf/1.1") -> list[Measurement]:
    """Everything convertible, in time order."""
    out: list[Measurement] = []
    d = log.data

    def add(kind, t, vals):
        for ti, v in zip(t, vals):
            out.append(Measurement(float(ti), kind, v, source, float(ti)))

    if "estAcceleration" in d:
        t, v = d["estAcceleration"]
        add(Kind.ACCEL, t, v * _FLU * G0)
    if "estGyroscope" in d:
        t, v = d["estGyroscope"]
        add(Kind.GYRO, t, np.radians(v) * _FLU)
    if "estBarometer" in d:
        t, v = d["estBarometer"]
        changed = np.r_[True, np.diff(v[:, 0]) != 0]
        log.skipped["baro_repeated_value"] = int((~changed).sum())
        add(Kind.BARO_ALTITUDE, t[changed], v[changed])
    if "estTOF" in d:
        t, v = d["estTOF"]
        r = v[:, 0] / 1000.0
        ok = (r > 0.005) & (r < 4.0)
        log.skipped["range_out_of_bounds"] = int((~ok).sum())
        add(Kind.RANGE, t[ok], r[ok, None])
    if "estPose" in d:
        t, v = d["estPose"]
        pos = v[:, 0:3] * _FLU
        qx, qy, qz, qw = v[:, 3], v[:, 4], v[:, 5], v[:, 6]
        q = np.stack([qw, qx, -qy, -qz], axis=1)
        add(Kind.TRUTH_POSE, t, np.hstack([pos, q]))
    for name in d:
        if name not in ("estAcceleration", "estGyroscope", "estBarometer", "estTOF", "estPose"):
            log.skipped[f"not_converted:{name}"] = len(d[name][0])
    out.sort(key=lambda m: m.t)
    return out


__all__ = ["CrazyflieLog", "CrazyflieLogError", "is_crazyflie_log", "read_crazyflie", "measurements"]
