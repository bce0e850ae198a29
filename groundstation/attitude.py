"""Roll and pitch from gyro and accelerometer: the complementary filter of the
coaxial-helicopter document (chapter 8) and an EKF as the stronger alternative.

Both read the same measurements: body rates (GYRO) as the "velocity" sensor,
and the attitude the accelerometer's gravity vector gives as the "position"
sensor (valid when the vehicle is not accelerating)::

    roll_a  = atan2(-f_y, -f_z),   pitch_a = atan2(f_x, sqrt(f_y^2 + f_z^2))     (FRD, at rest f = -g_body)
    Euler rates: roll_dot  = p + (q sin(roll) + r cos(roll)) tan(pitch)
                 pitch_dot = q cos(roll) - r sin(roll)

Complementary filter (eq. 8.3-8.5)::

    S_o(s) = w_c / (s + w_c) S(s) + 1 / (s + w_c) V(s)

discretised exactly for a held input over T: ``s_o <- e^{-w_c T} s_o +
(1 - e^{-w_c T}) (s + v / w_c)``. Correction: the document calls eq. 8.5's
second entry ``s / ((s + w_c) s)``; it is ``HP(s) I(s) = 1 / (s + w_c)``, as it
then writes. A gyro bias b passes through as a steady error b / w_c: the
filter has no way to learn it.

The EKF (state roll, pitch, b_p, b_q) integrates the bias-corrected rates and
updates with the accelerometer attitude (filterpy's
``ExtendedKalmanFilter.update``), with the measurement variance inflated when
the specific force's magnitude departs from g (the vehicle accelerates). The
yaw-rate bias is left out: gravity says nothing about yaw, so it would only
random-walk. Neither filter can do better than the accelerometer's attitude in
sustained accelerated flight: on a multirotor the specific force follows the
thrust, not gravity.
"""
from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from .measurement import Kind, Measurement

G = 9.80665


def accel_attitude(f) -> tuple[float, float]:
    fx, fy, fz = f
    return math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))


def euler_rates(roll: float, pitch: float, w) -> tuple[float, float]:
    p, q, r = w
    return (p + (q * math.sin(roll) + r * math.cos(roll)) * math.tan(pitch),
            q * math.cos(roll) - r * math.sin(roll))


class ComplementaryFilter:
    """Chapter 8, per axis (roll, pitch); ``w_c`` the crossover [rad/s]."""

    name = "complementary"

    def __init__(self, w_c: float = 1.0) -> None:
        self.w_c = w_c
        self.x: np.ndarray | None = None          # roll, pitch
        self.t = math.nan
        self._s = None                            # latest accelerometer attitude

    def handle(self, m: Measurement) -> None:
        if m.instance != 0:
            return
        if m.kind is Kind.ACCEL:
            self._s = np.array(accel_attitude(m.value))
            if self.x is None:
                self.x, self.t = self._s.copy(), m.t
        elif m.kind is Kind.GYRO and self.x is not None and self._s is not None:
            T = m.t - self.t
            if T <= 0:
                return
            v = np.array(euler_rates(self.x[0], self.x[1], m.value))
            a = math.exp(-self.w_c * T)
            self.x = a * self.x + (1 - a) * (self._s + v / self.w_c)
            self.t = m.t


class AttitudeEKF:
    """Roll, pitch and gyro biases; gyro rates in, accelerometer attitude as measurement."""

    name = "attitude_ekf"

    def __init__(self, *, gyro_noise: float = 0.005, bias_walk: float = 1e-4, accel_sigma: float = 0.03,
                 P0_bias: float = 0.05) -> None:
        self.ekf = ExtendedKalmanFilter(dim_x=4, dim_z=2)
        self.ekf.P = np.diag([0.1, 0.1, P0_bias**2, P0_bias**2])
        self.q_rate, self.q_bias, self.accel_sigma = gyro_noise**2, bias_walk**2, accel_sigma
        self.t = math.nan
        self.started = False
        self._f = None

    @property
    def x(self) -> np.ndarray:
        return self.ekf.x[:2]

    def handle(self, m: Measurement) -> None:
        if m.instance != 0:
            return
        if m.kind is Kind.ACCEL:
            self._f = m.value
            if not self.started:
                self.ekf.x = np.array([*accel_attitude(m.value), 0.0, 0.0])
                self.t, self.started = m.t, True
            else:
                self._update(m.value)
        elif m.kind is Kind.GYRO and self.started:
            self._predict(m.value, m.t)

    def _predict(self, w, t: float) -> None:
        T = t - self.t
        if T <= 0:
            return
        e = self.ekf
        roll, pitch, bp, bq = e.x
        p, q, r = w[0] - bp, w[1] - bq, w[2]
        sr, cr, tp = math.sin(roll), math.cos(roll), math.tan(pitch)
        sec2 = 1.0 / math.cos(pitch) ** 2
        rd = p + (q * sr + r * cr) * tp
        pd = q * cr - r * sr
        e.x = e.x + T * np.array([rd, pd, 0.0, 0.0])
        J = np.zeros((4, 4))
        J[0, 0] = (q * cr - r * sr) * tp
        J[0, 1] = (q * sr + r * cr) * sec2
        J[0, 2:] = [-1.0, -sr * tp]
        J[1, 0] = -q * sr - r * cr
        J[1, 3] = -cr
        F = np.eye(4) + T * J
        Q = np.diag([self.q_rate * T, self.q_rate * T, self.q_bias * T, self.q_bias * T])
        e.P = F @ e.P @ F.T + Q
        self.t = t

    def _update(self, f) -> None:
        dyn = abs(math.sqrt(f[0] ** 2 + f[1] ** 2 + f[2] ** 2) - G)
        sigma = self.accel_sigma + 0.5 * dyn        # trust gravity less while accelerating
        H = np.zeros((2, 4))
        H[0, 0] = H[1, 1] = 1.0
        self.ekf.update(np.array(accel_attitude(f)), HJacobian=lambda x: H, Hx=lambda x: x[:2],
                        R=np.eye(2) * sigma**2)
