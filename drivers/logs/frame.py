"""The airframe a log states, as the MAV_TYPE its vehicle's HEARTBEAT would send: which of the
motor outputs drive rotors.

A tlog carries the HEARTBEAT; an ArduPilot DataFlash log states the frame in its parameters
(``FRAME_CLASS``, Copter 3.5 on) and in the line Copter logs at boot (``Frame: HEXA/X``); a PX4
ULog in ``vehicle_status.system_type``. Read as four outputs, a hexacopter's collective is the mean
of four of its six motors, and an octocopter's of four of eight (ArduCopter's octa X puts motors 3
and 4 at 67.5 and 157.5 degrees: their mean moves with every roll and pitch command).

Only the frames whose motor *n* is on output *n* are named here (ArduCopter's ``AP_MotorsMatrix``
classes). A helicopter's, a single or coaxial copter's (fins on outputs 1-4, the rotors on 5 and 6)
and a tricopter's (its motors on 1, 2 and 4, the tail servo on 7) are left unnamed: their outputs
are not the first motors, and a count would mix servos into the collective.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from groundstation.core.measurement import Kind, Measurement

from .tables import LogTables

#: MAV_TYPE -> how many of the first outputs drive rotors (the rest are servos: a
#: coaxial helicopter's swash plate); SERVO_OUTPUT_RAW does not say which is which.
MOTOR_OUTPUTS = {
    mavlink.MAV_TYPE_QUADROTOR: 4,
    mavlink.MAV_TYPE_COAXIAL: 2,
    mavlink.MAV_TYPE_HELICOPTER: 1,
    mavlink.MAV_TYPE_HEXAROTOR: 6,
    mavlink.MAV_TYPE_OCTOROTOR: 8,
    mavlink.MAV_TYPE_TRICOPTER: 3,
    mavlink.MAV_TYPE_DECAROTOR: 10,
    mavlink.MAV_TYPE_DODECAROTOR: 12,
}


#: ArduCopter ``FRAME_CLASS`` -> MAV_TYPE (Copter's ``get_frame_mav_type``): 1 quad, 2 hexa, 3 octa,
#: 4 octaquad, 5 Y6, 12 dodecahexa, 14 deca
MAV_TYPE_OF_FRAME_CLASS = {
    1: mavlink.MAV_TYPE_QUADROTOR,
    2: mavlink.MAV_TYPE_HEXAROTOR,
    3: mavlink.MAV_TYPE_OCTOROTOR,
    4: mavlink.MAV_TYPE_OCTOROTOR,
    5: mavlink.MAV_TYPE_HEXAROTOR,
    12: mavlink.MAV_TYPE_DODECAROTOR,
    14: mavlink.MAV_TYPE_DECAROTOR,
}

#: the frame's name in Copter's boot line ``Frame: NAME/TYPE`` -> MAV_TYPE
MAV_TYPE_OF_FRAME_NAME = {
    "QUAD": mavlink.MAV_TYPE_QUADROTOR,
    "HEXA": mavlink.MAV_TYPE_HEXAROTOR,
    "OCTA": mavlink.MAV_TYPE_OCTOROTOR,
    "OCTAQUAD": mavlink.MAV_TYPE_OCTOROTOR,
    "Y6": mavlink.MAV_TYPE_HEXAROTOR,
    "DODECA_HEXA": mavlink.MAV_TYPE_DODECAROTOR,
    "DECA": mavlink.MAV_TYPE_DECAROTOR,
}


def mav_type_of_params(params: dict[str, float]) -> int | None:
    """The MAV_TYPE an ArduCopter log's ``FRAME_CLASS`` names; None where it names none of the
    matrix frames (or the log has no such parameter)."""
    fc = params.get("FRAME_CLASS")
    try:
        return MAV_TYPE_OF_FRAME_CLASS.get(int(fc)) if fc is not None else None
    except (ValueError, OverflowError):  # NaN or infinite: no frame stated
        return None


def mav_type_of_text(text: str) -> int | None:
    """The MAV_TYPE of Copter's boot line ``Frame: HEXA/X`` (None for any other line)."""
    text = text.strip()
    if not text.upper().startswith("FRAME:"):
        return None
    name = text[len("Frame:") :].strip().split("/")[0].strip().upper()
    return MAV_TYPE_OF_FRAME_NAME.get(name)


#: a multirotor's rotor count -> the MAV_TYPE that names it
MAV_TYPE_OF_ROTORS = {
    3: mavlink.MAV_TYPE_TRICOPTER,
    4: mavlink.MAV_TYPE_QUADROTOR,
    6: mavlink.MAV_TYPE_HEXAROTOR,
    8: mavlink.MAV_TYPE_OCTOROTOR,
    10: mavlink.MAV_TYPE_DECAROTOR,
    12: mavlink.MAV_TYPE_DODECAROTOR,
}

#: PX4's output functions ``PWM_MAIN_FUNCn`` = 101..112: Motor 1..12 (control allocation, v1.13 on)
PX4_MOTOR_FUNCTIONS = range(101, 113)


def px4_motor_columns(params: dict[str, float]) -> list[int] | None:
    """Which of ``actuator_outputs``' columns drive motors, in the motors' order, by the outputs'
    functions (``PWM_MAIN_FUNCn``); None where the log does not say (before control allocation:
    the mixer put the motors first)."""
    motor_of_column: dict[int, int] = {}
    for n in range(1, 17):
        f = params.get(f"PWM_MAIN_FUNC{n}")
        if f is not None and f in PX4_MOTOR_FUNCTIONS:
            motor_of_column[n - 1] = int(f)
    return sorted(motor_of_column, key=motor_of_column.__getitem__) or None


#: PX4's DShot driver's output values (``DShot.h``): 0 disarmed, 1 .. 1999 the throttle range
DSHOT_DISARMED, DSHOT_MIN_THROTTLE, DSHOT_MAX_THROTTLE = 0, 1, 1999
#: ``PWM_MAIN_TIMn``'s protocols that are DShot (PX4 1.14 on): -5 DShot150, -4 300, -3 600, -2 1200
PX4_DSHOT_TIMER_PROTOCOLS = (-5, -4, -3, -2)


def px4_dshot_outputs(params: dict[str, float]) -> bool:
    """Whether a PX4 log's main outputs drive DShot ESCs, by its parameters: the first timer's
    protocol (``PWM_MAIN_TIM0``, whose group holds output 1, where motor 1 is on every airframe) from
    v1.14 on, ``DSHOT_CONFIG`` before (on the FMU's outputs: the main ones on a board without an IO
    co-processor, ``SYS_USE_IO`` 0). Their ``actuator_outputs`` are then DShot values, 0 to 1999,
    not pulse widths in microseconds (:func:`px4_output_fraction`)."""
    tim = params.get("PWM_MAIN_TIM0")
    if tim is not None and math.isfinite(tim):
        return int(tim) in PX4_DSHOT_TIMER_PROTOCOLS
    config = params.get("DSHOT_CONFIG")
    on_fmu = params.get("SYS_USE_IO", 0.0) == 0.0
    return config is not None and math.isfinite(config) and config > 0 and on_fmu


def px4_output_fraction(values: np.ndarray, dshot: bool) -> np.ndarray:
    """``actuator_outputs``' values as the fraction of the ESC's full range ``Kind.ACTUATOR`` holds:
    a pulse (us - 1000) / 1000 (0 us: an output not driven, NaN), a DShot value over 1999 (0: the
    motor stopped, disarmed). The two read alike: 0 the motor stopped, 1 full throttle, the armed
    idle the autopilot's minimum (``PWM_MAIN_MINn``, ``DSHOT_MIN``)."""
    if dshot:
        return np.clip(values, DSHOT_DISARMED, DSHOT_MAX_THROTTLE) / DSHOT_MAX_THROTTLE
    return np.where(values > 0, (values - 1000.0) / 1000.0, math.nan)


def px4_dshot_idle(params: dict[str, float]) -> float:
    """The armed idle of PX4's DShot outputs as :func:`px4_output_fraction` reads it: ``DSHOT_MIN``
    (0.055 by default) of the throttle range, and at least its first value (``DShot::update_params``)."""
    share = params.get("DSHOT_MIN")
    share = share if share is not None and math.isfinite(share) and 0.0 <= share <= 1.0 else 0.055
    lowest = min(max(int(share * DSHOT_MAX_THROTTLE), DSHOT_MIN_THROTTLE), DSHOT_MAX_THROTTLE)
    return lowest / DSHOT_MAX_THROTTLE


def px4_mav_type(params: dict[str, float], system_type: float | None) -> int | None:
    """The MAV_TYPE of a PX4 vehicle's rotors: control allocation's own count (``CA_ROTOR_COUNT``)
    where the log has it, else the type ``vehicle_status`` (or ``MAV_TYPE``) announces, where it
    is a multirotor's."""
    rotors = params.get("CA_ROTOR_COUNT")
    if rotors is not None and rotors in MAV_TYPE_OF_ROTORS:
        return MAV_TYPE_OF_ROTORS[int(rotors)]
    said = system_type if system_type is not None else params.get("MAV_TYPE")
    if said is not None and said in MAV_TYPE_OF_ROTORS.values():
        return int(said)
    return None


def px4_logs_mav_type(tables: LogTables) -> int | None:
    """:func:`px4_mav_type` of a ULog's parameters and its first ``vehicle_status``."""
    vs = tables.get("vehicle_status")
    said = vs.numeric("system_type") if vs is not None else None
    return px4_mav_type(tables.params, float(said[0]) if said is not None and len(said) else None)


def frame_status(t: float, mav_type: int, autopilot: int, source: str) -> Measurement:
    """The frame a log states as the VEHICLE_STATUS a tlog's HEARTBEAT gives (its MAV_TYPE; armed, mode
    and state not said), at time ``t``: the log's first sample, so that every output is read by it."""
    status = np.array([math.nan, math.nan, math.nan, float(mav_type), float(autopilot)])
    return Measurement(t, Kind.VEHICLE_STATUS, status, source, t)
