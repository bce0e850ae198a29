"""The simulated vehicle's flight as PX4's logger keeps it: a ULog (``.ulg``) of its uORB topics.

=======================  ===========================================  ===========================
topic                    fields                                       from the sample
=======================  ===========================================  ===========================
sensor_combined          gyro_rad[3] [rad/s], accelerometer_m_s2[3]   imu (FRD)
vehicle_air_data         baro_alt_meter (pressure altitude),          baro
                         baro_temp_celcius, baro_pressure_pa
distance_sensor          current_distance [m], min/max_distance,      range (downward: orientation
                         signal_quality, orientation                  25)
vehicle_gps_position     lat, lon [1e-7 deg], alt [mm], vel_*_m_s,    gps (3-D fix)
                         fix_type
vehicle_attitude         q[4] (w, x, y, z: FRD to NED)                attitude (the autopilot's
                                                                      estimate)
actuator_outputs         noutputs, output[16] [us], or DShot values   actuators (1000 + 1000·u; DShot:
                                                                      DSHOT_MIN's idle + (1999 - it)·u,
                                                                      PWM_MAIN_TIM0 -3, DShot600)
vehicle_thrust_setpoint  xyz[3] (the collective thrust, -1..0 on z)   actuators (the throttle, as
                                                                      the DataFlash log's CTUN.ThO)
battery_status           voltage_v [V], current_a [A]                 battery
vehicle_status           arming_state, system_type (MAV_TYPE)         the vehicle, armed (2)
=======================  ===========================================  ===========================

Time is the vehicle's clock from boot (``timestamp`` [us]), as PX4's; the info names the system
and a release, the parameters the vehicle's type (the range's limits are its topic's). The topics'
fields are the ones readers take (PX4's own have more), in PX4's order.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import BinaryIO

from drivers.logs.frame import DSHOT_MAX_THROTTLE, px4_dshot_idle
from drivers.logs.ulog_writer import UlogWriter
from groundstation.core.atmosphere import altitude_at
from groundstation.core.frames import quaternion_from_euler

from .flight_log import RANGE_LIMITS_CM, collective
from .sensors import ESC_PROTOCOLS
from .simulator import Sample

#: PX4's v1.14.0 release as ``ver_sw_release`` (0xAABBCCTT: major, minor, patch, type 0xFF release)
RELEASE = (1 << 24) | (14 << 16) | (0 << 8) | 0xFF
#: MAVLink's MAV_TYPE of each simulated vehicle (PX4's ``vehicle_status.system_type``)
MAV_TYPE = {"quad": 2, "coax": 3, "heli3dof": 4}
ARMED = 2  # vehicle_status.arming_state: ARMING_STATE_ARMED
DOWNWARD = 25  # distance_sensor.orientation: ROTATION_DOWNWARD_FACING
OUTPUTS = 16
DSHOT600 = -3  # PWM_MAIN_TIMn: the timer's outputs speak DShot600
DSHOT_MIN = 0.055  # PX4's default: the armed idle as a share of DShot's throttle range

TOPICS = {
    "sensor_combined": "uint64_t timestamp;float[3] gyro_rad;int32_t accelerometer_timestamp_relative;"
    "float[3] accelerometer_m_s2",
    "vehicle_air_data": "uint64_t timestamp;uint64_t timestamp_sample;float baro_alt_meter;float baro_temp_celcius;"
    "float baro_pressure_pa",
    "distance_sensor": "uint64_t timestamp;float min_distance;float max_distance;float current_distance;"
    "int8_t signal_quality;uint8_t orientation",
    "vehicle_gps_position": "uint64_t timestamp;int32_t lat;int32_t lon;int32_t alt;float vel_n_m_s;"
    "float vel_e_m_s;float vel_d_m_s;uint8_t fix_type",
    "vehicle_attitude": "uint64_t timestamp;float[4] q",
    "actuator_outputs": f"uint64_t timestamp;uint32_t noutputs;float[{OUTPUTS}] output",
    "vehicle_thrust_setpoint": "uint64_t timestamp;uint64_t timestamp_sample;float[3] xyz",
    "battery_status": "uint64_t timestamp;float voltage_v;float current_a",
    "vehicle_status": "uint64_t timestamp;uint8_t arming_state;uint8_t system_type",
}


class Px4Log:
    """A ULog of the simulator's samples: :meth:`step` with each step's samples, :meth:`close` at
    the end (``out`` stays the caller's to close)."""

    def __init__(self, out: BinaryIO, vehicle: str, *, esc: str = "pwm") -> None:
        if esc not in ESC_PROTOCOLS:
            raise ValueError(f"ESC protocol {esc!r}: one of {', '.join(ESC_PROTOCOLS)}")
        self.w = UlogWriter(out)
        self.mav_type = MAV_TYPE.get(vehicle, 0)
        self.vehicle = vehicle
        self.dshot = esc == "dshot"
        for name, fields in TOPICS.items():
            self.w.define(name, fields)
        self.w.info("sys_name", "PX4")
        self.w.info("ver_hw", "SITL (simulated)")
        self.w.info("ver_sw_release", RELEASE)
        self.w.parameter("MAV_TYPE", self.mav_type)
        if self.dshot:
            self.w.parameter("PWM_MAIN_TIM0", DSHOT600)
            self.w.parameter("DSHOT_MIN", DSHOT_MIN)
        for name in TOPICS:
            self.w.add(name)
        self.w.log(6, 0, "[simulated] PX4 v1.14.0")
        self._next_status = 0.0

    def step(self, t: float, samples: Iterable[Sample]) -> None:
        if t >= self._next_status:  # at 1 Hz, as PX4 logs it when nothing changes
            self._next_status += 1.0
            self.w.write("vehicle_status", _us(t), ARMED, self.mav_type)
        for s in samples:
            self._write(s)

    def _write(self, s: Sample) -> None:
        w, v, us = self.w, s.values, _us(s.t)
        if s.sensor == "imu":
            w.write("sensor_combined", us, v[3], v[4], v[5], 0, v[0], v[1], v[2])
        elif s.sensor == "baro":
            p, temp = v
            w.write("vehicle_air_data", us, us, altitude_at(float(p)), temp - 273.15, p)
        elif s.sensor == "range":
            lo, hi = RANGE_LIMITS_CM
            w.write("distance_sensor", us, lo / 100, hi / 100, max(v[0], 0.0), -1, DOWNWARD)
        elif s.sensor == "gps":
            lat, lon, alt, vn, ve, vd = v[:6]
            w.write("vehicle_gps_position", us, round(lat * 1e7), round(lon * 1e7), round(alt * 1e3), vn, ve, vd, 3)
        elif s.sensor == "attitude":
            w.write("vehicle_attitude", us, *quaternion_from_euler(*v[:3]))
        elif s.sensor == "actuators":
            if self.dshot:  # PX4's mixer: its minimum value at a motor command of 0, 1999 at 1 (always armed)
                top = DSHOT_MAX_THROTTLE
                idle = px4_dshot_idle({"DSHOT_MIN": DSHOT_MIN}) * top
                out = [float(round(idle + (top - idle) * min(1.0, max(0.0, u)))) for u in v[:OUTPUTS]]
            else:
                out = [1000.0 + 1000.0 * min(1.0, max(0.0, u)) for u in v[:OUTPUTS]]
            w.write("actuator_outputs", us, len(out), *out, *[0.0] * (OUTPUTS - len(out)))
            # the controller's collective thrust, normalised and along body z (up is negative)
            w.write("vehicle_thrust_setpoint", us, us, 0.0, 0.0, -min(1.0, max(0.0, collective(self.vehicle, v))))
        elif s.sensor == "battery":
            w.write("battery_status", us, v[0], v[1])


def _us(t: float) -> int:
    return max(0, int(round(t * 1e6)))
