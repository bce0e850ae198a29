"""One 3-DOF helicopter session diagnosed: its columns read, the lab's model (or the rig's file)
checked against them, the effects it lacks found one at a time, and the model's error before and
after: the encoders predicted from the voltages (:mod:`.predict`), each equation's residual, and
the lab's Kalman filter's NIS (:mod:`.kalman`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from groundstation.core.imu import ImuColumns
from groundstation.core.measurement import Measurement
from groundstation.estimation.models.heli3dof_rig import Heli3dofRig

from .catalogue import RigCandidate, rig_catalogue
from .identify import Search, search
from .kalman import nis, noise
from .model import rig_of, values_of
from .predict import PredictionError, prediction_error
from .session import RigSession, read_session

#: [s] of free flight the search needs (the rig's closed loop settles in a few seconds; a few
#: elevation steps and a travel swing make its terms distinguishable)
MIN_FREE_S = 10.0


@dataclass
class RigDiagnosis:
    session: RigSession
    search: Search
    catalogue: list[RigCandidate]
    before: Heli3dofRig
    after: Heli3dofRig
    prediction: tuple[PredictionError, PredictionError]
    residual_rms: tuple[dict[str, float], dict[str, float]]
    nis: tuple[dict[str, float], dict[str, float]] | None
    R: dict[str, np.ndarray]


def _rms(fit) -> dict[str, float]:
    return {g: math.sqrt(fit.rss[g] / fit.n[g]) if fit.n[g] else math.nan for g in fit.rss}


def diagnose_rig(
    ms: Sequence[Measurement],
    imu: ImuColumns | None = None,
    *,
    start: Heli3dofRig | None = None,
    source: str = "",
    progress: Callable[[str], None] | None = None,
    with_kalman: bool = True,
) -> RigDiagnosis:
    """Diagnose a session's readings from the model ``start`` (the lab's by default; a rig file's to
    look for what it still lacks). One-line ValueError where the session cannot be diagnosed."""
    say = progress or (lambda _: None)
    s = read_session(list(ms), imu, source=source)
    if s.seconds_free < MIN_FREE_S:
        raise ValueError(
            f"the rig flew free for {s.seconds_free:.1f} s of the session (at least {MIN_FREE_S:.0f} s needed): "
            "it rested on the table or an end stop for the rest"
        )
    say(f"rig session: {s.t[-1] - s.t[0]:.1f} s, {s.seconds_free:.1f} s in free flight")
    catalogue = rig_catalogue(s.gyro is not None and s.specific_force is not None)
    start = start or Heli3dofRig()
    found = search(s, catalogue, values_of(start))
    for st in found.claimed:
        say(f"added {st.name} (Delta BIC {st.delta_bic:.0f})")
    before, after = rig_of(found.base.values), rig_of(found.final.values)
    pred = (prediction_error(s, found.base.values), prediction_error(s, found.final.values))
    R = noise(s, after)
    kalman = None
    if with_kalman:
        say("the lab's Kalman filter, before and after")
        records = list(ms)
        if imu is not None:  # the filter takes the IMU as records, in time order with the rest
            records = sorted(records + imu.records(), key=lambda m: m.t)
        kalman = (nis(records, s, before, R), nis(records, s, after, R))
    return RigDiagnosis(s, found, catalogue, before, after, pred, (_rms(found.base), _rms(found.final)), kalman, R)
