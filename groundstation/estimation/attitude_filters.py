"""Roll and pitch from gyro and accelerometer: three standalone filters on filterpy.

* :class:`ComplementaryFilter` and :class:`AttitudeEKF` read gravity from the accelerometer
  (the coaxial-helicopter document, chapter 8, and its EKF alternative);
* :class:`DragAttitudeEKF` reads the rotor drag instead, which is what a multirotor's
  accelerometer sees in flight (Leishman et al. 2014).

The declared-model form of the drag filter, which the diagnosis extends, is
:mod:`groundstation.estimation.models.attitude_drag`.

Gravity-vector filters
----------------------
The complementary filter of the coaxial-helicopter document (chapter 8) and an EKF as the
stronger alternative. Both read the same measurements: body rates (GYRO) as the "velocity" sensor,
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

The rotor-drag EKF
------------------
Why a third attitude filter: on a multirotor the accelerometer does not see
gravity in flight. Its specific force is thrust plus drag, ``f = T_b/m - mu v_b``,
so the gravity-direction attitude of the filters above reads
"level" whatever the tilt, and an EKF that takes it as a measurement is wrong by
the tilt itself (3-4 deg RMS and NEES > 100 on simulated flights). Leishman,
Macdonald, Beard and McLain (IEEE Control Systems Magazine 34(1), 2014,
"Quadrotors and accelerometers: state estimation with an improved dynamic
model") use what the accelerometer does see: the horizontal body velocity,
through the drag. The velocity's dynamics carry the tilt, so the tilt becomes
observable.

State ``x = (phi, theta, b_p, b_q, u, v)``: roll, pitch [rad], roll- and
pitch-rate gyro biases [rad/s], body-frame (FRD) horizontal velocity [m/s].
Inputs: the gyro rates ``(p, q, r)``. With ``w`` the body-z velocity (not a
state: its term ``q w`` is process noise)::

    phi_dot   = p~ + (q~ sin(phi) + r cos(phi)) tan(theta)      p~ = p - b_p, q~ = q - b_q
    theta_dot = q~ cos(phi) - r sin(phi)
    u_dot     = -g sin(theta) + r v - mu u          (- q w)
    v_dot     =  g sin(phi) cos(theta) - r u - mu v  (+ p w)

    accelerometer:  f_x = -mu u,   f_y = -mu v        (thrust acts along body z only)

``mu`` [1/s] is the linear drag over mass (the vehicle file's; the simulated
quadcopter's is 0.35). The prediction is first order at the gyro rate (500 Hz
and more) with the Jacobian below; the update is filterpy's
``ExtendedKalmanFilter.update`` (the measurement is linear), whose equations (K = P H^T S^-1,
Joseph's P) :func:`.kernels_numba.vector_update` computes as loops where numba is: at the
accelerometer's 500 Hz filterpy's call, its inverse and its copies were two thirds of a run.
``GROUNDSTATION_KERNELS=python`` runs filterpy's, the reference ``tests/test_attitude.py`` holds
the compiled one to.
"""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from groundstation.core.frames import accel_attitude, euler_rates
from groundstation.core.measurement import Kind, Measurement
from groundstation.core.units import G

from . import kernels


class ComplementaryFilter:
    """Chapter 8, per axis (roll, pitch); ``w_c`` the crossover [rad/s]."""

    name = "complementary"

    def __init__(self, w_c: float = 1.0) -> None:
        self.w_c = w_c
        self.x: np.ndarray | None = None  # roll, pitch
        self.t = math.nan
        self._s: np.ndarray | None = None  # latest accelerometer attitude

    def handle(self, m: Measurement) -> None:
        if m.instance != 0:
            return
        if m.kind is Kind.ACCEL:
            s = self._s = np.array(accel_attitude(m.value))
            if self.x is None:
                self.x, self.t = s.copy(), m.t
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

    def __init__(
        self, *, gyro_noise: float = 0.005, bias_walk: float = 1e-4, accel_sigma: float = 0.03, P0_bias: float = 0.05
    ) -> None:
        self.ekf = ExtendedKalmanFilter(dim_x=4, dim_z=2)
        self.ekf.P = np.diag([0.1, 0.1, P0_bias**2, P0_bias**2])
        self.q_rate, self.q_bias, self.accel_sigma = gyro_noise**2, bias_walk**2, accel_sigma
        self.t = math.nan
        self.started = False

    @property
    def x(self) -> np.ndarray:
        return self.ekf.x[:2]

    def handle(self, m: Measurement) -> None:
        if m.instance != 0:
            return
        if m.kind is Kind.ACCEL:
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
        sigma = self.accel_sigma + 0.5 * dyn  # trust gravity less while accelerating
        H = np.zeros((2, 4))
        H[0, 0] = H[1, 1] = 1.0
        self.ekf.update(np.array(accel_attitude(f)), HJacobian=lambda x: H, Hx=lambda x: x[:2], R=np.eye(2) * sigma**2)


class DragAttitudeEKF:
    """Multirotor roll/pitch EKF with gyro biases and body velocity (rotor-drag model)."""

    name = "drag_ekf"
    states = ("roll", "pitch", "b_p", "b_q", "u", "v")

    def __init__(
        self,
        *,
        mu: float = 0.35,
        gyro_noise: float = 2.2e-4,
        bias_walk: float = 3e-6,
        accel_sigma: float = 0.09,
        G_v: float = 2e-4,
        P0_angle: float = 0.05,
        P0_bias: float = 0.05,
        P0_v: float = 0.2,
    ) -> None:
        """Noise as densities: ``gyro_noise`` [rad/s/sqrt(Hz)] (0.005 rad/s per sample at 500 Hz),
        ``bias_walk`` [rad/s/sqrt(s)], ``G_v`` [(m/s^2)^2/Hz] for what the velocity model
        leaves out (the ``q w`` terms, gusts); ``accel_sigma`` [m/s^2] per sample. The
        defaults put NEES and NIS in their 95 % bands over 20 simulated flights."""
        self.mu = mu
        self.ekf = ExtendedKalmanFilter(dim_x=6, dim_z=2)
        self.ekf.P = np.diag([P0_angle**2] * 2 + [P0_bias**2] * 2 + [P0_v**2] * 2)
        self.ekf.R = np.eye(2) * accel_sigma**2
        self.q = np.array([gyro_noise**2] * 2 + [bias_walk**2] * 2 + [G_v] * 2)  # densities
        self.H = np.zeros((2, 6))
        self.H[0, 4] = self.H[1, 5] = -mu
        self.t = math.nan
        self.started = False
        self.nis: list[float] = []  # per accelerometer update
        kernels.ready()  # its update is compiled: loaded here, not at a live loop's first reading

    @property
    def x(self) -> np.ndarray:
        return self.ekf.x[:2]

    @property
    def P(self) -> np.ndarray:
        return self.ekf.P

    def handle(self, m: Measurement) -> None:
        if m.instance != 0:
            return
        if m.kind is Kind.ACCEL:
            if not self.started:
                # at rest: gravity gives the attitude, the vehicle is still
                self.ekf.x = np.array([*accel_attitude(m.value), 0.0, 0.0, 0.0, 0.0])
                self.t, self.started = m.t, True
            else:
                self._update(np.array(m.value[:2], dtype=float))
        elif m.kind is Kind.GYRO and self.started:
            self._predict(m.value, m.t)

    def _update(self, z: np.ndarray) -> None:
        e = self.ekf
        k = kernels.compiled()
        if k is None:
            e.update(z, HJacobian=lambda x: self.H, Hx=lambda x: self.H @ x)
            self.nis.append(float(e.y @ np.linalg.solve(e.S, e.y)))
            return
        x, P, K, S, y, nis, ok = k[3](np.asarray(e.x, dtype=float), np.ascontiguousarray(e.P), self.H, e.R, z)
        if not ok:  # as filterpy's inverse of S would
            raise np.linalg.LinAlgError("singular innovation covariance")
        e.x, e.P, e.K, e.S, e.y = x, P, K, S, y
        self.nis.append(float(nis))

    def _predict(self, w, t: float) -> None:
        T = t - self.t
        if T <= 0:
            return
        e, mu = self.ekf, self.mu
        phi, theta, bp, bq, u, v = e.x
        p, q, r = w[0] - bp, w[1] - bq, w[2]
        sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta)
        tt, sec2 = st / ct, 1.0 / ct**2
        xd = np.array(
            [*euler_rates(phi, theta, (p, q, r)), 0.0, 0.0, -G * st + r * v - mu * u, G * sf * ct - r * u - mu * v]
        )
        J = np.zeros((6, 6))
        J[0, 0], J[0, 1], J[0, 2], J[0, 3] = (q * cf - r * sf) * tt, (q * sf + r * cf) * sec2, -1.0, -sf * tt
        J[1, 0], J[1, 3] = -q * sf - r * cf, -cf
        J[4, 1], J[4, 4], J[4, 5] = -G * ct, -mu, r
        J[5, 0], J[5, 1], J[5, 4], J[5, 5] = G * cf * ct, -G * sf * st, -r, -mu
        F = np.eye(6) + T * J
        e.x = e.x + T * xd
        e.P = F @ e.P @ F.T + np.diag(self.q * T)
        self.t = t
