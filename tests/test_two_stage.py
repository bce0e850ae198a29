"""The candidates through the base filter's gains (the two-stage filter, diagnosis/runs/signature.py)
score as their own filter runs do: exactly for effects linear in their parameters, and the
diagnosis finds the same with either path on simulated, foreign and real logs."""

import gc
import math
import pickle
import weakref

import numpy as np
import pytest

from drivers.replay import Replay
from groundstation.diagnosis.engine import diagnose
from groundstation.diagnosis.models import setup
from groundstation.diagnosis.runs.run import SETTLE_S, run_model
from groundstation.diagnosis.scoring import holdout, trials
from groundstation.diagnosis.scoring.gains import CatalogueColumns, fit, run_signatures, virtual_run
from groundstation.estimation.logs import load_log
from groundstation.estimation.truth import truth_from
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario

from .conftest import bench_module, foreign_file, real_file

bench_speed = bench_module("diagnosis_speed")


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """25 s of a simulated quadcopter with rotor wash on its baro and its range 60 ms late."""
    log = tmp_path_factory.mktemp("two_stage") / "f.tlog"
    hidden = ["baro_thrust:k=2.5", "sensor_delay:sensor=range,seconds=0.06"]
    run_fast(Scenario.from_args("quad", 31, 25.0, ["range_tilt"], hidden), log, log.with_suffix(".csv"))
    return log


def test_a_linear_candidate_through_the_gains_is_its_own_run(flight):
    """Each linear candidate's augmented filter from the base run's gains (Friedland's separate-bias
    form): its likelihood per sensor, its parameters and their sigma, and its height trajectory, as
    the augmented model's own run gives them. The ground effect's regressor reads the estimate, so
    there the two are near, not equal: the gains agree on whether it could be claimed (where they
    say so, the diagnosis runs it as a filter of its own)."""
    su = setup(list(Replay(flight).iter_measurements()), model_name="altitude")
    cands = su.spec.catalogue(su.prep.kinds)
    columns = CatalogueColumns.of(cands, su.model)
    base = run_model(su.model, su.prep, su.make, probes=columns.probes())
    sig = run_signatures(base, su.model.n, columns.extra())
    assert sig is not None
    t_score = su.prep.t0 + SETTLE_S
    checked = 0
    for c in cands:
        shapes = columns.by_candidate.get(id(c))
        if shapes is None:
            continue
        for shape, cols in list(shapes.items())[:3]:
            f = fit(sig, cols, shape)
            aug = c.augment(su.model) if shape is None else c.augment(su.model, shape)
            virtual = virtual_run(aug, base, sig, f.J, f.ts, t_score)
            assert callable(virtual.covariance)  # computed when read: a ranking reads few candidates' P
            real = run_model(aug, su.prep, su.make)
            if checked == 0:  # to another process (trials.portable) with its covariance computed
                again = pickle.loads(pickle.dumps(trials.portable(virtual)))
                assert not callable(again.covariance)
                np.testing.assert_array_equal(again.P, virtual.P)
            if not all(col.exact for col in cols):
                n = base.n_scored
                claimable = [-2.0 * (r.loglik - base.loglik) + (c.k + 1) * math.log(n) < -10.0 for r in (virtual, real)]
                assert claimable[0] == claimable[1], (c.name, shape, virtual.loglik - real.loglik)
                continue
            for s in real.loglik_by:
                gain_v = virtual.loglik_by[s] - base.loglik_by[s]
                gain_r = real.loglik_by[s] - base.loglik_by[s]
                assert gain_v == pytest.approx(gain_r, rel=1e-6, abs=1e-6), (c.name, shape, s)
            for col in cols:
                (vv, vs), (rv, rs) = virtual.final(col.state), real.final(col.state)
                assert vv == pytest.approx(rv, rel=1e-6, abs=1e-9), (c.name, col.state)
                assert vs == pytest.approx(rs, rel=1e-6), (c.name, col.state)
            np.testing.assert_allclose(virtual.x[:, 0], real.x[:, 0], atol=1e-7)
            last = virtual.P_rows(slice(-1, None))[0]  # (Run.final's, without the rest)
            np.testing.assert_allclose(virtual.P[:, 0, 0], real.P[:, 0, 0], rtol=1e-6)
            np.testing.assert_array_equal(virtual.P[-1], last)
            checked += 1
    assert checked >= 5  # the drift, the wash at three time constants, the scale


def test_delta_asked_for_later_is_the_one_the_first_pass_keeps(flight):
    """A ranking keeps Delta of its candidates' best shapes alone; a column asked for afterwards is
    computed by another pass over the tape, and its numbers are those a pass keeping every column
    gives, to the bit. G does not depend on which columns keep their Delta; a column let go of
    (a ranking keeps a claim's alone) is computed again when it is read."""
    su = setup(list(Replay(flight).iter_measurements()), model_name="altitude")
    columns = CatalogueColumns.of(su.spec.catalogue(su.prep.kinds), su.model)
    base = run_model(su.model, su.prep, su.make, probes=columns.probes())
    every = run_signatures(base, su.model.n, columns.extra())
    none = run_signatures(base, su.model.n, columns.extra(), delta=())
    assert every is not None and none is not None
    P = len(every.columns)
    assert P >= 4 and len(every.delta) == P and not none.delta
    np.testing.assert_array_equal(none.G_of(range(P)), every.G_of(range(P)))
    rows = base.taped.x_record
    J = [P - 1, 0, P // 2]
    np.testing.assert_array_equal(none.columns_at(rows, J), every.columns_at(rows, J))
    assert sorted(none.delta) == sorted(J)  # kept from then on, the others still not computed
    none.keep([1])
    np.testing.assert_array_equal(none.columns_at(rows[-3:], [1, 0]), every.columns_at(rows[-3:], [1, 0]))
    none.forget([2, 0])
    assert none.G.shape[1] == 2 and sorted(none.delta) == [0]
    np.testing.assert_array_equal(none.G_of([2, 0]), every.G_of([2, 0]))
    np.testing.assert_array_equal(none.G_of([3]), every.G_of([3]))  # let go of: computed again
    np.testing.assert_array_equal(none.columns_at(rows, [P - 1]), every.columns_at(rows, [P - 1]))


def test_held_out_through_the_gains_is_held_out_by_runs(flight):
    """The hold-out's blocks as sums over the others give the verdict fitted runs give, and nearly
    their gains: the runs fit a block's absence with Schmidt updates, the sums leave its readings
    out of theta's likelihood."""
    su = setup(list(Replay(flight).iter_measurements()), model_name="altitude")
    cand = next(c for c in su.spec.catalogue(su.prep.kinds) if c.name == "baro_thrust")
    columns = CatalogueColumns.of([cand], su.model)
    base = run_model(su.model, su.prep, su.make, probes=columns.probes())
    sig = run_signatures(base, su.model.n, columns.extra())
    assert sig is not None
    shapes = columns.by_candidate[id(cand)]
    shape = min(shapes, key=lambda s: abs(s - 0.5))  # the grid's time constant nearest the simulator's
    f = fit(sig, shapes[shape], shape)
    aug = cand.augment(su.model, shape)
    run = run_model(aug, su.prep, su.make)
    params = cand.params(run)
    args = (cand, aug, run, params, su.model, base, su.prep, su.make, su.prep.measurements)
    by_runs, by_gains = holdout.check(*args), holdout.check(*args, fit=f)
    assert by_runs.holds and by_gains.holds
    assert by_gains.gain == pytest.approx(by_runs.gain, rel=0.1)
    for a, b in zip(by_gains.gain_by_block, by_runs.gain_by_block):
        assert a == pytest.approx(b, rel=0.15, abs=3.0)


def _both(ms, monkeypatch, **kw):
    monkeypatch.setattr(trials, "BY_RUNS", True)
    slow = diagnose(ms, **kw)
    monkeypatch.setattr(trials, "BY_RUNS", False)
    fast = diagnose(ms, **kw)
    return slow, fast


def _as_report(d) -> dict:
    """What bench/diagnosis_speed.py compares of a report.json, from a Diagnosis."""
    return {
        "effects": [{"name": e.name, "params": e.params} for e in d.effects],
        "rejected": [{"name": e.name} for e in d.rejected],
    }


@pytest.mark.slow
@pytest.mark.parametrize("which", ["simulated", "foreign baro_thermal_s1", "crazyflie 0422-log00"])
def test_the_diagnosis_finds_the_same_through_the_gains_as_by_a_run_per_candidate(which, flight, monkeypatch):
    """The same effects, in the same order, with the same parameters (within 5 % or half a standard
    error), and the same candidates turned away, on a simulated flight with two effects, a foreign
    flight with a baro thermal error, and a Crazyflie log with motion capture."""
    if which == "simulated":
        path = flight
    elif which.startswith("foreign"):
        path = foreign_file("baro_thermal_s1.tlog")
    else:
        path = real_file("crazyflie_util/0422-log00")
    log = load_log(path, imu_columns=True)
    kw = {"source": str(path), "truth": truth_from(log.measurements, path, None), "imu": log.imu}
    if log.vehicle:
        kw["vehicle"] = log.vehicle
    slow, fast = _both(log.measurements, monkeypatch, **kw)
    same, why = bench_speed.same_findings(_as_report(slow), _as_report(fast))
    assert same, why
    assert slow.effects, "the log has something to find"
    # and the errors against truth agree
    e0 = slow.truth.error(slow.after, slow.after.t[0] + 5.0, slow.after.t[-1]) if slow.truth else math.nan
    e1 = fast.truth.error(fast.after, fast.after.t[0] + 5.0, fast.after.t[-1]) if fast.truth else math.nan
    assert e1 == pytest.approx(e0, rel=0.1, abs=0.002)


class _Checked(Exception):
    """Stops a diagnosis where a test has looked at it."""


def test_the_raw_imu_is_let_go_once_the_log_is_prepared(flight):
    """The raw IMU's columns (0.3 GB of a 1-hour 1 kHz log's) are averaged into the prepared log's
    blocks; from then on nothing of the diagnosis holds them."""
    log = load_log(flight, imu_columns=True)
    assert log.imu is not None and len(log.imu)
    raw = weakref.ref(log.imu)

    def handed_over():
        imu, log.imu = log.imu, None
        return imu

    def progress(line: str) -> None:
        if line.startswith("running the model"):
            gc.collect()
            raise _Checked(raw() is None)

    with pytest.raises(_Checked) as checked:
        diagnose(log.measurements, imu=handed_over(), progress=progress)
    assert checked.value.args == (True,)
