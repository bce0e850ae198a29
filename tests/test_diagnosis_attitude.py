"""The IMU's own effects (gyro bias, IMU mounting), found by the attitude model on the raw IMU.

Each case is a 60 s simulated quadcopter flight with the effect undeclared and a
full ``diagnose --model attitude`` (about 10 s together). The sweep over 5 seeds
and 3 magnitudes is ``bench/diagnosis.py --effects gyro_bias,imu_misalignment,clean_attitude``.
"""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from drivers.replay import Replay
from groundstation.core.measurement import Kind
from groundstation.diagnosis.engine import diagnose
from groundstation.diagnosis.models import setup
from groundstation.estimation.models.attitude_drag import attitude_drag_model
from groundstation.estimation.truth import truth_from
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario


def fly(tmp_path, undeclared, seed, imu_hz=500.0):
    log = tmp_path / f"a{seed}.tlog"
    scenario = Scenario.from_args("quad", seed, 60.0, ["range_tilt"], list(undeclared))
    scenario.sensors.rates["imu"] = imu_hz
    run_fast(scenario, log, log.with_suffix(".csv"))
    return log, list(Replay(log).iter_measurements())


@pytest.mark.parametrize("v_d", [math.nan, 0.0, -1.2])
def test_the_jacobian_is_the_derivative_of_the_dynamics(v_d):
    """The EKF relinearises with the hand-written Jacobian: it must be df/dx, misalignment and
    gyro-bias columns included (central differences at a tilted, rotating, moving state), with the
    vertical velocity's q w, p w terms (v_d known) and without them (NaN)."""
    m = attitude_drag_model(gyro_bias=True, misalignment=True)
    x = np.array([0.3, -0.2, 1.5, -0.7, 0.02, -0.01, 0.03, -0.04])
    u = np.array([0.4, -0.3, 0.8, v_d])
    J = m.jacobian(x, u)
    num = np.zeros_like(J)
    for i in range(len(x)):
        dx = np.zeros_like(x)
        dx[i] = 1e-6
        num[:, i] = (m.f(x + dx, u) - m.f(x - dx, u)) / 2e-6
    assert np.allclose(J, num, atol=1e-6), np.round(J - num, 6)


@pytest.mark.slow
@pytest.mark.parametrize(
    "undeclared,name,expect,seed",
    [
        (["gyro_bias:x=0.015,y=-0.01,z=0"], "gyro_bias", {"x": 0.015, "y": -0.01}, 41),
        (["imu_misalignment:roll=2.5,pitch=-1.5,yaw=0"], "imu_misalignment", {"roll": 2.5, "pitch": -1.5}, 42),
    ],
)
def test_an_undeclared_imu_effect_is_found_with_its_parameters(tmp_path, undeclared, name, expect, seed):
    log, ms = fly(tmp_path, undeclared, seed)
    d = diagnose(ms, model_name="attitude", truth=truth_from(ms, log, None))
    assert [e.name for e in d.effects] == [name]
    for k, v in expect.items():
        assert d.effects[0].params[k] == pytest.approx(v, rel=0.15), d.effects[0].params
    before, after = (d.truth.error(r, 8.0, 50.0) for r in (d.before, d.after))
    assert after < 0.2 * before, (math.degrees(before), math.degrees(after))  # a geometric effect: >= 80 %
    nis = {f.test: f for f in d.findings_after if f.sensor == "accel"}["NIS mean"]
    assert 1.8 < nis.statistic < 2.2, nis  # two components: consistent again


@pytest.mark.slow
def test_a_clean_flight_claims_nothing_in_the_attitude_model(tmp_path):
    log, ms = fly(tmp_path, [], 43)
    d = diagnose(ms, model_name="attitude", truth=truth_from(ms, log, None))
    assert d.effects == [] and d.discoveries == []
    assert math.degrees(d.truth.error(d.after, 8.0, 50.0)) < 0.1


@pytest.mark.slow
@pytest.mark.parametrize("imu_hz", [250.0, 1000.0])
def test_the_accelerometers_noise_follows_the_imu_rate(tmp_path, imu_hz):
    """An update is a 10 ms block mean of the IMU's samples: 3 of them at the live demo's 250 Hz,
    10-11 at 1 kHz. Its R is one sample's variance over their number (``per_sample``); fixed at the
    500 Hz blocks' value, a live recording's NIS read 3.74 for 2 (and 1 kHz would read about 1.1)."""
    log, ms = fly(tmp_path, [], 43, imu_hz)
    d = diagnose(ms, model_name="attitude", truth=truth_from(ms, log, None))
    assert d.effects == [] and d.discoveries == []
    nis = {f.test: f for f in d.findings_before if f.sensor == "accel"}["NIS mean"]
    assert 1.9 < nis.statistic < 2.1, nis


@pytest.mark.slow
def test_the_truth_records_the_accelerometer_noise_the_innovations_carry(tmp_path):
    """The simulator's truth records what its accelerometer readings add to the specific force
    (noise and rounding) over each 10 ms row, and the bench judges that noise as it judges the
    innovations. The rows are the diagnosis' IMU blocks: a 500 Hz log's blocks all hold 5 samples
    (from microsecond stamps, without a microsecond's slack three in four take a sixth and the grid
    drifts), and on a clean flight the model's x innovations are that noise."""
    from groundstation.diagnosis.runs.run import run_model

    log, ms = fly(tmp_path, [], 43)
    su = setup(ms, model_name="attitude")
    assert {m.samples for m in su.prep.measurements if m.kind is Kind.ACCEL} == {5}
    acc = run_model(su.model, su.prep, su.make).sensors["accel"]
    truth = np.genfromtxt(log.with_suffix(".csv"), delimiter=",", names=True)
    row = np.searchsorted(truth["t"], acc.t + 0.01 - 1e-6)  # a block stamped t closes at t + 10 ms
    ok = (row < len(truth)) & (acc.t > 5.0)
    assert np.allclose(truth["t"][row[ok]], acc.t[ok] + 0.01)
    noise = truth["accel_err_x"][row[ok]]
    assert 0.95 < np.std(noise) / (0.08 / math.sqrt(5)) < 1.05
    assert np.corrcoef(acc.nu[ok, 0], noise)[0, 1] > 0.99


@pytest.mark.slow
def test_the_vertical_speed_makes_a_manoeuvring_flights_accelerometer_consistent(tmp_path):
    """The q w and p w terms need the body's vertical velocity; the diagnosis takes v_d from its own
    altitude filter. Without them this clean flight (climbs under tilt manoeuvres) read NIS 2.10
    (band [1.94, 2.06]) and Ljung-Box p = 0.000, and its roll/pitch error was 1.06 mrad (0.47 with)."""
    log, ms = fly(tmp_path, [], 1054)
    d = diagnose(ms, model_name="attitude", truth=truth_from(ms, log, None))
    assert d.effects == []
    acc = {f.test: f for f in d.findings_after if f.sensor == "accel"}
    assert acc["NIS mean"].passed and acc["Ljung-Box whiteness"].passed, acc
    assert d.truth.error(d.after, 8.0, 50.0) < 0.7e-3
    # the input it came from: the altitude filter's climb rate (not the log's VFR_HUD climb, 0 in the
    # simulator's logs), against the simulator's truth
    climb = [m for m in setup(ms, model_name="attitude").prep.measurements if m.kind is Kind.CLIMB_RATE]
    assert climb and {m.source for m in climb} == {"altitude model"}
    truth = np.genfromtxt(log.with_suffix(".csv"), delimiter=",", names=True)
    t = np.array([m.t for m in climb])
    err = np.array([m.value[0] for m in climb]) + np.interp(t, truth["t"], truth["vd"])
    assert np.sqrt(np.mean(err[t > 5.0] ** 2)) < 0.05


@pytest.mark.slow
def test_a_gyro_bias_and_a_mounting_error_at_once_are_both_found(tmp_path):
    log, ms = fly(tmp_path, ["gyro_bias:x=0.01,y=-0.02,z=0", "imu_misalignment:roll=-2,pitch=3,yaw=0"], 31)
    d = diagnose(ms, model_name="attitude", truth=truth_from(ms, log, None))
    found = {e.name: e.params for e in d.effects}
    assert set(found) == {"gyro_bias", "imu_misalignment"}
    assert found["gyro_bias"]["y"] == pytest.approx(-0.02, rel=0.15)
    assert found["imu_misalignment"]["pitch"] == pytest.approx(3.0, rel=0.15)
    assert d.truth.error(d.after, 8.0, 50.0) < 0.1 * d.truth.error(d.before, 8.0, 50.0)


@pytest.mark.slow
def test_the_attitude_report_gives_the_angle_error_in_degrees(tmp_path):
    log, _ = fly(tmp_path, ["gyro_bias:x=0.02,y=0,z=0"], 44)
    out = tmp_path / "rep"
    r = subprocess.run(
        [sys.executable, "-m", "groundstation", "diagnose", str(log), "--model", "attitude", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    j = json.loads((out / "report.json").read_text())
    assert j["effects"][0]["name"] == "gyro_bias" and j["after"]["rmse_of"] == "roll and pitch [rad]"
    assert "baro_thrust" in j["unobservable"] and "accel_bias" in j["unobservable"]
    assert "Roll and pitch error against the simulator sidecar" in j["conclusion"]
    assert "deg</b> before" in (out / "report.html").read_text()
    head = (out / "estimates_after.csv").read_text().splitlines()[0].split(",")
    assert head[:3] == ["t", "roll", "pitch"] and "b_p" in head


def test_attitude_diagnosis_needs_a_raw_imu(tmp_path):
    from .conftest import real_file

    p = real_file("ardupilot_dataflash/ardupilot_loganalyzer_underpowered.log")  # no IMU in it
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "groundstation",
            "diagnose",
            str(p),
            "--model",
            "attitude",
            "--out",
            str(tmp_path / "d"),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "no raw IMU" in r.stderr and "Traceback" not in r.stderr


def test_the_live_buffer_averages_the_imu_as_a_log_is_prepared(tmp_path):
    """The dashboard's diagnosis sees the same 10 ms IMU block means as a log's: the attitude
    model's accelerometer noise is that of a block mean."""
    from groundstation.core.measurement import Kind
    from groundstation.diagnosis.live import SessionBuffer
    from groundstation.diagnosis.runs.run import prepare

    log = tmp_path / "b.tlog"
    run_fast(Scenario.from_args("quad", 45, 12.0, ["range_tilt"], []), log)
    ms = list(Replay(log).iter_measurements())
    buf = SessionBuffer()
    for m in ms:
        buf.add(m)
    for kind in (Kind.ACCEL, Kind.GYRO):
        live = [m for m in buf.window(1e9) if m.kind is kind]
        logged = [m for m in prepare(ms).measurements if m.kind is kind]
        assert len(live) == len(logged) - 1 > 1000  # the last block is still open
        assert np.allclose([m.t for m in live], [m.t for m in logged[:-1]])
        assert np.allclose([m.value for m in live], [m.value for m in logged[:-1]])


def test_the_vertical_velocity_input_comes_from_velocity_or_climb_rate_and_goes_stale():
    """v_d (NED down) from VELOCITY_NED or CLIMB_RATE (up: the sign flips), NaN once older than
    VD_MAX_AGE (the model then leaves the q w, p w terms out); a GNSS board's VELOCITY_NED, whose
    vertical component is NaN, leaves the last one."""
    from groundstation.core.measurement import Measurement
    from groundstation.estimation.routing import VD_MAX_AGE, attitude_estimator

    est = attitude_estimator()

    def gyro(t):
        est.handle(Measurement(t, Kind.GYRO, np.array([0.1, -0.2, 0.05]), "t"))
        return est.filter.u

    assert math.isnan(gyro(0.0)[3])
    est.handle(Measurement(0.01, Kind.VELOCITY_NED, np.array([1.0, 2.0, -0.7]), "t"))
    assert gyro(0.02)[3] == -0.7
    est.handle(Measurement(0.03, Kind.CLIMB_RATE, np.array([0.4]), "t"))
    assert gyro(0.04)[3] == -0.4
    est.handle(Measurement(0.05, Kind.VELOCITY_NED, np.array([1.0, 2.0, math.nan]), "t"))
    assert gyro(0.06)[3] == -0.4
    assert math.isnan(gyro(0.03 + VD_MAX_AGE + 0.01)[3])
