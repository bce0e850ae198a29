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

from groundstation.core.measurement import Measurement

from .estimator import KalmanEstimator


def stationary_noise(measurements: Iterable[Measurement], est: KalmanEstimator, t0: float, t1: float) -> dict:
    """{sensor: {"R": matrix, "n": samples, "mean": vector}} over [t0, t1)."""
    ctx = est.filter.ctx
    samples: dict[str, list] = {}
    for m in measurements:
        if not t0 <= m.t < t1:
            continue
        for mm in est.model.measurements.values():
            if mm.kind is m.kind and (mm.instance is None or mm.instance == m.instance):
                z = mm.extract(m, ctx)
                if z is not None and np.all(np.isfinite(z)):
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


def load_noise(path: Path | None) -> dict | None:
    """``--noise FILE`` -> {sensor: R matrix}."""
    if path is None:
        return None
    try:
        d = json.loads(Path(path).read_text())
        return {k: np.array(v["R"], dtype=float) for k, v in d.items()}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{path}: not a noise file from 'groundstation noise': {e}") from None
