"""R from stationary data: the covariance of each sensor's measurement vector
while the vehicle rests (the lab document's eq. 59, ``R_d = cov(IMU)``).

Each measurement is taken exactly as its estimator's measurement model
extracts it (e.g. the accelerometer's pitch and elevation), so the matrices
drop straight into ``--noise``.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from groundstation.core.measurement import Kind, Measurement

from .estimator import KalmanEstimator

#: MAVLink MAV_STATE_ACTIVE: "motors are engaged"
MAV_STATE_ACTIVE = 4


def stationary_noise(measurements: Iterable[Measurement], est: KalmanEstimator, t0: float, t1: float) -> dict:
    """{sensor: {"R": matrix, "n": samples, "mean": vector}} over [t0, t1).

    The window is read twice: an absolute sensor's reading is a height only once its zero is
    calibrated (the baro's first 50 readings, 2 s at 25 Hz: :func:`.models.base.relative_to_estimate`),
    and a window as short as a pre-arm stretch would otherwise hold none of it. A constant zero
    moves no covariance."""
    ctx = est.filter.ctx
    window = [m for m in measurements if t0 <= m.t < t1]
    samples: dict[str, list] = {}
    for keep in (False, True):
        for m in window:
            for mm in est.model.measurements.values():
                if mm.kind is m.kind and (mm.instance is None or mm.instance == m.instance):
                    z = mm.extract(m, ctx)
                    if keep and z is not None and np.all(np.isfinite(z)):
                        samples.setdefault(mm.name, []).append(np.atleast_1d(z))
    out = {}
    for name, zs in samples.items():
        Z = np.array(zs)
        if len(Z) < 10:
            continue
        R = np.atleast_2d(np.cov(Z, rowvar=False))
        note = ""
        if np.linalg.matrix_rank(R) < R.shape[0]:
            # constant over the window (quantisation only): the model's own value
            R = np.atleast_2d(next(mm.R for mm in est.model.measurements.values() if mm.name == name))
            note = "constant while stationary (quantisation only): the model's default kept"
        out[name] = {"R": R.tolist(), "n": len(Z), "mean": Z.mean(axis=0).tolist(), **({"note": note} if note else {})}
    return out


def first_arming(measurements: Iterable[Measurement]) -> float | None:
    """The vehicle time [s] the log first states the vehicle armed (a HEARTBEAT's armed bit or its
    MAV_STATE_ACTIVE, "motors engaged"), or None where it states none: the end of the stretch in which
    the vehicle stood still on the ground."""
    for m in measurements:
        if m.kind is Kind.VEHICLE_STATUS and len(m.value) > 2 and (m.value[0] == 1.0 or m.value[2] == MAV_STATE_ACTIVE):
            return m.t
    return None


def load_noise(path: Path | None) -> dict | None:
    """``--noise FILE`` -> {sensor: R matrix}."""
    if path is None:
        return None
    try:
        d = json.loads(Path(path).read_text())
        return {k: np.array(v["R"], dtype=float) for k, v in d.items()}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{path}: not a noise file from 'groundstation noise': {e}") from None
