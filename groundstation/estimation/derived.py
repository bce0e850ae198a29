"""Measurements derived from others, for logs that lack them.

:func:`with_attitude` inserts ATTITUDE (roll, pitch) from the gyro for logs
with an IMU but no attitude (Crazyflie uSD logs): the altitude filter needs the
tilt to turn specific force into vertical acceleration, and the range sensor's
slant (``range_tilt``) needs it to be right. The derived measurements are
marked by their source (``derived/gyro``); truth is never used.

Why not the accelerometer. The complementary filter of the coaxial document's
chapter 8 (:class:`~groundstation.estimation.attitude_filters.ComplementaryFilter`) takes the
accelerometer's gravity vector as its "position" sensor. On a multirotor in
flight the specific force follows the thrust, not gravity (its horizontal part
is rotor drag, a few tenths of a m/s^2), so that sensor reads a tilted vehicle
as nearly level. And the 0425 Crazyflie logs' accelerometer reads 1.2-1.9 m/s^2
in x on the pad and in flight while Vicon says level (the data README), 7-11 deg
of false tilt. With its 1 rad/s crossover the filter was 7-12 deg RMS off Vicon
on those two logs, and 1/(cos roll cos pitch) was twice as far off as the slant
it should correct (traj4: 32e-3 RMS against 17e-3).

What is used instead: the gyro's body rates integrated to Euler angles
(:func:`~groundstation.core.frames.euler_rates`), and the gyro's bias removed as the
straight line over the whole log that the integrated roll and pitch drift
along. That line is the tilt's mean and trend, and a multirotor's tilt has
neither over a flight that starts and ends at rest where it took off, heading
held, in still air: its horizontal acceleration, g tan(tilt) less the drag,
integrates to the change of speed (0), and t times it to the change of position
less the start's speed times the flight's length (0). Pad time, level, adds
nothing to either. The drag's part of the trend, mu times the mean
displacement, is left. It is not causal (a log is read whole) and it is meant
for lab logs; an outdoor autopilot logs its own attitude. Against Vicon in
flight on the three Crazyflie logs: roll 0.55-0.77 deg RMS, pitch 0.33-0.79 deg;
on traj4 1/(cos roll cos pitch) is 2.3e-3 RMS off the true, whose own departure
from 1 is 16.9e-3 RMS.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from groundstation.core.frames import euler_rates
from groundstation.core.measurement import Kind, Measurement


def gyro_attitude(t: np.ndarray, w: np.ndarray, *, passes: int = 3) -> np.ndarray:
    """Roll and pitch [rad] at the gyro's samples ``t`` (body rates ``w``, n x 3).

    Euler rates integrated (forward Euler at the gyro's rate; at 1 kHz the step
    is 1e-6 rad at 1 rad/s), then the fitted line a + b (t - t0) of each angle
    removed: b is the gyro's bias on that axis (at small tilt the roll and pitch
    rates are p and q), -a the start's tilt. The Euler rates depend on the angles,
    so each pass integrates again from the start's tilt with the bias taken out
    of p and q, and fits what is left.
    """
    x0, bias = np.zeros(2), np.zeros(3)
    for _ in range(passes):
        x = _integrate(t, w - bias, x0)
        line = np.linalg.lstsq(np.column_stack([np.ones(len(t)), t - t[0]]), x, rcond=None)[0]
        x0, bias[:2] = x0 - line[0], bias[:2] + line[1]
    return x - np.column_stack([np.ones(len(t)), t - t[0]]) @ line


def _integrate(t: np.ndarray, w: np.ndarray, x0: np.ndarray) -> np.ndarray:
    x = np.empty((len(t), 2))
    roll, pitch = x[0] = x0
    for k in range(1, len(t)):
        d_roll, d_pitch = euler_rates(roll, pitch, w[k - 1])
        dt = t[k] - t[k - 1]
        roll += d_roll * dt
        pitch += d_pitch * dt
        x[k] = roll, pitch
    return x


def with_attitude(ms: Iterable[Measurement], *, rate: float = 100.0) -> list[Measurement]:
    """``ms`` with ATTITUDE inserted at ``rate`` [Hz] from the gyro (instance 0)."""
    ms = list(ms)
    gyro = [(i, m) for i, m in enumerate(ms) if m.kind is Kind.GYRO and m.instance == 0]
    gyro = [(i, m) for i, m in gyro if np.all(np.isfinite(m.value))]
    if len(gyro) < 3:
        return ms
    t = np.array([m.t for _, m in gyro])
    # a clock that stands still or steps back adds no rate: keep the samples past every earlier one
    keep = t > np.maximum.accumulate(np.concatenate([[-np.inf], t[:-1]]))
    gyro = [g for g, k in zip(gyro, keep) if k]
    t = t[keep]
    x = gyro_attitude(t, np.array([m.value for _, m in gyro]))
    insert: dict[int, Measurement] = {}
    next_t = -np.inf
    for (i, m), (roll, pitch) in zip(gyro, x):
        if m.t >= next_t:
            next_t = m.t + 1.0 / rate
            insert[i] = Measurement(m.t, Kind.ATTITUDE, np.array([roll, pitch, 0.0]), "derived/gyro.1", m.t_rx)
    out: list[Measurement] = []
    for i, m in enumerate(ms):
        if i in insert:
            out.append(insert[i])
        out.append(m)
    return out
