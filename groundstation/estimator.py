"""An estimator: a :class:`~groundstation.filters.ModelFilter` plus the rules that
route measurements to it (which kinds are inputs, which feed the context,
which are measurement updates), and the handling of time: prediction through
dropouts, re-initialisation on clock jumps.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from .filters import InnovationRecord, ModelFilter
from .measurement import Kind, Measurement
from .models.contact import in_contact
from .models.base import Context, LinearModel

G = 9.80665

InputRule = Callable[[Measurement, Context], "np.ndarray | None"]
ContextRule = Callable[[Measurement, Context], None]


@dataclass
class EstimatorCounters:
    updates: int = 0
    predictions: int = 0
    reinitialisations: int = 0
    skipped: dict = field(default_factory=dict)

    def skip(self, why: str) -> None:
        self.skipped[why] = self.skipped.get(why, 0) + 1

    @property
    def rejected(self) -> dict[str, int]:
        """The skips of data: not finite, out of order, invalid, or refused by a model with its reason
        (``range_on_ground``, ``range_out_of_bounds``). Not ``*_not_used``: a barometer's calibration
        readings, a pseudo-sensor's constraint that did not apply (``landed`` in flight)."""
        return {k: n for k, n in self.skipped.items() if not k.endswith("_not_used")}


class KalmanEstimator:
    """``handle(m)`` -> the innovation record when ``m`` was a measurement update.

    Clock jumps: a measurement more than ``jump_back`` seconds before the
    filter's time (a reboot, a replay seek) or more than ``max_gap`` after it
    re-initialises the filter at the new time, cleanly and counted. Shorter
    gaps are predicted through (the covariance grows, as it should).
    """

    def __init__(self, model: LinearModel, *, inputs: dict[Kind, InputRule], context: dict[Kind, ContextRule],
                 name: str | None = None, jump_back: float = 0.5, max_gap: float = 5.0) -> None:
        self.name = name or model.name
        self.model = model
        self.filter = ModelFilter(model)
        self.inputs = inputs
        self.context = context
        self.jump_back = jump_back
        self.max_gap = max_gap
        self.counters = EstimatorCounters()
        self.started = False
        self._by_kind: dict[Kind, list] = {}
        for mm in model.measurements.values():
            self._by_kind.setdefault(mm.kind, []).append(mm)
        # kinds that only carry constraints on the state as it is (MeasurementModel.untimed): they
        # leave the filter's clock alone, unless the kind is an input as well
        self._untimed = {k for k, mms in self._by_kind.items() if k not in inputs and all(mm.untimed for mm in mms)}

    @property
    def kinds(self) -> set[Kind]:
        return set(self.inputs) | set(self.context) | set(self._by_kind)

    def checkpoint(self) -> tuple:
        """Everything a rollback needs, before the first measurement too (a late one there was
        dropped: the outputs stamped just before the attitude that started the filter)."""
        return self.started, self.filter.checkpoint()

    def restore(self, cp: tuple) -> None:
        self.started, f = cp
        self.filter.restore(f)

    @property
    def t(self) -> float:
        return self.filter.t

    def _time(self, t: float) -> bool:
        f = self.filter
        if not self.started:
            f.reset(t)
            self.started = True
            return True
        if t < f.t - self.jump_back or t > f.t + self.max_gap:
            self.counters.reinitialisations += 1
            refs = {k: v for k, v in f.ctx.values.items() if not k.endswith("_ref")}
            f.reset(t)
            f.ctx.values.update(refs)
            return True
        return t >= f.t - 1e-9

    def handle(self, m: Measurement) -> InnovationRecord | None:
        v0 = m.value[0] if len(m.value) else math.nan
        if m.t != m.t or not math.isfinite(v0):
            self.counters.skip("not_finite")
            return None
        f = self.filter
        f.ctx.values["t"] = m.t
        rule = self.context.get(m.kind)
        if rule is not None:
            f.ctx.values["_x"] = f.kf.x
            f.ctx.values["_u"] = f.u
            rule(m, f.ctx)
        inp = self.inputs.get(m.kind)
        mms = self._by_kind.get(m.kind)
        if inp is None and not mms:
            return None
        if m.kind in self._untimed:
            return self._update(m, mms) if self.started else None
        if not self._time(m.t):
            self.counters.skip("out_of_order")
            return None
        f.predict_to(m.t)
        self.counters.predictions += 1
        if inp is not None:
            u = inp(m, f.ctx)
            if u is not None:
                f.u = u
        return self._update(m, mms or ())

    def _update(self, m: Measurement, mms: list) -> InnovationRecord | None:
        f = self.filter
        rec = None
        for mm in mms:
            if mm.instance is not None and m.instance != mm.instance:
                continue
            f.ctx.values["z"] = float(f.x[0])
            z = mm.extract(m, f.ctx)
            why = f.ctx.values.pop("skip_why", None)        # an extract's own reason (models.range_gate)
            if z is None:
                self.counters.skip(f"{mm.name}_{why or 'not_used'}")     # calibrating, out of range
                continue
            if not np.all(np.isfinite(z)):
                self.counters.skip(f"{mm.name}_invalid")
                continue
            rec = f.update(mm, z, R=mm.R / m.samples if mm.per_sample and m.samples > 1 else None)
            self.counters.updates += 1
        return rec


# -- the altitude estimator's routing (coaxial document, chapter 9) ---------------------------
def _set_tilt(ctx: Context, roll: float, pitch: float, yaw: float = 0.0) -> None:
    v = ctx.values
    v["roll"], v["pitch"], v["yaw"] = roll, pitch, yaw
    # the rows of A_IB (coaxial doc. eq. 3.10): body -> world, kept with the
    # attitude (50 Hz) rather than recomputed per IMU sample (1 kHz)
    sf, cf, st, ct, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch), math.sin(yaw), math.cos(yaw)
    v["north_row"] = (cp * ct, cp * sf * st - cf * sp, sf * sp + cf * cp * st)
    v["east_row"] = (ct * sp, cf * cp + sf * sp * st, cf * sp * st - cp * sf)
    v["down_row"] = (-st, ct * sf, cf * ct)


def _attitude(m: Measurement, ctx: Context) -> None:
    _set_tilt(ctx, float(m.value[0]), float(m.value[1]), float(m.value[2]) if len(m.value) > 2 else 0.0)
    ctx.values["attitude_t"] = m.t


def _angular_rate(m: Measurement, ctx: Context) -> None:
    """The attitude message's body rates: the held attitude is carried forward with them
    (models.base.tilt_now; p, q are the Euler rates to first order in the tilt)."""
    ctx.values["roll_rate"], ctx.values["pitch_rate"] = float(m.value[0]), float(m.value[1])


def _quaternion(m: Measurement, ctx: Context) -> None:
    w, x, y, z = m.value
    _set_tilt(ctx, math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)),
              math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x)))),
              math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
    ctx.values["attitude_t"] = m.t


def _throttle(m: Measurement, ctx: Context) -> None:
    """THROTTLE and ACTUATOR records alike: the log's one throttle source (:func:`collective`)."""
    tau = collective(m, ctx)
    if tau is not None:
        set_throttle(ctx, tau, m.t)


def set_throttle(ctx: Context, tau: float, t: float) -> None:
    """The throttle from ``t`` on; the one before stays as ``throttle_before`` for a reading at
    that same instant (:func:`throttle_at_reading`)."""
    v = ctx.values
    if v.get("throttle_since") != t:
        v["throttle_before"] = v.get("throttle")
    v["throttle"], v["throttle_since"] = tau, t


def throttle_at_reading(ctx: Context, t: float) -> float | None:
    """The throttle in effect when a sensor read at ``t``: written before ``t``. One written at
    that instant has not yet drawn its current: a simulated thrust test flight steps its throttle
    on the battery's 5 Hz grid, and a reading paired with the step's new throttle put up to
    1.6 V of error in the voltage carried forward (thrust_voltage's n = 1.5 read 1.85)."""
    v = ctx.values
    return v.get("throttle_before") if v.get("throttle_since", -math.inf) >= t else v.get("throttle")


#: MAV_TYPE -> how many of the first outputs drive rotors (the rest are servos: a
#: coaxial helicopter's swash plate); SERVO_OUTPUT_RAW does not say which is which.
#: Named from pymavlink: the numbers were once typed by hand, and a coax (3) got four.
MOTOR_OUTPUTS = {mavlink.MAV_TYPE_QUADROTOR: 4, mavlink.MAV_TYPE_COAXIAL: 2, mavlink.MAV_TYPE_HELICOPTER: 1,
                 mavlink.MAV_TYPE_HEXAROTOR: 6, mavlink.MAV_TYPE_OCTOROTOR: 8, mavlink.MAV_TYPE_TRICOPTER: 3}


def motor_outputs(ctx: Context) -> int:
    return int(ctx.values.get("motor_outputs", 4))


def _vehicle_status(m: Measurement, ctx: Context) -> None:
    """The vehicle's type (HEARTBEAT): which outputs are motors."""
    if len(m.value) > 3 and np.isfinite(m.value[3]):
        ctx.values["motor_outputs"] = MOTOR_OUTPUTS.get(int(m.value[3]), 4)


def collective(m: Measurement, ctx: Context) -> float | None:
    """The collective throttle 0..1 of a THROTTLE or ACTUATOR record, from one source per log: the
    motor outputs (their mean) once the log has shown them, else THROTTLE. None: not this record.

    An autopilot's THROTTLE (VFR_HUD) is an integer percent, at a fifth of the outputs' rate, and on
    the autopilot's own scale (ArduPilot's is not the PWM's (us - 1000) / 1000). Taken from both, a
    simulated quad's thrust model flew a 1 %-quantised throttle for 20 ms of every 100 (up to
    0.1 m/s^2 of thrust at alpha = 22), and an actuator lag was fitted over both streams."""
    if m.kind is Kind.ACTUATOR:
        v = m.value[:motor_outputs(ctx)]
        v = v[np.isfinite(v)]          # the motors' outputs, then the unused among them (not servos' in their place)
        if not len(v):
            return None
        ctx.values["throttle_from_outputs"] = True
        return float(np.mean(v))
    if ctx.values.get("throttle_from_outputs") or not len(m.value) or not math.isfinite(m.value[0]):
        return None
    return float(m.value[0])


def vertical_acceleration(m: Measurement, ctx: Context) -> np.ndarray | None:
    """(gamma_z, cos_tilt): gamma_z = -(A_IB f)_down - g, the world-vertical specific force with
    gravity removed, and cos_tilt = (A_IB)_down,z = cos(roll) cos(pitch), how much of the body's
    z axis (and of a bias along it) is vertical."""
    if m.instance != 0:
        return None
    fx, fy, fz = m.value.tolist()
    a, b, c = ctx.values.get("down_row", _LEVEL)
    return np.array([-(a * fx + b * fy + c * fz) - G, c])


_LEVEL = (0.0, 0.0, 1.0)


def altitude_estimator(model: LinearModel | None = None) -> KalmanEstimator:
    from .models.altitude import altitude_model
    return KalmanEstimator(model or altitude_model(), inputs={Kind.ACCEL: vertical_acceleration},
                           context={Kind.ATTITUDE: _attitude, Kind.ATTITUDE_QUATERNION: _quaternion,
                                    Kind.ANGULAR_RATE: _angular_rate, Kind.THROTTLE: _throttle,
                                    Kind.ACTUATOR: _throttle, Kind.VEHICLE_STATUS: _vehicle_status})


# -- the multirotor attitude (gyro input, accelerometer updates: models.attitude_drag) ----------
#: a vertical velocity older than this is not used (the stream stopped: no GPS fix, a gap in the log)
VD_MAX_AGE = 0.5


def gyro_rates(m: Measurement, ctx: Context) -> np.ndarray | None:
    """u = (p_m, q_m, r_m, v_d): the gyro as measured, body FRD, and the latest vertical velocity
    (NED down; NaN if none within :data:`VD_MAX_AGE`: the model then leaves its terms out)."""
    if m.instance != 0:
        return None
    v = ctx.values
    vd = v["v_d"] if m.t - v.get("v_d_t", -math.inf) <= VD_MAX_AGE else math.nan
    return np.array([float(m.value[0]), float(m.value[1]), float(m.value[2]), vd])


def _vertical_velocity(m: Measurement, ctx: Context) -> None:
    """v_d from VELOCITY_NED (down) or CLIMB_RATE (up)."""
    vd = float(m.value[2]) if m.kind is Kind.VELOCITY_NED else -float(m.value[0])
    if math.isfinite(vd):                 # a GNSS board's VELOCITY_NED has no vertical component
        ctx.values["v_d"], ctx.values["v_d_t"] = vd, m.t


def attitude_estimator(model: LinearModel | None = None) -> KalmanEstimator:
    from .models.attitude_drag import attitude_drag_model
    return KalmanEstimator(model or attitude_drag_model(), inputs={Kind.GYRO: gyro_rates},
                           context={Kind.THROTTLE: _throttle, Kind.ACTUATOR: _throttle,
                                    Kind.VEHICLE_STATUS: _vehicle_status, Kind.VELOCITY_NED: _vertical_velocity,
                                    Kind.CLIMB_RATE: _vertical_velocity})


# -- horizontal position (IMU input, GPS updates) -------------------------------------------------
def horizontal_acceleration(m: Measurement, ctx: Context) -> np.ndarray | None:
    """(a_n, a_e) = rows 1 and 2 of A_IB f (gravity has no horizontal component)."""
    if m.instance != 0:
        return None
    f = m.value.tolist()
    rn, re_ = ctx.values.get("north_row", (1.0, 0.0, 0.0)), ctx.values.get("east_row", (0.0, 1.0, 0.0))
    return np.array([rn[0] * f[0] + rn[1] * f[1] + rn[2] * f[2], re_[0] * f[0] + re_[1] * f[1] + re_[2] * f[2]])


def horizontal_estimator(model: LinearModel | None = None) -> KalmanEstimator:
    from .models.horizontal import horizontal_model
    return KalmanEstimator(model or horizontal_model(), inputs={Kind.ACCEL: horizontal_acceleration},
                           context={Kind.ATTITUDE: _attitude, Kind.ATTITUDE_QUATERNION: _quaternion})


# -- the quadcopter thrust-model estimator's routing (quadcopter document) ---------------------
#: below this throttle the vehicle is taken to stand on the ground (the ground,
#: not the thrust model, carries its weight); the thrust model is for flight
TAU_GROUND = 0.15
#: ... but only with the estimate near the ground: above it, a throttle below ground idle is a
#: fast descent. The thrust test flight's descent from 3.6 m cut the throttle to 0.11 for 40 ms;
#: taken as landed, the model stopped the vehicle in mid-air (no thrust, no gravity, vz held at 0),
#: and a 20 ms "actuator lag", smoothing the dip away, gained 50 in log-likelihood on a clean flight
H_LANDED = 0.5
#: below this the motors are stopped (disarmed, spinning down): landed wherever the estimate is. An
#: autopilot does not stop them in flight, and an estimate may be far off at touchdown (ArduPilot's
#: underpowered.log: 5 m, on the baro alone before its effects are known); flying that estimate on
#: with the motors off dropped it through the last seconds and moved the fitted thrust_voltage n
#: from 1.31 to 0.81
TAU_STOPPED = 0.05


def landed(ctx: Context) -> bool:
    """The vehicle stands on the ground: the motors stopped, or the throttle below ground idle with
    the estimated height (the state vector's first element, ``_x``, kept in the context) within
    :data:`H_LANDED`."""
    tau = ctx.get("throttle")
    if tau >= TAU_GROUND:
        return False
    if tau < TAU_STOPPED:
        return True
    x = ctx.values.get("_x")
    return x is None or float(x[0]) <= H_LANDED


def thrust_input(m: Measurement, ctx: Context) -> np.ndarray | None:
    """u = (tau c, c, g): throttle times tilt, tilt, gravity (see models.quad_thrust);
    all zero on the ground, where the document's model does not apply (landed: below ground idle)."""
    tau = ctx.get("throttle")
    if landed(ctx):
        return np.zeros(3)
    c = ctx.values.get("down_row", _LEVEL)[2]
    return np.array([tau * c, c, G])


def thrust_input_on_ground(m: Measurement, ctx: Context) -> np.ndarray | None:
    """:func:`thrust_input`, zero also in contact with the ground with the rotors turning
    (:mod:`groundstation.models.contact`, whose resets and range readings the model then has)."""
    v = ctx.values
    x = v.get("_x")
    lifts = x is not None and (float(x[2]) * ctx.get("throttle") + float(x[3])) * v.get("down_row", _LEVEL)[2] > G
    if in_contact(v, m.t, float(x[0]) if x is not None else 0.0, lifts, known=x is not None):
        return np.zeros(3)
    return thrust_input(m, ctx)


def quad_thrust_estimator(model: LinearModel | None = None) -> KalmanEstimator:
    from .models.quad_thrust import quad_thrust_model
    model = model or quad_thrust_model()
    inp = thrust_input_on_ground if model.options.get("ground_contact") else thrust_input
    return KalmanEstimator(model,
                           inputs={Kind.ACTUATOR: inp, Kind.THROTTLE: inp, Kind.ATTITUDE: inp},
                           context={Kind.ATTITUDE: _attitude, Kind.ATTITUDE_QUATERNION: _quaternion,
                                    Kind.ANGULAR_RATE: _angular_rate, Kind.ACTUATOR: _throttle,
                                    Kind.THROTTLE: _throttle, Kind.VEHICLE_STATUS: _vehicle_status})


# -- the 3-DOF helicopter's routing (lab document) ---------------------------------------------
V_MAX_3DOF = 12.0    # the simulated rig's motor voltage range (its outputs are V / V_max)


def _motor_voltages(m: Measurement, ctx: Context) -> np.ndarray | None:
    """u = (V_f + V_b - V_s0, V_b - V_f) from the motor outputs."""
    from .models.heli3dof import V_S0
    if m.kind is Kind.MOTOR_VOLTAGE:
        vf, vb = float(m.value[0]), float(m.value[1])
    else:                                         # ACTUATOR: normalised outputs
        vf, vb = float(m.value[0]) * V_MAX_3DOF, float(m.value[1]) * V_MAX_3DOF
    return np.array([vf + vb - V_S0, vb - vf])


def _estimate_for_accel(m: Measurement, ctx: Context) -> None:
    """The arm's own acceleration (removed before the gravity direction is read) needs
    the angles, the rates and the input."""
    x, u = ctx.values.get("_x"), ctx.values.get("_u")
    if x is not None:
        v = ctx.values
        v["p_hat"], v["p_dot_hat"], v["e_hat"], v["e_dot_hat"], v["lambda_dot_hat"] = (
            float(x[0]), float(x[1]), float(x[2]), float(x[3]), float(x[5]))
        v["u_s"] = float(u[0]) if u is not None and len(u) else 0.0


def _estimate_for_gyro(m: Measurement, ctx: Context) -> None:
    """The gyro's Euler-rate transform needs the current pitch and elevation."""
    x = ctx.values.get("_x")
    if x is not None:
        ctx.values["p_hat"], ctx.values["e_hat"] = float(x[0]), float(x[2])


def heli3dof_estimator(model: LinearModel | None = None) -> KalmanEstimator:
    from .models.heli3dof import heli3dof_model
    est = KalmanEstimator(model or heli3dof_model(), inputs={Kind.ACTUATOR: _motor_voltages,
                                                             Kind.MOTOR_VOLTAGE: _motor_voltages},
                          context={Kind.GYRO: _estimate_for_gyro, Kind.ACCEL: _estimate_for_accel})
    est.filter.ctx.values["_x"] = est.filter.kf.x
    return est
