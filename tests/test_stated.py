"""What a log states of its sensors besides their readings: the downward rangefinder's ground clearance,
from the vehicle standing on its gear or from the autopilot's parameters (estimation/stated.py)."""

import numpy as np
import pytest

from drivers.logs.tables import LogTables, Table
from groundstation.core.measurement import Kind, Measurement
from groundstation.estimation.logs import load_log
from groundstation.estimation.stated import range_clearance

from .conftest import foreign2_file


def flight(seconds=60.0, take_off=10.0, land=50.0, rate=10.0):
    """A throttle record stream: on the ground (0.1, idle) before ``take_off`` and after ``land``."""
    t = np.arange(0.0, seconds, 1.0 / rate)
    tau = np.where((t >= take_off) & (t < land), 0.45, 0.1)
    return [Measurement(float(a), Kind.THROTTLE, np.array([b]), "df") for a, b in zip(t, tau)]


def rfnd(dist, *, seconds=60.0, params=None, stat=None):
    t = np.linspace(0.0, seconds, len(dist), endpoint=False)
    cols = {"Dist": np.asarray(dist, float), "Orient": np.full(len(dist), 25.0), "Instance": np.zeros(len(dist))}
    if stat is not None:
        cols["Stat"] = np.asarray(stat, float)
    return LogTables({"RFND": Table(t, cols)}, dict(params or {}), fmt="dataflash", autopilot="ardupilot")


def readings(n, ground, air, *, seconds=60.0, take_off=10.0, land=50.0, seed=0):
    """n readings over the log: ``ground`` (a function of the rng) on the ground, ``air`` in flight."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, seconds, n, endpoint=False)
    on = (t < take_off) | (t >= land)
    return np.where(on, ground(rng, n), air(rng, n))


def test_the_ground_readings_below_the_sensors_minimum_give_the_clearance():
    """A lidar 5 cm above the floor reads 4-7 cm on the ground, below its 10 cm minimum: the readers skip
    those readings as measurements, and they are the clearance."""
    d = readings(1200, lambda r, n: np.round(0.05 + 0.01 * r.standard_normal(n), 2), lambda r, n: 2.0 + 0 * r.random(n))
    c = range_clearance(rfnd(d, params={"RNGFND1_MIN_CM": 10.0}), flight())
    assert c is not None and c.metres == pytest.approx(0.05, abs=0.005)
    assert c.readings > 100 and "on the ground" in c.source and c.parameter is None


def test_the_parameter_is_used_where_the_ground_says_nothing_and_disagreement_is_said():
    no_readings = LogTables({}, {"RNGFND1_GNDCLEAR": 12.0}, fmt="dataflash")
    c = range_clearance(no_readings, flight())
    assert c is not None and c.metres == pytest.approx(0.12) and c.parameter == "RNGFND1_GNDCLEAR"
    assert c.readings == 0 and not c.disagrees
    d = readings(1200, lambda r, n: np.round(0.05 + 0.01 * r.standard_normal(n), 2), lambda r, n: 2.0 + 0 * r.random(n))
    c = range_clearance(rfnd(d, params={"RNGFND1_GNDCLEAR": 12.0}), flight())
    assert c is not None and c.metres == pytest.approx(0.05, abs=0.005) and c.disagrees
    px4 = range_clearance(LogTables({}, {"EKF2_MIN_RNG": 0.08}, fmt="ulog"), flight())
    assert px4 is not None and px4.metres == pytest.approx(0.08) and px4.parameter == "EKF2_MIN_RNG"


def test_a_clamped_sonar_and_a_noisy_ground_give_no_clearance_from_the_data():
    """A sonar reads its 20 cm floor for anything closer: one value, the stated minimum, no distance.
    Readings that scatter over decimetres on the ground are no distance either."""
    floor = readings(1200, lambda r, n: np.full(n, 0.20), lambda r, n: 2.0 + 0 * r.random(n))
    assert range_clearance(rfnd(floor, params={"RNGFND1_MIN_CM": 20.0}), flight()) is None
    assert range_clearance(rfnd(floor), flight()) is None  # one value, even with no minimum stated
    scatter = readings(1200, lambda r, n: r.uniform(0.0, 0.4, n), lambda r, n: 2.0 + 0 * r.random(n))
    assert range_clearance(rfnd(scatter), flight()) is None
    # without a throttle there is no telling the ground from the flight
    assert (
        range_clearance(rfnd(readings(1200, lambda r, n: np.full(n, 0.05), lambda r, n: 2.0 + 0 * r.random(n))), [])
        is None
    )


def test_a_sensor_whose_noise_is_clipped_at_zero_reads_no_clearance():
    """Our simulator's range reads max(0, noise) on the ground: the median is 0, not the mean of what is
    left above zero."""
    d = readings(
        1200, lambda r, n: np.maximum(0.0, np.round(0.01 * r.standard_normal(n), 2)), lambda r, n: 2.0 + 0 * r.random(n)
    )
    c = range_clearance(rfnd(d), flight())
    assert c is not None and c.metres == 0.0


@pytest.mark.slow
@pytest.mark.parametrize("name", ["clean_range_s1.bin", "clean_range_s2.ulg"])
def test_the_second_foreign_sources_lidar_clearance_is_read_from_its_log(name):
    """The generator's lidar sits 5 cm above the floor: the .bin states it (RNGFND1_GNDCLEAR = 5 cm) and both
    formats log the readings on the ground."""
    log = load_log(foreign2_file(name), imu_columns=True)
    c = range_clearance(log.tables, log.measurements)
    assert c is not None and c.metres == pytest.approx(0.05, abs=0.005) and c.readings > 100
    assert not c.disagrees


def test_a_tlogs_ground_is_read_on_the_recording_clock():
    """A tlog's records are on the recording's clock, its readings on the vehicle's (booted 300 s before
    the recording began): the ground stretches are matched on the recording's clock."""
    boot = 300.0
    origin = 1.7e9
    ms = [
        Measurement(m.t + boot, m.kind, m.value, "mav/1", origin + m.t)  # t on the vehicle's clock, t_rx UNIX
        for m in flight()
    ]
    d = readings(1200, lambda r, n: np.round(0.05 + 0.01 * r.standard_normal(n), 2), lambda r, n: 2.0 + 0 * r.random(n))
    t = np.linspace(0.0, 60.0, len(d), endpoint=False)
    cols = {"current_distance": d * 100.0, "orientation": np.full(len(d), 25.0), "id": np.zeros(len(d))}
    tables = LogTables({"DISTANCE_SENSOR": Table(t, cols)}, {}, fmt="tlog", clock="recording", origin=origin)
    c = range_clearance(tables, ms)
    assert c is not None and c.metres == pytest.approx(0.05, abs=0.005)


def test_a_declared_offset_is_the_operators_word_over_the_logs_clearance():
    from groundstation.estimation.registry import effects_used
    from groundstation.estimation.stated import RangeClearance, clearance_effect

    stated = [clearance_effect(RangeClearance(0.05, "the rangefinder on the ground (900 readings)"))]
    assert [e["params"]["o"] for e in effects_used((), None, stated)] == [0.05]
    mine = [{"name": "range_offset", "params": {"o": 0.02}}]
    assert [e["params"]["o"] for e in effects_used(mine, None, stated)] == [0.02]


@pytest.mark.slow
def test_replay_and_evaluate_take_the_clearance_the_log_states():
    """The lidar's 5 cm on the ground is taken off its readings in a replay and an evaluation, as the
    diagnosis takes it: without it every estimate of the flight was 5 cm high (4.2 cm RMS)."""
    from groundstation.estimation.evaluate import evaluate
    from groundstation.estimation.logs import load_blocked

    path = foreign2_file("clean_range_s1.bin")
    blocked = load_blocked(path)
    assert blocked is not None and blocked.stated and blocked.stated[0]["params"]["o"] == pytest.approx(0.05, abs=0.005)
    ev = evaluate(path)
    assert "5.0 cm" in ev.clearance and ev.estimate_rmse < 0.02, ev.table()


def test_a_range_that_reads_zero_on_its_gear_gives_a_replay_no_offset(tmp_path):
    """Our simulator's range reads max(0, noise) on the ground: its clearance is 0 m, and a replay
    takes (and says) no offset for it, as the diagnosis takes none."""
    from groundstation.estimation.logs import load_blocked
    from groundstation.estimation.stated import GROUND_KINDS, STATED_TABLES
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    log = tmp_path / "q.tlog"
    run_fast(Scenario(vehicle="quad", seed=3, duration=20.0), log)
    loaded = load_log(log, tables=STATED_TABLES, imu_columns=True)
    c = range_clearance(loaded.tables, loaded.measurements.only(GROUND_KINDS))
    assert c is not None and c.metres == 0.0 and c.readings >= 10
    blocked = load_blocked(log)
    assert blocked is not None and blocked.clearance is None and blocked.stated == []
