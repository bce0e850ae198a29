"""Claims that hold out of sample: blocked cross-validation of a candidate over time.

Delta BIC (:mod:`.trace`) is computed on the data the effect was fitted on. With thousands of
updates, and innovations that are never quite white, it credits an augmented model with any
slight mismatch its extra state can absorb: on a clean flight from a generator that is not ours
an accelerometer scale of -0.0038 +- 0.0034 (1.1 sigma) scored Delta BIC -206. A claim therefore
also needs, for each parameter and over the log cut into :data:`BLOCKS` consecutive time blocks:

1. **size**: the estimate at least :data:`MIN_Z` of its standard error from zero, jointly for an
   effect of several parameters (sqrt of the sum of their z^2; for a delay, the profile
   likelihood's curvature gives the standard error; a flat profile locates nothing), and inside
   the physics' bar where the candidate has one (``Candidate.plausible``: an accelerometer's scale
   within what a MEMS sensitivity can be off, a ground effect that makes the baro read low). An
   accelerometer bias stepping as the IMU warms, which the base model's bias state follows only
   slowly, held out at +1132 as a scale of s = 0.29 on an outdoor flight of another generator,
   and its height after was seven times as far off the truth as before;
2. **held-out gain**: fitted without a block's sensor updates and applied to that block with its
   parameters fixed, the model raises the block's innovation log-likelihood over the model without
   the effect; summed over the blocks, the gain is positive;
3. **no sensor worse**: no sensor's held-out log-likelihood, summed over the blocks, falls by more
   than :data:`SENSOR_TOLERANCE` (a likelihood ratio of e^-2) or, when larger, twice its standard
   error (the per-update differences paired by time: more than chance gives) or a tenth of the
   effect's whole held-out gain (a model that reads one sensor right re-weighs the others);
4. **a delay on its own sensor**: a sensor's delay moves that sensor's readings alone, and the
   others gain only through the height those readings then correct: at least :data:`OWN_SHARE` of
   its held-out gain is on the readings it moves. A delay whose gain is on the others fits something
   they see: an outdoor baro reading high with the airspeed squared took a baro delay of 0.09 s that
   held out +12, +0.6 of it on the baro; lidars made 0.1 s late on indoor flights held out +25 and
   +38, +28 and +27 of it on the lidar;
5. **a delay's evidence at the innovations' effective size**: its Delta BIC with each sensor's gain
   counted at that sensor's effective number of innovations (:func:`.scored.delta_bic_effective`)
   below :data:`~.scored.STRONG`, as counted update by update. A delay shifts a sensor's readings by a
   fraction of a second, and a slow error the model leaves in the innovations lines up with such a
   shift over a whole log: on an outdoor flight of another generator, with the accelerometer's bias
   moving -0.3 m/s^2 as the IMU warmed or stepping -0.2 m/s^2 twice (which the bias state follows
   with a lag), a GPS height delay of 0.29-0.31 s scored Delta BIC -135 update by update, +24 to +29
   at the effective size, held out +6 to +12, and its height after was 3-5 % further off the truth.
   The delays that were there (a baro 0.2 s late, the GPS 0.25 s, a lidar 0.1 s, on the same
   generator's flights) scored -44 to -560 at the effective size.

Each sensor's gain (and its standard error) is counted at its innovations' effective sample size,
as Delta BIC's effective form counts it (:func:`.scored.delta_bic_effective`): divided by the
candidate's run's ``n / n_eff`` for that sensor. A sensor whose innovations carry a slow error the
model leaves in them (a GPS height's wander while the effects are traced at the floor of its slow
error: ``noise_match.match_gps_slow``) gains or loses on a block as the model's height happens to
move with that wander, and every one of its updates says the same thing. Counted update by update,
such a sensor outvotes the ones the effect acts on: a baro made 0.2 s late on an outdoor flight is
fitted at 0.16 s, gains 36 on the baro's held-out blocks and 40 on the receiver's velocity, and loses
98 on GPS heights whose innovations are worth one in eight (the GPS error's wander rising 2.4 m in
30 s through the descent): counted update by update it would be turned away.

How each kind of candidate is fitted without a block:

* a state (an unknown constant, a drift, a coefficient): the augmented filter run with the
  block's sensor updates blind to the added states (Schmidt updates that correct the model's own
  states only, so the height stays tracked through the block) gives the parameters at the end;
  carried back to the log's start through their own dynamics (``expm(-A_ee T)``: the added
  states evolve on their own, they are not driven by the old ones), they are fixed (P0 = 0, no
  process noise) for the run scored on the block;
* a delay or a lag on a grid: the grid value whose runs score best on the other blocks;
* a changed measurement function with nothing to fit (the slant range): the block's gain as it is.

The likelihood is each filter's own one-step prediction (prequential; Dawid 1984), so the held-out
block's innovations are predictions from the past with parameters fitted elsewhere (Arlot and
Celisse 2010 on blocked cross-validation for dependent data). A nonlinear model, rebuilt rather
than augmented (the attitude model), is checked for size only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import expm

from groundstation.core.measurement import Measurement
from groundstation.core.readings import Readings
from groundstation.diagnosis.catalogue.altitude import SENSOR_KINDS, delayed_kinds
from groundstation.diagnosis.runs.run import SETTLE_S, Prepared, Run, run_model
from groundstation.diagnosis.runs.signature import fitted_without, loglik
from groundstation.diagnosis.scoring.gains import Fit
from groundstation.diagnosis.scoring.scored import STRONG
from groundstation.diagnosis.scoring.trials import fork_map, portable
from groundstation.estimation.models.base import LinearModel, MeasurementModel
from groundstation.estimation.models.ground import LANDED

#: time blocks of the scored window
BLOCKS = 3
#: a parameter is claimed only this many standard errors from zero
MIN_Z = 3.0
#: [log-likelihood] the most a sensor's held-out innovations may lose with the effect added, or
#: :data:`SENSOR_SE` standard errors of that loss (paired per update) when that is more
SENSOR_TOLERANCE = 2.0
SENSOR_SE = 2.0
#: ... or this share of the effect's whole held-out gain: a model that reads one sensor right
#: re-weighs the others, and a slant range that gained 61 on a Crazyflie's ToF gave 3.7 of it back
#: on the baro, a real effect (the data README's) turned away by a trade of 6 %
SENSOR_SHARE = 0.1
#: the least share of a sensor's delay's held-out gain on that sensor's own readings (rule 4): a
#: quarter, between the 5 % of a baro delay that fitted an airspeed error and the 49-70 % of real
#: delays (a baro 0.15 s late outdoors, where a better height gains on the GPS's heights and
#: velocity as much as on the baro; lidars late indoors), a factor of two or more from each
OWN_SHARE = 0.25


@dataclass
class Holdout:
    """The out-of-sample evidence of one candidate."""

    z: dict[str, float] = field(default_factory=dict)  # parameter -> |estimate| / sigma
    gain_by_block: list[float] = field(default_factory=list)  # held-out log-likelihood gain per block
    gain_by_sensor: dict[str, float] = field(default_factory=dict)  # summed over the blocks
    reason: str | None = None  # why it is not claimed; None: it holds
    #: the reason is the physics' bar (``Candidate.plausible``): the fit is no such effect at its size
    implausible: bool = False

    @property
    def holds(self) -> bool:
        return self.reason is None

    @property
    def gain(self) -> float:
        return float(sum(self.gain_by_block))

    def as_dict(self) -> dict:
        return {
            "z": {k: round(v, 1) for k, v in self.z.items()},
            "held_out_gain": round(self.gain, 1),
            "held_out_gain_by_block": [round(g, 1) for g in self.gain_by_block],
            "held_out_gain_by_sensor": {k: round(v, 1) for k, v in self.gain_by_sensor.items()},
            **({"implausible": True} if self.implausible else {}),
        }


def blocks(prep: Prepared, k: int = BLOCKS) -> list[tuple[float, float]]:
    """``k`` consecutive equal blocks of the scored window (from SETTLE_S in to the end)."""
    edges = np.linspace(prep.t0 + SETTLE_S, prep.t1 + 1e-9, k + 1)
    return [(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:])]


def window_loglik(run: Run, lo: float, hi: float) -> dict[str, float]:
    """Each sensor's innovation log-likelihood over ``lo <= t < hi`` (the pseudo-sensor excluded)."""
    out = {}
    for s, tr in run.sensors.items():
        if s == LANDED:
            continue
        k = (tr.t >= lo) & (tr.t < hi)
        if not k.any():
            continue
        out[s] = float(np.sum(tr.loglik[k]))
    return out


def sizes(params: dict, delay: bool, fitted: tuple[str, ...] = ()) -> tuple[dict[str, float], str | None]:
    """Each parameter's |estimate| / sigma, and the reason it is too small to claim (or None); ``fitted``: the
    parameters that count (``Candidate.fitted``; empty: all), the others one of them in another unit."""
    z = {}
    for key, v in params.items():
        if key.startswith("sigma_") or not isinstance(v, (int, float)) or isinstance(v, bool):
            continue
        s = params.get(f"sigma_{key}")
        if isinstance(s, (int, float)) and math.isfinite(s) and s > 0:
            z[key] = abs(float(v)) / float(s)
        elif delay:
            return z, f"{key} = {v:.3g} is not located: its likelihood profile is flat"
    # jointly for an effect of several parameters (a gyro bias on two axes, one of them zero): the
    # Wald statistic's root, sqrt(sum z^2), against the same bar; a parameter restated in another unit
    # counted once (a wash's k_tw and k, one state, made 2.3 sigma each 3.3 together)
    counted = {q: v for q, v in z.items() if not fitted or q in fitted}
    joint = math.sqrt(sum(v * v for v in counted.values()))
    if counted and joint < MIN_Z:
        k = max(counted, key=lambda q: counted[q])
        if len(counted) == 1:
            return z, f"{k} = {params[k]:.3g} is {z[k]:.1f} sigma from zero (a claim needs {MIN_Z:.0f})"
        return z, f"its parameters are {joint:.1f} sigma from zero together (a claim needs {MIN_Z:.0f})"
    return z, None


def fixed(model: LinearModel, n0: int, theta_start: np.ndarray) -> LinearModel:
    """``model`` with its states from ``n0`` on fixed at ``theta_start`` (at the log's start)."""
    x0 = model.x0.astype(float).copy()
    x0[n0:] = theta_start
    P0 = model.P0.astype(float).copy()
    P0[n0:, :] = 0.0
    P0[:, n0:] = 0.0
    Qc = model.Qc.astype(float).copy()
    Qc[n0:, :] = 0.0
    Qc[:, n0:] = 0.0
    return replace(model, x0=x0, P0=P0, Qc=Qc)


class _BlindIn:
    """A sensor's measurement model whose updates within [lo, hi) correct only the first ``n0`` states
    (a Schmidt update, ``MeasurementModel.corrects``): the block's readings keep the height tracked
    and tell the effect's states nothing. Everything else is the model's own."""

    def __init__(self, mm: MeasurementModel, n0: int, lo: float, hi: float) -> None:
        self._mm, self._lo, self._hi = mm, lo, hi
        own = range(n0) if mm.corrects is None else [i for i in mm.corrects if i < n0]
        self._blind = tuple(own)
        self._inside = False

    def __getattr__(self, name: str):
        return getattr(self._mm, name)

    def extract(self, m, ctx):
        self._inside = self._lo <= m.t < self._hi
        return self._mm.extract(m, ctx)

    @property
    def corrects(self):
        return self._blind if self._inside else self._mm.corrects


def _blinded(model: LinearModel, n0: int, lo: float, hi: float, kinds: set) -> LinearModel:
    """``model`` fitted without the block [lo, hi): its sensors' updates there leave the added states
    (from ``n0`` on) alone. Removed outright instead, the block's readings left the height to the
    accelerometer for a third of the flight, and the effect's states took the transient back."""
    meas = {k: _BlindIn(mm, n0, lo, hi) if mm.kind in kinds else mm for k, mm in model.measurements.items()}
    return replace(model, measurements=meas)  # type: ignore[arg-type]


def effective_weights(run: Run) -> dict[str, float]:
    """Each sensor's weight in a held-out gain: ``n_eff / n`` of its innovations in ``run`` (at most 1;
    module docstring)."""
    return {s: 1.0 / max(v, 1.0) for s, v in run.inflation.items()}


def _gains(run: Run, base: Run, lo: float, hi: float, w: dict[str, float]) -> dict[str, float]:
    a, b = window_loglik(run, lo, hi), window_loglik(base, lo, hi)
    # sorted: the same report every run
    return {s: w.get(s, 1.0) * (a.get(s, 0.0) - b.get(s, 0.0)) for s in sorted(set(a) | set(b))}


def _weighted(ll: dict[str, float], w: dict[str, float]) -> float:
    return sum(w.get(s, 1.0) * v for s, v in ll.items())


def paired_se(runs: list[tuple[Run, float, float]], base: Run, sensor: str) -> float:
    """The standard error of a sensor's held-out gain: the spread of the per-update log-likelihood
    differences (the same updates in both runs, paired by time) over the held-out windows."""
    diffs = []
    for run, lo, hi in runs:
        if sensor not in run.sensors or sensor not in base.sensors:
            continue
        ta, la = run.sensors[sensor].t, run.sensors[sensor].loglik
        tb, lb = base.sensors[sensor].t, base.sensors[sensor].loglik
        _, i, j = np.intersect1d(ta, tb, return_indices=True)
        k = (ta[i] >= lo) & (ta[i] < hi)
        diffs.append(la[i][k] - lb[j][k])
    d = np.concatenate(diffs) if diffs else np.zeros(0)
    return float(np.std(d) * math.sqrt(len(d))) if len(d) > 1 else 0.0


def carried_back(model: LinearModel, n0: int, run: Run, t0: float) -> np.ndarray:
    """The added states' (from ``n0`` on) estimate at the end of ``run``, carried back to ``t0``
    through their own dynamics (``expm(-A_ee T)``: they are not driven by the model's own states)."""
    a_ee = model.A(np.zeros(len(model.inputs)))[n0:, n0:]
    return expm(-a_ee * (run.t[-1] - t0)) @ run.x[-1, n0:]


def _held_out(
    aug: LinearModel, n0: int, block: tuple[float, float], prep: Prepared, make, ms: Sequence[Measurement]
) -> Run | str | None:
    """The augmented model fitted without ``block``'s sensor updates, its added states (from ``n0``
    on) carried back to the log's start and fixed there, and run again: the run scored on the block
    (without its model: it may have crossed processes); the reason when that fails; None when
    nothing was left to fit on. Each run stops where nothing after it counts, the filter being
    causal: the fit of the last block at its start (blind from there on, the added states only
    follow their own dynamics, which the carrying back undoes), the scored run at the block's end."""
    lo, hi = block
    fit_on = ms if hi <= prep.t1 else Readings.of(ms).before(lo)
    train = run_model(_blinded(aug, n0, lo, hi, set().union(*SENSOR_KINDS.values())), prep, make, measurements=fit_on)
    if not len(train.t):
        return None
    theta = carried_back(aug, n0, train, prep.t0)
    if not np.all(np.isfinite(theta)):
        return "its parameters ran away when fitted without a block"
    try:
        return portable(run_model(fixed(aug, n0, theta), prep, make, measurements=Readings.of(ms).before(hi)))
    except np.linalg.LinAlgError:
        return "its filter diverged with the parameters fitted without a block"


def two_stage_blocks(f: Fit, prep: Prepared) -> tuple[list[dict[str, float]], dict[str, float]]:
    """The held-out gains of a candidate the two-stage filter fitted (:mod:`~groundstation.diagnosis.runs.signature`):
    for each block, theta fitted on every sensor update outside it (the base filter saw them all), then the block's
    innovations with theta fixed there, ``nu - G theta`` at the base filter's S, against the base's. Per block the gain
    by sensor; and each sensor's standard error of its summed gain (the per-update differences' spread)."""
    sig = f.sig
    G = sig.G_of(f.J)
    per_block: list[dict[str, float]] = []
    diffs: dict[str, list[np.ndarray]] = {}
    for lo, hi in blocks(prep):
        inside = (sig.t >= lo) & (sig.t < hi)
        theta = fitted_without(sig, f.J, f.prior, sig.informs & ~inside)
        d = loglik(sig.nu - G @ theta, sig.S) - loglik(sig.nu, sig.S)
        k = inside & sig.informs
        gains = {}
        for s in np.unique(sig.sensor[k]):
            ds = d[k & (sig.sensor == s)]
            gains[str(s)] = float(ds.sum())
            diffs.setdefault(str(s), []).append(ds)
        per_block.append(gains)
    se = {}
    for s, parts in diffs.items():
        d = np.concatenate(parts)
        se[s] = float(np.std(d) * math.sqrt(len(d))) if len(d) > 1 else 0.0
    return per_block, se


def check(
    cand,
    aug: LinearModel,
    run: Run,
    params: dict,
    base_model: LinearModel,
    base: Run,
    prep: Prepared,
    make,
    ms: Sequence[Measurement],
    profile: dict[float, Run] | None = None,
    *,
    workers: int = 1,
    fit: Fit | None = None,
    delta_bic_effective: float = math.nan,
) -> Holdout:
    """The candidate's out-of-sample evidence (module docstring); ``profile``: a grid candidate's
    runs by grid value; ``fit``: the two-stage filter's fit of a linear candidate, whose held-out
    blocks are then sums over the others (:func:`two_stage_blocks`), exactly what fitted runs give
    where the filter's gains do not depend on the data. Otherwise a fitted effect's blocks are
    fitted on up to ``workers`` processes. ``delta_bic_effective``: the candidate's Delta BIC at its
    innovations' effective size (rule 5; NaN where it was not computed)."""
    z, reason = sizes(params, bool(cand.delays), cand.fitted)
    implausible = False
    if reason is None and cand.plausible is not None:
        reason = cand.plausible(params)
        implausible = reason is not None
    if reason is None and cand.delays and delta_bic_effective >= STRONG:
        reason = (
            f"at its innovations' effective size its Delta BIC is {delta_bic_effective:+.1f}, not very strong "
            "evidence: a slow error the model leaves in them lines up with the shift"
        )
    h = Holdout(z=z, reason=reason, implausible=implausible)
    if reason is not None:
        return h
    if aug.f is not None:  # a rebuilt nonlinear model: size only
        return h
    per_block: list[dict[str, float]] = []
    held_runs: list[tuple[Run, float, float]] = []
    se: dict[str, float] | None = None
    w = effective_weights(run)
    if fit is not None and fit.exact:
        per_block, se = two_stage_blocks(fit, prep)
        per_block = [{s: w.get(s, 1.0) * v for s, v in g.items()} for g in per_block]
        se = {s: w.get(s, 1.0) * v for s, v in se.items()}
    elif cand.delays and profile:
        for lo, hi in blocks(prep):
            others = [(a, b) for a, b in blocks(prep) if (a, b) != (lo, hi)]
            best = max(profile, key=lambda d: sum(_weighted(window_loglik(profile[d], a, b), w) for a, b in others))
            per_block.append(_gains(profile[best], base, lo, hi, w))
            held_runs.append((profile[best], lo, hi))
    elif aug.n == base_model.n:  # nothing fitted (a changed measurement function)
        for lo, hi in blocks(prep):
            per_block.append(_gains(run, base, lo, hi, w))
            held_runs.append((run, lo, hi))
    else:
        n0 = base_model.n

        def held_out(block: tuple[float, float]) -> Run | str | None:
            return _held_out(aug, n0, block, prep, make, ms)

        for (lo, hi), held in zip(blocks(prep), fork_map(held_out, blocks(prep), workers)):
            if isinstance(held, str):
                h.reason = held
                return h
            if held is not None:
                per_block.append(_gains(held, base, lo, hi, w))
                held_runs.append((held, lo, hi))
    h.gain_by_block = [sum(g.values()) for g in per_block]
    for g in per_block:
        for s, v in g.items():
            h.gain_by_sensor[s] = h.gain_by_sensor.get(s, 0.0) + v
    if not per_block:
        h.reason = "no block to hold out"
    elif h.gain <= 0.0:
        h.reason = f"on data it was not fitted on it loses {-h.gain:.1f} in log-likelihood"
    else:
        worse = {
            s: v
            for s, v in h.gain_by_sensor.items()
            if v
            < -max(
                SENSOR_TOLERANCE,
                SENSOR_SE * (se.get(s, 0.0) if se is not None else w.get(s, 1.0) * paired_se(held_runs, base, s)),
                SENSOR_SHARE * h.gain,
            )
        }
        if worse:
            s = min(worse, key=lambda k: worse[k])
            h.reason = f"it makes the {s}'s held-out innovations worse ({worse[s]:+.1f} in log-likelihood)"
        elif cand.delays and cand.reshape is None and cand.sensor:
            h.reason = _not_on_own_sensor(cand, base_model, h)
    return h


def _not_on_own_sensor(cand, model: LinearModel, h: Holdout) -> str | None:
    """Why a sensor's delay does not hold out on the readings it moves (rule 4), or None: their
    held-out gain, summed over the measurements of the kinds it shifts, against the whole gain."""
    kinds = delayed_kinds(cand)
    own = {name for name, mm in model.measurements.items() if mm.kind in kinds}
    gain = sum(v for s, v in h.gain_by_sensor.items() if s in own)
    if gain >= OWN_SHARE * h.gain:
        return None
    return (
        f"its held-out gain is not on the {cand.sensor}'s readings it moves ({gain:+.1f} of {h.gain:+.1f}; "
        f"a delay needs {OWN_SHARE:.0%} there)"
    )
