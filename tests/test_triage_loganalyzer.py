"""Each of ArduPilot's LogAnalyzer tests as a triage finding, on a DataFlash log written for it
(``drivers.logs.dataflash_writer``): the quirk present gives the verdict LogAnalyzer gave at its
thresholds, and the same log without it says nothing. The mapping is docs/triage.md's table."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.logs.dataflash import read_dataflash
from drivers.logs.dataflash_writer import DataFlashWriter
from groundstation.diagnosis.triage import triage

FORMATS = {
    "EV": ("QB", "TimeUS,Id"),
    "ARM": ("QB", "TimeUS,ArmState"),
    "CTUN": ("Qfff", "TimeUS,ThO,BAlt,CRt"),
    "ATT": ("Qfff", "TimeUS,Roll,Pitch,Yaw"),
    "POWR": ("Qf", "TimeUS,Vcc"),
    "BAT": ("Qff", "TimeUS,Volt,Curr"),
    "GPS": ("QBBcLLe", "TimeUS,Status,NSats,HDop,Lat,Lng,Alt"),
    "MAG": ("Qfff", "TimeUS,MagX,MagY,MagZ"),
    "PM": ("QHH", "TimeUS,NLon,NLoop"),
    "BARO": ("Qf", "TimeUS,Alt"),
    "IMU": ("Qfff", "TimeUS,AccX,AccY,AccZ"),
    "PARM": ("QNf", "TimeUS,Name,Value"),
    "OF": ("QBffff", "TimeUS,Qual,flowX,flowY,bodyX,bodyY"),
}


def _triage(tmp_path, rows: dict[str, list[tuple]], params: dict[str, float] | None = None):
    """A .bin of ``rows`` (record -> [(t [s], value, ...)]) and ``params``, read and triaged."""
    f = tmp_path / "quirk.bin"
    with open(f, "wb") as out:
        w = DataFlashWriter(out)
        for name in ["PARM", *rows]:
            w.define(name, *FORMATS[name])
        for name, value in (params or {}).items():
            w.write("PARM", 0, name, value)
        merged = sorted((r[0], name, r[1:]) for name, rs in rows.items() for r in rs)
        for t, name, values in merged:
            w.write(name, int(round(t * 1e6)), *values)
    log = read_dataflash(f)
    return triage(log.tables, log.measurements)


def _named(tr, name):
    return [f for f in tr.findings if f.name == name]


def _flight(t_end: float, height, *, disarm: bool = False) -> dict[str, list[tuple]]:
    t = np.arange(0.0, t_end, 0.1)
    rows = {
        "EV": [(0.5, 10)] + ([(t_end, 11)] if disarm else []),
        "CTUN": [(ti, 0.5, height(ti), 0.0) for ti in t],
        "ATT": [(ti, 0.0, 0.0, 0.0) for ti in t],
    }
    return rows


def test_brownout_a_log_that_stops_armed_in_the_air(tmp_path):
    rows = _flight(30.0, lambda t: min(20.0, t))
    rows["POWR"] = [(t, 5.05) for t in np.arange(0, 30, 1.0)]
    rows["BAT"] = [(t, 15.1, 22.0) for t in np.arange(0, 30, 1.0)]
    (f,) = _named(_triage(tmp_path, rows), "log_ends_in_flight")
    assert f.severity == "error" and "at 20.0 m" in f.evidence and "VCC 5.05 V, battery 15.10 V 22.0 A" in f.evidence
    assert not _named(_triage(tmp_path, _flight(30.0, lambda t: min(20.0, t), disarm=True)), "log_ends_in_flight")
    assert not _named(_triage(tmp_path, _flight(30.0, lambda t: 0.5)), "log_ends_in_flight")  # on the ground


@pytest.mark.parametrize(("vcc", "severity"), [((5.0, 4.4), "error"), ((4.9, 5.3), "warning"), ((5.0, 5.1), None)])
def test_vcc_below_46_fails_and_a_spread_over_03_warns(tmp_path, vcc, severity):
    rows = _flight(10.0, lambda t: 1.0, disarm=True)
    rows["POWR"] = [(t, vcc[0] if t < 5 else vcc[1]) for t in np.arange(0, 10, 0.5)]
    got = _named(_triage(tmp_path, rows), "board_voltage")
    assert [f.severity for f in got] == ([severity] if severity else [])


def test_compass_offsets_and_a_field_that_changes(tmp_path):
    rows = _flight(10.0, lambda t: 1.0, disarm=True)
    (f,) = _named(_triage(tmp_path, rows, {"COMPASS_OFS_X": 400, "COMPASS_OFS_Y": 0, "COMPASS_OFS_Z": 0}), "compass")
    assert f.severity == "warning" and "400 mGauss" in f.evidence
    (f,) = _named(_triage(tmp_path, rows, {"COMPASS_OFS_X": 400, "COMPASS_OFS_Y": 400, "COMPASS_OFS_Z": 0}), "compass")
    assert f.severity == "error"
    rows["MAG"] = [(t, 360.0 if t > 5 else 200.0, 0.0, 300.0) for t in np.arange(0, 10, 0.1)]  # 361 -> 469 mGauss
    (f,) = _named(_triage(tmp_path, rows), "compass")
    assert f.severity == "warning" and "changed" in f.evidence


def test_dupe_log_data_a_block_of_attitude_written_twice(tmp_path):
    rng = np.random.default_rng(1)
    pitch = rng.normal(0, 3, 600)
    rows = _flight(60.0, lambda t: 1.0, disarm=True)
    rows["ATT"] = [(0.1 * k, 0.0, float(p), 0.0) for k, p in enumerate(pitch)]
    assert not _named(_triage(tmp_path, rows), "duplicate_data")
    pitch[400:430] = pitch[50:80]
    rows["ATT"] = [(0.1 * k, 0.0, float(p), 0.0) for k, p in enumerate(pitch)]
    (f,) = _named(_triage(tmp_path, rows), "duplicate_data")
    assert f.severity == "error" and f.t_start == pytest.approx(5.5, abs=0.6)


def test_empty_a_log_whose_vehicle_never_armed(tmp_path):
    rows = {"ARM": [(0.5, 0)], "ATT": [(t, 0.0, 0.0, 0.0) for t in np.arange(0, 5, 0.1)]}
    (f,) = _named(_triage(tmp_path, rows), "no_flight")
    assert f.severity == "info"
    rows["ARM"] = [(0.5, 1), (4.0, 0)]
    assert not _named(_triage(tmp_path, rows), "no_flight")


def test_gps_satellites_and_hdop_in_flight_not_before_the_fix(tmp_path):
    rows = _flight(20.0, lambda t: 1.0, disarm=True)
    rows["EV"] = [(5.0, 10), (20.0, 11)]
    good = [(t, 3, 10, 0.9, 47.0, 8.0, 500.0) for t in np.arange(5, 20, 0.2)]
    boot = [(t, 1, 0, 99.0, 0.0, 0.0, 0.0) for t in np.arange(0, 5, 0.2)]  # no fix yet, disarmed: not judged
    rows["GPS"] = boot + good
    assert not _named(_triage(tmp_path, rows), "gps_quality")
    rows["GPS"] = boot + [(t, 3, 4 if 10 < t < 12 else 10, 0.9, 47.0, 8.0, 500.0) for t in np.arange(5, 20, 0.2)]
    (f,) = _named(_triage(tmp_path, rows), "gps_quality")
    assert f.severity == "error" and "4 satellites" in f.evidence
    rows["GPS"] = boot + [(t, 3, 10, 4.0 if 10 < t < 12 else 0.9, 47.0, 8.0, 500.0) for t in np.arange(5, 20, 0.2)]
    (f,) = _named(_triage(tmp_path, rows), "gps_quality")
    assert f.severity == "warning" and "HDOP 4.0" in f.evidence


def test_nan_in_a_record_is_named_with_its_field(tmp_path):
    rows = _flight(10.0, lambda t: 1.0, disarm=True)
    rows["IMU"] = [(t, float("nan") if 3 < t < 3.2 else 0.0, 0.0, -9.8) for t in np.arange(0, 10, 0.1)]
    (f,) = _named(_triage(tmp_path, rows), "nan_in_records")
    assert "IMU.AccX" in f.evidence and f.t_start == pytest.approx(3.1, abs=0.11)


def test_params_thr_min_thr_mid_and_the_compass_off(tmp_path):
    tr = _triage(tmp_path, _flight(5.0, lambda t: 0.0, disarm=True), {"THR_MIN": 250, "THR_MID": 800, "MAG_ENABLE": 0})
    said = " | ".join(f.evidence for f in _named(tr, "config_risk"))
    assert "THR_MIN = 250" in said and "THR_MID = 800" in said and "MAG_ENABLE = 0" in said


@pytest.mark.parametrize(("slow", "severity"), [([700, 0, 0], "warning"), ([1200, 0, 0], "error"), ([0, 0, 0], None)])
def test_pm_slow_loops(tmp_path, slow, severity):
    rows = _flight(10.0, lambda t: 1.0, disarm=True)
    rows["PM"] = [(1.0 + k, n, 10000) for k, n in enumerate(slow)]
    got = _named(_triage(tmp_path, rows), "slow_loops")
    assert [f.severity for f in got] == ([severity] if severity else [])


def test_pitch_roll_past_angle_max_in_the_air_not_on_the_ground(tmp_path):
    rows = _flight(20.0, lambda t: 5.0, disarm=True)
    rows["ATT"] = [(t, 60.0 if 8 < t < 9 else 0.0, 0.0, 0.0) for t in np.arange(0, 20, 0.1)]
    (f,) = _named(_triage(tmp_path, rows, {"ANGLE_MAX": 3000}), "lean_angle")
    assert "40 deg" in f.evidence and "roll 60" in f.evidence
    rows["CTUN"] = [(t, 0.5, 1.0, 0.0) for t in np.arange(0, 20, 0.1)]  # 1 m up: not flying yet
    assert not _named(_triage(tmp_path, rows, {"ANGLE_MAX": 3000}), "lean_angle")
    assert not _named(_triage(tmp_path, _flight(20.0, lambda t: 5.0, disarm=True)), "lean_angle")


@pytest.mark.parametrize(("climb", "severity"), [(10.0, "error"), (70.0, "warning"), (200.0, None)])
def test_thrust_high_throttle_without_a_climb(tmp_path, climb, severity):
    t = np.arange(0, 30, 0.1)
    rows = _flight(30.0, lambda t: 3.0, disarm=True)
    rows["CTUN"] = [(ti, 0.8 if 10 < ti < 18 else 0.5, 3.0, climb if 10 < ti < 18 else 0.0) for ti in t]
    got = _named(_triage(tmp_path, rows), "thrust_margin")
    assert [f.severity for f in got] == ([severity] if severity else [])


def test_autotune_success_and_failure(tmp_path):
    rows = _flight(20.0, lambda t: 3.0, disarm=True)
    rows["EV"] = [(0.5, 10), (2.0, 30), (8.0, 33), (9.0, 37), (10.0, 30), (15.0, 34), (20.0, 11)]
    got = _named(_triage(tmp_path, rows), "autotune")
    assert [(f.severity, f.t_start) for f in got] == [("warning", 10.0), ("info", 2.0)]
    assert "saved" in got[1].evidence and "failed" in got[0].evidence


def test_a_baro_jump_the_gps_and_the_accelerometer_do_not_share_is_a_glitch(tmp_path):
    t = np.arange(0, 20, 0.02)
    rows = _flight(20.0, lambda t: 5.0, disarm=True)
    rows["BARO"] = [(ti, 5.0 + (6.0 if 10 < ti < 12 else 0.0)) for ti in t]
    rows["IMU"] = [(ti, 0.0, 0.0, -9.8) for ti in t]
    rows["GPS"] = [(ti, 3, 12, 0.8, 47.0, 8.0, 505.0) for ti in np.arange(0, 20, 0.2)]
    got = _named(_triage(tmp_path, rows), "baro_glitch")
    assert len(got) == 2 and "+6.0 m" in got[0].evidence and "the GPS moved +0.0 m" in got[0].evidence
    rows["GPS"] = [(ti, 3, 12, 0.8, 47.0, 8.0, 505.0 + (6.0 if 10 < ti < 12 else 0.0)) for ti in np.arange(0, 20, 0.2)]
    assert not _named(_triage(tmp_path, rows), "baro_glitch")  # the GPS climbed with it: a real motion


def test_calibrations_outside_their_documented_ranges(tmp_path):
    params = {"INS_ACCSCAL_Y": 1.35, "COMPASS_MOT_Z": -1500.0, "INS_ACCOFFS_X": 0.2}
    risks = [f for f in _named(_triage(tmp_path, _flight(5.0, lambda t: 0.0, disarm=True), params), "config_risk")]
    said = " | ".join(f.evidence for f in risks)
    assert "INS_ACCSCAL_Y = 1.35" in said and "COMPASS_MOT_Z = -1500" in said and "INS_ACCOFFS_X" not in said
    assert all(f.severity == "warning" for f in risks if "calibration" in f.evidence)


def test_optical_flow_scale_from_rocking_it(tmp_path):
    t = np.arange(0, 20, 0.01)
    rate = 1.2 * np.sin(2 * np.pi * 0.5 * t)  # rocked +-1.2 rad/s about each axis
    rng = np.random.default_rng(3)
    rows = _flight(20.0, lambda t: 0.0, disarm=True)
    rows["OF"] = [(ti, 200, 0.85 * r + rng.normal(0, 0.02), 1.01 * r, r, r) for ti, r in zip(t, rate)]
    (f,) = _named(_triage(tmp_path, rows, {"FLOW_FXSCALER": 0.0}), "flow_scale")
    # 1000 (1 / 0.85 - 1) = 176
    assert f.severity == "warning" and "0.850 x" in f.evidence and "FLOW_FXSCALER to 17" in f.evidence
    rows["OF"] = [(ti, 200, 0.7 * r, r, r, r) for ti, r in zip(t, rate)]
    (f,) = _named(_triage(tmp_path, rows, {"FLOW_FXSCALER": 0.0}), "flow_scale")
    assert f.severity == "error" and "beyond" in f.evidence  # 429: the setup, not a scale
    rows["OF"] = [(ti, 50, 0.7 * r, r, r, r) for ti, r in zip(t, rate)]  # poor quality: not used
    assert not _named(_triage(tmp_path, rows), "flow_scale")
