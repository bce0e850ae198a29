"""Steps 1 to 5 of a diagnosis (docs/diagnosis.md): the model run on the log with the log's own noise, then, one effect
at a time, the catalogue ranked through the filter (:mod:`~groundstation.diagnosis.scoring.trace`), the best candidate
that holds out of sample (:mod:`~groundstation.diagnosis.scoring.holdout`) and is not contradicted by truth added to the
model, or a correlate outside the catalogue (:mod:`.discovered`) where the log prefers it by strong evidence; until the
residuals pass or nothing more is claimed.

:class:`Search` holds what the loop carries from one effect to the next (the model, its run, the
measurements it reads, the candidates left) and what it found; each ranking's candidates live in
its own step and are let go of with it."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

from groundstation.core.measurement import Measurement
from groundstation.diagnosis.catalogue.altitude import with_throttle_stand_in
from groundstation.diagnosis.catalogue.candidate import Candidate
from groundstation.diagnosis.claims.detect import residuals_pass, sensor_findings
from groundstation.diagnosis.claims.discover import Discovery
from groundstation.diagnosis.claims.discovered import DISCOVERY_MARGIN, rival_discovery, taken
from groundstation.diagnosis.effect import Effect
from groundstation.diagnosis.models import Setup
from groundstation.diagnosis.runs.run import Prepared, Run, hold_zeros, run_model
from groundstation.diagnosis.runs.signature import Probes
from groundstation.diagnosis.scoring import holdout, trials
from groundstation.diagnosis.scoring.gains import CatalogueColumns
from groundstation.diagnosis.scoring.noise_match import NoiseLevel, match_gps_slow, match_noise
from groundstation.diagnosis.scoring.scored import Scored, smallest_claimed
from groundstation.diagnosis.scoring.trace import rank, realise
from groundstation.estimation.models.base import LinearModel
from groundstation.estimation.truth import Truth

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


def start_trials(
    cands: list[Candidate], model: LinearModel, prep: Prepared, make, columns: CatalogueColumns | None, workers: int
) -> trials.Started | None:
    """With cores to spare, the one trial each of the candidates without columns of their own (those the first ranking
    runs when their screen could be claimed, and those it always runs), begun beside the base run, one on each core but
    the one that makes it (:class:`~groundstation.diagnosis.scoring.trials.Started`)."""
    if workers < 2 or columns is None or trials.BY_RUNS:
        return None
    own = [c for c in cands if id(c) not in columns.by_candidate]
    own.sort(key=lambda c: id(c) in columns.screens)  # those always run first
    tasks = [(c, keys[0]) for c in own if len(keys := trials.first_keys(c)) == 1 and not c.delays]
    if not tasks:
        return None
    return trials.Started(tasks[: workers - 1], model, prep, make, prep.measurements)


@dataclass
class Search:
    """The search's state (the module's docstring). Made by :meth:`begin` (steps 1 and 2), run by
    :meth:`run` (steps 3 to 5)."""

    setup: Setup
    say: Callable[[str], None]
    workers: int
    #: truth for the veto (:func:`_contradicted`), None without one or with the veto off
    truth: Truth | None
    model0: LinearModel  #: the model the effects are added to: the declared one, its noise the log's
    first: Run  #: the run before any effect (the error "before")
    noise: list[NoiseLevel]
    columns: CatalogueColumns | None  #: every candidate's columns, for runs that may start a ranking
    model: LinearModel  #: as found so far ...
    base: Run  #: ... its run ...
    stream: Sequence[Measurement]  #: ... and the measurements it reads (a delay's shifted ones)
    cands: list[Candidate]  #: the candidates still to try
    started: trials.Started | None = None  #: the first ranking's trials, begun beside the base run
    effects: list[Effect] = field(default_factory=list)
    added: list[Candidate] = field(default_factory=list)  #: each effect's candidate, in step
    labels: list[str] = field(default_factory=list)
    rejected: list[Effect] = field(default_factory=list)
    ranking: list[list[tuple[str, float]]] = field(default_factory=list)  #: per step
    discoveries: list[Discovery] = field(default_factory=list)
    tried: set[tuple[str, str]] = field(default_factory=set)  #: (sensor, expression) of discoveries tried
    scored: list[Scored] = field(default_factory=list)  #: the last ranking, as its scores
    #: the model after's process noise against the model's (engine._together): 1 where the model's stays
    process_scale: float = 1.0
    #: told of each effect the search adds, once the model and its run hold it (the engine begins then
    #: what the model after needs, in case the search ends there)
    on_added: Callable[[Search], object] = lambda _search: None

    @property
    def prep(self) -> Prepared:
        return self.setup.prep

    @property
    def make(self):
        return self.setup.spec.make

    def probes(self) -> Probes | None:
        return self.columns.probes() if self.columns is not None else None

    @classmethod
    def begin(
        cls,
        su: Setup,
        *,
        say: Callable[[str], None],
        workers: int,
        truth: Truth | None,
        matched: Callable[[LinearModel], object] = lambda _model: None,
        gps_slow_later: bool = False,
        on_added: Callable[[Search], object] = lambda _search: None,
    ) -> Search:
        """Steps 1 and 2: each sensor's noise matched to the log, the absolute sensors' zeros held, the
        model run (before); with cores to spare the first ranking's own trials begun beside it.
        ``matched`` is given the model with its noise matched as soon as it is known, before anything
        else is made (what it forks holds the log alone). ``gps_slow_later``: the run before is the
        model's own for now, the GPS's slow error chosen for it later
        (:class:`~groundstation.diagnosis.scoring.noise_match.GpsSlowBefore`). ``on_added``: see :attr:`on_added`."""
        prep, make, model = su.prep, su.spec.make, su.model
        cands = [
            c
            for c in su.spec.catalogue(prep.kinds)
            if c.name not in su.declared and (c.needs_option is None or c.needs_option in model.options)
        ]
        if not prep.logged_throttle:
            cands = with_throttle_stand_in(cands)
        # a linear model's candidates as columns (a nonlinear one is run candidate by candidate)
        columns = CatalogueColumns.of(cands, model) if model.f is None and not trials.BY_RUNS else None
        probes = columns.probes if columns is not None else lambda: None
        say("matching the sensors' noise to the log")
        model, noise, matched_run = _noise_matched(model, prep, make, probes())
        matched(model)
        started = start_trials(cands, model, prep, make, columns, workers)
        try:
            say("running the model (before)")
            base = matched_run if matched_run is not None else run_model(model, prep, make, probes=probes())
            # before: the model as the log's noise has it, the GPS's slow error included; the effects are
            # traced against the GPS at the floor of that error (noise_match.match_gps_slow says why)
            first = base if gps_slow_later else match_gps_slow(model, prep, make, base=base)[2]
        except BaseException:
            if started is not None:
                started.close()
            raise
        stream = prep.measurements
        return cls(
            su, say, workers, truth, model, first, noise, columns, model, base, stream, cands, started,
            on_added=on_added,
        )  # fmt: skip

    def run(self) -> None:
        """Steps 3 to 5, an effect at a time (at most :data:`MAX_EFFECTS`), until the residuals pass or
        nothing more is claimed."""
        for k in range(MAX_EFFECTS):
            if not self.cands:
                break
            more = self._step()
            if more is None:
                break
            if more and self.cands and k + 1 < MAX_EFFECTS:
                # the next ranking lets go of this one first; let go now, before what is begun for the
                # effect added forks (a forked process keeps every page its parent frees after it)
                self.scored = []
            self.on_added(self)
            if not more:
                break

    def _step(self) -> bool | None:
        """One effect found and added (whether to look for another), or none (None). What the ranking scored
        lives in this step (the one added in the model and its run)."""
        self.scored = []  # the last ranking's candidates hold its signatures and runs: let go first
        self.scored = self._rank()
        best, held = self._claim()
        rival = self._rival(best)
        if rival is not None:
            self._take_discovery(*rival)
        elif best is None:
            return None
        else:
            self._take(best, held)
        return not residuals_pass(sensor_findings(self.base))

    def _rank(self) -> list[Scored]:
        """Step 3: the candidates left, ranked through the filter (the first ranking takes the trials
        begun beside the base run)."""
        try:
            scored = rank(
                self.cands,
                self.model,
                self.base,
                self.prep,
                self.make,
                self.stream,
                lambda s: self.say(f"trying {s}"),
                workers=self.workers,
                columns=self.columns,
                exact_gains=self.setup.spec.exact_gains,
                started=self.started,
            )
        finally:
            if self.started is not None:
                self.started.close()
                self.started = None
        self.ranking.append([(_label(s), round(s.delta_bic, 1)) for s in scored])
        _as_ended((s for s in scored if not s.accepted), self.base)
        return scored

    def _claim(self) -> tuple[Scored | None, holdout.Holdout | None]:
        """Step 4: the first accepted candidate, in the ranking's order, that truth does not contradict
        and that holds out of sample; each one before it is rejected, with why, and not tried again."""
        for s in (s for s in self.scored if s.accepted):
            veto = _contradicted(self.truth, self.base, s) if self.truth is not None else None
            if veto is None:
                self.say(f"holding out {_label(s)}")
                ho = holdout.check(
                    s.candidate,
                    s.model,
                    s.run,
                    s.params,
                    self.model,
                    self.base,
                    self.prep,
                    self.make,
                    self.stream,
                    s.profile,
                    workers=self.workers,
                    fit=s.fit,
                    delta_bic_effective=s.delta_bic_effective,
                )
                if ho.holds:
                    return s, ho
                evidence = {"delta_bic": round(s.delta_bic, 1), "sensor": s.candidate.sensor, "reason": ho.reason}
                veto = Effect(s.name, s.params, {**evidence, **ho.as_dict()})
                self.say(f"rejected {s.name}: {ho.reason}")
            else:
                self.say(f"rejected {s.name}: worse against {veto.evidence['against']}")
            self.rejected.append(veto)
            self._drop(s.candidate)
        return None, None

    def _rival(self, best: Scored | None) -> tuple[Discovery, Effect] | None:
        """Outside the catalogue, as a rival: a correlate of a failing sensor's innovations that the log
        prefers to the catalogue's best by strong evidence (held to the end, a baro error of 0.06 m per
        (m/s)^2 of climb was first taken for a baro delay of 0.15 s, which it beats by 208 in Delta BIC)."""
        findings = sensor_findings(self.base)
        if residuals_pass(findings):
            return None
        rival = rival_discovery(
            self.base, self.model, self.prep, self.make, self.stream, findings, set(), workers=self.workers
        )
        bar = (best.delta_bic if best is not None else math.inf) - DISCOVERY_MARGIN
        return rival if rival is not None and rival[1].evidence["delta_bic"] < bar else None

    def _take_discovery(self, d: Discovery, found: Effect) -> None:
        self.say(f"added the discovered {d.expression} on the {d.sensor} ({found.evidence['delta_bic']:.0f})")
        self.tried.add((d.sensor, d.expression))
        self.discoveries.append(d)
        self.added.append(found.evidence["candidate"])
        self.labels.append("discovered")
        self.model, self.base = taken(found, self.prep, self.make, self.stream, self.probes())
        self.effects.append(found)

    def _take(self, best: Scored, held: holdout.Holdout | None) -> None:
        """Step 5: the best candidate added, with its own run, which the next ranking starts from."""
        base = self.base
        _as_ended((s for s in self.scored if s is not best), base, best.run)
        if base is not best.run:
            # the ranking it started is done: from here on only the new base's gains are read (and
            # the run before, kept for the report, would hold its own to the end)
            base.taped = None
        if best.run.through_gains:
            # scored through the base filter's gains: the effect's own run, which the next ranking starts from
            self.say(f"running the model with {_label(best)}")
            realise(best, base, self.prep, self.make, self.probes())
        elif best.run.taped is None and self.columns is not None:
            # its trial's run, untaped (trials.trial): again with the gains and probes the next ranking reads
            self.say(f"running the model with {_label(best)}")
            best.run = run_model(
                best.model, self.prep, self.make, measurements=best.measurements or None, probes=self.probes()
            )
        # the next one down that is another effect, not another form of this one
        runner_up = next((s for s in self.scored[self.scored.index(best) + 1 :] if _label(s) != _label(best)), None)
        self.effects.append(Effect(best.name, best.params, _evidence(best, base, held, runner_up)))
        self.added.append(best.candidate)
        self.labels.append(_label(best))
        self.model, self.base, self.stream = best.model, best.run, best.measurements
        self._drop(best.candidate)
        if best.name == "baro_bias_drift":
            self.cands = [c for c in self.cands if c.name != "baro_bias_drift"]
        self.say(f"added {best.name} ({best.delta_bic:.0f})")

    def _drop(self, c: Candidate) -> None:
        self.cands = [k for k in self.cands if not (k.name == c.name and k.sensor == c.sensor)]


def _noise_matched(
    model: LinearModel, prep: Prepared, make, probes: Probes | None
) -> tuple[LinearModel, list[NoiseLevel], Run | None]:
    """The model with each sensor's noise the log shows
    (:func:`~groundstation.diagnosis.scoring.noise_match.match_noise`), and its run where that run can be the base
    (None: the first run, taken before the absolute sensors' zeros were held, reads them otherwise than every run after
    it). The first run, a long log's largest object, ends here."""
    first_run = run_model(model, prep, make)
    hold_zeros(prep, first_run)  # the absolute sensors' zeros, the same for every model from here on
    model, noise, matched = match_noise(model, prep, make, probes, first=first_run)
    return model, noise, (None if matched is first_run else matched)


def _evidence(best: Scored, base: Run, held: holdout.Holdout | None, runner_up: Scored | None) -> dict:
    """An added effect's evidence: its scores, where it acts, its hold-out, and its runner-up."""
    return {
        "delta_bic": round(best.delta_bic, 1),
        "sensor": best.candidate.sensor,
        **({"form": best.candidate.form} if best.candidate.form else {}),
        "loglik_gain": round(best.run.loglik - base.loglik, 1),
        "gain_per_update": round(best.gain_per_update, 4),
        "support": best.support,
        # the evidence at the innovations' effective sample size (trace's docstring)
        "delta_bic_effective": round(best.delta_bic_effective, 1),
        "innovation_colour": {k: round(v, 2) for k, v in best.run.inflation.items()},
        **(held.as_dict() if held is not None else {}),
        "runner_up": _label(runner_up) if runner_up else None,
        "runner_up_delta_bic": round(runner_up.delta_bic, 1) if runner_up else None,
        **_alternative(best, runner_up),
    }


def _as_ended(scored: Iterable[Scored], *kept: Run) -> None:
    """Candidates that will not be added, as their scores and where their runs ended (:func:`.run.
    ending`): their trajectories, tapes, fits and profiles let go of, but ``kept``'s runs (a
    candidate scored as the base itself shares its run). Only the base and the added effect's run
    start a ranking; of the others the size they would be claimed at is read (:func:`detectable`)."""
    for s in scored:
        if all(s.run is not k for k in kept):
            s.end()


def detectable(scored: list[Scored], added: list[Candidate], rejected: list[Effect]) -> list[dict]:
    """The candidates of the last ranking left unclaimed, each with the size this log would claim it
    at about half the time (scored.smallest_claimed). When the effect added last ended the search
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
    """A candidate's name, with a delay's sensor and its form (a GPS's fix, or its height alone)."""
    c = s.candidate
    return s.name + (f"({', '.join(x for x in (c.sensor, c.form) if x)})" if c.delays else "")


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
