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

import numpy as np

from groundstation.core.measurement import Kind, Measurement
from groundstation.diagnosis.runs.run import Prepared, run_model
from groundstation.diagnosis.scoring.background import Begun
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
    """``model`` with sensor ``name``'s readings scored and correcting nothing."""
    meas = {k: dataclasses.replace(mm, corrects=(), reset=False) if mm.name == name else mm
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
    """The runs of :func:`leave_one_out`, begun now (:class:`.Begun`: at a lower priority, on up to
    ``workers`` processes, no more runs held at once than that) and collected by :meth:`results`: the
    diagnosis reads the thrust curve beside the model meanwhile. The runs, two a sensor, are
    independent; each gives back its numbers alone, the same on any number of ``workers``."""

    def __init__(
        self,
        before: LinearModel,
        after: LinearModel,
        prep: Prepared,
        make: Callable[[LinearModel], KalmanEstimator],
        after_stream: Sequence[Measurement],
        truth=None,
        workers: int = 1,
    ) -> None:
        names_before = absolute(before)
        self._names = [name for name in absolute(after) if name in names_before]
        self._truth = truth
        t_from = prep.t0 + SETTLE_S

        def scored(job: tuple[str, bool]) -> tuple[float, int, float]:
            """(the left-out sensor's RMS innovation, its count, the height's RMSE against truth)."""
            name, as_found = job
            if as_found:
                run = run_model(without(after, name), prep, make, measurements=after_stream)
            else:
                run = run_model(without(before, name), prep, make)
            rms, n = _rms(run, name, t_from)
            return rms, n, truth.error(run, prep.t0, prep.t1) if truth is not None else math.nan

        self._runs = Begun(scored, [(name, as_found) for name in self._names for as_found in (False, True)], workers)

    def results(self) -> list[LeftOut]:
        """Each sensor left out, before and after."""
        runs = self._runs.results()
        out = []
        for k, name in enumerate(self._names):
            (b, n, eb), (a, _, ea) = runs[2 * k], runs[2 * k + 1]
            if not n:
                continue
            both = self._truth is not None and math.isfinite(eb) and math.isfinite(ea)
            out.append(LeftOut(name, b, a, n, eb if both else None, ea if both else None))
        return out

    def close(self) -> None:
        """Stop the runs still going (the diagnosis ended otherwise)."""
        self._runs.close()


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
    runs = LeftOutRuns(before, after, prep, make, after_stream, truth, workers)
    try:
        return runs.results()
    finally:
        runs.close()
