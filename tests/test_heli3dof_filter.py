"""The lab document's 3-DOF Kalman filter: observability, R from stationary data, accuracy."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from drivers.replay import Replay
from groundstation.core.measurement import Kind
from groundstation.estimation.loop import EstimationLoop
from groundstation.estimation.models.heli3dof import observability_report
from groundstation.estimation.noise import load_noise
from groundstation.estimation.registry import build_estimator
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario


def test_observability_as_the_lab_reports():
    r = observability_report()
    assert r["gyro"] == 4  # lab eq. (50)
    assert r["gyro+accel"] == 5  # lab eq. (58): travel is not observable from the IMU
    assert r["encoders"] == 6


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    d = tmp_path_factory.mktemp("h3")
    run_fast(Scenario("heli3dof", seed=2, duration=30), d / "h.tlog", d / "h.csv")
    return d


def _run(d, imu_only, noise=None):
    est = build_estimator("heli3dof", noise=noise)
    if imu_only:  # the lab's filter: no encoders
        est._by_kind.pop(Kind.ATTITUDE, None)
    loop = EstimationLoop([est])
    snaps = loop.snapshots.subscribe()
    for m in Replay(d / "h.tlog").iter_measurements():
        loop.push(m)
    rows = list(csv.DictReader(open(d / "h.csv")))
    tt = np.array([float(r["t"]) for r in rows])
    s = snaps.get_nowait()
    ts = np.array([x.t for x in s])
    keep = (ts > 8) & (ts < 28)
    X = np.array([x.x for x in s])[keep]
    rmse = {
        nm: float(np.sqrt(np.mean((X[:, i] - np.interp(ts[keep], tt, np.array([float(r[nm]) for r in rows]))) ** 2)))
        for i, nm in enumerate(est.model.states)
    }
    return est, rmse


@pytest.mark.slow
def test_noise_command_and_imu_only_filter(flight):
    out = flight / "noise.json"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "groundstation",
            "noise",
            str(flight / "h.tlog"),
            "--model",
            "heli3dof",
            "--start",
            "0",
            "--end",
            "1.9",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    d = json.loads(out.read_text())
    assert set(d) >= {"gyro", "accel"} and d["gyro"]["n"] > 900
    gyro_var = np.diag(np.array(d["gyro"]["R"]))
    assert gyro_var == pytest.approx([0.005**2] * 3, rel=0.25)  # the simulated gyro's noise
    est, rmse = _run(flight, imu_only=True, noise=load_noise(out))
    assert rmse["p"] < 0.01 and rmse["e"] < 0.01 and rmse["p_dot"] < 0.01
    for sensor, dof in (("accel", 2), ("gyro", 3)):
        a = est.filter.log.arrays(sensor)
        assert 0.5 * dof < a["nis"][a["t"] > 8].mean() < 1.5 * dof


@pytest.mark.slow
def test_encoders_make_travel_observable(flight):
    _, imu = _run(flight, imu_only=True)
    _, enc = _run(flight, imu_only=False)
    assert enc["lambda"] < 0.01 and enc["p"] < imu["p"]
