"""Outside the catalogue: a correlate of a failing sensor's innovations (:mod:`.discover`), added to
the model as a regressor on that sensor and claimed on the catalogue's own terms (strong evidence, 3
sigma, a gain on held-out blocks)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from groundstation.diagnosis.catalogue.candidate import Candidate, state_param, with_regressor
from groundstation.diagnosis.claims.detect import Finding, residuals_pass
from groundstation.diagnosis.claims.discover import Discovery, discover, library
from groundstation.diagnosis.effect import Effect
from groundstation.diagnosis.runs.run import SETTLE_S, Prepared, Run, run_model
from groundstation.diagnosis.runs.signature import Column, Probes
from groundstation.diagnosis.scoring import holdout, trials
from groundstation.diagnosis.scoring.gains import fit, run_signatures, virtual_run
from groundstation.diagnosis.scoring.scored import STRONG
from groundstation.estimation.models.base import LinearModel
from groundstation.estimation.models.ground import LANDED

#: a discovered correlate is added in the catalogue's place when the log prefers it by this much more
#: (Delta BIC): strong evidence on Kass and Raftery's scale, so that where the two nearly tie the
#: physical effect the catalogue names is the one added
DISCOVERY_MARGIN = 10.0


def rival_discovery(
    base: Run,
    model,
    prep,
    make,
    stream,
    findings: list[Finding],
    tried: set,
    rejected: list[Effect] | None = None,
    *,
    workers: int = 1,
) -> tuple[Discovery, Effect] | None:
    """The strongest discovery that holds (:func:`add_discovery`) on a sensor whose residuals fail,
    with its effect: the correlate the regression names, or where it names none on the baro the
    dynamic pressure over the ground (:func:`.discover`'s ``weak``), each claimed only on the
    filter's own evidence. One tried before (same sensor and correlate) is not tried again. A failed
    one goes to ``rejected`` when given."""
    best: tuple[Discovery, Effect] | None = None
    if model.f is not None:  # a nonlinear model is rebuilt from its options: no regressor to add
        return None
    for sensor in base.sensors:
        if sensor == LANDED or residuals_pass([f for f in findings if f.sensor == sensor]):
            continue
        # named by the regression, or on a static port failing that the flight's dynamic pressure over
        # the ground (discover.WEAK_CORRELATES), for the filter to weigh (of any slow regressor the
        # GPS's slow error makes a correlate: the tilt low-passed over 2 s scored Delta BIC -1335 there)
        d = discover(base, sensor) or (discover(base, sensor, weak=True) if sensor == "baro" else None)
        if d is None or (sensor, d.expression) in tried:
            continue
        tried.add((sensor, d.expression))
        found = add_discovery(d, model, base, prep, make, stream, workers=workers)
        if "reason" in found.evidence:
            if rejected is not None:
                rejected.append(found)
            continue
        if best is None or found.evidence["delta_bic"] < best[1].evidence["delta_bic"]:
            best = (d, found)
    return best


def discovered_state(model: LinearModel) -> str:
    """The state a discovered correlate's coefficient takes in ``model``: one of its own beside any
    discovered before (sharing a name, a second discovery read the first one's coefficient)."""
    name, i = "k_discovered", 1
    while name in model.states:
        i += 1
        name = f"k_discovered_{i}"
    return name


def discovered_column(
    sensor: str, t_sig: np.ndarray, sig: np.ndarray, nu_sd: float, state: str = "k_discovered"
) -> Column:
    """A discovered correlate as a column on its sensor (:mod:`~groundstation.diagnosis.runs.signature`): its values at
    the times given, held between them; prior: ten times the innovations' spread per signal spread (diffuse against any
    plausible coefficient), as the augmented model's."""

    def values(t: np.ndarray, t0: np.ndarray) -> np.ndarray:
        return np.interp(t, t_sig, sig)

    return Column(state, (10.0 * nu_sd / (float(np.std(sig)) or 1.0)) ** 2, sensor, of_time=values)


#: refits of a discovered correlate on the estimate it corrects (settled_signal), at most
SETTLE_ITERATIONS = 4


def settled_signal(d: Discovery, base: Run, model: LinearModel, nu_sd: float) -> np.ndarray:
    """The discovered correlate's values evaluated on the estimate it corrects. Read off the run before
    it, a correlate of the estimate (the height, the vertical speed) carries the very error it
    explains: a baro reading high in a fast climb lifts the estimate's climb rate, and with it its own
    regressor, and a baro error of 0.070 m per (m/s)^2 read 0.019. So it is fitted through the base
    run's gains (two-stage filter), read again on the estimate with the term in it at the value found,
    and fitted again, until the coefficient settles (2 %, at most :data:`SETTLE_ITERATIONS` times).
    Where the two-stage filter does not apply, or the correlate is not the estimate's, the values
    are as discovered."""
    t_sig, sig = np.asarray(d.keep_t), np.asarray(d.signal)
    taped = base.taped
    if taped is None:
        return sig
    k_last = None
    for _ in range(SETTLE_ITERATIONS):
        column = discovered_column(d.sensor, t_sig, sig, nu_sd, discovered_state(model))
        sig_d = run_signatures(base, model.n, [column], probed=False)  # its own alone: each column's is its own
        if sig_d is None:
            return sig
        f = fit(sig_d, [column])
        k = float(f.ts.theta[-1][0])
        x = base.x + np.einsum("kij,j->ki", sig_d.columns_at(taped.x_record, f.J), f.ts.theta[-1])
        again = library(replace(base, x=x), d.sensor).get(d.expression)
        if again is None or len(again) != len(sig):
            return sig
        sig = again
        if k_last is not None and abs(k - k_last) <= 0.02 * abs(k):
            break
        k_last = k
    return sig


def add_discovery(d: Discovery, model, base: Run, prep, make, stream, *, workers: int = 1) -> Effect:
    """The discovered correlate added to the model as a regressor on its sensor, ``y = h(x) + k s(t)`` (``s`` the signal
    as the run before it saw it), claimed on the catalogue's terms: strong evidence (Delta BIC), k at least 3 sigma from
    zero, and a gain on held-out blocks (:mod:`~groundstation.diagnosis.scoring.holdout`). The claimed effect carries
    the augmented model, its candidate and its run in its evidence (taken out by the caller); a discovery that fails
    comes back as a rejected effect with the reason."""
    t_sig = np.asarray(d.keep_t)
    nu_sd = float(np.std(base.sensors[d.sensor].nu[:, 0])) or 1.0
    sig = np.asarray(d.signal) if trials.BY_RUNS else settled_signal(d, base, model, nu_sd)
    spread = float(np.std(sig)) or 1.0

    def regressor(ctx, t_sig=t_sig, sig=sig):
        return float(np.interp(ctx.t if ctx.t is not None else t_sig[0], t_sig, sig))

    def augment(m):
        # prior: ten times the innovations' spread per signal spread (diffuse against any plausible k)
        return with_regressor(m, d.sensor, state, regressor, (10.0 * nu_sd / spread) ** 2)

    state = discovered_state(model)
    read_k = state_param("k", state)
    cand = Candidate("discovered", 1, set(), d.sensor, augment, read_k)
    aug = augment(model)
    params: dict = {"expression": d.expression}
    # through the base run's gains where the two-stage filter applies (the regressor is a function of
    # time alone, so it is exact there): the effect's own run only once it is claimed
    column = discovered_column(d.sensor, t_sig, sig, nu_sd, state)
    sig_d = None if trials.BY_RUNS else run_signatures(base, model.n, [column], probed=False)
    f = fit(sig_d, [column]) if sig_d is not None else None
    try:
        if f is not None:
            run = virtual_run(aug, base, f.sig, f.J, f.ts, prep.t0 + SETTLE_S)
        else:
            run = run_model(aug, prep, make, measurements=stream)
    except np.linalg.LinAlgError:
        return Effect(
            "discovered", params, {"sensor": d.sensor, "reason": "its filter diverged", "delta_bic": math.nan}
        )
    params.update(read_k(run))
    n = max(base.sensors[d.sensor].t.size, 1)
    dbic = -2.0 * (run.loglik - base.loglik) + math.log(n)
    ho = holdout.check(
        cand,
        aug,
        run,
        {k: v for k, v in params.items() if k != "expression"},
        model,
        base,
        prep,
        make,
        stream,
        workers=workers,
        fit=f,
    )
    evidence = {
        "delta_bic": round(dbic, 1),
        "sensor": d.sensor,
        "r2": round(d.r2, 3),
        # the regression's terms, as the report gives a claimed discovery's (report.as_json)
        "terms": [{"regressor": a, "coefficient": b} for a, b in d.terms],
        **ho.as_dict(),
    }
    if dbic >= STRONG:
        return Effect("discovered", params, {**evidence, "reason": f"Delta BIC {dbic:+.1f} is not strong evidence"})
    if not ho.holds:
        return Effect("discovered", params, {**evidence, "reason": ho.reason})
    return Effect("discovered", params, {**evidence, "model": aug, "run": run, "candidate": cand})


def taken(found: Effect, prep: Prepared, make, stream, probes: Probes | None) -> tuple[LinearModel, Run]:
    """A claimed discovery's model and run, taken out of its evidence: the filter's own run where it
    was scored through the base run's gains (taped, with ``probes``: a ranking may start from it),
    its coefficient read from that run."""
    model, run = found.evidence.pop("model"), found.evidence.pop("run")
    read_k = found.evidence.pop("candidate").params
    if run.through_gains or (probes is not None and run.taped is None):
        run = run_model(model, prep, make, measurements=stream, taped=True, probes=probes)
        assert read_k is not None  # a discovery's candidate reads its coefficient (add_discovery)
        found.params.update(read_k(run))
    return model, run
