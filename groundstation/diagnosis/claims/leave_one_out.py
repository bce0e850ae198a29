"""Evidence from the log alone: each absolute sensor predicted by the others, before and after the
effects.

A pilot without motion capture cannot score the height; the log can still say whether the effects
describe it better. Each absolute sensor (range, baro, GPS) is left out of the filter in turn: its
readings correct no state (a Schmidt update of no state, ``MeasurementModel.corrects = ()``), so
each of its innovations is the reading less the prediction the *other* sensors and the
accelerometer made of it, through its own measurement function. The RMS of those innovations,
with the base model and with the model as found (the effects fixed at their fitted values), is the
evidence: where the effects are real, the others predict the left-out sensor better. Where the log
has truth, the height of the same runs is scored against it too (on the Crazyflie logs: the
baro-and-IMU height with the range left out, against the motion capture).

The effects' parameters are those fitted on the whole log (a handful of numbers against thousands
of readings); the left-out sensor's readings move no state in either run.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np

from groundstation.core.measurement import Kind, Measurement
from groundstation.diagnosis.runs.run import Prepared, run_model
from groundstation.diagnosis.scoring.background import Begun
from groundstation.diagnosis.scoring.noise_match import MatchedNoise
from groundstation.estimation.estimator import KalmanEstimator
from groundstation.estimation.models.base import LinearModel

#: the sensors that measure the height itself (the accelerometer is the model's input)
ABSOLUTE = {Kind.RANGE, Kind.BARO_ALTITUDE, Kind.BARO_PRESSURE, Kind.GPS}
SETTLE_S = 5.0  # [s] from the log's start not scored: the filter converging without the sensor


@dataclass(frozen=True)
class LeftOut:
    """One sensor left out: its readings' RMS prediction error from the others [its unit, m]."""

    sensor: str
    before: float
    after: float
    n: int
    truth_before: float | None = None  # the height's RMSE against truth in the same runs [m]
    truth_after: float | None = None

    def as_dict(self) -> dict:
        d = {"sensor": self.sensor, "rms_before": _r(self.before), "rms_after": _r(self.after), "n": self.n}
        if self.truth_before is not None and self.truth_after is not None:
            d |= {"height_rmse_before": _r(self.truth_before), "height_rmse_after": _r(self.truth_after)}
        return d

    def line(self) -> str:
        s = f"{self.sensor} {100 * self.before:.1f} -> {100 * self.after:.1f} cm RMS"
        if self.truth_before is not None and self.truth_after is not None:
            s += f" (the height without it: {100 * self.truth_before:.1f} -> {100 * self.truth_after:.1f} cm vs truth)"
        return s


def _r(v: float) -> float:
    return round(v, 5) if math.isfinite(v) else v


def without(model: LinearModel, name: str) -> LinearModel:
    """``model`` with sensor ``name``'s readings scored and correcting nothing (a GPS's with its
    velocity, ``gps_vz``: one receiver)."""
    meas = {k: dataclasses.replace(mm, corrects=(), reset=False) if mm.name in (name, f"{name}_vz") else mm
            for k, mm in model.measurements.items()}  # fmt: skip
    return dataclasses.replace(model, measurements=meas)


def _rms(run, name: str, t_from: float) -> tuple[float, int]:
    tr = run.sensors.get(name)
    if tr is None:
        return math.nan, 0
    keep = tr.t >= t_from
    nu = np.asarray(tr.nu, dtype=float)[keep]
    if not nu.size:
        return math.nan, 0
    nu = nu.reshape(len(nu), -1)
    return float(np.sqrt(np.mean(np.sum(nu * nu, axis=1)))), int(len(nu))


def absolute(model: LinearModel) -> list[str]:
    """The absolute sensors ``model`` reads, in its order."""
    names: list[str] = []
    for mm in model.measurements.values():
        if mm.kind in ABSOLUTE and mm.name not in names and dataclasses.is_dataclass(mm):
            names.append(mm.name)
    return names


class LeftOutRuns:
    """The runs of :func:`leave_one_out`, two a sensor, forked early and collected by :meth:`results`
    (:class:`.Begun`: at a lower priority, each run read for its scores alone, ``run_model(scores_only=True)``).

    Made with the model as declared, before the search's first run: the model before's runs are
    forked then, held (``workers`` - 1 processes, the cores the search's one-at-a-time stretches leave
    idle), while the diagnosis's heap holds little more than the log. :meth:`before` starts them with
    the noise the log shows and the zeros the search holds (numbers alone cross to them); :meth:`then`
    begins the model after's, on ``workers``, while the diagnosis reads the thrust curve beside the
    model. Each gives back its numbers alone, the same on any number of ``workers``; with one, all are
    made here when collected. The model before's runs hold the model's process noise (they begin before
    the level is chosen, ``noise_match.match_process_noise``): where the log chose another, what the
    model after gains on them holds that level's share too."""

    def __init__(
        self,
        declared: LinearModel,
        prep: Prepared,
        make: Callable[[LinearModel], KalmanEstimator],
        truth=None,
        workers: int = 1,
    ) -> None:
        self._prep, self._make, self._truth, self._workers = prep, make, truth, workers
        self._declared = declared
        self._names_before = absolute(declared)
        self._names: list[str] = []
        self._before: Begun = Begun(
            self._scored_before, self._names_before, workers - 1 if workers > 1 else 0, held=True
        )
        self._after: Begun | None = None

    def _scored(
        self, model: LinearModel, prep: Prepared, stream: Sequence[Measurement] | None, name: str
    ) -> tuple[float, int, float]:
        """(the left-out sensor's RMS innovation, its count, the height's RMSE against truth)."""
        run = run_model(without(model, name), prep, self._make, measurements=stream, scores_only=True)
        rms, n = _rms(run, name, prep.t0 + SETTLE_S)
        return rms, n, self._truth.error(run, prep.t0, prep.t1) if self._truth is not None else math.nan

    def _scored_before(self, matched: MatchedNoise, name: str) -> tuple[float, int, float]:
        """The model before's: the declared model with the noise ``matched``, over the log with its zeros."""
        model, prep = matched.applied(self._declared, self._prep)
        return self._scored(model, prep, None, name)

    def before(self, model0: LinearModel) -> None:
        """The model before's runs started: ``model0`` is the declared model with each sensor's noise as
        the log shows it (:func:`.noise_match.match_noise`), over the prepared log with its zeros held."""
        self._before.go(MatchedNoise.of(model0, self._prep))

    def then(self, after: LinearModel, after_stream: Sequence[Measurement]) -> None:
        """The model after's runs begun (its readings ``after_stream``: its delays applied), each sensor the
        model before has too; in place of those begun before (stopped, where still running)."""
        if self._after is not None:
            self._after.close()
        self._names = [name for name in absolute(after) if name in self._names_before]
        self._after = Begun(
            partial(self._scored, after, self._prep, after_stream),
            self._names,
            self._workers if self._workers > 1 else 0,
        )

    def results(self) -> list[LeftOut]:
        """Each sensor left out, before and after (none before :meth:`then`)."""
        if self._after is None:
            return []
        after = self._after.results()
        before = dict(zip(self._names_before, self._before.results()))
        out = []
        for name, (a, _, ea) in zip(self._names, after):
            b, n, eb = before[name]
            if not n:
                continue
            both = self._truth is not None and math.isfinite(eb) and math.isfinite(ea)
            out.append(LeftOut(name, b, a, n, eb if both else None, ea if both else None))
        return out

    def close(self) -> None:
        """Stop the runs still going (the diagnosis ended otherwise)."""
        self._before.close()
        if self._after is not None:
            self._after.close()


def leave_one_out(
    before: LinearModel,
    after: LinearModel,
    prep: Prepared,
    make: Callable[[LinearModel], KalmanEstimator],
    after_stream: Sequence[Measurement],
    truth=None,
    workers: int = 1,
) -> list[LeftOut]:
    """Each absolute sensor both models have, left out of each (the after model's readings: its
    delays applied, ``after_stream``), on up to ``workers`` processes."""
    runs = LeftOutRuns(before, prep, make, truth, workers)
    try:
        runs.before(before)
        runs.then(after, after_stream)
        return runs.results()
    finally:
        runs.close()
