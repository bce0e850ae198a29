"""The catalogue through the base filter's gains: each candidate scored by the two-stage filter.

:mod:`~groundstation.diagnosis.runs.signature` gives, from one taped run of the base model, every linear candidate's
augmented filter as sums over time. This module turns that into what the trace and the hold-out read: a candidate's run
(:func:`virtual_run`, a :class:`.Run` like any other: innovations per sensor, its likelihood, the estimate with the
effect's states appended), its best shape (a wash's time constant profiled over a grid of them, all in the same pass),
and for an effect not linear in its parameters, whether its linear stand-in (``Candidate.screen``) could be claimed at
all, which decides whether its own runs are made.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from groundstation.diagnosis.catalogue.candidate import Candidate
from groundstation.diagnosis.runs.run import SETTLE_S, Prepared, Run, SensorTrace, run_model
from groundstation.diagnosis.runs.signature import Column, Probes, Signatures, TwoStage, loglik, signatures, two_stage
from groundstation.estimation.models.base import LinearModel
from groundstation.estimation.models.ground import LANDED
from groundstation.estimation.whiteness import effective_size

#: [s] the rotor wash's time constants profiled at once (a candidate with ``refine_shape``): from a
#: twentieth of a second to about two, each 1.5 times the one before; the profile's parabola through
#: the best and its neighbours (in log tau) places the shape between them. The grid ends where a
#: rotor's wake settling at the static port does (altitude.WASH_TCS: a tenth of a second to a couple
#: of seconds): slower, the term fits the slow wander a GPS and a baro share outdoors. With time
#: constants to 4.3 s, a wash of 0.3 m per unit thrust over the weight (0.35 s) added to an outdoor
#: flight was fitted at 4.3 s and 1.06 m, lost on its held-out blocks and was not named (27.9 cm);
#: to 1.9 s it is named and leaves 4.9 cm
WASH_GRID = tuple(round(0.05 * 1.5**k, 4) for k in range(10))
#: a stand-in's gain (its best fit's) counted at this share of what a claim needs before the effect's
#: own runs are made: it is linear in the effect only to first order
SCREEN_SHARE = 0.5


def grid(c: Candidate) -> tuple:
    """The shapes a candidate's columns are probed at (``(None,)``: it has none)."""
    if c.refine_shape:
        return WASH_GRID
    return c.shapes or (None,)


@dataclass
class CatalogueColumns:
    """The columns of every candidate of a catalogue (each shape of it, its screen), built once for
    the model they act on: what a run that may become a ranking's base is probed with."""

    by_candidate: dict[int, dict] = field(default_factory=dict)  # id(candidate) -> {shape: [Column]}
    screens: dict[int, list[list[Column]]] = field(default_factory=dict)  # id(candidate) -> its probed stand-ins

    @classmethod
    def of(cls, cands: Sequence[Candidate], model: LinearModel) -> CatalogueColumns:
        out = cls()
        for c in cands:
            out.add(c, model)
        return out

    def add(self, c: Candidate, model: LinearModel) -> None:
        if c.columns is not None and id(c) not in self.by_candidate:
            self.by_candidate[id(c)] = {s: (c.columns(model) if s is None else c.columns(model, s)) for s in grid(c)}
        if c.screen is not None and id(c) not in self.screens:
            self.screens[id(c)] = c.screen(model, None)

    def all(self) -> list[Column]:
        out = [col for shapes in self.by_candidate.values() for cols in shapes.values() for col in cols]
        return out + [col for stand_ins in self.screens.values() for cols in stand_ins for col in cols]

    def probes(self) -> Probes:
        return Probes([c for c in self.all() if c.regressor is not None])

    def extra(self) -> list[Column]:
        """The columns read off a run afterwards (of time, on the input)."""
        return [c for c in self.all() if c.regressor is None]


def run_signatures(
    run: Run, n: int, columns: Sequence[Column], *, probed: bool = True, delta: Sequence[int] | None = None
) -> Signatures | None:
    """The signatures through ``run``'s gains (``run`` taped) of ``columns`` and, with ``probed``,
    of the regressor columns the run was probed with; None where the two-stage filter does not
    apply (no tape, a vector reading). ``delta``: the columns whose Delta is kept now (None: all;
    :meth:`.Signatures.keep` computes others when they are wanted)."""
    tp = run.taped
    if tp is None or not tp.scalar:
        return None
    informs = tp.sensor != LANDED
    probes = tp.probes if probed else None
    return signatures(tp.tape, n, tp.t, tp.sensor, tp.nu, tp.S, informs, probes, columns, delta)


def sensor_scores(sensors: dict[str, SensorTrace], t_score: float) -> tuple[dict[str, float], dict[str, float], int]:
    """Each real sensor's innovation log-likelihood from ``t_score`` on, its innovations' colour
    (n / n_eff) and the count of updates scored: what :func:`~groundstation.diagnosis.runs.run.run_model` scores."""
    ll_by, inflation, n = {}, {}, 0
    for s, tr in sensors.items():
        scored = tr.t >= t_score
        if scored.any() and s != LANDED:
            ll_by[s] = float(np.sum(tr.loglik[scored]))
            inflation[s] = int(scored.sum()) / max(effective_size(tr.nu_normalised[scored]), 1.0)
            n += int(scored.sum())
    return ll_by, inflation, n


def virtual_run(aug: LinearModel, base: Run, sig: Signatures, J: Sequence[int], ts: TwoStage, t_score: float) -> Run:
    """The augmented model's run as the two-stage filter gives it (:mod:`~groundstation.diagnosis.runs.signature`): the
    base run's readings with the augmented innovations, and its estimate ``x + Delta theta`` with theta's states
    appended (their covariance, and the cross terms, as the augmented filter has them). The covariance is computed when
    it is read (``Run.P``): a ranking reads most candidates' final row alone (``Run.final``), and all of it, (N, n + p,
    n + p), only for the effects added."""
    assert base.taped is not None
    rows = base.taped.x_record
    J = list(J)
    # the effect's states at each time from their values at the filter's start (a drift's error grows
    # with its rate: b(t) = b0 + rate (t - t_start)); constants stay as they are
    n0 = base.x.shape[1]
    a_ee = aug.A(np.zeros(len(aug.inputs)))[n0:, n0:]
    own_dynamics = bool(np.any(a_ee))
    if own_dynamics and np.any(a_ee @ a_ee):
        raise ValueError(f"{aug.name}: the two-stage filter carries an effect's own dynamics only when nilpotent")

    def at(k: slice) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """Rows ``k``: Delta of the effect's columns (k, n, p), theta, Sigma, and Psi (theta from the
        filter's start to then) where the effect has dynamics of its own."""
        r = rows[k]
        Psi = None
        if own_dynamics:
            tau = sig.t[r] - sig.t_start[r]
            Psi = np.eye(len(J))[None] + a_ee[None] * tau[:, None, None]
        return sig.columns_at(r, J), ts.theta[r], ts.Sigma[r], Psi

    def covariance(k: slice) -> np.ndarray:
        D, _, Sg, Psi = at(k)
        DS = np.einsum("kij,kjl->kil", D, Sg)
        top = base.P_rows(k) + np.einsum("kil,kml->kim", DS, D)
        if Psi is not None:
            DS = np.einsum("kil,kml->kim", DS, Psi)
            Sg = np.einsum("kij,kjl,kml->kim", Psi, Sg, Psi)
        return np.concatenate(
            [np.concatenate([top, DS], axis=2), np.concatenate([np.transpose(DS, (0, 2, 1)), Sg], axis=2)], axis=1
        )

    D, th, _, Psi = at(slice(None))
    x_own = base.x + np.einsum("kij,kj->ki", D, th)
    if Psi is not None:
        th = np.einsum("kij,kj->ki", Psi, th)
    x = np.concatenate([x_own, th], axis=1)
    del D
    sensors = {}
    for s, tr in base.sensors.items():
        idx = np.flatnonzero(sig.sensor == s)
        if s == LANDED or len(idx) != len(tr.t):
            sensors[s] = tr
            continue
        nu, S = ts.nu[idx], ts.S[idx]
        sensors[s] = SensorTrace(tr.t, nu[:, None], S[:, None, None], nu * nu / S, tr.z, tr.signals)
    ll_by, inflation, n = sensor_scores(sensors, t_score)
    return Run(
        aug, sensors, base.t, x, covariance, sum(ll_by.values()), n, base.ctx, ll_by, inflation, through_gains=True
    )


@dataclass
class Fit:
    """A candidate fitted by the two-stage filter: its columns in the signatures, their priors, the
    shape, the filter, and whether it is exact (no regressor reads the estimate)."""

    sig: Signatures
    J: list[int]
    prior: np.ndarray
    shape: float | None
    ts: TwoStage
    exact: bool

    def gain(self, t_score: float) -> float:
        """The augmented filter's log-likelihood gain over the base's from ``t_score`` on."""
        k = self.sig.informs & (self.sig.t >= t_score)
        return float(np.sum(loglik(self.ts.nu[k], self.ts.S[k]) - loglik(self.sig.nu[k], self.sig.S[k])))

    def best_fit_gain(self, t_score: float, at_least: float | None = None) -> float:
        """The gain at theta's best value for the whole log, fixed (the generalised likelihood ratio:
        no prior, no learning): at least the gain at any other fixed theta, which bounds a stand-in's.
        ``at_least`` (one column): the best over the values theta can physically take, theta >= it
        (the likelihood is concave in theta, so a best fit below it gives way to it)."""
        k = self.sig.informs & (self.sig.t >= t_score)
        G = self.sig.G_of(self.J)
        w = np.where(self.sig.informs, 1.0 / self.sig.S, 0.0)
        A = (G * w[:, None]).T @ G
        b = (G * w[:, None]).T @ self.sig.nu
        theta = np.linalg.lstsq(A, b, rcond=None)[0]
        if at_least is not None and len(theta) == 1:
            theta = np.maximum(theta, at_least)
        nu = self.sig.nu - G @ theta
        return float(np.sum(loglik(nu[k], self.sig.S[k]) - loglik(self.sig.nu[k], self.sig.S[k])))


def fit(sig: Signatures, columns: Sequence[Column], shape: float | None = None) -> Fit:
    J = sig.where(columns)
    prior = np.array([c.prior for c in columns], dtype=float)
    return Fit(sig, J, prior, shape, two_stage(sig, J, prior), all(c.exact for c in columns))


def best_shape(fits: dict, t_score: float, log_refine: bool) -> tuple[Fit, float | None]:
    """The shape whose fit gains most, and with ``log_refine`` (a continuous shape on a log grid) the
    vertex of the parabola through it and its neighbours in log(shape) where that lies between
    them: the value a run is then made at."""
    gains = {s: f.gain(t_score) for s, f in fits.items()}
    best = max(gains, key=lambda s: gains[s])
    if not log_refine or best is None:
        return fits[best], best
    shapes = sorted(gains)
    i = shapes.index(best)
    if i == 0 or i == len(shapes) - 1:
        return fits[best], best
    x = np.log(shapes[i - 1 : i + 2])
    y = np.array([gains[s] for s in shapes[i - 1 : i + 2]])
    a, b, _ = np.polyfit(x - x[1], y, 2)
    if a >= 0:
        return fits[best], best
    v = x[1] - b / (2 * a)
    return fits[best], round(float(math.exp(min(max(v, x[0]), x[2]))), 4)


def materially_worth(gain: float, k: int, n: int, support: int, strong: float, material: float) -> bool:
    """A gain a claim could be made on: Delta BIC below ``strong`` and ``material`` per update."""
    return -2.0 * gain + k * math.log(max(n, 1)) < strong and gain >= material * max(support, 1)


def participation(G: np.ndarray, S: np.ndarray) -> int:
    """(sum w)^2 / sum w^2 of w = G^2 / S: over how many updates a signature spreads
    (:func:`.trace.signature_support`, from the signature itself instead of a run at a small size)."""
    w = G * G / S
    sq = float(np.sum(w * w))
    return int(round(float(np.sum(w)) ** 2 / sq)) if sq > 0 else len(w)


def scored_window(sig: Signatures, t0: float) -> np.ndarray:
    return sig.informs & (sig.t >= t0 + SETTLE_S)


def profile_shape(c: Candidate, without: LinearModel, prep: Prepared, make, ms) -> float | None:
    """A continuous shape's best value (a wash's time constant, :data:`WASH_GRID`) for candidate ``c``
    added to ``without`` (a model with every other effect), by the two-stage filter through one taped
    run of ``without``; None where that filter does not apply."""
    assert c.columns is not None
    shapes = {s: c.columns(without, s) for s in WASH_GRID}
    r = run_model(without, prep, make, measurements=ms, probes=Probes([col for cs in shapes.values() for col in cs]))
    sig = run_signatures(r, without.n, [], delta=())  # the shapes' fits read G alone
    if sig is None:
        return None
    fits = {s: fit(sig, cols, s) for s, cols in shapes.items()}
    return best_shape(fits, prep.t0 + SETTLE_S, True)[1]
