"""The model's error as the lab measured it (its Figures 2-4): the encoders predicted from the motor
voltages alone, here over ``HORIZON_S`` from each of many starts, before and after the effects.

The lab integrated its model from one start over the whole flight; the error then grows without
bound (travel integrates the pitch twice), so a short flight's figure says more about its length
than about the model. From a start every ``EVERY_S`` of free flight, each run begins at the measured
state (the smoothed encoders and their rates) and is driven by the logged voltages only, and its
error is read against the encoders over the next ``HORIZON_S``: the model's own error, as a
controller designed on it would meet it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .model import lagged, rig_of
from .session import RigSession

HORIZON_S = 1.0
EVERY_S = 0.5
AXES = ("p", "e", "lambda")


@dataclass(frozen=True)
class PredictionError:
    """RMS error of the predicted encoder angles over the horizon [rad], per axis, and the number
    of runs it is over."""

    rms: dict[str, float]
    runs: int
    horizon: float

    def as_json(self) -> dict:
        return {
            "rms_deg": {k: round(math.degrees(v), 4) for k, v in self.rms.items()},
            "runs": self.runs,
            "horizon_s": self.horizon,
        }


def starts(s: RigSession, horizon: float = HORIZON_S) -> np.ndarray:
    """Start samples whose whole horizon is free flight."""
    n = int(round(horizon / s.dt))
    every = max(1, int(round(EVERY_S / s.dt)))
    blocked = np.concatenate([[0], np.cumsum(~s.free)])
    i = np.arange(0, s.n - n - 1, every)
    return i[(blocked[i + n + 1] - blocked[i]) == 0]


def prediction_error(s: RigSession, v: dict[str, float], horizon: float = HORIZON_S) -> PredictionError:
    """Every start's run of the model ``v`` (all starts at once, a column each), semi-implicit Euler
    at the encoders' step."""
    i0 = starts(s, horizon)
    n = int(round(horizon / s.dt))
    if not len(i0):
        return PredictionError({k: math.nan for k in AXES}, 0, horizon)
    rig = rig_of(v)
    V_f, V_b = lagged(s, v["tc"])
    off = {"p": v["o_p"], "e": v["o_e"], "lambda": 0.0}
    x = {k: s.angle[k][i0] - off[k] for k in AXES}
    xd = {k: s.rate[k][i0].copy() for k in AXES}
    sq = {k: 0.0 for k in AXES}
    for j in range(1, n + 1):
        k0 = i0 + j - 1
        acc = rig.accelerations(x["p"], x["e"], xd["p"], xd["e"], xd["lambda"], V_f[k0], V_b[k0])
        for k, a in zip(AXES, acc):
            xd[k] = xd[k] + a * s.dt
            x[k] = x[k] + xd[k] * s.dt
            err = x[k] + off[k] - s.angle[k][i0 + j]
            sq[k] += float(err @ err)
    count = n * len(i0)
    return PredictionError({k: math.sqrt(sq[k] / count) for k in AXES}, len(i0), horizon)
