"""The multirotor attitude filter as a diagnosis model: where the IMU's own effects can show.

The altitude and thrust models take the attitude as given (the autopilot's), so
an error of the gyro or of the IMU's mounting never reaches their innovations.
The drag attitude model (:mod:`groundstation.estimation.models.attitude_drag`) runs on the
raw IMU: the gyro as its input, the accelerometer's horizontal specific force as
its measurement (rotor drag of the body velocity). There both effects leave a
residual:

* ``gyro_bias``: the rates integrate to a tilt that the drag dynamics then
  contradict. States ``b_p, b_q``; params ``x, y`` [rad/s] as the simulator's
  ``w_m = w + b`` (a yaw-rate bias is not observable from gravity and drag).
* ``imu_misalignment``: the IMU mounted rotated by ``(roll, pitch)``; params in
  degrees as the simulator's ``f_m = C f, w_m = C w``. It shows through thrust
  changes and the rates it mixes (see the model's docstring); its yaw part does not.

Each is added by rebuilding the model with the option on (a nonlinear model is
not augmented column by column). Run with ``--model attitude`` on a multirotor log
with a raw IMU (HIGHRES_IMU / RAW_IMU / SCALED_IMU, DataFlash IMU).
"""

from __future__ import annotations

import math

from groundstation.core.measurement import Kind
from groundstation.diagnosis.catalogue.candidate import Candidate
from groundstation.estimation.models.attitude_drag import attitude_drag_model
from groundstation.estimation.models.base import LinearModel


def _rebuilt(**option):
    def augment(model: LinearModel) -> LinearModel:
        return attitude_drag_model(**{**model.options, **option})

    return augment


def _gyro_bias(run) -> dict:
    (bp, sp), (bq, sq) = run.final("b_p"), run.final("b_q")
    return {"x": bp, "y": bq, "sigma_x": sp, "sigma_y": sq}


def _mounting(run) -> dict:
    (r, sr), (p, sp) = run.final("m_roll"), run.final("m_pitch")
    return {
        "roll": math.degrees(r),
        "pitch": math.degrees(p),
        "sigma_roll": math.degrees(sr),
        "sigma_pitch": math.degrees(sp),
        "unit": "deg",
    }


def attitude_catalogue(kinds: set) -> list[Candidate]:
    cands = [
        Candidate("gyro_bias", 2, {Kind.GYRO, Kind.ACCEL}, "accel", _rebuilt(gyro_bias=True), _gyro_bias),
        Candidate("imu_misalignment", 2, {Kind.GYRO, Kind.ACCEL}, "accel", _rebuilt(misalignment=True), _mounting),
    ]
    return [c for c in cands if c.needs <= kinds]


_HEIGHT = "acts on the height sensors, which this model does not use: run the altitude model"
#: effects this model cannot show, and why (reported, not guessed)
UNOBSERVABLE_ATTITUDE = {
    "accel_bias": "a horizontal accelerometer bias is exactly a tilt with a velocity offset (b = g delta): "
    "a simulated 0.2 m/s^2 raised the likelihood by 1 over 5000 updates when modelled; a vertical "
    "one is the altitude model's state b_acc",
    "accel_scale": "the drag model reads the horizontal specific force, whose scale is the drag coefficient's: "
    "run the altitude model",
    **{
        name: _HEIGHT
        for name in (
            "baro_bias_drift",
            "baro_thermal",
            "baro_thrust",
            "baro_ground_effect",
            "range_tilt",
            "range_offset",
            "sensor_delay",
        )
    },
    **{
        name: "thrust-side: run the quad_thrust model"
        for name in ("thrust_voltage", "thrust_ground_effect", "actuator_lag")
    },
}
