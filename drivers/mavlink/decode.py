"""MAVLink messages (the framer's field tuples, or pymavlink objects) to :class:`Measurement` records.

A message comes as the tuple of its fields in wire order (pymavlink's
``ordered_fieldnames``), as the framer unpacks it; a pymavlink message object is
turned into that tuple first. Each handler reads its fields through an
``itemgetter`` built from the field names (:func:`_fields`), which at 1 kHz
costs a fraction of reading them by name from an object.

Every unit conversion of the MAVLink driver happens here, driven by the unit
names of the message definitions (:data:`VECTORS` and :data:`SPECIAL_UNITS`,
checked against pymavlink's ``fieldunits_by_name`` by the tests). Frames are
already MAVLink's (NED/FRD) and stay so.

Vehicle time: the message's ``time_usec``/``time_boot_ms`` where it has one
(a UNIX-epoch ``time_usec`` or a zero time is treated as absent); otherwise the
system's aligned clock (:mod:`drivers.mavlink.clock`). SERVO_OUTPUT_RAW's
``time_usec`` is a uint32 that wraps every 71.6 minutes: the aligned clock says
which turn it is on, and the field gives the time within it (the aligned clock
alone is the receive time's: a few ms of jitter, which a 3-DOF rig's
identification read as a 2 ms lag of its motor voltages).

Until a system has sent its first timestamped message, the offset is unknown:
its untimed measurements wait (at most ``PENDING_S``) and are stamped once the
clock is known. A system that never sends a time field is put on receive time
after ``PENDING_S`` (``VehicleClock.assumed``).

Invalid values the protocol marks as such (UINT16_MAX voltages, -1 currents,
unused RC/servo channels, no GPS fix, out-of-range distances) are skipped and
counted in :attr:`MavlinkDecoder.skipped`, never passed on as numbers.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from operator import itemgetter

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundstation.core.measurement import Kind, Measurement

from .clock import EPOCH_THRESHOLD_US, VehicleClock
from .units import UNIT_TO_SI, scale

_nan = math.nan
_array = np.array
#: Builds a Measurement from a full 8-tuple without NamedTuple's keyword
#: __new__ (a third of the cost at 1 kHz). Field order as in Measurement.
_M = Measurement
_new = tuple.__new__

#: Regular vector conversions: message -> [(kind, fields, unit)].
#: The instance is the message's number (SCALED_IMU2 -> 1) unless the message
#: has an ``id`` field.
VECTORS: dict[str, list[tuple[Kind, tuple[str, ...], str]]] = {
    **{
        name: [
            (Kind.ACCEL, ("xacc", "yacc", "zacc"), "mG"),
            (Kind.GYRO, ("xgyro", "ygyro", "zgyro"), "mrad/s"),
            (Kind.MAG, ("xmag", "ymag", "zmag"), "mgauss"),
        ]
        for name in ("SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "RAW_IMU")
    },
    "ATTITUDE": [
        (Kind.ATTITUDE, ("roll", "pitch", "yaw"), "rad"),
        (Kind.ANGULAR_RATE, ("rollspeed", "pitchspeed", "yawspeed"), "rad/s"),
    ],
    "LOCAL_POSITION_NED": [
        (Kind.POSITION_NED, ("x", "y", "z"), "m"),
        (Kind.VELOCITY_NED, ("vx", "vy", "vz"), "m/s"),
    ],
}

#: Units of the fields the special handlers below read (checked by the tests).
SPECIAL_UNITS: dict[str, dict[str, str]] = {
    "HIGHRES_IMU": {
        "xacc": "m/s/s",
        "xgyro": "rad/s",
        "xmag": "gauss",
        "abs_pressure": "hPa",
        "diff_pressure": "hPa",
        "temperature": "degC",
    },
    "SCALED_PRESSURE": {"press_abs": "hPa", "press_diff": "hPa", "temperature": "cdegC"},
    "SCALED_PRESSURE2": {"press_abs": "hPa", "press_diff": "hPa", "temperature": "cdegC"},
    "SCALED_PRESSURE3": {"press_abs": "hPa", "press_diff": "hPa", "temperature": "cdegC"},
    "DISTANCE_SENSOR": {"current_distance": "cm", "min_distance": "cm", "max_distance": "cm", "covariance": "cm^2"},
    "GPS_RAW_INT": {"lat": "degE7", "lon": "degE7", "alt": "mm", "h_acc": "mm", "v_acc": "mm"},
    "GLOBAL_POSITION_INT": {
        "lat": "degE7",
        "lon": "degE7",
        "alt": "mm",
        "relative_alt": "mm",
        "vx": "cm/s",
        "vy": "cm/s",
        "vz": "cm/s",
    },
    "VFR_HUD": {"airspeed": "m/s", "groundspeed": "m/s", "heading": "deg", "throttle": "%", "alt": "m", "climb": "m/s"},
    "SYS_STATUS": {"voltage_battery": "mV", "current_battery": "cA", "battery_remaining": "%"},
    "BATTERY_STATUS": {"voltages": "mV", "voltages_ext": "mV", "current_battery": "cA", "battery_remaining": "%"},
    "SERVO_OUTPUT_RAW": {f"servo{i}_raw": "us" for i in range(1, 17)},
    "RC_CHANNELS": {f"chan{i}_raw": "us" for i in range(1, 19)},
    "ATT_POS_MOCAP": {"x": "m", "y": "m", "z": "m"},
}

_CLASS = {cls.msgname: cls for cls in mavlink.mavlink_map.values()}


def _fields(name: str, *fields: str) -> Callable:
    """The getter of ``fields`` from a message ``name``'s field tuple (wire order): the value of
    one field, or the tuple of several."""
    order = _CLASS[name].ordered_fieldnames
    return itemgetter(*(order.index(f) for f in fields))


def _as_fields(cls) -> Callable:
    """Message object -> its field tuple in wire order; a field an older dialect's object lacks
    (MAVLink 2 extensions) is 0, as on the wire."""
    names = cls.ordered_fieldnames
    return lambda m: tuple(getattr(m, f, 0) for f in names)


_SERVO_FIELDS = tuple(f"servo{i}_raw" for i in range(1, 17))
_RC_FIELDS = tuple(f"chan{i}_raw" for i in range(1, 19))
_servo_values = _fields("SERVO_OUTPUT_RAW", *_SERVO_FIELDS)
_servo_port = _fields("SERVO_OUTPUT_RAW", "port")
_rc_count = _fields("RC_CHANNELS", "chancount")
_rc_values = _fields("RC_CHANNELS", *_RC_FIELDS)
_hr_flags = _fields("HIGHRES_IMU", "fields_updated", "id")
_hr_imu = _fields("HIGHRES_IMU", "xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro")
_hr_all = _fields(
    "HIGHRES_IMU",
    *("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag"),
    *("abs_pressure", "diff_pressure", "temperature"),
)
_pressure = _fields("SCALED_PRESSURE", "press_abs", "press_diff", "temperature")  # (2 and 3 alike)
_distance = _fields("DISTANCE_SENSOR", "current_distance", "min_distance", "max_distance", "covariance", "id")
_gps = _fields("GPS_RAW_INT", "fix_type", "lat", "lon", "alt", "h_acc", "v_acc")
_global_position = _fields("GLOBAL_POSITION_INT", "lat", "lon", "alt", "relative_alt", "vx", "vy", "vz")
_vfr_hud_fields = _fields("VFR_HUD", "throttle", "alt", "climb", "airspeed", "groundspeed", "heading")
_sys_battery = _fields("SYS_STATUS", "voltage_battery", "current_battery", "battery_remaining")
_battery_status_fields = _fields(
    "BATTERY_STATUS", "id", "voltages", "voltages_ext", "current_battery", "battery_remaining"
)
_manual = _fields("MANUAL_CONTROL", "x", "y", "z", "r", "target")
_heartbeat_fields = _fields("HEARTBEAT", "type", "base_mode", "custom_mode", "system_status", "autopilot")
_quaternion = _fields("ATTITUDE_QUATERNION", "q1", "q2", "q3", "q4")
_mocap = _fields("ATT_POS_MOCAP", "x", "y", "z", "q")
_ekf = _fields(
    "EKF_STATUS_REPORT",
    *("flags", "velocity_variance", "pos_horiz_variance", "pos_vert_variance"),
    *("compass_variance", "terrain_alt_variance"),
)

_INSTANCE_BY_NAME = {"SCALED_IMU2": 1, "SCALED_IMU3": 2, "SCALED_PRESSURE2": 1, "SCALED_PRESSURE3": 2}

# Pre-computed scale factors (the hot path multiplies by constants).
_MG = scale("mG")
_CM = scale("cm")
_MM = scale("mm")
_DEGE7 = scale("degE7")
_HPA = scale("hPa")
_MV = scale("mV")
_CA = scale("cA")
_PCT = scale("%")
_DEG = scale("deg")
_GAUSS = scale("gauss")
_CDEGC_S, _CDEGC_O = UNIT_TO_SI["cdegC"]
_DEGC_O = UNIT_TO_SI["degC"][1]
_UINT16_MAX = 65535
#: metres per degree of latitude (WGS84 mean), to express GPS accuracy in degrees
_M_PER_DEG = 111_320.0

# HIGHRES_IMU fields_updated bits (MAVLink HIGHRES_IMU_UPDATED_FLAGS)
_HR_ACC, _HR_GYRO, _HR_MAG = 0x7, 0x38, 0x1C0
_HR_ABS, _HR_DIFF, _HR_TEMP = 0x200, 0x400, 0x1000
_HR_OTHER = _HR_MAG | _HR_ABS | _HR_DIFF | _HR_TEMP

Out = list  # list[Measurement]

#: How long untimed measurements wait for their system's clock [s].
PENDING_S = 2.0
_PENDING_MAX = 2000


def _time_field(cls) -> tuple[Callable | None, float, float]:
    """The getter of the message's vehicle-time field (None: it has none), the largest raw value
    that is a time since boot (a larger ``time_usec`` is a UNIX-epoch time; a negative one is minus
    the period of a field that wraps), and its scale to s."""
    names = cls.ordered_fieldnames
    if cls.msgname == "SERVO_OUTPUT_RAW":  # uint32 us wraps every 71.6 min: minus its period
        return itemgetter(names.index("time_usec")), -(2**32) * 1e-6, 1e-6
    if "time_usec" in names:
        return itemgetter(names.index("time_usec")), EPOCH_THRESHOLD_US, 1e-6
    if "time_boot_ms" in names:
        return itemgetter(names.index("time_boot_ms")), math.inf, 1e-3
    return None, 0.0, 0.0


# Kind's members as module constants, for the handlers: an enum member's lookup costs 100 ns, a
# global's 30 (a 1 kHz HIGHRES_IMU names six)
(
    _ACCEL,
    _ACTUATOR,
    _AIRSPEED,
    _ALTITUDE,
    _ATTITUDE_QUATERNION,
    _BARO_PRESSURE,
    _BATTERY_CURRENT,
    _BATTERY_REMAINING,
    _BATTERY_VOLTAGE,
    _CLIMB_RATE,
    _DIFF_PRESSURE,
    _EKF_STATUS,
    _GLOBAL_POSITION,
    _GPS,
    _GYRO,
    _MAG,
    _MANUAL_CONTROL,
    _RANGE,
    _RC_INPUT,
    _TEMPERATURE,
    _THROTTLE,
    _TRUTH_POSE,
    _VEHICLE_STATUS,
    _VELOCITY_NED,
) = (
    Kind.ACCEL,
    Kind.ACTUATOR,
    Kind.AIRSPEED,
    Kind.ALTITUDE,
    Kind.ATTITUDE_QUATERNION,
    Kind.BARO_PRESSURE,
    Kind.BATTERY_CURRENT,
    Kind.BATTERY_REMAINING,
    Kind.BATTERY_VOLTAGE,
    Kind.CLIMB_RATE,
    Kind.DIFF_PRESSURE,
    Kind.EKF_STATUS,
    Kind.GLOBAL_POSITION,
    Kind.GPS,
    Kind.GYRO,
    Kind.MAG,
    Kind.MANUAL_CONTROL,
    Kind.RANGE,
    Kind.RC_INPUT,
    Kind.TEMPERATURE,
    Kind.THROTTLE,
    Kind.TRUTH_POSE,
    Kind.VEHICLE_STATUS,
    Kind.VELOCITY_NED,
)


class MavlinkDecoder:
    """Turns decoded pymavlink messages into measurements, one link's worth.

    ``decode(msg, t_rx)`` returns a (possibly empty) list. ``skipped`` counts
    values the protocol marks invalid, by reason; ``unknown`` counts messages
    this decoder has no conversion for, by type (they still reach the raw hook
    and the recording).
    """

    def __init__(self, link_name: str = "mav") -> None:
        self.link_name = link_name
        self.clocks: dict[int, VehicleClock] = {}
        self.skipped: Counter[str] = Counter()
        self.unknown: Counter[str] = Counter()
        #: sysid << 8 | compid -> (its system's clock, the component's source name)
        self._senders: dict[int, tuple[VehicleClock, str]] = {}
        self._pending: dict[int, list[Measurement]] = {}
        #: called with a system id whose clock went back (it restarted: VehicleClock.restarts)
        self.on_restart: Callable[[int], None] | None = None
        #: system ids heard with a ground station's heartbeat
        self.ground_stations: set[int] = set()
        #: sources whose first battery comes in BATTERY_STATUS: their SYS_STATUS repeats it
        self._battery_status_from: set[str] = set()
        # Keyed by class: a message's ``id`` attribute can be a field (RAW_IMU.id).
        # (handler, the time field's getter or None, instance, its largest time since boot, its scale
        # to s, a message object's field tuple)
        self._handlers: dict[type, tuple[Callable, Callable | None, int, float, float, Callable]] = {}
        for cls in mavlink.mavlink_map.values():
            handler = self._handler_for(cls.msgname)
            if handler is not None:
                getter, largest, to_s = _time_field(cls)
                instance = _INSTANCE_BY_NAME.get(cls.msgname, 0)
                self._handlers[cls] = (handler, getter, instance, largest, to_s, _as_fields(cls))

    @property
    def waiting(self) -> bool:
        """Whether untimed measurements wait for their system's clock (:data:`PENDING_S`)."""
        return bool(self._pending)

    def waiting_for(self, sysid: int) -> bool:
        """Whether untimed measurements of system ``sysid`` wait for its clock."""
        return sysid in self._pending

    # -- dispatch -----------------------------------------------------------
    def decode(self, m, t_rx: float) -> Out:
        """Measurements from a pymavlink message object."""
        hdr = m._header
        return self.convert(type(m), m, hdr.srcSystem, hdr.srcComponent, t_rx)

    def convert(self, cls, m, sysid: int, compid: int, t_rx: float) -> Out:
        """Measurements from message ``m`` of pymavlink class ``cls``.

        ``m`` is the tuple of the message's fields in wire order (the framer's), or anything with
        the message's field names as attributes (a pymavlink object).
        """
        out: Out = []
        self.convert_into(out, cls, m, sysid, compid, t_rx)
        return out

    def convert_into(self, out: Out, cls, m, sysid: int, compid: int, t_rx: float) -> None:
        """:meth:`convert`, appending to ``out`` (a receiver's list of one read's measurements)."""
        entry = self._handlers.get(cls)
        if entry is None:
            self.unknown[cls.msgname] += 1
            return
        handler, time_field, instance, largest, to_s, as_fields = entry
        if type(m) is not tuple:
            m = as_fields(m)
        sender = self._senders.get(sysid << 8 | compid)
        if sender is None:
            sender = self._sender(sysid, compid)
        clock, source = sender
        if time_field is not None and (raw := time_field(m)) and raw <= largest:
            t = raw * to_s
            if clock.observe(t, t_rx) and self.on_restart is not None:
                self.on_restart(sysid)
        else:  # no time field, a zero one, or a UNIX-epoch time_usec: the system's aligned clock
            t = clock.vehicle_time(t_rx)
            if largest < 0.0 and raw and t == t:  # a field that wraps: the clock picks its turn
                t_field = raw * to_s
                t = t_field - largest * round((t - t_field) / -largest)
        n = len(out)
        try:
            handler(m, t, t_rx, source, instance, out)
        except BaseException:
            del out[n:]  # a message is converted whole or not at all
            raise
        if t != t:  # clock still unknown: hold these back
            held = out[n:]
            del out[n:]
            out += self._hold(sysid, clock, held, t_rx)
        elif self._pending and sysid in self._pending:  # the clock came: those held go first
            out[n:n] = self._release(sysid, clock)

    def _sender(self, sysid: int, compid: int) -> tuple[VehicleClock, str]:
        """A component's system clock and its source name, the first time it is heard."""
        clock = self.clocks.get(sysid)
        if clock is None:
            clock = self.clocks[sysid] = VehicleClock()
        sender = self._senders[sysid << 8 | compid] = (clock, f"{self.link_name}/{sysid}.{compid}")
        return sender

    def _hold(self, sysid: int, clock: VehicleClock, out: Out, t_rx: float) -> Out:
        pend = self._pending.setdefault(sysid, [])
        if len(pend) + len(out) > _PENDING_MAX:
            self.skipped["no_vehicle_clock"] += len(out)
        else:
            pend.extend(out)
        if pend and t_rx - pend[0].t_rx > PENDING_S:
            clock.assume_receive_time()
            return self._release(sysid, clock)
        return []

    def _release(self, sysid: int, clock: VehicleClock) -> Out:
        vt = clock.vehicle_time
        return [m._replace(t=vt(m.t_rx)) for m in self._pending.pop(sysid, ())]

    def _handler_for(self, name: str):
        if name in VECTORS:
            fields = tuple(f for _, fs, _ in VECTORS[name] for f in fs)
            scales = np.array([scale(u) for _, fs, u in VECTORS[name] for _ in fs])
            slices, k = [], 0
            for kind, fs, _ in VECTORS[name]:
                slices.append((kind, slice(k, k + len(fs))))
                k += len(fs)
            imu_id = _fields(name, "id") if name == "RAW_IMU" else None
            values = _fields(name, *fields)
            unscaled = bool(np.all(scales == 1.0))  # (radians: the ATTITUDE at an IMU's rate)

            def vectors(m, t, t_rx, source, instance, out, values=values, scales=scales, slices=slices, imu_id=imu_id):
                if imu_id is not None:
                    instance = imu_id(m) or 0
                v = _array(values(m), dtype=float)
                if not unscaled:
                    v *= scales
                for kind, sl in slices:
                    out.append(_new(_M, (t, kind, v[sl], source, t_rx, None, instance, 1)))

            return vectors
        return getattr(self, "_" + name.lower(), None)

    # -- messages with special rules ----------------------------------------
    def _highres_imu(self, m, t, t_rx, source, instance, out):
        upd, instance = _hr_flags(m)
        upd = upd or 0xFFFF  # 0 from legacy senders: treat as all
        if upd & _HR_OTHER == 0:  # the IMU alone (most messages: PX4 flags a sensor after it updated)
            v = _array(_hr_imu(m), dtype=float)
            if upd & _HR_ACC:
                out.append(_new(_M, (t, _ACCEL, v[0:3], source, t_rx, None, instance, 1)))
            if upd & _HR_GYRO:
                out.append(_new(_M, (t, _GYRO, v[3:6], source, t_rx, None, instance, 1)))
            return
        # One array for the whole message; the measurements hold views of it.
        xacc, yacc, zacc, xgyro, ygyro, zgyro, xmag, ymag, zmag, abs_pressure, diff_pressure, temperature = _hr_all(m)
        v = _array(
            (
                xacc,
                yacc,
                zacc,
                xgyro,
                ygyro,
                zgyro,
                xmag * _GAUSS,
                ymag * _GAUSS,
                zmag * _GAUSS,
                abs_pressure * _HPA,
                diff_pressure * _HPA,
                temperature + _DEGC_O,
            )
        )
        if upd & _HR_ACC:
            out.append(_new(_M, (t, _ACCEL, v[0:3], source, t_rx, None, instance, 1)))
        if upd & _HR_GYRO:
            out.append(_new(_M, (t, _GYRO, v[3:6], source, t_rx, None, instance, 1)))
        if upd & _HR_MAG:
            out.append(_new(_M, (t, _MAG, v[6:9], source, t_rx, None, instance, 1)))
        if upd & _HR_ABS:
            out.append(_new(_M, (t, _BARO_PRESSURE, v[9:10], source, t_rx, None, instance, 1)))
        if upd & _HR_DIFF:
            out.append(_new(_M, (t, _DIFF_PRESSURE, v[10:11], source, t_rx, None, instance, 1)))
        if upd & _HR_TEMP:
            out.append(_new(_M, (t, _TEMPERATURE, v[11:12], source, t_rx, None, instance, 1)))

    def _scaled_pressure(self, m, t, t_rx, source, instance, out):
        # one array for the message; the measurements hold views of it
        press_abs, press_diff, temperature = _pressure(m)
        v = _array((press_abs * _HPA, press_diff * _HPA, temperature * _CDEGC_S + _CDEGC_O))
        out.append(_new(_M, (t, _BARO_PRESSURE, v[0:1], source, t_rx, None, instance, 1)))
        if press_diff:
            out.append(_new(_M, (t, _DIFF_PRESSURE, v[1:2], source, t_rx, None, instance, 1)))
        out.append(_new(_M, (t, _TEMPERATURE, v[2:3], source, t_rx, None, instance, 1)))

    _scaled_pressure2 = _scaled_pressure
    _scaled_pressure3 = _scaled_pressure

    def _distance_sensor(self, m, t, t_rx, source, instance, out):
        d, lo, hi, cov, sensor = _distance(m)
        if d <= lo or d >= hi:
            # a reading at or beyond a limit is the sensor's clamp, not a distance: ArduPilot and PX4
            # report out-of-range readings this way, and a sensor on the ground reads its minimum
            self.skipped["range_out_of_bounds"] += 1
            return
        var = None if cov in (0, 255) else _array([cov * 1e-4])
        out.append(_new(_M, (t, _RANGE, _array([d * _CM]), source, t_rx, var, sensor, 1)))

    def _gps_raw_int(self, m, t, t_rx, source, instance, out):
        fix_type, lat, lon, alt, h_acc, v_acc = _gps(m)
        if fix_type < 3:  # no fix or 2D: no usable altitude
            self.skipped["gps_no_3d_fix"] += 1
            return
        lat = lat * _DEGE7
        var = None
        if h_acc and v_acc:
            # Accuracy [mm] to variance in the value's own units (deg^2, deg^2, m^2).
            h_deg = h_acc * _MM / _M_PER_DEG
            coslat = max(math.cos(math.radians(lat)), 1e-6)
            var = _array([h_deg**2, (h_deg / coslat) ** 2, (v_acc * _MM) ** 2])
        out.append(_new(_M, (t, _GPS, _array([lat, lon * _DEGE7, alt * _MM]), source, t_rx, var, instance, 1)))

    def _global_position_int(self, m, t, t_rx, source, instance, out):
        lat, lon, alt, relative_alt, vx, vy, vz = _global_position(m)
        v = _array((lat * _DEGE7, lon * _DEGE7, alt * _MM, relative_alt * _MM, vx * _CM, vy * _CM, vz * _CM))
        out.append(_new(_M, (t, _GLOBAL_POSITION, v[0:4], source, t_rx, None, instance, 1)))
        out.append(_new(_M, (t, _VELOCITY_NED, v[4:7], source, t_rx, None, instance, 1)))

    def _vfr_hud(self, m, t, t_rx, source, instance, out):
        throttle, alt, climb, airspeed, groundspeed, heading = _vfr_hud_fields(m)
        v = _array((throttle * _PCT, alt, climb, airspeed, groundspeed, heading * _DEG), dtype=float)
        out.append(_new(_M, (t, _THROTTLE, v[0:1], source, t_rx, None, instance, 1)))
        out.append(_new(_M, (t, _ALTITUDE, v[1:2], source, t_rx, None, instance, 1)))
        out.append(_new(_M, (t, _CLIMB_RATE, v[2:3], source, t_rx, None, instance, 1)))
        out.append(_new(_M, (t, _AIRSPEED, v[3:6], source, t_rx, None, instance, 1)))

    def _sys_status(self, m, t, t_rx, source, instance, out):
        if source in self._battery_status_from:
            return  # the same battery monitor's reading, already taken from BATTERY_STATUS
        volts, current, remaining = _sys_battery(m)
        self._battery(volts, current, remaining, t, t_rx, source, 0, out)

    def _battery_status(self, m, t, t_rx, source, instance, out):
        battery, voltages, voltages_ext, current, remaining = _battery_status_fields(m)
        if battery == 0:
            self._battery_status_from.add(source)
        cells = [v for v in voltages if v != _UINT16_MAX]
        cells += [v for v in (voltages_ext or ()) if v not in (0, _UINT16_MAX)]
        volts = sum(cells) if cells else _UINT16_MAX
        self._battery(volts, current, remaining, t, t_rx, source, battery, out)

    def _battery(self, mv, ca, pct, t, t_rx, source, instance, out):
        if mv not in (_UINT16_MAX, 0):
            out.append(_new(_M, (t, _BATTERY_VOLTAGE, _array([mv * _MV]), source, t_rx, None, instance, 1)))
        else:
            self.skipped["battery_voltage_unknown"] += 1
        if ca != -1:
            out.append(_new(_M, (t, _BATTERY_CURRENT, _array([ca * _CA]), source, t_rx, None, instance, 1)))
        if pct != -1:
            out.append(_new(_M, (t, _BATTERY_REMAINING, _array([pct * _PCT]), source, t_rx, None, instance, 1)))

    def _servo_output_raw(self, m, t, t_rx, source, instance, out):
        raw = list(_servo_values(m))
        while len(raw) > 8 and raw[-1] == 0:  # MAVLink 2 extension channels 9-16 unused
            raw.pop()
        v = _array([(x - 1000.0) * 1e-3 if x else _nan for x in raw])
        out.append(_new(_M, (t, _ACTUATOR, v, source, t_rx, None, _servo_port(m), 1)))

    def _rc_channels(self, m, t, t_rx, source, instance, out):
        n = min(_rc_count(m) or 18, 18)  # a count past the 18 fields the message has is damage
        raw = _rc_values(m)[:n]
        v = _array([(x - 1000.0) * 1e-3 if x != _UINT16_MAX else _nan for x in raw], dtype=float)
        out.append(_new(_M, (t, _RC_INPUT, v, source, t_rx, None, instance, 1)))

    def _manual_control(self, m, t, t_rx, source, instance, out):
        # Normalised as MAVLink defines them: x, y, r in [-1000, 1000]; z in [0, 1000]
        # for ArduPilot and PX4 (some GCSs send [-1000, 1000]); passed on as sent / 1000.
        x, y, z, r, target = _manual(m)
        v = _array([x, y, z, r], dtype=float) * 1e-3
        out.append(_new(_M, (t, _MANUAL_CONTROL, v, source, t_rx, None, target, 1)))

    def _heartbeat(self, m, t, t_rx, source, instance, out):
        vehicle_type, base_mode, custom_mode, system_status, autopilot = _heartbeat_fields(m)
        if vehicle_type == mavlink.MAV_TYPE_GCS:
            # a ground station's (ours, recorded in a tlog): no vehicle status, and not a vehicle
            self.ground_stations.add(int(source.rsplit("/", 1)[1].split(".")[0]))
            return
        armed = 1.0 if base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED else 0.0
        v = _array([armed, custom_mode, system_status, vehicle_type, autopilot], dtype=float)
        out.append(_new(_M, (t, _VEHICLE_STATUS, v, source, t_rx, None, instance, 1)))

    def _attitude_quaternion(self, m, t, t_rx, source, instance, out):
        out.append(_new(_M, (t, _ATTITUDE_QUATERNION, _array(_quaternion(m)), source, t_rx, None, instance, 1)))

    def _att_pos_mocap(self, m, t, t_rx, source, instance, out):
        x, y, z, q = _mocap(m)
        out.append(_new(_M, (t, _TRUTH_POSE, _array([x, y, z, *q]), source, t_rx, None, instance, 1)))

    def _ekf_status_report(self, m, t, t_rx, source, instance, out):
        out.append(_new(_M, (t, _EKF_STATUS, _array(_ekf(m), dtype=float), source, t_rx, None, instance, 1)))


#: Every message type this decoder converts (the issue's list and a few more).
DECODED_TYPES = sorted(
    set(VECTORS) | set(SPECIAL_UNITS) | {"HEARTBEAT", "ATTITUDE_QUATERNION", "MANUAL_CONTROL", "EKF_STATUS_REPORT"}
)
