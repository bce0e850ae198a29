"""Triage: what a log says happened, stated before any model is fitted, on the real logs the
flight-log tools' users bring (ArduPilot's LogAnalyzer examples, a real tlog, a PX4 ULog), and
the fit cut to the stretches where the model holds."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.logs.tables import LogTables, Table
from groundstation.core.measurement import Kind, Measurement
from groundstation.diagnosis.triage import triage, usable
from groundstation.estimation.logs import load_log

from .conftest import REPO, real_file

FIXTURES = REPO / "tests" / "fixtures"


def _triage(path: Path):
    log = load_log(path)
    return log, triage(log.tables, log.measurements)


def _named(tr, name: str):
    return [f for f in tr.findings if f.name == name]


def test_mechanical_failure_is_a_crash_and_a_flip_stated_first_with_motor_two_working_hardest():
    """ArduPilot's mechanical_fail.log: the peers (LogAnalyzer) say upside down (roll 178 deg),
    radio failsafe, fence, CRASH, and motor 2 about 80 us above the others throughout."""
    _, tr = _triage(real_file("ardupilot_dataflash/ardupilot_loganalyzer_mechanical_fail.log"))
    first = tr.findings[:3]
    assert {f.name for f in first} == {"crash", "flip"} and all(f.severity == "critical" for f in first)
    flips = _named(tr, "flip")
    assert len(flips) == 1 and "2 times" in flips[0].evidence and "roll 178 deg" in flips[0].evidence
    assert 90 < flips[0].t_start < 94
    assert any("ERR: crash detected" in f.evidence and f.t_start == pytest.approx(110.0, abs=0.2) for f in tr.findings)
    fs = " ".join(f.evidence for f in _named(tr, "failsafe"))
    assert "radio failsafe" in fs and "fence breach" in fs
    (imb,) = _named(tr, "motor_imbalance")
    assert imb.detail["motor"] == 2 and 50 <= imb.detail["offset_us"] <= 110
    assert imb.t_end < flips[0].t_start  # judged on the flight before the crash, not on the tumble


def test_erle_log_crash_flip_gps_ekf_gap_and_configuration():
    """The erle log: roll not followed from about 28 s of the log (49 s of its boot clock), a crash,
    a GPS glitch and failsafe with the fix lost, a 22 s logging gap, the EKF's position test ratio
    1.63, ARMING_CHECK 0 and a compass never calibrated."""
    _, tr = _triage(real_file("ardupilot_dataflash/erle_pxf_copter_Loiter_RTL.bin"))
    assert sorted(f.name for f in tr.findings[:3]) == ["crash", "crash", "flip"]
    crash, flip = _named(tr, "crash")[0], _named(tr, "flip")[0]
    assert 48.5 < crash.t_start < 50.0 and 48.5 < flip.t_start < 50.0
    assert "attitude not followed" in crash.evidence
    (gap,) = _named(tr, "logging_gap")
    assert gap.t_end - gap.t_start == pytest.approx(22.2, abs=0.3)
    assert any("GPS glitch" in f.evidence for f in _named(tr, "gps_glitch"))
    assert any("3-D fix lost" in f.evidence for f in _named(tr, "gps_glitch"))
    assert any("GPS lost" in f.evidence for f in _named(tr, "failsafe"))
    ekf = [f for f in _named(tr, "ekf_innovation") if f.severity == "error"]
    assert len(ekf) == 1 and "position test ratio up to 1.63" in ekf[0].evidence
    assert ekf[0].t_start == pytest.approx(104.3, abs=0.5)  # 83.6 s of the log's own start, boot at 20.7 s
    risks = " ".join(f.evidence for f in _named(tr, "config_risk"))
    assert "ARMING_CHECK = 0" in risks and "compass was never calibrated" in risks


def test_dronekit_tlog_vibration_clipping_and_battery():
    """The dronekit tlog (a fixture: Apache-2.0): VibeZ up to 85 m/s^2, 716 and 1,406 clipping
    events, the battery down to 6.98 V at 475 s of the recording, "Low Battery!" from the vehicle."""
    _, tr = _triage(FIXTURES / "dronekit_flight.tlog")
    assert tr.clock == "recording"
    vib = _named(tr, "vibration")
    assert any("up to 85.4 m/s^2" in f.evidence and f.severity == "error" for f in vib)
    clip = _named(tr, "clipping")
    assert clip and all("counter 0: 716, counter 1: 1406" in f.evidence for f in clip)
    (bat,) = [f for f in _named(tr, "battery") if "critical" in f.evidence]
    assert "6.98 V at 475 s" in bat.evidence and "3S" in bat.evidence
    assert any('"Low Battery!"' in f.evidence for f in _named(tr, "failsafe"))
    assert not _named(tr, "crash") and not _named(tr, "flip")


def test_underpowered_log_battery_failsafe_and_a_gps_failsafe_that_is_only_no_gps():
    """underpowered.log: the battery failsafe near the end (about 425 s on its row clock); the
    GPS failsafe ArduCopter 3.0 raises at boot on a vehicle with no GPS is a configuration, not a
    stretch to cut (it would cut the whole flight)."""
    log, tr = _triage(real_file("ardupilot_dataflash/ardupilot_loganalyzer_underpowered.log"))
    (bfs,) = [f for f in _named(tr, "failsafe") if "battery failsafe" in f.evidence]
    assert bfs.t_start == pytest.approx(425.0, abs=2.0) and bfs.cuts
    assert any("no GPS fix at all" in f.evidence for f in _named(tr, "config_risk"))
    kept, used, cut = usable(log.measurements, tr)
    assert [c["name"] for c in cut] == ["failsafe"] and used[0][0] == pytest.approx(0.0, abs=0.2)
    assert sum(b - a for a, b in used) > 420 and len(kept) > 0.98 * len(log.measurements)


def test_px4_ulog_reads_and_triages():
    """PX4/pyulog's sample_log_small.ulg (PX4 v1.11 on a CubeOrange): measurements in SI on the
    boot clock, every topic as a table, the parameters, and a triage with nothing wrong in it."""
    log, tr = _triage(FIXTURES / "px4_sample_log_small.ulg")
    kinds = {m.kind for m in log.measurements}
    assert {Kind.ACCEL, Kind.GYRO, Kind.ATTITUDE, Kind.BARO_ALTITUDE, Kind.GPS, Kind.BATTERY_VOLTAGE} <= kinds
    acc = np.array([m.value for m in log.measurements if m.kind is Kind.ACCEL])
    assert np.median(acc[:, 2]) == pytest.approx(-9.8, abs=0.5)  # FRD: gravity's reaction along -z
    assert log.tables.autopilot == "px4" and "sensor_combined" in log.tables and len(log.tables.params) > 500
    assert not [f for f in tr.findings if f.severity in ("critical", "error")]


@pytest.mark.slow
def test_triage_command_says_the_crash_first(tmp_path):
    """``groundstation triage LOG --json`` on the erle log: the roll-over first."""
    p = real_file("ardupilot_dataflash/erle_pxf_copter_Loiter_RTL.bin")
    r = subprocess.run(
        [sys.executable, "-m", "groundstation", "triage", str(p), "--json"], capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    j = json.loads(r.stdout)
    assert j["findings"][0]["name"] in ("crash", "flip") and j["findings"][0]["severity"] == "critical"
    assert set(j["findings"][0]) >= {"name", "t_start", "t_end", "severity", "evidence", "doc"}


def test_a_log_that_is_not_one_is_a_one_line_error(tmp_path):
    bad = tmp_path / "x.ulg"
    bad.write_bytes(b"ULog\x01\x12\x35" + b"\x00" * 5)  # the magic, then nothing readable
    r = subprocess.run([sys.executable, "-m", "groundstation", "triage", str(bad)], capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr and str(bad) in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


# ------------------------------------------------------------------ synthetic: each check alone


def _att_tables(t, roll, des_roll=None) -> LogTables:
    cols = {"Roll": roll, "Pitch": np.zeros_like(t)}
    if des_roll is not None:
        cols |= {"DesRoll": des_roll, "DesPitch": np.zeros_like(t)}
    return LogTables({"ATT": Table(t, cols)}, fmt="dataflash", autopilot="ardupilot")


def test_flip_is_upside_down_and_a_bank_is_not():
    t = np.arange(0, 20, 0.1)
    bank = np.where((t > 5) & (t < 8), 60.0, 0.0)
    assert not _named(triage(_att_tables(t, bank), []), "flip")
    flip = np.where(t > 12, 175.0, 0.0)
    (f,) = _named(triage(_att_tables(t, flip), []), "flip")
    assert f.t_start == pytest.approx(12.1, abs=0.11) and f.cuts and f.t_end == pytest.approx(19.9)


def _heartbeats(t, base_mode, system_status) -> LogTables:
    n = len(t)
    cols = {
        "base_mode": np.full(n, 0.0) + base_mode,
        "system_status": np.full(n, 0.0) + system_status,
        "type": np.full(n, 2.0),
        "autopilot": np.full(n, 3.0),
        "custom_mode": np.zeros(n),
    }
    return LogTables({"HEARTBEAT": Table(t, cols)}, fmt="tlog", autopilot="ardupilot")


def test_a_heartbeat_states_arming_by_its_armed_bit_or_by_the_active_state():
    """MAVLink's MAV_STATE_ACTIVE is "motors are engaged": a vehicle whose HEARTBEAT says so without
    the base mode's armed bit (81: custom mode, stabilize, manual input) flew, and is not a log
    with nothing in it; with neither, it is."""
    t = np.arange(0.0, 60.0, 1.0)
    flying = (t >= 3) & (t < 50)
    standby_then_active = np.where(flying, 4.0, 3.0)
    assert not _named(triage(_heartbeats(t, 81.0, standby_then_active), []), "no_flight")
    assert not _named(triage(_heartbeats(t, np.where(flying, 81.0 + 128.0, 81.0), 3.0), []), "no_flight")
    (f,) = _named(triage(_heartbeats(t, 81.0, 3.0), []), "no_flight")
    assert f.severity == "info"


def test_crash_is_attitude_not_followed_for_a_second_not_a_brief_lag():
    t = np.arange(0, 20, 0.1)
    asked = np.where(t > 5, 20.0, 0.0)
    lag = np.where((t > 5) & (t < 5.5), 0.0, asked)  # 0.5 s behind a 20 deg step: not a crash
    assert not _named(triage(_att_tables(t, lag, asked), []), "crash")
    lost = np.where(t > 10, -40.0, asked)  # asked +20, rolling -40 from 10 s on
    (c,) = _named(triage(_att_tables(t, lost, asked), []), "crash")
    assert c.t_start == pytest.approx(10.1, abs=0.11) and "up to 60 deg" in c.evidence


def test_err_resolution_closes_the_failsafe_and_only_its_stretch_is_cut():
    err = Table(np.array([10.0, 14.0]), {"Subsys": np.array([5.0, 5.0]), "ECode": np.array([1.0, 0.0])})
    tables = LogTables({"ERR": err}, fmt="dataflash", autopilot="ardupilot")
    ms = [Measurement(float(t), Kind.BARO_ALTITUDE, np.array([1.0]), "x", float(t)) for t in np.arange(0, 30, 0.5)]
    tr = triage(tables, ms)
    (fs,) = _named(tr, "failsafe")
    assert (fs.t_start, fs.t_end) == (10.0, 14.0) and "radio failsafe" in fs.evidence
    kept, used, cut = usable(ms, tr)
    assert used == [(0.0, 10.0), (14.0, 29.5)] and all(not 10.0 <= m.t <= 14.0 for m in kept)
    assert cut == [{"name": "failsafe", "t_start": 10.0, "t_end": 14.0, "why": fs.evidence}]


def test_vibration_from_the_raw_accelerometer_where_the_log_has_no_metric():
    """A 1 kHz accelerometer with a 60 m/s^2 rotor harmonic from 10 to 20 s (RMS 42 m/s^2): above
    30, below 60 (its amplitude, not its RMS, passes 60)."""
    rng = np.random.default_rng(1)
    t = np.arange(0, 30, 0.001)
    a = np.zeros((len(t), 3))
    a[:, 2] = -9.81 + 0.1 * rng.standard_normal(len(t))
    on = (t > 10) & (t < 20)
    a[on, 2] += 60 * np.sin(2 * np.pi * 140 * t[on])
    ms = [Measurement(float(ti), Kind.ACCEL, v, "x", float(ti)) for ti, v in zip(t, a)]
    (v,) = _named(triage(LogTables(fmt="crazyflie"), ms), "vibration")
    assert v.t_start == pytest.approx(10, abs=1.1) and v.t_end == pytest.approx(19, abs=1.1)
    assert v.severity == "warning" and "raw accelerometer at 1000 Hz" in v.evidence


# ------------------------------------------------------------------ diagnose: triage first, the fit cut


def _gs(*args, timeout=600):
    return subprocess.run(
        [sys.executable, "-m", "groundstation", *args], capture_output=True, text=True, timeout=timeout
    )


@pytest.mark.slow
def test_diagnose_of_a_crash_fits_only_the_flight_before_it(tmp_path):
    """mechanical_fail.log through ``diagnose`` (the thrust model: it has no IMU): the crash and the
    flip open the report and its conclusion, the fit ends where the first of them (the fence
    failsafe at 88.1 s) begins, so no effect can be claimed from the tumble; the estimates stop there."""
    p = real_file("ardupilot_dataflash/ardupilot_loganalyzer_mechanical_fail.log")
    out = tmp_path / "d"
    r = _gs("diagnose", str(p), "--model", "quad_thrust", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert r.stdout.index("CRITICAL crash") < r.stdout.index("fitting the model to 0.0-88.1 s")
    j = json.loads((out / "report.json").read_text())
    assert j["triage"][0]["name"] in ("crash", "flip") and j["triage"][0]["severity"] == "critical"
    assert j["segments_used"] == [{"t_start": 0.0, "t_end": 88.1}]
    assert {"crash", "flip", "failsafe"} <= {c["name"] for c in j["segments_cut"]}
    assert j["conclusion"].startswith("The log shows crash at")
    ts = [float(row.split(",")[0]) for row in (out / "estimates_after.csv").read_text().splitlines()[1:]]
    assert max(ts) <= 88.1
    html = (out / "report.html").read_text()
    assert html.index("What the log says happened") < html.index("Effects found")
    for e in j["effects"]:  # each claim names the parameters a GCS would set, or says there is none
        assert any(s["effect"] == e["name"] for s in j["parameters"]), e["name"]


@pytest.mark.slow
def test_a_ulog_replays_evaluates_and_diagnoses(tmp_path):
    """PX4/pyulog's sample_px4_events.ulg (PX4 SITL, 31 s, baro and GPS): the live path replays it,
    ``evaluate`` scores the estimators on it, ``diagnose`` runs the loop and writes PX4's parameter
    file (QGroundControl's format) for what it found."""
    ulg = FIXTURES / "px4_sitl_events.ulg"
    est = tmp_path / "est.csv"
    r = _gs("replay", str(ulg), "--speed", "max", "--no-web", "--quiet", "--export", str(est))
    assert r.returncode == 0, r.stderr
    rows = est.read_text().splitlines()
    assert rows[0].startswith("t,z,vz") and len(rows) > 100
    r = _gs("evaluate", str(ulg))
    assert r.returncode == 0 and "altitude" in r.stdout, r.stderr
    r = _gs("diagnose", str(ulg), "--out", str(tmp_path / "d"))
    assert r.returncode == 0, r.stderr
    j = json.loads((tmp_path / "d" / "report.json").read_text())
    assert "triage" in j and "parameters" in j and j["before"]["sensors"]["baro"]["n"] > 300
    px4 = [p for p in j["parameters"] if p["autopilot"] == "PX4" and p["name"]]
    assert px4  # SITL's baro and GPS are quieter than a real vehicle's: their noise levels, at least
    lines = [ln for ln in (tmp_path / "d" / "params_px4.params").read_text().splitlines() if not ln.startswith("#")]
    assert [ln.split("\t")[2] for ln in lines] == [p["name"] for p in px4]
    assert all(ln.split("\t")[:2] == ["1", "1"] and ln.split("\t")[4] in ("6", "9") for ln in lines)


# ------------------------------------------------------------------ simulated flights with injected faults


def _sim(tmp_path, effect: str, seconds: float = 30.0):
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    p = tmp_path / "f.tlog"
    run_fast(Scenario.from_args("quad", 3, seconds, [], [effect] if effect else []), p)
    return p, _triage(p)[1]


def test_simulated_clean_flight_has_nothing_to_say(tmp_path):
    _, tr = _triage(_sim(tmp_path, "")[0])
    assert not [f for f in tr.findings if f.severity != "info"], tr.summary()


def test_simulated_weak_motor_shows_as_that_motor_working_harder(tmp_path):
    """Motor 2 losing 15 % of its thrust from 8 s: the attitude loop drives it 1/0.85 harder (about
    70 us at the hover's 1500 us), the vehicle stays level."""
    _, tr = _sim(tmp_path, "motor_failure:motor=2,loss=0.15,t=8")
    (imb,) = _named(tr, "motor_imbalance")
    assert imb.detail["motor"] == 2 and 50 < imb.detail["offset_us"] < 100
    assert not _named(tr, "flip") and not _named(tr, "motor_saturation")


def test_a_weak_motor_shows_alike_through_dshot_escs(tmp_path):
    """The same weak motor in a PX4 log whose ESCs speak DShot (``actuator_outputs`` 0..1999): read
    as the pulse of the same share of the range, motor 2 works harder by what the pulse widths show
    (the idle's share aside); read as microseconds, by 184 "us", an error where there is a warning."""
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    sc = Scenario.from_args("quad", 3, 30.0, [], ["motor_failure:motor=2,loss=0.15,t=8"])
    sc.sensors.esc = "dshot"
    p = tmp_path / "f.ulg"
    run_fast(sc, p)
    (imb,) = _named(_triage(p)[1], "motor_imbalance")
    assert imb.detail["motor"] == 2 and 50 < imb.detail["offset_us"] < 100 and "(DShot)" in imb.evidence


def test_simulated_failing_motor_saturates_then_the_vehicle_flips(tmp_path):
    """Motor 1 losing half its thrust from 15 s: at full output it still falls short, the vehicle
    rolls over: the flip first, then the saturated motor and its imbalance before the flip."""
    _, tr = _sim(tmp_path, "motor_failure:motor=1,loss=0.5,t=15")
    assert tr.findings[0].name == "flip" and 15.0 < tr.findings[0].t_start < 22.0
    (sat,) = _named(tr, "motor_saturation")
    assert "most often motor 1" in sat.evidence and sat.t_start == pytest.approx(15.0, abs=0.6)
    (imb,) = _named(tr, "motor_imbalance")
    assert imb.detail["motor"] == 1 and imb.t_end <= tr.findings[0].t_start


def test_simulated_vibration_from_the_raw_imu(tmp_path):
    """A 123 Hz rotor harmonic of 90 m/s^2 at full throttle (45 at the hover): the sim sends no
    VIBRATION message, so the raw 500 Hz accelerometer gives the level, above 30 m/s^2."""
    _, tr = _sim(tmp_path, "vibration:A=90")
    (v,) = _named(tr, "vibration")
    assert v.severity == "warning" and "raw accelerometer at 500 Hz" in v.evidence
    assert v.t_end - v.t_start > 20


@pytest.mark.slow
def test_diagnosis_of_a_simulated_crash_claims_nothing_from_the_tumble(tmp_path, monkeypatch):
    """A flight whose motor 3 stops at 12 s (it rolls over within a second and tumbles to the end):
    the triage cuts the flight from where the tilt passed 30 deg, and the diagnosis of what is left
    claims nothing the simulator does not have (its range sensor reads the slant distance, always:
    the roll towards 30 deg shows it). Fitted to the whole log instead, the tumble reads as an
    accelerometer scale error (1.5 % on this flight), the first effect claimed."""
    from groundstation.diagnosis.claims import search
    from groundstation.diagnosis.engine import diagnose

    p, tr = _sim(tmp_path, "motor_failure:motor=3,loss=1,t=12", seconds=40.0)
    assert tr.findings[0].name == "flip"
    out = tmp_path / "d"
    r = _gs("diagnose", str(p), "--out", str(out))
    assert r.returncode == 0, r.stderr
    j = json.loads((out / "report.json").read_text())
    flip = tr.findings[0]
    assert j["segments_used"][0]["t_end"] == pytest.approx(flip.t_start, abs=0.01)
    assert all(s["t_end"] <= flip.t_start + 1e-3 or s["t_start"] >= flip.t_end - 1e-3 for s in j["segments_used"])
    assert {e["name"] for e in j["effects"]} <= {"range_tilt"}, j["conclusion"]
    monkeypatch.setattr(search, "MAX_EFFECTS", 1)
    whole = diagnose(load_log(p).measurements, source=str(p), model_name="altitude")
    assert whole.effects[0].name == "accel_scale"  # what the cut keeps out


def test_two_imus_that_disagree_past_the_pre_arm_limit():
    """IMU 1 reads 1.0 m/s^2 more along x than IMU 0 from 10 to 20 s (ArduPilot's pre-arm limit
    is 0.75); gyros agree."""
    ms = []
    for t in np.arange(0, 30, 0.01):
        off = 1.0 if 10 <= t < 20 else 0.0
        for inst, dx in ((0, 0.0), (1, off)):
            ms.append(Measurement(float(t), Kind.ACCEL, np.array([dx, 0.0, -9.81]), "x", float(t), None, inst))
            ms.append(Measurement(float(t), Kind.GYRO, np.zeros(3), "x", float(t), None, inst))
    (f,) = _named(triage(LogTables(fmt="dataflash"), ms), "imu_mismatch")
    assert f.t_start == pytest.approx(10, abs=1) and f.t_end == pytest.approx(20, abs=1)
    assert "accel 0 and 1 differ by up to 1.00 m/s^2" in f.evidence


def test_ekf_lane_switch_and_px4_test_ratios():
    t = np.arange(0, 10, 0.1)
    xkf4 = Table(t, {"C": np.zeros_like(t), "PI": np.where(t > 6, 1.0, 0.0), "SV": np.full_like(t, 0.2)})
    est = Table(t, {"hgt_test_ratio": np.where((t > 3) & (t < 4), 1.7, 0.1), "mag_test_ratio": np.full_like(t, np.inf)})
    tr = triage(LogTables({"XKF4": xkf4, "estimator_status": est}, fmt="ulog"), [])
    (lane,) = _named(tr, "lane_switch")
    assert lane.t_start == pytest.approx(6.1) and "from 0 to 1" in lane.evidence
    (ekf,) = _named(tr, "ekf_innovation")  # the magnetometer's inf (not fused) is no finding
    assert "height test ratio up to 1.70" in ekf.evidence and ekf.severity == "error"


def test_vibe_clipping_counts_and_a_saturated_motor():
    t = np.arange(0, 60, 0.1)
    clip = np.cumsum((t > 30) & (t < 33)).astype(float)  # one clip a record for 3 s
    vibe = Table(t, {"VibeX": np.full_like(t, 5.0), "VibeY": np.full_like(t, 5.0), "VibeZ": np.full_like(t, 20.0),
                     "Clip0": clip, "Clip1": np.zeros_like(t), "Clip2": np.zeros_like(t)})  # fmt: skip
    pwm = np.full((len(t), 4), 1550.0)
    pwm[t > 40, 2] = 2000.0  # motor 3 at the top for the last 20 s of the flight
    rcou = Table(t, {f"C{i + 1}": pwm[:, i] for i in range(4)})
    tr = triage(LogTables({"VIBE": vibe, "RCOU": rcou}, fmt="dataflash", autopilot="ardupilot"), [])
    (c,) = _named(tr, "clipping")
    assert c.t_start == pytest.approx(30.1, abs=0.11) and "counter 0: 29" in c.evidence and c.cuts
    assert not _named(tr, "vibration")  # 20 m/s^2 is within ArduPilot's 30
    (s,) = _named(tr, "motor_saturation")
    assert "most often motor 3" in s.evidence and s.severity == "error"  # a third of the flight


def test_a_rotor_harmonic_gives_a_harmonic_notch(tmp_path):
    """The simulator's 123 Hz rotor harmonic on the accelerometer (500 Hz IMU): a throttle-referenced
    notch at that frequency, half as wide, referenced to the hover throttle; a clean flight none."""
    from groundstation.diagnosis.report.autopilot_params import suggest_notch

    p, _ = _sim(tmp_path, "vibration:A=20")
    got = {s.name: s.value for s in suggest_notch(load_log(p).measurements, "ardupilot")}
    assert got["INS_HNTCH_FREQ"] == pytest.approx(123, abs=1.0) and got["INS_HNTCH_BW"] == pytest.approx(61.5, abs=1)
    assert 0.4 < got["INS_HNTCH_REF"] < 0.7 and got["INS_HNTCH_MODE"] == 1
    p, _ = _sim(tmp_path, "")
    assert suggest_notch(load_log(p).measurements, "ardupilot") == []


def _idle_then_flight(throttle_record: bool) -> list[Measurement]:
    """60 s armed at idle on the ground with a strong 60 Hz shake, then 30 s in flight with a weaker
    123 Hz rotor harmonic: a 500 Hz IMU, four motor outputs at 50 Hz, and a throttle record beside
    them only where ``throttle_record`` (a PX4 1.14 ULog has none)."""
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 90.0, 0.002)
    flying = t >= 60.0
    shake = np.where(flying, 0.3 * np.sin(2 * np.pi * 123.0 * t), 1.0 * np.sin(2 * np.pi * 60.0 * t))
    ms = []
    for kind, rest in ((Kind.GYRO, (0.0, 0.0, 0.0)), (Kind.ACCEL, (0.0, 0.0, -9.81))):
        v = np.array(rest) + shake[:, None] + rng.normal(0.0, 0.05, (len(t), 3))
        ms += [Measurement(ti, kind, vi, "imu", ti) for ti, vi in zip(t.tolist(), v)]
    for ti in np.arange(0.0, 90.0, 0.02).tolist():
        u = 0.5 if ti >= 60.0 else 0.05
        ms.append(Measurement(ti, Kind.ACTUATOR, np.full(4, u), "outputs", ti))
        if throttle_record:
            ms.append(Measurement(ti, Kind.THROTTLE, np.array([u]), "throttle", ti))
    return sorted(ms, key=lambda m: m.t)


def test_the_notch_is_read_in_flight_also_from_the_motor_outputs_alone():
    """The flight's 123 Hz, not the longer and stronger idle shake on the ground, with a throttle
    record and with the motor outputs alone; the hover throttle only from the throttle record (the
    outputs are on another scale)."""
    from groundstation.diagnosis.report.autopilot_params import notch_from_imu

    with_throttle = notch_from_imu(_idle_then_flight(True))
    outputs_alone = notch_from_imu(_idle_then_flight(False))
    assert with_throttle is not None and outputs_alone is not None
    assert with_throttle[0] == pytest.approx(123.0, abs=1.0) and with_throttle[2] == pytest.approx(0.5)
    assert outputs_alone[0] == pytest.approx(123.0, abs=1.0) and np.isnan(outputs_alone[2])


@pytest.mark.slow
def test_the_diagnosis_suggests_the_notch_alike_on_one_process_and_beside_it(tmp_path):
    """``diagnose`` reads the notch from the raw IMU before the diagnosis lets go of it: on one process
    there and then, on two in a process forked for it; the same parameters either way."""
    from groundstation.diagnosis.pipeline import run

    p, _ = _sim(tmp_path, "vibration:A=20")
    got = []
    for workers in (1, 2):
        d = run(p, tmp_path / f"out{workers}", workers=workers)
        got.append({x["name"]: x["value"] for x in d.report["parameters"] if x["name"].startswith("INS_HNTCH")})
    assert got[0] == got[1] and got[0]["INS_HNTCH_FREQ"] == pytest.approx(123, abs=1.0), got


def _text_log(path: Path, params: dict[str, str], seconds: float, att, acc) -> Path:
    """A text DataFlash log as an ArduCopter 3.1 writes one (FMT lines, then records on TimeMS): its
    parameters, ATT at 10 Hz from ``att(t) -> (roll, pitch)`` [deg] and IMU at 50 Hz from
    ``acc(t) -> (ax, ay, az)`` [m/s^2], the gyros still."""
    lines = [
        "ArduCopter V3.1 (5c6503e2)",
        "FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns",
        "FMT, 129, 23, PARM, Nf, Name,Value",
        "FMT, 130, 31, IMU, Iffffff, TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ",
        "FMT, 131, 31, ATT, IcccccCC, TimeMS,RollIn,Roll,PitchIn,Pitch,YawIn,Yaw,NavYaw",
    ]
    lines += [f"PARM, {k}, {v}" for k, v in params.items()]
    for k in range(int(seconds * 50)):
        ms = 1000 + 20 * k
        ax, ay, az = acc(ms / 1000.0)
        lines.append(f"IMU, {ms}, 0.001, -0.002, 0.001, {ax:.3f}, {ay:.3f}, {az:.3f}")
        if k % 5 == 0:
            roll, pitch = att(ms / 1000.0)
            lines.append(f"ATT, {ms}, 0, {roll:.2f}, 0, {pitch:.2f}, 0, 10.00, 10.00")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_an_attitude_estimate_that_runs_away_on_the_ground_is_a_divergence_not_a_flip(tmp_path):
    """The issue's ArduCopter 3.1 log: COMPASS_MOT_X/Y/Z are NaN; the vehicle sits level at idle while its
    roll estimate runs to 95 deg. The raw IMU says level and still: an estimator divergence with the NaN
    parameters named as the likely cause, never a flip or a crash."""
    nan = {"COMPASS_MOT_X": "nan", "COMPASS_MOT_Y": "nan", "COMPASS_MOT_Z": "nan", "ARMING_CHECK": "1"}
    p = _text_log(
        tmp_path / "diverged.log",
        nan,
        30.0,
        att=lambda t: (min(95.0, max(0.0, (t - 10.0) * 12.0)), 0.0),
        acc=lambda t: (0.01, -0.02, -9.81),
    )
    _, tr = _triage(p)
    names = [f.name for f in tr.findings]
    assert "flip" not in names and "crash" not in names, tr.summary()
    (div,) = _named(tr, "estimator_divergence")
    assert "COMPASS_MOT_X" in div.evidence and "likely cause" in div.evidence and div.cuts
    assert "COMPASS_MOT_X" in _named(tr, "bad_parameter")[0].evidence
    # the same attitude with an accelerometer that turns over with it: a flip
    p2 = _text_log(
        tmp_path / "flipped.log",
        {},
        30.0,
        att=lambda t: (min(170.0, max(0.0, (t - 10.0) * 40.0)), 0.0),
        acc=lambda t: (
            0.0,
            9.81 * np.sin(np.radians(min(170.0, max(0.0, (t - 10.0) * 40.0)))),
            -9.81 * np.cos(np.radians(min(170.0, max(0.0, (t - 10.0) * 40.0)))),
        ),
    )
    assert "flip" in [f.name for f in _triage(p2)[1].findings]


def test_every_finding_is_shown_folded_and_counted(tmp_path):
    """The text output had said "5 findings" and printed 2 (the info ones hidden, CBRK_SUPPLY_CHK
    among them); 80 imu_mismatch lines on one log were one story. All are shown: repeats folded into
    the worst with their count, info last."""
    from groundstation.diagnosis.triage import Triage, TriageFinding

    fs = [TriageFinding("imu_mismatch", float(k), k + 0.5, "warning", f"accel differ by {k}") for k in range(80)]
    fs += [TriageFinding("config_risk", 0.0, 0.0, "info", "CBRK_SUPPLY_CHK = 894281: that safety check is disabled")]
    fs += [TriageFinding("mode_change", float(k), float(k), "info", "mode LOITER") for k in range(3)]
    text = Triage(fs, "vehicle", (0.0, 100.0), 0.1, records=100).summary()
    assert "84 findings" in text and "(and 79 more like it, 0.0-79.5 s)" in text
    assert "CBRK_SUPPLY_CHK" in text and "mode LOITER (x3" in text
    assert len(text.splitlines()) == 4
