"""The simulator: a vehicle, its autopilot, its sensors and the scenario's effects.

``step()`` advances the physics by one fixed step (1 kHz for the quadcopter
and coaxial helicopter, 500 Hz for the 3-DOF helicopter, as its lab samples)
and returns the sensor samples that fall due, delayed as the scenario's
``sensor_delay`` effects say. Transports (:mod:`sim_bridge.bridge`,
:mod:`sim_bridge.fast`) turn samples into bytes; nothing here knows about
MAVLink.

Commands from the ground station (:meth:`command`) override the built-in
profile while they keep coming; ``command_timeout`` seconds after the last
one the vehicle falls back to its own autopilot (a failsafe).
"""

from __future__ import annotations

import heapq
from typing import Any, NamedTuple

import numpy as np

from groundstation.core.frames import euler_from_matrix, quaternion_from_euler
from groundstation.core.measurement import Kind, Measurement

from .effects import Effect
from .profile import CoaxAutopilot, FlightProfile, GuidedProfile, Heli3dofAutopilot, QuadAutopilot
from .scenario import Scenario
from .sensors import SensorSuite
from .vehicles.coax import Coax, CoaxParams
from .vehicles.heli3dof import Heli3dof, Heli3dofParams
from .vehicles.quad import Quad


class Sample(NamedTuple):
    t: float  # vehicle time when the reading is delivered [s]
    sensor: str
    values: tuple


#: Physics step rates [Hz]; never below the IMU's rate (the quadcopter's slowest
#: dynamics, 0.12 s, are resolved many times over at 500 Hz).
PHYSICS_RATE = {"quad": 500.0, "coax": 1000.0, "heli3dof": 500.0}


class Simulator:
    def __init__(self, scenario: Scenario, *, truth_rate: float = 100.0, command_timeout: float = 0.5) -> None:
        self.scenario = scenario
        self.rng = np.random.default_rng(scenario.seed)
        self.profile: FlightProfile | GuidedProfile = (
            GuidedProfile(scenario.duration)
            if scenario.flight == "guided"
            else FlightProfile(scenario.seed, scenario.duration, scenario.flight)
        )
        name = scenario.vehicle
        self.vehicle: Quad | Coax | Heli3dof
        self.autopilot: QuadAutopilot | CoaxAutopilot | Heli3dofAutopilot
        if name == "quad":
            quad = Quad()
            self.vehicle, self.autopilot = quad, QuadAutopilot(quad, self.profile)
        elif name == "coax":
            coax = Coax(self._constants(CoaxParams()))
            self.vehicle, self.autopilot = coax, CoaxAutopilot(coax, self.profile)
        else:
            rig = Heli3dof(self._constants(Heli3dofParams()), e0=0.0 if scenario.flight == "small" else None)
            assert isinstance(self.profile, FlightProfile)  # the scenario refuses a guided flight here
            self.vehicle, self.autopilot = rig, Heli3dofAutopilot(rig, self.profile)
        self.rate = max(PHYSICS_RATE[name], scenario.sensors.rates.get("imu", 0.0))
        self.dt = 1.0 / self.rate
        self.effects = scenario.effects
        self.imu_effects = [
            e for e in self.effects if type(e).accel is not Effect.accel or type(e).gyro is not Effect.gyro
        ]
        self.sensors = SensorSuite(name, scenario.sensors, self.rng)
        self.temperature = scenario.sensors.ambient_temp
        self.temperature_start = self.temperature
        self.delays: dict[str, float] = {}
        for e in self.effects:
            self.delays.update(e.delay)
        self._pending: list[tuple[float, int, Sample]] = []
        self._seq = 0
        #: the IMU's truth summed over the physics steps since its last sample (see imu_truth)
        self._imu_sum = [0.0] * 6
        self._imu_steps = 0
        self.t = 0.0
        self.step_count = 0
        self.truth_every = max(1, int(round(self.rate / truth_rate)))
        self.truth_rows: list[dict] = []
        self.keep_truth = True
        self.command_timeout = command_timeout
        #: the on-board controllers run at 250 Hz, as an autopilot's outer loops do
        self.autopilot_every = max(1, int(round(self.rate / 250.0)))
        self._auto_cmd: Any = None  # the autopilot's latest command (the vehicle's own command type)
        self._external = None
        self._external_cmd = None
        self._external_until = -1.0
        self.output_command = None  # what the outputs (PWM) show: the command from now on
        self._next_command = None  # that command, for the next step
        self.last_command = None  # what the vehicle was given (after the motors' effects)

    def _constants(self, params):
        """A vehicle's constants as the scenario's effects make them (a rig unlike Table 1)."""
        for e in self.scenario.effects:
            params = e.constants(params)
        return params

    # -- ground-station commands -------------------------------------------------------
    def command(self, cmd) -> None:
        """Fly this command until it goes stale: the vehicle's own command type, or a
        callable ``(t, dt) -> command`` evaluated at the autopilot's rate (a stabilised
        mode: the ground station sets attitude and collective, the inner loop flies them)."""
        self._external = cmd
        self._external_cmd = None
        self._external_until = self.t + self.command_timeout
        self._next_command = None  # flown from the next step, not after the held one

    @property
    def externally_commanded(self) -> bool:
        return self._external is not None and self.t <= self._external_until

    # -- stepping -------------------------------------------------------------------------
    def _command_from_now(self):
        """The command from this instant on, as the outputs (PWM) show it: the autopilot's at its
        ticks, held between them, or the ground station's while it keeps coming."""
        dt = self.dt
        if self.externally_commanded:
            ext = self._external
            if callable(ext):
                if self._external_cmd is None or self.step_count % self.autopilot_every == 0:
                    self._external_cmd = ext(self.t, dt * self.autopilot_every)
                cmd = self._external_cmd
            else:
                cmd = ext
        elif self._auto_cmd is None or self.step_count % self.autopilot_every == 0:
            cmd = self._auto_cmd = self.autopilot(self.t, dt * self.autopilot_every)
        else:
            cmd = self._auto_cmd
        for e in self.effects:
            if not e.in_the_motors:
                cmd = e.command(cmd, dt, self)
        return cmd

    def step(self) -> list[Sample]:
        dt, v = self.dt, self.vehicle
        # computed at the end of the previous step, so that the outputs read then were the command
        # the motors got from then on (read before it, they showed the autopilot's previous tick:
        # the logged throttle was 4 ms stale, and a 0.05 s actuator lag read 0.042 s)
        cmd = self._next_command if self._next_command is not None else self._command_from_now()
        self._next_command = None
        self.output_command = cmd
        for e in self.effects:
            if e.in_the_motors:
                cmd = e.command(cmd, dt, self)
        self.last_command = cmd
        factor = 1.0
        for e in self.effects:
            factor *= e.thrust_factor(self)
        if hasattr(v, "thrust_factor"):
            v.thrust_factor = factor
        v.step(dt, cmd)
        rates = self.sensors.rates
        if "imu" in rates and rates["imu"] * dt < 0.999:
            self._imu_steps += 1
            self._imu_sum = [a + b for a, b in zip(self._imu_sum, v.imu_truth())]
        self.temperature = self.sensors.temperature(self, dt)
        for e in self.effects:
            e.step(dt, self)
        self.t = (self.step_count + 1) * dt
        self.step_count += 1
        self.output_command = self._next_command = self._command_from_now()
        out: list[Sample] = []
        for name in self.sensors.due(self.t, dt):
            s = Sample(self.t, name, self.sensors.read(name, self))
            d = self.delays.get(self._delay_key(name), 0.0)
            if d > 0:
                self._seq += 1
                heapq.heappush(self._pending, (self.t + d, self._seq, s))
            else:
                out.append(s)
        while self._pending and self._pending[0][0] <= self.t + 0.5 * dt:
            due, _, s = heapq.heappop(self._pending)
            # delivered (and stamped) late: the reading is old, the stamp is not
            out.append(Sample(self.t, s.sensor, s.values))
        if self.keep_truth and self.step_count % self.truth_every == 0:
            self.truth_rows.append(self.truth())
        return out

    def imu_truth(self) -> tuple:
        """The true specific force and rates an IMU sample reads: their mean over the physics
        steps since the previous sample, as an IMU that integrates (delta velocity) or filters
        before it decimates reads them. Sampled at one step of several, the landing's impact
        was aliased: the live demo's 250 Hz IMU over 500 Hz physics lost part of the touchdown's
        velocity change, and its altitude estimate sank 5 cm/s on the ground. One step per
        sample (the quadcopter's 500 Hz IMU and physics) is the step's own value."""
        n = self._imu_steps
        if not n:
            return self.vehicle.imu_truth()
        out = tuple(a / n for a in self._imu_sum)
        self._imu_sum, self._imu_steps = [0.0] * 6, 0
        return out

    @staticmethod
    def _delay_key(name: str) -> str:
        return "imu" if name == "encoders" else name

    def run(self, seconds: float):
        """Yield samples for ``seconds`` of simulated time (batch use)."""
        n = int(round(seconds / self.dt))
        for _ in range(n):
            yield from self.step()

    # -- outputs --------------------------------------------------------------------------
    def actuator_outputs(self) -> list[float]:
        """What the outputs show, normalised 0..1 (PWM (us - 1000) / 1000 on the wire), clipped as
        the vehicle clips them: the commands as sent. An effect in the motors (``actuator_lag``)
        acts after them, as on a real vehicle, whose log records the PWM the rotors then follow."""
        v = self.vehicle
        c = v.clipped(self.output_command) if self.output_command is not None else None
        if isinstance(v, Quad):
            out = [c.throttle if c is not None else v.tau] * 4
            for e in self.effects:
                out = e.outputs(out, self)
            return out
        if isinstance(v, Coax):
            if c is None:
                return [0.0, 0.0, 0.5, 0.5]
            # flapping angles through the swash-plate servos, centred at 0.5
            m = v.p.max_flap
            return [c.i_L, c.i_U, 0.5 + c.a / (2 * m), 0.5 + c.b / (2 * m)]
        c = c or v.cmd
        return [c.V_f / v.p.V_max, c.V_b / v.p.V_max]

    def truth(self) -> dict[str, float]:
        row = {"t": self.t, "h": self.vehicle.kin.height}
        row.update(self.vehicle.truth())
        row["baro_alt_error"] = sum(e.baro_alt(self) for e in self.effects)
        row["temperature"] = self.temperature
        k = self.vehicle.kin
        row["range_true"] = max(0.0, k.height) / max(0.2, k.R[2, 2])
        row["accel_err_x"], row["accel_err_y"], row["accel_samples"] = self.sensors.take_accel_error()
        if "roll" not in row:
            r, p, y = euler_from_matrix(k.R)
            row.update({"roll": r, "pitch": p, "yaw": y})
        return {key: float(val) for key, val in row.items()}


def truth_pose(row: dict[str, float], source: str = "sim/truth") -> Measurement:
    """A row of :meth:`Simulator.truth` as motion capture reports a pose (``Kind.TRUTH_POSE``: NED
    position, the FRD body's quaternion), for a dashboard to draw and to score the height against.
    Down is minus the height above the floor, the height every estimate is scored on."""
    q = quaternion_from_euler(row.get("roll", 0.0), row.get("pitch", 0.0), row.get("yaw", 0.0))
    return Measurement(
        row["t"], Kind.TRUTH_POSE, np.array([row.get("n", 0.0), row.get("e", 0.0), -row["h"], *q]), source
    )
