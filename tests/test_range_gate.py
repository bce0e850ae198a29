"""models.range_gate: a landed vehicle's range readings that are not its height, in the live filters."""

import math
import re
import subprocess
import sys

import numpy as np
import pytest

from drivers.logs.dataflash import read_dataflash
from groundstation.core.measurement import Kind, Measurement
from groundstation.estimation.registry import build_estimator

from .conftest import real_file

G = 9.80665


def _m(t, kind, value):
    return Measurement(t, kind, np.atleast_1d(np.asarray(value, dtype=float)), "sim/1.1", t, None, 0)


def _climb(t, t0=8.0, h0=0.2, rise=1.6, dur=4.0):
    """A smooth take-off: height and upward acceleration."""
    s = min(max((t - t0) / dur, 0.0), 1.0)
    w = math.pi / dur
    a = rise / 2 * w * w * math.cos(math.pi * s) if 0.0 < s < 1.0 else 0.0
    return h0 + rise * (1 - math.cos(math.pi * s)) / 2, a


class _Heights:
    """The estimated height after each measurement; ``z[t]``: as it stood at time t."""

    def __init__(self, est, ms):
        self.t, self.z, n = [], [], []
        for m in sorted(ms, key=lambda m: m.t):
            est.handle(m)
            self.t.append(m.t)
            self.z.append(float(est.filter.kf.x[0]))
            n.append(est.counters.skipped.get("range_on_ground", 0))
        self.skipped = _At(self.t, n)

    def __getitem__(self, t):
        return _At(self.t, self.z)[t]


class _At:
    def __init__(self, t, v):
        self.t, self.v = t, v

    def __getitem__(self, t):
        return self.v[int(np.searchsorted(self.t, t, side="right")) - 1]


@pytest.mark.parametrize("model", ["altitude", "quad_thrust"])
def test_echoes_with_the_motors_stopped_and_in_spin_up_are_skipped_and_a_take_off_opens_the_gate(model):
    """Motors stopped 0-5 s with the range reading a steady 1.98 m (underpowered.log's echo), spun up
    on the ground 5-8 s with readings jumping 0.21-7.6 m, then a take-off from 0.2 m to 1.8 m, where
    nothing is skipped once the range has followed the vehicle 0.15 m up."""
    est = build_estimator(model)
    echoes = [3.0, 0.21, 2.57, 7.61, 2.11, 6.65]
    ms = []
    for k in range(1200):  # IMU at 100 Hz
        t = k * 0.01
        ms.append(_m(t, Kind.ACCEL, [0.0, 0.0, -G - _climb(t)[1]]))
    for k in range(600):  # throttle at 50 Hz
        t = k * 0.02
        # the thrust model's prior (alpha 20, beta 0): below hover on the ground, then the climb's
        ms.append(_m(t, Kind.THROTTLE, 0.0 if t < 5.0 else 0.3 if t < 8.0 else (G + _climb(t)[1]) / 20.0))
    for k in range(120):  # range at 10 Hz
        t = 0.005 + k * 0.1
        d = 1.98 if t < 5.0 else echoes[k % len(echoes)] if t < 8.0 else _climb(t)[0]
        ms.append(_m(t, Kind.RANGE, d))
    z = _Heights(est, ms)
    skipped = est.counters.skipped.get("range_on_ground", 0)
    assert abs(z[4.99]) < 0.05, z[4.99]  # on the ground, not 1.98 m up
    assert abs(z[7.99]) < 0.35, z[7.99]  # the 0.21 m floor readings used, the echoes not
    # the motors-stopped readings, and the spin-up's beyond reach (5 of every 6), all skipped
    assert 50 + 20 <= skipped <= 50 + 26, est.counters.skipped
    # and in the air the range carries the height (the thrust model's z + d_tof: its ToF offset takes
    # the 0.2 m the range read on the ground, where z = 0)
    x = est.filter.kf.x
    assert x[0] + (x[est.model.index("d_tof")] if "d_tof" in est.model.states else 0.0) == pytest.approx(1.8, abs=0.05)
    # nothing skipped after the take-off's first 0.15 m
    assert z.skipped[8.0] == skipped


def test_a_link_joined_in_flight_takes_the_range_once_it_has_held_and_without_a_throttle_at_once():
    """Unsure at the start, with the motors running: a steady 3 m is the height after 2 s. A link
    without a throttle has no gate."""

    def flight(with_throttle):
        ms = [_m(k * 0.01, Kind.ACCEL, [0.0, 0.0, -G]) for k in range(500)]
        ms += [_m(0.005 + k * 0.1, Kind.RANGE, 3.0 + 0.01 * math.sin(k)) for k in range(50)]
        if with_throttle:
            ms += [_m(k * 0.02, Kind.THROTTLE, 0.5) for k in range(250)]
        est = build_estimator("altitude")
        return est, _Heights(est, ms)

    est, z = flight(True)
    assert abs(z[1.5]) < 0.1 and 15 <= est.counters.skipped["range_on_ground"] <= 21  # 2 s at 10 Hz
    assert z[4.99] == pytest.approx(3.0, abs=0.1)
    est, z = flight(False)
    assert z[1.5] == pytest.approx(3.0, abs=0.05) and "range_on_ground" not in est.counters.skipped


@pytest.mark.parametrize("model", ["altitude", "quad_thrust"])
def test_underpowered_log_stands_on_the_ground_and_flies_on_its_sonar(model):
    """ArduPilot's underpowered.log: its sonar reads 1.98 m for 28 s with the motors stopped (baro
    0.0 m) and 2-7.6 m in spin-up. Replayed without the range gate, the live filter stands 1.9 m
    (altitude) and 1.5-6 m (thrust) up; with it, it stands on the ground, and flies on the sonar."""
    log = read_dataflash(real_file("ardupilot_dataflash/ardupilot_loganalyzer_underpowered.log"))
    est = build_estimator(model, vehicle="apm2_sonar")
    t, z = [], []
    for m in log.measurements:
        est.handle(m)
        t.append(m.t)
        z.append(float(est.filter.kf.x[0]))
    t, z = np.array(t), np.array(z)
    ground = (t > 12.0) & (t < 22.0) | (t > 30.0) & (t < 50.0)
    assert np.abs(z[ground]).max() < 0.1
    assert est.counters.skipped["range_on_ground"] > 200, est.counters.skipped
    rng = np.array([(m.t, m.value[0]) for m in log.measurements if m.kind is Kind.RANGE and 66.0 < m.t < 80.0])
    in_air = (t > 66.0) & (t < 80.0)
    assert abs(np.median(z[in_air]) - np.median(rng[:, 1])) < 0.15


@pytest.mark.slow
def test_replay_says_what_the_reader_and_the_estimator_skipped():
    """The counted skips are on the replay's first and last lines, and on evaluate's first two: the
    sonar's clamps (the reader) and its echoes on the ground (the estimator)."""
    log = real_file("ardupilot_dataflash/ardupilot_loganalyzer_underpowered.log")
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "groundstation",
            "replay",
            str(log),
            "--speed",
            "max",
            "--no-web",
            "--quiet",
            "--vehicle",
            "apm2_sonar",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    first, last = r.stdout.splitlines()[0], r.stdout.splitlines()[-1]
    assert "17503 measurements" in first and first.endswith("the reader skipped 564 range_out_of_bounds"), first
    n = int(re.search(r"the estimator skipped (\d+) range_on_ground", last).group(1))
    assert 200 < n < 600, last
    from groundstation.estimation.evaluate import evaluate

    table = evaluate(log, vehicle="apm2_sonar").table().splitlines()
    assert table[0].endswith("the reader skipped 564 range_out_of_bounds"), table[0]
    assert table[1].endswith(f"the estimator skipped {n} range_on_ground"), table[1]


def test_motors_stopped_in_the_air_do_not_lock_the_range_out_for_the_flight():
    """A throttle at 0 for 0.5 s in flight (a pilot's stick fully down, on a log whose throttle is
    the demand) closes the gate 3 m up, with no take-off to come: a track that holds 10 s opens it."""
    ms = [_m(k * 0.01, Kind.ACCEL, [0.0, 0.0, -G]) for k in range(1600)]
    ms += [_m(0.005 + k * 0.1, Kind.RANGE, 3.0 + 0.01 * math.sin(k)) for k in range(160)]
    ms += [_m(k * 0.02, Kind.THROTTLE, 0.0 if 4.0 <= k * 0.02 < 4.5 else 0.5) for k in range(800)]
    est = build_estimator("altitude")
    z = _Heights(est, ms)
    assert z[3.99] > 2.5  # unsure for 2 s, then the range's
    n = z.skipped[3.99]
    assert z.skipped[14.4] - n > 90  # closed at 4 s: skipped while the track holds
    assert z.skipped[15.99] == z.skipped[14.6]  # open again
    assert z[14.4] < 1.0 and z[15.99] == pytest.approx(3.0, abs=0.2)  # set down at 4 s, back up on the range
