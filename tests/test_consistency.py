"""Filter consistency over 20 seeded simulated flights (Bar-Shalom's Monte-Carlo test).

For each estimator: per run, the time-averaged NEES (error against the
simulator's truth, normalised by the filter's own covariance) and NIS; across
the M = 20 runs, their average must lie in the two-sided 95 % band of
chi^2(n M) / M. Where the truth is not at the filter's prior mean (thrust
coefficients, biases, offsets), it is drawn from the prior, so that the test
asks exactly "is P honest?". The altitude filter's run is in test_estimation.py.
"""

import csv

import numpy as np
import pytest
from scipy.stats import chi2

from drivers.replay import Replay
from groundstation.core.measurement import Kind
from groundstation.estimation.attitude_filters import DragAttitudeEKF
from groundstation.estimation.loop import EstimationLoop
from groundstation.estimation.models.heli3dof import heli3dof_model
from groundstation.estimation.models.quad_thrust import quad_thrust_model
from groundstation.estimation.routing import heli3dof_estimator, quad_thrust_estimator
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario

M = 20


def band(dof: int) -> tuple[float, float]:
    lo, hi = chi2.ppf([0.025, 0.975], dof * M) / M
    return float(lo), float(hi)


def nees(E: np.ndarray, P: np.ndarray) -> float:
    return float(np.mean([e @ np.linalg.solve(p, e) for e, p in zip(E, P)]))


def truth_of(csv_path):
    rows = list(csv.DictReader(open(csv_path)))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def run_loop(est, tlog):
    loop = EstimationLoop([est])
    sub = loop.snapshots.subscribe()
    for m in Replay(tlog).iter_measurements():
        loop.push(m)
    s = sub.get_nowait()
    return np.array([x.t for x in s]), np.array([x.x for x in s]), np.array([x.P for x in s])


@pytest.mark.slow
def test_quad_thrust_filter_is_consistent(tmp_path):
    rng = np.random.default_rng(11)
    runs, nis = [], {"baro": [], "range": []}
    for k in range(M):
        m = quad_thrust_model()
        sd = np.sqrt(np.diag(m.P0))
        o = float(rng.normal(0.0, sd[5]))  # ToF offset, from the prior
        sc = Scenario.from_args("quad", 200 + k, 60.0, ["range_tilt", f"range_offset:o={o}"], [])
        run_fast(sc, tmp_path / "q.tlog", tmp_path / "q.csv")
        tr = truth_of(tmp_path / "q.csv")
        x0 = m.x0.copy()  # the prior mean drawn around the truth
        x0[2], x0[3] = 22.0 + rng.normal(0, sd[2]), -1.2 + rng.normal(0, sd[3])
        m.x0 = x0
        est = quad_thrust_estimator(m)
        t, X, P = run_loop(est, tmp_path / "q.tlog")
        t_land = tr["t"][np.flatnonzero(tr["h"] > 0.3)[-1]]
        keep = (t > 15.0) & (t < t_land - 1.0)  # in the air, after take-off
        T = np.stack(
            [
                np.interp(t, tr["t"], tr["h"]),
                -np.interp(t, tr["t"], tr["vd"]),
                np.full(len(t), 22.0),
                np.full(len(t), -1.2),
                np.full(len(t), o),
            ],
            1,
        )
        idx = [0, 1, 2, 3, 5]  # d_bar: relative to the filter's own reference
        runs.append(nees((X[:, idx] - T)[keep], P[keep][:, idx][:, :, idx]))
        for s in nis:
            a = est.filter.log.arrays(s)
            nis[s].append(a["nis"][(a["t"] > 15.0) & (a["t"] < t_land - 1.0)].mean())
    lo, hi = band(5)
    assert lo <= np.mean(runs) <= hi, (np.mean(runs), lo, hi)
    lo, hi = band(1)
    for s, v in nis.items():
        assert lo <= np.mean(v) <= hi, (s, np.mean(v), lo, hi)


@pytest.mark.slow
def test_heli3dof_filter_is_consistent_with_the_arm_acceleration_removed(tmp_path):
    runs, nis = [], {"gyro": [], "accel": []}
    for k in range(M):
        run_fast(Scenario("heli3dof", seed=k, duration=24), tmp_path / "h.tlog", tmp_path / "h.csv")
        tr = truth_of(tmp_path / "h.csv")
        est = heli3dof_estimator(heli3dof_model())
        est._by_kind.pop(Kind.ATTITUDE, None)  # the lab's IMU-only filter
        t, X, P = run_loop(est, tmp_path / "h.tlog")
        keep = (t > 8.0) & (t < 22.0)
        T = np.stack([np.interp(t, tr["t"], tr[n]) for n in est.model.states], 1)
        idx = [0, 1, 2, 3, 5]  # travel itself is unobservable from the IMU
        runs.append(nees((X - T)[keep][:, idx], P[keep][:, idx][:, :, idx]))
        for s in nis:
            a = est.filter.log.arrays(s)
            nis[s].append(a["nis"][(a["t"] > 8.0) & (a["t"] < 22.0)].mean())
    lo, hi = band(5)
    assert lo <= np.mean(runs) <= hi, (np.mean(runs), lo, hi)
    for s, dof in (("gyro", 3), ("accel", 2)):
        lo, hi = band(dof)
        assert lo <= np.mean(nis[s]) <= hi, (s, np.mean(nis[s]), lo, hi)


@pytest.mark.slow
def test_drag_attitude_ekf_is_consistent_on_a_multirotor(tmp_path):
    rng = np.random.default_rng(5)
    runs, nis = [], []
    for k in range(M):
        bx, by = rng.normal(0.0, 0.05, 2)  # gyro biases from the prior (P0_bias = 0.05)
        run_fast(
            Scenario.from_args("quad", 300 + k, 50.0, [], [f"gyro_bias:x={bx},y={by},z=0"]),
            tmp_path / "q.tlog",
            tmp_path / "q.csv",
        )
        tr = truth_of(tmp_path / "q.csv")
        ekf = DragAttitudeEKF()
        E, P, n0 = [], [], 0
        for m in Replay(tmp_path / "q.tlog").iter_measurements():
            ekf.handle(m)
            if m.kind is Kind.ACCEL and 10.0 < m.t < 45.0 and ekf.started:
                if n0 == 0:
                    n0 = len(ekf.nis)
                x = np.array([np.interp(m.t, tr["t"], tr["roll"]), np.interp(m.t, tr["t"], tr["pitch"]), bx, by])
                E.append(ekf.ekf.x[:4] - x)
                P.append(ekf.P[:4, :4].copy())
        runs.append(nees(np.array(E), np.array(P)))
        nis.append(np.mean(ekf.nis[n0 : n0 + len(E)]))
    lo, hi = band(4)
    assert lo <= np.mean(runs) <= hi, (np.mean(runs), lo, hi)
    lo, hi = band(2)
    assert lo <= np.mean(nis) <= hi, (np.mean(nis), lo, hi)


def test_recursive_least_squares_is_consistent_under_its_own_assumptions():
    """Chapter 7's RLS: white noise on y, an exact regressor. (With the noisy pressure as the
    regressor, as in flight, least squares is biased by regression dilution: rls.py says so.)"""
    from groundstation.estimation.rls import RecursiveLeastSquares

    rng = np.random.default_rng(21)
    sigma = 0.02
    nees_runs, nis_runs = [], []
    for _ in range(M):
        theta = np.array([rng.normal(-0.083, 0.01), rng.normal(0.0, 1.0)])  # m/Pa, m
        rls = RecursiveLeastSquares(2)
        nees_k, nis_k = [], []
        for k in range(400):
            phi = np.array([rng.uniform(-40, 40), 1.0])  # Pa about the reference
            y = float(phi @ theta + rng.normal(0.0, sigma))
            s = sigma**2 * (1.0 + phi @ rls.P @ phi)
            e = rls.update(phi, y)
            if k >= 10:  # after the diffuse start
                nis_k.append(e**2 / s)
                d = rls.theta - theta
                nees_k.append(d @ np.linalg.solve(rls.covariance(sigma**2), d))
        nees_runs.append(np.mean(nees_k))
        nis_runs.append(np.mean(nis_k))
    lo, hi = band(2)
    assert lo <= np.mean(nees_runs) <= hi, (np.mean(nees_runs), lo, hi)
    lo, hi = band(1)
    assert lo <= np.mean(nis_runs) <= hi, (np.mean(nis_runs), lo, hi)


def test_the_truth_says_whether_a_sigma_is_honest():
    """``Truth.consistency`` (what ``evaluate`` and the diagnosis report print): errors drawn with
    the sigma the estimate claims hold the truth within 2 sigma 95 % of the time at NEES 1; a sigma
    half the real spread, 68 % at NEES 4; a constant error of 3 sigma, never; and times outside the
    truth's span or the window are not scored."""
    from groundstation.estimation.truth import Truth

    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 100.0, 20_001)
    truth = Truth(t, np.sin(0.3 * t), "test")
    sigma = np.full(len(t), 0.05)
    z = truth.h + rng.normal(0.0, 0.05, len(t))
    within, n = truth.consistency(t, z, sigma, 0.0, 100.0)
    assert within == pytest.approx(0.954, abs=0.01) and n == pytest.approx(1.0, abs=0.05)
    within, n = truth.consistency(t, z, sigma / 2, 0.0, 100.0)
    assert within == pytest.approx(0.683, abs=0.01) and n == pytest.approx(4.0, abs=0.2)
    within, n = truth.consistency(t, truth.h + 0.15, sigma, 0.0, 100.0)
    assert within == 0.0 and n == pytest.approx(9.0)
    wrong_later = np.where(t > 50.0, truth.h + 1.0, z)
    within, n = truth.consistency(t, wrong_later, sigma, 0.0, 50.0)
    assert within == pytest.approx(0.954, abs=0.015)
    assert np.isnan(truth.consistency(t + 200.0, z, sigma, 0.0, 1e9)[1])


def test_a_live_truth_scores_each_estimate_between_the_truth_samples_around_it():
    """``LiveTruthScore`` (the dashboard's): estimates at 50 Hz against a 100 Hz truth, whichever
    comes first, each scored against the truth interpolated at its time; honest noise reads 95 %
    and NEES 1, a 3 sigma offset 16 % and NEES 10; truth lost for 0.5 s scores nothing there; and time
    going back starts over."""
    from groundstation.estimation.truth import LiveTruthScore

    rng = np.random.default_rng(3)
    t_truth = np.arange(0.0, 60.0, 0.01)
    t_est = np.arange(0.0037, 60.0, 0.02)
    h = lambda t: 1.0 + 0.8 * np.sin(0.7 * t)  # noqa: E731
    z = h(t_est) + rng.normal(0.0, 0.02, len(t_est))

    def played(truth_late: bool, offset: float = 0.0, lost=(np.inf, np.inf)) -> LiveTruthScore:
        score = LiveTruthScore(window_s=120.0)
        events = [(t, 0, float(h(t))) for t in t_truth if not lost[0] <= t < lost[1]]
        events += [(t, 1, float(v) + offset) for t, v in zip(t_est, z)]
        # the truth reaches the dashboard 50 ms late, or 50 ms early
        events.sort(key=lambda e: e[0] + (0.05 if (e[1] == 0) == truth_late else 0.0))
        for t, which, v in events:
            score.truth(t, v) if which == 0 else score.estimate(t, v, 0.02)
        return score

    for truth_late in (True, False):
        n, rms, within, nees = played(truth_late).summary()
        assert n == len(t_est) and rms == pytest.approx(0.02, rel=0.05)
        assert within == pytest.approx(0.954, abs=0.015) and nees == pytest.approx(1.0, abs=0.08)
        _, _, within, nees = played(truth_late, offset=0.06).summary()  # 3 sigma off: |3 + N(0, 1)| <= 2
        assert within == pytest.approx(0.159, abs=0.02) and nees == pytest.approx(10.0, abs=0.6)
    n_lost = played(True, lost=(20.0, 20.5)).summary()[0]
    assert n_lost == len(t_est) - 25  # 20.0037 to 20.4837 s: between the truth samples of 19.99 and 20.5 s
    score = played(True)
    score.truth(5.0, 1.0)  # a seek back
    assert score.summary() is None
