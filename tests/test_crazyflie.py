"""Crazyflie uSD logs (real flights with Vicon truth, read from ../shared; never copied here)."""

import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest

from drivers.logs.crazyflie import (
    CrazyflieLogError,
    is_crazyflie_log,
    measurements,
    read_crazyflie,
)
from groundstation.core.measurement import Kind

from .conftest import real_file

LOGS = ["0425-traj6", "0425-traj4", "0422-log00"]


@pytest.mark.parametrize("name", LOGS)
def test_reads_every_log_with_its_crc_and_converts_units_and_frames(name):
    p = real_file(f"crazyflie_util/{name}")
    assert is_crazyflie_log(p)
    log = read_crazyflie(p)
    assert log.crc_ok and log.damage is None and 28 < log.duration < 51
    ms = measurements(log)
    kinds = {m.kind for m in ms}
    assert {Kind.ACCEL, Kind.GYRO, Kind.BARO_ALTITUDE, Kind.RANGE, Kind.TRUTH_POSE} <= kinds
    t0 = ms[0].t  # microseconds since boot
    still = [m.value for m in ms if m.kind is Kind.ACCEL and m.t < t0 + 1.0]
    assert np.mean(still, axis=0)[2] == pytest.approx(-9.81, abs=0.15)  # FRD: level reads -g on z
    vicon = [m for m in ms if m.kind is Kind.TRUTH_POSE]
    assert -2.1 < min(m.value[2] for m in vicon) and max(m.value[2] for m in vicon) < 0.0  # NED: down is +
    baro = [m.t for m in ms if m.kind is Kind.BARO_ALTITUDE]
    assert 20 < len(baro) / log.duration < 30  # repeats dropped: ~25 Hz


def test_truncated_and_corrupted_files_keep_what_came_before(tmp_path):
    raw = real_file("crazyflie_util/0425-traj4").read_bytes()
    cut = tmp_path / "cut"
    cut.write_bytes(raw[:1_000_000])
    log = read_crazyflie(cut)
    assert log.damage and "cut" in log.damage and "offset" in log.damage
    assert len(measurements(log)) > 10_000
    bad = bytearray(raw)
    bad[500_000] ^= 0xFF  # a value byte: records stay aligned, the CRC catches it
    (tmp_path / "bad").write_bytes(bytes(bad))
    log = read_crazyflie(tmp_path / "bad")
    assert not log.crc_ok and "CRC-32 mismatch" in log.damage


@pytest.mark.parametrize(
    "content,text",
    [
        (b"\xbc\x03\x00\x00\x00" + b"\x00" * 10, "version 3"),
        (b"hello", "not a Crazyflie"),
        (b"\xbc\x02\x00\x05\x00\x01", "damaged"),
    ],
)
def test_foreign_files_are_clear_errors(tmp_path, content, text):
    p = tmp_path / "x"
    body = content
    p.write_bytes(body + struct.pack("<I", zlib.crc32(body)))
    with pytest.raises(CrazyflieLogError, match=text):
        read_crazyflie(p)


@pytest.mark.parametrize("name", LOGS)
@pytest.mark.slow
def test_evaluate_the_altitude_filter_against_vicon(name):
    p = real_file(f"crazyflie_util/{name}")
    r = subprocess.run([sys.executable, "-m", "groundstation", "evaluate", str(p)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    lines = {ln.split()[0]: ln.split() for ln in r.stdout.splitlines() if ln.split()}
    est, tof, tof_o = float(lines["estimate"][1]), float(lines["range"][2]), float(lines["range-o"][2])
    # The bar: the filter (IMU input, baro and ToF updates) beats the ToF alone.
    assert tof < 0.05 and est < 0.95 * tof
    # Against the ToF with the same mounting offset applied the margin is thin: the
    # IMU input carries rotor vibration, and on traj4 (tilts to 17 deg) the slant is
    # left in both (see crazyflie.json). Kept here so a regression shows.
    assert est < 1.15 * tof_o


@pytest.mark.slow
def test_diagnose_finds_what_the_data_readme_describes_on_0422_log00():
    """The closed loop on measured data: the baro's jump when the rotors carry the vehicle (README: +8.7 m)
    and its drift in flight (0.09-0.13 m/s), the ToF's mounting offset against Vicon (-3.3 to -4.0 cm),
    and the height error against Vicon before and after. A few minutes: 50 s of 1 kHz IMU, every
    candidate a full filter run."""
    from groundstation.diagnosis.engine import diagnose
    from groundstation.estimation.logs import load_measurements
    from groundstation.estimation.truth import truth_from

    p = real_file("crazyflie_util/0422-log00")
    ms, _desc, vehicle = load_measurements(p)  # as `groundstation diagnose` reads it
    assert vehicle == "crazyflie"
    d = diagnose(ms, source=str(p), vehicle=vehicle, truth=truth_from(ms, None, None))
    found = {e.name: e.params for e in d.effects}
    assert list(found)[:1] == ["baro_thrust"], list(found)
    assert 6.0 < found["baro_thrust"]["k"] < 11.0  # per unit throttle; ~0.9 at hover here
    # the drift is sized as the README gives it; a constant rate fitted on two thirds of this flight
    # loses on the third (25.6 in log-likelihood), so it is claimed only when it holds out of sample
    drift = {e.name: e for e in d.effects + d.rejected}["baro_bias_drift"]
    assert 0.07 < drift.params["rate"] < 0.14
    assert drift in d.effects or "not fitted on" in drift.evidence["reason"], drift.evidence
    offset = {e.name: e.params for e in d.against_truth}["range_offset"]["o"]
    assert -0.042 < offset < -0.030
    before, after = (d.truth.rmse(r.t, r.x[:, 0], r.t[0] + 5.0, r.t[-1]) for r in (d.before, d.after))
    assert after < 0.3 * before, (before, after)
    # the baro's innovations stay coloured (vibration, the throttle's shape): the report says how much
    # of the evidence survives counting them at their effective sample size
    thrust = {e.name: e.evidence for e in d.effects}["baro_thrust"]
    assert thrust["innovation_colour"]["baro"] > 10 and thrust["delta_bic_effective"] > thrust["delta_bic"]
    from groundstation.diagnosis.report.conclusion import conclusion
    from groundstation.diagnosis.report.report import as_json

    assert "Counted at their effective sample size, baro_thrust scores" in conclusion(d, as_json(d))
    # what still colours the baro after the fit (the throttle's shape, README: 60 % in sample) is not
    # named: predicted on stretches it was not fitted on, the regression explains too little of it
    assert not any(x.sensor == "baro" for x in d.discoveries)


@pytest.mark.slow
def test_attitude_diagnosis_rejects_a_mounting_error_that_vicon_contradicts():
    """The attitude model on 0422-log00: a large "IMU mounting error" fits the vibrating
    accelerometer better, and makes roll and pitch worse against Vicon. It is rejected, said
    with its evidence, and what is kept does not worsen the estimate."""
    from groundstation.diagnosis.engine import diagnose
    from groundstation.diagnosis.report.conclusion import conclusion
    from groundstation.diagnosis.report.report import as_json
    from groundstation.estimation.logs import load_measurements
    from groundstation.estimation.truth import truth_from

    p = real_file("crazyflie_util/0422-log00")
    ms, _desc, vehicle = load_measurements(p)
    truth = truth_from(ms, None, None)
    d = diagnose(ms, source=str(p), model_name="attitude", vehicle=vehicle, truth=truth)
    assert "imu_misalignment" not in [e.name for e in d.effects]
    rejected = {e.name: e for e in d.rejected}
    ev = rejected["imu_misalignment"].evidence
    assert ev["delta_bic"] < -10 and ev["error_with"] > 1.2 * ev["error_before"]
    t0, t1 = d.before.t[0] + 5.0, d.before.t[-1]
    assert truth.error(d.after, t0, t1) <= truth.error(d.before, t0, t1) < np.radians(1.0)
    j = as_json(d)
    assert j["rejected"][0]["name"] == "imu_misalignment"
    assert "was rejected" in conclusion(d, j)
    # without the veto the same log "has" the mounting error: the guard is what keeps it out
    d2 = diagnose(ms, source=str(p), model_name="attitude", vehicle=vehicle, truth=truth, veto_with_truth=False)
    assert d2.effects[0].name == "imu_misalignment" and truth.error(d2.after, t0, t1) > np.radians(3.0)


@pytest.mark.slow
def test_diagnose_finds_the_tofs_slant_under_tilt_on_0425_traj4():
    """The closed loop on measured data: traj4 tilts to 18 deg, and the data README's regression of the ToF's
    error on z (1/cos - 1) has slope 0.95. The diagnosis finds the slant from the log's own gyro tilt
    (derived.with_attitude), keeps it against Vicon, and the height error falls by two thirds
    (3.05 -> 0.96 cm measured; with the accelerometer's tilt it was vetoed, 3.21 -> 7.33 cm)."""
    from groundstation.diagnosis.engine import diagnose
    from groundstation.estimation.logs import load_measurements
    from groundstation.estimation.truth import truth_from

    p = real_file("crazyflie_util/0425-traj4")
    ms, _desc, vehicle = load_measurements(p)
    d = diagnose(ms, source=str(p), vehicle=vehicle, truth=truth_from(ms, None, None))
    found = {e.name: e.evidence for e in d.effects}
    assert "range_tilt" in found and "range_tilt" not in [e.name for e in d.rejected], list(found)
    assert found["range_tilt"]["delta_bic"] < -30 and found["range_tilt"]["delta_bic_effective"] < -10
    # the baro's drift is not steady over this flight: a rate fitted on two thirds of it loses on the
    # third, and it is turned away with the reason instead of claimed
    drift = {e.name: e for e in d.effects + d.rejected}["baro_bias_drift"]
    assert 0.06 < drift.params["rate"] < 0.14
    assert drift in d.effects or "not fitted on" in drift.evidence["reason"], drift.evidence
    before, after = (d.truth.rmse(r.t, r.x[:, 0], r.t[0] + 5.0, r.t[-1]) for r in (d.before, d.after))
    assert after < 0.5 * before and after < 0.015, (before, after)
