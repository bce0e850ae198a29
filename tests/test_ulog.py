"""PX4 ULog: the simulated vehicle's own ULog (sim_bridge.px4_log, drivers.logs.ulog_writer), read
back by pyulog and by the reader; the IMU read as columns against the IMU read record by record."""

import io

import numpy as np
import pytest
from pyulog import ULog

from drivers.logs.ulog import read_ulog
from drivers.logs.ulog_writer import UlogWriter
from groundstation.core.imu import ImuColumns
from groundstation.core.measurement import Kind
from groundstation.estimation.logs import load_log
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario
from tests.conftest import REPO, foreign2_file


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    log = tmp_path_factory.mktemp("ulog") / "f.ulg"
    run_fast(Scenario.from_args("quad", 7, 60.0, ["range_tilt"], ["baro_thrust:k=3"], flight="high"), log)
    return log


def test_a_simulated_flight_as_px4s_ulog_reads_back_topic_by_topic(flight):
    u = ULog(str(flight))
    counts = {d.name: len(d.data["timestamp"]) for d in u.data_list}
    assert counts["sensor_combined"] == 30_000 and counts["vehicle_air_data"] == 3001, counts
    assert {"distance_sensor", "vehicle_gps_position", "vehicle_attitude", "actuator_outputs"} <= set(counts)
    assert u.msg_info_dict["sys_name"] == "PX4" and u.initial_parameters["MAV_TYPE"] == 2
    sc = next(d for d in u.data_list if d.name == "sensor_combined").data
    assert np.median(sc["accelerometer_m_s2[2]"]) == pytest.approx(-9.81, abs=0.3)  # FRD: z down, at rest
    loaded = load_log(flight)
    assert "PX4 ULog (SITL (simulated)), 60.0 s" in loaded.description and "PX4 v1.14.0" == loaded.tables.firmware
    kinds = {m.kind for m in loaded.measurements}
    assert {Kind.ACCEL, Kind.BARO_PRESSURE, Kind.RANGE, Kind.GPS, Kind.ATTITUDE, Kind.ACTUATOR} <= kinds


def _same_imu(path) -> None:
    """``read_ulog(imu_columns=True)`` against the records, split as ``load_log`` splits them."""
    fast, slow = read_ulog(path, imu_columns=True), read_ulog(path)
    rest, imu = ImuColumns.split(slow.measurements)
    assert fast.imu is not None and fast.imu.series.keys() == imu.series.keys() and len(imu) > 0
    for key, s in imu.series.items():
        g = fast.imu.series[key]
        for got, want in ((g.t, s.t), (g.t_rx, s.t_rx), (g.value, s.value), (g.samples, s.samples)):
            assert got.dtype == want.dtype and np.array_equal(got, want)
    assert [(m.t, m.kind) for m in fast.measurements] == [(m.t, m.kind) for m in rest]
    assert fast.duration == slow.duration and fast.skipped == slow.skipped


def test_the_imu_read_as_columns_is_the_imu_read_record_by_record(flight):
    _same_imu(flight)
    loaded = load_log(flight, imu_columns=True)
    assert loaded.imu is not None and len(loaded.imu) == 60_000
    assert f", {len(loaded.measurements) + 60_000} measurements" in loaded.description


@pytest.mark.slow
def test_the_imu_read_as_columns_is_the_imu_read_record_by_record_on_foreign_logs():
    for rel in ("clean_s2.ulg", "range_tilt_s2.ulg"):
        _same_imu(foreign2_file(rel))


@pytest.mark.slow
def test_a_simulated_flight_as_px4s_ulog_diagnoses_as_its_tlog(flight):
    """The same hidden effect named with the same size as the tlog's (test_dataflash's twin: k = 3.0
    within 0.2), from the ULog alone."""
    from groundstation.diagnosis.engine import diagnose

    loaded = load_log(flight, imu_columns=True)
    d = diagnose(loaded.measurements, source=str(flight), declared=[{"name": "range_tilt"}], imu=loaded.imu)
    assert [e.name for e in d.effects][:1] == ["baro_thrust"]
    assert d.effects[0].params["k"] == pytest.approx(3.0, abs=0.2)


def test_the_writer_refuses_what_a_ulog_cannot_hold():
    w = UlogWriter(io.BytesIO())
    with pytest.raises(ValueError, match="begin with 'uint64_t timestamp'"):
        w.define("x", "float a;uint64_t timestamp")
    with pytest.raises(ValueError, match="not one of"):
        w.define("x", "uint64_t timestamp;float16 a")
    w.define("x", "uint64_t timestamp;float[2] a")
    with pytest.raises(ValueError, match="written before it was added"):
        w.write("x", 0, 1.0, 2.0)
    with pytest.raises(ValueError, match="added before it was defined"):
        w.add("y")
    w.add("x")
    w.write("x", 5, 1.0, 2.0)
    with pytest.raises(ValueError, match="come before its first sample"):
        w.parameter("P", 1.0)
    with pytest.raises(ValueError, match="level is 0 to 7"):
        w.log(9, 0, "no")


def test_a_sitl_logs_records_stamped_off_its_epoch_clock_are_counted_not_placed_decades_back():
    """PX4 SITL stamps from the UNIX epoch; a few topics published before its clock was set carry 0
    X. They are counted as skipped, and the
    log, its triage's findings included, starts where the flight does."""
    from groundstation.diagnosis.triage import triage

    log = read_ulog(REPO / "tests" / "fixtures" / "px4_sitl_events.ulg")
    assert log.skipped["timestamp_off_the_log_clock"] == 12
    t0, t1 = log.tables.span
    assert -1.0 < t0 < 0.0 and 30.0 < t1 < 32.0
    tr = triage(log.tables, log.measurements)
    assert all(-1.0 < f.t_start for f in tr.findings), tr.summary()


def test_dshot_outputs_read_as_the_same_share_of_the_motors_range_as_pulse_widths(tmp_path):
    """One flight as PX4 logs it with PWM ESCs (pulse widths) and with DShot ESCs (values 0..1999,
    ``PWM_MAIN_TIM0`` -3 and ``DSHOT_MIN`` saying so): the outputs' share of the motors' working range
    (the stated motor curve's) is the same to DShot's quantum, where DShot values read as microseconds
    were -0.89 at idle."""
    from groundstation.estimation.stated import motor_curve

    read = {}
    for esc in ("pwm", "dshot"):
        sc = Scenario.from_args("quad", 5, 30.0, [], [])
        sc.sensors.esc = esc
        log = load_log(run_fast(sc, tmp_path / f"{esc}.ulg").log)
        curve = motor_curve({**log.tables.params, "THR_MDL_FAC": 0.0})  # as a PX4 log states it (its default)
        assert curve is not None, esc
        outputs = [m.value for m in log.measurements if m.kind is Kind.ACTUATOR]
        read[esc] = (curve, np.array([curve.thrust(list(v), clip=False) for v in outputs]), np.array(outputs))
    (pwm_curve, pwm, _), (dshot_curve, dshot, raw) = read["pwm"], read["dshot"]
    assert (pwm_curve.low, pwm_curve.high) == (0.0, 1.0) and "DShot" not in pwm_curve.source
    assert dshot_curve.low == pytest.approx(109 / 1999) and dshot_curve.high == 1.0 and "DShot" in dshot_curve.source
    assert raw.min() >= dshot_curve.low - 1e-9 and raw.max() <= 1.0
    assert len(pwm) == len(dshot) and np.abs(dshot - pwm).max() < 1.0 / 1890
    assert pwm.max() > 0.3  # the flight, not only its idle


def test_px4_1_14s_collective_thrust_reads_as_the_throttle(flight):
    """PX4 1.14 logs no ``actuator_controls_0``: the mixer's input, the collective thrust, is
    ``vehicle_thrust_setpoint``'s ``xyz[2]`` (FRD, negative up). It reads as THROTTLE 0..1, the same
    command the flight's motor outputs carry, sample for sample."""
    log = load_log(flight)
    thr = [(m.t, float(m.value[0])) for m in log.measurements if m.kind is Kind.THROTTLE]
    out = [(m.t, float(m.value[0])) for m in log.measurements if m.kind is Kind.ACTUATOR]
    assert len(thr) == len(out) > 1000
    (t1, v1), (t2, v2) = np.array(thr).T, np.array(out).T
    assert np.array_equal(t1, t2) and np.abs(v1 - v2).max() < 1e-6  # float32 in the log
    assert 0.0 <= v1.min() and v1.max() <= 1.0 and 0.2 < np.median(v1[v1 > 0.1]) < 0.8


def test_actuator_controls_is_the_throttle_where_a_log_has_both(tmp_path):
    """A log from before control allocation keeps ``actuator_controls_0``: its ``control[3]`` is the
    throttle, and a thrust setpoint beside it (as a VTOL's or a replayed log's) is not read twice."""
    path = tmp_path / "both.ulg"
    with open(path, "wb") as f:
        w = UlogWriter(f)
        w.define("actuator_controls_0", "uint64_t timestamp;float[8] control")
        w.define("vehicle_thrust_setpoint", "uint64_t timestamp;uint64_t timestamp_sample;float[3] xyz")
        w.info("sys_name", "PX4")
        w.add("actuator_controls_0")
        w.add("vehicle_thrust_setpoint")
        for k in range(50):
            us = 1_000_000 + 20_000 * k
            w.write("actuator_controls_0", us, 0.0, 0.0, 0.0, 0.45, 0.0, 0.0, 0.0, 0.0)
            w.write("vehicle_thrust_setpoint", us + 5_000, us + 5_000, 0.0, 0.0, -0.7)
    thr = [m for m in read_ulog(path).measurements if m.kind is Kind.THROTTLE]
    assert len(thr) == 50 and {round(float(m.value[0]), 6) for m in thr} == {0.45}


def test_a_px4_sitl_logs_throttle_hovers_where_px4_estimates_its_hover_thrust():
    """A PX4 SITL log (1.15, control allocation: ``vehicle_thrust_setpoint``, no
    ``actuator_controls_0``): the throttle read from it, in flight, has its median at the hover
    thrust PX4's own estimator logged (``hover_thrust_estimate``, valid), on the same scale."""
    path = REPO / "tests" / "fixtures" / "px4_sitl_events.ulg"
    log = read_ulog(path)
    thr = np.array([float(m.value[0]) for m in log.measurements if m.kind is Kind.THROTTLE])
    assert len(thr) > 1000 and 0.0 <= thr.min() and thr.max() <= 1.0
    est = next(d for d in ULog(str(path)).data_list if d.name == "hover_thrust_estimate").data
    hover = est["hover_thrust"][est["valid"] == 1]
    assert len(hover) and np.median(thr[thr > 0.1]) == pytest.approx(float(np.median(hover)), abs=0.02)
