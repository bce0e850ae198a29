"""The simulated autopilot's own height estimate: what it sends as GLOBAL_POSITION_INT and
LOCAL_POSITION_NED and logs as CTUN.Alt, made from its sensors with its parameters, as
ArduCopter's EKF3 makes it by default (``EK3_SRC1_POSZ`` 1: the barometer).

A 3-state Kalman filter, x = [h, v, b] (height and climb rate up [m, m/s], the accelerometer's
bias along the vertical [m/s²]), the same form as the coaxial helicopter document's altitude filter
(its chapter on sensor fusion; there with the range sensor, here with the barometer):

* predict with the IMU's vertical acceleration, a = −(R·f)_z − g (f the specific force in FRD, R
  body to NED): h += v·dt + ½(a − b)·dt², v += (a − b)·dt; F = [[1, dt, −½dt²], [0, 1, −dt],
  [0, 0, 1]]; Q from ArduPilot's default accelerometer noise ``EK3_ACC_P_NSE`` (0.35 m/s²) and
  bias walk ``EK3_ABIAS_P_NSE`` (0.003 m/s³);
* update with the barometer's height, from the pressure less ``BARO1_THST_SCALE`` × throttle, about
  the pressure where it booted (its first readings' mean), R = ``EK3_ALT_M_NSE``², against the
  height ``EK3_HGT_DELAY`` ago
  (the innovation from the past height, the correction applied now, as an EKF fusing on a delayed
  horizon does to first order).

The vehicle flies on the truth (its controllers do not read this estimate), so a wrong estimate
shows as the estimate's error, not as a different flight.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from filterpy.kalman import KalmanFilter

from groundstation.core.atmosphere import altitude_at

from .autopilot_params import AutopilotParams

G = 9.80665
ACC_P_NSE = 0.35  # [m/s^2] EK3_ACC_P_NSE's default
ABIAS_P_NSE = 0.003  # [m/s^3] EK3_ABIAS_P_NSE's default
HISTORY_S = 0.3  # [s] of past heights kept (EK3_HGT_DELAY is at most 250 ms)
#: baro readings averaged for the ground's pressure at boot (as AP_Baro's calibration averages;
#: one reading alone is off by its noise, 0.3 m here)
ZERO_SAMPLES = 20


class OnboardHeight:
    """The filter is filterpy's :class:`~filterpy.kalman.KalmanFilter` (``kf``: x, P, F, B, Q, H, R
    as the document writes them). It is not the ground station's altitude estimator
    (``groundstation.estimation``): the simulator may not import it (the layer contract), and an
    autopilot's estimator is its own."""

    def __init__(self, params: AutopilotParams) -> None:
        self.params = params
        self.kf = KalmanFilter(dim_x=3, dim_z=1, dim_u=1)
        self.kf.P = np.diag([1.0, 0.25, 0.01])
        self.kf.H = np.array([[1.0, 0.0, 0.0]])
        self._dt = 0.0  # the step F, B and Q were made for
        self.t: float | None = None
        self.baro_zero: float | None = None  # [m] the pressure altitude where it booted
        self._zero_n = 0
        self.baro_height = 0.0  # [m] the last corrected baro height
        self._past: deque[tuple[float, float]] = deque()  # (t, h)

    @property
    def height(self) -> float:
        return float(self.kf.x[0, 0])

    @property
    def climb_rate(self) -> float:
        return float(self.kf.x[1, 0])

    def _step(self, dt: float) -> None:
        """F, B and Q for a step of ``dt`` (the IMU's period: made again only when it changes)."""
        kf = self.kf
        kf.F = np.array([[1.0, dt, -0.5 * dt * dt], [0.0, 1.0, -dt], [0.0, 0.0, 1.0]])
        kf.B = np.array([[0.5 * dt * dt], [dt], [0.0]])
        q_a, q_b = (ACC_P_NSE**2) * dt, (ABIAS_P_NSE**2) * dt
        kf.Q = np.array([[0.25 * dt**2 * q_a, 0.5 * dt * q_a, 0.0], [0.5 * dt * q_a, q_a, 0.0], [0.0, 0.0, q_b]])
        self._dt = dt

    def imu(self, t: float, specific_force, R) -> None:
        """A calibrated IMU sample: the specific force in FRD [m/s²] and the attitude (body to NED)."""
        if self.t is None:
            self.t = t
            return
        dt = t - self.t
        self.t = t
        if not 0.0 < dt < 0.1:
            return
        if abs(dt - self._dt) > 1e-9:
            self._step(dt)
        a = -float(R[2] @ np.asarray(specific_force, dtype=float)) - G
        self.kf.predict(u=np.array([[a]]))
        self._past.append((t, self.height))
        while self._past and self._past[0][0] < t - HISTORY_S:
            self._past.popleft()

    def baro(self, t: float, pressure: float, throttle: float) -> None:
        """A baro sample [Pa], with the motors' throttle (0..1) when it was read."""
        p = pressure - self.params["BARO1_THST_SCALE"] * max(0.0, throttle)
        alt = float(altitude_at(p))
        if self._zero_n < ZERO_SAMPLES:  # the ground's pressure altitude: the mean of the first readings
            self._zero_n += 1
            self.baro_zero = alt if self.baro_zero is None else self.baro_zero + (alt - self.baro_zero) / self._zero_n
        assert self.baro_zero is not None
        self.baro_height = z = alt - self.baro_zero
        delay = self.params["EK3_HGT_DELAY"] * 1e-3
        # against the height ``delay`` ago: the reading moved by what the height did since then
        lag = self.height - self._height_at(t - delay) if delay > 0 else 0.0
        self.kf.update(np.array([[z + lag]]), R=self.params["EK3_ALT_M_NSE"] ** 2)

    def _height_at(self, t: float) -> float:
        for tp, h in reversed(self._past):
            if tp <= t:
                return h
        return self._past[0][1] if self._past else self.height
