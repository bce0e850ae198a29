"""Horizontal position (IMU + GPS with its correlated error as states), and how the dashboard shows it."""

import csv

import numpy as np
import pytest

from drivers.replay import Replay
from groundstation.estimation.loop import EstimationLoop, Snapshot
from groundstation.estimation.routing import horizontal_estimator
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario


@pytest.mark.slow
def test_horizontal_filter_tracks_velocity_and_says_what_gps_allows(tmp_path):
    run_fast(Scenario.from_args("quad", 401, 90.0, [], []), tmp_path / "q.tlog", tmp_path / "q.csv")
    tr = list(csv.DictReader(open(tmp_path / "q.csv")))
    tt = np.array([float(r["t"]) for r in tr])
    truth = {k: np.array([float(r[k]) for r in tr]) for k in ("n", "e", "vn", "ve")}
    est = horizontal_estimator()
    loop = EstimationLoop([est])
    sub = loop.snapshots.subscribe()
    for m in Replay(tmp_path / "q.tlog").iter_measurements():
        loop.push(m)
    s = sub.get_nowait()
    t = np.array([x.t for x in s])
    X, P = np.array([x.x for x in s]), np.array([x.P for x in s])
    k = t > 10.0
    gps = est.filter.log.arrays("gps")
    t0 = gps["t"][0]  # the local origin is the first fix
    err_n = X[k, 0] - (np.interp(t[k], tt, truth["n"]) - np.interp(t0, tt, truth["n"]))
    err_e = X[k, 1] - (np.interp(t[k], tt, truth["e"]) - np.interp(t0, tt, truth["e"]))
    sig = np.sqrt(P[k, 0, 0])
    # the GPS error is correlated (1 m over 20 s): the filter can't beat it, and says so
    assert 0.5 < sig.mean() < 1.5
    assert np.sqrt(np.mean(err_n**2 + err_e**2) / 2) < 2.0 * sig.mean()
    # the IMU carries velocity between fixes
    v_rmse = np.sqrt(np.mean((X[k, 2] - np.interp(t[k], tt, truth["vn"])) ** 2))
    assert v_rmse < 0.3
    assert 1.0 < gps["nis"][gps["t"] > 10].mean() < 3.0  # 2 dof


def test_dashboard_ellipsoid_takes_the_horizontal_covariance():
    from web.dashboard import Dashboard

    d = Dashboard(port=0)
    try:
        d.feed_snapshot(
            Snapshot(
                1.0, "altitude", ("z", "vz", "b_acc"), np.array([2.0, 0, 0]), np.diag([0.01**2, 1e-4, 1e-4]), None, 0.0
            )
        )
        d.feed_snapshot(
            Snapshot(
                1.0,
                "horizontal",
                ("n", "e", "vn", "ve", "b_n", "b_e"),
                np.array([3.0, -1.0, 0, 0, 0, 0]),
                np.diag([4.0, 1.0, 0.1, 0.1, 1, 1]),
                None,
                0.0,
            )
        )
        d.update_scene()
        np.testing.assert_allclose(d.vehicle_frame.position, [3.0, 1.0, 2.0])  # (n, -e, -d)
        assert sorted(np.round(d.ellipsoid.scale, 4)) == [0.03, 3.0, 6.0]  # 3 sigma: z, e, n
    finally:
        d.stop()
