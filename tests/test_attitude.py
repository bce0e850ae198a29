"""Chapter 8's complementary filter against an attitude EKF, on the same simulated flight."""
import csv
import math

import numpy as np
import pytest

from groundstation.attitude import AttitudeEKF, ComplementaryFilter, accel_attitude
from groundstation.attitude_drag import DragAttitudeEKF
from groundstation.measurement import Kind
from groundstation.replay import Replay
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario


def _compare(tmp_path, undeclared):
    run_fast(Scenario.from_args("quad", 4, 60.0, [], undeclared), tmp_path / "q.tlog", tmp_path / "q.csv")
    rows = list(csv.DictReader(open(tmp_path / "q.csv")))
    tt = np.array([float(r["t"]) for r in rows])
    truth = {k: np.array([float(r[k]) for r in rows]) for k in ("roll", "pitch")}
    cf, ekf, drag = ComplementaryFilter(w_c=1.0), AttitudeEKF(), DragAttitudeEKF()
    err = {"cf": [], "ekf": [], "accel": [], "drag": []}
    for m in Replay(tmp_path / "q.tlog").iter_measurements():
        cf.handle(m)
        ekf.handle(m)
        drag.handle(m)
        if m.kind is Kind.ACCEL and 6.0 < m.t < 50.0 and cf.x is not None:
            tr = np.array([np.interp(m.t, tt, truth["roll"]), np.interp(m.t, tt, truth["pitch"])])
            err["cf"].append(cf.x - tr)
            err["ekf"].append(ekf.x - tr)
            err["drag"].append(drag.x - tr)
            err["accel"].append(np.array(accel_attitude(m.value)) - tr)
    return {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in err.items()}, ekf


def test_accelerometer_attitude_convention():
    g = 9.80665
    roll, pitch = 0.3, -0.2
    f = [g * math.sin(pitch), -g * math.cos(pitch) * math.sin(roll), -g * math.cos(pitch) * math.cos(roll)]
    assert accel_attitude(f) == pytest.approx((roll, pitch))


def test_both_beat_the_accelerometer_and_the_ekf_learns_a_gyro_bias(tmp_path):
    clean, _ = _compare(tmp_path, [])
    assert clean["cf"] < clean["accel"] and clean["ekf"] < clean["accel"]
    biased, ekf = _compare(tmp_path, ["gyro_bias:x=0.02,y=-0.015,z=0"])
    # the complementary filter keeps a steady error b / w_c on top; the EKF estimates b
    # (what remains for both is the accelerometer's attitude in accelerated flight)
    assert biased["ekf"] < 0.7 * biased["cf"] and biased["cf"] > clean["cf"]
    assert ekf.ekf.x[2] == pytest.approx(0.02, abs=0.004) and ekf.ekf.x[3] == pytest.approx(-0.015, abs=0.004)
    # on a multirotor the accelerometer sees drag, not gravity: the drag-model EKF reads the tilt
    # from the velocity the drag reveals, and is an order of magnitude better than both
    assert clean["drag"] < 0.2 * min(clean["cf"], clean["ekf"]) and biased["drag"] < 0.2 * biased["ekf"]
