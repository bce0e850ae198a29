"""A candidate as its scores (:class:`Scored`): its Delta BIC, at the innovations' effective sample
size too, its gain per update it can act on, and whether that claims it (very strong evidence, and
material); and the smallest size of it a log would claim (:func:`smallest_claimed`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from groundstation.core.measurement import Measurement
from groundstation.diagnosis.catalogue.candidate import Candidate
from groundstation.diagnosis.runs.run import Run, ending
from groundstation.diagnosis.scoring.gains import (
    Fit,
)
from groundstation.estimation.models.base import LinearModel

STRONG = -10.0  # Delta BIC: very strong evidence (Kass & Raftery 1995)


#: and material: the log-likelihood gain per innovation of the sensor it acts on (a
#: mean-NIS change of about 4 %; for an effect on the input, of the sensor that gains most),
#: counted over the updates it can act on (a candidate's ``support``, or its signature's:
#: :func:`signature_support`, which also counts a delay's: a late reading differs only while
#: what it measures changes).
#: With thousands of updates BIC alone picks up every slight mismatch between the model and
#: the world: a clean simulated flight "had" 0.08 m of baro_thrust (1/40 of a realistic one)
#: at Delta BIC = -28.
MATERIAL = 0.02


#: the fewest updates a gain is spread over (a candidate's ``support``): ~2 s of baro and range
MIN_SUPPORT = 150


@dataclass
class Scored:
    candidate: Candidate
    model: LinearModel
    run: Run
    delta_bic: float
    params: dict
    measurements: Sequence[Measurement] = ()  # the (shifted) stream, for delays

    gain_per_update: float = 0.0
    support: int = 0  # the updates its gain is spread over
    #: a grid candidate's runs by grid value (a delay's profile), for its held-out evidence (holdout.py)
    profile: dict = field(default_factory=dict)
    n: int = 1  # the innovations its Delta BIC counts
    delta_bic_effective: float = math.nan
    #: scored by the two-stage filter through the base run's gains (its run is that filter's)
    fit: Fit | None = None
    #: only its linear stand-in was scored (``Candidate.screen``), and it could not be claimed
    screened: bool = False

    @property
    def name(self) -> str:
        return self.candidate.name

    @property
    def accepted(self) -> bool:
        return not self.screened and self.delta_bic < STRONG and self.gain_per_update >= MATERIAL

    def end(self) -> None:
        """Kept as its scores and where its run ended (:func:`~groundstation.diagnosis.runs.run.ending`): its
        trajectory, tape, fit and profile let go of. What a candidate that is not added is read for afterwards."""
        self.run, self.fit, self.profile = ending(self.run), None, {}


def delta_bic_effective(aug: Run, base: Run, k: int, n: int) -> float:
    """Delta BIC with each sensor's log-likelihood gain discounted by the colour of the
    augmented run's innovations (module docstring); reported beside the white-noise one."""
    gain = sum(
        (aug.loglik_by.get(s, 0.0) - base.loglik_by.get(s, 0.0)) / max(aug.inflation.get(s, 1.0), 1.0)
        for s in sorted(set(aug.loglik_by) | set(base.loglik_by))  # sorted: the same sum every run
    )
    return -2.0 * gain + k * math.log(n)


def scored(cand: Candidate, model: LinearModel, r: Run, base: Run, n: int, params: dict, ms) -> Scored:
    """The candidate's run ``r`` against the base run: Delta BIC on white innovations and at
    their effective size (module docstring)."""
    dbic = -2.0 * (r.loglik - base.loglik) + cand.k * math.log(n)
    return Scored(cand, model, r, dbic, params, ms, n=n, delta_bic_effective=delta_bic_effective(r, base, cand.k, n))


def profile_sigma(lik: dict[float, float], best: float, step: float) -> float:
    """The standard error of a profiled parameter (a delay), from the curvature of its
    log-likelihood at the best value: sigma = (-d2l/dd2)^-1/2, the least-squares parabola through
    the points within one grid ``step`` of the best (three at least, the nearest). Not from the
    best point's nearest neighbours alone: the refinement can put them 0.1 ms apart, where the
    likelihood steps as readings cross the IMU's 10 ms blocks. On the standard flight the range
    delay's profile is a parabola to 3 % out to 0.04 s. inf when it is flat or not concave."""
    xs = sorted(lik, key=lambda v: abs(v - best))
    near = [v for v in xs if abs(v - best) <= step + 1e-9]
    x = np.array(near if len(near) >= 3 else xs[:3])
    if len(x) < 3:
        return math.inf
    a = np.polyfit(x - best, [lik[v] for v in x], 2)[0]
    return 1.0 / math.sqrt(-2.0 * a) if a < 0 else math.inf


def smallest_claimed(s: Scored) -> dict[str, float]:
    """For each of the candidate's fitted parameters, the size this log would claim it at about
    half the time: a true theta gains about (theta / sigma)^2 / 2 in log-likelihood (sigma its
    estimate's, from the candidate's own filter, which does not depend on theta for these linear
    states), and a claim needs Delta BIC < STRONG and the gain MATERIAL per supported update:

        theta_50 = sigma sqrt(2 max((k ln n - STRONG) / 2, MATERIAL support))

    What "nothing claimed" means on this log, in each effect's own unit."""
    need = max((s.candidate.k * math.log(max(s.n, 1)) - STRONG) / 2.0, MATERIAL * s.support)
    z = math.sqrt(2.0 * need)
    if s.candidate.limit:
        return s.candidate.limit(s.run, z)
    return {
        k[len("sigma_") :]: float(v) * z
        for k, v in s.params.items()
        if k.startswith("sigma_") and isinstance(v, float) and math.isfinite(v)
    }
