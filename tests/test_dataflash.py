"""ArduPilot DataFlash logs through pymavlink's DFReader, with the time base fixed."""

import re
import subprocess
import sys

import numpy as np
import pytest

from drivers.logs.dataflash import DataFlashError, read_dataflash
from groundstation.core.measurement import Kind

from .conftest import foreign2_file, real_file

DURATIONS = {
    "ardupilot_loganalyzer_underpowered.log": 430.1,
    "ardupilot_loganalyzer_mechanical_fail.log": 110.0,
    "pyflightcoach_pilot_0004.BIN": 99.4,
    "erle_pxf_copter_Loiter_RTL.bin": 257.9,  # boot 20.7 s to 278.6 s, GPS on the same clock
}


@pytest.mark.parametrize("name,duration", DURATIONS.items())
def test_reads_every_log(name, duration):
    log = read_dataflash(real_file(f"ardupilot_dataflash/{name}"))
    assert log.duration == pytest.approx(duration, abs=0.5)
    ts = [m.t for m in log.measurements]
    assert ts == sorted(ts)


def test_clockless_text_log_gets_the_control_loop_clock_and_shows_the_voltage_sag():
    log = read_dataflash(real_file("ardupilot_dataflash/ardupilot_loganalyzer_underpowered.log"))
    assert log.clock.startswith("row count of CTUN")
    by = {
        k: np.array([(m.t, m.value[0]) for m in log.measurements if m.kind is k])
        for k in (Kind.THROTTLE, Kind.BATTERY_VOLTAGE, Kind.RANGE, Kind.BARO_ALTITUDE)
    }
    v = by[Kind.BATTERY_VOLTAGE]
    thr = np.interp(v[:, 0], by[Kind.THROTTLE][:, 0], by[Kind.THROTTLE][:, 1])
    air = thr > 0.3
    # the data README: volts 10.9 -> 9.2 in the air, corr(throttle, volt) = -0.86
    assert v[air, 1][:20].mean() > 10.5 and v[air, 1].min() < 9.3
    assert np.corrcoef(thr[air], v[air, 1])[0, 1] < -0.8
    assert by[Kind.RANGE][:, 1].max() < 8.0  # sonar 0.2-7.7 m


def test_the_sonars_clamped_readings_are_skipped_with_the_limits_the_log_gives():
    """underpowered.log's sonar (SONAR_TYPE 0, an XL-EZ0: ArduPilot's driver sets 20-765 cm) reads
    exactly its floor or its no-echo maximum 564 times, mostly on the ground, where a replay showed
    the vehicle 7.65 m up: they are counted skips, not heights. Newer logs give the limits as
    RNGFND parameters; a log with no rangefinder parameters keeps every positive reading."""
    from drivers.logs.dataflash import rangefinder_limits

    log = read_dataflash(real_file("ardupilot_dataflash/ardupilot_loganalyzer_underpowered.log"))
    assert log.range_limits == (0.2, 7.65) and log.skipped["range_out_of_bounds"] == 564
    r = np.array([m.value[0] for m in log.measurements if m.kind is Kind.RANGE])
    assert len(r) == 4302 - 564 and 0.2 < r.min() and r.max() < 7.65
    assert rangefinder_limits({"RNGFND_MIN_CM": 20.0, "RNGFND_MAX_CM": 700.0, "SONAR_TYPE": 1.0}) == (0.2, 7.0)
    assert rangefinder_limits({"RNGFND1_MIN_CM": 5.0, "RNGFND1_MAX_CM": 400.0}) == (0.05, 4.0)
    assert rangefinder_limits({"SONAR_ENABLE": 1.0, "SONAR_TYPE": 1.0}) == (0.15, 6.45)
    assert rangefinder_limits({"SONAR_ENABLE": 0.0, "SONAR_TYPE": 0.0}) is None
    assert rangefinder_limits({}) is None


def test_binary_log_units_and_frames():
    log = read_dataflash(real_file("ardupilot_dataflash/erle_pxf_copter_Loiter_RTL.bin"))
    acc = np.array([m.value for m in log.measurements if m.kind is Kind.ACCEL][:50])
    assert acc[:, 2].mean() == pytest.approx(-9.8, abs=0.2)  # FRD, at rest
    temps = [m.value[0] for m in log.measurements if m.kind is Kind.TEMPERATURE]
    assert 280 < min(temps) and max(temps) < 330  # kelvin


def test_foreign_and_truncated_files(tmp_path):
    (tmp_path / "x.bin").write_bytes(b"\x00" * 5000)
    with pytest.raises(DataFlashError, match="not a DataFlash log"):
        read_dataflash(tmp_path / "x.bin")
    raw = real_file("ardupilot_dataflash/erle_pxf_copter_Loiter_RTL.bin").read_bytes()
    (tmp_path / "cut.bin").write_bytes(raw[:400_000])
    log = read_dataflash(tmp_path / "cut.bin")
    assert 50 < log.duration < 278  # what came before the cut is kept


@pytest.mark.slow
def test_replay_export_and_evaluate_on_dataflash(tmp_path):
    p = real_file("ardupilot_dataflash/ardupilot_loganalyzer_underpowered.log")
    out = tmp_path / "e.csv"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "groundstation",
            "replay",
            str(p),
            "--speed",
            "max",
            "--no-web",
            "--export-measurements",
            str(out),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    assert "battery_voltage" in out.read_text()
    n_max = int(re.search(r"done: (\d+) measurements", r.stdout).group(1))
    # paced: 430 s of log at 100x, every record delivered
    r = subprocess.run(
        [sys.executable, "-m", "groundstation", "replay", str(p), "--no-web", "--quiet", "--speed", "100"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    assert int(re.search(r"done: (\d+) measurements", r.stdout).group(1)) == n_max


@pytest.mark.slow
def test_a_baro_given_as_pressure_and_altitude_is_one_update_with_its_own_zero():
    """DataFlash BARO carries Press and Alt for one sample: the filter reads it once (it once
    read it twice, the two against one shared zero, and NIS came out at 5e5)."""
    from groundstation.estimation.evaluate import evaluate

    p = real_file("ardupilot_dataflash/erle_pxf_copter_Loiter_RTL.bin")
    n_baro = sum(1 for m in read_dataflash(p).measurements if m.kind is Kind.BARO_PRESSURE)
    rows = {r.sensor: r for r in evaluate(p).rows}
    row = rows["baro"]
    assert n_baro - 60 <= row.n <= n_baro and row.nis < 10.0
    assert "landed" not in rows  # the ground's pseudo-sensor (models.ground) is not a sensor's row


def test_current_messages_rangefinder_battery_compass_and_instances(tmp_path):
    """ArduPilot 4.x records, as a text log writes them: RFND (metres; only a good, downward
    reading is a range), BAT, CTUN's short names (ThO, BAlt), BARO and IMU with their instance, MAG
    in milligauss; the rest (VIBE) kept as a table on the same clock."""
    lines = [
        "FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns",
        "FMT, 129, 31, IMU, QBffffff, TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ",
        "FMT, 130, 20, BARO, QBfff, TimeUS,I,Alt,Press,Temp",
        "FMT, 131, 20, RFND, QBfBB, TimeUS,Instance,Dist,Stat,Orient",
        "FMT, 132, 20, BAT, QBff, TimeUS,Inst,Volt,Curr",
        "FMT, 133, 20, CTUN, Qff, TimeUS,ThO,BAlt",
        "FMT, 134, 20, MAG, QBfff, TimeUS,I,MagX,MagY,MagZ",
        "FMT, 135, 20, VIBE, QBfff, TimeUS,IMU,VibeX,VibeY,VibeZ",
    ]
    for k in range(20):
        us = 1_000_000 + 100_000 * k
        lines += [
            f"IMU, {us}, {k % 2}, 0, 0, 0, 0, 0, -9.8",
            f"BARO, {us}, 1, 2.5, 101000, 30",
            f"RFND, {us}, 0, 1.25, {4 if k < 15 else 1}, {25 if k % 5 else 0}",
            f"BAT, {us}, 0, 15.6, 12.5",
            f"CTUN, {us}, 0.42, 2.4",
            f"MAG, {us}, 0, 200, 0, 400",
            f"VIBE, {us}, 0, 3.5, 4.5, 12.0",
        ]
    p = tmp_path / "modern.log"
    p.write_text("\n".join(lines) + "\n")
    log = read_dataflash(p)
    by = {k: [m for m in log.measurements if m.kind is k] for k in Kind}
    assert len(by[Kind.RANGE]) == 12 and all(m.value[0] == 1.25 for m in by[Kind.RANGE])  # good and down
    assert log.skipped["range_not_good"] == 4
    assert {m.instance for m in by[Kind.ACCEL]} == {0, 1} and {m.instance for m in by[Kind.BARO_PRESSURE]} == {1}
    assert by[Kind.BATTERY_VOLTAGE][0].value[0] == 15.6 and by[Kind.BATTERY_CURRENT][0].value[0] == 12.5
    assert by[Kind.THROTTLE][0].value[0] == pytest.approx(0.42)
    assert np.allclose(by[Kind.MAG][0].value, [2e-5, 0.0, 4e-5])  # 200 and 400 mG in tesla
    vibe = log.tables["VIBE"]
    assert vibe.t[0] == pytest.approx(1.0) and vibe["VibeZ"][0] == pytest.approx(12.0)


def test_the_gps_records_velocity_is_ned_and_a_damaged_one_is_left_out(tmp_path):
    """ArduPilot's GPS record: Spd and GCrs (ground speed, course over the ground) and VZ (its
    velocity.z: down) are VELOCITY_NED. A speed or course that is not a number (a damaged record)
    gives no velocity and no traceback; the position still reads."""
    lines = [
        "FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns",
        "FMT, 129, 31, IMU, QBffffff, TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ",
        "FMT, 130, 45, GPS, QBBIHBcLLeffff, TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw",
    ]
    for k, (spd, crs) in enumerate([(5.0, 90.0), (2.0, 180.0), ("nan", 90.0), (3.0, "inf")]):
        us = 1_000_000 + 200_000 * k
        lines += [
            f"IMU, {us}, 0, 0, 0, 0, 0, 0, -9.8",
            f"GPS, {us}, 0, 3, 1000, 2200, 12, 0.8, 47.39, 8.54, 490.5, {spd}, {crs}, -1.5, 0",
        ]
    p = tmp_path / "gps.log"
    p.write_text("\n".join(lines) + "\n")
    log = read_dataflash(p)
    gps = [m for m in log.measurements if m.kind is Kind.GPS]
    vel = [m.value for m in log.measurements if m.kind is Kind.VELOCITY_NED]
    assert len(gps) == 4 and len(vel) == 2
    assert np.allclose(vel[0], [0.0, 5.0, -1.5], atol=1e-9) and np.allclose(vel[1], [-2.0, 0.0, -1.5], atol=1e-9)


def test_records_without_a_clock_share_the_imus():
    """The erle log's ERR records and its ArduCopter 3.3 GPS (boot time in T) on the IMU's clock:
    the crash check's ERR comes as logging resumes after the 22 s gap, and the first GPS fix
    within a second of the first IMU sample (the log starts 20.7 s after boot)."""
    log = read_dataflash(real_file("ardupilot_dataflash/erle_pxf_copter_Loiter_RTL.bin"))
    first_imu = min(m.t for m in log.measurements if m.kind is Kind.ACCEL)
    first_gps = min(m.t for m in log.measurements if m.kind is Kind.GPS)
    assert first_imu == pytest.approx(20.66, abs=0.05) and abs(first_gps - first_imu) < 1.0
    err = log.tables["ERR"]
    crash = err.t[(err["Subsys"] == 12) & (err["ECode"] == 1)]
    imu_t = log.tables["IMU"].t
    assert len(crash) == 1 and imu_t[imu_t < crash[0]].max() == pytest.approx(51.5, abs=0.1)


def test_an_arducopter_30_text_log_whose_gps_has_no_week_is_read(tmp_path):
    """ArduCopter 3.0.x text logs write GPS with ``Time`` and no week: pymavlink's text reader could
    not set up its clock (``unsupported operand type(s) for *: 'int' and 'NoneType'``) and the log was
    refused. Read by the project's own text reader: its GPS, throttle, baro, sonar and raw IMU, its
    firmware from the header line, and it triages."""
    from groundstation.diagnosis.triage import triage
    from groundstation.estimation.logs import load_log

    lines = [
        "ArduCopter V3.0.1",
        "FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns",
        "FMT, 129, 23, PARM, Nf, Name,Value",
        "FMT, 130, 45, GPS, BIBcLLeeEe, Status,Time,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs",
        "FMT, 131, 27, IMU, ffffff, GyrX,GyrY,GyrZ,AccX,AccY,AccZ",
        "FMT, 132, 30, CTUN, hcefhhhhh, ThrIn,SonAlt,BarAlt,WPAlt,NavThr,AngBst,CRate,ThrOut,DCRate",
        "FMT, 133, 9, MODE, Mh, Mode,ThrCrs",
        "PARM, SONAR_TYPE, 0",
        "MODE, STABILIZE, 0",
    ]
    for k in range(200):
        lines.append(f"GPS, 3, {100000 + 200 * k}, 9, 1.20, -35.3632, 149.1652, 1.50, 584.10, 0.10, 12.00")
        lines.append(f"CTUN, 500, 1.20, {1.0 + 0.01 * k:.2f}, 1.50, 500, 0, 10, 520, 0")
        lines.append("IMU, 0.01, 0.0, 0.0, 0.1, 0.0, -9.80")
    p = tmp_path / "ac30.log"
    p.write_text("\n".join(lines) + "\n")
    log = read_dataflash(p)
    kinds = {m.kind for m in log.measurements}
    assert {Kind.GPS, Kind.THROTTLE, Kind.BARO_ALTITUDE, Kind.RANGE, Kind.ACCEL} <= kinds
    assert log.tables.firmware == "ArduCopter V3.0.1" and log.clock.startswith("row count")
    loaded = load_log(p, imu_columns=True)
    tr = triage(loaded.tables, loaded.measurements, loaded.imu)
    assert tr.records > 0 and "mode STABILIZE" in tr.summary()


@pytest.mark.slow
def test_a_simulated_flight_as_the_vehicles_own_dataflash_log_diagnoses_as_its_tlog(tmp_path):
    """``sim --fast --log X.bin`` writes what the vehicle itself would log (flight_log.py): the same
    flight as a tlog and as a .bin, each diagnosed from the log alone, name the same hidden effect
    with the same size."""
    from groundstation.diagnosis.engine import diagnose
    from groundstation.diagnosis.report.autopilot_params import suggest
    from groundstation.diagnosis.triage import triage
    from groundstation.estimation.logs import load_log
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    found = {}
    for suffix in (".tlog", ".bin"):
        log = tmp_path / f"f{suffix}"
        run_fast(Scenario.from_args("quad", 7, 60.0, ["range_tilt"], ["baro_thrust:k=3"], flight="high"), log)
        loaded = load_log(log)
        ms = loaded.measurements
        said = triage(loaded.tables, ms).findings
        assert [f.severity for f in said if f.severity != "info"] == [], [f.line() for f in said]
        d = diagnose(ms, source=str(log), declared=[{"name": "range_tilt"}])
        found[suffix] = [(e.name, round(e.params["k"], 2)) for e in d.effects]
        (scale,) = [p for p in suggest(d, ms, loaded.tables.params, "ardupilot") if p.name == "BARO1_THST_SCALE"]
        assert -40.0 < scale.value < -30.0 and "lags the throttle by 0.4" in scale.why  # (the simulator's 0.5 s)
    assert found[".bin"] == found[".tlog"] and found[".bin"][0][0] == "baro_thrust", found
    assert found[".bin"][0][1] == pytest.approx(3.0, abs=0.2)


def _same_reading(fast, slow) -> None:
    """``read_dataflash(imu_columns=True)`` against the record-by-record read split as ``load_log`` split it:
    the same readings, IMU columns, counts, clock, duration and tables, number for number."""
    from groundstation.core.imu import ImuColumns
    from groundstation.core.readings import Readings

    rest, imu = ImuColumns.split(slow.measurements)
    a, b = list(Readings.of(fast.measurements)), list(Readings.of(rest))
    assert [(m.t, m.kind, m.instance, m.t_rx, m.source) for m in a] == [
        (m.t, m.kind, m.instance, m.t_rx, m.source) for m in b
    ]
    assert all(np.array_equal(x.value, y.value, equal_nan=True) for x, y in zip(a, b))
    assert fast.imu.series.keys() == imu.series.keys()
    for key, s in imu.series.items():
        g = fast.imu.series[key]
        for got, want in ((g.t, s.t), (g.t_rx, s.t_rx), (g.value, s.value), (g.samples, s.samples)):
            assert got.dtype == want.dtype and np.array_equal(got, want)
    assert (fast.counts, fast.skipped, fast.clock, fast.duration) == (
        slow.counts,
        slow.skipped,
        slow.clock,
        slow.duration,
    )
    assert fast.tables.tables.keys() == slow.tables.tables.keys() and fast.tables.params == slow.tables.params
    for name, want in slow.tables.tables.items():
        got = fast.tables.tables[name]
        assert np.array_equal(got.t, want.t) and list(got.cols) == list(want.cols)
        for c, col in want.cols.items():
            assert col.dtype == object or np.array_equal(got.cols[c], col, equal_nan=True)
            assert col.dtype != object or got.cols[c].tolist() == col.tolist()


def test_the_imu_read_as_arrays_is_the_imu_read_record_by_record(tmp_path):
    """A 1 kHz IMU is most of a log's records: read as arrays per record type (``imu_columns``) it
    gives what DFReader's records of it give, on a simulated vehicle's own log."""
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    log = tmp_path / "sim.bin"
    run_fast(Scenario.from_args("quad", 5, 20.0, ["range_tilt"], []), log)
    fast = read_dataflash(log, imu_columns=True)
    assert fast.imu is not None and len(fast.imu) == 2 * fast.counts["IMU"] > 10_000
    _same_reading(fast, read_dataflash(log))


@pytest.mark.slow
def test_the_imu_read_as_arrays_is_the_imu_read_record_by_record_on_foreign_and_real_logs():
    """As above on another generator's logs (Copter 4.5's IMU, with its temperature and error
    counts, and its attitude at the IMU's 400 Hz, in centidegrees, read as arrays too); one of them
    holds an FMT header's bytes inside a record, which is data and no damage. A log the fast read
    cannot take (the IMU on a TimeMS clock, records without a time of their own, a cut end) is read
    record by record."""
    for rel in ("clean_s1.bin", "baro_thrust_s1.bin"):
        p = foreign2_file(rel)
        fast = read_dataflash(p, imu_columns=True)
        assert fast.imu is not None and fast.damage == "" and fast.counts["ATT"] == fast.counts["IMU"] > 50_000
        _same_reading(fast, read_dataflash(p))
    for rel in (
        "ardupilot_dataflash/erle_pxf_copter_Loiter_RTL.bin",
        "ardupilot_dataflash/pyflightcoach_pilot_0004.BIN",
    ):
        assert read_dataflash(real_file(rel), imu_columns=True).imu is None  # TimeMS; FILE records, a cut end
