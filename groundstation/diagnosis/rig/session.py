"""A 3-DOF helicopter session as the rig's identification reads it: uniform columns of the encoder
angles and their derivatives, the motor voltages and the IMU, and where the rig flew free.

The encoders are the rig's truth (4096 counts a turn, 1.5 mrad). They are smoothed by a Gaussian
(``scipy.ndimage.gaussian_filter1d``, standard deviation ``SMOOTH_S``) and differentiated by central
differences; the same Gaussian smooths every column they are compared with (the voltages, the gyro,
the accelerometer). The second difference of the smoothed angle is the smoothed acceleration
(``(g * x)'' = g * x''``, to (w dt)^2 / 12, 1e-4 at 3 Hz), so an equation ``e_dd = K2 (V_s - V_s0)``
holds between the filtered quantities as between the raw ones (a linear filter commutes with a
linear model). Two filters that only look alike do not: a Savitzky-Golay second derivative does not
share its own smoothing's response (beside it, a 50 ms motor lag reads 30 ms), and scipy's sampled
Gaussian-derivative kernels are not normalised (a constant 30 rad comes out as -18 rad/s^2). What the filter does to the
nonlinear terms (cos p V_s) over 40 ms is far below the terms themselves.

Contact: on the table or an end stop the encoder stands still while the lab's model asks for an
acceleration the stop takes up; those samples, and ``GUARD_S`` either side, are not free flight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter1d

from groundstation.core.imu import ImuColumns
from groundstation.core.measurement import Kind, Measurement
from groundstation.estimation.models.heli3dof import K_F, V_S0, gains
from groundstation.estimation.routing import V_MAX_3DOF

SMOOTH_S = 0.04  #: [s] the Gaussian's standard deviation (-3 dB at 3.3 Hz; the rig's closed loop moves at 1-3 Hz)
GUARD_S = 0.5  #: [s] kept off either side of a contact
STILL = 0.01  #: [rad/s] an axis this slow is standing still
#: [rad/s^2] an acceleration the lab's model asks for while the axis stands still: a stop holds it
#: (6 V of V_s below the hover's on elevation; the pitch's own scale is 30 times the elevation's)
HELD = {"p": 3.0, "e": 0.5}
#: [s] a stop holds the axis this long at least (a lagging motor holds it back for a few tens of ms)
HELD_FOR_S = 0.2
#: [V] below this sum the motors are off and the rig rests on the table
MOTORS_OFF = 1.0


@dataclass
class RigSession:
    """Columns on one uniform clock ``t`` [s]. Angles [rad], rates [rad/s], accelerations [rad/s^2],
    voltages [V], gyro [rad/s] and accelerometer [m/s^2] in the IMU's FRD frame (None where the log
    has no IMU), all smoothed by the same filter; ``free``: the rig flew free there."""

    t: np.ndarray
    angle: dict[str, np.ndarray]  #: "p", "e", "lambda" (encoders, travel unwrapped)
    rate: dict[str, np.ndarray]
    accel: dict[str, np.ndarray]
    V_f: np.ndarray
    V_b: np.ndarray
    gyro: np.ndarray | None
    specific_force: np.ndarray | None
    free: np.ndarray
    dt: float
    source: str = ""
    #: the IMU as read (interpolated, not smoothed), for its noise
    gyro_raw: np.ndarray | None = None
    specific_force_raw: np.ndarray | None = None
    #: [rad] the encoders' step (their resolution), read from the readings
    encoder_step: float = 0.0
    notes: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def seconds_free(self) -> float:
        return float(self.free.sum()) * self.dt


def _series(ms, kinds: tuple[Kind, ...]) -> tuple[np.ndarray, np.ndarray] | None:
    """(times, values) of the first of ``kinds`` the readings hold."""
    for kind in kinds:
        rows = [(m.t, *np.asarray(m.value, dtype=float)[:3]) for m in ms if m.kind is kind]
        if rows:
            a = np.array(rows, dtype=float)
            keep = np.isfinite(a).all(axis=1)
            a = a[keep]
            order = np.argsort(a[:, 0], kind="stable")
            a = a[order]
            _, first = np.unique(a[:, 0], return_index=True)  # one reading a time stamp
            a = a[first]
            if len(a) >= 2:
                return a[:, 0], a[:, 1:]
    return None


def _voltages(ms) -> tuple[np.ndarray, np.ndarray] | None:
    """(times, (V_f, V_b)): MOTOR_VOLTAGE in volts, or ACTUATOR outputs (0-1) times the rig's range."""
    rows = [(m.t, float(m.value[0]), float(m.value[1])) for m in ms if m.kind is Kind.MOTOR_VOLTAGE]
    if not rows:
        rows = [
            (m.t, float(m.value[0]) * V_MAX_3DOF, float(m.value[1]) * V_MAX_3DOF)
            for m in ms
            if m.kind is Kind.ACTUATOR and len(m.value) >= 2
        ]
    if len(rows) < 2:
        return None
    a = np.array(rows, dtype=float)
    a = a[np.isfinite(a).all(axis=1)]
    a = a[np.argsort(a[:, 0], kind="stable")]
    return a[:, 0], a[:, 1:]


def _held(t_src: np.ndarray, v: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``v`` held from each of its times to the next (a command stays until the next)."""
    i = np.clip(np.searchsorted(t_src, t, side="right") - 1, 0, len(t_src) - 1)
    return v[i]


def _imu(imu: ImuColumns | None, ms, kind: Kind, t: np.ndarray) -> np.ndarray | None:
    """The IMU's ``kind`` interpolated onto ``t`` (from the columns, or from the records)."""
    s = imu.get(kind) if imu is not None else None
    if s is not None and len(s) >= 2:
        ts, vs = np.asarray(s.t, dtype=float), s.values().astype(float)
    else:
        got = _series(ms, (kind,))
        if got is None:
            return None
        ts, vs = got
    order = np.argsort(ts, kind="stable")
    ts, vs = ts[order], vs[order]
    return np.column_stack([np.interp(t, ts, vs[:, i]) for i in range(3)])


def _second_difference(x: np.ndarray, dt: float) -> np.ndarray:
    out = np.empty_like(x)
    out[1:-1] = (x[2:] - 2.0 * x[1:-1] + x[:-2]) / dt**2
    out[0], out[-1] = out[1], out[-2]
    return out


def _step(angles: np.ndarray) -> float:
    """The encoders' resolution: the smallest change between readings (pitch and elevation)."""
    d = np.abs(np.diff(angles[:, :2], axis=0)).ravel()
    d = d[d > 1e-9]
    return float(d.min()) if len(d) else 0.0


def _lasting(x: np.ndarray, n: int) -> np.ndarray:
    """``x`` where it holds for ``n`` samples in a row or more."""
    out = np.zeros_like(x)
    d = np.diff(np.concatenate([[0], x.astype(np.int8), [0]]))
    for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)):
        if b - a >= n:
            out[a:b] = True
    return out


def _edge(dt: float) -> int:
    """Samples at either end where the filter reads past the session (extended by its end values)."""
    return int(math.ceil(4 * SMOOTH_S / dt))


def read_session(ms: list[Measurement], imu: ImuColumns | None = None, *, source: str = "") -> RigSession:
    """The rig's columns from a session's readings: encoders (ENCODERS, or ATTITUDE as the rig sends
    them over MAVLink), motor voltages, and the IMU. One-line ValueError where they are missing."""
    enc = _series(ms, (Kind.ENCODERS, Kind.ATTITUDE))
    if enc is None:
        raise ValueError("the 3-DOF helicopter's diagnosis needs its encoders (ENCODERS, or ATTITUDE from the rig)")
    volts = _voltages(ms)
    if volts is None:
        raise ValueError("the 3-DOF helicopter's diagnosis needs the motor voltages (MOTOR_VOLTAGE or the outputs)")
    te, angles = enc
    dt = float(np.median(np.diff(te)))
    if not dt > 0:
        raise ValueError("the encoder readings have no usable clock")
    t0, t1 = max(te[0], volts[0][0]), te[-1]
    t = t0 + dt * np.arange(int((t1 - t0) / dt) + 1)
    if len(t) < 10 * _edge(dt):
        raise ValueError(f"the session is too short to identify the rig: {t[-1] - t[0]:.1f} s of encoders")
    sigma = SMOOTH_S / dt

    def smooth(x: np.ndarray) -> np.ndarray:
        return gaussian_filter1d(x, sigma, axis=0, mode="nearest")

    raw = {
        "p": np.interp(t, te, angles[:, 0]),
        "e": np.interp(t, te, angles[:, 1]),
        "lambda": np.interp(t, te, np.unwrap(angles[:, 2])),
    }
    angle = {k: smooth(v) for k, v in raw.items()}
    rate = {k: np.gradient(v, dt) for k, v in angle.items()}
    accel = {k: _second_difference(v, dt) for k, v in angle.items()}
    V = _held(volts[0], volts[1], t)
    gyro = _imu(imu, ms, Kind.GYRO, t)
    f = _imu(imu, ms, Kind.ACCEL, t)
    s = RigSession(
        t=t,
        angle=angle,
        rate=rate,
        accel=accel,
        V_f=smooth(V[:, 0]),
        V_b=smooth(V[:, 1]),
        gyro=None if gyro is None else smooth(gyro),
        specific_force=None if f is None else smooth(f),
        free=np.ones(len(t), dtype=bool),
        dt=dt,
        source=source,
        gyro_raw=gyro,
        specific_force_raw=f,
        encoder_step=_step(angles),
    )
    s.free = free_flight(s, raw, V)
    if gyro is None or f is None:
        s.notes.append("no IMU in the log: its effects (biases, mounting, encoder offsets) are not looked for")
    return s


def free_flight(s: RigSession, raw: dict[str, np.ndarray], V: np.ndarray) -> np.ndarray:
    """Where the rig flew free: not on the table with its motors off, and no axis held by a stop
    (standing still, for ``HELD_FOR_S`` or more, while the lab's model with Table 1's constants
    asks it to move)."""
    K1, K2, _ = gains(K_F, V_S0)
    V_s, V_d = V.sum(axis=1), V[:, 1] - V[:, 0]
    contact = V_s < MOTORS_OFF
    for axis, asked in (("p", K1 * V_d), ("e", K2 * (V_s - V_S0))):
        held = (np.abs(s.rate[axis]) < STILL) & (np.abs(asked) > HELD[axis]) & (np.abs(s.accel[axis]) < HELD[axis] / 4)
        contact |= _lasting(held, int(round(HELD_FOR_S / s.dt)))
    guard = int(round(GUARD_S / s.dt))
    if contact.any() and guard:
        # widen each contact by the guard: a sample is out if any contact lies within guard of it
        c = np.concatenate([[0], np.cumsum(contact)])
        n = len(contact)
        i = np.arange(n)
        lo, hi = np.clip(i - guard, 0, n), np.clip(i + guard + 1, 0, n)
        contact = (c[hi] - c[lo]) > 0
    free = ~contact
    edge = _edge(s.dt)
    free[:edge] = free[-edge:] = False
    return free
