"""Quadcopter: the quadcopter-altitude document's thrust model, with attitude and a battery.

Thrust model (quadcopter document, eq. 2), along the body's up axis::

    a_T = alpha * tau + beta            [m/s^2],  tau = collective throttle 0..1

so the NED acceleration is ``R @ (0, 0, -a_T) + (0, 0, g) - c_d * v`` (linear drag).
A level hover needs ``tau_h = (g - beta) / alpha`` (document eq. 1-2 with
z_ddot = 0). ``a_T`` is clipped at 0: the affine law is a fit around the
operating range and a rotor cannot push down (the document's beta < 0 would
otherwise pull the idle vehicle into the ground).

The document is altitude-only. Attitude here is the inner loop an autopilot
closes: roll and pitch follow their setpoints as first-order lags (``tau_att``),
yaw follows a yaw-rate setpoint; body rates are the Euler-rate transform, so a
gyro sees what it would on a real vehicle.

Battery: open-circuit voltage linear in state of charge, internal resistance,
current drawn ``I = I_idle + I_max * tau^2``::

    V = n_cells * (v_empty + (v_full - v_empty) * soc) - R_int * I

(``R_int`` = 0.12 ohm as the ArduPilot ``underpowered.log`` shows). By default
the ESCs compensate voltage, so thrust does not depend on V; the
``thrust_voltage`` effect removes that compensation (thrust ~ V^2).

Effects that act on the vehicle (:mod:`sim_bridge.effects`) hook in through
``thrust_hooks`` (a_T -> a_T) and ``actuator_hooks`` (tau_cmd -> tau).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..rotation import a_ib
from .base import G, Kinematics, Vehicle


@dataclass
class QuadParams:
    alpha: float = 22.0        # thrust gain [m/s^2 per unit throttle]
    beta: float = -1.2         # thrust offset [m/s^2]  -> hover at tau = 0.5004
    drag: float = 0.35         # linear drag [1/s]
    tau_att: float = 0.12      # attitude response time constant [s]
    n_cells: int = 3
    v_full: float = 4.2        # cell voltage at full charge [V]
    v_empty: float = 3.45      # cell voltage when empty [V]
    capacity_ah: float = 2.2
    r_int: float = 0.12        # pack internal resistance [ohm]
    i_idle: float = 0.5        # current with motors stopped [A]
    i_max: float = 40.0        # current at full throttle [A]
    soc0: float = 1.0          # initial state of charge

    @property
    def hover_throttle(self) -> float:
        return (G - self.beta) / self.alpha


@dataclass
class QuadCommand:
    throttle: float = 0.0      # 0..1
    roll: float = 0.0          # roll setpoint [rad]
    pitch: float = 0.0         # pitch setpoint [rad]
    yaw_rate: float = 0.0      # [rad/s]


class Quad(Vehicle):
    name = "quad"

    def __init__(self, params: QuadParams | None = None) -> None:
        self.p = params or QuadParams()
        self.kin = Kinematics()
        self.phi = self.theta = self.psi = 0.0
        self.tau = 0.0                 # throttle applied to the motors
        self.tau_cmd = 0.0
        self.a_thrust = 0.0            # thrust acceleration [m/s^2]
        self.soc = self.p.soc0
        self.current = self.p.i_idle
        self.voltage = self.open_circuit_voltage()
        self.on_ground = True
        self.thrust_hooks: list[Callable[["Quad", float], float]] = []
        self.actuator_hooks: list[Callable[["Quad", float, float], float]] = []

    def open_circuit_voltage(self) -> float:
        p = self.p
        return p.n_cells * (p.v_empty + (p.v_full - p.v_empty) * max(0.0, self.soc))

    @property
    def throttle(self) -> float:
        return self.tau

    def step(self, dt: float, cmd: QuadCommand) -> None:
        p, k = self.p, self.kin
        self.tau_cmd = min(1.0, max(0.0, cmd.throttle))
        tau = self.tau_cmd
        for hook in self.actuator_hooks:
            tau = hook(self, tau, dt)
        self.tau = tau
        # attitude inner loop (first-order) and Euler rates -> body rates
        a = dt / p.tau_att
        dphi = (cmd.roll - self.phi) * a / dt
        dtheta = (cmd.pitch - self.theta) * a / dt
        dpsi = cmd.yaw_rate
        if self.on_ground:
            dphi = -self.phi / p.tau_att
            dtheta = -self.theta / p.tau_att
            dpsi = 0.0
        self.phi += dphi * dt
        self.theta += dtheta * dt
        self.psi = (self.psi + dpsi * dt + math.pi) % (2 * math.pi) - math.pi
        sf, cf = math.sin(self.phi), math.cos(self.phi)
        st, ct = math.sin(self.theta), math.cos(self.theta)
        # body rates from Euler rates (coaxial document eq. 6.13)
        k.omega = np.array([dphi - st * dpsi, ct * sf * dpsi + cf * dtheta, cf * ct * dpsi - sf * dtheta])
        # battery
        self.current = p.i_idle + p.i_max * tau * tau
        self.soc -= self.current * dt / (3600.0 * p.capacity_ah)
        self.voltage = self.open_circuit_voltage() - p.r_int * self.current
        # thrust (document eq. 2), then effects acting on it
        a_t = max(0.0, p.alpha * tau + p.beta)
        for hook in self.thrust_hooks:
            a_t = hook(self, a_t)
        self.a_thrust = a_t
        R = a_ib(self.phi, self.theta, self.psi)
        k.R = R
        thrust_ned = R[:, 2] * (-a_t)
        acc = thrust_ned + np.array([0.0, 0.0, G]) - p.drag * k.vel
        if self.on_ground:
            if acc[2] < 0:          # lift-off once thrust exceeds weight
                self.on_ground = False
            else:
                acc[:] = 0.0
                k.vel[:] = 0.0
        k.vel = k.vel + acc * dt
        k.pos = k.pos + k.vel * dt
        if k.pos[2] >= 0.0 and not self.on_ground and k.vel[2] >= 0:
            k.pos[2] = 0.0          # touch-down
            k.vel[:] = 0.0
            acc[:] = 0.0
            self.on_ground = True
        # specific force = acceleration minus gravity, in the body frame
        k.specific_force = R.T @ (acc - np.array([0.0, 0.0, G]))

    def truth(self) -> dict[str, float]:
        k = self.kin
        return {
            "n": k.pos[0], "e": k.pos[1], "d": k.pos[2], "vn": k.vel[0], "ve": k.vel[1], "vd": k.vel[2],
            "roll": self.phi, "pitch": self.theta, "yaw": self.psi,
            "p": k.omega[0], "q": k.omega[1], "r": k.omega[2],
            "throttle": self.tau, "a_thrust": self.a_thrust,
            "alpha_eff": (self.a_thrust - self.p.beta) / self.tau if self.tau > 0.05 else self.p.alpha,
            "voltage": self.voltage, "current": self.current, "soc": self.soc,
        }
