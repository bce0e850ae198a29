"""Step 3, trace: rank the catalogue's candidates by what the data say through the filter.

Each candidate's augmented model is run over the log and scored by its
innovation log-likelihood, penalised for its added parameters (BIC):

    Delta BIC = -2 (l_aug - l_base) + k ln n

Negative is better; Kass and Raftery's scale calls -10 and below very strong
evidence. Because the likelihood is the filter's own (its gains, its S), an
effect is credited with exactly what the filter could not already absorb: the
generalized-likelihood-ratio idea of Willsky and Jones (1976), with the
effect's parameters estimated as states instead of a separate GLR search.
Delays are profiled: one run per delay on a grid, the best one kept. The runs of
one ranking are independent of one another and run on every core given (:mod:`.trials`).

The likelihood is the filter's, which assumes white innovations. Measured ones
rarely are, even after the fix, and then each innovation carries less than one
sample's evidence: for a slowly varying signature the log-likelihood ratio is
inflated by ``f = n / n_eff`` (Bartlett 1946; the AR(1) form ``(1 + r) / (1 - r)``
of :func:`~groundstation.diagnosis.claims.detect.effective_size`). Each effect's evidence therefore also carries

    Delta BIC_eff = -2 sum_s (l_aug,s - l_base,s) / f_s + k ln n

with ``f_s`` from the innovations of sensor s *with the effect added* (what it
leaves unexplained), and ``f_s`` itself (``innovation_colour``). It is reported,
not used to decide: on Crazyflie 0422-log00 the baro's innovations have
f = 45 with the rotor-wash term (Delta BIC -3854, effective -78) and f = 72 with
the baro drift the data README and Vicon confirm (0.097 m/s; Delta BIC -1133,
effective +0.3). The colour comes from what the catalogue lacks (after both, the
discovery step names the low-passed throttle, 60 % of the baro residual's
variance), and discounting by it would hide real effects with spurious ones.
A large f says: weigh this effect's Delta BIC with care.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from functools import partial

import numpy as np

from groundstation.diagnosis.catalogue.candidate import Candidate
from groundstation.diagnosis.runs.run import SETTLE_S, Prepared, Run, run_model
from groundstation.diagnosis.runs.signature import Signatures
from groundstation.diagnosis.scoring import trials
from groundstation.diagnosis.scoring.gains import (
    SCREEN_SHARE,
    WASH_GRID,
    CatalogueColumns,
    Fit,
    best_shape,
    fit,
    participation,
    run_signatures,
    virtual_run,
)
from groundstation.diagnosis.scoring.scored import (
    MATERIAL,
    MIN_SUPPORT,
    STRONG,
    Scored,
    profile_sigma,
    scored,
)
from groundstation.diagnosis.scoring.trials import SIGNATURE, Trials, delayed, log_profile, refine, scan_grid
from groundstation.estimation.models.base import LinearModel


def score(cand: Candidate, model: LinearModel, base: Run, trials: Trials, i: int, ms) -> Scored | None:
    """Candidate ``i`` of ``trials`` scored against the base run: a grid candidate (a delay) at its
    profile's best value, a shaped one at its best shape."""
    n = max(base.n_scored, 1)
    if cand.delays:

        def at(d: float) -> float:
            r = trials.run(i, d)  # keyed as trials.first_keys keys it
            assert r is not None  # a delayed stream does not change the model
            return r.loglik

        lik = scan_grid(cand.delays, at, cand.k * math.log(n))
        refine(cand, lik, lambda d: trials.run(i, d), {}, trials.floor(i))
        d = max(lik, key=lambda x: lik[x])
        r = trials.run(i, d)
        assert r is not None
        shifted = delayed(cand, ms, d)
        sd = profile_sigma(lik, d, cand.delays[1] - cand.delays[0])
        if d >= max(cand.delays) - 1e-9:
            # the likelihood still rises at the end of the range: no delay has been
            # located, something else is being fitted; not a finding
            return Scored(
                cand,
                model,
                r,
                math.inf,
                {"sensor": cand.sensor, "seconds": d, "note": "at the edge of the search range"},
                shifted,
            )
        p = {"tc": round(float(d), 4)} if cand.reshape else {"sensor": cand.sensor, "seconds": round(float(d), 4)}
        if math.isfinite(sd):  # a flat profile has none (and JSON no infinity)
            p[f"sigma_{'tc' if cand.reshape else 'seconds'}"] = sd
        out = scored(cand, model, r, base, n, p, shifted)
        out.profile = {x: trials.run(i, x) for x in lik}
        return out
    if cand.augment is None:
        return None
    best: tuple | None = None
    for shape in cand.shapes or (None,):
        r = trials.run(i, shape)
        if r is not None and (best is None or r.loglik > best[0].loglik):
            best = (r, shape)
    if best is not None and cand.refine_shape and 2.0 * (best[0].loglik - base.loglik) > (cand.k + 1) * math.log(n):
        # refined where the shapes already find the effect worth its parameters (Delta BIC < 0): the
        # five runs a refinement costs are spent on an effect being sized, not on every ranking of
        # every flight without it
        shape, r = log_profile(lambda x: trials.run(i, x), cand.shapes, most=WASH_GRID[-1])
        assert r is not None  # the best of finite likelihoods
        best = (r, shape)
    if best is None:
        return Scored(cand, model, base, math.inf, {"note": "the filter diverged"}, ms)
    r, shape = best
    params = cand.params(r) if cand.params else {}
    if shape is not None:
        params[cand.shape_name] = shape
        unshaped = cand.augment if cand.refine_shape else None
        cand = replace(cand, k=cand.k + 1, augment=with_shape(cand.augment, shape), shapes=(), unshaped=unshaped)
    return scored(cand, r.model, r, base, n, params, ms)


def with_shape(augment: Callable[..., LinearModel], shape: float) -> Callable[[LinearModel], LinearModel]:
    """A shaped candidate's ``augment`` at the shape the likelihood chose."""

    def at(model: LinearModel) -> LinearModel:
        return augment(model, shape)

    return at


def signature_support(pert: Run | None, base: Run, prep: Prepared, sensor: str) -> int:
    """The updates of ``sensor`` an effect on the input (or a delay) acts on: the participation ratio

        n_sig = (sum_k w_k)^2 / sum_k w_k^2,   w_k = (nu_k(delta) - nu_k)^2 / S_k

    of its signature ``pert``, the base filter's innovations nu(delta) with the effect acting at a
    small size (``cand.perturb``, the candidate's :data:`.trials.SIGNATURE` trial): the effect
    seen through the filter's own gains, as Willsky and Jones's GLR sees it. An effect spread
    evenly over the flight counts every update; the accelerometer's scale acts only where the
    vertical acceleration changes. On the standard flight, its signature sits on about 150 of
    1270 range updates: the steps and the descent. Spread over all 1270, a scale error of 0.01
    (Delta BIC -22, estimated 0.0125 +- 0.0021) gained 0.012 per update and was not material."""
    if pert is None:
        return base.n_scored
    a, b = base.sensors.get(sensor), pert.sensors.get(sensor)
    if a is None or b is None:
        return base.n_scored
    # the same updates in both runs (a gate may take a different one when the stream moves)
    _, i, j = np.intersect1d(a.t, b.t, return_indices=True)
    keep = a.t[i] >= prep.t0 + SETTLE_S
    i, j = i[keep], j[keep]
    w = (b.nu[j, 0] - a.nu[i, 0]) ** 2 / a.S[i, 0, 0]
    sq = float(np.sum(w * w))
    return int(round(float(np.sum(w)) ** 2 / sq)) if sq > 0 else len(w)


def _supported(
    s: Scored, base: Run, prep: Prepared, t_score: float, signature: Callable[[], Run | None] | None = None
) -> Scored:
    """``s`` with its support (the updates its gain is spread over) and gain per update; one that cannot be accepted
    then kept as its scores and where its run ended (:func:`~groundstation.diagnosis.runs.run.ending`): of those only
    the size they would be claimed at is read, and a ranking's dozen candidates' runs and fits are some 25 MB each on a
    1-hour log. ``signature``: its signature trial, for an effect on the input scored by its own runs."""
    sensor = s.candidate.sensor
    if sensor is None:
        # an effect on the input (the accelerometer's scale, the thrust) acts on every sensor
        # through the state, and shows in the one that resolves the height best: its gain is
        # spread over that sensor's updates. Over all of them, a 0.02 accelerometer scale
        # error (estimated 0.019-0.022, Delta BIC -80 to -137, all of it on the range) was
        # diluted by the baro's 2750 updates to 0.011-0.018 per update and not claimed.
        gains = {k: s.run.loglik_by.get(k, 0.0) - v for k, v in base.loglik_by.items()}
        sensor = max(gains, key=lambda k: gains[k]) if gains else None
    tr = base.sensors.get(sensor) if sensor else None
    m = int((tr.t >= t_score).sum()) if tr is not None else base.n_scored
    if s.candidate.support:
        m = min(m, max(s.candidate.support(s.run, t_score), MIN_SUPPORT))
    if s.candidate.delays and tr is not None and sensor is not None and math.isfinite(s.delta_bic):
        # a late reading differs from an on-time one only while what it measures changes: its run at
        # the fitted delay is its own signature (a lidar 0.1 s late on a flight that mostly hovers
        # gained 0.0076 per update over all 3,900 readings)
        m = min(m, max(signature_support(s.run, base, prep, sensor), MIN_SUPPORT))
    if s.candidate.perturb and tr is not None and sensor is not None and math.isfinite(s.delta_bic):
        if s.fit is not None:
            k = s.fit.sig.informs & (s.fit.sig.t >= t_score) & (s.fit.sig.sensor == sensor)
            support = participation(s.fit.sig.G_of(s.fit.J)[k].sum(axis=1), s.fit.sig.S[k])
        else:
            assert signature is not None
            support = signature_support(signature(), base, prep, sensor)
        m = min(m, max(support, MIN_SUPPORT))
    s.support = m
    s.gain_per_update = (s.run.loglik - base.loglik) / max(m, 1)
    if not s.accepted:
        s.end()
    return s


def rank(
    cands: list[Candidate],
    model: LinearModel,
    base: Run,
    prep: Prepared,
    make,
    ms,
    progress: Callable[[str], None] | None = None,
    *,
    workers: int = 1,
    columns: CatalogueColumns | None = None,
    exact_gains: bool = True,
    started: trials.Started | None = None,
) -> list[Scored]:
    """The candidates scored and sorted by Delta BIC, each with its gain per supported update.

    With ``columns`` (the catalogue's, which ``base`` was probed with) the candidates that act
    linearly are scored by the two-stage filter through ``base``'s gains (:mod:`.gains`), and an
    effect that does not is run only where its linear stand-in could be claimed; ``exact_gains``:
    the model's gains do not depend on the data (else a two-stage score that could be claimed is
    run too). The rest, and everything without ``columns`` or with ``GROUNDSTATION_TRACE=runs``,
    is run: each candidate's filter runs on ``workers`` processes (:mod:`.trials`: the same scores
    on any number). ``trials.BY_RUNS`` runs every candidate. ``started``: trials begun beside the base
    run (:class:`.trials.Started`), taken as made."""
    t_score = prep.t0 + SETTLE_S
    sig, best, read_off = _signatures(cands, model, base, columns, t_score)
    out: list[tuple[int, Scored]] = []
    to_run: list[tuple[int, Candidate]] = [(i, c) for i, c in enumerate(cands)]
    shaped: dict[int, tuple[float, Fit]] = {}  # a candidate run at the shape the two-stage filter chose for it
    if sig is not None and columns is not None:
        out, to_run, shaped = _through_gains(
            cands, model, base, prep, ms, sig, columns, best, read_off, t_score, exact_gains
        )
    if to_run:
        # with columns, the effect added is run again with their probes (search.Search._take): its trials are read
        # for their scores alone
        scores_only = columns is not None
        out += _by_runs(to_run, shaped, model, base, prep, make, ms, progress, workers, started, t_score, scores_only)
    out.sort(key=lambda p: p[0])
    ranked = [s for _, s in out]
    ranked.sort(key=lambda s: s.delta_bic)
    if sig is not None:
        # from here on only a claim's columns are read (its hold-out): the others' G and Delta go
        sig.forget([j for s in ranked if s.accepted and s.fit is not None and s.fit.sig is sig for j in s.fit.J])
    return ranked


def _signatures(
    cands: list[Candidate], model: LinearModel, base: Run, columns: CatalogueColumns | None, t_score: float
) -> tuple[Signatures | None, dict[int, tuple[Fit, float | None]], dict[int, list]]:
    """The candidates' signatures through the base run's gains (None without ``columns``), each linear
    candidate's best shape by its fit, and the stand-ins read off the base run itself (a delay's
    heights then against now)."""
    read_off = {id(c): c.screen(model, base) for c in cands if c.screen is not None} if columns is not None else {}
    best: dict[int, tuple[Fit, float | None]] = {}
    if columns is None or trials.BY_RUNS:
        return None, best, read_off
    extra = columns.extra() + [col for stand_ins in read_off.values() for cols in stand_ins for col in cols]
    sig = run_signatures(base, model.n, extra, delta=())
    if sig is None:
        return None, best, read_off
    # each linear candidate's best shape first, then Delta of those shapes' columns alone, in one pass
    for i, c in enumerate(cands):
        shapes = columns.by_candidate.get(id(c))
        if shapes is not None:
            fits = {shape: fit(sig, cols, shape) for shape, cols in shapes.items()}
            best[i] = best_shape(fits, t_score, c.refine_shape)
    sig.keep([j for f, _ in best.values() for j in f.J])
    return sig, best, read_off


def _through_gains(
    cands: list[Candidate],
    model: LinearModel,
    base: Run,
    prep: Prepared,
    ms,
    sig: Signatures,
    columns: CatalogueColumns,
    best: dict[int, tuple[Fit, float | None]],
    read_off: dict[int, list],
    t_score: float,
    exact_gains: bool,
) -> tuple[list[tuple[int, Scored]], list[tuple[int, Candidate]], dict[int, tuple[float, Fit]]]:
    """The candidates scored through the base run's gains (:func:`rank`'s docstring), and those that
    need runs of their own (with the shape the gains chose for any that does)."""
    n = max(base.n_scored, 1)
    out: list[tuple[int, Scored]] = []
    to_run: list[tuple[int, Candidate]] = []
    shaped: dict[int, tuple[float, Fit]] = {}
    for i, c in enumerate(cands):
        shapes = columns.by_candidate.get(id(c))
        if shapes is not None:
            s = _two_stage_score(c, best[i], model, base, sig, t_score, n, ms)
            columns_exact = exact_gains and all(col.exact for cols in shapes.values() for col in cols)
            if s.delta_bic < STRONG and not columns_exact:
                # claimable by a score the augmented filter only approaches: its own runs, every shape
                to_run.append((i, c))
            elif s.delta_bic < STRONG and s.fit is not None and s.params.get(c.shape_name) != s.fit.shape:
                # claimable at a shape between the grid's: its run there (held out through the gains at
                # the grid's nearest shape)
                to_run.append((i, s.candidate))
                shaped[i] = (s.params[c.shape_name], s.fit)
            else:
                out.append((i, _supported(s, base, prep, t_score)))
        elif id(c) in columns.screens:
            stand_ins = columns.screens[id(c)] + read_off.get(id(c), [])
            bound = _screened(c, stand_ins, model, base, sig, t_score, n, ms)
            if bound is None:
                to_run.append((i, c))
            else:
                out.append((i, _supported(bound, base, prep, t_score)))
        else:
            to_run.append((i, c))
    return out, to_run, shaped


def _by_runs(
    to_run: list[tuple[int, Candidate]],
    shaped: dict[int, tuple[float, Fit]],
    model: LinearModel,
    base: Run,
    prep: Prepared,
    make,
    ms,
    progress: Callable[[str], None] | None,
    workers: int,
    started: trials.Started | None,
    t_score: float,
    scores_only: bool,
) -> list[tuple[int, Scored]]:
    """The candidates scored by their own runs, on ``workers`` processes (:mod:`.trials`), those
    begun beside the base run (``started``) taken as made; ``scores_only``: runs without covariances or signals
    (:func:`.trials.trial`)."""
    out: list[tuple[int, Scored]] = []
    made = Trials([c for _, c in to_run], model, prep, make, ms, workers=workers, base=base, scores_only=scores_only)
    if started is not None:
        begun = started.take([c for _, c in to_run])
        for j, (_, c) in enumerate(to_run):
            for key, got in begun.get(id(c), {}).items():
                if key not in made.runs[j]:
                    made.runs[j][key] = made.attach(j, key, got)
    if made.workers > 1:
        if progress and made.pending():
            progress(f"{len(to_run)} candidates on {made.workers} cores")
        made.compute_all()
    for j, (i, c) in enumerate(to_run):
        if progress:
            progress(c.name + (f" ({c.sensor})" if c.sensor and c.delays else ""))
        r = score(c, model, base, made, j, ms)
        if r is not None:
            if i in shaped:
                r.params[c.shape_name], r.fit = shaped[i]
            out.append((i, _supported(r, base, prep, t_score, partial(made.run, j, SIGNATURE))))
        # what its score holds kept, the rest of its runs let go (each a candidate's whole run)
        made.settle(j, [r.run, *r.profile.values()] if r is not None else [])
    return out


def realise(s: Scored, base: Run, prep: Prepared, make, probes) -> None:
    """``s``, scored by the two-stage filter, with the augmented model's own run instead (taped, with
    ``probes``: it starts the next ranking), its parameters and Delta BIC read from that run."""
    shape = s.params.get(s.candidate.shape_name)
    r = run_model(s.model, prep, make, measurements=s.measurements or None, probes=probes)
    params = s.candidate.params(r) if s.candidate.params else {}
    if shape is not None:
        params[s.candidate.shape_name] = shape
    again = scored(s.candidate, s.model, r, base, s.n, params, s.measurements)
    s.run, s.params, s.delta_bic, s.delta_bic_effective = r, params, again.delta_bic, again.delta_bic_effective


def _two_stage_score(
    c: Candidate, best: tuple[Fit, float | None], model: LinearModel, base: Run, sig, t_score: float, n: int, ms
) -> Scored:
    """A linear candidate scored by the two-stage filter at its best shape (``best``, as
    :func:`.gains.best_shape` chose it): its run that filter's; the candidate as it is then added (its
    shape bound, as :func:`score` binds it)."""
    f, shape = best
    assert c.augment is not None
    aug = c.augment(model) if f.shape is None else c.augment(model, f.shape)
    r = virtual_run(aug, base, sig, f.J, f.ts, t_score)
    params = c.params(r) if c.params else {}
    cand = c
    if shape is not None:
        params[c.shape_name] = shape
        unshaped = c.augment if c.refine_shape else None
        cand = replace(
            c, k=c.k + 1, augment=with_shape(c.augment, shape), shapes=(), refine_shape=False, unshaped=unshaped
        )
        if shape != f.shape:  # a refined shape between the grid's: its run is the augmented model's there
            aug = cand.augment(model)  # type: ignore[misc]
            r.model = aug
    out = scored(cand, aug, r, base, n, params, ms)
    out.fit = f
    return out


def _screened(
    c: Candidate, stand_ins: list, model: LinearModel, base: Run, sig, t_score: float, n: int, ms
) -> Scored | None:
    """A nonlinear candidate's linear stand-ins (``Candidate.screen``) through the base run's gains:
    None when one's best fit could be claimed (:data:`.gains.SCREEN_SHARE` of a claim's need), so the
    candidate's own runs are made; else the candidate scored by the best of those bounds, not to be
    claimed (its size and sigma the first stand-in's, a delay's to first order)."""
    fits = [fit(sig, cols) for cols in stand_ins]
    gains = [f.best_fit_gain(t_score, cols[0].at_least if len(cols) == 1 else None) for f, cols in zip(fits, stand_ins)]
    g = max(gains)
    tr = base.sensors.get(c.sensor or "")
    support = int((tr.t >= t_score).sum()) if tr is not None else n
    if c.delays:
        # where the best stand-in's signature sits, as a delay's own run is counted (_supported)
        best = fits[gains.index(g)]
        k = sig.informs & (sig.t >= t_score) & (sig.sensor == c.sensor)
        support = min(support, max(participation(sig.G_of(best.J)[k].sum(axis=1), sig.S[k]), MIN_SUPPORT))
    need = max((c.k * math.log(n) - STRONG) / 2.0, MATERIAL * support)
    if g >= SCREEN_SHARE * need:
        return None
    f = fits[0]
    theta, sd = float(f.ts.theta[-1][0]), float(math.sqrt(f.ts.Sigma[-1][0, 0]))
    params: dict = {"note": "its linear stand-ins through the base filter's gains could not be claimed"}
    if c.delays:
        params = {"sensor": c.sensor, "seconds": round(theta, 4), "sigma_seconds": sd, **params}
    return Scored(c, model, base, -2.0 * g + c.k * math.log(n), params, ms, n=n, fit=f, screened=True)
