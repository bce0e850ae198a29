"""A plain altitude Kalman filter, written apart from the project's estimators: the reference the
foreign flights' table measures the diagnosis against.

Three states, x = [h, v, b] (height up [m], vertical speed up [m/s], accelerometer bias along the
vertical [m/s^2]), the vertical specific force as the input (the accelerometer rotated by the logged
roll and pitch, gravity taken off), and every absolute height the log has as a measurement: the
baro's pressure altitude and the GPS altitude, both zeroed on the pre-arm ground segment, and the
downward rangefinder less its stated ground clearance. It is the coaxial document's 3-state filter
(ch. 7) with nothing else: no tilt for the range, no ground, no effect. ``reference`` runs it on the
log as it is ("nominal") and with the hidden effect taken out of the sensors by the truth file's own
columns ("oracle": ``baro_err_m``, ``range_tilt_factor``, ``accel_bias_z``).

Its noise is what a person sets from the log's own stationary stretch and the sensors' data sheets,
once for every flight: nothing here is fitted to a flight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from filterpy.kalman import KalmanFilter

from groundstation.core.atmosphere import altitude_at
from groundstation.core.measurement import Kind
from groundstation.estimation.logs import load_log

G = 9.80665
DT = 0.01  #: [s] the input's block
#: the process noise: the vertical specific force's white noise over a block [m/s^2] and the bias's
#: random walk [m/s^2/sqrt(s)]
SIGMA_ACCEL = 0.35
SIGMA_BIAS_WALK = 0.003
#: the measurements' noise [m]: a baro's 1-sigma height noise (10 Hz, the foreign generators' order),
#: a GPS altitude's (white and slow together), a lidar's (data sheet: 1.5 cm + 0.5 % of range)
SIGMA_BARO = 0.10
SIGMA_GPS = 0.9


@dataclass
class Sensors:
    """What the filter reads from a log, in seconds of its clock."""

    t_acc: np.ndarray  #: block start times
    a_up: np.ndarray  #: the vertical specific force less gravity, up [m/s^2], one a block
    baro: tuple[np.ndarray, np.ndarray] | None  #: (t, pressure altitude [m])
    gps: tuple[np.ndarray, np.ndarray] | None  #: (t, altitude AMSL [m])
    rng: tuple[np.ndarray, np.ndarray] | None  #: (t, range [m])
    ground_clearance: float  #: [m] the range's reading on the ground, as the log's parameters state
    tilt_cos: tuple[np.ndarray, np.ndarray]  #: (t, cos(roll) cos(pitch))


def read(path: Path, ground_clearance: float | None = None) -> Sensors:
    """The log's sensors; the range's ground clearance as given, else as the log's parameters state
    it (``RNGFND1_GNDCLEAR``), else 0."""
    log = load_log(path, imu_columns=True)
    by: dict[Kind, list] = {}
    for m in log.measurements:
        if math.isfinite(m.t):
            by.setdefault(m.kind, []).append((m.t, m.value))
    att = by[Kind.ATTITUDE]
    ta = np.array([a[0] for a in att])
    roll = np.array([a[1][0] for a in att])
    pitch = np.array([a[1][1] for a in att])
    assert log.imu is not None
    acc = next(s for (k, _), s in log.imu.series.items() if k is Kind.ACCEL)
    f = acc.values()
    r = np.interp(acc.t, ta, roll)
    p = np.interp(acc.t, ta, pitch)
    # NED z of the specific force: -sin(p) fx + sin(r) cos(p) fy + cos(r) cos(p) fz; at rest -g
    fz = -np.sin(p) * f[:, 0] + np.sin(r) * np.cos(p) * f[:, 1] + np.cos(r) * np.cos(p) * f[:, 2]
    a_up = -(fz + G)
    edges = np.arange(acc.t[0], acc.t[-1], DT)
    idx = np.searchsorted(edges, acc.t, side="right") - 1
    sums = np.bincount(idx, a_up, len(edges))
    counts = np.bincount(idx, None, len(edges))
    keep = counts > 0
    blocks = (edges[keep], sums[keep] / counts[keep])

    def series(kind: Kind, fn) -> tuple[np.ndarray, np.ndarray] | None:
        rows = by.get(kind)
        if not rows:
            return None
        return np.array([r[0] for r in rows]), np.array([fn(r[1]) for r in rows])

    baro = series(Kind.BARO_PRESSURE, lambda v: altitude_at(v[0]))
    params = log.tables.params or {}
    clear = params.get("RNGFND1_GNDCLEAR")
    return Sensors(
        blocks[0],
        blocks[1],
        baro,
        series(Kind.GPS, lambda v: v[2]),
        series(Kind.RANGE, lambda v: v[0]),
        ground_clearance if ground_clearance is not None else float(clear) / 100.0 if clear is not None else 0.0,
        (ta, np.cos(roll) * np.cos(pitch)),
    )


def run(s: Sensors, arm: float, *, sigma_baro: float = SIGMA_BARO) -> tuple[np.ndarray, np.ndarray]:
    """The filter over the log: (t, h) at each input block. The baro and the GPS are zeroed by their
    medians before ``arm`` (the vehicle stands on its gear there, height 0)."""
    kf = KalmanFilter(dim_x=3, dim_z=1, dim_u=1)
    kf.F = np.array([[1.0, DT, -0.5 * DT * DT], [0.0, 1.0, -DT], [0.0, 0.0, 1.0]])
    kf.B = np.array([[0.5 * DT * DT], [DT], [0.0]])
    g = np.array([[0.5 * DT * DT], [DT], [0.0]])
    kf.Q = g @ g.T * SIGMA_ACCEL**2 + np.diag([0.0, 0.0, SIGMA_BIAS_WALK**2 * DT])
    kf.x = np.zeros((3, 1))
    kf.P = np.diag([0.5**2, 0.2**2, 0.3**2])
    kf.H = np.array([[1.0, 0.0, 0.0]])

    events: list[tuple[float, int, float, float]] = []  # (t, order, height read, variance)
    for order, (series, sigma, zero) in enumerate(
        ((s.baro, sigma_baro, True), (s.gps, SIGMA_GPS, True), (s.rng, None, False))
    ):
        if series is None:
            continue
        t, v = series
        ok = np.isfinite(v)
        t, v = t[ok], v[ok]
        if zero:
            before = t < arm
            if not before.any():
                continue
            v = v - np.median(v[before])
        else:
            v = v - s.ground_clearance
        for ti, vi in zip(t, v):
            sd = sigma if sigma is not None else 0.015 + 0.005 * abs(vi + s.ground_clearance)
            events.append((float(ti), order, float(vi), sd * sd + (0.01**2 / 12 if sigma is None else 0.0)))
    events.sort()
    out_t = np.empty(len(s.t_acc))
    out_h = np.empty(len(s.t_acc))
    j = 0
    for i, (t, a) in enumerate(zip(s.t_acc, s.a_up)):
        kf.predict(u=np.array([[a]]))
        t_end = t + DT
        while j < len(events) and events[j][0] < t_end:
            _, _, z, var = events[j]
            kf.update(np.array([[z]]), R=np.array([[var]]))
            j += 1
        out_t[i] = t_end
        out_h[i] = kf.x[0, 0]
    return out_t, out_h


def without_hidden(s: Sensors, truth: np.ndarray, hidden: set[str]) -> Sensors:
    """The sensors with the truth file's own effect columns taken out: the baro's error, the range's
    tilt factor where the range's tilt is the hidden effect (a clean flight's lidar reads slant range
    too, below its tolerance), the accelerometer's vertical bias."""
    tt = truth["t"]
    baro = s.baro
    if baro is not None and "baro_err_m" in truth.dtype.names:
        baro = (baro[0], baro[1] - np.interp(baro[0], tt, truth["baro_err_m"]))
    rng = s.rng
    if rng is not None and "range_tilt" in hidden and "range_tilt_factor" in truth.dtype.names:
        f = np.interp(rng[0], tt, truth["range_tilt_factor"])
        rng = (rng[0], rng[1] / f)
    a_up = s.a_up
    if "accel_bias_z" in truth.dtype.names:
        # the bias adds to the body z axis's reading (FRD, down): up, it subtracts
        a_up = a_up + np.interp(s.t_acc, tt, truth["accel_bias_z"])
    return Sensors(s.t_acc, a_up, baro, s.gps, rng, s.ground_clearance, s.tilt_cos)
