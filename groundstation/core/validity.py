"""Whether a reading can be believed at all: finite, and within what the sensor can physically read.

A reading that fails is rejected by whoever would use it (the estimators, the controllers'
feedback) and counted under ``<kind>_not_finite`` or ``<kind>_implausible``; it never reaches a
filter. The ranges are wide on purpose: they catch a damaged frame or a driver's unit error, not a
hard manoeuvre (an IMU's full scale is 16 g and 2000 deg/s; these allow more).
"""

from __future__ import annotations

import math

from .measurement import Kind, Measurement

#: kinds whose NaN components mean "absent" (an unused output channel, a GNSS velocity without its
#: vertical component, a field the autopilot did not fill); an infinity is still damage
NAN_MEANS_ABSENT = frozenset(
    {
        Kind.ACTUATOR,
        Kind.RC_INPUT,
        Kind.VELOCITY_NED,
        Kind.VEHICLE_STATUS,
        Kind.EKF_STATUS,
        Kind.AIRSPEED,
        Kind.GLOBAL_POSITION,
        Kind.MANUAL_CONTROL,
        Kind.BATTERY_CURRENT,
        Kind.BATTERY_REMAINING,
    }
)

#: per kind, the bound on every component's absolute value (a vector's components alike)
ABS_LIMIT: dict[Kind, float] = {
    Kind.ACCEL: 50 * 9.80665,  # m/s^2
    Kind.GYRO: 50.0,  # rad/s
    Kind.ANGULAR_RATE: 50.0,
    Kind.MAG: 1e-2,  # T (the Earth's field is 5e-5)
    Kind.BARO_ALTITUDE: 2e4,  # m
    Kind.ALTITUDE: 2e4,
    Kind.CLIMB_RATE: 200.0,  # m/s
    Kind.VELOCITY_NED: 500.0,
    Kind.GPS_VD: 200.0,  # m/s
    Kind.POSITION_NED: 1e6,  # m
    Kind.ATTITUDE: 2 * math.pi,  # rad (yaw may be reported in 0..2 pi)
    Kind.ATTITUDE_QUATERNION: 1.5,
    Kind.ENCODERS: 100.0,  # rad
    Kind.MOTOR_VOLTAGE: 100.0,  # V
    Kind.THROTTLE: 2.0,
    Kind.ACTUATOR: 2.0,  # normalised PWM (us - 1000) / 1000
}

#: per kind, the range of its first component
RANGE_LIMIT: dict[Kind, tuple[float, float]] = {
    Kind.BARO_PRESSURE: (1e3, 2e5),  # Pa: 1 kPa is above 30 km
    Kind.DIFF_PRESSURE: (-1e5, 1e5),
    Kind.TEMPERATURE: (150.0, 450.0),  # K
    Kind.RANGE: (-1.0, 1e3),  # m (a small negative reading: a calibrated offset)
    Kind.BATTERY_VOLTAGE: (0.0, 200.0),  # V
    Kind.GPS: (-90.0, 90.0),  # latitude [deg]
}


def reading_problem(m: Measurement) -> str | None:
    """``"not_finite"``, ``"implausible"``, or None for a reading that can be used. Pure Python over
    the few components a reading has: this runs on every reading, at 1 kHz per IMU."""
    if not math.isfinite(m.t):
        return "not_finite"
    v = m.value.tolist()
    if not v:
        return None
    if math.isfinite(sum(v)):  # every component finite (a NaN or an infinity carries into the sum)
        present = v
    else:
        absent_ok = m.kind in NAN_MEANS_ABSENT
        present = []
        for x in v:
            if x != x:
                if not absent_ok:
                    return "not_finite"
            elif x in (math.inf, -math.inf):
                return "not_finite"
            else:
                present.append(x)
        if not present:
            return "not_finite"
    limit = ABS_LIMIT.get(m.kind)
    if limit is not None and max(abs(x) for x in present) > limit:
        return "implausible"
    bounds = RANGE_LIMIT.get(m.kind)
    if bounds is not None and v[0] == v[0] and not bounds[0] <= v[0] <= bounds[1]:
        return "implausible"
    if m.kind is Kind.GPS and len(v) > 1 and not -180.0 <= v[1] <= 360.0:
        return "implausible"
    if m.kind is Kind.ATTITUDE_QUATERNION and not 0.25 <= sum(x * x for x in v) <= 2.25:
        return "implausible"
    return None
