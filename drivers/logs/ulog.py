"""PX4 ULog (``.ulg``) to measurements and tables.

Parsing is pyulog's (``pyulog.ULog``: definitions, multi-instance topics, logged messages,
parameters); this module maps topics to measurements, as :mod:`.dataflash` does DataFlash records.
Time is each topic's ``timestamp`` [us since boot] x 1e-6 (the sample time where the topic has
``timestamp_sample``).

========================  ==========================================  ==============================
topic                     fields                                      measurement
========================  ==========================================  ==============================
sensor_combined           gyro_rad[3] [rad/s], accelerometer_m_s2[3]  GYRO, ACCEL (FRD already)
vehicle_air_data          baro_alt_meter [m], baro_pressure_pa,       BARO_ALTITUDE, BARO_PRESSURE,
                          baro_temp_celcius                           TEMPERATURE [K]
distance_sensor           current_distance [m], min/max_distance,     RANGE (downward-facing, inside
                          orientation (25 = down), signal_quality     its limits, quality not 0)
vehicle_gps_position      lat, lon [1e-7 deg], alt [mm], fix_type     GPS (3-D fix only)
                          (newer PX4: latitude_deg, altitude_msl_m)
                          vel_n_m_s, vel_e_m_s, vel_d_m_s,            VELOCITY_NED (3-D fix and
                          vel_ned_valid                               vel_ned_valid only); vel_d
                                                                      alone as GPS_VD
vehicle_attitude          q[4] (w, x, y, z; FRD to NED)               ATTITUDE [rad]
actuator_outputs          output[0..n] [us] (the motors': PWM_MAIN_   ACTUATOR, (us - 1000) / 1000;
                          FUNCn, else the first noutputs); DShot     value / 1999 (.frame)
                          values 0..1999 where the parameters say
                          DShot (PWM_MAIN_TIM0, DSHOT_CONFIG)
vehicle_status            system_type (MAV_TYPE), CA_ROTOR_COUNT      VEHICLE_STATUS's mav_type, at
                                                                      the first sample (.frame)
actuator_controls_0       control[3] (thrust 0..1)                    THROTTLE
vehicle_thrust_setpoint   xyz[2] (thrust, -1..0: FRD; PX4 1.14 on,    THROTTLE, as -xyz[2]
                          without actuator_controls_0)
battery_status            voltage_v [V], current_a [A]                BATTERY_VOLTAGE, BATTERY_CURRENT
========================  ==========================================  ==============================

Every topic also goes to :attr:`UlogLog.tables` (``name`` for instance 0, ``name[i]`` for the
others), the logged messages to the table ``logged_messages`` (``level``, ``text``), the
parameters to ``tables.params``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from groundstation.core.imu import ImuColumns, ImuSeries
from groundstation.core.measurement import Kind, Measurement

from .frame import frame_status, px4_dshot_outputs, px4_logs_mav_type, px4_motor_columns, px4_output_fraction
from .quiet import quiet
from .tables import LogTables, Table
from .ulog_check import ULogStructureError, check
from .ulog_source import ULogSource

#: a ULog file's first bytes: "ULog", then 0x01 0x12 0x35 (the format's magic)
ULOG_MAGIC = b"ULog\x01\x12\x35"
#: [us] a timestamp past this is from the UNIX epoch (PX4 SITL), not from boot: about 31 years of uptime
EPOCH_US = 1e15


class ULogError(ValueError):
    """Not a readable ULog (one line naming the file)."""


def is_ulog(path: str | Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(7) == ULOG_MAGIC
    except OSError:
        return False


@dataclass
class UlogLog:
    path: Path
    measurements: list[Measurement]
    tables: LogTables
    skipped: Counter = field(default_factory=Counter)
    damage: str = ""
    hardware: str = ""
    #: with ``imu_columns``: sensor_combined's accelerometer and gyro as columns, not among ``measurements``
    imu: ImuColumns | None = None

    @property
    def duration(self) -> float:
        ts = [self.measurements[0].t, self.measurements[-1].t] if self.measurements else []
        for series in self.imu.series.values() if self.imu is not None else ():
            if len(series):
                ts += [float(series.t[0]), float(series.t[-1])]
        return max(ts) - min(ts) if ts else 0.0


def read_ulog(path: str | Path, source: str = "ulog/1.1", *, imu_columns: bool = False) -> UlogLog:
    """The log's measurements and tables. ``imu_columns``: sensor_combined's samples as columns
    (:class:`~groundstation.core.imu.ImuColumns`, :attr:`UlogLog.imu`) straight from pyulog's arrays,
    not a record each (a 1 kHz IMU is most of a log's readings)."""
    from pyulog import ULog  # imported here: its import costs 0.3 s that other logs do not need

    p = Path(path)
    if not p.exists():
        raise ULogError(f"{p}: cannot read: no such file")
    if not is_ulog(p):
        raise ULogError(f"{p}: not a ULog (no ULog magic at offset 0)")
    try:
        data = p.read_bytes()
    except OSError as e:
        raise ULogError(f"{p}: cannot read: {e.strerror or e}") from None
    try:
        checked = check(data)  # bounds first: pyulog trusts the file (ulog_check.py)
    except ULogStructureError as e:
        raise ULogError(f"{p}: not a readable ULog: {e}") from None
    # pyulog is handed the file up to its last whole message, from memory (it takes a file object),
    # its resynchronisation on damage made to move forward (ulog_source.py)
    source_file = ULogSource(data[: checked.end] if checked.cut else data)
    del data
    try:
        with quiet():  # pyulog prints a warning per message it cannot place
            u = ULog(source_file)
    except Exception as e:  # pyulog raises assorted errors on damaged files
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ULogError(f"{p}: not a readable ULog: {first}") from None
    finally:
        source_file.close()
    tables = LogTables(params=dict(u.initial_parameters), fmt="ulog", autopilot="px4", firmware=_px4_version(u))
    untimed: Counter = Counter()
    # a vehicle's clock counts from its boot; PX4 SITL's (lockstep) from the UNIX epoch: its times are
    # taken from the log's start, as a pilot reads a flight's (1710773351.3 s is 1.0 s into the log)
    zero_us = float(u.start_timestamp) if u.start_timestamp > EPOCH_US else 0.0
    for d in u.data_list:
        name = d.name if d.multi_id == 0 else f"{d.name}[{d.multi_id}]"
        if "timestamp" not in d.data:
            untimed["topic_without_timestamp"] += 1  # no clock to put it on
            continue
        raw = np.asarray(d.data["timestamp"], dtype=float)
        cols = {k: np.asarray(v) for k, v in d.data.items() if k != "timestamp"}
        if zero_us and (off := raw < EPOCH_US).any():
            # a topic published before SITL's clock was set, stamped 0 or from boot: on no clock of
            # this log (it had put the parameters' risks 1.7e9 s before the flight), so counted, not placed
            untimed["timestamp_off_the_log_clock"] += int(off.sum())
            raw, cols = raw[~off], {k: v[~off] for k, v in cols.items()}
        t = (raw - zero_us) * 1e-6
        if zero_us and "timestamp_sample" in cols:
            cols["timestamp_sample"] = cols["timestamp_sample"].astype(float) - zero_us
        tables.tables[name] = Table(t, cols)
    msgs = list(u.logged_messages)
    tables.tables["logged_messages"] = Table(
        np.array([(m.timestamp - zero_us) * 1e-6 for m in msgs], dtype=float),
        {
            "level": np.array([m.log_level for m in msgs], dtype=float),
            "text": np.array([m.message for m in msgs], dtype=object),
        },
    )
    log = UlogLog(p, [], tables, skipped=untimed, hardware=str(u.msg_info_dict.get("ver_hw", "")))
    damage = []
    if getattr(u, "file_corruption", False):
        damage.append("damaged stretches skipped by the reader")
    if checked.cut:
        damage.append(f"last message cut at offset {checked.end}")
    if damage:
        log.damage = f"{p}: " + "; ".join(damage)
    _measurements(tables, log, source, imu_columns)
    log.measurements.sort(key=lambda m: m.t)
    # the frame the log states, as the HEARTBEAT a tlog would carry: from the log's first sample
    t0 = min(log.measurements[0].t if log.measurements else math.inf, log.imu.start if log.imu else math.inf)
    if math.isfinite(t0) and (mav_type := px4_logs_mav_type(tables)) is not None:
        log.measurements.insert(0, frame_status(t0, mav_type, mavlink.MAV_AUTOPILOT_PX4, source))
    return log


def _sample_time(tb: Table) -> np.ndarray:
    ts = tb.numeric("timestamp_sample")
    return ts * 1e-6 if ts is not None and np.all(ts > 0) else tb.t


def _vec(tb: Table, base: str, n: int) -> np.ndarray | None:
    cols = [tb.numeric(f"{base}[{i}]") for i in range(n)]
    if any(c is None for c in cols):
        return None
    return np.column_stack(cols)  # type: ignore[arg-type]


def _measurements(tables: LogTables, log: UlogLog, s: str, imu_columns: bool = False) -> None:
    out, skipped = log.measurements, log.skipped

    def add_rows(kind: Kind, t: np.ndarray, values: np.ndarray, instance: int = 0) -> None:
        for ti, v in zip(t.tolist(), values):
            out.append(Measurement(ti, kind, np.asarray(v, dtype=float), s, ti, None, instance))

    sc = tables.get("sensor_combined")
    if sc is not None:
        gyro, acc = _vec(sc, "gyro_rad", 3), _vec(sc, "accelerometer_m_s2", 3)
        if gyro is not None and acc is not None:
            rel = sc.numeric("accelerometer_timestamp_relative")
            imu = ((Kind.GYRO, sc.t, gyro), (Kind.ACCEL, sc.t + (rel * 1e-6 if rel is not None else 0.0), acc))
            if imu_columns:
                log.imu = ImuColumns({(kind, 0): _series(s, times, vals) for kind, times, vals in imu})
            else:
                for kind, times, vals in imu:
                    add_rows(kind, times, vals)
    ad = tables.get("vehicle_air_data")
    if ad is not None:
        t = _sample_time(ad)
        for col, kind, conv in (
            ("baro_alt_meter", Kind.BARO_ALTITUDE, 0.0),
            ("baro_pressure_pa", Kind.BARO_PRESSURE, 0.0),
            ("baro_temp_celcius", Kind.TEMPERATURE, 273.15),
        ):
            v = ad.numeric(col)
            if v is not None:
                add_rows(kind, t, (v + conv)[:, None])
    for name, ds in tables.starting("distance_sensor"):
        d = ds.numeric("current_distance")
        if d is None:
            continue
        lo, hi = ds.numeric("min_distance"), ds.numeric("max_distance")
        ori, q = ds.numeric("orientation"), ds.numeric("signal_quality")
        ok = np.isfinite(d)
        if ori is not None:
            ok &= ori == 25  # ROTATION_DOWNWARD_FACING
        if lo is not None and hi is not None:
            inside = (d > lo) & (d < hi)
            skipped["range_out_of_bounds"] += int((ok & ~inside).sum())
            ok &= inside
        if q is not None:
            skipped["range_no_signal"] += int((ok & (q == 0)).sum())
            ok &= q != 0
        add_rows(Kind.RANGE, ds.t[ok], d[ok][:, None], 0 if name == "distance_sensor" else 1)
    gps = tables.get("vehicle_gps_position", "sensor_gps")
    if gps is not None:
        fix = gps.numeric("fix_type")
        if gps.get("latitude_deg") is not None:
            lat, lon, alt = gps.numeric("latitude_deg"), gps.numeric("longitude_deg"), gps.numeric("altitude_msl_m")
        else:
            lat, lon, alt = gps.numeric("lat"), gps.numeric("lon"), gps.numeric("alt")
            if lat is not None and lon is not None and alt is not None:
                lat, lon, alt = lat * 1e-7, lon * 1e-7, alt * 1e-3
        if lat is not None and lon is not None and alt is not None:
            ok = fix >= 3 if fix is not None else np.ones(len(gps), bool)
            skipped["gps_no_3d_fix"] += int((~ok).sum())
            add_rows(Kind.GPS, gps.t[ok], np.column_stack([lat, lon, alt])[ok])
            vn, ve, vd = (gps.numeric(f"vel_{a}_m_s") for a in "ned")
            if vn is not None and ve is not None and vd is not None:
                valid = gps.numeric("vel_ned_valid")
                ok_v = ok & (valid != 0) if valid is not None else ok
                add_rows(Kind.VELOCITY_NED, gps.t[ok_v], np.column_stack([vn, ve, vd])[ok_v])
                add_rows(Kind.GPS_VD, gps.t[ok_v], vd[ok_v][:, None])  # the fix's own, as DataFlash's VZ
    att = tables.get("vehicle_attitude")
    if att is not None:
        q = _vec(att, "q", 4)
        if q is not None:
            w, x, y, z = q.T
            roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
            pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
            yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
            add_rows(Kind.ATTITUDE, att.t, np.column_stack([roll, pitch, yaw]))
    ao = tables.get("actuator_outputs")
    if ao is not None:
        pwm = _motor_outputs(ao, tables.params)
        if pwm is not None:
            add_rows(Kind.ACTUATOR, ao.t, px4_output_fraction(pwm, px4_dshot_outputs(tables.params)))
    t_thr, thr = _collective_thrust(tables)
    if thr is not None:
        add_rows(Kind.THROTTLE, t_thr, np.clip(thr, 0.0, 1.0)[:, None])
    bat = tables.get("battery_status")
    if bat is not None:
        v, i = bat.numeric("voltage_v"), bat.numeric("current_a")
        if v is not None and i is not None:
            ok = v > 0
            skipped["battery_not_connected"] += int((~ok).sum())
            add_rows(Kind.BATTERY_VOLTAGE, bat.t[ok], v[ok][:, None])
            add_rows(Kind.BATTERY_CURRENT, bat.t[ok], i[ok][:, None])


def _collective_thrust(tables: LogTables) -> tuple[np.ndarray, np.ndarray | None]:
    """The controller's collective thrust 0..1: ``actuator_controls_0``'s ``control[3]`` up to PX4
    1.13; from 1.14 on (control allocation) the mixer's input is ``vehicle_thrust_setpoint``, whose
    ``xyz[2]`` is the same normalised thrust along body z, negative up (FRD). Instance 0 is the
    multicopter's (a VTOL's fixed-wing thrust is instance 1)."""
    ac = tables.get("actuator_controls_0")
    if ac is not None and (thr := ac.numeric("control[3]")) is not None:
        return ac.t, thr
    ts = tables.get("vehicle_thrust_setpoint")
    if ts is not None and (z := ts.numeric("xyz[2]")) is not None:
        return ts.t, -z
    return np.empty(0), None


def _motor_outputs(ao: Table, params: dict[str, float]) -> np.ndarray | None:
    """``actuator_outputs``' motor columns in the motors' order where the outputs' functions say
    which (:func:`.frame.px4_motor_columns`), else the outputs it has (``noutputs``)."""
    columns = px4_motor_columns(params)
    if columns is None:
        n = ao.numeric("noutputs")
        count = int(np.max(n)) if n is not None and len(n) else 4
        columns = list(range(max(1, min(count, 16))))
    cols = [ao.numeric(f"output[{i}]") for i in columns]
    if any(c is None for c in cols):
        return None
    return np.column_stack(cols)  # type: ignore[arg-type]


def _series(source: str, t: np.ndarray, values: np.ndarray) -> ImuSeries:
    """One IMU sensor's samples as a series, in time order (as its records would be, sorted)."""
    order = np.argsort(t, kind="stable")
    t = np.asarray(t, dtype=float)[order]
    return ImuSeries(source, t, t, np.asarray(values, dtype=float)[order], np.ones(len(t), dtype=np.int32))


def _px4_version(u) -> str:
    """ "PX4 v1.14.0" from the log's info (``sys_name``, ``ver_sw_release``: 0xAABBCCTT, major, minor,
    patch and type), or the bare system name."""
    info = u.msg_info_dict
    name = str(info.get("sys_name", "") or "")
    release = info.get("ver_sw_release")
    if isinstance(release, int) and release > 0:
        return f"{name or 'PX4'} v{(release >> 24) & 0xFF}.{(release >> 16) & 0xFF}.{(release >> 8) & 0xFF}"
    return name
