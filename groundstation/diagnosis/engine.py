"""The closed loop: residual -> detect -> trace -> add -> repeat, then the error before and after.

:func:`diagnose` reads as the steps of docs/diagnosis.md. It takes each sensor's noise from the log
(:mod:`~groundstation.diagnosis.scoring.noise_match`) and runs the model on the measured data (steps 1 and 2); then, an
effect at a time, ranks the catalogue's effects through the filter (:mod:`~groundstation.diagnosis.scoring.trace`), adds
the best one that holds out of sample (:mod:`~groundstation.diagnosis.scoring.holdout`) with its parameters estimated
from the data, or a correlate outside the catalogue the log prefers (:mod:`~groundstation.diagnosis.claims.discovered`),
until the residuals pass or nothing improves the criterion by strong evidence (Delta BIC < -10) (steps 3 to 5,
:class:`~groundstation.diagnosis.claims.search.Search`); then estimates the effects again together
(:mod:`~groundstation.diagnosis.claims.joint`), names what lies outside the catalogue, and reports the error before and
after (step 6). With truth (motion capture), a winner whose fix makes the error against it worse is rejected and
reported as such, and the next candidate is tried.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from groundstation.core.imu import ImuColumns
from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings
from groundstation.diagnosis.catalogue.altitude import unobservable_in
from groundstation.diagnosis.catalogue.thrust_side import voltage_effect
from groundstation.diagnosis.claims.detect import Finding, residuals_pass, sensor_findings
from groundstation.diagnosis.claims.discover import Discovery
from groundstation.diagnosis.claims.discovered import rival_discovery, taken
from groundstation.diagnosis.claims.joint import joint_params, joint_shapes, model_of
from groundstation.diagnosis.claims.leave_one_out import LeftOut, LeftOutRuns
from groundstation.diagnosis.claims.search import Search, detectable
from groundstation.diagnosis.effect import Effect
from groundstation.diagnosis.models import setup
from groundstation.diagnosis.runs.run import Run, run_model
from groundstation.diagnosis.scoring import holdout
from groundstation.diagnosis.scoring.noise_match import (
    GpsSlowBefore,
    NoiseLevel,
    match_gps_slow,
    match_process_noise,
    with_gps_slow,
    with_process_noise,
)
from groundstation.diagnosis.scoring.scored import STRONG
from groundstation.estimation.models.base import LinearModel
from groundstation.estimation.stated import RangeClearance, Stated
from groundstation.estimation.truth import Truth


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
    #: per candidate left unclaimed, the size this log would claim it at about half the time (scored.smallest_claimed)
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
        """The residuals pass: NIS in its band and white (the search's stopping rule)."""
        return residuals_pass(findings)


#: [m/s^2] the least change of the accelerometer's bias over a log that is said (:func:`_bias_moved`):
#: what an IMU's temperature calibration leaves over its range (a few mg), so that a smaller change
#: has nothing left for a calibration to take out
BIAS_MOVED = 0.05


def _modelled(run: Run) -> list[Effect]:
    """Effects the base model estimates itself, when the data say they are there (|x| > 3 sigma), or
    when the bias moved over the log (:func:`_bias_moved`)."""
    out = []
    if "b_acc" in run.model.states:
        v, s = run.final("b_acc")
        moved = _bias_moved(run)
        if (abs(v) > 3 * s and abs(v) > 0.02) or moved is not None:
            # b_acc acts on gamma_z (up); the simulator's accel_bias z is on body z (down)
            out.append(
                Effect(
                    "accel_bias",
                    {"z": -v, "sigma_z": s},
                    {
                        "state": "b_acc",
                        "z_over_sigma": round(abs(v) / s, 1),
                        "note": "already a state of the model: estimated, not added",
                        **({"moved": moved} if moved is not None else {}),
                    },
                )
            )
    return out


def _bias_moved(run: Run) -> dict | None:
    """The accelerometer's bias (body z) a third of the way through the log and at its end, where it
    moved by :data:`BIAS_MOVED` or more and by the claim's :data:`~.holdout.MIN_Z` standard errors (the
    two estimates' taken as independent: they are positively correlated, so the bar is the stricter
    for it); else None. An IMU's bias that steps as it warms is no catalogue effect (the bias is the
    model's own state, whose random walk follows it over seconds), so this is where such steps are
    said. From a third in, not the start: until the bias is found from its prior, it moves anyway."""
    if len(run.t) < 3:
        return None
    i = run.model.index("b_acc")
    k = min(int(np.searchsorted(run.t, run.t[0] + (run.t[-1] - run.t[0]) / 3.0)), len(run.t) - 2)
    before = float(run.x[k, i])
    s_before = math.sqrt(max(float(run.P_rows(slice(k, k + 1))[0, i, i]), 0.0))
    after, s_after = run.final("b_acc")
    change, sigma = after - before, math.hypot(s_before, s_after)
    if sigma <= 0.0 or abs(change) < BIAS_MOVED or abs(change) < holdout.MIN_Z * sigma:
        return None  # (a bias held exactly says nothing of how it moved)
    return {
        "from": round(-before, 4),
        "to": round(-after, 4),
        "t_from": round(float(run.t[k]), 1),
        "t_to": round(float(run.t[-1]), 1),
        "z": round(abs(change) / sigma, 1),
    }


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
    meanwhile: Callable[[Run, Run], object] | None = None,
) -> Diagnosis:
    """``truth`` (motion capture, a simulator's sidecar) is used for the error before and after and, unless
    ``veto_with_truth`` is off, to reject an effect whose fix makes that error worse (see
    :data:`~groundstation.diagnosis.claims.search.VETO_FACTOR`); it never ranks or sizes an effect. ``workers``: the
    processes the candidates' runs are spread over (:mod:`~groundstation.diagnosis.scoring.trials`; the findings are the
    same on any number). ``imu``: the log's raw IMU as columns, when ``ms`` does not hold it. ``stated``: what the log
    states besides its readings (the range's ground clearance, the motors' thrust curve: :func:`.models.setup`).
    ``meanwhile(before, after)``: given the runs before and after once they are final, while the runs that each absolute
    sensor's evidence reads still go (the report's parts made of those two runs alone)."""
    su = setup(ms, source=source, model_name=model_name, declared=declared, vehicle=vehicle, imu=imu, stated=stated)
    imu = None  # averaged into the prepared log's blocks: the raw columns are no longer needed
    say = progress or (lambda _s: None)
    # runs of the model before that only the report reads (each absolute sensor predicted by the others; the GPS's slow
    # error chosen), forked now, while the heap holds little more than the log, and started as soon as that model is
    # known, on the cores the search leaves idle
    left = LeftOutRuns(su.model, su.prep, su.spec.make, truth, workers) if su.model.f is None else None
    slow = None
    if workers > 1 and su.model.f is None and "b_gps" in su.model.states:
        slow = GpsSlowBefore(su.model, su.prep, su.spec.make, workers - 1)

    def matched(model0: LinearModel) -> None:
        if left is not None:
            left.before(model0)
        if slow is not None:
            slow.start(model0)

    #: what the model after's left-out runs were begun for: (model, run, readings) as the search held them
    begun_for: tuple[LinearModel, Run, object] | None = None

    def added(s: Search) -> None:
        """Each effect added: the model after's left-out runs begun for the model as it now is, on the
        cores the search's next ranking leaves idle (the last ranking finds nothing, so they are usually
        the ones the report reads); the same runs as those begun once the search ends, or replaced then."""
        nonlocal begun_for
        if left is not None and s.model.f is None:
            left.then(_found_model(s), s.stream)
            begun_for = (s.model, s.base, s.stream)

    try:
        search = Search.begin(
            su,
            say=say,
            workers=workers,
            truth=truth if veto_with_truth else None,
            matched=matched,
            gps_slow_later=slow is not None,
            on_added=added,
        )  # steps 1, 2
        search.run()  # steps 3 to 5
        _together(search)  # step 6: the effects estimated together, then what lies outside the catalogue
        unobs = {**su.spec.unobservable, **(unobservable_in(su.prep.kinds) if model_name == "altitude" else {})}
        against = _against_truth(search, truth, unobs)
        held = (search.model, search.base, search.stream)
        found = _as_found(search)
        if left is not None and search.model.f is None:
            say("predicting each absolute sensor from the others")
            # the model after's, begun on the cores the thrust curve, read beside the model meanwhile, leaves idle;
            # begun already where nothing moved since the last effect was added (the same model, run and readings:
            # the model after is made of those alone)
            if begun_for is None or not all(a is b for a, b in zip(begun_for, held)):
                left.then(found, search.stream)
        found_beside, unclaimed = _beside(search, model_name, unobs)
        if slow is not None:
            search.first = slow.chosen(search.model0, search.first)[2]
        _before_with_process_noise(search)
        if meanwhile is not None:
            meanwhile(search.first, search.base)
        left_out: list[LeftOut] = left.results() if left is not None else []
    finally:
        if left is not None:
            left.close()
        if slow is not None:
            slow.close()
    return Diagnosis(
        source,
        model_name,
        search.first,
        search.base,
        search.effects,
        sensor_findings(search.first),
        sensor_findings(search.base),
        search.discoveries,
        unobs,
        _modelled(search.base),
        search.ranking,
        truth,
        against,
        search.rejected,
        vehicle,
        su.airframe,
        unclaimed,
        search.noise,
        su.prep.unusable,
        su.clearance,
        found_beside,
        left_out,
    )


def _together(search: Search) -> None:
    """The effects added, estimated again together (:mod:`~groundstation.diagnosis.claims.joint`); then outside the
    catalogue, after it, so that a physical effect the catalogue names comes first (scored beside it, a regression over
    a hundred columns found the battery current on the range where a delay of 60 ms was); then the GPS given the slow
    error the log shows; then each effect read from that final run, whose values the model after holds. Read before the
    GPS's level is chosen, a PX4 flight's rotor wash would be reported at 0.88 of the thrust over the weight (traced
    against the GPS at the floor of its slow error) while the model after holds 0.93 (the GPS at its 1 m). Last, the
    vertical speed's process noise the likelihood chooses with the effects in the model (and the effects read again
    where it moved)."""
    s = search
    s.model, s.base = joint_shapes(s.model0, s.effects, s.added, s.prep, s.make, s.stream, s.model, s.base)
    for e in s.effects:  # an alternative the search added after all is a second effect, not an alternative
        if e.evidence.get("alternative", {}).get("name") in s.labels:
            del e.evidence["alternative"]
    findings = sensor_findings(s.base)
    rival = rival_discovery(s.base, s.model, s.prep, s.make, s.stream, findings, s.tried, s.rejected, workers=s.workers)
    if rival is not None:
        d, found = rival
        s.say(f"added the discovered {d.expression} on the {d.sensor}")
        s.discoveries.append(d)
        s.effects.append(found)
        s.added.append(found.evidence["candidate"])  # read again from the final run, as the others
        s.labels.append("discovered")
        s.model, s.base = taken(found, s.prep, s.make, s.stream, None)
    s.say("giving the GPS the slow error the log shows")
    s.model, slow, s.base = match_gps_slow(s.model, s.prep, s.make, s.stream, base=s.base, workers=s.workers)
    joint_params(s.effects, s.added, s.base)
    if _drop_unsupported(s):
        s.say("giving the GPS the slow error the log shows, without what the others explain")
        model = model_of(s.model0, s.added)
        first = run_model(model, s.prep, s.make, measurements=s.stream)
        s.model, slow, s.base = match_gps_slow(model, s.prep, s.make, s.stream, base=first, workers=s.workers)
        joint_params(s.effects, s.added, s.base)
    if slow is not None:
        s.noise.append(slow)
    s.say("choosing the process noise the log shows")
    with_q, level = match_process_noise(s.model, s.prep, s.make, s.base, s.stream, workers=s.workers)
    if level is not None:
        s.model = with_q
        s.base = run_model(with_q, s.prep, s.make, measurements=s.stream)
        joint_params(s.effects, s.added, s.base)
        s.noise.append(level)
        s.process_scale = level.ratio**2
        if _drop_unsupported(s):
            # read again at the process noise chosen, an effect can fall below the claim's bar (a PX4 flight's
            # accelerometer reading 5 % high drew a rotor wash of 14.9 sigma that the model after held at 2.3)
            s.say("the model after without what it holds too near zero")
            model = with_process_noise(model_of(s.model0, s.added), s.process_scale)
            if slow is not None:
                model = with_gps_slow(model, slow.sigma_data)
            s.model = model
            s.base = run_model(model, s.prep, s.make, measurements=s.stream)
            joint_params(s.effects, s.added, s.base)


def _before_with_process_noise(search: Search) -> None:
    """The run before with the process noise the model after took (:func:`_together`): a property of the vehicle's
    accelerometer, chosen once, with the effects in the model, so that before and after differ by the effects alone.
    Chosen for the model before on its own, an effect the model lacks drew it up to take the effect's place (our
    simulator's 10-minute flight with a range read under tilt: 729 times the model's level, where the model with the
    slant keeps the model's)."""
    s = search
    if s.process_scale != 1.0:
        s.first = run_model(with_process_noise(s.first.model, s.process_scale), s.prep, s.make)


def _drop_unsupported(s: Search) -> bool:
    """The effects added as states that the final model, with every effect added after them, holds too near
    zero to claim (the claim's own bar, :func:`.holdout.sizes`), moved to the rejected (their states out of the
    model); whether any was. A GPS height 0.25 s late on a PX4 flight first drew a rotor wash that the GPS's
    delay, added after it, explained: the wash was reported at 0.11 +- 0.05 and the height after was 5.3 cm
    where before it was 4.5."""
    dropped = []
    for i, (e, c) in enumerate(zip(s.effects, s.added)):
        if c.augment is None or c.delays:
            continue
        _, why = holdout.sizes(e.params, delay=False, fitted=c.fitted)
        if why is None and c.plausible is not None:
            why = c.plausible(e.params)
            if why is not None:
                e.evidence["implausible"] = True
        if why is not None:
            dropped.append(i)
            e.evidence["reason"] = f"with the effects added after it, {why}"
    for i in reversed(dropped):
        e = s.effects.pop(i)
        s.added.pop(i)
        s.labels.pop(i)
        if e.name == "discovered":
            del s.discoveries[sum(1 for x in s.effects[:i] if x.name == "discovered")]
        s.rejected.append(e)
    return bool(dropped)


def _against_truth(search: Search, truth: Truth | None, unobs: dict[str, str]) -> list[Effect]:
    """With truth and a range sensor, the range's mounting offset measured against it: a calibration
    a user applies from then on, so the model after reads the range corrected."""
    s = search
    if truth is None or "range" not in s.base.sensors:
        return []
    against = _range_offset_against_truth(s.base, truth)
    if against:
        unobs.pop("range_offset", None)
        o = against[0].params["o"]
        s.stream = Readings.of(s.stream).with_values(Kind.RANGE, lambda v: v - o)
        s.say("applying the range offset measured against truth")
        s.base = run_model(s.model, s.prep, s.make, measurements=s.stream)
    return against


def _as_found(search: Search) -> LinearModel:
    """The model after, with each added effect's state held at the value found
    (:func:`~groundstation.diagnosis.scoring.holdout.fixed`, carried back to the log's start), and its run (the search's
    base from here on): the error after is the fix's, not a filter's still learning it."""
    s = search
    found = _found_model(s)
    if found is s.model:
        return found
    s.say("running the model with the effects as found")
    s.base = run_model(found, s.prep, s.make, measurements=s.stream)
    return found


def _found_model(s: Search) -> LinearModel:
    """The model after as :func:`_as_found` makes it of the search's model and run as they are now (the
    model itself where no effect added a state)."""
    if s.model.f is not None or s.model.n <= s.model0.n:
        return s.model
    n0 = s.model0.n
    return holdout.fixed(s.model, n0, holdout.carried_back(s.model, n0, s.base, s.prep.t0))


def _beside(search: Search, model_name: str, unobs: dict[str, str]) -> tuple[list[Effect], list[dict]]:
    """Effects found beside the model, where it cannot show them (the altitude model: thrust lost as the battery sags,
    from the accelerometer's thrust curve, :mod:`~groundstation.diagnosis.catalogue.thrust_side`), and the candidates
    left unclaimed with the size this log would claim them at."""
    s = search
    found: list[Effect] = []
    unclaimed = detectable(s.scored, s.added, s.rejected)
    if model_name != "altitude":
        return found, unclaimed
    s.say("reading the thrust curve from the accelerometer")
    tv = voltage_effect(s.prep, s.base)
    if tv is not None:
        unobs.pop("thrust_voltage", None)  # traced beside the model
        if tv.evidence["claimed"]:
            found.append(tv)
        elif tv.evidence["delta_bic"] < STRONG:  # it fitted better, and a later bar turned it away
            s.rejected.append(tv)
        else:
            size = {"n": tv.evidence["n_50"]}
            unclaimed.append({"name": tv.name, "size": size, "delta_bic": tv.evidence["delta_bic"]})
    return found, unclaimed


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
