"""For what lies outside the catalogue: a sparse regression over the log's signals.

The library holds what the log has, at the sensor's update instants: throttle,
height, tilt, vertical speed, its square and its signed square v|v| (dynamic pressure), the speed
over the ground and its square (the GNSS velocity's), voltage, current, temperature,
rotor vibration, time; each also low-passed (0.5 s, 2 s) and delayed (0.1 s,
0.3 s). Columns are standardised; the target is the sensor's raw innovation
``nu`` [sensor units]. Orthogonal matching pursuit (the greedy sparse
regression) picks the columns one at a time while each still lowers the BIC
of the least-squares fit; the first pick is the strongest correlate, and its
coefficient is given back in the signal's own units. It is named when it explains
:data:`MIN_R2` of the innovations' variance, or their colour (:data:`WHITENS`), *out of sample*:
each of three consecutive time blocks predicted by the terms fitted on the other two, and over
them the prediction better than the mean. Scored in sample, a clean flight of a
generator that is not ours "had" a baro error following the throttle delayed by 0.1 s.
The coefficient comes from the raw innovations, so it is short by what the
filter absorbed: a simulated 0.1, 0.2 and 0.3 m per (m/s)^2 read 0.077, 0.174
and 0.325 (``tests/test_diagnosis.py``).

Why not regress raw innovations on raw features for the catalogue too: the
filter absorbs part of every effect, so such coefficients are biased
low; the catalogue's candidates are scored through the filter itself
(:mod:`~groundstation.diagnosis.scoring.trace`). This regression only *names* what the catalogue does not.
OMP is written out (30 lines) rather than pulled from scikit-learn, which the
project does not otherwise need.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from groundstation.diagnosis.runs.run import Run
from groundstation.estimation.whiteness import ljung_box_q

LAGS = 20  # the Ljung-Box test's, as sensor_findings runs it (evaluate.ljung_box)

#: a discovery must explain this much of the innovation variance: with thousands of
#: updates a 1 % correlate is "significant" and still not worth a person's time...
MIN_R2 = 0.10
#: ... unless it is what colours them: the innovations fail Ljung-Box (p < 0.05) and, with the fit taken
#: out, the statistic falls to this fraction of itself or less. A noisy sensor's error can be small
#: against its noise and still be all of its colour: a simulated baro reading high by 0.2 m per (m/s)^2
#: of climb rate (``baro_airflow``) is 5 % of the baro's innovation variance, and Q falls 139 -> 14
#: (p 6e-20 -> 0.82); the range's 3-5 % correlates on the same flights leave Q where it was
WHITENS = 0.5


#: the correlates a weak discovery is drawn from (:func:`discover`): a static port's error that
#: physics predicts and the catalogue does not name, the dynamic pressure of the flight over the
#: ground (ArduPilot's BARO1_WCF_* model it per body axis), read from the GNSS velocity, apart from
#: the estimate. The vertical speed's terms are the estimate's own, which the baro's error feeds:
#: weighed by the filter on a Crazyflie's baro, v^2 was claimed, and the height the baro and the IMU
#: give without the range came out 6.8 cm off the motion capture, where without the claim it is 4.6
WEAK_CORRELATES = ("ground speed^2",)


@dataclass
class Discovery:
    sensor: str
    expression: str  # the regressor, e.g. "lowpass(throttle, 0.5 s)"
    coefficient: float  # in the sensor's units per signal unit
    r2: float  # fraction of the innovation variance it explains
    terms: list[tuple[str, float]]  # all picked (expression, coefficient)
    #: the Ljung-Box p of the normalised innovations, and of them with the held-out fit taken out
    ljung_box_p: tuple[float, float] = (math.nan, math.nan)
    #: the strongest correlate's values [signal units] at every update of the sensor (their times),
    #: for adding it to the model as a regressor (engine); fitted on the scored ones, it acts on all:
    #: held at its first scored value before them, a baro error of 0.07 m per (m/s)^2 of climb left
    #: a take-off at 7 m/s, 4 s into the log, 3.4 m off
    keep_t: np.ndarray | None = field(default=None, repr=False)
    signal: np.ndarray | None = field(default=None, repr=False)


def lowpass(t: np.ndarray, x: np.ndarray, tc: float) -> np.ndarray:
    """``x`` sampled at ``t`` through a first-order low-pass of time constant ``tc`` [s], exact for
    a signal held between samples. (A recursion whose coefficient changes with each step: no
    ``scipy.signal`` filter takes one; on Python floats, not numpy's scalars, for speed.)"""
    y = np.empty_like(x)
    if not len(x):
        return y
    xs, ts = x.tolist(), t.tolist()
    out = [0.0] * len(xs)
    acc = xs[0]
    exp = math.exp
    for i in range(len(xs)):
        if i:
            acc += (xs[i] - acc) * (1.0 - exp(-max(ts[i] - ts[i - 1], 0.0) / tc))
        out[i] = acc
    y[:] = out
    return y


def library(run: Run, sensor: str) -> dict[str, np.ndarray]:
    tr = run.sensors[sensor]
    t = tr.t
    base: dict[str, np.ndarray] = {}
    for k, v in tr.signals.items():
        if k in ("roll", "pitch", "throttle_lp", "ground_speed"):
            continue
        if np.isfinite(v).mean() > 0.9 and np.nanstd(v) > 1e-9:
            base[k] = np.where(np.isfinite(v), v, np.nanmean(v))
    speed = tr.signals.get("ground_speed")
    if speed is not None and np.isfinite(speed).mean() > 0.5:
        # the dynamic pressure of the flight over the ground on a static port, q ~ rho v^2 / 2
        # (ArduPilot's BARO1_WCF_* model it per body axis): before the GNSS has a velocity the vehicle
        # stands on the ground
        v = np.where(np.isfinite(speed), speed, 0.0)
        if np.std(v) > 1e-9:
            base["ground speed"] = v
            base["ground speed^2"] = v**2
    roll, pitch = tr.signals.get("roll"), tr.signals.get("pitch")
    if roll is not None and pitch is not None and np.isfinite(roll).all():
        base["tilt"] = 1.0 / np.maximum(np.cos(roll) * np.cos(pitch), 0.2) - 1.0
    iz = run.model.states.index("z") if "z" in run.model.states else None
    iv = run.model.states.index("vz") if "vz" in run.model.states else None
    if iz is not None:
        base["height"] = np.interp(t, run.t, run.x[:, iz])
    if iv is not None:
        vz = np.interp(t, run.t, run.x[:, iv])
        base["vertical speed"] = vz
        base["vertical speed^2"] = vz**2
        # the dynamic pressure of the climb on a static port, signed: q ~ rho v |v| / 2
        base["vertical speed |vertical speed|"] = vz * np.abs(vz)
    base["time"] = t - t[0]
    lib = dict(base)
    for name, x in base.items():
        if name == "time":
            continue
        for tc in (0.5, 2.0):
            lib[f"lowpass({name}, {tc:g} s)"] = lowpass(t, x, tc)
        for d in (0.1, 0.3):
            lib[f"delay({name}, {d:g} s)"] = np.interp(t - d, t, x)
    return lib


def discover(run: Run, sensor: str, max_terms: int = 3, *, weak: bool = False) -> Discovery | None:
    """The sparse regression's correlate of ``sensor``'s innovations, named when it explains enough of
    them out of sample (the module's docstring). ``weak``: its strongest correlate among
    :data:`WEAK_CORRELATES`, whatever it explains, in or out of sample: a correlate for the filter
    itself to weigh (:func:`~groundstation.diagnosis.claims.discovered.rival_discovery`). The raw innovations show a
    slow error only as the filter fails to follow it: a baro reading high by 0.01 m per (m/s)^2 of
    speed over the ground, which the baro's weight in the height estimate carries along, explained
    6 % of them, while added to the filter it scored Delta BIC -498 (a clean flight: -1.5)."""
    tr = run.sensors[sensor]
    y = tr.nu[:, 0].astype(float)
    keep = tr.t >= tr.t[0] + 5.0
    y = y[keep]
    if len(y) < 50:
        return None
    whole = library(run, sensor)
    # the scored updates' values standardised, a column at a time (the library's scored copies all
    # at once were a sixth of a 1-hour log's diagnosis at its peak)
    spread = {k: float(np.std(v[keep])) for k, v in whole.items()}
    names = [k for k, sd in spread.items() if sd > 1e-12 and (not weak or any(p in k for p in WEAK_CORRELATES))]
    if not names:
        return None
    X = np.empty((int(keep.sum()), len(names)))
    for i, k in enumerate(names):
        v = whole[k][keep]
        X[:, i] = (v - v.mean()) / spread[k]
    n = len(y)
    yc = y - y.mean()
    picked: list[int] = []
    resid = yc.copy()
    bic = n * math.log(np.mean(yc**2) + 1e-300)
    coef = np.zeros(0)
    for _ in range(max_terms):
        j = int(np.argmax(np.abs(X.T @ resid)))
        if j in picked:
            break
        trial = picked + [j]
        c, *_ = np.linalg.lstsq(X[:, trial], yc, rcond=None)
        r = yc - X[:, trial] @ c
        new_bic = n * math.log(np.mean(r**2) + 1e-300) + len(trial) * math.log(n)
        if new_bic > bic - 10.0:  # strong evidence only (Kass & Raftery: Delta BIC > 10)
            break
        picked, coef, resid, bic = trial, c, r, new_bic
    if not picked:
        return None
    terms = [(names[j], float(c / spread[names[j]])) for j, c in zip(picked, coef)]
    # out of sample: each block's innovations predicted by the terms fitted on the other blocks
    fit = held_out_fit(X[:, picked], yc)
    if fit is None:
        if not weak:
            return None
        # the strongest correlate alone, in sample: the filter's own held-out check weighs it
        c1, *_ = np.linalg.lstsq(X[:, picked[:1]], yc, rcond=None)
        fit = X[:, picked[:1]] @ c1
    r2 = 1.0 - float(np.mean((yc - fit) ** 2) / np.mean(yc**2))
    sd = np.sqrt(tr.S[keep, 0, 0])
    q0, q1 = ljung_box_q(y / sd), ljung_box_q((yc - fit) / sd)
    colour = bool(chi2.sf(q0, LAGS) < 0.05 and q1 <= WHITENS * q0)
    if r2 < MIN_R2 and not colour and not weak:
        return None
    return Discovery(
        sensor,
        terms[0][0],
        terms[0][1],
        r2,
        terms,
        (float(chi2.sf(q0, LAGS)), float(chi2.sf(q1, LAGS))),
        keep_t=tr.t,
        signal=whole[terms[0][0]],
    )


#: consecutive time blocks of the held-out fit
BLOCKS = 3


def held_out_fit(X: np.ndarray, y: np.ndarray, blocks: int = BLOCKS) -> np.ndarray | None:
    """Each of ``blocks`` consecutive blocks of ``y`` predicted by least squares on the others (blocked
    cross-validation: the regression is scored on data it was not fitted on). None when, over all
    blocks, the prediction leaves more than it explains (a correlate of one stretch of the log, not
    of the sensor's error), or a block is too short to fit on."""
    n = len(y)
    edges = np.linspace(0, n, blocks + 1).astype(int)
    out = np.empty(n)
    for a, b in zip(edges[:-1], edges[1:]):
        train = np.r_[0:a, b:n]
        if len(train) < X.shape[1] + 10 or b <= a:
            return None
        c, *_ = np.linalg.lstsq(X[train], y[train] - y[train].mean(), rcond=None)
        out[a:b] = X[a:b] @ c + y[train].mean()
    if np.sum((y - out) ** 2) >= np.sum((y - y.mean()) ** 2):
        return None
    return out
