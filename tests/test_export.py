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
    for t, src in ((50.0, "mav/1.1"), (3.0, "board"), (50.1, "mav/1.1"), (3.1, "board"), (0.2, "mav/1.1")):
        w.write(Measurement(t, Kind.RANGE, one, src))
    w.close()
    assert _times(tmp_path / "m.csv") == [50.0, 3.0, 50.1, 3.1]
    assert _times(tmp_path / "m.seg2.csv") == [0.2]
    assert w.paths == [tmp_path / "m.csv", tmp_path / "m.seg2.csv"]
    assert segment_path(tmp_path / "m.csv", 3).name == "m.seg3.csv"
