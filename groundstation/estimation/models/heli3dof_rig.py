"""A 3-DOF helicopter rig's own constants: the lab document's model (part 1) with what a rig has
beyond its Table 1 and its small-angle assumption, as a vehicle file states them and as
``diagnose --model heli3dof`` finds them.

The lab's linear model (eq. 14-20, with the corrected K_f of :mod:`.heli3dof`), on torques::

    p_dd   = l_p (F_b - F_f) / J_p                                   (9)
    e_dd   = l_h [(F_f + F_b) - K_f V_s0] / J_e                       (10-12, linearised)
    lam_dd = l_h K_f V_s0 p / J_lambda                               (13, 16, 19: K3 p)
    F_f = K_f V_f,  F_b = K_f V_b                                    (4, 5)

and each thing a rig adds, zero (or Table 1's) in the lab's model:

* ``K_f``, ``V_s0``: the motor constant and the equilibrium voltage, found by hand in the lab (1.2);
* ``a``: the motors unlike, ``F_f = K_f (1 - a) V_f``, ``F_b = K_f (1 + a) V_b``;
* ``w_e``: elevation's full equation (10), ``l_h [cos(p) (F_f + F_b) - K_f V_s0 cos(e)]`` at
  ``w_e = 1`` (the gravity torque written through V_s0, whose definition (12) makes it
  ``l_h K_f V_s0`` at e = 0); ``cp = 1 + w_e (cos p - 1)`` and ``ce`` likewise;
* ``w_l``: travel's full torque (13) with its lever arm, ``l_h cos(e) (F_f + F_b) sin(p)``, mixed
  with K3 p as ``(1 - w_l) lin + w_l full``;
* ``c_p``, ``c_e``, ``c_l``: viscous friction, ``- c x_dot`` on each axis [1/s] (d / J);
* ``tc``: the motors' first-order lag [s] from the voltage to the thrust;
* ``gyro_bias``, ``accel_bias``: constants on the IMU's axes (FRD) [rad/s], [m/s^2];
* ``imu_mounting``: the IMU mounted rotated on the arm, ``f_m = C f``, ``w_m = C w``,
  ``C = A_IB(roll, pitch, yaw)^T`` [rad];
* ``encoder_offset``: the pitch and elevation encoders' zeros, ``angle_read = angle + o`` [rad]
  (travel's zero shows in nothing).

The shares ``w_e`` and ``w_l`` are numbers, not switches, so that a fit can say how much of the full
equations a session shows (1: all of them).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from groundstation.core.frames import a_ib

G = 9.81
#: Table 1 and the corrected motor constant (:mod:`.heli3dof`'s docstring)
L_P, L_H, J_P, J_E, J_L, K_F, V_S0 = 0.175, 0.66, 0.044, 1.03, 1.08, 0.1248, 8.0


@dataclass(frozen=True)
class Heli3dofRig:
    K_f: float = K_F  #: [N/V]
    V_s0: float = V_S0  #: [V]
    a: float = 0.0
    w_e: float = 0.0
    w_l: float = 0.0
    c_p: float = 0.0  #: [1/s]
    c_e: float = 0.0
    c_l: float = 0.0
    tc: float = 0.0  #: [s]
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: [rad/s]
    accel_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: [m/s^2]
    imu_mounting: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: roll, pitch, yaw [rad]
    encoder_offset: tuple[float, float] = (0.0, 0.0)  #: p, e [rad]

    @property
    def linear_dynamics(self) -> bool:
        """Its dynamics are the lab's linear ones with other constants (no trig, lag or offsets
        that a linear model with an input ``V_s - V_s0`` could not hold)."""
        return self.w_e == 0 and self.w_l == 0 and self.tc == 0 and self.a == 0

    def accelerations(self, p, e, pd, ed, ld, V_f, V_b):
        """(p_dd, e_dd, lambda_dd) at these true angles, rates and (lagged) voltages; numbers or
        numpy columns alike."""
        K_f, a = self.K_f, self.a
        F_f, F_b = K_f * (1.0 - a) * V_f, K_f * (1.0 + a) * V_b
        pdd = L_P * (F_b - F_f) / J_P - self.c_p * pd
        cp = 1.0 + self.w_e * (np.cos(p) - 1.0)
        ce = 1.0 + self.w_e * (np.cos(e) - 1.0)
        edd = L_H * (cp * (F_f + F_b) - K_f * self.V_s0 * ce) / J_E - self.c_e * ed
        linear = L_H * K_f * self.V_s0 * p / J_L
        full = L_H * np.cos(e) * (F_f + F_b) * np.sin(p) / J_L
        ldd = (1.0 - self.w_l) * linear + self.w_l * full - self.c_l * ld
        return pdd, edd, ldd

    def mounting(self) -> np.ndarray:
        """C: the IMU's axes from the arm's (``f_m = C f``)."""
        return a_ib(*self.imu_mounting).T

    def as_vehicle(self) -> dict:
        """The ``heli3dof`` section of a vehicle file: angles in degrees, as people read them."""
        d = asdict(self)
        d["imu_mounting_deg"] = [round(math.degrees(x), 4) for x in d.pop("imu_mounting")]
        d["encoder_offset_deg"] = [round(math.degrees(x), 4) for x in d.pop("encoder_offset")]
        d["gyro_bias"], d["accel_bias"] = list(d["gyro_bias"]), list(d["accel_bias"])
        return d

    @classmethod
    def from_vehicle(cls, d: dict) -> Heli3dofRig:
        """From a vehicle file's section (:meth:`as_vehicle`); a name it does not know is a one-line
        error."""
        d = dict(d)
        if "imu_mounting_deg" in d:
            d["imu_mounting"] = tuple(math.radians(x) for x in d.pop("imu_mounting_deg"))
        if "encoder_offset_deg" in d:
            d["encoder_offset"] = tuple(math.radians(x) for x in d.pop("encoder_offset_deg"))
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(
                f"the 3-DOF rig's constants have no {', '.join(unknown)}; known: {', '.join(sorted(known))}"
            )
        for k in ("gyro_bias", "accel_bias", "imu_mounting", "encoder_offset"):
            if k in d:
                d[k] = tuple(float(x) for x in d[k])
        return cls(**d)


def imu_frame(p, e, pd, ed, ld, edd, ldd) -> tuple[np.ndarray, np.ndarray]:
    """The true body rates and specific force (N x 3, FRD) of the IMU ``l_h`` out on the arm, at
    travel 0 (the body-frame values do not depend on travel): the Euler-rate transform of
    (p_dot, e_dot, lambda_dot), and the point's acceleration minus gravity through
    ``R_IB(p, e, 0)^T`` (``heli3dof.arm_acceleration_body``, on columns)."""
    sp, cp, se, ce = np.sin(p), np.cos(p), np.sin(e), np.cos(e)
    w = np.column_stack([pd - se * ld, ce * sp * ld + cp * ed, cp * ce * ld - sp * ed])
    a0 = L_H * (-ce * (ed**2 + ld**2) - se * edd)
    a1 = L_H * (-2 * se * ed * ld + ce * ldd)
    a2 = L_H * (se * ed**2 - ce * edd) - G  # minus gravity (NED, down positive)
    y0, y2 = ce * a0 - se * a2, se * a0 + ce * a2  # Ry(e)^T
    f = np.column_stack([y0, cp * a1 + sp * y2, -sp * a1 + cp * y2])  # Rx(p)^T
    return w, f


#: the routing's input is ``u = (V_s - V_S0, V_d)`` with the lab's V_s0 (estimation.routing): the
#: rig's own V_s0 enters through its dynamics
U_REFERENCE = V_S0


def voltages(u) -> tuple[float, float]:
    """(V_f, V_b) of the input ``u = (V_s - U_REFERENCE, V_d)``."""
    V_s, V_d = float(u[0]) + U_REFERENCE, float(u[1])
    return (V_s - V_d) / 2.0, (V_s + V_d) / 2.0


def dynamics(rig: Heli3dofRig):
    """``f(x, u)`` and its Jacobian over ``x = (p, p_dot, e, e_dot, lambda, lambda_dot)``, with two
    more states ``(V_f, V_b)`` as the motors make them where the rig has a lag (``tc > 0``)."""
    lag = rig.tc > 0.0
    n = 8 if lag else 6
    K, a = rig.K_f, rig.a
    kf, kb = K * (1.0 - a), K * (1.0 + a)

    def motor(x, u) -> tuple[float, float]:
        return (float(x[6]), float(x[7])) if lag else voltages(u)

    def f(x, u):
        p, pd, e, ed, _, ld = (float(v) for v in x[:6])
        V_f, V_b = motor(x, u)
        pdd, edd, ldd = rig.accelerations(p, e, pd, ed, ld, V_f, V_b)
        xd = np.zeros(n)
        xd[0], xd[1], xd[2], xd[3], xd[4], xd[5] = pd, pdd, ed, edd, ld, ldd
        if lag:
            cmd = voltages(u)
            xd[6], xd[7] = (cmd[0] - V_f) / rig.tc, (cmd[1] - V_b) / rig.tc
        return xd

    def jacobian(x, u):
        p, e = float(x[0]), float(x[2])
        V_f, V_b = motor(x, u)
        S = kf * V_f + kb * V_b
        sp, cp_, se, ce_ = math.sin(p), math.cos(p), math.sin(e), math.cos(e)
        cp = 1.0 + rig.w_e * (cp_ - 1.0)
        J = np.zeros((n, n))
        J[0, 1] = J[2, 3] = J[4, 5] = 1.0
        J[1, 1], J[3, 3], J[5, 5] = -rig.c_p, -rig.c_e, -rig.c_l
        J[3, 0] = -L_H * rig.w_e * sp * S / J_E
        J[3, 2] = L_H * K * rig.V_s0 * rig.w_e * se / J_E
        J[5, 0] = ((1.0 - rig.w_l) * L_H * K * rig.V_s0 + rig.w_l * L_H * ce_ * S * cp_) / J_L
        J[5, 2] = -rig.w_l * L_H * se * S * sp / J_L
        if lag:
            J[1, 6], J[1, 7] = -L_P * kf / J_P, L_P * kb / J_P
            J[3, 6], J[3, 7] = L_H * cp * kf / J_E, L_H * cp * kb / J_E
            J[5, 6], J[5, 7] = rig.w_l * L_H * ce_ * sp * kf / J_L, rig.w_l * L_H * ce_ * sp * kb / J_L
            J[6, 6] = J[7, 7] = -1.0 / rig.tc
        return J

    return f, jacobian
