"""How each model's estimator is fed: which measurement kinds are its inputs, which set its
context (tilt, throttle, vehicle type), and the builders of the estimators themselves.

Every rule is ``rule(m, ctx)``: an *input rule* returns the model's input vector u (or None:
not this record), a *context rule* updates the filter's :class:`~.models.base.Context`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from drivers.logs.frame import MOTOR_OUTPUTS
from groundstation.core.frames import euler_from_quaternion
from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings
from groundstation.core.units import G

from .context import Context
from .estimator import KalmanEstimator
from .models.altitude import altitude_model
from .models.attitude_drag import attitude_drag_model
from .models.base import LinearModel
from .models.contact import in_contact
from .models.ground import landed
from .models.heli3dof import V_S0, heli3dof_model
from .models.horizontal import horizontal_model
from .models.quad_thrust import quad_thrust_model


# -- the altitude estimator's routing (coaxial document, chapter 9) ---------------------------
def set_tilt(ctx: Context, roll: float, pitch: float, yaw: float = 0.0) -> None:
    ctx.roll, ctx.pitch, ctx.yaw = roll, pitch, yaw
    # the rows of A_IB (coaxial doc. eq. 3.10): body -> world, kept with the
    # attitude (50 Hz) rather than recomputed per IMU sample (1 kHz)
    sf, cf, st, ct, sp, cp = (
        math.sin(roll),
        math.cos(roll),
        math.sin(pitch),
        math.cos(pitch),
        math.sin(yaw),
        math.cos(yaw),
    )
    ctx.north_row = (cp * ct, cp * sf * st - cf * sp, sf * sp + cf * cp * st)
    ctx.east_row = (ct * sp, cf * cp + sf * sp * st, cf * sp * st - cp * sf)
    ctx.down_row = (-st, ct * sf, cf * ct)


def read_attitude(m: Measurement, ctx: Context) -> None:
    set_tilt(ctx, float(m.value[0]), float(m.value[1]), float(m.value[2]) if len(m.value) > 2 else 0.0)
    ctx.attitude_t = m.t


def read_angular_rate(m: Measurement, ctx: Context) -> None:
    """The attitude message's body rates: the held attitude is carried forward with them
    (models.base.tilt_now; p, q are the Euler rates to first order in the tilt)."""
    ctx.roll_rate, ctx.pitch_rate = float(m.value[0]), float(m.value[1])


def read_quaternion(m: Measurement, ctx: Context) -> None:
    set_tilt(ctx, *euler_from_quaternion(*m.value))
    ctx.attitude_t = m.t


def read_specific_force(m: Measurement, ctx: Context) -> None:
    """The accelerometer's specific force along the world's up, -(A_IB f)_down (coaxial doc. eq.
    3.10's rows): what holds the body up, the ground or the rotors (``models.ground.landed``)."""
    if m.instance == 0:
        fx, fy, fz = m.value.tolist()
        a, b, c = ctx.down_row
        ctx.f_up = -(a * fx + b * fy + c * fz)


def read_throttle(m: Measurement, ctx: Context) -> None:
    """THROTTLE and ACTUATOR records alike: the log's one throttle source (:func:`collective`)."""
    tau = collective(m, ctx)
    if tau is not None:
        set_throttle(ctx, tau, m.t)


def set_throttle(ctx: Context, tau: float, t: float) -> None:
    """The throttle from ``t`` on; the one before stays as ``throttle_before`` for a reading at
    that same instant (:func:`throttle_at_reading`)."""
    if ctx.throttle_since != t:
        ctx.throttle_before = ctx.throttle
    ctx.throttle, ctx.throttle_since = tau, t


def throttle_at_reading(ctx: Context, t: float) -> float | None:
    """The throttle in effect when a sensor read at ``t``: written before ``t``. One written at
    that instant has not yet drawn its current: a simulated thrust test flight steps its throttle
    on the battery's 5 Hz grid, and a reading paired with the step's new throttle put up to
    1.6 V of error in the voltage carried forward (thrust_voltage's n = 1.5 read 1.85)."""
    since = ctx.throttle_since if ctx.throttle_since is not None else -math.inf
    return ctx.throttle_before if since >= t else ctx.throttle


def motor_outputs(ctx: Context) -> int:
    return ctx.motor_outputs


def motor_outputs_of(ms: Iterable[Measurement]) -> int:
    """How many of the first actuator outputs drive rotors, by the log's first vehicle status."""
    if isinstance(ms, Readings):
        ms = ms.only((Kind.VEHICLE_STATUS,))
    for m in ms:
        if m.kind is Kind.VEHICLE_STATUS:
            ctx = Context()
            read_vehicle_status(m, ctx)
            return motor_outputs(ctx)
    return Context.motor_outputs


def read_vehicle_status(m: Measurement, ctx: Context) -> None:
    """The vehicle's type (HEARTBEAT): which outputs are motors."""
    if len(m.value) > 3 and np.isfinite(m.value[3]):
        ctx.motor_outputs = MOTOR_OUTPUTS.get(int(m.value[3]), 4)


def collective(m: Measurement, ctx: Context) -> float | None:
    """The collective throttle 0..1 of a THROTTLE or ACTUATOR record, from one source per log: the
    motor outputs (their mean) once the log has shown them, else THROTTLE. None: not this record.

    An autopilot's THROTTLE (VFR_HUD) is an integer percent, at a fifth of the outputs' rate, and on
    the autopilot's own scale (ArduPilot's is not the PWM's (us - 1000) / 1000). Taken from both, a
    simulated quad's thrust model flew a 1 %-quantised throttle for 20 ms of every 100 (up to
    0.1 m/s^2 of thrust at alpha = 22), and an actuator lag was fitted over both streams."""
    if m.kind is Kind.ACTUATOR:
        # the motors' outputs, then the unused among them (not servos' in their place); in plain
        # floats: a handful of numbers, read at the outputs' full rate
        v = [x for x in m.value[: motor_outputs(ctx)].tolist() if math.isfinite(x)]
        if not v:
            return None
        ctx.throttle_from_outputs = True
        return sum(v) / len(v)
    if ctx.throttle_from_outputs or not len(m.value) or not math.isfinite(m.value[0]):
        return None
    return float(m.value[0])


def vertical_acceleration(m: Measurement, ctx: Context) -> np.ndarray | None:
    """(gamma_z, cos_tilt): gamma_z = -(A_IB f)_down - g, the world-vertical specific force with
    gravity removed, and cos_tilt = (A_IB)_down,z = cos(roll) cos(pitch), how much of the body's
    z axis (and of a bias along it) is vertical."""
    if m.instance != 0:
        return None
    read_specific_force(m, ctx)  # f_up, which models.ground.landed reads too: computed once
    assert ctx.f_up is not None
    return np.array([ctx.f_up - G, ctx.down_row[2]])


def altitude_estimator(model: LinearModel | None = None, *, still_noise: bool = False) -> KalmanEstimator:
    """``still_noise``: the baro's noise from the still stretch before the first take-off
    (:mod:`.still_noise`; the live estimators', not a diagnosis's, which matches its own)."""
    return KalmanEstimator(
        model or altitude_model(),
        inputs={Kind.ACCEL: vertical_acceleration},
        context={
            Kind.ATTITUDE: read_attitude,
            Kind.ATTITUDE_QUATERNION: read_quaternion,
            Kind.ANGULAR_RATE: read_angular_rate,
            Kind.THROTTLE: read_throttle,
            Kind.ACTUATOR: read_throttle,
            Kind.VEHICLE_STATUS: read_vehicle_status,
        },
        still_noise=still_noise,
    )


# -- the multirotor attitude (gyro input, accelerometer updates: models.attitude_drag) ----------
#: a vertical velocity older than this is not used (the stream stopped: no GPS fix, a gap in the log)
VD_MAX_AGE = 0.5


def gyro_rates(m: Measurement, ctx: Context) -> np.ndarray | None:
    """u = (p_m, q_m, r_m, v_d): the gyro as measured, body FRD, and the latest vertical velocity
    (NED down; NaN if none within :data:`VD_MAX_AGE`: the model then leaves its terms out)."""
    if m.instance != 0:
        return None
    vd = ctx.v_d if m.t - ctx.v_d_t <= VD_MAX_AGE else math.nan
    return np.array([float(m.value[0]), float(m.value[1]), float(m.value[2]), vd])


def read_vertical_velocity(m: Measurement, ctx: Context) -> None:
    """v_d from VELOCITY_NED (down) or CLIMB_RATE (up)."""
    vd = float(m.value[2]) if m.kind is Kind.VELOCITY_NED else -float(m.value[0])
    if math.isfinite(vd):  # a GNSS board's VELOCITY_NED has no vertical component
        ctx.v_d, ctx.v_d_t = vd, m.t


def attitude_estimator(model: LinearModel | None = None) -> KalmanEstimator:
    return KalmanEstimator(
        model or attitude_drag_model(),
        inputs={Kind.GYRO: gyro_rates},
        context={
            Kind.THROTTLE: read_throttle,
            Kind.ACTUATOR: read_throttle,
            Kind.VEHICLE_STATUS: read_vehicle_status,
            Kind.VELOCITY_NED: read_vertical_velocity,
            Kind.CLIMB_RATE: read_vertical_velocity,
        },
    )


# -- horizontal position (IMU input, GPS updates) -------------------------------------------------
def horizontal_acceleration(m: Measurement, ctx: Context) -> np.ndarray | None:
    """(a_n, a_e) = rows 1 and 2 of A_IB f (gravity has no horizontal component)."""
    if m.instance != 0:
        return None
    f = m.value.tolist()
    rn, re_ = ctx.north_row, ctx.east_row
    return np.array([rn[0] * f[0] + rn[1] * f[1] + rn[2] * f[2], re_[0] * f[0] + re_[1] * f[1] + re_[2] * f[2]])


def horizontal_estimator(model: LinearModel | None = None) -> KalmanEstimator:
    return KalmanEstimator(
        model or horizontal_model(),
        inputs={Kind.ACCEL: horizontal_acceleration},
        context={Kind.ATTITUDE: read_attitude, Kind.ATTITUDE_QUATERNION: read_quaternion},
    )


# -- the quadcopter thrust-model estimator's routing (quadcopter document) ---------------------
def thrust_input(m: Measurement, ctx: Context) -> np.ndarray | None:
    """u = (tau c, c, g): throttle times tilt, tilt, gravity (see models.quad_thrust);
    all zero on the ground, where the document's model does not apply (landed: below ground idle)."""
    tau = ctx.tau
    if landed(ctx):
        return np.zeros(3)
    c = ctx.down_row[2]
    return np.array([tau * c, c, G])


def thrust_input_on_ground(m: Measurement, ctx: Context) -> np.ndarray | None:
    """:func:`thrust_input`, zero also in contact with the ground with the rotors turning
    (:mod:`.models.contact`, whose resets and range readings the model then has)."""
    x = ctx.x
    lifts = x is not None and (float(x[2]) * ctx.tau + float(x[3])) * ctx.down_row[2] > G
    if in_contact(ctx, m.t, float(x[0]) if x is not None else 0.0, lifts, known=x is not None):
        return np.zeros(3)
    return thrust_input(m, ctx)


#: what the thrust model reads beside its inputs: the attitude (the thrust's vertical share), the
#: throttle and whether the vehicle is armed (the diagnosis's thrust filter adds its own)
THRUST_CONTEXT = {
    Kind.ATTITUDE: read_attitude,
    Kind.ATTITUDE_QUATERNION: read_quaternion,
    Kind.ANGULAR_RATE: read_angular_rate,
    Kind.ACTUATOR: read_throttle,
    Kind.THROTTLE: read_throttle,
    Kind.VEHICLE_STATUS: read_vehicle_status,
}


def quad_thrust_estimator(model: LinearModel | None = None, *, still_noise: bool = False) -> KalmanEstimator:
    """``still_noise``: as :func:`altitude_estimator`'s."""
    model = model or quad_thrust_model()
    inp = thrust_input_on_ground if model.options.get("ground_contact") else thrust_input
    return KalmanEstimator(
        model,
        inputs={Kind.ACTUATOR: inp, Kind.THROTTLE: inp, Kind.ATTITUDE: inp},
        context=dict(THRUST_CONTEXT),
        still_noise=still_noise,
    )


# -- the 3-DOF helicopter's routing (lab document) ---------------------------------------------
V_MAX_3DOF = 12.0  # the simulated rig's motor voltage range (its outputs are V / V_max)


def motor_voltages(m: Measurement, ctx: Context) -> np.ndarray | None:
    """u = (V_f + V_b - V_s0, V_b - V_f) from the motor outputs."""
    if m.kind is Kind.MOTOR_VOLTAGE:
        vf, vb = float(m.value[0]), float(m.value[1])
    else:  # ACTUATOR: normalised outputs
        vf, vb = float(m.value[0]) * V_MAX_3DOF, float(m.value[1]) * V_MAX_3DOF
    return np.array([vf + vb - V_S0, vb - vf])


def estimate_for_accel(m: Measurement, ctx: Context) -> None:
    """The arm's own acceleration (removed before the gravity direction is read) needs
    the angles, the rates and the input."""
    x, u = ctx.x, ctx.u
    if x is not None:
        ctx.p_hat, ctx.p_dot_hat, ctx.e_hat, ctx.e_dot_hat, ctx.lambda_dot_hat = (
            float(x[0]),
            float(x[1]),
            float(x[2]),
            float(x[3]),
            float(x[5]),
        )
        ctx.u_s = float(u[0]) if u is not None and len(u) else 0.0
        ctx.u_d = float(u[1]) if u is not None and len(u) > 1 else 0.0


def estimate_for_gyro(m: Measurement, ctx: Context) -> None:
    """The gyro's Euler-rate transform needs the current pitch and elevation."""
    x = ctx.x
    if x is not None:
        ctx.p_hat, ctx.e_hat = float(x[0]), float(x[2])


def heli3dof_estimator(model: LinearModel | None = None) -> KalmanEstimator:
    est = KalmanEstimator(
        model or heli3dof_model(),
        inputs={Kind.ACTUATOR: motor_voltages, Kind.MOTOR_VOLTAGE: motor_voltages},
        context={Kind.GYRO: estimate_for_gyro, Kind.ACCEL: estimate_for_accel},
    )
    est.filter.ctx.x = est.filter.kf.x
    return est
