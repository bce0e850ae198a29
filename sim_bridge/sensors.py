"""Sensor models: rates, noise, quantisation, limits, and where the effects act.

Each sensor produces a sample ``(t, name, values)`` at its own rate. Values are
SI; quantisation to the wire format (cm for DISTANCE_SENSOR, 1e-7 deg for GPS,
cdegC for temperatures) happens again in the MAVLink encoder, as on a vehicle.

Defaults (all in :class:`SensorConfig`, each overridable per scenario):

=========  ========  ==============================================================
sensor     rate      model
=========  ========  ==============================================================
imu        500 Hz    specific force + N(0, 0.08 m/s^2), LSB 4.8 mm/s^2 (16 g/16 bit);
                     body rate + N(0, 0.005 rad/s), LSB 1.07 mrad/s (2000 dps/16 bit)
baro       50 Hz     ISA pressure of (h + effects' altitude error) + N(0, 4 Pa),
                     LSB 1.2 Pa (MS5611); temperature warms 8 K while the motors run
range      25 Hz     slant d = h / (cos phi cos theta) + N(0, 0.01 m); 0.05..4 m
gps        5 Hz      NED -> WGS84 about an origin; Gauss-Markov error (1 m, 20 s)
                     horizontal, (2 m, 20 s) vertical, plus white 0.3 m
attitude   50 Hz     the autopilot's attitude estimate: truth + N(0, 0.005 rad)
actuators  50 Hz     the outputs (throttle, rotor inputs); the 3-DOF rig's motor voltages
                     at 250 Hz, its control loop's rate (the lab logs its model at 500 Hz)
battery    5 Hz      V + N(0, 0.02 V), I + N(0, 0.1 A) (quadcopter)
encoders   500 Hz    3-DOF helicopter angles, 4096 counts per revolution
=========  ========  ==============================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from groundstation.core.atmosphere import pressure_at
from groundstation.core.frames import euler_from_matrix


@dataclass
class SensorConfig:
    rates: dict[str, float] = field(
        default_factory=lambda: {
            "imu": 500.0,
            "baro": 50.0,
            "range": 25.0,
            "gps": 5.0,
            "attitude": 50.0,
            "actuators": 50.0,
            "battery": 5.0,
            "encoders": 500.0,
        }
    )
    accel_sigma: float = 0.08
    accel_lsb: float = 16 * 9.80665 / 32768
    gyro_sigma: float = 0.005
    gyro_lsb: float = math.radians(2000.0) / 32768
    baro_sigma: float = 4.0  # [Pa]
    baro_lsb: float = 1.2  # [Pa]
    ground_alt: float = 120.0  # ground altitude AMSL [m]
    ambient_temp: float = 293.15  # [K]
    heating: float = 8.0  # sensor warming while the motors run [K]
    heating_tc: float = 60.0  # [s]
    range_sigma: float = 0.01
    range_min: float = 0.05
    range_max: float = 4.0
    gps_origin: tuple[float, float] = (47.397742, 8.545594)
    gps_h_sigma: float = 1.0
    gps_v_sigma: float = 2.0
    gps_tc: float = 20.0
    gps_white: float = 0.3
    attitude_sigma: float = 0.005
    battery_v_sigma: float = 0.02
    battery_i_sigma: float = 0.1
    encoder_counts: int = 4096
    #: the ESCs' protocol a PX4 log's actuator_outputs show: "pwm" pulse widths [us], "dshot" DShot
    #: values (0 .. 1999; ArduPilot and MAVLink give DShot outputs as pulse widths all the same)
    esc: str = "pwm"


#: the ESC protocols a simulated PX4 log can state (:attr:`SensorConfig.esc`)
ESC_PROTOCOLS = ("pwm", "dshot")


#: which sensors each vehicle carries
VEHICLE_SENSORS = {
    "quad": ("imu", "baro", "range", "gps", "attitude", "actuators", "battery"),
    "coax": ("imu", "baro", "range", "gps", "attitude", "actuators"),
    "heli3dof": ("imu", "encoders", "actuators"),
}
#: a vehicle's own rates where they are not the table's: the rig's voltages are logged by the loop
#: that sets them (a 50 Hz record of a 250 Hz command reads the command 10 ms late on average, as
#: long as the motor lag a rig's identification is after)
VEHICLE_RATES = {"heli3dof": {"actuators": 250.0}}

M_PER_DEG = 111_320.0


def _q(x, lsb):
    return np.round(x / lsb) * lsb


class SensorSuite:
    def __init__(self, vehicle_name: str, config: SensorConfig, rng: np.random.Generator) -> None:
        self.cfg = config
        self.rng = rng
        self.names = VEHICLE_SENSORS[vehicle_name]
        own = VEHICLE_RATES.get(vehicle_name, {})
        self.rates = {n: own.get(n, config.rates[n]) for n in self.names}
        self.next_due = {n: 0.0 for n in self.names}
        self.gps_err = np.zeros(3)
        self._noise = np.empty(0)
        self._k = 0
        #: what the accelerometer's readings have added to the (effect-altered) specific force
        #: since :meth:`take_accel_error`: noise and rounding, x and y summed, and the sample count
        self._accel_error = [0.0, 0.0, 0]

    def normal(self) -> float:
        """One standard normal draw, from blocks drawn in advance (per-call
        numpy draws cost more than the whole IMU model)."""
        if self._k >= len(self._noise):
            self._noise = self.rng.standard_normal(8192).tolist()
            self._k = 0
        self._k += 1
        return self._noise[self._k - 1]

    def set_rate(self, name: str, hz: float) -> None:
        """Change a sensor's rate (the ground station's stream-rate request)."""
        if name in self.rates and hz > 0:
            self.rates[name] = hz

    def due(self, t: float, dt: float) -> list[str]:
        out = []
        for n in self.names:
            if t + 0.5 * dt >= self.next_due[n]:
                out.append(n)
                # keep the schedule on the grid: no drift from float rounding
                self.next_due[n] = max(self.next_due[n] + 1.0 / self.rates[n], t)
        return out

    # -- readings --------------------------------------------------------------------------
    def read(self, name: str, sim) -> tuple:
        return getattr(self, "_" + name)(sim)

    def _imu(self, sim):
        c = self.cfg
        fx, fy, fz, wx, wy, wz = sim.imu_truth()
        if sim.imu_effects:
            f, w = np.array([fx, fy, fz]), np.array([wx, wy, wz])
            for e in sim.imu_effects:
                f = e.accel(f, sim)
                w = e.gyro(w, sim)
            fx, fy, fz = f.tolist()
            wx, wy, wz = w.tolist()
        n, sa, sg, la, lg = self.normal, c.accel_sigma, c.gyro_sigma, c.accel_lsb, c.gyro_lsb
        ax, ay = round((fx + sa * n()) / la) * la, round((fy + sa * n()) / la) * la
        err = self._accel_error
        err[0], err[1], err[2] = err[0] + ax - fx, err[1] + ay - fy, err[2] + 1
        return (
            ax,
            ay,
            round((fz + sa * n()) / la) * la,
            round((wx + sg * n()) / lg) * lg,
            round((wy + sg * n()) / lg) * lg,
            round((wz + sg * n()) / lg) * lg,
            sim.temperature,
        )

    def take_accel_error(self) -> tuple[float, float, float]:
        """The accelerometer's own error (x, y: noise and rounding) averaged over the samples since
        the last call, and their count; the truth's record of what a perfect model's innovations
        would be. Blocks of the truth's 10 ms rows are the diagnosis' 10 ms input blocks."""
        sx, sy, k = self._accel_error
        self._accel_error = [0.0, 0.0, 0]
        return (sx / k, sy / k, k) if k else (math.nan, math.nan, 0)

    def _baro(self, sim):
        c = self.cfg
        h = sim.vehicle.kin.height + sum(e.baro_alt(sim) for e in sim.effects)
        p = float(pressure_at(c.ground_alt + h)) + c.baro_sigma * self.normal()
        return (round(p / c.baro_lsb) * c.baro_lsb, sim.temperature + 0.05 * self.normal())

    def _range(self, sim):
        k = sim.vehicle.kin
        cos_tilt = max(0.2, k.R[2, 2])  # cos(phi) cos(theta) = A_IB[2, 2]
        d = max(0.0, k.height) / cos_tilt  # slant range: always physical
        for e in sim.effects:
            d = e.range(d, sim)
        return (d + self.cfg.range_sigma * self.normal(),)

    def _gps(self, sim):
        c, k, rng = self.cfg, sim.vehicle.kin, self.rng
        dt = 1.0 / self.rates["gps"]
        a = math.exp(-dt / c.gps_tc)
        sig = np.array([c.gps_h_sigma, c.gps_h_sigma, c.gps_v_sigma])
        self.gps_err = a * self.gps_err + math.sqrt(1 - a * a) * sig * rng.standard_normal(3)
        pos = k.pos + self.gps_err + rng.normal(0.0, c.gps_white, 3)
        lat0, lon0 = c.gps_origin
        lat = lat0 + pos[0] / M_PER_DEG
        lon = lon0 + pos[1] / (M_PER_DEG * math.cos(math.radians(lat0)))
        alt = c.ground_alt - pos[2]
        vel = k.vel + rng.normal(0.0, 0.1, 3)
        return (lat, lon, alt, *vel, math.hypot(c.gps_h_sigma, c.gps_white), math.hypot(c.gps_v_sigma, c.gps_white))

    def _attitude(self, sim):  # noqa: D401 - the autopilot's estimate
        k = sim.vehicle.kin
        roll, pitch, yaw = euler_from_matrix(k.R)
        n = self.rng.normal(0.0, self.cfg.attitude_sigma, 3)
        return (roll + n[0], pitch + n[1], yaw + n[2], *k.omega)

    def _actuators(self, sim):
        return tuple(sim.actuator_outputs())

    def _battery(self, sim):
        v = sim.vehicle
        return (
            v.voltage + self.rng.normal(0.0, self.cfg.battery_v_sigma),
            v.current + self.rng.normal(0.0, self.cfg.battery_i_sigma),
            v.soc,
        )

    def _encoders(self, sim):
        x = sim.vehicle.x
        lsb = 2 * math.pi / self.cfg.encoder_counts
        angles = (float(x[0]), float(x[2]), float(x[4]))
        for e in sim.effects:
            angles = e.encoders(angles, sim)
        return tuple(float(_q(v, lsb)) for v in angles)

    def temperature(self, sim, dt: float) -> float:
        """Sensor temperature: ISA at the ground, warming while the motors run."""
        return sim.temperature + (
            (self.cfg.ambient_temp + (self.cfg.heating if sim.vehicle.motors_running else 0.0)) - sim.temperature
        ) * (1 - math.exp(-dt / self.cfg.heating_tc))
