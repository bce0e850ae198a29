"""Coaxial helicopter, 6-DOF: coaxial-helicopter document, part I.

Rotor drive systems (ch. 5): first-order lags from the speed-controller inputs
``i_L, i_U`` (0..1) to thrust and drag torque::

    F(s) = k_F / (1 + T s) * i(s),   T_(s) = k_T / (1 + T s) * i(s)      (5.21, 5.22, 5.31)
    k_F = 4.4 N, k_T = 0.135 N m, T = 0.17 s; lower thrust x k_w = 0.84 when
    both rotors run (5.23, 5.29).

Lower-rotor thrust and torque direction from the flapping angles (ch. 4)::

    G(a, b) = 1/sqrt(1 - sin^2 a sin^2 b) (-sin a cos b, cos a sin b, -cos a cos b)^T  (4.7)
    F_L = G F_L,  T_L = G T_L (4.6, 4.8);  F_U = (0, 0, -F_U),  T_U = (0, 0, T_U)  (6.5, 6.22)

Rigid body (ch. 6): forces (6.7) and torques (6.23) with Euler's equation
(6.2) for the body rates ``Omega``.

Deliberate departures from the document, each for a stated reason:

* Translation is integrated in the inertial frame, ``m r_ddot_I = A_IB F_B + m g``.
  Eq. (6.3)/(6.8) write ``B r_ddot = F_B / m``, i.e. differentiate body-frame
  coordinates as if the frame did not rotate (the ``Omega x v`` term is lost).
* Attitude is integrated as a rotation matrix from ``Omega`` (exact exponential
  map), not through the Euler-angle form (6.24): that form is singular at
  theta = +-90 deg, and its Delta M^A (6.18) has a typo in the third row
  (``cos Phi Phi_dot Phi_dot`` where the derivative of ``-sin Phi Theta_dot``
  gives ``cos Phi Phi_dot Theta_dot``). Euler angles are reported from the matrix.
* Eq. (4.3) says "projection of F_L on the x_B-axis"; it is the z_B-axis.
* The document gives neither mass, inertia nor rotor heights. We take
  ``m = 0.5 kg`` (the document's step tests at input 0.6 then are a hover:
  (1 + k_w) k_F 0.6 = 4.86 N = m g for m = 0.495 kg), ``I = diag(4.0, 4.0,
  2.5) g m^2`` and ``l_L = 0.08 m``, ``l_U = 0.16 m`` above the CoG.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from groundstation.core.frames import euler_from_matrix, exp_so3

from .base import G, Kinematics, Vehicle
from .quad import CONTACT_TC, REST_GAP


@dataclass
class CoaxParams:
    k_F: float = 4.4  # thrust gain [N] (5.21)
    k_T: float = 0.135  # drag-torque gain [N m] (5.31)
    T: float = 0.17  # rotor time constant [s] (5.20, 5.30)
    k_w: float = 0.84  # lower-rotor thrust factor in the upper rotor's wake (5.29)
    mass: float = 0.5  # [kg] (not in the document; see module docstring)
    inertia: tuple[float, float, float] = (4.0e-3, 4.0e-3, 2.5e-3)  # [kg m^2]
    l_L: float = 0.08  # lower rotor above the CoG [m]
    l_U: float = 0.16  # upper rotor above the CoG [m]
    max_flap: float = 0.25  # flapping-angle limit [rad]

    @property
    def hover_input(self) -> float:
        """Equal inputs that hover: (1 + k_w) k_F i = m g."""
        return self.mass * G / ((1 + self.k_w) * self.k_F)


@dataclass
class CoaxCommand:
    i_L: float = 0.0  # lower speed-controller input 0..1
    i_U: float = 0.0  # upper speed-controller input 0..1
    a: float = 0.0  # longitudinal flapping angle [rad]
    b: float = 0.0  # lateral flapping angle [rad]


def G_ab(a: float, b: float) -> np.ndarray:
    """Direction of the lower rotor's thrust and torque, eq. (4.7)."""
    sa, ca, sb, cb = math.sin(a), math.cos(a), math.sin(b), math.cos(b)
    return np.array([-sa * cb, ca * sb, -ca * cb]) / math.sqrt(1.0 - sa * sa * sb * sb)


class Coax(Vehicle):
    name = "coax"

    def __init__(self, params: CoaxParams | None = None) -> None:
        self.p = params or CoaxParams()
        self.kin = Kinematics()
        self.F_L = self.F_U = self.T_L = self.T_U = 0.0
        self.cmd = CoaxCommand()
        self.I = np.diag(self.p.inertia)
        self.I_inv = np.linalg.inv(self.I)
        self.on_ground = True
        self.thrust_factor = 1.0  # set by thrust effects each step

    @property
    def throttle(self) -> float:
        return 0.5 * (self.cmd.i_L + self.cmd.i_U)

    def forces_torques(self) -> tuple[np.ndarray, np.ndarray]:
        """Rotor force (6.7 without gravity) and torque (6.23) in the body frame."""
        p, c = self.p, self.cmd
        g = G_ab(c.a, c.b)
        k_w = p.k_w if self.F_U > 1e-3 else 1.0
        f_l = g * (k_w * self.F_L)
        f_u = np.array([0.0, 0.0, -self.F_U])
        tau = np.cross([0.0, 0.0, -p.l_L], f_l) + g * self.T_L + np.array([0.0, 0.0, self.T_U])
        return (f_l + f_u) * self.thrust_factor, tau

    def clipped(self, cmd: CoaxCommand) -> CoaxCommand:
        """The command within the actuators' range (what the outputs can show)."""
        m = self.p.max_flap
        return CoaxCommand(
            min(1.0, max(0.0, cmd.i_L)), min(1.0, max(0.0, cmd.i_U)), max(-m, min(m, cmd.a)), max(-m, min(m, cmd.b))
        )

    def step(self, dt: float, cmd: CoaxCommand) -> None:
        p, k = self.p, self.kin
        self.cmd = self.clipped(cmd)
        # rotor first-order lags, exact for a held input over dt
        e = math.exp(-dt / p.T)
        self.F_L = p.k_F * self.cmd.i_L + (self.F_L - p.k_F * self.cmd.i_L) * e
        self.F_U = p.k_F * self.cmd.i_U + (self.F_U - p.k_F * self.cmd.i_U) * e
        self.T_L = p.k_T * self.cmd.i_L + (self.T_L - p.k_T * self.cmd.i_L) * e
        self.T_U = p.k_T * self.cmd.i_U + (self.T_U - p.k_T * self.cmd.i_U) * e
        f_b, tau = self.forces_torques()
        # Euler's equation (6.2): I Omega_dot = T - Omega x (I Omega)
        w = k.omega
        w_dot = self.I_inv @ (tau - np.cross(w, self.I @ w))
        acc = k.R @ f_b / p.mass + np.array([0.0, 0.0, G])
        if self.on_ground:
            if acc[2] < 0:
                self.on_ground = False
            else:
                acc[:] = 0.0
                w_dot[:] = 0.0
                k.vel[:] = 0.0
                k.omega = np.zeros(3)
        elif k.vel[2] > 0.0 and k.pos[2] >= -k.vel[2] * CONTACT_TC:
            # ground contact: the landing gear's damper stops the descent over
            # ~CONTACT_TC, so the IMU sees the impact (stopping within one step
            # hid a 0.65 m/s velocity change from the accelerometer). Engaged at its
            # stopping distance above the ground: the vehicle comes to rest at h = 0
            # (see the quadcopter's)
            acc[2] = min(acc[2], -k.vel[2] / CONTACT_TC)
            acc[0], acc[1] = -k.vel[0] / CONTACT_TC, -k.vel[1] / CONTACT_TC
        k.omega = k.omega + w_dot * dt
        k.R = k.R @ exp_so3(k.omega, dt)
        k.vel = k.vel + acc * dt
        k.pos = k.pos + k.vel * dt
        if not self.on_ground and k.pos[2] >= -REST_GAP and 0.0 <= k.vel[2] <= 0.02 and acc[2] >= -G:
            acc = acc - k.vel / dt  # at rest on the ground: the IMU reads the last of the velocity go
            k.pos[2] = 0.0
            k.vel[:] = 0.0
            self.on_ground = True
        elif k.pos[2] > 0.0:
            k.pos[2] = 0.0
        k.specific_force = k.R.T @ (acc - np.array([0.0, 0.0, G]))

    def truth(self) -> dict[str, float]:
        k = self.kin
        roll, pitch, yaw = euler_from_matrix(k.R)
        return {
            "n": k.pos[0],
            "e": k.pos[1],
            "d": k.pos[2],
            "vn": k.vel[0],
            "ve": k.vel[1],
            "vd": k.vel[2],
            "roll": roll,
            "pitch": pitch,
            "yaw": yaw,
            "p": k.omega[0],
            "q": k.omega[1],
            "r": k.omega[2],
            "F_L": self.F_L,
            "F_U": self.F_U,
            "T_L": self.T_L,
            "T_U": self.T_U,
            "i_L": self.cmd.i_L,
            "i_U": self.cmd.i_U,
            "a": self.cmd.a,
            "b": self.cmd.b,
        }
