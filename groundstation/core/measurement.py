"""The one record every source produces: a :class:`Measurement`.

Drivers (live MAVLink links, serial boards, log readers, the simulator) convert
their data into these records once, at the driver, so that everything after
them sees SI units, MAVLink frames and vehicle time.

Conventions
-----------
* ``t``: vehicle time in float seconds (the vehicle's own clock, from the
  message's ``time_usec``/``time_boot_ms`` where it has one, otherwise the
  link's aligned clock; see :mod:`drivers.mavlink.clock`). ``nan`` while the
  vehicle clock is still unknown.
* ``t_rx``: receive time, float seconds of the ground station's wall clock
  (for a replay: the recording's timestamp).
* Frames: world NED, body FRD (as MAVLink). Exceptions are named in the kind's
  description (``ALTITUDE`` and ``CLIMB_RATE`` are positive up, as MAVLink's
  VFR_HUD and DataFlash logs give them).
* ``value``: a float64 numpy vector laid out as :data:`KIND_COMPONENTS` says.
* ``variance``: per-component variance in the value's units squared, or None.
* ``instance``: which of several like sensors (IMU 0/1/2, baro 0/1/2,
  distance sensor id, battery id).
"""

from __future__ import annotations

import enum
import re
from typing import NamedTuple

import numpy as np


class Kind(enum.Enum):
    """What a measurement measures. The vector layout is in :data:`KIND_COMPONENTS`."""

    ACCEL = "accel"  # specific force, body FRD [m/s^2]
    GYRO = "gyro"  # angular rate, body FRD [rad/s]
    MAG = "mag"  # magnetic flux density, body FRD [T]
    BARO_PRESSURE = "baro_pressure"  # static pressure [Pa]
    BARO_ALTITUDE = "baro_altitude"  # pressure altitude, positive up [m]
    DIFF_PRESSURE = "diff_pressure"  # differential (airspeed) pressure [Pa]
    TEMPERATURE = "temperature"  # sensor temperature [K]
    RANGE = "range"  # distance along the sensor axis [m]
    ATTITUDE = "attitude"  # roll, pitch, yaw of FRD w.r.t. NED [rad]
    ATTITUDE_QUATERNION = "attitude_quaternion"  # w, x, y, z (FRD w.r.t. NED)
    ANGULAR_RATE = "angular_rate"  # estimated body rates FRD [rad/s]
    GPS = "gps"  # lat [deg], lon [deg], alt AMSL up [m]
    GLOBAL_POSITION = "global_position"  # lat [deg], lon [deg], alt AMSL [m], height above home [m]
    POSITION_NED = "position_ned"  # local position NED [m]
    VELOCITY_NED = "velocity_ned"  # velocity NED [m/s]
    GPS_VD = "gps_vd"  # a GNSS receiver's own vertical velocity, down [m/s] (its fix's, not a filter's)
    ALTITUDE = "altitude"  # autopilot altitude estimate, positive up [m]
    CLIMB_RATE = "climb_rate"  # vertical speed, positive up [m/s]
    AIRSPEED = "airspeed"  # airspeed, groundspeed [m/s], heading [rad]
    THROTTLE = "throttle"  # collective throttle [0..1]
    ACTUATOR = "actuator"  # actuator outputs, PWM normalised (us-1000)/1000
    RC_INPUT = "rc_input"  # RC channels, PWM normalised (us-1000)/1000
    MANUAL_CONTROL = "manual_control"  # x, y, r in [-1, 1]; z (thrust) in [0, 1] as sent
    BATTERY_VOLTAGE = "battery_voltage"  # pack voltage [V]
    BATTERY_CURRENT = "battery_current"  # pack current, positive discharging [A]
    BATTERY_REMAINING = "battery_remaining"  # state of charge [0..1]
    VEHICLE_STATUS = "vehicle_status"  # armed, custom_mode, system_status, mav_type, autopilot
    EKF_STATUS = "ekf_status"  # flags, velocity/pos-h/pos-v/compass/terrain variance ratios
    ENCODERS = "encoders"  # joint angles [rad] (3-DOF helicopter: p, e, lambda)
    MOTOR_VOLTAGE = "motor_voltage"  # motor voltages [V] (3-DOF helicopter: V_f, V_b)
    TRUTH_POSE = "truth_pose"  # motion capture / simulator truth: x, y, z NED [m], qw, qx, qy, qz

    # members are singletons: hashed by identity, in C (Enum hashes the name in Python, and every
    # reading costs several dict lookups by kind)
    __hash__ = object.__hash__

    @property
    def is_truth(self) -> bool:
        """Truth is shown and scored against, never fed to an estimator."""
        return self is Kind.TRUTH_POSE


#: Names of the value vector's components for each kind (used for export
#: columns and the dashboard's labels). Variable-length kinds list ``None``.
KIND_COMPONENTS: dict[Kind, tuple[str, ...] | None] = {
    Kind.ACCEL: ("x", "y", "z"),
    Kind.GYRO: ("x", "y", "z"),
    Kind.MAG: ("x", "y", "z"),
    Kind.BARO_PRESSURE: ("p",),
    Kind.BARO_ALTITUDE: ("h",),
    Kind.DIFF_PRESSURE: ("dp",),
    Kind.TEMPERATURE: ("T",),
    Kind.RANGE: ("d",),
    Kind.ATTITUDE: ("roll", "pitch", "yaw"),
    Kind.ATTITUDE_QUATERNION: ("w", "x", "y", "z"),
    Kind.ANGULAR_RATE: ("p", "q", "r"),
    Kind.GPS: ("lat", "lon", "alt"),
    Kind.GLOBAL_POSITION: ("lat", "lon", "alt", "relative_alt"),
    Kind.POSITION_NED: ("n", "e", "d"),
    Kind.VELOCITY_NED: ("vn", "ve", "vd"),
    Kind.GPS_VD: ("vd",),
    Kind.ALTITUDE: ("h",),
    Kind.CLIMB_RATE: ("climb",),
    Kind.AIRSPEED: ("airspeed", "groundspeed", "heading"),
    Kind.THROTTLE: ("throttle",),
    Kind.ACTUATOR: None,
    Kind.RC_INPUT: None,
    Kind.MANUAL_CONTROL: ("x", "y", "z", "r"),
    Kind.BATTERY_VOLTAGE: ("V",),
    Kind.BATTERY_CURRENT: ("I",),
    Kind.BATTERY_REMAINING: ("soc",),
    Kind.VEHICLE_STATUS: ("armed", "custom_mode", "system_status", "mav_type", "autopilot"),
    Kind.EKF_STATUS: ("flags", "velocity", "pos_horiz", "pos_vert", "compass", "terrain_alt"),
    Kind.ENCODERS: ("p", "e", "lambda"),
    Kind.MOTOR_VOLTAGE: ("V_f", "V_b"),
    Kind.TRUTH_POSE: ("n", "e", "d", "qw", "qx", "qy", "qz"),
}


class Measurement(NamedTuple):
    """One measurement in SI units (see the module docstring for conventions).

    A NamedTuple rather than a dataclass: it is immutable, typed, and the
    cheapest record Python can build, which matters at 1 kHz per sensor.
    """

    t: float
    kind: Kind
    value: np.ndarray
    source: str
    t_rx: float = float("nan")
    variance: np.ndarray | None = None
    instance: int = 0
    #: how many raw samples the value averages (a diagnosis's IMU block mean); 1 as sent
    samples: int = 1

    def describe(self) -> str:
        names = KIND_COMPONENTS.get(self.kind) or tuple(str(i) for i in range(len(self.value)))
        parts = ", ".join(f"{n}={v:.6g}" for n, v in zip(names, self.value))
        return f"t={self.t:.6f} {self.kind.value}[{self.instance}] {parts} ({self.source})"


_MAVLINK_SOURCE = re.compile(r"/(\d+)\.(\d+)$")


def source_system(source: str) -> int | None:
    """The MAVLink system id a measurement's source names (``mav/2.1``: system 2, component 1, as
    the MAVLink decoder names them); None for a source of no system (a sensor board, a log)."""
    m = _MAVLINK_SOURCE.search(source)
    return int(m.group(1)) if m else None
