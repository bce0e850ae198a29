"""The lab's Kalman filter (part 4, :func:`~groundstation.estimation.models.heli3dof.heli3dof_model`)
run over the session on the lab's constants and on the rig's, and its normalised innovation squared
per sensor: each sensor's mean NIS over its dimension is 1 where the model and its noise hold.

The measurement noise is the session's own (the lab's eq. 59 takes it from data as well): the
gyro's and the accelerometer's from their readings against what the encoders say they read, the
encoders' from their resolution (a uniform quantisation, step^2 / 12).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from groundstation.core.measurement import Kind, Measurement
from groundstation.estimation.models.heli3dof import heli3dof_model
from groundstation.estimation.models.heli3dof_rig import Heli3dofRig, imu_frame
from groundstation.estimation.routing import heli3dof_estimator

from .session import RigSession

G = 9.81
#: [s] of each free stretch the NIS is not counted over (the filter's start, or its recovery from
#: the table's contact its model does not hold)
SETTLE_S = 2.0


def noise(s: RigSession, rig: Heli3dofRig) -> dict[str, np.ndarray]:
    """The filter's R from the session: per-axis variances of the IMU's readings against the
    encoders' prediction of them (free flight), the encoders' quantisation."""
    R: dict[str, np.ndarray] = {}
    if s.encoder_step > 0:
        R["encoders"] = np.eye(3) * s.encoder_step**2 / 12.0
    if s.gyro_raw is None or s.specific_force_raw is None:
        return R
    k = s.free
    p, e = s.angle["p"][k] - rig.encoder_offset[0], s.angle["e"][k] - rig.encoder_offset[1]
    w, f = imu_frame(p, e, s.rate["p"][k], s.rate["e"][k], s.rate["lambda"][k], s.accel["e"][k], s.accel["lambda"][k])
    C = rig.mounting()
    dw = s.gyro_raw[k] - w @ C.T - np.asarray(rig.gyro_bias)
    df = s.specific_force_raw[k] - f @ C.T - np.asarray(rig.accel_bias)
    if len(dw) > 10:
        R["gyro"] = np.diag(np.maximum(np.var(dw, axis=0), 1e-10))
        # the accelerometer enters as two angles (atan2 of gravity's direction): y and z for the
        # pitch, x for the elevation, each over g
        R["accel"] = np.diag(np.maximum([np.var(df[:, 1]) / G**2, np.var(df[:, 0]) / G**2], 1e-10))
    return R


def nis(ms: Sequence[Measurement], s: RigSession, rig: Heli3dofRig, R: dict[str, np.ndarray]) -> dict[str, float]:
    """Each sensor's mean NIS over its dimension, over the free flight (``SETTLE_S`` into each
    stretch on). NaN for a sensor that never updated there."""
    est = heli3dof_estimator(heli3dof_model(R=R, rig=rig))
    t_free = _settled(s)
    sums: dict[str, list[float]] = {}
    for m in ms:
        if m.kind not in _USED:
            continue
        rec = est.handle(m)
        if rec is None or not _inside(t_free, rec.t):
            continue
        acc = sums.setdefault(rec.sensor, [0.0, 0])
        acc[0] += rec.nis / len(rec.nu)
        acc[1] += 1
    return {k: (v[0] / v[1] if v[1] else math.nan) for k, v in sorted(sums.items())}


_USED = frozenset({Kind.ENCODERS, Kind.ATTITUDE, Kind.GYRO, Kind.ACCEL, Kind.ACTUATOR, Kind.MOTOR_VOLTAGE})


def _settled(s: RigSession) -> np.ndarray:
    """(start, end) of each free stretch, its first ``SETTLE_S`` left out."""
    f = s.free.astype(np.int8)
    d = np.diff(np.concatenate([[0], f, [0]]))
    spans = [(s.t[a] + SETTLE_S, s.t[b - 1]) for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1))]
    return np.array([x for x in spans if x[1] > x[0]] or [(math.inf, -math.inf)])


def _inside(spans: np.ndarray, t: float) -> bool:
    i = int(np.searchsorted(spans[:, 0], t, side="right")) - 1
    return i >= 0 and t <= spans[i, 1]
