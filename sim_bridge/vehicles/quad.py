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

Effects that act on the thrust (:mod:`sim_bridge.effects`) set ``thrust_factor``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from groundstation.core.frames import a_ib

from .base import G, Kinematics, Vehicle

#: Landing-gear contact time constant [s]: a touchdown at 1 m/s peaks at ~3.4 g.
CONTACT_TC = 0.03
#: m: within this of the ground, sinking at 2 cm/s or less, the vehicle is at rest (the damper's
#: remaining travel at 2 cm/s is 0.6 mm); climbing, it is lifting off
REST_GAP = 0.001


@dataclass
class QuadParams:
    alpha: float = 22.0  # thrust gain [m/s^2 per unit throttle]
    beta: float = -1.2  # thrust offset [m/s^2]  -> hover at tau = 0.5004
    drag: float = 0.35  # linear drag [1/s]
    tau_att: float = 0.12  # attitude response time constant [s]
    n_cells: int = 3
    v_full: float = 4.2  # cell voltage at full charge [V]
    v_empty: float = 3.45  # cell voltage when empty [V]
    capacity_ah: float = 2.2
    r_int: float = 0.12  # pack internal resistance [ohm]
    i_idle: float = 0.5  # current with motors stopped [A]
    i_max: float = 40.0  # current at full throttle [A]
    soc0: float = 1.0  # initial state of charge

    @property
    def hover_throttle(self) -> float:
        return (G - self.beta) / self.alpha


@dataclass
class QuadCommand:
    throttle: float = 0.0  # 0..1
    roll: float = 0.0  # roll setpoint [rad]
    pitch: float = 0.0  # pitch setpoint [rad]
    yaw_rate: float = 0.0  # [rad/s]


class Quad(Vehicle):
    """State in plain floats (this model runs at >= 50x real time with all
    sensors); the numpy :class:`Kinematics` the sensors read is built lazily."""

    name = "quad"

    def __init__(self, params: QuadParams | None = None) -> None:
        self.p = params or QuadParams()
        self.n = self.e = self.d = 0.0  # NED position [m]
        self.vn = self.ve = self.vd = 0.0  # NED velocity [m/s]
        self.an = self.ae = self.ad = 0.0  # NED acceleration [m/s^2]
        self.phi = self.theta = self.psi = 0.0
        self.w = (0.0, 0.0, 0.0)  # body rates
        self.tau = 0.0  # throttle applied to the motors
        self.tau_cmd = 0.0
        self.a_thrust = 0.0  # thrust acceleration [m/s^2]
        self.soc = self.p.soc0
        self.current = self.p.i_idle
        self.voltage = self.open_circuit_voltage()
        self.on_ground = True
        self.thrust_factor = 1.0  # set by thrust effects each step
        self._kin: Kinematics | None = None

    def open_circuit_voltage(self) -> float:
        p = self.p
        return p.n_cells * (p.v_empty + (p.v_full - p.v_empty) * max(0.0, self.soc))

    @property
    def throttle(self) -> float:
        return self.tau

    @property
    def kin(self) -> Kinematics:
        k = self._kin
        if k is None:
            R = a_ib(self.phi, self.theta, self.psi)
            acc = np.array([self.an, self.ae, self.ad - G])
            k = self._kin = Kinematics(
                np.array([self.n, self.e, self.d]),
                np.array([self.vn, self.ve, self.vd]),
                R,
                np.array(self.w),
                R.T @ acc,
            )
        return k

    @kin.setter
    def kin(self, k: Kinematics) -> None:
        self._kin = k

    def imu_truth(self):
        """R^T (a - g) with R = A_IB(phi, theta, psi) written out (eq. 3.10)."""
        sf, cf = math.sin(self.phi), math.cos(self.phi)
        st, ct = math.sin(self.theta), math.cos(self.theta)
        sp, cp = math.sin(self.psi), math.cos(self.psi)
        an, ae, ad = self.an, self.ae, self.ad - G
        fx = cp * ct * an + ct * sp * ae - st * ad
        fy = (cp * sf * st - cf * sp) * an + (cf * cp + sf * sp * st) * ae + ct * sf * ad
        fz = (sf * sp + cf * cp * st) * an + (cf * sp * st - cp * sf) * ae + cf * ct * ad
        return (fx, fy, fz, *self.w)

    def place(self, height: float) -> None:
        """Put the vehicle in the air at ``height`` (tests)."""
        self.d = -height
        self.on_ground = False
        self._kin = None

    @staticmethod
    def clipped(cmd: QuadCommand) -> QuadCommand:
        """The command within the actuators' range (what the outputs can show)."""
        return QuadCommand(min(1.0, max(0.0, cmd.throttle)), cmd.roll, cmd.pitch, cmd.yaw_rate)

    def step(self, dt: float, cmd: QuadCommand) -> None:
        p = self.p
        self._kin = None
        self.tau_cmd = self.clipped(cmd).throttle
        self.tau = tau = self.tau_cmd
        # attitude inner loop (first-order) and Euler rates -> body rates
        if self.on_ground:
            dphi, dtheta, dpsi = -self.phi / p.tau_att, -self.theta / p.tau_att, 0.0
        else:
            dphi = (cmd.roll - self.phi) / p.tau_att
            dtheta = (cmd.pitch - self.theta) / p.tau_att
            dpsi = cmd.yaw_rate
        self.phi += dphi * dt
        self.theta += dtheta * dt
        self.psi = (self.psi + dpsi * dt + math.pi) % (2 * math.pi) - math.pi
        sf, cf = math.sin(self.phi), math.cos(self.phi)
        st, ct = math.sin(self.theta), math.cos(self.theta)
        sp, cp = math.sin(self.psi), math.cos(self.psi)
        # body rates from Euler rates (coaxial document eq. 6.13)
        self.w = (dphi - st * dpsi, ct * sf * dpsi + cf * dtheta, cf * ct * dpsi - sf * dtheta)
        # battery
        self.current = p.i_idle + p.i_max * tau * tau
        self.soc = max(0.0, self.soc - self.current * dt / (3600.0 * p.capacity_ah))  # an empty pack stays empty
        self.voltage = self.open_circuit_voltage() - p.r_int * self.current
        # thrust (document eq. 2) along the body's -z axis: third column of A_IB (eq. 3.10)
        a_t = max(0.0, p.alpha * tau + p.beta) * self.thrust_factor
        self.a_thrust = a_t
        an = -a_t * (sf * sp + cf * cp * st) - p.drag * self.vn
        ae = -a_t * (cf * sp * st - cp * sf) - p.drag * self.ve
        ad = -a_t * cf * ct + G - p.drag * self.vd
        if self.on_ground:
            if ad < 0:  # lift-off once thrust exceeds weight
                self.on_ground = False
            else:
                an = ae = ad = 0.0
                self.vn = self.ve = self.vd = 0.0
        elif self.vd > 0.0 and self.d >= -self.vd * CONTACT_TC:
            # ground contact: a damper stops the descent over ~CONTACT_TC (the
            # IMU sees the landing impact, as on a real vehicle). It engages at its
            # stopping distance, vd * CONTACT_TC, above the ground, so the vehicle comes
            # to rest at h = 0 with its position the integral of its velocity (engaged at
            # h = 0 with the position held there, the vehicle stopped 1.7 cm before its
            # IMU said so)
            ad = min(ad, -self.vd / CONTACT_TC)
            an, ae = -self.vn / CONTACT_TC, -self.ve / CONTACT_TC
        self.vn += an * dt
        self.ve += ae * dt
        self.vd += ad * dt
        self.n += self.vn * dt
        self.e += self.ve * dt
        self.d += self.vd * dt
        if not self.on_ground and self.d >= -REST_GAP and 0.0 <= self.vd <= 0.02 and ad >= -G:
            # at rest on the ground: the last of the velocity goes in this step, and the
            # IMU reads it (zeroed unreported, 2 cm/s of it became a 2 cm/s sink of the
            # estimate on the ground)
            an, ae, ad = an - self.vn / dt, ae - self.ve / dt, ad - self.vd / dt
            self.d = 0.0
            self.vn = self.ve = self.vd = 0.0
            self.on_ground = True
        elif self.d > 0.0:
            self.d = 0.0
        self.an, self.ae, self.ad = an, ae, ad

    def truth(self) -> dict[str, float]:
        return {
            "n": self.n,
            "e": self.e,
            "d": self.d,
            "vn": self.vn,
            "ve": self.ve,
            "vd": self.vd,
            "roll": self.phi,
            "pitch": self.theta,
            "yaw": self.psi,
            "p": self.w[0],
            "q": self.w[1],
            "r": self.w[2],
            "throttle": self.tau,
            "a_thrust": self.a_thrust,
            "alpha_eff": (self.a_thrust - self.p.beta) / self.tau if self.tau > 0.05 else self.p.alpha,
            "voltage": self.voltage,
            "current": self.current,
            "soc": self.soc,
        }
