"""The altitude filter and the estimation loop, against the document and the simulator's truth."""

import csv
import math
import time

import numpy as np
import pytest
from scipy.stats import chi2

from drivers.replay import Replay
from groundstation.core.measurement import Kind, Measurement
from groundstation.estimation.filters import InnovationLog, InnovationRecord
from groundstation.estimation.loop import EstimationLoop
from groundstation.estimation.models.altitude import altitude_model
from groundstation.estimation.models.base import (
    discretize,
    discretize_series,
    observability_rank,
)
from groundstation.estimation.routing import altitude_estimator, horizontal_estimator
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario


def test_exact_discretisation_reproduces_the_documents_closed_forms():
    m = altitude_model(G_acc=0.7, G_bias=0.3)
    T, Ga, Gb = 0.01, 0.7, 0.3
    Phi, G, Qk = discretize(m.A(None), m.B, m.Qc, T)
    np.testing.assert_allclose(Phi, [[1, T, -(T**2) / 2], [0, 1, -T], [0, 0, 1]], atol=1e-15)  # (9.14)
    np.testing.assert_allclose(G[:, 0], [T**2 / 2, T, 0], atol=1e-15)  # (9.16)
    np.testing.assert_array_equal(G[:, 1], 0.0)  # cos_tilt acts through A only (the bias's share)
    Q924 = np.array(
        [
            [T**3 / 3 * Ga + T**5 / 20 * Gb, T**2 / 2 * Ga + T**4 / 8 * Gb, -(T**3) / 6 * Gb],
            [T**2 / 2 * Ga + T**4 / 8 * Gb, T * Ga + T**3 / 3 * Gb, -(T**2) / 2 * Gb],
            [-(T**3) / 6 * Gb, -(T**2) / 2 * Gb, T * Gb],
        ]
    )
    np.testing.assert_allclose(Qk, Q924, rtol=1e-9, atol=1e-18)  # (9.24)


def test_the_series_discretisation_matches_the_exponentials_where_the_filter_uses_it():
    """Input-dependent and nonlinear models sum the integrals as a series while |A| dt < 0.2
    (filters.SERIES_LIMIT): there it must agree with Van Loan's exponentials."""
    from groundstation.estimation.filters import SERIES_LIMIT

    rng = np.random.default_rng(0)
    for _ in range(20):
        A = rng.standard_normal((6, 6))
        A *= SERIES_LIMIT / np.abs(A).sum(axis=1).max()
        B, Qc = rng.standard_normal((6, 2)), np.diag(rng.uniform(0.0, 1.0, 6))
        for exact, series, tol in zip(discretize(A, B, Qc, 1.0), discretize_series(A, B, Qc, 1.0), (1e-6, 1e-6, 5e-5)):
            assert np.abs(series - exact).max() <= tol * np.abs(exact).max()


def test_a_longer_step_is_halved_and_doubled_to_the_exponentials_accuracy():
    """Past |A| dt = 0.2 (a 10 Hz log's step, a stiff A) the series is summed over dt / 2^s and
    doubled back: it agrees with Van Loan's exponentials as closely as one short step does, up to
    the most halvings; beyond those, and on a NaN, the exponentials themselves are used."""
    from groundstation.estimation.filters import MAX_HALVINGS, SERIES_LIMIT, discretized

    rng = np.random.default_rng(1)
    for size in (0.21, 0.5, 1.7, 6.0, SERIES_LIMIT * 2**MAX_HALVINGS * 0.99):
        for _ in range(10):
            A = rng.standard_normal((8, 8)) - np.eye(8)
            A *= size / np.abs(A).sum(axis=1).max()
            B, Qc = rng.standard_normal((8, 3)), np.diag(rng.uniform(0.0, 1.0, 8))
            for exact, fast, tol in zip(discretize(A, B, Qc, 1.0), discretized(A, B, Qc, 1.0), (1e-6, 1e-6, 5e-5)):
                assert np.abs(fast - exact).max() <= tol * np.abs(exact).max(), size
    A = np.eye(3) * 20.0
    B, Qc = np.ones((3, 1)), np.eye(3)
    for exact, fast in zip(discretize(A, B, Qc, 1.0), discretized(A, B, Qc, 1.0)):
        np.testing.assert_array_equal(fast, exact)  # past the halvings: the exponentials
    A[0, 0] = np.nan
    assert np.isnan(discretized(A, B, Qc, 1.0)[0]).any()  # no exception: the divergence check reads it


def test_the_covariance_over_jittered_steps_of_one_a_is_the_covariance_stepped_each_time():
    """A logged IMU's steps each have their own length; while A stays the same the filter sums them
    and propagates P once, which must equal P propagated at every step by the exponentials."""
    from groundstation.estimation.filters import ModelFilter

    rng = np.random.default_rng(3)
    model = altitude_model()
    f = ModelFilter(model, t0=0.0)
    f.u = np.array([0.3, 0.97])
    A = model.A(f.u)
    P, x, t = f.P.copy(), f.x.copy(), 0.0
    for dt in rng.uniform(0.0024, 0.0026, 200):
        t += dt
        f.predict_to(t)
        Phi, G, Qk = discretize(A, model.B, model.Qc, dt)
        P = Phi @ P @ Phi.T + Qk
        x = Phi @ x + G @ f.u
    # to the step length's key (0.1 us: a step whose length rounds to one seen takes its Phi and G)
    np.testing.assert_allclose(f.x, x, rtol=1e-5)
    np.testing.assert_allclose(f.P, P, rtol=1e-5, atol=1e-15)
    assert f.P[0, 0] > 2.0 * model.P0[0, 0] or f.P[1, 1] > model.P0[1, 1]  # it did grow


def test_altitude_model_is_observable_from_the_range_sensor():
    m = altitude_model()
    assert observability_rank(m.A(None), m.measurements["range"].row(None)) == 3


def test_the_accelerometers_bias_acts_along_the_body_axis():
    """A vehicle holding its height at 20 deg of roll, its accelerometer biased 0.4 m/s^2 along the
    body's up axis: the vertical input carries cos(20 deg) of the bias, and the model takes that share
    out. Held on the vertical, as the document has it, 10 s would sink the estimate by 1.2 m."""
    from groundstation.estimation.context import Context
    from groundstation.estimation.filters import ModelFilter
    from groundstation.estimation.routing import vertical_acceleration

    b, roll = 0.4, math.radians(20.0)
    c = math.cos(roll)
    ctx = Context(down_row=(0.0, math.sin(roll), c))  # (A_IB)_down for roll only
    f_body = np.array([0.0, 0.0, -9.80665 / c - b])  # thrust holding the height; the bias (FRD z)
    u = vertical_acceleration(_m(0.0, Kind.ACCEL, f_body), ctx)
    assert u == pytest.approx([c * b, c])
    f = ModelFilter(altitude_model())
    f.kf.x = np.array([1.0, 0.0, b])
    f.u = u
    for k in range(1, 1001):
        f.predict_to(0.01 * k)
    # to A's step in cos_tilt (models.altitude.COS_TILT_STEP: 3e-4 of this bias here, 6 mm after 10 s),
    # against the 1.2 m the document's vertical bias would sink
    assert f.x[0] == pytest.approx(1.0, abs=0.01) and f.x[1] == pytest.approx(0.0, abs=2e-3)


def run_altitude(tmp_path, seed, *, bias=0.0, seconds=60.0):
    """A simulated flight (range tilt declared, IMU bias drawn from the filter's prior) through the loop."""
    sc = Scenario.from_args("quad", seed, seconds, ["range_tilt", f"accel_bias:z={bias}"], [])
    run_fast(sc, tmp_path / f"q{seed}.tlog", tmp_path / f"q{seed}.csv")
    rows = list(csv.DictReader(open(tmp_path / f"q{seed}.csv")))
    truth = {k: np.array([float(r[k]) for r in rows]) for k in ("t", "h", "vd", "roll", "pitch")}
    est = altitude_estimator(altitude_model(range_tilt=True))
    loop = EstimationLoop([est])
    snaps = loop.snapshots.subscribe()
    ranges = []
    for m in Replay(tmp_path / f"q{seed}.tlog").iter_measurements():
        loop.push(m)
        if m.kind is Kind.RANGE:
            ranges.append((m.t, m.value[0]))
    return est, snaps.get_nowait(), truth, np.array(ranges)


def errors(snaps, truth, bias, t0=6.0, t1=50.0):
    t = np.array([s.t for s in snaps])
    keep = (t > t0) & (t < t1)
    xt = np.stack(
        [np.interp(t, truth["t"], truth["h"]), -np.interp(t, truth["t"], truth["vd"]), np.full(len(t), bias)], 1
    )
    e = np.array([s.x for s in snaps]) - xt
    P = np.array([s.P for s in snaps])
    return t[keep], e[keep], P[keep]


@pytest.mark.slow
def test_nees_and_nis_inside_their_95_percent_bands_over_20_seeded_runs(tmp_path):
    M = 20
    rng = np.random.default_rng(2024)
    nees_runs, nis_runs = [], {"range": [], "baro": []}
    for seed in range(M):
        bias = float(rng.normal(0.0, 0.2))  # drawn from the filter's prior (P0_bias = 0.2^2)
        est, snaps, truth, _ = run_altitude(tmp_path, 100 + seed, bias=bias)
        _, e, P = errors(snaps, truth, -bias)  # a body-z (down) bias is -b on gamma_z (up)
        nees_runs.append(np.mean([ei @ np.linalg.solve(Pi, ei) for ei, Pi in zip(e, P)]))
        for s in nis_runs:
            a = est.filter.log.arrays(s)
            nis_runs[s].append(a["nis"][(a["t"] > 6) & (a["t"] < 50)].mean())
    anees = np.mean(nees_runs)
    lo, hi = chi2.ppf([0.025, 0.975], 3 * M) / M
    assert lo <= anees <= hi, (anees, lo, hi)
    lo1, hi1 = chi2.ppf([0.025, 0.975], M) / M
    for s, v in nis_runs.items():
        assert lo1 <= np.mean(v) <= hi1, (s, np.mean(v), lo1, hi1)


@pytest.mark.slow
def test_rmse_below_the_range_sensor_noise_and_below_a_low_pass_of_equal_lag(tmp_path):
    est, snaps, truth, rng = run_altitude(tmp_path, 3)
    t, e, _ = errors(snaps, truth, 0.0)
    rmse = np.sqrt(np.mean(e[:, 0] ** 2))
    # the range sensor's own error (against the slant it really measures)
    slant = np.interp(rng[:, 0], truth["t"], truth["h"]) / (
        np.cos(np.interp(rng[:, 0], truth["t"], truth["roll"]))
        * np.cos(np.interp(rng[:, 0], truth["t"], truth["pitch"]))
    )
    keep = (rng[:, 0] > 6) & (rng[:, 0] < 50)
    sensor_noise = np.std(rng[keep, 1] - slant[keep])
    assert rmse < sensor_noise
    # a first-order low-pass of the range with the filter's lag (group delay = its time constant)
    zs = np.array([s.x[0] for s in snaps])
    ts = np.array([s.t for s in snaps])
    h_at = np.interp(ts, truth["t"], truth["h"])
    lags = np.arange(0.0, 0.2, 0.002)
    lag = lags[np.argmin([np.mean((zs - np.interp(ts - L, truth["t"], truth["h"])) ** 2) for L in lags])]
    tau = max(lag, 0.02)
    lp, y = [], rng[0, 1]
    for (tk, d), tprev in zip(rng, np.r_[rng[0, 0], rng[:-1, 0]]):
        y += (1 - math.exp(-(tk - tprev) / tau)) * (d - y)
        lp.append(y)
    lp_err = np.array(lp) - np.interp(rng[:, 0], truth["t"], truth["h"])
    assert rmse < np.sqrt(np.mean(lp_err[keep] ** 2))
    assert rmse < 0.006 and abs(np.mean(h_at - zs)) < 0.005


def _m(t, kind, value, source="sim/1.1", t_rx=None, instance=0):
    return Measurement(
        t, kind, np.atleast_1d(np.asarray(value, dtype=float)), source, t if t_rx is None else t_rx, None, instance
    )


def test_loop_orders_within_the_window_counts_late_and_reinitialises_on_a_clock_jump():
    est = altitude_estimator()
    loop = EstimationLoop([est], reorder_s=0.05)
    out = loop.snapshots.subscribe()
    for k in range(100):  # 1 s of IMU at 100 Hz, level and still
        loop.push(_m(10 + k * 0.01, Kind.ACCEL, [0, 0, -9.80665]))
        if k % 4 == 0 and k:
            loop.push(_m(10 + k * 0.01 - 0.02, Kind.RANGE, [1.0]))  # 20 ms late: inside the window
    loop.push(_m(10.2, Kind.RANGE, [1.0]))  # 0.8 s late: dropped, counted
    assert loop.counters.late == 1 and loop.counters.rollbacks == 24
    snaps = out.get_nowait()
    assert len(snaps) == 24
    # the rolled-back run equals a perfectly ordered one
    est2 = altitude_estimator()
    ordered = EstimationLoop([est2], reorder_s=0.05)
    ms = [_m(10 + k * 0.01, Kind.ACCEL, [0, 0, -9.80665]) for k in range(100)]
    ms += [_m(10 + k * 0.01 - 0.02, Kind.RANGE, [1.0]) for k in range(4, 100, 4)]
    for m in sorted(ms, key=lambda m: (m.t, m.kind is Kind.ACCEL)):
        ordered.push(m)
    np.testing.assert_allclose(est2.filter.x, est.filter.x, atol=1e-9)
    np.testing.assert_allclose(est2.filter.P, est.filter.P, atol=1e-12)
    assert snaps[-1].x[0] == pytest.approx(1.0, abs=0.05)
    # the vehicle reboots: its clock starts again from zero
    for k in range(10):
        loop.push(_m(0.01 * k, Kind.ACCEL, [0, 0, -9.80665]))
    loop.push(_m(0.1, Kind.RANGE, [2.0]))
    assert est.counters.reinitialisations == 1 and loop.latest["altitude"].t == pytest.approx(0.1)


def test_a_mavlink_streams_untimed_outputs_are_on_time_and_give_the_ordered_result(tmp_path):
    """SERVO_OUTPUT_RAW and VFR_HUD have no usable time field: the decoder stamps them on the aligned
    clock, a fraction of a microsecond before the ATTITUDE of the same instant that came first. That
    is within a timestamp's resolution: processed in place, with no rollback (one per message made
    each cost a re-run, and capacity fell from 10k to under 1k messages per second), nothing lost,
    and the time-ordered stream's result."""
    from groundstation.estimation.routing import quad_thrust_estimator

    run_fast(Scenario.from_args("quad", 7, 20.0, [], []), tmp_path / "q.tlog", tmp_path / "q.csv")
    ms = list(Replay(tmp_path / "q.tlog").iter_measurements())
    late = sum(b.t < a.t for a, b in zip(ms, ms[1:]) if b.kind in (Kind.ACTUATOR, Kind.THROTTLE))
    assert late > 400  # the stream really is out of order
    live, ordered = quad_thrust_estimator(), quad_thrust_estimator()
    loop = EstimationLoop([live])
    for m in ms:
        loop.push(m)
    for m in sorted(ms, key=lambda m: m.t):  # stable: arrival order at equal times
        ordered.handle(m)
    assert loop.counters.rollbacks == 0 and loop.counters.late == 0
    assert live.counters.skipped.get("out_of_order", 0) == 0
    assert live.filter.t == ordered.filter.t
    np.testing.assert_allclose(live.filter.x, ordered.filter.x, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(live.filter.P, ordered.filter.P, rtol=1e-4, atol=1e-10)


def test_a_millisecond_stamp_behind_the_imu_is_on_time_and_real_reordering_still_rolls_back():
    est = altitude_estimator()
    loop = EstimationLoop([est])
    for k in range(200):  # IMU stamped in microseconds, the range reading in milliseconds
        t = 1.0 + k * 0.004 + 0.0007
        loop.push(_m(t, Kind.ACCEL, [0, 0, -9.80665]))
        loop.push(_m(math.floor(t * 1e3) / 1e3, Kind.RANGE, [1.0]))  # 0.7 ms behind: on time
    assert loop.counters.rollbacks == 0 and est.counters.skipped.get("out_of_order", 0) == 0
    assert est.counters.updates == 200
    loop.push(_m(loop.latest["altitude"].t - 0.01, Kind.RANGE, [1.0]))  # 10 ms late: reordering
    assert loop.counters.rollbacks == 1


def test_the_innovation_log_gives_back_what_it_was_given_and_forgets_what_a_rollback_undid():
    def rec(t, sensor, m):
        nu = np.arange(m, dtype=float) + t
        return InnovationRecord(t, sensor, nu, np.eye(m) * (1 + t), t * t, np.ones((3, m)), np.zeros(2), nu * 2)

    log = InnovationLog()
    updates = [rec(0.1 * i, ("baro", "gps", "range")[i % 3], 3 if i % 3 == 1 else 1) for i in range(30)]
    for r in updates[:20]:
        log.append(r)
    log.truncate(11)  # a rollback to before the 12th update
    for r in updates[11:]:
        log.append(r)
    assert len(log) == 30 and log.sensors() == ["baro", "gps", "range"]
    for s in log.sensors():
        mine = [r for r in updates if r.sensor == s]
        a = log.arrays(s)
        np.testing.assert_array_equal(a["t"], [r.t for r in mine])
        np.testing.assert_array_equal(a["nu"], [r.nu for r in mine])
        np.testing.assert_array_equal(a["S"], [r.S for r in mine])
        np.testing.assert_array_equal(a["nis"], [r.nis for r in mine])
        np.testing.assert_array_equal(a["z"], [r.z for r in mine])
    t, sensor, nu, S = log.in_order()
    np.testing.assert_array_equal(t, [r.t for r in updates])
    assert sensor.tolist() == [r.sensor for r in updates]
    scalar = np.array([r.nu.size == 1 for r in updates])
    np.testing.assert_array_equal(nu[scalar], [r.nu[0] for r in updates if r.nu.size == 1])
    np.testing.assert_array_equal(S[scalar], [r.S[0, 0] for r in updates if r.nu.size == 1])
    assert np.isnan(nu[~scalar]).all() and np.isnan(S[~scalar]).all()
    assert log.arrays("mag")["t"].size == 0
    with pytest.raises(ValueError, match="another size"):
        log.append(rec(5.0, "baro", 2))


def test_prediction_through_a_dropout_grows_the_covariance():
    est = altitude_estimator()
    loop = EstimationLoop([est], reorder_s=0.0)
    for k in range(200):
        loop.push(_m(k * 0.01, Kind.ACCEL, [0, 0, -9.80665]))
        if k % 4 == 0:
            loop.push(_m(k * 0.01, Kind.RANGE, [1.0]))
    p_before = est.filter.P[0, 0]
    for k in range(200, 400):  # the range sensor goes quiet for 2 s
        loop.push(_m(k * 0.01, Kind.ACCEL, [0, 0, -9.80665]))
    assert est.filter.P[0, 0] > 10 * p_before


def test_truth_never_reaches_an_estimator_and_clocks_are_aligned():
    est = altitude_estimator()
    loop = EstimationLoop([est])
    truth = loop.truth.subscribe()
    loop.push(_m(1.0, Kind.TRUTH_POSE, [0, 0, -1, 1, 0, 0, 0]))
    assert est.counters.predictions == 0 and len(truth.get_nowait()) == 1
    # a second source whose clock runs 100 s ahead of the vehicle's
    loop.push(_m(5.0, Kind.ACCEL, [0, 0, -9.8], source="mav/1.1", t_rx=1000.0))
    loop.push(_m(105.0, Kind.RANGE, [1.0], source="board", t_rx=1000.01))
    assert loop.latest["altitude"].t == pytest.approx(5.01, abs=1e-6)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_measurements_are_counted_and_skipped(bad):
    est = altitude_estimator()
    loop = EstimationLoop([est], reorder_s=0.0)
    loop.push(_m(0.0, Kind.ACCEL, [0, 0, -9.8]))
    loop.push(_m(0.01, Kind.RANGE, [bad]))
    assert est.counters.skipped.get("range_not_finite") == 1 and np.all(np.isfinite(est.filter.x))


@pytest.mark.parametrize(
    "kind, value, why",
    [
        (Kind.ACCEL, [0.0, math.nan, -9.8], "accel_not_finite"),  # one component of a vector
        (Kind.ATTITUDE, [0.0, math.nan, 0.0], "attitude_not_finite"),  # the tilt every input rotates by
        (Kind.ATTITUDE_QUATERNION, [1.0, 0.0, math.inf, 0.0], "attitude_quaternion_not_finite"),
        (Kind.ACCEL, [0.0, 3e4, -9.8], "accel_implausible"),
        (Kind.BARO_PRESSURE, [-5.0], "baro_pressure_implausible"),
    ],
)
def test_every_component_of_every_reading_is_checked_and_the_estimate_survives(kind, value, why):
    """One accelerometer reading with y = NaN made the altitude and horizontal filters NaN for the rest
    of a replay; one NaN attitude killed the live estimator. Every component is checked, the reading
    is rejected and counted by kind and reason, and the estimates stay finite after it."""
    est, horizontal = altitude_estimator(), horizontal_estimator()
    loop = EstimationLoop([est, horizontal], reorder_s=0.0)
    for k in range(100):
        t = 0.01 * k
        loop.push(_m(t, Kind.ACCEL, [0.0, 0.0, -9.80665]))
        loop.push(_m(t + 0.001, Kind.ATTITUDE, [0.01, -0.02, 0.0]))
        if k == 50:
            loop.push(_m(t + 0.002, kind, value))
        loop.push(_m(t + 0.003, Kind.RANGE, [1.0]))
    assert est.counters.skipped.get(why) == 1 or horizontal.counters.skipped.get(why) == 1, est.counters.skipped
    for e in (est, horizontal):
        assert np.all(np.isfinite(e.filter.x)) and np.all(np.isfinite(e.filter.P)) and e.counters.diverged == 0
    assert loop.latest["altitude"].x[0] == pytest.approx(1.0, abs=0.05)


def test_a_filter_that_goes_non_finite_starts_over_and_says_so():
    """Whatever gets a filter's state to NaN (here: a model's own arithmetic, injected), it is no
    estimate: the estimator re-initialises at the next reading and counts it."""
    est = altitude_estimator()
    loop = EstimationLoop([est], reorder_s=0.0)
    loop.push(_m(0.0, Kind.ACCEL, [0, 0, -9.8]))
    loop.push(_m(0.01, Kind.RANGE, [1.0]))
    est.filter.kf.x = est.filter.kf.x * math.nan  # a fault no reading causes: injected
    loop.push(_m(0.02, Kind.ACCEL, [0, 0, -9.8]))
    assert est.counters.diverged == 1 and np.all(np.isfinite(est.filter.x))
    loop.push(_m(0.03, Kind.RANGE, [1.0]))
    assert np.all(np.isfinite(est.filter.x))


def test_a_consider_update_corrects_only_its_states_and_a_reset_sets_them():
    """MeasurementModel.corrects (Schmidt-Kalman): the gain's other rows are zero, so the other states and
    their covariance are what they were; with reset, the states are set with variance R and uncorrelated.
    The thrust model's ground contact uses both (models.contact.ground_contact)."""
    from dataclasses import replace

    from groundstation.estimation.filters import ModelFilter
    from groundstation.estimation.models.base import MeasurementModel

    model = altitude_model()
    f = ModelFilter(model)
    f.kf.P = np.array([[0.04, 0.01, 0.002], [0.01, 0.09, 0.003], [0.002, 0.003, 0.01]])
    f.kf.x = np.array([0.3, -0.8, 0.05])
    x0, P0 = f.kf.x.copy(), f.kf.P.copy()
    vz = MeasurementModel(
        "landed",
        Kind.THROTTLE,
        lambda m, c: np.array([0.0]),
        lambda c: np.array([[0.0, 1.0, 0.0]]),
        np.array([[0.05**2]]),
        corrects=(1,),
    )
    f.update(vz, np.array([0.0]))
    k = 0.09 / (0.09 + 0.05**2)
    assert f.kf.x[1] == pytest.approx(-0.8 * (1 - k))
    assert f.kf.x[[0, 2]] == pytest.approx(x0[[0, 2]])  # a full update moves z by P_zv/S*nu
    assert f.kf.P[np.ix_([0, 2], [0, 2])] == pytest.approx(P0[np.ix_([0, 2], [0, 2])])
    assert f.kf.P[1, 1] == pytest.approx(0.09 * (1 - k))
    assert np.allclose(f.kf.P, f.kf.P.T) and np.all(np.linalg.eigvalsh(f.kf.P) > 0)
    f.update(replace(vz, reset=True), np.array([0.0]))
    assert f.kf.x[1] == 0.0 and f.kf.P[1, 1] == pytest.approx(0.05**2)
    assert f.kf.P[1, [0, 2]] == pytest.approx([0.0, 0.0]) and f.kf.x[[0, 2]] == pytest.approx(x0[[0, 2]])


@pytest.mark.parametrize("range_reads_on", [False, True])
def test_landed_the_filter_holds_still_and_a_quiet_range_puts_it_on_the_ground(range_reads_on):
    """models.ground: a hover at 0.3 m on the range, then the motors stop. With the range quiet (below
    its minimum) the landed vehicle is set on the ground (z = 0); with the range still reading, the
    range carries the height and the ground constraint only holds it still."""
    from groundstation.estimation.models.ground import LANDED
    from groundstation.estimation.registry import build_estimator

    est = build_estimator("altitude")
    ms = [_m(k * 0.01, Kind.ACCEL, [0.0, 0.0, -9.80665]) for k in range(600)]
    ms += [_m(k * 0.02, Kind.THROTTLE, 0.5 if k * 0.02 < 2.0 else 0.0) for k in range(300)]
    ms += [_m(0.005 + k * 0.04, Kind.RANGE, 0.30) for k in range(150) if range_reads_on or k * 0.04 < 2.0]
    ms.sort(key=lambda m: m.t)
    z = {}
    for m in ms:
        est.handle(m)
        z[round(m.t, 3)] = float(est.filter.kf.x[0])
    assert z[1.98] == pytest.approx(0.30, abs=0.01)
    landed = est.filter.log.arrays(LANDED)
    assert len(landed["t"]) > 0 and landed["t"].min() >= 2.0  # only once the motors stopped
    if range_reads_on:
        assert z[5.98] == pytest.approx(0.30, abs=0.01)
    else:
        assert abs(z[5.98]) < 0.02, z[5.98]
        assert z[2.2] > 0.25  # held still while the range may only have missed a reading


def test_at_lift_off_the_ground_lets_go_of_the_vertical_speed():
    """models.ground: 2 s on the ground, then the vehicle leaves it at 0.5 m/s between two IMU samples
    (an impulse the accelerometer does not show). Held at vz = 0 by the ground until then, the filter
    releases vz at lift-off (SIGMA_LIFTOFF), and the range reading takes it along: the height stays
    within 3 sigma of the truth through the climb. Without the release it lagged by 13 cm with
    sigma_z at 4 mm."""
    from groundstation.estimation.models.ground import SIGMA_LIFTOFF
    from groundstation.estimation.registry import build_estimator

    est = build_estimator("altitude")
    rng = np.random.default_rng(3)

    def h(t):
        return 0.1 + 0.5 * (t - 2.0) if t > 2.0 else 0.1  # range above its clamp throughout

    ms = [_m(k * 0.004, Kind.ACCEL, [0.0, 0.0, -9.80665]) for k in range(1500)]
    ms += [_m(k * 0.02, Kind.THROTTLE, 0.0 if k * 0.02 < 2.0 else 0.5) for k in range(300)]
    ms += [_m(0.01 + k * 0.05, Kind.RANGE, h(0.01 + k * 0.05) + 0.01 * rng.standard_normal()) for k in range(120)]
    ms.sort(key=lambda m: m.t)
    worst, sigma_vz_at_release = 0.0, 0.0
    for m in ms:
        est.handle(m)
        P = est.filter.P
        if 2.0 <= m.t < 2.03 and m.kind is Kind.THROTTLE:
            sigma_vz_at_release = max(sigma_vz_at_release, math.sqrt(P[1, 1]))
        if 2.0 < m.t < 5.8:
            worst = max(worst, abs(est.filter.kf.x[0] - h(m.t)) / math.sqrt(P[0, 0]))
    assert sigma_vz_at_release >= 0.9 * SIGMA_LIFTOFF
    assert worst < 3.5, worst


def test_a_throttle_message_dated_ahead_of_the_sensors_does_not_move_the_filters_clock():
    """The ground's constraints are read at throttle messages, whose time may lead the sensors' (on
    the live simulated link SERVO_OUTPUT_RAW led the IMU by 90 ms): applied at the filter's own
    time, they leave the IMU blocks after them in order (MeasurementModel.untimed)."""
    from groundstation.estimation.registry import build_estimator

    est = build_estimator("altitude")
    ms = [_m(k * 0.01, Kind.ACCEL, [0.0, 0.0, -9.80665]) for k in range(200)]
    ms += [_m(k * 0.02 + 0.09, Kind.ACTUATOR, [0.0, 0.0, 0.0, 0.0], t_rx=k * 0.02) for k in range(100)]
    ms.sort(key=lambda m: m.t_rx)  # in arrival order: each output 90 ms ahead of the IMU
    for m in ms:
        est.handle(m)
    assert "out_of_order" not in est.counters.skipped, est.counters.skipped
    assert est.filter.t == pytest.approx(1.99)
    assert len(est.filter.log.arrays("landed")["t"]) > 50  # and the constraint still applies


def test_the_throttle_comes_from_one_source_the_motor_outputs_when_the_log_has_them():
    """An autopilot's THROTTLE (VFR_HUD: an integer percent, every fifth output message, on its own
    scale) and the motor outputs (SERVO_OUTPUT_RAW, 1 us) once both set the models' throttle: a
    simulated quad's thrust model flew a 1 %-quantised throttle for 20 ms of every 100."""
    from groundstation.diagnosis.catalogue.thrust_model import throttle_series
    from groundstation.estimation.context import Context
    from groundstation.estimation.routing import read_throttle

    ctx = Context()
    thr = [Measurement(t, Kind.THROTTLE, np.array([0.50]), "sim") for t in (0.0, 0.1)]
    pwm = Measurement(0.05, Kind.ACTUATOR, np.array([0.503] * 4 + [math.nan] * 4), "sim")
    read_throttle(thr[0], ctx)
    assert ctx.throttle == 0.50  # no outputs yet: THROTTLE is all there is
    read_throttle(pwm, ctx)
    read_throttle(thr[1], ctx)
    assert ctx.throttle == pytest.approx(0.503)
    assert throttle_series([thr[0], pwm, thr[1]]) == [(0.05, pytest.approx(0.503))]
    assert throttle_series(thr) == [(0.0, 0.5), (0.1, 0.5)]  # a log without outputs


def test_a_battery_reading_pairs_with_the_throttle_written_before_it():
    """A throttle written at the reading's instant has not yet drawn its current. The simulated thrust
    test flight steps its throttle on the battery's 5 Hz grid; paired with the new throttle, the
    voltage carried forward between readings was off by k (0.77^2 - 0.5^2) = 1.6 V after each step,
    and thrust_voltage's n = 1.5 read 1.85 (with a false actuator lag beside it)."""
    from groundstation.diagnosis.catalogue.battery import load_line
    from groundstation.estimation.context import Context
    from groundstation.estimation.routing import read_throttle, throttle_at_reading

    ctx = Context()
    read_throttle(Measurement(10.98, Kind.ACTUATOR, np.array([0.5] * 4), "sim"), ctx)
    read_throttle(Measurement(11.0, Kind.ACTUATOR, np.array([0.77] * 4), "sim"), ctx)
    assert throttle_at_reading(ctx, 11.0) == 0.5 and throttle_at_reading(ctx, 11.01) == 0.77
    # a pack with k = 4 V: each reading drawn by the throttle before it, the throttle stepping at the readings
    rng = np.random.default_rng(0)
    taus = 0.5 + 0.25 * rng.random(40)
    ms, throttle = [], []
    for j, tau in enumerate(taus):
        t = 0.2 * j
        drawn = taus[j - 1] if j else tau
        ms.append(Measurement(t, Kind.BATTERY_VOLTAGE, np.array([12.0 - 4.0 * drawn**2]), "sim"))
        throttle.append((t, float(tau)))
    k, _ = load_line(ms, throttle)
    assert k == pytest.approx(4.0, rel=1e-6)


def test_decimation_averages_the_imu_thins_the_attitude_and_keeps_order_and_the_rest():
    from groundstation.estimation.shedding import decimate

    ms = []
    for k in range(12):
        t = 1.0 + k * 0.001
        ms.append(_m(t, Kind.ACCEL, [0.0, 0.0, -9.0 - k]))
        if k % 2 == 0:
            ms.append(_m(t + 0.0002, Kind.ATTITUDE, [0.01 * k, 0.0, 0.0]))
    ms.insert(5, _m(1.0025, Kind.VEHICLE_STATUS, [1, 0, 4, 2, 3]))
    out, removed = decimate(ms, 4)
    assert [m.t for m in out] == sorted(m.t for m in out)
    accel = [m for m in out if m.kind is Kind.ACCEL]
    assert [(m.t, m.samples) for m in accel] == [(1.0, 4), (1.004, 4), (1.008, 4)]  # at the first one's time
    assert accel[0].value[2] == pytest.approx(-10.5)
    attitude = [m for m in out if m.kind is Kind.ATTITUDE]
    assert [m.value[0] for m in attitude] == pytest.approx([0.0, 0.08])  # one in four, the first of each
    assert sum(m.kind is Kind.VEHICLE_STATUS for m in out) == 1
    assert removed == len(ms) - len(out) == 9 + 4
    # a block with a bad reading goes through reading by reading, for the estimator to count it
    bad = [m._replace(value=np.array([np.nan, 0.0, -9.0])) if m.t == 1.005 and m.kind is Kind.ACCEL else m for m in ms]
    out, _ = decimate(bad, 4)
    assert [m.samples for m in out if m.kind is Kind.ACCEL] == [4, 1, 1, 1, 1, 4]


def _hover(seed: int, seconds: float = 5.0) -> list[Measurement]:
    """A 1 kHz IMU and a 50 Hz range sensor, hovering at 1.5 m, with the noise the altitude model
    assumes (G_acc 3e-5 (m/s^2)^2/Hz: 0.17 m/s^2 at 1 kHz; range 1.05 cm)."""
    rng = np.random.default_rng(seed)
    ms = []
    for k in range(int(seconds * 1000)):
        t = 10 + k * 0.001
        ms.append(_m(t, Kind.ACCEL, [0, 0, -9.80665 + rng.normal(0, 0.173)], t_rx=t))
        if k % 20 == 0:
            ms.append(_m(t, Kind.RANGE, [1.5 + rng.normal(0, 0.0105)], t_rx=t))
    return ms


def test_an_overloaded_batch_is_decimated_within_budget_and_estimates_consistently():
    """A live batch far older than the latency budget (the loop was stalled half a second): the
    loop decimates instead of running through it all, and counts what it shed. Its estimates stay
    consistent: over twelve flights, the height error in units of the filter's own sigma has an RMS
    near 1 (1.10 here; 1.07 over 30 flights of 5 s, where the whole stream gives 0.91). A fresh
    batch, small enough for the budget, is processed whole."""
    errors = []
    for seed in range(12):
        ms = _hover(seed, 4.0)
        est = altitude_estimator()
        loop = EstimationLoop([est])
        warm = [m for m in ms if m.t < 12.0]  # settled on 2 s; then 2 s come at once
        rest = ms[len(warm) :]
        for m in warm:
            loop.push(m)
        now = time.time()
        loop.push_many([m._replace(t_rx=now - 0.5 - (rest[-1].t - m.t)) for m in rest])
        c = loop.counters
        assert c.shed > 1000 and c.processed - len(warm) + c.shed == len(rest)
        errors.append((est.filter.x[0] - 1.5) / math.sqrt(est.filter.P[0, 0]))
    assert math.sqrt(np.mean(np.square(errors))) < 1.5 and abs(np.mean(errors)) < 0.6, errors
    fresh = EstimationLoop([altitude_estimator()])
    fresh.push_many([m._replace(t_rx=time.time()) for m in _hover(0, 0.05)])
    assert fresh.counters.shed == 0 and fresh.counters.processed == 53
