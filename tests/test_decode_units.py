"""Unit and frame conversions, checked against the MAVLink message definitions."""

import math
import types

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.mavlink.decode import DECODED_TYPES, SPECIAL_UNITS, VECTORS, MavlinkDecoder
from drivers.mavlink.receiver import MavlinkReceiver
from drivers.mavlink.units import G0, UNIT_TO_SI
from groundstation.core.measurement import Kind

ISSUE_TYPES = [
    "HEARTBEAT",
    "SYS_STATUS",
    "BATTERY_STATUS",
    "HIGHRES_IMU",
    "SCALED_IMU",
    "SCALED_IMU2",
    "SCALED_IMU3",
    "RAW_IMU",
    "SCALED_PRESSURE",
    "SCALED_PRESSURE2",
    "SCALED_PRESSURE3",
    "DISTANCE_SENSOR",
    "ATTITUDE",
    "ATTITUDE_QUATERNION",
    "GPS_RAW_INT",
    "GLOBAL_POSITION_INT",
    "LOCAL_POSITION_NED",
    "VFR_HUD",
    "SERVO_OUTPUT_RAW",
    "RC_CHANNELS",
    "MANUAL_CONTROL",
    "ATT_POS_MOCAP",
    "EKF_STATUS_REPORT",
]


def _cls(name):
    return mavlink.mavlink_map[getattr(mavlink, f"MAVLINK_MSG_ID_{name}")]


def test_every_required_message_is_decoded():
    assert set(ISSUE_TYPES) <= set(DECODED_TYPES)


@pytest.mark.parametrize("name", sorted(set(VECTORS) | set(SPECIAL_UNITS)))
def test_declared_units_match_the_message_definition(name):
    defined = _cls(name).fieldunits_by_name
    declared = {f: u for _, fields, u in VECTORS.get(name, []) for f in fields}
    declared.update(SPECIAL_UNITS.get(name, {}))
    for field, unit in declared.items():
        assert field in _cls(name).fieldnames, (name, field)
        assert defined.get(field) == unit, (
            f"{name}.{field}: definition says {defined.get(field)!r}, decoder assumes {unit!r}"
        )
        assert unit in UNIT_TO_SI


def decode(msg, mavlink1=False, t_rx=1000.0):
    """Encode with pymavlink, decode through the receiver: the whole wire path."""
    enc = mavlink.MAVLink(None, 1, 1)
    buf = msg.pack(enc, force_mavlink1=mavlink1)
    r = MavlinkReceiver("t")
    # a timestamped message first, so untimed ones get a clock straight away
    r.feed(mavlink.MAVLink_attitude_message(5000, 0, 0, 0, 0, 0, 0).pack(enc), t_rx)
    out = r.feed(bytes(buf), t_rx)
    return {(m.kind, m.instance): m for m in out}, r


def test_scaled_imu_milli_g_and_milliradians():
    out, _ = decode(mavlink.MAVLink_scaled_imu2_message(12345, 1000, -500, -1000, 100, -200, 300, 250, 0, -250, 2150))
    acc = out[(Kind.ACCEL, 1)]
    assert acc.t == pytest.approx(12.345)
    np.testing.assert_allclose(acc.value, [G0, -G0 / 2, -G0])  # FRD, z down: level vehicle reads -g
    np.testing.assert_allclose(out[(Kind.GYRO, 1)].value, [0.1, -0.2, 0.3])
    np.testing.assert_allclose(out[(Kind.MAG, 1)].value, [25e-6, 0, -25e-6])  # 250 mG = 25 uT


def test_raw_imu_uses_time_usec_and_id():
    out, _ = decode(mavlink.MAVLink_raw_imu_message(2_500_000, 0, 0, -1000, 0, 0, 0, 0, 0, 0, id=2))
    m = out[(Kind.ACCEL, 2)]
    assert m.t == pytest.approx(2.5)
    assert m.value[2] == pytest.approx(-G0)


def test_highres_imu_si_and_fields_updated():
    flags = 0x7 | 0x38 | 0x200 | 0x1000  # acc, gyro, abs pressure, temperature; no mag
    out, _ = decode(
        mavlink.MAVLink_highres_imu_message(
            3_000_000, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0.2, 0.0, 0.4, 1013.25, 0.5, 11.0, 21.5, flags, 0
        )
    )
    assert out[(Kind.ACCEL, 0)].value == pytest.approx([0.1, 0.2, -9.8], rel=1e-6)
    assert out[(Kind.BARO_PRESSURE, 0)].value[0] == pytest.approx(101325.0, rel=1e-6)
    assert out[(Kind.TEMPERATURE, 0)].value[0] == pytest.approx(294.65, rel=1e-6)
    assert (Kind.MAG, 0) not in out and (Kind.DIFF_PRESSURE, 0) not in out


@pytest.mark.parametrize("flags, kinds", [(0x3F, {Kind.ACCEL, Kind.GYRO}), (0x7, {Kind.ACCEL}), (0x38, {Kind.GYRO})])
def test_highres_imu_of_the_imu_alone(flags, kinds):
    """The messages in between the slower sensors' updates: only what they flag."""
    out, _ = decode(
        mavlink.MAVLink_highres_imu_message(
            3_000_000, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0.2, 0.0, 0.4, 1013.25, 0.5, 11.0, 21.5, flags, 1
        )
    )
    assert {k for k, _ in out} == kinds and {i for _, i in out} == {1}
    if Kind.GYRO in kinds:
        assert out[(Kind.GYRO, 1)].value == pytest.approx([0.01, 0.02, 0.03], rel=1e-6)
        assert out[(Kind.GYRO, 1)].t == pytest.approx(3.0)


def test_scaled_pressure_hpa_to_pa_and_cdegc_to_kelvin():
    out, _ = decode(mavlink.MAVLink_scaled_pressure3_message(4000, 1000.5, 0.0, 2500, 0))
    assert out[(Kind.BARO_PRESSURE, 2)].value[0] == pytest.approx(100050.0)
    assert out[(Kind.TEMPERATURE, 2)].value[0] == pytest.approx(298.15)
    assert out[(Kind.BARO_PRESSURE, 2)].t == pytest.approx(4.0)


def test_distance_sensor_cm_to_m_with_variance_and_bounds():
    out, _ = decode(mavlink.MAVLink_distance_sensor_message(7000, 20, 400, 153, 0, 3, 25, 4))
    m = out[(Kind.RANGE, 3)]
    assert m.value[0] == pytest.approx(1.53)
    assert m.variance[0] == pytest.approx(4e-4)  # 4 cm^2
    out, r = decode(mavlink.MAVLink_distance_sensor_message(7000, 20, 400, 401, 0, 3, 25, 255))
    assert (Kind.RANGE, 3) not in out
    assert r.decoder.skipped["range_out_of_bounds"] == 1
    # a reading at a limit is the sensor's clamp (on the ground it reads its minimum), not a height
    for at_limit in (20, 400):
        out, r = decode(mavlink.MAVLink_distance_sensor_message(7000, 20, 400, at_limit, 0, 3, 25, 255))
        assert (Kind.RANGE, 3) not in out and r.decoder.skipped["range_out_of_bounds"] == 1


def test_attitude_and_quaternion():
    out, _ = decode(mavlink.MAVLink_attitude_message(9000, 0.1, -0.2, 3.0, 0.01, 0.02, 0.03))
    assert out[(Kind.ATTITUDE, 0)].value == pytest.approx([0.1, -0.2, 3.0], rel=1e-6)
    assert out[(Kind.ANGULAR_RATE, 0)].value == pytest.approx([0.01, 0.02, 0.03], rel=1e-6)
    out, _ = decode(mavlink.MAVLink_attitude_quaternion_message(9000, 1, 0, 0, 0, 0, 0, 0))
    assert out[(Kind.ATTITUDE_QUATERNION, 0)].value == pytest.approx([1, 0, 0, 0])


def test_gps_raw_int_degrees_metres_and_accuracy():
    out, _ = decode(
        mavlink.MAVLink_gps_raw_int_message(
            1_700_000_000_000_000, 3, -353632610, 1491652300, 584070, 120, 200, 150, 9000, 10, h_acc=1500, v_acc=3000
        )
    )
    m = out[(Kind.GPS, 0)]
    assert m.value == pytest.approx([-35.363261, 149.16523, 584.07])
    assert m.variance[2] == pytest.approx(9.0)  # (3 m)^2
    assert m.variance[0] == pytest.approx((1.5 / 111320) ** 2)  # 1.5 m as degrees of latitude
    assert m.t == pytest.approx(5.0, abs=0.01)  # UNIX-epoch time_usec: aligned clock, not the epoch
    out, r = decode(mavlink.MAVLink_gps_raw_int_message(0, 1, 0, 0, 0, 0, 0, 0, 0, 0))
    assert (Kind.GPS, 0) not in out and r.decoder.skipped["gps_no_3d_fix"] == 1


def test_global_and_local_position():
    out, _ = decode(
        mavlink.MAVLink_global_position_int_message(1000, 473977418, 85455938, 500000, 12345, 100, -200, 50, 0)
    )
    assert out[(Kind.GLOBAL_POSITION, 0)].value == pytest.approx([47.3977418, 8.5455938, 500.0, 12.345])
    assert out[(Kind.VELOCITY_NED, 0)].value == pytest.approx([1.0, -2.0, 0.5])
    out, _ = decode(mavlink.MAVLink_local_position_ned_message(1000, 1, 2, -3, 0.1, 0.2, -0.3))
    assert out[(Kind.POSITION_NED, 0)].value == pytest.approx([1, 2, -3])


def test_vfr_hud_throttle_fraction_altitude_up():
    out, _ = decode(mavlink.MAVLink_vfr_hud_message(5.0, 6.0, 90, 55, 12.5, -0.5))
    assert out[(Kind.THROTTLE, 0)].value[0] == pytest.approx(0.55)
    assert out[(Kind.ALTITUDE, 0)].value[0] == pytest.approx(12.5)
    assert out[(Kind.CLIMB_RATE, 0)].value[0] == pytest.approx(-0.5)
    assert out[(Kind.AIRSPEED, 0)].value[2] == pytest.approx(math.pi / 2)
    assert out[(Kind.THROTTLE, 0)].t == pytest.approx(5.0)  # on the aligned vehicle clock


def test_battery_from_sys_status_and_battery_status():
    out, _ = decode(mavlink.MAVLink_sys_status_message(0, 0, 0, 0, 11870, 1520, 63, 0, 0, 0, 0, 0, 0))
    assert out[(Kind.BATTERY_VOLTAGE, 0)].value[0] == pytest.approx(11.87)
    assert out[(Kind.BATTERY_CURRENT, 0)].value[0] == pytest.approx(15.2)
    assert out[(Kind.BATTERY_REMAINING, 0)].value[0] == pytest.approx(0.63)
    out, r = decode(mavlink.MAVLink_sys_status_message(0, 0, 0, 0, 65535, -1, -1, 0, 0, 0, 0, 0, 0))
    assert not out and r.decoder.skipped["battery_voltage_unknown"] == 1
    cells = [4100, 4050, 4000] + [65535] * 7
    out, _ = decode(mavlink.MAVLink_battery_status_message(2, 0, 0, 2500, cells, 800, 100, 50, 80))
    assert out[(Kind.BATTERY_VOLTAGE, 2)].value[0] == pytest.approx(12.15)


def test_servo_rc_manual_control_normalised():
    out, _ = decode(mavlink.MAVLink_servo_output_raw_message(1000, 0, 1000, 1500, 2000, 1100, 0, 0, 0, 0))
    v = out[(Kind.ACTUATOR, 0)].value
    assert v[:4] == pytest.approx([0.0, 0.5, 1.0, 0.1]) and np.isnan(v[4:]).all() and len(v) == 8
    out, _ = decode(mavlink.MAVLink_rc_channels_message(1000, 4, 1500, 1000, 2000, 1500, *[65535] * 14, 255))
    assert out[(Kind.RC_INPUT, 0)].value == pytest.approx([0.5, 0.0, 1.0, 0.5])
    out, _ = decode(mavlink.MAVLink_manual_control_message(1, 200, -300, 500, 0, 0))
    assert out[(Kind.MANUAL_CONTROL, 1)].value == pytest.approx([0.2, -0.3, 0.5, 0.0])


def test_an_object_without_an_extension_field_converts_as_the_wire_would():
    """``convert`` takes any object with the message's fields as attributes: one an older dialect
    made has no MAVLink 2 extensions (servo9..16, GPS accuracies), which count as 0, as on the wire."""
    servo = types.SimpleNamespace(time_usec=1000, port=2, **{f"servo{i}_raw": 1500 for i in range(1, 9)})
    gps = types.SimpleNamespace(time_usec=1000, fix_type=3, lat=473977418, lon=85455938, alt=500000)
    for name in ("eph", "epv", "vel", "cog", "satellites_visible"):
        setattr(gps, name, 0)
    dec = MavlinkDecoder("t")
    (fix,) = dec.convert(mavlink.MAVLink_gps_raw_int_message, gps, 1, 1, 10.0)  # (timed: the clock is known)
    assert fix.variance is None and fix.value == pytest.approx([47.3977418, 8.5455938, 500.0])
    (actuator,) = dec.convert(mavlink.MAVLink_servo_output_raw_message, servo, 1, 1, 10.0)
    assert actuator.instance == 2 and actuator.value == pytest.approx([0.5] * 8)


def test_heartbeat_mocap_ekf():
    out, _ = decode(mavlink.MAVLink_heartbeat_message(2, 3, mavlink.MAV_MODE_FLAG_SAFETY_ARMED, 5, 4, 3))
    assert out[(Kind.VEHICLE_STATUS, 0)].value == pytest.approx([1, 5, 4, 2, 3])
    out, _ = decode(mavlink.MAVLink_att_pos_mocap_message(6_000_000, [1, 0, 0, 0], 1.0, 2.0, -1.5))
    m = out[(Kind.TRUTH_POSE, 0)]
    assert m.kind.is_truth and m.value[:3] == pytest.approx([1.0, 2.0, -1.5]) and m.t == pytest.approx(6.0)
    out, _ = decode(mavlink.MAVLink_ekf_status_report_message(0x1FF, 0.1, 0.2, 0.3, 0.4, 0.5))
    assert out[(Kind.EKF_STATUS, 0)].value == pytest.approx([0x1FF, 0.1, 0.2, 0.3, 0.4, 0.5], rel=1e-6)


@pytest.mark.parametrize("mavlink1", [True, False])
def test_mavlink1_and_2_decode_alike(mavlink1):
    out, r = decode(mavlink.MAVLink_scaled_imu_message(100, 0, 0, -1000, 0, 0, 0, 0, 0, 0), mavlink1=mavlink1)
    assert out[(Kind.ACCEL, 0)].value[2] == pytest.approx(-G0)
    assert (r.counters.mavlink1 > 0) == mavlink1


def test_untimed_messages_wait_for_the_vehicle_clock():
    enc = mavlink.MAVLink(None, 7, 1)
    r = MavlinkReceiver("t")
    assert r.feed(mavlink.MAVLink_vfr_hud_message(0, 0, 0, 40, 3.0, 0).pack(enc), 100.0) == []
    out = r.feed(mavlink.MAVLink_attitude_message(20_000, 0, 0, 0, 0, 0, 0).pack(enc), 100.5)
    thr = [m for m in out if m.kind is Kind.THROTTLE][0]
    assert thr.t == pytest.approx(19.5)  # stamped on the vehicle clock once it was known
    # A system that never sends a time field goes on receive time after the wait.
    enc2 = mavlink.MAVLink(None, 8, 1)
    assert r.feed(mavlink.MAVLink_vfr_hud_message(0, 0, 0, 40, 3.0, 0).pack(enc2), 200.0) == []
    out = r.feed(mavlink.MAVLink_vfr_hud_message(0, 0, 0, 41, 3.0, 0).pack(enc2), 203.0)
    assert [m.t for m in out if m.kind is Kind.THROTTLE] == [200.0, 203.0]


def test_untimed_messages_keep_to_the_timed_ones_when_the_delay_grows():
    """A vehicle clock that falls behind the receive clock (a simulator on a loaded machine: 1.6 s in
    60 s; a radio link that buffers): the offset, the least delay seen, stamped VFR_HUD up to the
    accumulated lag ahead of the ATTITUDE sent with it (here 1.0 s, where the clock resets), and the
    estimation loop dropped what followed as late."""
    enc = mavlink.MAVLink(None, 7, 1)
    r = MavlinkReceiver("t")
    lead = []
    for k in range(1, 600):  # (a zero time field counts as none)
        t = 0.1 * k
        rx = 1000.0 + t * 1.03  # 3 % behind: 1.8 s after 60 s
        timed = r.feed(mavlink.MAVLink_attitude_message(int(t * 1000), 0, 0, 0, 0, 0, 0).pack(enc), rx)
        hud = r.feed(mavlink.MAVLink_vfr_hud_message(0, 0, 0, 40, 3.0, 0).pack(enc), rx + 0.001)
        lead.append(hud[0].t - timed[0].t)
    assert max(lead) < 0.01 and min(lead) >= 0.0, (min(lead), max(lead))


def test_unknown_messages_are_counted_recorded_and_hooked():
    frames, hooked = [], []
    r = MavlinkReceiver("t", on_frame=lambda f, t: frames.append(f), on_message=lambda m, t: hooked.append(m))
    # a MAVLink 2 frame with a message id no dialect defines (0xABCDE)
    hdr = bytes([0xFD, 2, 0, 0, 0, 1, 1, 0xDE, 0xBC, 0x0A, 7, 8])
    raw = hdr + b"\x00\x00"
    assert r.feed(raw, 1.0) == []
    assert r.counters.unknown == 1 and frames == [raw] and hooked[0].get_type().startswith("UNKNOWN")


def test_ground_station_heartbeats_are_not_vehicle_status():
    out, _ = decode(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, 8, 0, 0, 4, 3))
    assert (Kind.VEHICLE_STATUS, 0) not in out


@pytest.mark.parametrize(
    "mav_type,throttle",
    [
        (mavlink.MAV_TYPE_QUADROTOR, 0.575),  # four motors
        (mavlink.MAV_TYPE_COAXIAL, 0.6),  # two rotors; outputs 3-4 are swash-plate servos
        (mavlink.MAV_TYPE_HELICOPTER, 0.6),  # one main rotor
    ],
)
def test_the_throttle_averages_only_the_outputs_that_drive_rotors(mav_type, throttle):
    from groundstation.estimation.context import Context
    from groundstation.estimation.routing import read_throttle, read_vehicle_status

    ctx = Context()
    out, _ = decode(mavlink.MAVLink_heartbeat_message(mav_type, 3, mavlink.MAV_MODE_FLAG_SAFETY_ARMED, 0, 4, 3))
    read_vehicle_status(out[(Kind.VEHICLE_STATUS, 0)], ctx)
    out, _ = decode(mavlink.MAVLink_servo_output_raw_message(1000, 0, 1600, 1600, 1500, 1600, 0, 0, 0, 0))
    read_throttle(out[(Kind.ACTUATOR, 0)], ctx)
    assert ctx.throttle == pytest.approx(throttle)


def test_values_are_floats_from_a_message_built_in_code():
    """A message object made in Python (integer fields, never on the wire) still gives float64."""
    d = MavlinkDecoder("t")
    msgs = [
        mavlink.MAVLink_highres_imu_message(1_000_000, 0, 0, -10, 0, 0, 1, 0, 0, 0, 1013, 0, 0, 25, 0x3F, 0),
        mavlink.MAVLink_highres_imu_message(1_001_000, 0, 0, -10, 0, 0, 1, 0, 0, 0, 1013, 0, 0, 25, 0x1FFF, 0),
        mavlink.MAVLink_attitude_message(1002, 0, 0, 1, 0, 0, 0),
    ]
    out = [x for m in msgs for x in d.convert(type(m), m, 1, 1, 5.0)]
    assert len(out) == 10 and all(x.value.dtype == np.float64 for x in out)
