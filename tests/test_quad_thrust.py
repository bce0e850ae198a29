"""The quadcopter document's thrust-model filter: observability, parameters, thrust loss."""
import csv

import numpy as np
import pytest

from groundstation.estimators import build_estimator
from groundstation.loop import EstimationLoop
from groundstation.models.quad_thrust import observability_report
from groundstation.replay import Replay
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario


def test_observability_ranks():
    r = observability_report()
    assert r["states"] == 6
    assert r["range+baro+gps, constant throttle"] == 5     # only alpha*tau + beta shows
    assert r["range+baro+gps, varying throttle"] == 6
    assert r["range+baro, constant throttle"] == 4         # and the (z, d_bar, d_tof) common mode
    assert r["range+baro, varying throttle"] == 5


def _fly(tmp_path, seconds, undeclared=()):
    sc = Scenario.from_args("quad", 3, seconds, ["range_tilt"], list(undeclared))
    run_fast(sc, tmp_path / "q.tlog", tmp_path / "q.csv")
    est = build_estimator("quad_thrust", [{"name": "range_tilt"}])
    loop = EstimationLoop([est])
    snaps = loop.snapshots.subscribe()
    for m in Replay(tmp_path / "q.tlog").iter_measurements():
        loop.push(m)
    rows = list(csv.DictReader(open(tmp_path / "q.csv")))
    return est, snaps.get_nowait(), rows


def _at(snaps, t):
    return min(snaps, key=lambda s: abs(s.t - t))


def test_thrust_coefficients_and_height_on_a_simulated_flight(tmp_path):
    est, snaps, rows = _fly(tmp_path, 120.0)
    s = _at(snaps, 110.0)
    assert s.x[2] == pytest.approx(22.0, rel=0.08) and s.x[3] == pytest.approx(-1.2, abs=0.8)
    tt = np.array([float(r["t"]) for r in rows])
    h = np.array([float(r["h"]) for r in rows])
    ts = np.array([x.t for x in snaps])
    keep = (ts > 10) & (ts < 100)
    z = np.array([x.x[0] for x in snaps])[keep]
    assert np.sqrt(np.mean((z - np.interp(ts[keep], tt, h)) ** 2)) < 0.05
    for sensor in ("range", "baro"):
        a = est.filter.log.arrays(sensor)
        assert 0.7 < a["nis"][a["t"] > 10].mean() < 1.3


def test_thrust_loss_with_battery_sag_shows_in_this_filter(tmp_path):
    est, snaps, rows = _fly(tmp_path, 200.0, ["thrust_voltage:n=2"])
    full_early = _at(snaps, 30.0).x[2] + _at(snaps, 30.0).x[3]      # acceleration at full throttle
    full_late = _at(snaps, 150.0).x[2] + _at(snaps, 150.0).x[3]
    assert full_late < 0.85 * full_early
