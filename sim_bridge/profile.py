"""The built-in flight: a reference profile and the on-board controllers that fly it.

Without commands from the ground station the simulated vehicle flies:
ground idle, take-off, hover, climb/descend steps, an altitude sine, tilt
manoeuvres, descent and landing (and repeats the middle part for long runs).
The seed varies heights, periods and tilt amplitudes so that nothing
downstream gets tuned to one trajectory.

``flight="thrust_test"`` flies what a thrust identification flight flies
instead of the altitude sine: a hover low in ground effect (0.15-0.3 m, where a
rotor of R = 0.1-0.25 m adds 1-7 % of thrust) and height steps, whose throttle
steps show a lag in the actuators (the standard flight's lowest hover
is 0.6 m and its throttle is smooth: ground effect and actuator lag act there
only during take-off and touchdown).

``flight="high"`` climbs above the range sensor's reach (4 m) for about a
quarter of the flight: a smooth climb to 5-8 m, a sine there, a smooth descent,
then the standard flight's tilt manoeuvres. Up there the barometer alone
carries the height, as on any field flight above a few metres, so a baro error
shows in the height, where the standard flight's range sensor hides it.

The controllers stand for the vehicle's own autopilot. They fly on the true
state (a real autopilot flies on its estimate; the simulator's point is the
sensors, not the autopilot) and on the *nominal* vehicle parameters, so an
undeclared thrust effect shows up as it does in real logs: the throttle moves
to compensate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from groundstation.core.frames import euler_from_matrix

from .names import FLIGHTS
from .vehicles.base import G
from .vehicles.coax import Coax, CoaxCommand
from .vehicles.heli3dof import Heli3dof, Heli3dofCommand
from .vehicles.quad import Quad, QuadCommand


@dataclass
class Setpoint:
    height: float = 0.0  # [m], up
    roll: float = 0.0  # [rad] (feed-forward tilt manoeuvres)
    pitch: float = 0.0
    armed: bool = False
    rate: float = 0.0  # [m/s] the height's rate and
    accel: float = 0.0  # [m/s^2] acceleration, fed forward (only the ramps set them: FlightProfile._ramp)
    north: float = 0.0  # [m] the position held, from where the vehicle was switched on
    east: float = 0.0


class FlightProfile:
    """Height and tilt references over time, varied by the seed."""

    def __init__(self, seed: int = 0, duration: float = 60.0, flight: str = "standard") -> None:
        if flight not in FLIGHTS or flight == "guided":
            raise ValueError(f"unknown flight {flight!r}; use one of {', '.join(FLIGHTS)}")
        rng = np.random.default_rng(seed + 1000)
        self.h1 = rng.uniform(1.0, 2.0)  # hover height
        self.h_hi = self.h1 + rng.uniform(0.8, 1.6)
        self.h_lo = max(0.6, self.h1 - rng.uniform(0.3, 0.8))
        self.sine_amp = rng.uniform(0.3, 0.7)
        self.sine_period = rng.uniform(5.0, 10.0)
        self.tilt = math.radians(rng.uniform(8.0, 20.0))
        self.tilt_period = rng.uniform(2.0, 4.0)
        self.duration = duration
        self.flight = flight
        self.seed = seed
        # thrust_test (drawn after the standard's draws, which stay as they were)
        self.h_ground = rng.uniform(0.15, 0.3)
        self.step = rng.uniform(0.3, 0.6)
        self.step_period = rng.uniform(1.5, 2.5)
        # high (drawn after thrust_test's)
        self.h_top = rng.uniform(5.0, 8.0)

    def __call__(self, t: float) -> Setpoint:
        land_at = max(20.0, self.duration - 7.0)
        if t < 2.0:
            return Setpoint(0.0, armed=False)  # ground idle, motors off
        if t >= land_at + 4.0:
            return Setpoint(0.0, armed=False)  # landed
        if t >= land_at:
            return Setpoint(self.h1 * max(0.0, 1 - (t - land_at) / 3.0) - 0.3, armed=True)
        if t < 5.0:
            return Setpoint(self.h1 * (t - 2.0) / 3.0, armed=True)  # take-off ramp
        # the middle repeats with a 40 s period for long runs
        u = (t - 5.0) % 40.0
        if u < 6.0:
            return Setpoint(self.h1, armed=True)
        if u < 16.0 and self.flight != "high":
            return Setpoint(self.h_hi if u < 11.0 else self.h_lo, armed=True)
        if u < 28.0 and self.flight == "thrust_test":
            if u < 21.0:
                # a smooth ramp down, its rate and acceleration fed forward: a step, or a ramp
                # without, overshoots into the ground
                return self._ramp(u - 16.0, 5.0, self.h_lo, self.h_ground)
            if u < 25.0:
                return Setpoint(self.h_ground, armed=True)  # low hover, in ground effect
            sign = 1.0 if int((u - 25.0) / self.step_period) % 2 == 0 else -1.0
            return Setpoint(self.h1 + sign * self.step, armed=True)  # throttle steps
        if u < 28.0 and self.flight == "high":
            # the climb starts at 8 s, so that a 60 s flight's repeat (u = 40-48 before the landing at
            # 53 s) hovers instead of starting one
            if u < 8.0:
                return Setpoint(self.h1, armed=True)
            if u < 13.0:
                return self._ramp(u - 8.0, 5.0, self.h1, self.h_top)
            if u < 22.0:
                return Setpoint(
                    self.h_top + self.sine_amp * math.sin(2 * math.pi * (u - 13.0) / self.sine_period), armed=True
                )
            return self._ramp(min(u - 22.0, 5.0), 5.0, self.h_top, self.h1)
        if u < 28.0:
            return Setpoint(self.h1 + self.sine_amp * math.sin(2 * math.pi * (u - 16.0) / self.sine_period), armed=True)
        w = 2 * math.pi / self.tilt_period
        return Setpoint(self.h1, self.tilt * math.sin(w * (u - 28.0)), self.tilt * math.sin(0.7 * w * (u - 28.0)), True)

    @staticmethod
    def _ramp(s: float, T: float, h0: float, h1: float) -> Setpoint:
        """A cosine ramp from h0 to h1 over T seconds, its rate and acceleration fed forward."""
        w = math.pi / T
        dh = h1 - h0
        return Setpoint(
            h0 + dh * (1 - math.cos(w * s)) / 2,
            armed=True,
            rate=dh * w / 2 * math.sin(w * s),
            accel=dh * w * w / 2 * math.cos(w * s),
        )


class GuidedProfile:
    """The flight a ground station commands (``flight="guided"``), as ArduCopter's GUIDED and AUTO
    modes fly it: on the ground, motors off, until armed and told to take off; then a climb to the
    height asked, a hold, straight legs to the positions asked at :attr:`SPEED`, and a landing
    that ends disarmed, as ArduCopter disarms itself after touching down. The vehicle protocol
    (:mod:`sim_bridge.vehicle_protocol`) and the mission (:mod:`sim_bridge.mission`) call it."""

    CLIMB = 1.0  # [m/s] take-off and landing rates
    SPEED = 2.0  # [m/s] horizontal speed along a leg

    def __init__(self, duration: float = 60.0) -> None:
        self.duration = duration
        self.flight = "guided"
        self.armed = False
        self.flying = False  # taken off and not yet landed
        self.landing = False
        self._h = (0.0, 0.0, 0.0, 1.0)  # height ramp: t0, from, to, duration
        self._leg = (0.0, 0.0, 0.0, 0.0, 0.0, 1.0)  # t0, north/east from, north/east to, duration

    def __call__(self, t: float) -> Setpoint:
        if not (self.armed and self.flying):
            return Setpoint(0.0, armed=False)
        t0, h0, h1, T = self._h
        sp = FlightProfile._ramp(min(t - t0, T), T, h0, h1) if t - t0 < T else Setpoint(h1, armed=True)
        lt0, n0, e0, n1, e1, LT = self._leg
        f = min(1.0, max(0.0, (t - lt0) / LT))
        sp.north, sp.east = n0 + f * (n1 - n0), e0 + f * (e1 - e0)
        return sp

    def height_target(self, t: float) -> float:
        return self(t).height if self.flying else 0.0

    def arrived(self, t: float) -> bool:
        """The height ramp and the leg are flown (the vehicle itself settles behind them)."""
        return t >= self._h[0] + self._h[3] and t >= self._leg[0] + self._leg[5]

    def takeoff(self, t: float, height: float) -> None:
        self.flying, self.landing = True, False
        self.climb_to(t, height, from_height=0.0)

    def climb_to(self, t: float, height: float, from_height: float | None = None) -> None:
        h0 = self.height_target(t) if from_height is None else from_height
        self._h = (t, h0, height, max(1.0, abs(height - h0) / self.CLIMB))

    def go_to(self, t: float, north: float, east: float) -> None:
        sp = self(t)
        dist = math.hypot(north - sp.north, east - sp.east)
        self._leg = (t, sp.north, sp.east, north, east, max(1.0, dist / self.SPEED))

    def land(self, t: float) -> None:
        """Down to below the ground (-0.3 m: the height loop pushes it onto the ground)."""
        if self.flying:
            self.landing = True
            self.climb_to(t, -0.3)

    def landed(self, t: float, on_ground: bool) -> bool:
        """After a landing: on the ground with the descent flown; the motors stop."""
        if self.landing and on_ground and t >= self._h[0] + self._h[3]:
            self.flying = self.landing = self.armed = False
            return True
        return False


class QuadAutopilot:
    """Height PID through the nominal thrust model; horizontal position hold by tilt."""

    def __init__(self, quad: Quad, profile: FlightProfile | GuidedProfile) -> None:
        self.q, self.profile = quad, profile
        self.i = 0.0

    def __call__(self, t: float, dt: float) -> QuadCommand:
        q, p = self.q, self.q.p
        sp = self.profile(t)
        if not sp.armed:
            self.i = 0.0
            return QuadCommand(0.0)
        h, vz = -q.d, -q.vd
        err = sp.height - h
        self.i = max(-3.0, min(3.0, self.i + err * dt * 1.2))
        a_cmd = 4.0 * err + 3.2 * (sp.rate - vz) + self.i + sp.accel
        tilt = max(0.5, math.cos(q.phi) * math.cos(q.theta))
        tau = (a_cmd + G - p.beta) / (p.alpha * tilt)
        # horizontal: hold the origin (tilt setpoints from a PD on position)
        c, s = math.cos(q.psi), math.sin(q.psi)
        an = -0.8 * (q.n - sp.north) - 1.2 * q.vn
        ae = -0.8 * (q.e - sp.east) - 1.2 * q.ve
        pitch = -(c * an + s * ae) / G
        roll = (-s * an + c * ae) / G
        lim = 0.35
        return QuadCommand(tau, max(-lim, min(lim, roll + sp.roll)), max(-lim, min(lim, pitch + sp.pitch)), 0.0)


class CoaxAutopilot:
    """Collective for height, flapping angles for roll/pitch, differential for yaw."""

    def __init__(self, coax: Coax, profile: FlightProfile | GuidedProfile) -> None:
        self.c, self.profile = coax, profile
        self.i = 0.0

    def __call__(self, t: float, dt: float) -> CoaxCommand:
        p, k = self.c.p, self.c.kin
        sp = self.profile(t)
        if not sp.armed:
            self.i = 0.0
            return CoaxCommand()
        roll, pitch, _ = euler_from_matrix(k.R)
        h, vz = k.height, -k.vel[2]
        err = sp.height - h
        self.i = max(-3.0, min(3.0, self.i + err * dt * 1.0))
        a_cmd = 3.0 * err + 2.5 * (sp.rate - vz) + self.i + sp.accel
        tilt = max(0.5, math.cos(roll) * math.cos(pitch))
        i_col = p.mass * (G + a_cmd) / ((1 + p.k_w) * p.k_F * tilt)
        # position hold -> attitude setpoints
        an = -0.5 * (k.pos[0] - sp.north) - 1.0 * k.vel[0]
        ae = -0.5 * (k.pos[1] - sp.east) - 1.0 * k.vel[1]
        pitch_sp = max(-0.3, min(0.3, -an / G + sp.pitch))
        roll_sp = max(-0.3, min(0.3, ae / G + sp.roll))
        return self.stabilised(i_col, roll_sp, pitch_sp, 0.0)

    def stabilised(self, i_col: float, roll_sp: float, pitch_sp: float, yaw_rate_sp: float) -> CoaxCommand:
        """The inner attitude loop: collective as given, flapping angles for roll and
        pitch, the rotors' differential for the yaw rate (as MANUAL_CONTROL flies it)."""
        v, p, k = self.c, self.c.p, self.c.kin
        roll, pitch, _ = euler_from_matrix(k.R)
        # torques about x / y come from the lower rotor: (l_L b F_L, l_L a F_L) for small a, b
        f_l = max(0.5, v.F_L)
        Ix, Iy, Iz = p.inertia
        tx = Ix * (36.0 * (roll_sp - roll) - 12.0 * k.omega[0])
        ty = Iy * (36.0 * (pitch_sp - pitch) - 12.0 * k.omega[1])
        b = tx / (p.l_L * f_l)
        a = ty / (p.l_L * f_l)
        dyaw = Iz * (4.0 * (yaw_rate_sp - k.omega[2])) / p.k_T
        return CoaxCommand(i_col - dyaw, i_col + dyaw, a, b)


class Heli3dofAutopilot:
    """PD on elevation through V_s, on pitch through V_d, pitch set from travel.

    The flights: ``standard`` takes off from the table and steps elevation by 0.15-0.25 rad with
    travel swinging at 0.3 rad/s; ``small`` is recorded from level flight on and stays within a few
    degrees of it (where the lab's linear model holds); ``large`` takes off and flies far from it
    (elevation from -0.3 to +0.5 rad, pitch to 0.6 rad, travel at 0.8 rad/s). ``small`` and
    ``large`` vary their sizes and periods with the seed."""

    def __init__(self, heli: Heli3dof, profile: FlightProfile) -> None:
        self.h, self.profile = heli, profile
        rng = np.random.default_rng(profile.duration.__hash__() % 1000)
        self.e_step = 0.15 + 0.1 * rng.random()
        self.flight = profile.flight
        seeded = np.random.default_rng(profile.seed + 3000)
        if self.flight == "small":
            self.e_up, self.e_down = seeded.uniform(0.03, 0.06), -seeded.uniform(0.03, 0.06)
            self.lamd_amp, self.p_lim = seeded.uniform(0.06, 0.12), 0.1
        else:
            self.e_up, self.e_down = seeded.uniform(0.35, 0.5), -seeded.uniform(0.2, 0.3)
            self.lamd_amp, self.p_lim = seeded.uniform(0.6, 0.9), 0.6
        self.e_period, self.lamd_period = seeded.uniform(6.0, 10.0), seeded.uniform(12.0, 20.0)
        self.start = 0.0 if self.flight == "small" else 2.0

    def references(self, t: float) -> tuple[float, float]:
        """(elevation, travel rate) references [rad, rad/s]."""
        if self.flight == "standard":
            e_ref = 0.0 if t < 10.0 else (self.e_step if (t // 8) % 2 else -self.e_step / 2)
            return e_ref, (0.0 if t < 15.0 else 0.3 * math.sin(2 * math.pi * t / 20.0))
        s = t - self.start
        e_ref = 0.0 if s < 4.0 else (self.e_up if (s // self.e_period) % 2 else self.e_down)
        return e_ref, (0.0 if s < 6.0 else self.lamd_amp * math.sin(2 * math.pi * (s - 6.0) / self.lamd_period))

    def __call__(self, t: float, dt: float) -> Heli3dofCommand:
        P = self.h.p
        p, pd, e, ed, lam, lamd = self.h.x
        if t < self.start:
            return Heli3dofCommand(0.0, 0.0)
        e_ref, lamd_ref = self.references(t)
        p_lim = 0.4 if self.flight == "standard" else self.p_lim
        p_ref = max(-p_lim, min(p_lim, 1.5 * (lamd_ref - lamd)))
        V_s = P.V_s0 + 40.0 * (e_ref - e) - 25.0 * ed
        V_d = 60.0 * (p_ref - p) - 12.0 * pd
        return Heli3dofCommand((V_s - V_d) / 2.0, (V_s + V_d) / 2.0)
