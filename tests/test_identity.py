"""Which vehicle wrote a log, and which models describe it (estimation/identity.py), and the model
``diagnose --model auto`` picks from that and the log's readings (diagnosis/models.choose_model)."""

import numpy as np
import pytest

from drivers.logs.tables import LogTables, Table
from groundstation.core.measurement import Kind
from groundstation.diagnosis.models import choose_model
from groundstation.estimation.identity import UNKNOWN, Vehicle, identify
from groundstation.estimation.logs import load_log

from .conftest import real_file


def heartbeats(*rows):
    """A tlog's HEARTBEAT table: rows of (type, autopilot)."""
    t = np.arange(len(rows), dtype=float)
    types, pilots = zip(*rows)
    return LogTables({"HEARTBEAT": Table(t, {"type": np.array(types, float), "autopilot": np.array(pilots, float)})})


def test_a_heartbeat_names_the_vehicle_by_its_autopilots_rows_alone():
    """ArduSub's log holds a camera's and a companion computer's heartbeats too (MAV_AUTOPILOT_INVALID):
    only the autopilot's say what the vehicle is."""
    v = identify(heartbeats((30, 8), (18, 8), (12, 3), (30, 8), (12, 3)))
    assert (v.kind, v.models) == ("submarine", ())
    assert "water depth" in v.why_not("altitude")
    assert identify(heartbeats((2, 3), (6, 8))).kind == "multirotor"
    assert identify(heartbeats((13, 12))).name == "hexarotor"
    assert identify(heartbeats((1, 3))).models == ("altitude",)


@pytest.mark.parametrize(
    ("banner", "params", "kind"),
    [
        ("ArduCopter V4.5.7 (2a3dc4b7)", {}, "multirotor"),
        ("ArduCopter V4.5.7 (2a3dc4b7)", {"FRAME_CLASS": 6.0}, "helicopter"),
        ("ArduPlane V4.2.3 (55685c43)", {}, "fixed_wing"),
        ("ArduPlane V4.2.3 (55685c43)", {"Q_ENABLE": 1.0}, "vtol"),
        ("ArduRover V4.4.0", {"FRAME_CLASS": 2.0}, "boat"),
        ("APMrover2 v2.51", {}, "rover"),
        ("ArduSub V4.1.1 BETA5 (66c674c1)", {}, "submarine"),
    ],
)
def test_a_firmware_banner_and_its_parameters_name_the_vehicle(banner, params, kind):
    assert identify(LogTables(params=params, fmt="dataflash", firmware=banner)).kind == kind


def test_px4s_vehicle_status_names_the_vehicle_and_a_silent_log_is_unknown():
    vs = LogTables(
        {"vehicle_status": Table(np.zeros(3), {"system_type": np.full(3, 13.0)})}, fmt="ulog", autopilot="px4"
    )
    assert identify(vs).name == "hexarotor"
    assert identify(LogTables(params={"MAV_TYPE": 2.0}, fmt="ulog", autopilot="px4")).kind == "multirotor"
    assert identify(LogTables()) is UNKNOWN
    assert identify(LogTables(fmt="crazyflie")).kind == "multirotor"


@pytest.mark.parametrize(
    ("rel", "kind"),
    [
        ("mavlink_tlog/ardusub_small.tlog", "submarine"),
        ("mavlink_tlog/dronekit_flight_replay_flight.tlog", "multirotor"),
        ("ardupilot_dataflash/ardupilot_loganalyzer_underpowered.log", "multirotor"),  # its text header's banner
        ("ardupilot_dataflash/pyflightcoach_pilot_0004.BIN", "fixed_wing"),
    ],
)
def test_the_real_logs_vehicles_are_recognised(rel, kind):
    log = load_log(real_file(rel), imu_columns=True)
    assert identify(log.tables).kind == kind, (log.tables.firmware, identify(log.tables))


MULTI = Vehicle("multirotor", "quadrotor", "HEARTBEAT type 2")


def test_auto_takes_the_altitude_model_then_the_thrust_model_then_nothing_with_the_reason():
    imu_baro = {Kind.ACCEL, Kind.GYRO, Kind.BARO_PRESSURE, Kind.THROTTLE}
    assert choose_model(imu_baro, MULTI)[0] == "altitude"
    # an ArduCopter 3.0 text log: a throttle, a baro and a sonar, no accelerometer records
    assert choose_model({Kind.THROTTLE, Kind.BARO_ALTITUDE, Kind.RANGE}, MULTI)[0] == "quad_thrust"
    # a raw IMU and no height sensor: the attitude model
    assert choose_model({Kind.ACCEL, Kind.GYRO, Kind.ATTITUDE}, MULTI)[0] == "attitude"
    model, why = choose_model({Kind.GPS, Kind.ATTITUDE}, Vehicle("fixed_wing", "fixed wing", "firmware ArduPlane"))
    assert model is None and "no accelerometer" in why and "no barometer or range sensor" in why
    # a helicopter's collective is no thrust model's throttle; a submarine is described by no model
    heli = Vehicle("helicopter", "helicopter", "HEARTBEAT type 4")
    assert choose_model({Kind.THROTTLE, Kind.BARO_ALTITUDE}, heli)[0] is None
    model, why = choose_model(imu_baro, Vehicle("submarine", "submarine", "HEARTBEAT type 12"))
    assert model is None and "water depth" in why
