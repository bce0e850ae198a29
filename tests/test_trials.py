"""The candidates' filter runs spread over forked processes score exactly as they do one after
another: the ranking, the held-out evidence and a diverging candidate, on a simulated flight with
a baro effect and a late range sensor."""

import math
import subprocess
import sys
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.replay import Replay
from groundstation.core.measurement import Kind
from groundstation.diagnosis.catalogue.altitude import altitude_catalogue, with_throttle_stand_in
from groundstation.diagnosis.catalogue.candidate import Candidate
from groundstation.diagnosis.claims.leave_one_out import SETTLE_S as LEFT_OUT_SETTLE_S
from groundstation.diagnosis.claims.leave_one_out import LeftOutRuns, leave_one_out, without
from groundstation.diagnosis.models import setup
from groundstation.diagnosis.runs.run import run_model
from groundstation.diagnosis.scoring import holdout, trials
from groundstation.diagnosis.scoring.background import NICENESS, Begun
from groundstation.diagnosis.scoring.gains import CatalogueColumns
from groundstation.diagnosis.scoring.noise_match import GpsSlowBefore, match_gps_slow, sensor_noise, with_noise
from groundstation.diagnosis.scoring.trace import rank
from groundstation.diagnosis.scoring.trials import fork_map, log_profile
from groundstation.estimation.models.altitude import altitude_model
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    log = tmp_path_factory.mktemp("trials") / "f.tlog"
    hidden = ["baro_thrust:k=2.5", "sensor_delay:sensor=range,seconds=0.06"]
    sc = Scenario.from_args("quad", 31, 25.0, ["range_tilt"], hidden)
    run_fast(sc, log, log.with_suffix(".csv"))
    su = setup(list(Replay(log).iter_measurements()), model_name="altitude")
    return su, run_model(su.model, su.prep, su.make)


def blind_range(model):
    """A range row of zeros with no noise: its innovation covariance is singular (the filter diverges)."""
    meas = dict(model.measurements)
    meas["range"] = replace(meas["range"], row=lambda ctx: np.zeros((1, model.n)), R=np.zeros((1, 1)))
    return replace(model, measurements=meas)


def summary(scored):
    return [(s.name, s.candidate.sensor, s.delta_bic, s.params, s.support, s.gain_per_update) for s in scored]


@pytest.mark.slow
def test_two_workers_rank_the_catalogue_exactly_as_one(flight):
    su, base = flight
    cands = su.spec.catalogue(su.prep.kinds) + [Candidate("blind", 0, set(), "range", blind_range, None)]
    one = rank(cands, su.model, base, su.prep, su.make, su.prep.measurements)
    seen: list[str] = []
    two = rank(cands, su.model, base, su.prep, su.make, su.prep.measurements, seen.append, workers=2)
    assert seen[0] == f"{len(cands)} candidates on 2 cores"
    assert summary(two) == summary(one)
    # what was found is what the flight has: the baro's thrust term and the range 60 ms late
    by_name = {(s.name, s.candidate.sensor): s for s in two}
    assert by_name[("sensor_delay", "range")].params["seconds"] == pytest.approx(0.06, abs=0.015)
    assert by_name[("baro_thrust", "baro")].accepted
    # each run came back whole: its trajectory, its context and its model rebuilt
    for a, b in zip(one, two):
        assert np.array_equal(a.run.x, b.run.x) and a.run.model.states == b.run.model.states
        assert type(a.run.ctx) is type(b.run.ctx)
        assert sorted(a.profile) == sorted(b.profile)
    blind = by_name[("blind", "range")]
    assert blind.delta_bic == float("inf") and blind.params == {"note": "the filter diverged"}
    # one that cannot be accepted is kept as its scores and where its run ended, as soon as it is
    # scored; one that can keeps its whole run (its hold-out reads it)
    for s in two:
        ended = len(s.run.t) == 1 and s.fit is None and not s.profile
        assert ended != s.accepted, (s.name, s.accepted, len(s.run.t))


@pytest.mark.slow
def test_the_grids_scan_and_gate_rank_the_catalogue_as_every_grid_run_does(flight, monkeypatch):
    """trials.scan_grid and refine's gate leave out runs that cannot change a finding: the same
    candidates claimed, at the same Delta BIC and parameters, in the same order, as with every grid
    value and every refinement run (the diagnosis as it was made before them), in fewer runs."""
    su, base = flight
    cands = su.spec.catalogue(su.prep.kinds)
    counted = {"runs": 0}
    real_trial = trials.trial

    def trial(*args):
        counted["runs"] += 1
        return real_trial(*args)

    monkeypatch.setattr(trials, "trial", trial)
    runs = {}
    ranked = {}
    for exhaustive in (True, False):
        monkeypatch.setattr(trials, "BY_RUNS", exhaustive)
        counted["runs"] = 0
        ranked[exhaustive] = rank(cands, su.model, base, su.prep, su.make, su.prep.measurements)
        runs[exhaustive] = counted["runs"]
    claimed = {k: [x for x in summary(v) if x[2] < -10.0] for k, v in ranked.items()}
    assert claimed[False] == claimed[True] and claimed[True], claimed
    assert [s.name for s in ranked[False] if s.accepted] == [s.name for s in ranked[True] if s.accepted]
    assert runs[False] < runs[True], runs


def test_two_workers_hold_out_the_blocks_exactly_as_one(flight):
    su, base = flight
    cand = next(c for c in su.spec.catalogue(su.prep.kinds) if c.name == "baro_thrust")
    (s,) = rank([cand], su.model, base, su.prep, su.make, su.prep.measurements)
    args = (s.candidate, s.model, s.run, s.params, su.model, base, su.prep, su.make, su.prep.measurements)
    one, two = holdout.check(*args), holdout.check(*args, workers=2)
    assert two.as_dict() == one.as_dict()
    assert len(two.gain_by_block) == holdout.BLOCKS and two.holds, two.reason


def test_a_worker_that_fails_fails_the_call_with_its_error():
    """An exception in a forked worker reaches the caller as itself, not as a hang or a lost result."""

    def boom(x):
        if x == 3:
            raise ValueError(f"item {x} is bad")
        return x * x

    assert fork_map(lambda x: x * x, range(5), 2) == [0, 1, 4, 9, 16]
    with pytest.raises(ValueError, match="item 3 is bad"):
        fork_map(boom, range(5), 2)


def test_runs_begun_early_come_back_as_made_here_and_yield_the_busy_cores():
    """``Begun``: forked at a lower priority, the results are those made here with one worker, in
    order; an error in a process reaches the caller as itself; a begun run no longer wanted is
    stopped, its process gone."""
    import os

    def niceness_and_square(x):
        return os.getpriority(os.PRIO_PROCESS, 0), x * x

    mine = os.getpriority(os.PRIO_PROCESS, 0)
    got = Begun(niceness_and_square, range(4), 2).results()
    assert [sq for _, sq in got] == [0, 1, 4, 9]
    assert {n for n, _ in got} == {min(mine + NICENESS, 19)}
    assert Begun(niceness_and_square, range(4), 0).results() == [(mine, x * x) for x in range(4)]

    def boom(x):
        if x == 2:
            raise ValueError(f"item {x} is bad")
        return x

    with pytest.raises(ValueError, match="item 2 is bad"):
        Begun(boom, range(4), 2).results()
    begun = Begun(lambda x: __import__("time").sleep(60), [1], 2)
    ((proc, _, _),) = begun._running
    begun.close()
    assert not proc.is_alive() and proc.exitcode is not None


@pytest.mark.parametrize("processes", [0, 2])
def test_runs_forked_held_start_with_what_go_gives_them(processes):
    """``Begun(held=True)``: forked now, each run made with the arguments :meth:`go` sends later,
    as made here; collected before they were started is an error, not a hang; held ones let go of
    are stopped, their processes gone."""
    import os

    parent = os.getpid()
    begun = Begun(lambda scale, shift, x: (scale * x + shift, os.getpid() != parent), range(5), processes, held=True)
    with pytest.raises(RuntimeError, match="before they were started"):
        begun.results()
    begun.go(10, 1)
    assert begun.results() == [(10 * x + 1, processes > 0) for x in range(5)]
    never = Begun(lambda x: x, range(3), 2, held=True)
    procs = [proc for proc, _, _ in never._running]
    assert len(procs) == 2 and all(proc.is_alive() for proc in procs)
    never.close()
    assert not any(proc.is_alive() for proc in procs)


def test_a_trial_begun_beside_the_base_run_is_the_rankings_own(flight):
    """The range's tilt, begun on a forked process before the ranking (``trials.Started``), ranks as
    the ranking's own run of it; a begun trial the ranking does not ask for is stopped, its process
    gone; an error in a begun trial reaches the caller as itself."""
    su, base = flight
    tilt = next(c for c in su.spec.catalogue(su.prep.kinds) if c.name == "range_tilt")
    one = rank([tilt], su.model, base, su.prep, su.make, su.prep.measurements)
    started = trials.Started([(tilt, None)], su.model, su.prep, su.make, su.prep.measurements)
    two = rank([tilt], su.model, base, su.prep, su.make, su.prep.measurements, started=started)
    assert summary(two) == summary(one)
    assert np.array_equal(two[0].run.x, one[0].run.x) and two[0].run.model.states == one[0].run.model.states

    unasked = trials.Started([(tilt, None)], su.model, su.prep, su.make, su.prep.measurements)
    ((proc, _),) = unasked._running.values()
    assert unasked.take([]) == {} and not proc.is_alive() and proc.exitcode is not None

    def no_estimator(model):
        raise ValueError("no estimator for this model")

    broken = trials.Started([(tilt, None)], su.model, su.prep, no_estimator, su.prep.measurements)
    with pytest.raises(ValueError, match="no estimator for this model"):
        broken.take([tilt])
    assert not broken._running


def test_a_trial_runs_untaped_and_taped_again_once_added_it_is_the_same_run(flight):
    """A candidate's trial keeps no gains or probes (only an added effect's run starts the next
    ranking); the added effect's run made again with them is the trial's, number for number, and
    its other trials are let go once it is scored."""
    su, base = flight
    tilt = next(c for c in su.spec.catalogue(su.prep.kinds) if c.name == "range_tilt")
    r = trials.trial(tilt, None, su.model, su.prep, su.make, su.prep.measurements)
    assert r is not None and r.taped is None
    columns = CatalogueColumns.of(su.spec.catalogue(su.prep.kinds), su.model)
    again = run_model(r.model, su.prep, su.make, measurements=su.prep.measurements, probes=columns.probes())
    assert again.taped is not None and again.taped.probes is not None
    assert again.loglik == r.loglik and np.array_equal(again.x, r.x) and np.array_equal(again.P, r.P)
    assert all(np.array_equal(again.sensors[s].nu, r.sensors[s].nu) for s in r.sensors)

    made = trials.Trials([tilt], su.model, su.prep, su.make, su.prep.measurements)
    kept = made.run(0, None)
    made.runs[0]["other"] = r
    made.settle(0, [kept])
    assert list(made.runs[0].values()) == [kept]


def test_a_candidates_runs_below_its_best_keep_their_scores_and_ends_only(flight):
    """Of a shaped candidate's runs only the best stays whole; the others keep their likelihoods,
    their innovations and where they ended, the same numbers as their whole runs."""
    su, _ = flight
    thrust = next(c for c in su.spec.catalogue(su.prep.kinds) if c.name == "baro_thrust" and len(c.shapes) > 1)
    ms = su.prep.measurements
    whole = {k: trials.trial(thrust, k, su.model, su.prep, su.make, ms) for k in thrust.shapes}
    made = trials.Trials([thrust], su.model, su.prep, su.make, ms)
    for k in thrust.shapes:
        made.run(0, k)
    best = max(whole, key=lambda k: whole[k].loglik)
    for k, r in made.runs[0].items():
        w = whole[k]
        assert r.loglik == w.loglik and r.loglik_by == w.loglik_by
        assert all(np.array_equal(r.sensors[s].nu, w.sensors[s].nu) for s in w.sensors)
        assert np.array_equal(r.x[-1], w.x[-1]) and np.array_equal(r.P[-1], w.P[-1])
        assert (len(r.x) == len(w.x)) == (k == best)
    assert np.array_equal(made.runs[0][best].P, whole[best].P)

    shape, r = log_profile(lambda x: made.run(0, x), thrust.shapes)
    assert r is not None and len(r.x) == len(whole[best].x) and r.loglik >= whole[best].loglik


@pytest.mark.parametrize("jobs", ["0", "-2", "two"])
def test_diagnose_with_no_cores_to_run_on_is_one_line(tmp_path, jobs):
    log = tmp_path / "f.tlog"
    log.write_bytes(b"")
    r = subprocess.run(
        [sys.executable, "-m", "groundstation", "diagnose", str(log), "--jobs", jobs], capture_output=True, text=True
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last.endswith(f"argument --jobs: expected a whole number of 1 or more, got {jobs!r}")


def test_a_prepared_log_leaves_out_the_readings_no_estimator_takes_and_counts_them(flight):
    """Checked once when the log is prepared, not on each run: a NaN and an impossible pressure are
    left out, counted by kind and problem, and the runs on what is left are what the estimator's
    own check gives."""
    from groundstation.core.measurement import Kind
    from groundstation.diagnosis.runs.run import prepare
    from groundstation.diagnosis.runs.signals import add_signal_rules

    su, base = flight
    ms = list(su.prep.measurements)
    baro = [i for i, m in enumerate(ms) if m.kind is Kind.BARO_PRESSURE]
    ms[baro[100]] = ms[baro[100]]._replace(value=np.array([np.nan]))
    ms[baro[200]] = ms[baro[200]]._replace(value=np.array([3.0e6]))
    prep = prepare(ms)
    assert prep.unusable == {"baro_pressure_not_finite": 1, "baro_pressure_implausible": 1}
    assert len(prep.measurements) == len(prepare(su.prep.measurements).measurements) - 2
    checked_here = run_model(su.model, prep, su.make)
    est = su.make(su.model)  # the same readings, each checked by the estimator itself
    add_signal_rules(est)
    for m in ms:
        est.handle(m)
    bad = {k: v for k, v in est.counters.skipped.items() if k.endswith(("_not_finite", "_implausible"))}
    assert bad == prep.unusable
    np.testing.assert_array_equal(checked_here.sensors["baro"].nu, est.filter.log.arrays("baro")["nu"])


class Scored:
    """What log_profile reads of a run: its log-likelihood."""

    def __init__(self, loglik: float) -> None:
        self.loglik = loglik


@pytest.mark.parametrize("peak", [0.37, 0.12, 4.0])
def test_a_time_constant_is_read_off_its_log_likelihood_profile_between_and_beyond_its_grid(peak):
    """A likelihood peaked at ``peak`` in log(tc), as a rotor wash's is: found to within 3 % from the
    grid (0.15, 0.5, 1.5), inside it, below its first value and carried beyond its last."""
    tried = []

    def run_at(tc):
        tried.append(tc)
        return Scored(-200.0 * (np.log(tc) - np.log(peak)) ** 2)

    tc, r = log_profile(run_at, (0.15, 0.5, 1.5))
    assert tc == pytest.approx(peak, rel=0.03), tried
    assert r.loglik == max(-200.0 * (np.log(t) - np.log(peak)) ** 2 for t in tried)
    assert len(tried) <= 8, tried  # a handful of runs, not a fine grid


def test_a_diverged_run_in_a_profile_is_the_worst_there_is_not_an_error():
    tc, r = log_profile(lambda t: None if t > 1.0 else Scored(-((t - 0.6) ** 2)), (0.15, 0.5, 1.5))
    assert r is not None and 0.45 < tc < 0.8


def test_a_throttle_stand_in_holds_the_rotor_wash_at_its_default_time_constant():
    """Motors on or off from vibration (a Crazyflie log) have no time course a wash's time constant
    could be read from: the catalogue then offers baro_thrust at 0.5 s alone."""
    kinds = {Kind.BARO_PRESSURE, Kind.RANGE, Kind.ACCEL, Kind.ATTITUDE, Kind.THROTTLE}
    full = {c.name: c for c in altitude_catalogue(kinds)}
    held = {c.name: c for c in with_throttle_stand_in(altitude_catalogue(kinds))}
    assert full["baro_thrust"].refine_shape and len(full["baro_thrust"].shapes) >= 3
    assert held["baro_thrust"].shapes == () and not held["baro_thrust"].refine_shape
    assert held["baro_thrust"].augment(altitude_model()).options["throttle_tcs"] == (0.5,)


def test_two_workers_leave_each_sensor_out_exactly_as_one(flight):
    """The leave-one-out evidence (each absolute sensor predicted by the others, before and after
    an effect) gives the same numbers from forked runs as from runs one after another. (The effect
    here is estimated, not fixed as the engine fixes it: with the baro left out nothing learns it,
    so before and after agree; what is checked is the fork.)"""
    su, base = flight
    cand = next(c for c in su.spec.catalogue(su.prep.kinds) if c.name == "baro_thrust")
    (s,) = rank([cand], su.model, base, su.prep, su.make, su.prep.measurements)
    after = s.model
    one = leave_one_out(su.model, after, su.prep, su.make, su.prep.measurements)
    two = leave_one_out(su.model, after, su.prep, su.make, su.prep.measurements, workers=2)
    assert [x.as_dict() for x in two] == [x.as_dict() for x in one]
    assert {x.sensor for x in one} == {"baro", "range"} and all(x.n > 0 for x in one)


def test_a_run_read_for_its_scores_is_the_full_run_without_its_covariances(flight):
    """``run_model(scores_only=True)``, the leave-one-out runs' and a linear model's trials' form: the
    same innovations, states and likelihood as the full run, and of the covariances the last alone
    (where the run ended); asked for more, it says so."""
    su, base = flight
    full = run_model(su.model, su.prep, su.make)
    lean = run_model(su.model, su.prep, su.make, scores_only=True)
    assert lean.loglik == full.loglik and lean.sensors.keys() == full.sensors.keys()
    for name, tr in full.sensors.items():
        np.testing.assert_array_equal(lean.sensors[name].nu, tr.nu)
    np.testing.assert_array_equal(lean.t, full.t)
    np.testing.assert_array_equal(lean.x, full.x)
    np.testing.assert_array_equal(lean.P_rows(slice(-1, None)), full.P[-1:])
    assert lean.final("z") == full.final("z")
    for asked in (lambda: lean.P, lambda: lean.P_rows(slice(0, 10))):
        with pytest.raises(ValueError, match="last covariance alone"):
            asked()


def test_the_model_befores_runs_forked_early_are_the_noise_matched_models_own(flight):
    """The leave-one-out runs of the model before, forked before the noise is matched and started with
    it (``LeftOutRuns.before``), score each sensor left out as a run of the matched model itself does,
    and not as the declared model would."""
    su, _ = flight
    matched = with_noise(su.model, {s: 4.0 * r for s, r in sensor_noise(su.model).items()})
    runs = LeftOutRuns(su.model, su.prep, su.make, None, 2)
    try:
        runs.before(matched)
        runs.then(matched, su.prep.measurements)
        got = runs.results()
    finally:
        runs.close()

    def rms(model, name):
        tr = run_model(without(model, name), su.prep, su.make).sensors[name]
        nu = tr.nu[tr.t >= su.prep.t0 + LEFT_OUT_SETTLE_S]
        return float(np.sqrt(np.mean(np.sum(nu * nu, axis=1))))

    assert {x.sensor for x in got} == {"baro", "range"}
    for x in got:
        assert x.before == x.after == rms(matched, x.sensor) != rms(su.model, x.sensor)


@pytest.mark.slow
def test_the_gps_slow_error_is_chosen_the_same_on_forked_processes_and_on_a_spare_core(tmp_path):
    """``match_gps_slow`` over its levels on two processes, and the model before's on a process forked
    before the noise is known (``GpsSlowBefore``, as the diagnosis begins it), choose the level one
    process chooses, with the same run."""
    log = tmp_path / "gps.tlog"
    run_fast(Scenario.from_args("quad", 12, 25.0, [], ["baro_thrust:k=2.5"]), log, log.with_suffix(".csv"))
    ms = [m for m in Replay(log).iter_measurements() if m.kind != Kind.RANGE]  # no range: the GPS is measured
    su = setup(ms, model_name="altitude")
    assert "b_gps" in su.model.states
    matched = with_noise(su.model, {s: 2.0 * r for s, r in sensor_noise(su.model).items()})
    base = run_model(matched, su.prep, su.make)
    one = match_gps_slow(matched, su.prep, su.make, base=base)
    two = match_gps_slow(matched, su.prep, su.make, base=base, workers=2)
    later = GpsSlowBefore(su.model, su.prep, su.make, 1)
    try:
        later.start(matched)
        spare = later.chosen(matched, base)
    finally:
        later.close()
    assert one[2] is not base  # a level other than the model's own: a run of its own, come back from a process
    for _, level, run in (two, spare):
        assert level is not None and one[1] is not None and level.as_dict() == one[1].as_dict()
        assert run.loglik == one[2].loglik and np.array_equal(run.x, one[2].x)
        assert run.model.P0.tolist() == one[2].model.P0.tolist()


def test_held_processes_end_when_their_parent_is_killed(tmp_path):
    """A held run's process waits for its start; its parent killed outright (nothing closed, no
    clean-up), it notices and ends instead of waiting for ever with the log in its memory."""
    import os
    import signal
    import time

    from groundstation.diagnosis.scoring.background import PARENT_CHECK_S

    script = (
        "import sys, time\n"
        "from groundstation.diagnosis.scoring.background import Begun\n"
        "b = Begun(lambda x: x, range(4), 2, held=True)\n"
        "print(*[p.pid for p, _, _ in b._running], flush=True)\n"
        "time.sleep(600)\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)

    def alive(pid: int) -> bool:
        try:
            with open(f"/proc/{pid}/stat") as f:
                return f.read().rsplit(")", 1)[1].split()[0] != "Z"  # a zombie has ended
        except OSError:
            return False

    held: list[int] = []
    try:
        assert parent.stdout is not None
        held = [int(x) for x in parent.stdout.readline().split()]
        assert len(held) == 2 and all(alive(pid) for pid in held)
        parent.kill()
        parent.wait()
        deadline = time.monotonic() + 20 * PARENT_CHECK_S
        while any(alive(pid) for pid in held) and time.monotonic() < deadline:
            time.sleep(PARENT_CHECK_S / 5)
        assert not any(alive(pid) for pid in held)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        for pid in held:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)


@pytest.mark.slow
def test_the_model_afters_left_out_runs_begun_at_the_effect_added_are_its_own(tmp_path, monkeypatch):
    """The diagnosis begins the model after's left-out runs when it adds an effect, before its last
    ranking and the effects' joint estimate (``Search.on_added``); where nothing moves after, the
    report reads those. Each is the run of the model the diagnosis ends with, with that sensor left out,
    over the same readings; begun again (``LeftOutRuns.then``), the earlier ones are stopped."""
    from groundstation.diagnosis.engine import diagnose

    log = tmp_path / "w.tlog"
    run_fast(Scenario.from_args("quad", 5, 30.0, [], ["baro_thrust:k=2.5"]), log, log.with_suffix(".csv"))
    begun: list[tuple] = []
    then = LeftOutRuns.then

    def recorded(self, after, stream):
        begun.append((self._prep, self._make, after, stream, self._after))
        then(self, after, stream)

    monkeypatch.setattr(LeftOutRuns, "then", recorded)
    d = diagnose(list(Replay(log).iter_measurements()), model_name="altitude", workers=2)
    assert [e.name for e in d.effects] == ["baro_thrust"]
    assert len(begun) == 1  # begun as the effect was added; not again once the search had ended
    prep, make, after, stream, earlier = begun[0]
    assert earlier is None and after is not d.after.model and d.after.model.n == after.n
    assert {x.sensor for x in d.left_out} == {"baro", "range"}
    for x in d.left_out:
        tr = run_model(without(d.after.model, x.sensor), prep, make, measurements=stream).sensors[x.sensor]
        nu = tr.nu[tr.t >= prep.t0 + LEFT_OUT_SETTLE_S]
        assert x.after == float(np.sqrt(np.mean(np.sum(nu * nu, axis=1))))


def test_left_out_runs_begun_again_replace_those_begun_before(flight):
    su, _ = flight
    louder = with_noise(su.model, {s: 4.0 * r for s, r in sensor_noise(su.model).items()})
    runs = LeftOutRuns(su.model, su.prep, su.make, None, 2)
    try:
        runs.before(su.model)
        runs.then(louder, su.prep.measurements)
        first = runs._after
        runs.then(su.model, su.prep.measurements)
        assert first is not None and not first._running  # stopped, its processes joined
        got = runs.results()
    finally:
        runs.close()
    assert got and all(x.before == x.after for x in got)  # the model before's own, not the louder one's


def test_a_wash_time_constant_is_not_carried_past_what_a_wake_takes_to_settle():
    """A profile that still rises at its longest shape (a slow error the baro and the GPS share outdoors,
    which a wash of ever longer lag fits) is carried outward no further than ``most``, the end of the
    two-stage filter's grid (gains.WASH_GRID), and the shapes beyond it are not run; a profile with its
    peak inside is refined to it as before."""
    from groundstation.diagnosis.scoring.gains import WASH_GRID

    def run_at(lik):
        asked = []

        def at(shape):
            asked.append(shape)
            return SimpleNamespace(loglik=lik(math.log(shape)))

        return at, asked

    rising, asked = run_at(lambda v: 100.0 * v)
    shape, r = log_profile(rising, (0.15, 0.5, 1.5, 3.0), most=WASH_GRID[-1])
    assert shape == pytest.approx(WASH_GRID[-1], rel=1e-3) and max(asked) <= WASH_GRID[-1] + 1e-9, asked
    assert 1.5 <= WASH_GRID[-1] <= 2.5  # a couple of seconds (catalogue.altitude.WASH_TCS)
    unbounded, asked = run_at(lambda v: 100.0 * v)
    assert log_profile(unbounded, (0.15, 0.5, 1.5))[0] > 4.0  # without the bound: 4.5 s and more
    peaked, asked = run_at(lambda v: -100.0 * (v - math.log(0.35)) ** 2)
    assert log_profile(peaked, (0.15, 0.5, 1.5), most=WASH_GRID[-1])[0] == pytest.approx(0.35, rel=0.02)
