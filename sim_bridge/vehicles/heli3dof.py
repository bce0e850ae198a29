"""3-DOF lab helicopter (pitch p, elevation e, travel lambda): the lab document, part 1.

Full equations, before the small-angle linearisation of the lab's eq. (14)-(16),
so that the linear model the estimators and controllers use has real errors::

    J_p p_dd   = l_p (F_b - F_f)                                              (9)
    J_e e_dd   = l_h cos(p) (F_f + F_b) - l_h cos(e) 2 m_p g + l_c cos(e) m_c g  (10)
    J_l lam_dd = l_h cos(e) (F_f + F_b) sin(p)                                (13)
    F_f = K_f V_f,  F_b = K_f V_b                                            (4, 5)

Table 1 constants: l_p = 0.175 m, l_c = 0.46 m, l_h = 0.66 m, J_p = 0.044,
J_e = 1.03, J_lambda = 1.08 kg m^2, m_p = 0.72 kg, m_c = 1.92 kg, g = 9.81.

Corrections, made knowingly:

* Eq. (12) adds the counterweight term; eq. (10), which it is derived from,
  subtracts it (the counterweight helps lift). The equilibrium of (10) is
  ``V_s0 = (2 l_h m_p g - l_c m_c g) / (l_h K_f)``.
* The lab's ``K_f = 3.4`` comes from the plus sign of (12) with V_s0 = 8 V.
  With the correct sign and Table 1, V_s0 = 8 V gives K_f = 0.1248 N/V, which
  we use so that the full model holds elevation at V_s0 (the lab's controller
  gains were tuned on the larger K_f; the control issue discusses that).
* Below eq. (12), "F_g,f = F_g,b = m_c g where m_c is the propeller mass" means
  m_p (Table 1's motor mass).
* Travel torque (13) gets the lever arm ``l_h cos(e)``; the lab drops it with
  the small-angle assumption.

What a real rig has beyond Table 1, each zero by default and set by the
simulator's effects (``sim_bridge.effects``: motor_asymmetry, viscous_friction,
motor_constant, counterweight): the two motors' constants ``K_f (1 -+ a)``
(front, back) and a viscous friction torque ``-d x_dot`` on each axis::

    J_p p_dd   = l_p (F_b - F_f) - d_p p_dot
    J_e e_dd   = ... (10) ... - d_e e_dot
    J_l lam_dd = ... (13) ... - d_l lam_dot
    F_f = K_f (1 - a) V_f,  F_b = K_f (1 + a) V_b

The IMU sits on the arm that carries the rotors, as the lab describes (sec. 4.1):
its frame follows travel (yaw), elevation (pitch) and the helicopter's pitch p
(roll), so its gyro reads the Euler-rate transform of (p_dot, e_dot,
lambda_dot) and its accelerometer the specific force of the point ``l_h`` out on
the arm (centripetal terms included).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from groundstation.core.frames import a_ib

from .base import Kinematics, Vehicle


@dataclass
class Heli3dofParams:
    g: float = 9.81
    l_p: float = 0.175
    l_c: float = 0.46
    l_h: float = 0.66
    J_p: float = 0.044
    J_e: float = 1.03
    J_l: float = 1.08
    m_p: float = 0.72
    m_c: float = 1.92
    K_f: float = 0.1248  # [N/V], see the module docstring
    V_max: float = 12.0  # motor voltage limit [V]
    e_min: float = -0.5  # elevation end stop (resting on the table) [rad]
    e_max: float = 1.0  # elevation end stop above (the rig's frame) [rad]
    p_max: float = 1.2  # pitch end stops [rad]
    a: float = 0.0  # motor asymmetry: F_f = K_f (1 - a) V_f, F_b = K_f (1 + a) V_b
    d_p: float = 0.0  # viscous friction on pitch [N m s/rad]
    d_e: float = 0.0  # on elevation
    d_l: float = 0.0  # on travel

    @property
    def V_s0(self) -> float:
        """Sum voltage that holds elevation at e = 0, p = 0 (corrected eq. 12)."""
        return (2 * self.l_h * self.m_p * self.g - self.l_c * self.m_c * self.g) / (self.l_h * self.K_f)


@dataclass
class Heli3dofCommand:
    V_f: float = 0.0  # front motor voltage [V]
    V_b: float = 0.0  # back motor voltage [V]


class Heli3dof(Vehicle):
    name = "heli3dof"

    def __init__(self, params: Heli3dofParams | None = None, e0: float | None = None) -> None:
        self.p = params or Heli3dofParams()
        self.x = np.zeros(6)  # p, p_dot, e, e_dot, lambda, lambda_dot
        self.x[2] = self.p.e_min if e0 is None else e0
        self.cmd = Heli3dofCommand()
        self.kin = Kinematics()
        self._update_kinematics(np.zeros(6))

    @property
    def throttle(self) -> float:
        return (self.cmd.V_f + self.cmd.V_b) / (2 * self.p.V_max)

    def derivatives(self, x: np.ndarray, cmd: Heli3dofCommand) -> np.ndarray:
        P = self.p
        p, pd, e, ed, lam, lamd = x
        F_f, F_b = P.K_f * (1.0 - P.a) * cmd.V_f, P.K_f * (1.0 + P.a) * cmd.V_b
        pdd = (P.l_p * (F_b - F_f) - P.d_p * pd) / P.J_p
        edd = (
            P.l_h * math.cos(p) * (F_f + F_b)
            - P.l_h * math.cos(e) * 2 * P.m_p * P.g
            + P.l_c * math.cos(e) * P.m_c * P.g
            - P.d_e * ed
        ) / P.J_e
        ldd = (P.l_h * math.cos(e) * (F_f + F_b) * math.sin(p) - P.d_l * lamd) / P.J_l
        return np.array([pd, pdd, ed, edd, lamd, ldd])

    def clipped(self, cmd: Heli3dofCommand) -> Heli3dofCommand:
        """The command within the motors' range (what the outputs can show)."""
        v_max = self.p.V_max
        return Heli3dofCommand(min(v_max, max(0.0, cmd.V_f)), min(v_max, max(0.0, cmd.V_b)))

    def step(self, dt: float, cmd: Heli3dofCommand) -> None:
        P = self.p
        self.cmd = self.clipped(cmd)
        x = self.x
        # classical Runge-Kutta 4: the lab samples at 500 Hz; RK4 keeps the
        # integration error far below the linearisation error it is compared with
        k1 = self.derivatives(x, self.cmd)
        k2 = self.derivatives(x + 0.5 * dt * k1, self.cmd)
        k3 = self.derivatives(x + 0.5 * dt * k2, self.cmd)
        k4 = self.derivatives(x + dt * k3, self.cmd)
        self.x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        # end stops: the table under the arm, the frame above it, the pitch limits
        if self.x[2] < P.e_min:
            self.x[2], self.x[3] = P.e_min, max(0.0, self.x[3])
        elif self.x[2] > P.e_max:
            self.x[2], self.x[3] = P.e_max, min(0.0, self.x[3])
        if abs(self.x[0]) > P.p_max:
            self.x[0] = math.copysign(P.p_max, self.x[0])
            self.x[1] = 0.0
        self._update_kinematics(self.derivatives(self.x, self.cmd))

    def _update_kinematics(self, xd: np.ndarray) -> None:
        """IMU frame on the arm: yaw = travel, pitch = elevation, roll = helicopter pitch."""
        P, k = self.p, self.kin
        p, pd, e, ed, lam, lamd = self.x
        edd, ldd = xd[3], xd[5]
        R = a_ib(p, e, lam)
        k.R = R
        sp, cp, se, ce = math.sin(p), math.cos(p), math.sin(e), math.cos(e)
        k.omega = np.array([pd - se * lamd, ce * sp * lamd + cp * ed, cp * ce * lamd - sp * ed])
        # point l_h out on the arm: r = l_h (ce cl, ce sl, -se) in NED; its acceleration
        cl, sl, l = math.cos(lam), math.sin(lam), P.l_h
        acc = l * np.array(
            [
                -ce * cl * (ed**2 + lamd**2) - se * cl * edd + 2 * se * sl * ed * lamd - ce * sl * ldd,
                -ce * sl * (ed**2 + lamd**2) - se * sl * edd - 2 * se * cl * ed * lamd + ce * cl * ldd,
                se * ed**2 - ce * edd,
            ]
        )
        k.pos = l * np.array([ce * cl, ce * sl, -se])
        k.specific_force = R.T @ (acc - np.array([0.0, 0.0, P.g]))

    def truth(self) -> dict[str, float]:
        p, pd, e, ed, lam, lamd = self.x
        return {
            "p": p,
            "p_dot": pd,
            "e": e,
            "e_dot": ed,
            "lambda": lam,
            "lambda_dot": lamd,
            "V_f": self.cmd.V_f,
            "V_b": self.cmd.V_b,
        }
