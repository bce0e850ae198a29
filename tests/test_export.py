"""The CSV exports across a vehicle restart: time never goes back within one file; the next
flight segment goes on beside it (``OUT.seg2.csv``), and the counters list the segments."""

from __future__ import annotations

import csv
import json
import time
from types import SimpleNamespace

import numpy as np

from groundstation.core.measurement import Kind, Measurement
from groundstation.estimation.export import EstimateCsvWriter, MeasurementCsvWriter, segment_path
from groundstation.estimation.loop import Snapshot


def _times(path) -> list[float]:
    return [float(r["t"]) for r in csv.DictReader(open(path))]


def _snap(t: float) -> Snapshot:
    return Snapshot(t, "altitude", ("z", "vz"), np.array([1.0, 0.0]), np.eye(2) * 0.01, None, time.monotonic())


def test_estimates_go_on_in_a_new_file_after_a_restart(tmp_path):
    w = EstimateCsvWriter(tmp_path / "est.csv", "altitude", ["z", "vz"])
    for t in (10.0, 10.1, 10.05, 10.2, 0.1, 0.2):  # a late one (0.05 s back) stays; then a restart
        w.write(_snap(t))
    w.close(counters=SimpleNamespace(updates=6, rejected={}, diverged=0, reinitialisations=0))
    assert _times(tmp_path / "est.csv") == [10.0, 10.1, 10.05, 10.2]
    assert _times(tmp_path / "est.seg2.csv") == [0.1, 0.2]
    assert json.loads((tmp_path / "est.counters.json").read_text())["segments"] == ["est.csv", "est.seg2.csv"]


def test_measurements_follow_each_source_on_its_own_clock(tmp_path):
    """A board on its own clock, seconds apart from the vehicle's, is no restart; the vehicle's
    clock going back is."""
    w = MeasurementCsvWriter(tmp_path / "m.csv")
    one = np.array([1.0])
    rows = ((50.0, "mav/1.1"), (3.0, "board"), (50.1, "mav/1.1"), (3.1, "board"))
    for t, src in (*rows, (0.2, "mav/1.1"), (0.25, "mav/1.1"), (0.3, "mav/1.1")):
        w.write(Measurement(t, Kind.RANGE, one, src))
    w.close()
    assert _times(tmp_path / "m.csv") == [50.0, 3.0, 50.1, 3.1]
    assert _times(tmp_path / "m.seg2.csv") == [0.2, 0.25, 0.3]
    assert w.paths == [tmp_path / "m.csv", tmp_path / "m.seg2.csv"]
    assert segment_path(tmp_path / "m.csv", 3).name == "m.seg3.csv"


def test_one_timestamp_going_back_is_no_restart_and_the_files_are_bounded(tmp_path):
    """The audit: every step back of the clock had started a new file without limit (24 measurement
    files in 110 s); a time of UINT32_MAX ms and values of inf reached the export. One reading behind
    is an outlier (counted); restarts confirmed by three readings each open at most MAX_SEGMENTS files;
    impossible times and values are counted, not written."""
    from groundstation.estimation.export import MAX_SEGMENTS

    w = MeasurementCsvWriter(tmp_path / "m.csv")
    one = np.array([1.0])
    w.write(Measurement(100.0, Kind.RANGE, one, "mav/1.1"))
    w.write(Measurement(0.5, Kind.RANGE, one, "mav/1.1"))  # one forged time
    w.write(Measurement(100.1, Kind.RANGE, one, "mav/1.1"))
    assert w.segments == 1 and w.back_in_time == 1
    t = 1000.0
    for _ in range(3 * MAX_SEGMENTS):  # a clock that steps back again and again, each step confirmed
        t -= 30.0
        for k in range(3):
            w.write(Measurement(t + 0.01 * k, Kind.RANGE, one, "mav/1.1"))
    for bad_t, v in ((4294967.295, 1.0), (-1.0, 1.0), (5.0, np.inf), (5.0, np.nan)):
        w.write(Measurement(bad_t, Kind.RANGE, np.array([v]), "mav/1.1"))
    w.close()
    assert w.segments == MAX_SEGMENTS and len(list(tmp_path.glob("m*.csv"))) == MAX_SEGMENTS
    assert w.refused == 4 and w.back_in_time > 1
    for p in w.paths:
        ts = _times(p)
        assert all(b >= a - 0.5 for a, b in zip(ts, ts[1:])), p  # time never goes back within a file
        assert all(0 <= x < 4294967 for x in ts)


def test_a_vehicle_clock_declares_a_restart_on_three_agreeing_readings_only():
    from drivers.mavlink.clock import VehicleClock

    c = VehicleClock()
    for k in range(10):
        assert not c.observe(100.0 + 0.01 * k, 1000.0 + 0.01 * k)
    assert not c.observe(0.3, 1000.2)  # one forged or corrupt time
    assert not c.observe(100.2, 1000.21)
    assert c.restarts == 0 and c.outliers == 1
    assert not c.observe(0.5, 1000.3) and not c.observe(0.51, 1000.31)
    assert c.observe(0.52, 1000.32) and c.restarts == 1  # the third agrees: it rebooted


def test_a_reading_with_unused_components_keeps_its_numbers(tmp_path):
    """SERVO_OUTPUT_RAW's eight channels on a quadrotor: four motors, four unused (NaN). The motors'
    outputs are written, the unused channels left out and not counted as refused; a reading that
    is all NaN, or has an infinite component, is refused whole."""
    w = MeasurementCsvWriter(tmp_path / "m.csv")
    outputs = np.array([0.55, 0.56, 0.54, 0.55, np.nan, np.nan, np.nan, np.nan])
    w.write(Measurement(1.0, Kind.ACTUATOR, outputs, "mav/1.1"))
    w.write(Measurement(1.1, Kind.ACTUATOR, np.full(8, np.nan), "mav/1.1"))
    w.write(Measurement(1.2, Kind.ACTUATOR, np.array([0.5, np.inf, np.nan, 0.5]), "mav/1.1"))
    w.close()
    rows = list(csv.DictReader(open(tmp_path / "m.csv")))
    assert [(r["t"], r["component"], float(r["value"])) for r in rows] == [
        (rows[0]["t"], str(j), v) for j, v in enumerate([0.55, 0.56, 0.54, 0.55])
    ]
    assert w.refused == 2
