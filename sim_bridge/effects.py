"""The simulator's catalogue of physical effects, switched on per scenario.

Each effect documents its equation, units and a realistic range, and acts at
one or more stages of the simulation:

* ``command(cmd, dt)``: on the actuator command before the vehicle sees it;
* ``thrust_factor(sim)``: a factor on the rotors' thrust;
* ``accel(f, sim)``, ``gyro(w, sim)``: on the IMU's readings (body FRD);
* ``baro_alt(sim)``: an altitude error [m] the barometer reads in addition
  (turned into pressure through the standard atmosphere);
* ``range(d, sim)``: on the range reading [m];
* ``constants(params)``: on a vehicle's constants, once, before it flies (a 3-DOF rig that is not
  Table 1's: its motor constant, counterweight, friction; a coax's rotors);
* ``encoders(angles, sim)``: on the 3-DOF helicopter's encoder angles [rad];
* ``delay``: a per-sensor latency [s].

The names are the catalogue's canonical names, shared with the diagnosis
(which has its own code: the two share names, not code paths). A scenario says
which effects exist and which are *declared* to the ground station; an
undeclared effect reaches it by no channel at all (see :mod:`sim_bridge.scenario`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from groundstation.core.frames import a_ib

from .vehicles.coax import CoaxParams
from .vehicles.heli3dof import Heli3dofParams


@dataclass(frozen=True)
class Param:
    default: float
    unit: str
    low: float  # realistic range
    high: float
    help: str = ""


class Effect:
    name: ClassVar[str] = ""
    equation: ClassVar[str] = ""
    params: ClassVar[dict[str, Param]] = {}
    #: sensors whose readings this effect delays (sensor_delay only)
    delay: dict[str, float]

    def __init__(self, **kw) -> None:
        unknown = set(kw) - set(self.params) - self.extra_keys()
        if unknown:
            raise ValueError(
                f"effect {self.name}: unknown parameter(s) {', '.join(sorted(unknown))}; "
                f"known: {', '.join(self.params) or 'none'}"
            )
        self.values = {k: float(kw.get(k, p.default)) for k, p in self.params.items()}
        self.delay = {}
        self.setup(kw)

    def extra_keys(self) -> set[str]:
        return set()

    def setup(self, kw: dict) -> None:
        """Derived quantities (called once)."""

    def __getattr__(self, item):
        values = self.__dict__.get("values")
        if values is not None and item in values:
            return values[item]
        raise AttributeError(item)

    def describe(self) -> dict:
        return {"name": self.name, "params": dict(self.values), **({"delay": self.delay} if self.delay else {})}

    #: True for an effect in the motors themselves: it acts after the outputs (PWM) that the log
    #: records, so the log shows the command and not what the motors made of it
    in_the_motors = False

    # stages (identity by default)
    def command(self, cmd, dt, sim):
        return cmd

    def thrust_factor(self, sim) -> float:
        return 1.0

    def outputs(self, values: list[float], sim) -> list[float]:
        """The motor outputs (PWM, normalised) as the log records them."""
        return values

    def accel(self, f, sim):
        return f

    def gyro(self, w, sim):
        return w

    def baro_alt(self, sim) -> float:
        return 0.0

    def range(self, d, sim):
        return d

    def constants(self, params):
        """The vehicle's constants (its ``*Params``) as this one has them; each effect changes only
        the vehicle it names."""
        return params

    def encoders(self, angles, sim):
        return angles

    def step(self, dt, sim) -> None:
        """Advance internal state (random walks, filters) by one physics step."""


REGISTRY: dict[str, type[Effect]] = {}


def register(cls):
    REGISTRY[cls.name] = cls
    return cls


@register
class AccelBias(Effect):
    name = "accel_bias"
    equation = "f_meas = f + b  (body FRD)"
    params = {
        "x": Param(0.0, "m/s^2", -0.5, 0.5),
        "y": Param(0.0, "m/s^2", -0.5, 0.5),
        "z": Param(0.2, "m/s^2", -0.5, 0.5, "a real IMU's z bias is typically 0.05-0.3"),
    }

    def setup(self, kw):
        self.b = np.array([self.x, self.y, self.z])

    def accel(self, f, sim):
        return f + self.b


@register
class AccelScale(Effect):
    name = "accel_scale"
    equation = "f_meas = (1 + s) f  (all axes)"
    params = {"s": Param(0.02, "1", -0.05, 0.05, "scale-factor error, 0.5-3 % is typical")}

    def accel(self, f, sim):
        return f * (1.0 + self.s)


@register
class GyroBias(Effect):
    name = "gyro_bias"
    equation = "w_meas = w + b  (body FRD)"
    params = {
        "x": Param(0.01, "rad/s", -0.05, 0.05),
        "y": Param(0.0, "rad/s", -0.05, 0.05),
        "z": Param(0.0, "rad/s", -0.05, 0.05),
    }

    def setup(self, kw):
        self.b = np.array([self.x, self.y, self.z])

    def gyro(self, w, sim):
        return w + self.b


@register
class BaroBiasDrift(Effect):
    name = "baro_bias_drift"
    equation = "h_err(t) = rate * t + sigma * W(t)  (W: standard Wiener process)"
    params = {
        "rate": Param(0.02, "m/s", -0.15, 0.15, "Crazyflie logs drift 0.09-0.13 m/s in flight"),
        "sigma": Param(0.05, "m/sqrt(s)", 0.0, 0.3),
    }

    def setup(self, kw):
        self.err = 0.0

    def step(self, dt, sim):
        self.err += self.rate * dt + self.sigma * math.sqrt(dt) * sim.rng.standard_normal()

    def baro_alt(self, sim):
        return self.err


@register
class BaroThermal(Effect):
    name = "baro_thermal"
    equation = "h_err = k * (T - T_start),  T: sensor temperature (rises while the motors run)"
    params = {"k": Param(0.3, "m/K", -1.0, 1.0)}

    def baro_alt(self, sim):
        return self.k * (sim.temperature - sim.temperature_start)


@register
class BaroThrust(Effect):
    name = "baro_thrust"
    equation = "h_err = k * LPF(throttle),  LPF: first order, time constant tc (rotor wash)"
    params = {
        "k": Param(2.0, "m per unit throttle", -8.0, 8.0, "Crazyflie: +4 m jump at spin-up"),
        "tc": Param(0.5, "s", 0.05, 3.0),
    }

    def setup(self, kw):
        self.lp = 0.0

    def step(self, dt, sim):
        self.lp += (sim.vehicle.throttle - self.lp) * (1 - math.exp(-dt / self.tc))

    def baro_alt(self, sim):
        return self.k * self.lp


@register
class BaroGroundEffect(Effect):
    name = "baro_ground_effect"
    equation = "h_err = A * exp(-h / h0) while the rotors run (pressure field near the ground)"
    params = {
        "A": Param(-1.5, "m", -3.0, 0.0, "ArduPilot underpowered.log dips -2.7 m at spin-up"),
        "h0": Param(0.5, "m", 0.2, 1.5),
    }

    def baro_alt(self, sim):
        if not sim.vehicle.motors_running:
            return 0.0
        return self.A * math.exp(-max(0.0, sim.vehicle.kin.height) / self.h0)


@register
class BaroAirflow(Effect):
    """Outside the diagnosis' catalogue on purpose: what its sparse regression must name. The air a
    climb or descent moves past the static port lowers the pressure it reads by C q, q = rho v^2 / 2,
    so the baro reads high by C v^2 / (2 g) (ArduPilot's BARO1_WCF_UP/DN model it the same way for
    the body's vertical axis; the README's "outside the catalogue")."""

    name = "baro_airflow"
    equation = "h_err = k * vz^2  (static-port error from the vertical airflow, k = C / (2 g))"
    params = {
        "k": Param(
            0.1,
            "m/(m/s)^2",
            0.0,
            0.3,
            "pressure coefficient C = 2 g k: 0-6; 1-2 m in fast descents on poorly ported airframes",
        )
    }

    def baro_alt(self, sim):
        return self.k * float(sim.vehicle.kin.vel[2]) ** 2


@register
class RangeTilt(Effect):
    """Always physical: the range sensor reads the slant distance. The effect's
    presence in a scenario only says whether the ground station is told."""

    name = "range_tilt"
    equation = "d = h / (cos(phi) cos(theta))  (always simulated; declaring it tells the estimator)"
    params = {}


@register
class RangeOffset(Effect):
    name = "range_offset"
    equation = "d_meas = d + o  (mounting lever arm, ground clearance)"
    params = {"o": Param(-0.035, "m", -0.1, 0.1, "Crazyflie flow deck: -3.3 to -4.0 cm")}

    def range(self, d, sim):
        return d + self.o


SENSORS = ("imu", "baro", "range", "gps", "attitude", "battery")


@register
class SensorDelay(Effect):
    name = "sensor_delay"
    equation = "y_meas(t) = y(t - seconds)  (for the named sensor)"
    params = {"seconds": Param(0.03, "s", 0.005, 0.2)}

    def extra_keys(self):
        return {"sensor"}

    def setup(self, kw):
        sensor = str(kw.get("sensor", "range"))
        if sensor not in SENSORS:
            raise ValueError(f"sensor_delay: sensor must be one of {', '.join(SENSORS)}")
        self.sensor = sensor
        self.delay = {sensor: self.seconds}

    def describe(self):
        return {"name": self.name, "params": {"sensor": self.sensor, "seconds": self.seconds}}


@register
class ThrustVoltage(Effect):
    name = "thrust_voltage"
    equation = "thrust = thrust_nominal * (V / V_ref)^n  (no ESC voltage compensation)"
    params = {
        "n": Param(2.0, "1", 1.0, 2.5, "thrust ~ rpm^2 ~ V^2"),
        "v_ref": Param(0.0, "V", 0.0, 30.0, "0: a full pack's voltage under hover load"),
    }

    def thrust_factor(self, sim):
        v = getattr(sim.vehicle, "voltage", None)
        if v is None:
            return 1.0
        if self.values["v_ref"] <= 0.0:  # the voltage the vehicle was tuned at
            p = sim.vehicle.p
            self.values["v_ref"] = p.n_cells * p.v_full - p.r_int * (p.i_idle + p.i_max * p.hover_throttle**2)
        return (v / self.v_ref) ** self.n


@register
class ThrustGroundEffect(Effect):
    name = "thrust_ground_effect"
    equation = "thrust = thrust_nominal / (1 - (R / (4 h))^2)  (Cheeseman-Bennett, h >= R)"
    params = {"R": Param(0.12, "m", 0.03, 0.3, "rotor radius")}

    def thrust_factor(self, sim):
        h = max(sim.vehicle.kin.height, self.R)
        return 1.0 / (1.0 - (self.R / (4.0 * h)) ** 2)


@register
class ActuatorLag(Effect):
    name = "actuator_lag"
    equation = "u_applied' = (u_cmd - u_applied) / tc  (first order, on every actuator input)"
    params = {"tc": Param(0.08, "s", 0.01, 0.3)}
    in_the_motors = True  # ESC and rotor spin-up: the logged outputs are the commands

    def setup(self, kw):
        self.state = None

    def command(self, cmd, dt, sim):
        # the motors lag what their drivers give them: the command within its range, as the outputs
        # a log records show it. A lag ahead of the clip would carry a voltage below 0 V (or above
        # the supply) that no motor gets and no log shows
        cmd = sim.vehicle.clipped(cmd)
        fields = list(vars(cmd))
        now = np.array([getattr(cmd, f) for f in fields], dtype=float)
        if self.state is None:
            self.state = now
        else:
            self.state = self.state + (now - self.state) * (1 - math.exp(-dt / self.tc))
        out = type(cmd)(*self.state)
        return out


@register
class ImuMisalignment(Effect):
    name = "imu_misalignment"
    equation = "f_meas = C f,  w_meas = C w,  C = A_IB(roll, pitch, yaw)^T of the mounting error"
    params = {
        "roll": Param(2.0, "deg", -5.0, 5.0),
        "pitch": Param(-1.5, "deg", -5.0, 5.0),
        "yaw": Param(0.0, "deg", -5.0, 5.0),
    }

    def setup(self, kw):
        self.C = a_ib(math.radians(self.roll), math.radians(self.pitch), math.radians(self.yaw)).T

    def accel(self, f, sim):
        return self.C @ f

    def gyro(self, w, sim):
        return self.C @ w


@register
class Vibration(Effect):
    name = "vibration"
    equation = "f_meas = f + A * throttle * sin(2 pi freq t + phase_i)  (each axis, rotor harmonic)"
    params = {"A": Param(2.0, "m/s^2", 0.2, 8.0), "freq": Param(123.0, "Hz", 50.0, 300.0)}

    def setup(self, kw):
        self.phase = np.array([0.0, 2.1, 4.2])

    def accel(self, f, sim):
        return f + self.A * sim.vehicle.throttle * np.sin(2 * math.pi * self.freq * sim.t + self.phase)


@register
class MotorOffset(Effect):
    """A constant disturbance for the control tests: the 3-DOF rig's motor board
    adds a voltage to each motor (a miscalibrated driver; the same as a moved
    counterweight or a heavier rotor). Other vehicles are not affected."""

    name = "motor_offset"
    equation = "V_applied = V_cmd + offset  (3-DOF helicopter, each motor)"
    params = {"front": Param(0.0, "V", -2.0, 2.0), "back": Param(0.5, "V", -2.0, 2.0)}

    def command(self, cmd, dt, sim):
        if sim.scenario.vehicle != "heli3dof":
            return cmd
        return type(cmd)(cmd.V_f + self.front, cmd.V_b + self.back)


@register
class MotorConstant(Effect):
    """The 3-DOF rig's motors give more or less thrust per volt than the lab's K_f (the lab found
    K_f by hand, from the equilibrium voltage and eq. 12). With the masses unchanged, the voltage
    that holds the rig level moves with it: V_s0 = (2 l_h m_p - l_c m_c) g / (l_h K_f)."""

    name = "motor_constant"
    equation = "K_f = K_f_table * (1 + s)  (3-DOF helicopter)"
    params = {"s": Param(0.08, "1", -0.3, 0.3)}

    def constants(self, params):
        if not isinstance(params, Heli3dofParams):
            return params
        return replace(params, K_f=params.K_f * (1.0 + self.s))


@register
class Counterweight(Effect):
    """The 3-DOF rig's counterweight heavier (or lighter) than Table 1's: the equilibrium voltage
    moves by -l_c g dm / (l_h K_f) (about -0.55 V per 10 g). Its moment of inertia is kept
    (l_c^2 dm is under 0.1 % of J_e for the range here)."""

    name = "counterweight"
    equation = "m_c = m_c_table + dm  (3-DOF helicopter; V_s0 = (2 l_h m_p - l_c m_c) g / (l_h K_f))"
    params = {"dm": Param(0.02, "kg", -0.1, 0.1)}

    def constants(self, params):
        if not isinstance(params, Heli3dofParams):
            return params
        return replace(params, m_c=params.m_c + self.dm)


@register
class MotorAsymmetry(Effect):
    """The 3-DOF rig's two motors unlike: the back one gives (1 + a) K_f per volt, the front one
    (1 - a) K_f. Level flight then needs a voltage difference, and the sum's lift is shared unevenly."""

    name = "motor_asymmetry"
    equation = "F_f = K_f (1 - a) V_f,  F_b = K_f (1 + a) V_b  (3-DOF helicopter)"
    params = {"a": Param(0.04, "1", -0.15, 0.15)}

    def constants(self, params):
        if not isinstance(params, Heli3dofParams):
            return params
        return replace(params, a=self.a)


@register
class ViscousFriction(Effect):
    """Bearing and air friction on the 3-DOF rig's axes, a torque against each rate."""

    name = "viscous_friction"
    equation = "J x_dd = ... - d x_dot  (3-DOF helicopter: pitch, elevation, travel)"
    params = {
        "p": Param(0.005, "N m s/rad", 0.0, 0.05),
        "e": Param(0.05, "N m s/rad", 0.0, 0.3),
        "lambda": Param(0.08, "N m s/rad", 0.0, 0.3),
    }

    def constants(self, params):
        if not isinstance(params, Heli3dofParams):
            return params
        return replace(params, d_p=self.values["p"], d_e=self.values["e"], d_l=self.values["lambda"])


@register
class EncoderOffset(Effect):
    """The 3-DOF rig's encoders zeroed away from level (the lab's own pitch offset, sec. 4.6): each
    reads its angle plus an offset. Travel's zero is arbitrary and shows in nothing."""

    name = "encoder_offset"
    equation = "angle_read = angle + offset  (3-DOF helicopter: p, e, lambda)"
    params = {
        "p": Param(1.0, "deg", -5.0, 5.0),
        "e": Param(-0.8, "deg", -5.0, 5.0),
        "lambda": Param(0.0, "deg", -180.0, 180.0),
    }

    def setup(self, kw):
        self.offset = tuple(math.radians(self.values[k]) for k in ("p", "e", "lambda"))

    def encoders(self, angles, sim):
        return tuple(a + o for a, o in zip(angles, self.offset))


@register
class RotorTimeConstant(Effect):
    """The coaxial helicopter's rotors spin up slower or faster than the document's step tests gave
    (a heavier rotor, another speed controller): thrust and drag torque follow the input through a
    first-order lag of time constant T (coaxial document, 5.20-5.22, 5.30-5.31; 0.17 s there)."""

    name = "rotor_time_constant"
    equation = "F(s) = k_F / (1 + T s) i(s)  (coaxial helicopter, both rotors; the document's T = 0.17 s)"
    params = {"T": Param(0.3, "s", 0.05, 0.6)}

    def constants(self, params):
        return replace(params, T=self.T) if isinstance(params, CoaxParams) else params


@register
class MotorFailure(Effect):
    """One rotor of a quadcopter losing thrust from ``t`` on (a damaged propeller, a failing motor or
    ESC). The attitude loop holds the vehicle level by driving that motor harder: its output reads
    ``tau / (1 - loss)`` while the others keep ``tau``. When that passes full output (``tau > 1 -
    loss``), the loop has no authority left: the vehicle lacks ``tau - (1 - loss)`` of one motor's
    full thrust, and the torque of that deficit over the inertia rolls (or pitches) it away
    (``authority`` [rad/s^2] per unit deficit) until, past 90 degrees, it falls. ``loss = 1`` is a
    motor that stops. Motors in ArduPilot's quad X order: 1 front right, 2 back left, 3 front left,
    4 back right."""

    name = "motor_failure"
    equation = "out_k = tau / (1 - loss); deficit = max(0, tau - (1 - loss)): thrust lost, roll/pitch accel ~ deficit"
    in_the_motors = False
    params = {
        "motor": Param(1.0, "1", 1.0, 4.0, "which motor (1-4, ArduPilot quad X order)"),
        "loss": Param(0.15, "1", 0.0, 1.0, "fraction of its thrust lost"),
        "t": Param(10.0, "s", 0.0, 3600.0, "onset"),
        "authority": Param(60.0, "rad/s^2", 1.0, 500.0, "angular acceleration per unit thrust deficit"),
    }
    #: each motor's position (forward, right) in ArduPilot's quad X, sign only
    POSITION = {1: (1, 1), 2: (-1, -1), 3: (1, -1), 4: (-1, 1)}

    def setup(self, kw):
        self.rate = [0.0, 0.0]  # the roll and pitch rates the lost authority has built [rad/s]

    def _deficit(self, sim) -> float:
        """The thrust motor k cannot give at full output, in units of its full thrust: it is asked
        for tau (the others' share) and gives at most 1 - loss."""
        return max(0.0, sim.vehicle.throttle - (1.0 - self.loss))

    def active(self, sim) -> bool:
        return sim.t >= self.t and sim.scenario.vehicle == "quad"

    def outputs(self, values, sim):
        if not self.active(sim):
            return values
        out = list(values)
        k = int(self.motor) - 1
        out[k] = min(1.0, out[k] / (1.0 - self.loss)) if self.loss < 1.0 else (1.0 if out[k] > 0 else 0.0)
        return out

    def thrust_factor(self, sim) -> float:
        tau = sim.vehicle.throttle
        if not self.active(sim) or tau <= 0:
            return 1.0
        return 1.0 - self._deficit(sim) / (4.0 * tau)

    def step(self, dt, sim) -> None:
        v = sim.vehicle
        if not self.active(sim) or v.on_ground:
            self.rate = [0.0, 0.0]
            return
        deficit = self._deficit(sim)
        if deficit <= 0.0 and abs(self.rate[0]) + abs(self.rate[1]) == 0.0:
            return
        fwd, right = self.POSITION[int(self.motor)]
        # a weak motor on the right lets the vehicle roll right (+roll), one in front pitch down (-pitch)
        self.rate[0] += right * self.authority * deficit * dt
        self.rate[1] += -fwd * self.authority * deficit * dt
        v.phi = (v.phi + self.rate[0] * dt + math.pi) % (2 * math.pi) - math.pi
        v.theta = max(-1.5, min(1.5, v.theta + self.rate[1] * dt))


def parse_effect(text: str) -> Effect:
    """``NAME`` or ``NAME:k=v,k=v`` -> an effect instance (one-line errors)."""
    name, _, rest = text.partition(":")
    name = name.strip()
    cls = REGISTRY.get(name)
    if cls is None:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(sorted(REGISTRY))}")
    kw = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        k, eq, v = item.partition("=")
        if not eq:
            raise ValueError(f"effect {name}: expected k=v, got {item!r}")
        kw[k.strip()] = v.strip() if k.strip() == "sensor" else _number(name, k, v)
    return cls(**kw)


def _number(name: str, k: str, v: str) -> float:
    try:
        return float(v)
    except ValueError:
        raise ValueError(f"effect {name}: {k}={v!r} is not a number") from None


def catalogue_markdown() -> str:
    """The catalogue as a table (for the README and ``groundstation sim --list-effects``)."""
    rows = ["| effect | equation | parameters (default, unit, realistic range) |", "|---|---|---|"]
    for name in sorted(REGISTRY):
        cls = REGISTRY[name]
        ps = "; ".join(f"{k} = {p.default:g} {p.unit} [{p.low:g}, {p.high:g}]" for k, p in cls.params.items())
        if name == "sensor_delay":
            ps = "sensor = one of " + "/".join(SENSORS) + "; " + ps
        rows.append(f"| `{name}` | {cls.equation} | {ps or 'none'} |")
    return "\n".join(rows)
