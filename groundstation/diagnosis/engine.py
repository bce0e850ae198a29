"""The closed loop: residual -> detect -> trace -> add -> repeat, then the error before and after.

:func:`diagnose` takes each sensor's noise from the log (:mod:`.noise_match`), runs the model
on the measured data (step 1), tests every sensor's innovations (step 2, :mod:`.detect`), ranks
the catalogue's effects through the filter (step 3, :mod:`.trace`), adds the best one that holds
out of sample (:mod:`.holdout`) to the model with its parameters estimated from the data
(step 4), and repeats until the residuals pass or no candidate improves the criterion by strong
evidence (Delta BIC < -10); then names what lies outside the catalogue (:mod:`.discover`) and
adds it on the same terms.
With truth (motion capture), a winner whose fix makes the error against it
worse is rejected and reported as such, and the next candidate is tried.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from groundstation.core.imu import ImuColumns
from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings
from groundstation.estimation.models.base import LinearModel
from groundstation.estimation.models.ground import LANDED
from groundstation.estimation.stated import RangeClearance, Stated
from groundstation.estimation.truth import Truth

from . import holdout, trials
from .catalogue import Candidate, state_param, unobservable_in, with_regressor, with_throttle_stand_in
from .detect import Finding, detect
from .discover import Discovery, discover, library
from .effect import Effect
from .gains import CatalogueColumns, fit, profile_shape, run_signatures, virtual_run
from .leave_one_out import LeftOut, leave_one_out
from .models import setup
from .noise_match import NoiseLevel, match_gps_slow, match_noise
from .run import SETTLE_S, Prepared, Run, hold_zeros, run_model
from .signature import Column, Probes
from .thrust_side import voltage_effect
from .trace import STRONG, Scored, rank, realise, smallest_claimed, with_shape
from .trials import log_profile

#: a discovered correlate is added in the catalogue's place when the log prefers it by this much more
#: (Delta BIC): strong evidence on Kass and Raftery's scale, so that where the two nearly tie the
#: physical effect the catalogue names is the one added
DISCOVERY_MARGIN = 10.0
#: effects added at most, one per iteration of the loop (underpowered.log's fifth, the sonar's delay,
#: came after four: the baro's drift, thrust loss, rotor and baro ground effect)
MAX_EFFECTS = 5
#: with truth, an effect whose fix makes the estimate's error against it this much worse (by a factor,
#: and by more than :data:`VETO_FLOOR`) is rejected: its better fit to the measurements comes from
#: something the model lacks, not from this effect (on a real Crazyflie log a "mounting error" of
#: -11 deg fitted the accelerometer's vibration and took roll and pitch from 0.66 deg to 6.45 deg off)
VETO_FACTOR = 1.2
VETO_FLOOR = {"height [m]": 0.01, "roll and pitch [rad]": math.radians(0.5)}
#: an added effect whose runner-up is claimable too and scores within this much of it is reported with that
#: runner-up as its alternative: the log prefers the one by less than very strong evidence (the claim's
#: own 10; Kass and Raftery's scale). A baro drift of 0.03 m/s on a flight whose temperature rose almost
#: in a line was named baro_thermal, Delta BIC -7168.5 against the drift's -7161.9
CLOSE_CALL = 10.0


@dataclass
class Diagnosis:
    source: str
    model: str
    before: Run
    after: Run
    effects: list[Effect]
    findings_before: list[Finding]
    findings_after: list[Finding]
    discoveries: list[Discovery]
    unobservable: dict[str, str]
    modelled: list[Effect]  # effects the base model already estimates
    ranking: list[list[tuple[str, float]]] = field(default_factory=list)  # per iteration
    truth: Truth | None = None
    against_truth: list[Effect] = field(default_factory=list)  # measurable only against truth
    rejected: list[Effect] = field(default_factory=list)  # fitted better, contradicted by truth
    vehicle: str | None = None  # the airframe's constants the model started from
    airframe: dict | None = None  # ... or the thrust curve read from the log's accelerometer
    #: per candidate left unclaimed, the size this log would claim it at about half the time (trace.smallest_claimed)
    detectable: list[dict] = field(default_factory=list)
    #: each sensor's noise as the log shows it, beside the model's (noise_match.py)
    noise: list[NoiseLevel] = field(default_factory=list)
    #: readings no estimator takes (not finite, out of the sensor's range), by ``<kind>_<problem>``
    unusable: dict[str, int] = field(default_factory=dict)
    #: the range's ground clearance taken off its readings (estimation.stated), if any
    clearance: RangeClearance | None = None
    #: effects found beside the model, where it cannot show them (thrust_side: thrust lost with the
    #: battery, from the accelerometer's thrust curve); each one's evidence names how it was found
    beside: list[Effect] = field(default_factory=list)
    #: each absolute sensor predicted by the others, before and after (leave_one_out.py)
    left_out: list[LeftOut] = field(default_factory=list)

    @staticmethod
    def passes(findings: list[Finding]) -> bool:
        """The residuals pass: NIS in its band and white (the loop's stopping rule)."""
        return all(f.passed for f in findings if f.test in ("NIS mean", "Ljung-Box whiteness"))


def sensor_findings(run: Run) -> list[Finding]:
    out = []
    for s, tr in run.sensors.items():
        if s == LANDED:
            continue
        k = tr.t >= tr.t[0] + 5.0
        sig = {n: v[k] for n, v in tr.signals.items() if n not in ("throttle_lp",)}
        out += detect(s, tr.t[k], tr.nu_normalised[k], tr.nis[k], tr.nu.shape[1], sig, nu=tr.nu[k, 0])
    return out


def _start_trials(
    cands: list[Candidate], model: LinearModel, prep: Prepared, make, columns: CatalogueColumns | None, workers: int
) -> trials.Started | None:
    """With cores to spare, the one trial each of the candidates without columns of their own (those
    the first ranking runs when their screen could be claimed, and those it always runs), begun
    beside the base run, one on each core but the one that makes it (:class:`.trials.Started`)."""
    if workers < 2 or columns is None or trials.BY_RUNS:
        return None
    own = [c for c in cands if id(c) not in columns.by_candidate]
    own.sort(key=lambda c: id(c) in columns.screens)  # those always run first
    tasks = [(c, keys[0]) for c in own if len(keys := trials.first_keys(c)) == 1 and not c.delays]
    if not tasks:
        return None
    return trials.Started(tasks[: workers - 1], model, prep, make, prep.measurements)


def _modelled(run: Run) -> list[Effect]:
    """Effects the base model estimates itself, when the data say they are there (|x| > 3 sigma)."""
    out = []
    if "b_acc" in run.model.states:
        v, s = run.final("b_acc")
        if abs(v) > 3 * s and abs(v) > 0.02:
            # b_acc acts on gamma_z (up); the simulator's accel_bias z is on body z (down)
            out.append(
                Effect(
                    "accel_bias",
                    {"z": -v, "sigma_z": s},
                    {
                        "state": "b_acc",
                        "z_over_sigma": round(abs(v) / s, 1),
                        "note": "already a state of the model: estimated, not added",
                    },
                )
            )
    return out


def _joint_params(effects: list[Effect], added: list[Candidate], final: Run) -> None:
    """An effect estimated as states is reported as the final model estimates it, jointly with every
    effect added after it; its value when it was added goes to the evidence. Read when it was added,
    a thrust_voltage n = 1.5 found before a 0.1 s actuator lag read 1.36 (simulated thrust test flight,
    seed 1101); a profiled one (a delay, a lag: a grid of runs) keeps its profile's value."""
    for e, c in zip(effects, added):
        if c.augment is None or c.params is None or c.delays:
            continue
        joint = {**e.params, **c.params(final)}  # a chosen shape (a fall-off height) stays
        if joint != e.params:
            e.evidence.setdefault("params_when_added", e.params)
            e.params = joint


#: the factor either side of a shape chosen alone that :func:`joint_shapes` starts its profile at
JOINT_SHAPE_STEP = 1.5
#: a shape chosen again within this much of its log (2 %) is the same shape: the model is not run again
SAME_SHAPE = 0.02


def joint_shapes(
    model0: LinearModel,
    effects: list[Effect],
    added: list[Candidate],
    prep: Prepared,
    make,
    stream: Sequence[Measurement],
    model: LinearModel,
    base: Run,
) -> tuple[LinearModel, Run]:
    """A continuous shape (the rotor wash's time constant) chosen again with every effect found after
    it in the model, by its profile likelihood (:func:`.trials.log_profile`, from the value chosen
    alone and a factor 1.5 either side). Chosen alone, the wash of a flight whose baro also read
    its temperature took 0.28 s for its true 0.39 s (the thermal error's share in what the wash
    explained), and the fix left 1.7 times the error of the true model; with the thermal term in the
    model the profile peaks at 0.36 s. ``model0``: the model the effects were added to, in the
    order of ``added``; returns the final model and its run, as they were when nothing moved."""
    for j, c in enumerate(added[:-1]):
        if c.unshaped is None:
            continue
        unshaped, e = c.unshaped, effects[j]

        def build(shape: float | None, j=j, unshaped=unshaped) -> LinearModel:
            """The final model with the shaped effect at ``shape`` (None: without it)."""
            m = model0
            for k, ck in enumerate(added):
                if ck.augment is not None and not (k == j and shape is None):
                    m = unshaped(m, shape) if k == j else ck.augment(m)
            return m

        s0 = float(e.params[c.shape_name])
        if c.columns is not None and not trials.BY_RUNS:
            # the others as they are, the shape profiled through their run's gains (gains.profile_shape)
            shape = profile_shape(c, build(None), prep, make, stream)
            if shape is None or abs(math.log(shape / s0)) < SAME_SHAPE:
                continue
            e.evidence["params_when_added"] = dict(e.params)
            e.params[c.shape_name] = shape
            added[j] = replace(c, augment=with_shape(unshaped, shape))
            model = build(shape)
            base = run_model(model, prep, make, measurements=stream, taped=True)
            continue

        def run_at(shape: float, build=build) -> Run | None:
            try:
                return run_model(build(shape), prep, make, measurements=stream)
            except np.linalg.LinAlgError:  # the filter ran away at that shape
                return None

        shapes = (s0 / JOINT_SHAPE_STEP, s0, s0 * JOINT_SHAPE_STEP)
        shape, r = log_profile(run_at, shapes, known={s0: base})
        if r is None or shape == s0:
            continue
        e.evidence["params_when_added"] = dict(e.params)
        e.params[c.shape_name] = shape
        added[j] = replace(c, augment=with_shape(unshaped, shape))
        model, base = build(shape), r
    return model, base


def diagnose(
    ms: Sequence[Measurement],
    *,
    source: str = "",
    model_name: str = "altitude",
    declared: Sequence[dict] = (),
    vehicle: str | None = None,
    truth: Truth | None = None,
    progress: Callable[[str], None] | None = None,
    veto_with_truth: bool = True,
    workers: int = 1,
    imu: ImuColumns | None = None,
    stated: Stated | None = None,
) -> Diagnosis:
    """``truth`` (motion capture, a simulator's sidecar) is used for the error before and after and, unless
    ``veto_with_truth`` is off, to reject an effect whose fix makes that error worse (see
    :data:`VETO_FACTOR`); it never ranks or sizes an effect. ``workers``: the processes the
    candidates' runs are spread over (:mod:`.trials`; the findings are the same on any number).
    ``imu``: the log's raw IMU as columns, when ``ms`` does not hold it. ``stated``: what the log
    states besides its readings (the range's ground clearance, the motors' thrust curve:
    :func:`.models.setup`)."""
    su = setup(ms, source=source, model_name=model_name, declared=declared, vehicle=vehicle, imu=imu, stated=stated)
    imu = None  # averaged into the prepared log's blocks: the raw columns are no longer needed
    prep, model, make, catalogue, names = su.prep, su.model, su.spec.make, su.spec.catalogue, su.declared
    say = progress or (lambda _s: None)
    cands = [c for c in catalogue(prep.kinds) if c.name not in names]
    if not prep.logged_throttle:
        cands = with_throttle_stand_in(cands)
    # every candidate's columns, which each run that may start a ranking is probed with (a linear
    # model's: a nonlinear one is run candidate by candidate)
    columns = CatalogueColumns.of(cands, model) if model.f is None and not trials.BY_RUNS else None

    def probes() -> Probes | None:
        return columns.probes() if columns is not None else None

    say("matching the sensors' noise to the log")
    first_run = run_model(model, prep, make)
    hold_zeros(prep, first_run)  # the absolute sensors' zeros, the same for every model from here on
    model, noise, matched = match_noise(model, prep, make, probes(), first=first_run)
    if matched is first_run:  # taken with the zeros still open: its readings differ from the runs after it
        matched = None
    del first_run  # (its zeros are the prepared log's now; a long log's run is large)
    model0 = model  # what the effects are added to
    started = _start_trials(cands, model, prep, make, columns, workers)
    try:
        say("running the model (before)")
        base = matched if matched is not None else run_model(model, prep, make, probes=probes())
        matched = None  # base's alone, which an added effect's run replaces
        # before: the model as the log's noise has it, the GPS's slow error included; the effects are
        # traced against the GPS at the floor of that error (noise_match.match_gps_slow says why)
        _, _, first = match_gps_slow(model, prep, make, base=base)
    except BaseException:
        if started is not None:
            started.close()
        raise
    findings0 = sensor_findings(first)
    stream: Sequence[Measurement] = prep.measurements
    effects: list[Effect] = []
    rejected: list[Effect] = []
    ranking = []
    added: list[Candidate] = []
    labels: list[str] = []
    scored: list[Scored] = []
    held: dict[int, holdout.Holdout] = {}
    discoveries: list[Discovery] = []
    tried: set[tuple[str, str]] = set()  # (sensor, expression) of the discoveries tried
    best: Scored | None = None
    runner_up: Scored | None = None
    s: Scored | None = None
    for _ in range(MAX_EFFECTS):
        if not cands:
            break
        # the last ranking's candidates hold its signatures and runs: let go before the next is made
        scored, best, runner_up, s = [], None, None, None
        held.clear()
        try:
            scored = rank(
                cands,
                model,
                base,
                prep,
                make,
                stream,
                lambda s: say(f"trying {s}"),
                workers=workers,
                columns=columns,
                exact_gains=su.spec.exact_gains,
                started=started,
            )
        finally:
            if started is not None:  # the first ranking's only
                started.close()
                started = None
        ranking.append([(_label(s), round(s.delta_bic, 1)) for s in scored])
        _as_ended((s for s in scored if not s.accepted), base)
        for s in (s for s in scored if s.accepted):
            veto = _contradicted(truth, base, s) if veto_with_truth and truth is not None else None
            if veto is None:
                say(f"holding out {_label(s)}")
                ho = holdout.check(
                    s.candidate,
                    s.model,
                    s.run,
                    s.params,
                    model,
                    base,
                    prep,
                    make,
                    stream,
                    s.profile,
                    workers=workers,
                    fit=s.fit,
                )
                held[id(s)] = ho
                if ho.holds:
                    best = s
                    break
                veto = Effect(
                    s.name,
                    s.params,
                    {
                        "delta_bic": round(s.delta_bic, 1),
                        "sensor": s.candidate.sensor,
                        "reason": ho.reason,
                        **ho.as_dict(),
                    },
                )
                say(f"rejected {s.name}: {ho.reason}")
            else:
                say(f"rejected {s.name}: worse against {veto.evidence['against']}")
            rejected.append(veto)
            cands = [c for c in cands if not (c.name == s.name and c.sensor == s.candidate.sensor)]
        # outside the catalogue, as a rival: a correlate of a failing sensor's innovations that the log
        # prefers to the catalogue's best by strong evidence is added instead (held at the end, a
        # baro error of 0.06 m per (m/s)^2 of climb was first taken for a baro delay of 0.15 s, which
        # it beats by 208 in Delta BIC)
        findings = sensor_findings(base)
        rival = (
            _rival_discovery(base, model, prep, make, stream, findings, set(), workers=workers)
            if not Diagnosis.passes(findings)
            else None
        )
        if (
            rival is not None
            and rival[1].evidence["delta_bic"] < (best.delta_bic if best is not None else math.inf) - DISCOVERY_MARGIN
        ):
            d, found = rival
            say(f"added the discovered {d.expression} on the {d.sensor} ({found.evidence['delta_bic']:.0f})")
            tried.add((d.sensor, d.expression))
            discoveries.append(d)
            added.append(found.evidence["candidate"])
            labels.append("discovered")
            model, base = _taken(found, prep, make, stream, probes())
            effects.append(found)
            if Diagnosis.passes(sensor_findings(base)):
                break
            continue
        if best is None:
            break
        _as_ended((s for s in scored if s is not best), base, best.run)
        if base is not best.run:
            # the ranking it started is done: from here on only the new base's gains are read (and
            # the run before, kept for the report, would hold its own to the end)
            base.taped = None
        if best.run.through_gains:
            # scored through the base filter's gains: the effect's own run, which the next ranking starts from
            say(f"running the model with {_label(best)}")
            realise(best, base, prep, make, probes())
        elif best.run.taped is None and columns is not None:
            # its trial's run, untaped (trials.trial): again with the gains and probes the next ranking reads
            say(f"running the model with {_label(best)}")
            best.run = run_model(best.model, prep, make, measurements=best.measurements or None, probes=probes())
        runner_up = next(iter(scored[scored.index(best) + 1 :]), None)  # the next one down, not a rejected one
        effects.append(
            Effect(
                best.name,
                best.params,
                {
                    "delta_bic": round(best.delta_bic, 1),
                    "sensor": best.candidate.sensor,
                    "loglik_gain": round(best.run.loglik - base.loglik, 1),
                    "gain_per_update": round(best.gain_per_update, 4),
                    "support": best.support,
                    # the evidence at the innovations' effective sample size (trace's docstring)
                    "delta_bic_effective": round(best.delta_bic_effective, 1),
                    "innovation_colour": {k: round(v, 2) for k, v in best.run.inflation.items()},
                    **held[id(best)].as_dict(),
                    "runner_up": _label(runner_up) if runner_up else None,
                    "runner_up_delta_bic": round(runner_up.delta_bic, 1) if runner_up else None,
                    **_alternative(best, runner_up),
                },
            )
        )
        added.append(best.candidate)
        labels.append(_label(best))
        model, base, stream = best.model, best.run, best.measurements
        cands = [c for c in cands if not (c.name == best.name and c.sensor == best.candidate.sensor)]
        if best.name == "baro_bias_drift":
            cands = [c for c in cands if c.name != "baro_bias_drift"]
        say(f"added {best.name} ({best.delta_bic:.0f})")
        if Diagnosis.passes(sensor_findings(base)):
            break
    model, base = joint_shapes(model0, effects, added, prep, make, stream, model, base)
    _joint_params(effects, added, base)
    for e in effects:  # an alternative the loop added after all is a second effect, not an alternative
        if e.evidence.get("alternative", {}).get("name") in labels:
            del e.evidence["alternative"]
    findings1 = sensor_findings(base)
    # outside the catalogue: after it, so a physical effect the catalogue names comes first (scored
    # beside it, a regression over a hundred columns found the battery current on the range where a
    # delay of 60 ms was)
    rival = _rival_discovery(base, model, prep, make, stream, findings1, tried, rejected, workers=workers)
    if rival is not None:
        d, found = rival
        say(f"added the discovered {d.expression} on the {d.sensor}")
        discoveries.append(d)
        effects.append(found)
        model, base = _taken(found, prep, make, stream, None)
        findings1 = sensor_findings(base)
    say("giving the GPS the slow error the log shows")
    model, slow, base = match_gps_slow(model, prep, make, stream, base=base)
    if slow is not None:
        noise.append(slow)
        findings1 = sensor_findings(base)
    unobs = {**su.spec.unobservable, **(unobservable_in(prep.kinds) if model_name == "altitude" else {})}
    against = []
    if truth is not None and "range" in base.sensors:
        against = _range_offset_against_truth(base, truth)
        if against:
            # a mounting offset measured once against motion capture is a calibration a
            # user applies from then on: the "after" model reads the range corrected
            unobs.pop("range_offset", None)
            o = against[0].params["o"]
            stream = Readings.of(stream).with_values(Kind.RANGE, lambda v: v - o)
            say("applying the range offset measured against truth")
            base = run_model(model, prep, make, measurements=stream)
            findings1 = sensor_findings(base)
    found_model = model
    if model.f is None and model.n > model0.n:
        say("running the model with the effects as found")
        found_model = holdout.fixed(model, model0.n, holdout.carried_back(model, model0.n, base, prep.t0))
        base = run_model(found_model, prep, make, measurements=stream)
        findings1 = sensor_findings(base)
    left_out: list[LeftOut] = []
    if model.f is None and model0.f is None:
        say("predicting each absolute sensor from the others")
        left_out = leave_one_out(model0, found_model, prep, make, stream, truth)
    beside: list[Effect] = []
    detectable = _detectable(scored, added, rejected)
    if model_name == "altitude":
        say("reading the thrust curve from the accelerometer")
        tv = voltage_effect(prep, base)
        if tv is not None:
            unobs.pop("thrust_voltage", None)  # traced beside the model
            if tv.evidence["claimed"]:
                beside.append(tv)
            elif tv.evidence["delta_bic"] < STRONG:  # it fitted better, and a later bar turned it away
                rejected.append(tv)
            else:
                detectable.append(
                    {"name": tv.name, "size": {"n": tv.evidence["n_50"]}, "delta_bic": tv.evidence["delta_bic"]}
                )
    return Diagnosis(
        source,
        model_name,
        first,
        base,
        effects,
        findings0,
        findings1,
        discoveries,
        unobs,
        _modelled(base),
        ranking,
        truth,
        against,
        rejected,
        vehicle,
        su.airframe,
        detectable,
        noise,
        prep.unusable,
        su.clearance,
        beside,
        left_out,
    )


def _rival_discovery(
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
    """The strongest discovery that holds (:func:`_add_discovery`) on a sensor whose residuals fail,
    with its effect; one tried before (same sensor and correlate) is not tried again. A failed one
    goes to ``rejected`` when given."""
    best: tuple[Discovery, Effect] | None = None
    if model.f is not None:  # a nonlinear model is rebuilt from its options: no regressor to add
        return None
    for sensor in base.sensors:
        if sensor == LANDED or Diagnosis.passes([f for f in findings if f.sensor == sensor]):
            continue
        d = discover(base, sensor)
        if d is None or (sensor, d.expression) in tried:
            continue
        tried.add((sensor, d.expression))
        found = _add_discovery(d, model, base, prep, make, stream, workers=workers)
        if "reason" in found.evidence:
            if rejected is not None:
                rejected.append(found)
            continue
        if best is None or found.evidence["delta_bic"] < best[1].evidence["delta_bic"]:
            best = (d, found)
    return best


def discovered_column(sensor: str, t_sig: np.ndarray, sig: np.ndarray, nu_sd: float) -> Column:
    """A discovered correlate as a column on its sensor (:mod:`.signature`): its values at the times
    given, held between them; prior: ten times the innovations' spread per signal spread (diffuse
    against any plausible coefficient), as the augmented model's."""

    def values(t: np.ndarray, t0: np.ndarray) -> np.ndarray:
        return np.interp(t, t_sig, sig)

    return Column("k_discovered", (10.0 * nu_sd / (float(np.std(sig)) or 1.0)) ** 2, sensor, of_time=values)


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
        column = discovered_column(d.sensor, t_sig, sig, nu_sd)
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


def _add_discovery(d: Discovery, model, base: Run, prep, make, stream, *, workers: int = 1) -> Effect:
    """The discovered correlate added to the model as a regressor on its sensor, ``y = h(x) + k s(t)``
    (``s`` the signal as the run before it saw it), claimed on the catalogue's terms: strong evidence
    (Delta BIC), k at least 3 sigma from zero, and a gain on held-out blocks (:mod:`.holdout`). The
    claimed effect carries the augmented model, its candidate and its run in its evidence (taken out
    by the caller); a discovery that fails comes back as a rejected effect with the reason."""
    t_sig = np.asarray(d.keep_t)
    nu_sd = float(np.std(base.sensors[d.sensor].nu[:, 0])) or 1.0
    sig = np.asarray(d.signal) if trials.BY_RUNS else settled_signal(d, base, model, nu_sd)
    spread = float(np.std(sig)) or 1.0

    def regressor(ctx, t_sig=t_sig, sig=sig):
        return float(np.interp(ctx.t if ctx.t is not None else t_sig[0], t_sig, sig))

    def augment(m):
        # prior: ten times the innovations' spread per signal spread (diffuse against any plausible k)
        return with_regressor(m, d.sensor, "k_discovered", regressor, (10.0 * nu_sd / spread) ** 2)

    cand = Candidate("discovered", 1, set(), d.sensor, augment, state_param("k", "k_discovered"))
    aug = augment(model)
    params: dict = {"expression": d.expression}
    # through the base run's gains where the two-stage filter applies (the regressor is a function of
    # time alone, so it is exact there): the effect's own run only once it is claimed
    column = discovered_column(d.sensor, t_sig, sig, nu_sd)
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
    params.update(state_param("k", "k_discovered")(run))
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


def _as_ended(scored: Iterable[Scored], *kept: Run) -> None:
    """Candidates that will not be added, as their scores and where their runs ended (:func:`.run.
    ending`): their trajectories, tapes, fits and profiles let go of, but ``kept``'s runs (a
    candidate scored as the base itself shares its run). Only the base and the added effect's run
    start a ranking; of the others the size they would be claimed at is read (``_detectable``)."""
    for s in scored:
        if all(s.run is not k for k in kept):
            s.end()


def _taken(found: Effect, prep: Prepared, make, stream, probes: Probes | None) -> tuple[LinearModel, Run]:
    """A claimed discovery's model and run, taken out of its evidence: the filter's own run where it
    was scored through the base run's gains (taped, with ``probes``: a ranking may start from it),
    its coefficient read from that run."""
    model, run = found.evidence.pop("model"), found.evidence.pop("run")
    found.evidence.pop("candidate", None)
    if run.through_gains or (probes is not None and run.taped is None):
        run = run_model(model, prep, make, measurements=stream, taped=True, probes=probes)
        found.params.update(state_param("k", "k_discovered")(run))
    return model, run


def _detectable(scored: list[Scored], added: list[Candidate], rejected: list[Effect]) -> list[dict]:
    """The candidates of the last ranking left unclaimed, each with the size this log would claim it
    at about half the time (trace.smallest_claimed). When the effect added last ended the search
    (the residuals then passed), they were scored against the model before it."""
    out = []
    for s in scored:
        if (
            any(c.name == s.name and c.sensor == s.candidate.sensor for c in added)
            or any(e.name == s.name for e in rejected)
            or not math.isfinite(s.delta_bic)
        ):
            continue
        size = smallest_claimed(s)
        if size:
            out.append(
                {
                    "name": _label(s),
                    "size": {k: float(f"{v:.3g}") for k, v in size.items()},
                    "delta_bic": round(s.delta_bic, 1),
                }
            )
    return out


def _contradicted(truth: Truth, base: Run, s: Scored) -> Effect | None:
    """The candidate as a rejected effect, when its fix makes the error against truth worse by
    :data:`VETO_FACTOR` and :data:`VETO_FLOOR`; otherwise None."""
    t0, t1 = base.t[0] + 5.0, base.t[-1]
    e0, e1 = truth.error(base, t0, t1), truth.error(s.run, t0, t1)
    floor = VETO_FLOOR.get(truth.quantity(base), 0.0)
    if not (math.isfinite(e0) and math.isfinite(e1)) or e1 <= VETO_FACTOR * e0 or e1 - e0 <= floor:
        return None
    return Effect(
        s.name,
        s.params,
        {
            "delta_bic": round(s.delta_bic, 1),
            "delta_bic_effective": round(s.delta_bic_effective, 1),
            "sensor": s.candidate.sensor,
            "against": truth.source,
            "quantity": truth.quantity(base),
            "error_before": e0,
            "error_with": e1,
        },
    )


def _label(s: Scored) -> str:
    return s.name + (f"({s.candidate.sensor})" if s.candidate.delays else "")


def _alternative(best: Scored, runner_up: Scored | None) -> dict:
    """``{"alternative": {name, params, delta_bic}}`` when the runner-up would have been claimed on its own
    and the log prefers ``best`` to it by less than :data:`CLOSE_CALL`; else nothing."""
    if runner_up is None or not runner_up.accepted or runner_up.delta_bic - best.delta_bic >= CLOSE_CALL:
        return {}
    return {
        "alternative": {
            "name": _label(runner_up),
            "params": runner_up.params,
            "delta_bic": round(runner_up.delta_bic, 1),
        }
    }


def _range_offset_against_truth(run: Run, truth: Truth) -> list[Effect]:
    """The range sensor's mounting offset, which no sensor of the log can show, measured against truth:
    o = median(range reading - h_true(t)/c) in flight (h > 0.3 m), the simulator's d_meas = d + o."""
    tr = run.sensors["range"]
    h = np.interp(tr.t, truth.t, truth.h)
    c = np.ones_like(h)
    if truth.cos_tilt is not None:  # the truth's own attitude, not the log's estimate
        c = np.maximum(np.interp(tr.t, truth.t, truth.cos_tilt), 0.2)
    else:
        roll, pitch = tr.signals.get("roll"), tr.signals.get("pitch")
        if roll is not None and pitch is not None and np.isfinite(roll).all():
            c = np.maximum(np.cos(roll) * np.cos(pitch), 0.2)
    air = h > 0.3
    if air.sum() < 30:
        return []
    # the raw reading: z (the extracted measurement) is the reading minus any offset already modelled
    d = tr.z[air, 0] - h[air] / c[air]
    o, s = float(np.median(d)), float(1.2533 * np.std(d) / math.sqrt(air.sum()))
    if abs(o) < 3 * s or abs(o) < 0.005:
        return []
    return [
        Effect(
            "range_offset",
            {"o": round(o, 4), "sigma_o": round(s, 4)},
            {
                "against": truth.source,
                "n": int(air.sum()),
                "note": "unobservable from the log's own sensors; measured against the truth",
            },
        )
    ]
