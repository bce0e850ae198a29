"""Recursive least squares (coaxial document ch. 7): exact against the offline solution,
and calibrating the barometer against the range sensor on a simulated flight."""

import numpy as np
import pytest

from drivers.replay import Replay
from groundstation.estimation.rls import (
    BaroRangeCalibration,
    RecursiveLeastSquares,
    least_squares,
)
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario


def test_recursion_equals_the_offline_solution():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(500, 3))
    y = X @ [1.5, -2.0, 0.25] + rng.normal(scale=0.1, size=500)
    rls = RecursiveLeastSquares(3, P0=1e9)
    for phi, yk in zip(X, y):
        rls.update(phi, yk)
    np.testing.assert_allclose(rls.theta, least_squares(X, y), atol=1e-6)  # eq. 7.10


def test_forgetting_factor_tracks_a_drifting_parameter():
    rng = np.random.default_rng(2)
    plain, forget = RecursiveLeastSquares(2), RecursiveLeastSquares(2, lam=0.98)
    for k in range(2000):
        x = rng.normal()
        b = 0.002 * k  # the offset drifts
        y = 2.0 * x + b + rng.normal(scale=0.05)
        plain.update([x, 1.0], y)
        forget.update([x, 1.0], y)
    # lambda = 0.98 remembers ~50 samples: it lags the ramp by ~50 x 0.002 = 0.1; plain RLS by ~2
    assert abs(forget.theta[1] - 4.0) < 0.15 and abs(plain.theta[1] - 4.0) > 1.5
    with pytest.raises(ValueError):
        RecursiveLeastSquares(2, lam=1.5)


def test_baro_calibrated_against_range_on_a_simulated_flight(tmp_path):
    run_fast(Scenario("quad", seed=5, duration=60), tmp_path / "q.tlog", tmp_path / "q.csv")
    cal = BaroRangeCalibration()
    p_pairs = []
    for m in Replay(tmp_path / "q.tlog").iter_measurements():
        if cal.handle(m) is not None:
            p_pairs.append(cal._baro[1])
    # the standard atmosphere's slope at 120 m is dh/dp = -1 / (rho g) = -0.0842 m/Pa; least
    # squares with a noisy regressor (4 Pa) flattens it by var(p) / (var(p) + 4^2)
    var_p = np.var(p_pairs)
    expected = -0.0842 * (var_p - 16.0) / var_p
    assert cal.pairs > 500 and cal.a == pytest.approx(expected, rel=0.05)
