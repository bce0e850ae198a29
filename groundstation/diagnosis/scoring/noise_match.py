"""Noise from the data, before any effect is traced: each sensor's R by covariance matching.

A noise level set wrong (a vehicle file written for another airframe, a default for our
simulator) moves every sensor's NIS off 1, and a diagnosis that trusts the file then reads the
mis-set level as a physical effect: a baro whose noise is 0.12 m, modelled as 0.34 m, hides small
baro effects; modelled as 0.05 m, any slow regressor "explains" the excess.

Mehra's covariance matching (1970): for white measurement noise the innovation covariance is
``S = H P- H' + R``, so ``R = E[nu^2] - E[H P- H']``. That total holds every error the model lacks,
effects included, so it is trusted only to *lower* a level: innovations smaller than the model
expects are no effect's doing. A level is *raised* only to the white part, from the first
differences of consecutive innovations, which a slow error (a temperature, a rotor wash of 0.3 s
against 25 Hz) barely reaches: ``E[(nu_k - nu_(k-1))^2] / 2 = R + E[H P- H']`` for white
innovations. A sensor whose noise is coloured keeps its model's level when the two bracket it
(a Crazyflie's baro: 0.15 m white, 1.5 m in the vehicle file, its slow wander in between; set to
the white part, the slant range's likelihood fell by 350 and it was no longer found). A GPS, whose
slow error is a state of its own, takes the white part. Iterated (the
filter re-run with the new R, :data:`ITERATIONS` times), since P depends on R.

The process noise of the vertical speed (``G_acc``: the accelerometer's noise and what the input
model misses, the attitude's error in the rotation among it) is set by the likelihood
(:func:`match_process_noise`): the model's level is what our simulator's flights need, and another
airframe's IMU, mounting and vibration, or an accelerometer whose bias steps as it warms, needs more.
It is chosen once, for the model after (the effects in it), and the run before takes the same level:
the effects are traced at the model's level. Chosen before them, a rotor wash's baro error the model
lacked drew a level 30-100 times the model's, the wash then read smaller, and the height after it was
twice as far off the truth (another generator's two wash flights: 8.7 and 9.5 cm became 18.0 and
20.7); chosen for the model before on its own, an effect it lacks draws the level up in the same way.
Taken as the model's on another generator's lidar flight with a bias step of 0.3 m/s^2, the height
lagged the lidar by 9 cm for seconds, and came out 2.96 cm off the truth where a plain filter with an
autopilot's default process noise was 1.48 cm off; at the level the likelihood chose, 1.16 cm.
Autocovariance least squares (Odelson, Rajamani and Rawlings 2006) would give the whole Q; one
scale on one state, searched in factors of :data:`PROCESS_STEP`, is what the altitude's innovations
decide well, and a sensor whose matched noise still leaves its NIS far from 1 points at the
dynamics, which the findings then show.

The report lists each sensor's noise from the data beside the model's, and calls out a ratio
outside [1/:data:`DIFFERS`, :data:`DIFFERS`] as a finding of its own.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from groundstation.core.measurement import Measurement
from groundstation.diagnosis.runs.run import SETTLE_S, Prepared, Run, run_model
from groundstation.diagnosis.runs.signature import Probes
from groundstation.diagnosis.scoring.background import Begun
from groundstation.diagnosis.scoring.trials import fork_map
from groundstation.estimation.context import Zero
from groundstation.estimation.models.base import LinearModel

#: scalar sensors whose R is matched (the pseudo-sensor and vector sensors keep theirs)
MATCHED = ("range", "baro", "gps", "gps_vz")
ITERATIONS = 2
#: a level from the data this many times the model's (or less than 1/this) is reported as a finding
DIFFERS = 1.5
#: fewest consecutive innovation pairs a level is matched on
MIN_PAIRS = 100
#: the process noise's search (:func:`match_process_noise`): each trial's level this factor from the
#: last, at most this many trials a direction (3^6 = 729 times the model's, or 1/729 of it)
PROCESS_STEP = 3.0
PROCESS_STEPS = 6
#: Delta BIC a trial must reach against the level before it to be taken: very strong evidence (Kass
#: and Raftery 1995), as an effect's claim (scoring.scored.STRONG)
PROCESS_STRONG = -10.0
#: the state whose process noise is searched, and the name its level is reported under
PROCESS_STATE = "vz"
PROCESS_LEVEL = "acceleration"


@dataclass
class NoiseLevel:
    sensor: str
    sigma_data: float  # [sensor units]
    sigma_model: float  # what the model (or the vehicle file) had
    pairs: int

    @property
    def ratio(self) -> float:
        return self.sigma_data / self.sigma_model if self.sigma_model > 0 else math.inf

    @property
    def differs(self) -> bool:
        return not 1.0 / DIFFERS <= self.ratio <= DIFFERS

    def as_dict(self) -> dict:
        return {
            "sensor": self.sensor,
            "sigma_data": float(f"{self.sigma_data:.3g}"),
            "sigma_model": float(f"{self.sigma_model:.3g}"),
            "pairs": self.pairs,
            "differs": self.differs,
        }


def matched_r(run: Run, sensor: str, R: float, t_from: float, white_only: bool = False) -> tuple[float, int] | None:
    """R from one run's innovations of ``sensor`` (module docstring), and the pairs it used;
    ``white_only``: the white part whatever the rest (a sensor whose slow error is a state)."""
    tr = run.sensors.get(sensor)
    if tr is None or tr.nu.shape[1] != 1:
        return None
    k = tr.t >= t_from
    t, nu, S = tr.t[k], tr.nu[k, 0], tr.S[k, 0, 0]
    if len(t) < MIN_PAIRS + 1:
        return None
    dt = np.diff(t)
    # consecutive updates only: not across a dropout, a gate's gap or the ground
    pair = dt <= 3.0 * float(np.median(dt))
    if pair.sum() < MIN_PAIRS:
        return None
    hph = S - R
    # the white part: from the differences, which a slow error barely reaches
    white = float(np.mean(np.diff(nu)[pair] ** 2 / 2.0 - (hph[1:][pair] + hph[:-1][pair]) / 2.0))
    # everything: the innovations' own variance (white and coloured noise, and any effect)
    total = float(np.mean(nu**2 - hph))
    if white_only:
        return max(white, 0.0), int(pair.sum())
    if white > R:
        return white, int(pair.sum())  # even the white part exceeds the model's: raised to it
    if total < R:
        return max(total, 0.0), int(pair.sum())  # even all of it is below the model's: lowered to it
    return R, int(pair.sum())


def with_r(model: LinearModel, sensor: str, R: float) -> LinearModel:
    meas = {
        key: replace(mm, R=np.array([[R]])) if mm.name == sensor and mm.dim == 1 else mm
        for key, mm in model.measurements.items()
    }
    return replace(model, measurements=meas)


def sensor_r(model: LinearModel, sensor: str) -> float | None:
    mm = next((mm for mm in model.measurements.values() if mm.name == sensor and mm.dim == 1), None)
    return float(np.atleast_2d(mm.R)[0, 0]) if mm is not None else None


def sensor_noise(model: LinearModel) -> dict[str, float]:
    """Each matched sensor's R in ``model`` (:data:`MATCHED`): all that :func:`match_noise` changes."""
    return {s: r for s in MATCHED if (r := sensor_r(model, s)) is not None}


def with_noise(model: LinearModel, noise: dict[str, float]) -> LinearModel:
    """``model`` with each sensor's R from ``noise`` (:func:`sensor_noise`'s)."""
    for s, r in noise.items():
        model = with_r(model, s, r)
    return model


@dataclass(frozen=True)
class MatchedNoise:
    """What makes the declared model the model before, as numbers a process forked before they were
    known can be sent: each sensor's R (:func:`sensor_noise`) and the zeros the runs hold
    (``Prepared.zeros``)."""

    noise: dict[str, float]
    zeros: dict[str, Zero]

    @classmethod
    def of(cls, model0: LinearModel, prep: Prepared) -> MatchedNoise:
        return cls(sensor_noise(model0), dict(prep.zeros))

    def applied(self, declared: LinearModel, prep: Prepared) -> tuple[LinearModel, Prepared]:
        """The model before and the prepared log it runs over."""
        return with_noise(declared, self.noise), replace(prep, zeros=self.zeros)


#: [m] the GPS error's slow part (its Gauss-Markov sigma) is chosen from these by the likelihood
GPS_SLOW = (0.03, 0.1, 0.3, 1.0)
#: [m] a single-frequency receiver's vertical wander, as a model without the log would set it: what
#: the level from the log is reported against
GPS_ERROR_MODEL = 0.5


def with_gps_slow(model: LinearModel, sigma: float) -> LinearModel:
    """The model with its GPS error state's sigma set (``models.altitude.with_gps_error``)."""
    i = model.index("b_gps")
    tau = -1.0 / float(model.A(np.zeros(len(model.inputs)))[i, i])
    Qc, P0 = model.Qc.astype(float).copy(), model.P0.astype(float).copy()
    Qc[i, i], P0[i, i] = 2.0 * sigma**2 / tau, sigma**2
    return replace(model, Qc=Qc, P0=P0)


def match_gps_slow(
    model: LinearModel,
    prep: Prepared,
    make,
    measurements: Sequence[Measurement] | None = None,
    *,
    base: Run,
    workers: int = 1,
) -> tuple[LinearModel, NoiseLevel | None, Run]:
    """The GPS error's slow part by profile likelihood over :data:`GPS_SLOW` (the one noise
    parameter covariance matching cannot reach: a slow error lives in the low frequencies the
    differences drop), with the model's run at it. Only with a GPS error state; ``base`` is the run
    of ``model`` as it is, returned when nothing changes.

    Chosen *after* the effects are traced, not before: a GPS's slow wander and a baro's slow error
    (a temperature, a drift) both live in what the two disagree on, and no sensor tells which one
    moved. Matched first, the GPS's state took the disagreement (a baro reading 0.13 m/K high with
    the temperature rising 7 K gave it 0.3 m), the estimate followed the baro (0.64 m off) and the
    thermal term gained nothing to be claimed with. So the effects are traced against the GPS at
    the floor of its slow error, each on the catalogue's terms (strong, 3 sigma, held out), and what
    they leave is then given to the GPS, at the level the log's likelihood picks. The levels' runs
    on up to ``workers`` processes (:func:`.trials.fork_map`), the same numbers on any number."""
    if "b_gps" not in model.states:
        return model, None, base
    now = _gps_slow_now(model)
    levels = [s for s in GPS_SLOW if not math.isclose(s, now)]
    n = max(1, min(workers, len(levels)))

    def best_of(share: list[float]) -> tuple[dict[float, float], float, Run | None]:
        return _best_of_levels(model, prep, make, measurements, share)

    return _gps_slow_chosen(model, now, base, fork_map(best_of, [levels[k::n] for k in range(n)], n))


def _gps_slow_now(model: LinearModel) -> float:
    i = model.index("b_gps")
    return math.sqrt(float(model.P0[i, i]))


def _best_of_levels(
    model: LinearModel, prep: Prepared, make, measurements: Sequence[Measurement] | None, levels: list[float]
) -> tuple[dict[float, float], float, Run | None]:
    """The model's runs at each of ``levels``: (each one's log-likelihood, the first best, its run without its model,
    as it crosses processes). The best run so far is kept, not all of them (a long log's runs are large)."""
    lik: dict[float, float] = {}
    best, run = math.nan, None
    for s in levels:
        r = run_model(with_gps_slow(model, s), prep, make, measurements=measurements)
        lik[s] = r.loglik
        if run is None or r.loglik > run.loglik:
            best, run = s, r
    return lik, best, (replace(run, model=None) if run is not None else None)  # type: ignore[arg-type]


def _gps_slow_chosen(
    model: LinearModel, now: float, base: Run, shares: list[tuple[dict[float, float], float, Run | None]]
) -> tuple[LinearModel, NoiseLevel, Run]:
    """The first best of :data:`GPS_SLOW` (``base`` at ``now``, the others from the shares' bests, each the
    first best of its own), as one pass over them in order keeps it."""
    lik = {now: base.loglik}
    runs: dict[float, Run] = {}
    for got, s, r in shares:
        lik.update(got)
        if r is not None:
            runs[s] = replace(r, model=with_gps_slow(model, s))
    best = math.nan
    for s in GPS_SLOW:
        if s in lik and (math.isnan(best) or lik[s] > lik[best]):
            best = s
    run = base if math.isclose(best, now) else runs[best]
    n = int(run.sensors["gps"].t.size) if "gps" in run.sensors else 0
    level = NoiseLevel("gps (slow)", best, GPS_ERROR_MODEL, n)
    return (model if math.isclose(best, now) else with_gps_slow(model, best)), level, run


class GpsSlowBefore:
    """:func:`match_gps_slow` of the model before (the run the error "before" is read from), made on the
    cores the search leaves idle. The search reads the model at the floor of the GPS's slow error
    (match_gps_slow says why), so the runs at the other levels are wanted for the report alone.

    Forked held as the diagnosis starts, while its heap holds little more than the log
    (:class:`.background.Begun`, ``processes`` of them, each keeping the best run of its share of the
    levels); :meth:`start` gives them the noise the log shows and the zeros held (numbers);
    :meth:`chosen` is match_gps_slow's answer for the model before, number for number."""

    def __init__(self, declared: LinearModel, prep: Prepared, make, processes: int) -> None:
        self._declared, self._prep, self._make = declared, prep, make
        self._now = _gps_slow_now(declared)
        levels = [s for s in GPS_SLOW if not math.isclose(s, self._now)]
        n = max(1, min(processes, len(levels)))
        self._runs: Begun = Begun(self._best_of, [levels[k::n] for k in range(n)], processes, held=True)

    def _best_of(self, matched: MatchedNoise, levels: list[float]) -> tuple[dict[float, float], float, Run | None]:
        model, prep = matched.applied(self._declared, self._prep)
        return _best_of_levels(model, prep, self._make, None, levels)

    def start(self, model0: LinearModel) -> None:
        """The runs started: ``model0`` is the declared model with each sensor's noise as the log shows it."""
        self._runs.go(MatchedNoise.of(model0, self._prep))

    def chosen(self, model0: LinearModel, base: Run) -> tuple[LinearModel, NoiseLevel, Run]:
        """:func:`match_gps_slow` ``(model0, ..., base=base)``: ``base`` is ``model0``'s own run."""
        return _gps_slow_chosen(model0, self._now, base, self._runs.results())

    def close(self) -> None:
        self._runs.close()


def match_noise(
    model: LinearModel, prep: Prepared, make, probes: Probes | None = None, *, first: Run | None = None
) -> tuple[LinearModel, list[NoiseLevel], Run | None]:
    """The model with each matched sensor's R from the data, the levels found, and the model's run
    when the last iteration changed nothing (that run is the model's own; else None). ``probes``:
    the runs are taped with them, so that run can start a ranking; ``first``: the model's run
    already made (the first iteration's)."""
    original = sensor_noise(model)
    if not original:
        return model, [], first
    pairs: dict[str, int] = {}
    last: Run | None = None
    for i in range(ITERATIONS):
        if i == 0 and first is not None:
            run = first
        else:
            run = run_model(model, prep, make, probes=probes.fresh() if probes is not None else None)
        last = run
        changed = False
        for s in original:
            R = sensor_r(model, s)
            assert R is not None
            # a GPS's slow error is a state of the model (b_gps): its R is the white part alone
            got = matched_r(run, s, R, prep.t0 + SETTLE_S, white_only=s == "gps" and "b_gps" in model.states)
            if got is None:
                continue
            # never below a hundredth of the model's variance: a quantised sensor whose readings do
            # not change between updates has no difference to match on
            r_new, pairs[s] = max(got[0], original[s] * 1e-2), got[1]
            if abs(r_new - R) > 1e-3 * R:
                model, changed = with_r(model, s, r_new), True
        if not changed:
            break
        last = None  # the model moved on from the run
    levels = [
        NoiseLevel(s, math.sqrt(sensor_r(model, s) or 0.0), math.sqrt(original[s]), pairs[s])
        for s in original
        if s in pairs
    ]
    return model, levels, last


def match_process_noise(
    model: LinearModel,
    prep: Prepared,
    make,
    base: Run,
    measurements: Sequence[Measurement] | None = None,
    *,
    workers: int = 1,
) -> tuple[LinearModel, NoiseLevel | None]:
    """The model with the vertical speed's process noise (``Qc[vz, vz]``, the altitude document's
    G_acc of eq. 9.22) the log's innovations choose, and its level; the model unchanged and None
    where no other level is chosen.

    The level is scaled by :data:`PROCESS_STEP` up from the model's, and where the first step up is not
    taken, down, each trial run over the whole log (its scores alone) and taken while its likelihood
    beats the level before it by very strong evidence: Delta BIC = -2 Delta l + ln n <
    :data:`PROCESS_STRONG`, n the updates scored (one parameter, the scale). ``base``: the model's own
    run over ``measurements`` (by default the prepared log's), whose likelihood the first trial must
    beat. With ``workers`` > 1 the first step each way runs at once, and then the next steps two at a
    time (:func:`.trials.fork_map`): the same level on any number. A model without a vertical speed, or
    with none of its process noise, is left as it is."""
    if PROCESS_STATE not in model.states or model.f is not None:
        return model, None
    q0 = float(model.Qc[model.index(PROCESS_STATE), model.index(PROCESS_STATE)])
    if not q0 > 0.0 or base.n_scored < 2:
        return model, None
    penalty = math.log(base.n_scored)
    n = 2 if workers > 1 else 1

    def loglik(scale: float) -> float:
        m = with_process_noise(model, scale)
        return run_model(m, prep, make, measurements=measurements, scores_only=True).loglik

    def taken(new: float, old: float) -> bool:
        return -2.0 * (new - old) + penalty < PROCESS_STRONG

    up, down = PROCESS_STEP, 1.0 / PROCESS_STEP
    first = dict(zip((up, down), fork_map(loglik, [up, down], n))) if n > 1 else {up: loglik(up)}
    if down not in first and not taken(first[up], base.loglik):
        first[down] = loglik(down)
    step = next((k for k in (up, down) if k in first and taken(first[k], base.loglik)), None)
    if step is None:
        return model, None
    scale, ll, k = step, first[step], 1
    while k < PROCESS_STEPS:
        ahead = [scale * step**j for j in range(1, min(n, PROCESS_STEPS - k) + 1)]
        moved = 0
        for trial, got in zip(ahead, fork_map(loglik, ahead, n)):
            if not taken(got, ll):
                break
            scale, ll, moved = trial, got, moved + 1
        k += moved
        if moved < len(ahead):
            break
    level = NoiseLevel(PROCESS_LEVEL, math.sqrt(q0 * scale), math.sqrt(q0), base.n_scored)
    return with_process_noise(model, scale), level


def with_process_noise(model: LinearModel, scale: float) -> LinearModel:
    """``model`` with the vertical speed's process noise ``scale`` times its own."""
    i = model.index(PROCESS_STATE)
    Qc = model.Qc.astype(float).copy()
    Qc[i, i] *= scale
    return replace(model, Qc=Qc)
