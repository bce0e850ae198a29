"""``groundstation evaluate LOG``: how well the estimators do on measured data.

Runs the estimator the log's sensors allow and prints, per sensor: its raw
error against truth (motion capture in the log, or a truth CSV beside it or named), the estimate's
RMSE against truth, the innovations' mean NIS, and a whiteness p-value
(Ljung-Box on the normalised innovations): a small p says the innovations are
correlated, i.e. the model misses something the diagnosis should find. Against truth it also
says whether the height's sigma (what the dashboard draws) is honest: the share of the errors
within 2 sigma (95 % if so) and the height's NEES (1 if so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from groundstation.core.atmosphere import altitude_at
from groundstation.core.counts import counted
from groundstation.core.measurement import Kind

from .logs import load_blocked, load_measurements
from .loop import EstimationLoop
from .models.ground import LANDED
from .registry import build_estimator, effects_used
from .truth import truth_from
from .vehicles import range_offset
from .whiteness import ljung_box


@dataclass
class SensorRow:
    sensor: str
    n: int
    raw_rmse: float
    nis: float
    whiteness_p: float


@dataclass
class Evaluation:
    description: str
    model: str
    rows: list[SensorRow]
    estimate_rmse: float
    estimates: int
    skipped: dict[str, int] = field(default_factory=dict)  # the estimator's counted skips
    truth: str = ""  # where the truth came from ('' without one)
    within_2sigma: float = float("nan")  # share of the height's errors within its 2 sigma
    nees: float = float("nan")  # the height's mean squared error in sigmas
    #: the range's ground clearance the log states, taken as its mounting offset ('' if none was)
    clearance: str = ""
    #: what the still stretch before take-off said of the baro's noise (estimation.still_noise)
    noise: str = ""

    def table(self) -> str:
        out = [
            self.description,
            f"model: {self.model}, {self.estimates} estimates"
            + (f"; the estimator skipped {counted(self.skipped)}" if self.skipped else "")
            + (f"; range offset {self.clearance}" if self.clearance else ""),
            *([self.noise] if self.noise else []),
            f"{'sensor':<10}{'n':>7}{'raw RMSE vs truth [m]':>24}{'NIS mean':>10}{'whiteness p':>13}",
        ]
        for r in self.rows:
            raw = f"{r.raw_rmse:.4f}" if r.raw_rmse == r.raw_rmse else "-"
            if r.nis == r.nis:
                out.append(f"{r.sensor:<10}{r.n:>7}{raw:>24}{r.nis:>10.2f}{r.whiteness_p:>13.3g}")
            else:
                out.append(f"{r.sensor:<10}{r.n:>7}{raw:>24}   (raw reading with the mounting offset applied)")
        if self.estimate_rmse == self.estimate_rmse:
            est = f"{self.estimate_rmse:.4f}"
        else:  # no truth, or a model with no height to score (the 3-DOF rig's)
            est = "- (no height state)" if self.truth else "- (no truth)"
        out.append(f"{'estimate':<10}{'':>7}{est:>24}" + (f"   (truth: {self.truth})" if self.truth else ""))
        if self.nees == self.nees:
            out.append(
                f"its sigma: {self.within_2sigma:.0%} of the height within 2 sigma of truth (95 % if honest), "
                f"NEES {self.nees:.2f} (1 if honest)"
            )
        return "\n".join(out)


def evaluate(
    path: Path,
    model: str = "altitude",
    *,
    vehicle: str | None = None,
    t_window: tuple[float, float] | None = None,
    truth_csv: Path | None = None,
) -> Evaluation:
    """The model over the whole log (its IMU in blocks, :func:`.logs.load_blocked`, where it has one
    vehicle), scored against truth: motion capture in the log, ``truth_csv``, or a truth CSV beside
    the log (``LOG.csv``, ``LOG_truth.csv``; :func:`.truth.truth_from`)."""
    blocked = load_blocked(path)
    stated: list[dict] = []
    if blocked is not None:
        ms, desc, implied, stated = blocked.measurements, blocked.description, blocked.vehicle, blocked.stated
    else:
        ms, desc, implied = load_measurements(path)
    est = build_estimator(model, vehicle=vehicle or implied, stated=stated)
    used = effects_used((), vehicle or implied, stated)
    offset = range_offset(used)
    clearance = next((f"{e['params']['o'] * 100:.1f} cm ({e['stated']})" for e in used if "stated" in e), "")
    loop = EstimationLoop([est], reorder_s=0.0) if blocked is not None else EstimationLoop([est])
    snaps = loop.snapshots.subscribe()
    raw: dict[str, list[tuple[float, float]]] = {"range": [], "baro": [], "baro_alt": []}
    for m in ms:
        loop.push(m)
        if m.kind is Kind.RANGE:
            raw["range"].append((m.t, float(m.value[0])))
        elif m.kind is Kind.BARO_PRESSURE:
            raw["baro"].append((m.t, float(altitude_at(m.value[0]))))
        elif m.kind is Kind.BARO_ALTITUDE:
            raw["baro_alt"].append((m.t, float(m.value[0])))
    # one barometer read as the model reads it (models.base.barometer): from its pressure where the
    # log gives one, its altitude otherwise (a DataFlash BARO record gives both of one sample)
    raw["baro"] = raw["baro"] or raw.pop("baro_alt")
    s = snaps.get_nowait()
    truth = truth_from(ms, path, truth_csv)
    if truth_csv is not None and truth is None:
        raise ValueError(f"{truth_csv}: no truth in it (a CSV with columns t and h, or t and z)")
    tt, zz = (truth.t, truth.h) if truth is not None else (np.zeros(0), np.zeros(0))
    t0, t1 = t_window or ((tt[0], tt[-1]) if len(tt) else (-np.inf, np.inf))

    def rmse_vs_truth(t, v):
        if truth is None or not len(t):
            return float("nan")
        return truth.rmse(np.asarray(t), np.asarray(v), t0, t1)

    rows = []
    for sensor in est.filter.log.sensors():
        if sensor == LANDED:  # the ground's pseudo-sensor (models.ground), not a sensor
            continue
        a = est.filter.log.arrays(sensor)
        nu = a["nu"][:, 0] / np.sqrt(a["S"][:, 0, 0])
        r = np.array(raw.get(sensor, []))
        raw_rmse = float("nan")
        if len(r) and len(tt):
            t, v = r[:, 0], r[:, 1]
            if sensor == "baro":  # an absolute sensor's zero: its first second against truth
                first = t < t[0] + 1.0
                v = v - np.mean(v[first] - np.interp(t[first], tt, zz))
            raw_rmse = rmse_vs_truth(t, v)
        rows.append(SensorRow(sensor, len(nu), raw_rmse, float(a["nis"].mean()), ljung_box(nu)))
        if sensor == "range" and offset and len(r) and len(tt):
            # the sensor alone at its best: the same mounting offset the model uses, applied to the raw reading
            rows.append(SensorRow("range-o", len(r), rmse_vs_truth(r[:, 0], r[:, 1] - offset), math.nan, math.nan))
    # the height truth scores is the model's z (a model without one, as the 3-DOF rig's, is not scored)
    iz = s[0].states.index("z") if s and "z" in s[0].states else None
    st = np.array([x.t for x in s])
    sz = np.array([x.x[iz] for x in s]) if iz is not None else np.zeros(0)
    within, nees = math.nan, math.nan
    if truth is not None and iz is not None:
        sigma = np.sqrt(np.clip([x.P[iz, iz] for x in s], 0.0, None))
        within, nees = truth.consistency(st, sz, sigma, t0, t1)
    return Evaluation(
        desc,
        model,
        rows,
        rmse_vs_truth(st, sz) if iz is not None else math.nan,
        len(s),
        est.counters.rejected,
        truth.source if truth else "",
        within,
        nees,
        clearance,
        est.still_noise_note,
    )
