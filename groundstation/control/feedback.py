"""Where a controller's state comes from: the lab's four feedback sources, and the altitude filter.

Every source takes the measurements as they arrive (``feed(m)``) and gives the
state by name (``state()``), or ``None`` until it has one. The lab document
(sec. 4-5) compares them on the 3-DOF helicopter:

* :class:`EncoderFeedback`: p, e, lambda from the encoders; their rates by a
  filtered difference (time constant ``tau_d``: the encoders' 1.5 mrad steps
  over 2 ms would otherwise be 0.2 rad/s of noise on the rates);
* :class:`ImuFeedback`: the raw IMU, p and e from the gravity direction
  (eq. 51-52, on the raw specific force as the lab reads it), the rates from
  the gyro through the Euler-rate transform (the lab's "Euler block", eq. 47);
* :class:`KalmanFeedback`: the lab's discrete Kalman filter on the IMU
  (:func:`groundstation.estimation.routing.heli3dof_estimator`, encoders left out as
  in the lab's flight), fed the commanded voltages as its input;
* :class:`PredictorFeedback`: the open-loop predictor, the linear model
  (eq. 14-16) integrated from the commanded voltages alone, exactly
  (zero-order hold) from a known start.

:class:`EstimatorFeedback` gives any estimator's state (the altitude filters
for the altitude hold), plus the attitude the thrust model needs.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from groundstation.core.measurement import Kind, Measurement
from groundstation.core.validity import reading_problem
from groundstation.estimation.estimator import KalmanEstimator
from groundstation.estimation.models.heli3dof import STATES, V_S0, euler_rates, matrices
from groundstation.estimation.routing import heli3dof_estimator


class Feedback:
    name = "feedback"
    #: what it reads (the commander also feeds it its own commands as MOTOR_VOLTAGE)
    kinds: frozenset[Kind] = frozenset()

    def feed(self, m: Measurement) -> None:
        """Take one measurement."""

    def state(self) -> dict[str, float] | None:
        """The state by name, or None before the first usable measurement."""
        return None


class EncoderFeedback(Feedback):
    name = "encoders"
    kinds = frozenset({Kind.ENCODERS, Kind.ATTITUDE})

    def __init__(self, tau_d: float = 0.01) -> None:
        self.tau_d = tau_d
        self._x: dict[str, float] | None = None
        self._prev: tuple[float, np.ndarray] | None = None
        self._rates = np.zeros(3)

    def feed(self, m):
        if m.kind not in self.kinds:
            return
        # MAVLink ATTITUDE from a 3-DOF rig carries (p, e, lambda) as roll, pitch, yaw
        ang = np.asarray(m.value[:3], dtype=float)
        if self._prev is not None:
            t0, a0 = self._prev
            dt = m.t - t0
            if dt <= 0:
                return
            k = dt / (self.tau_d + dt)
            self._rates += k * ((ang - a0) / dt - self._rates)
        self._prev = (m.t, ang)
        p, e, lam = ang
        self._x = {
            "p": p,
            "e": e,
            "lambda": lam,
            "p_dot": self._rates[0],
            "e_dot": self._rates[1],
            "lambda_dot": self._rates[2],
        }

    def state(self):
        return self._x


class ImuFeedback(Feedback):
    name = "imu"
    kinds = frozenset({Kind.ACCEL, Kind.GYRO})

    def __init__(self) -> None:
        self._pe: tuple[float, float] | None = None
        self._x: dict[str, float] | None = None
        self._lam = 0.0
        self._t: float | None = None

    def feed(self, m):
        if m.kind is Kind.ACCEL:
            fx, fy, fz = (float(v) for v in m.value[:3])
            self._pe = (math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz)))  # eq. 51, 52
        elif m.kind is Kind.GYRO and self._pe is not None:
            p, e = self._pe
            pd, ed, ld = euler_rates(p, e, m.value[:3])
            if self._t is not None and m.t > self._t:
                self._lam += ld * (m.t - self._t)  # travel has no absolute IMU reading
            self._t = m.t
            self._x = {"p": p, "e": e, "lambda": self._lam, "p_dot": pd, "e_dot": ed, "lambda_dot": ld}

    def state(self):
        return self._x


class KalmanFeedback(Feedback):
    name = "kalman"
    kinds = frozenset({Kind.ACCEL, Kind.GYRO, Kind.MOTOR_VOLTAGE})

    def __init__(self, estimator: KalmanEstimator | None = None) -> None:
        self.estimator = estimator or heli3dof_estimator()

    def feed(self, m):
        if m.kind in self.kinds:
            self.estimator.handle(m)

    def state(self):
        est = self.estimator
        if not est.started:
            return None
        return dict(zip(est.model.states, map(float, est.filter.x)))


class PredictorFeedback(Feedback):
    """Open loop: x(t) from x(t0) and the commands alone (the lab's model-only prediction).

    The start is known (resting on the table, or given); after that nothing
    measured enters, so every model error integrates, as the lab's figures 2-4 show.
    """

    name = "predictor"
    kinds = frozenset({Kind.MOTOR_VOLTAGE, Kind.ENCODERS, Kind.ACCEL, Kind.GYRO})

    def __init__(self, x0: np.ndarray | None = None) -> None:
        self.A, self.B = matrices()
        n, k = self.B.shape
        self._M = np.zeros((n + k, n + k))
        self._M[:n, :n], self._M[:n, n:] = self.A, self.B
        self.x = np.array([0.0, 0.0, -0.5, 0.0, 0.0, 0.0]) if x0 is None else np.asarray(x0, float)
        self.u = np.zeros(k)
        self.t: float | None = None  # time of self.x
        self._t_now: float | None = None  # newest time a measurement gave

    def _propagate(self, t: float) -> None:
        if self.t is None:
            self.t = t
            return
        dt = t - self.t
        if dt <= 0:
            return
        n = self.A.shape[0]
        Phi = scipy.linalg.expm(self._M * dt)
        self.x = Phi[:n, :n] @ self.x + Phi[:n, n:] @ self.u
        self.t = t

    def feed(self, m):
        if m.kind not in self.kinds:
            return
        # measurements only tell the time; the model is integrated when the input
        # changes or the state is asked for (not at every IMU sample)
        self._t_now = m.t if self._t_now is None else max(self._t_now, m.t)
        if m.kind is Kind.MOTOR_VOLTAGE:
            self._propagate(m.t)
            vf, vb = float(m.value[0]), float(m.value[1])
            self.u = np.array([vf + vb - V_S0, vb - vf])

    def state(self):
        if self._t_now is None:
            return None
        self._propagate(self._t_now)
        return dict(zip(STATES, map(float, self.x)))


class EstimatorFeedback(Feedback):
    """Any estimator's state by its model's names, with the latest roll and pitch."""

    def __init__(self, estimator: KalmanEstimator) -> None:
        self.estimator = estimator
        self.name = estimator.name
        self.kinds = frozenset(estimator.kinds | {Kind.ATTITUDE})
        self._att = (0.0, 0.0)

    def feed(self, m):
        if m.kind is Kind.ATTITUDE and reading_problem(m) is None:  # the estimator rejects it too
            self._att = (float(m.value[0]), float(m.value[1]))
        if m.kind in self.estimator.kinds:
            self.estimator.handle(m)

    def state(self):
        est = self.estimator
        if not est.started:
            return None
        x = dict(zip(est.model.states, map(float, est.filter.x)))
        x["roll"], x["pitch"] = self._att
        return x


FEEDBACK_3DOF = {
    "encoders": EncoderFeedback,
    "kalman": KalmanFeedback,
    "imu": ImuFeedback,
    "predictor": PredictorFeedback,
}
