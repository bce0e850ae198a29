"""The rotors' thrust over the vehicle's weight, T / (m g), from the motor command, as the log shows it.

A rotor's wash, and the pressure field it raises near the ground, scale with its disc loading
(momentum theory: the induced velocity's dynamic pressure is T / (2 A)), so the error a wash puts on
a barometer follows the thrust, not the command. How a command becomes thrust is the vehicle's own
(the ESC's curve, the spin minimum, the autopilot's thrust linearisation, and which throttle the log
records: ArduPilot's ``CTUN.ThO`` is not its outputs' PWM), and no parameter states all of it. The
log shows it: in the air the accelerometer reads the thrust over the mass along the body's z axis,
f_z = -T / m (FRD; rotor drag along z neglected), so T / (m g) = -f_z / g.

:func:`thrust_ratio` fits T / (m g) = a c + b over the flight's airborne stretch against the
command c the rotor-wash signal is read from (:func:`command`), and :meth:`ThrustRatio.of` maps every
command through it. On the ground the accelerometer reads the ground's support, not the thrust; the
map is what says the thrust there, and a command at idle or below (c <= 0) makes none.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings
from groundstation.estimation.stated import MotorCurve, ground_segments

G = 9.80665
#: [s] the accelerometer averaged over this long before each command (the rotors' vibration out)
WINDOW_S = 0.2
#: [s] the airborne stretch a fit needs, and its commands' least spread (a command held at one
#: value says nothing of the slope)
MIN_AIRBORNE_S = 10.0
MIN_SPREAD = 1e-3
#: the command at or above which the rotors carry the vehicle (as the ground segments take it)
AIRBORNE = 0.15
#: [s] kept clear of the ground segments (which end a second short of the take-off and begin a second
#: after the landing): the gear's support is still in the accelerometer around both
EDGE_S = 2.0
#: the map's residual, in standard deviations, the accelerometer may read above it before the excess is
#: taken for the ground's support (a one-sided test at 3 sigma: 0.13 % of a flight's true thrust
#: clipped, were the residual Gaussian); and the least residual taken (a map fitted to a smooth flight)
SPREAD_SIGMAS = 3.0
SPREAD_FLOOR = 0.03


@dataclass(frozen=True)
class ThrustRatio:
    """T / (m g) = a c + b for a command c > 0, 0 at c <= 0 (module docstring)."""

    a: float
    b: float
    rms: float  #: the fit's residual over the airborne stretch [T / (m g)]
    seconds: float  #: the airborne stretch it was fitted on [s]

    def of(self, command: float) -> float:
        return max(self.a * command + self.b, 0.0) if command > 0.0 else 0.0

    def most(self, command: float) -> float:
        """The most thrust over the weight ``command`` makes: the map's, and :data:`SPREAD_SIGMAS` times
        its residual above it (at least :data:`SPREAD_FLOOR`). Where the accelerometer reads more, the
        ground carries the rest: touching down, the gear takes the weight while the throttle winds
        down, before any land detector says so."""
        return self.of(command) + SPREAD_SIGMAS * max(self.rms, SPREAD_FLOOR)

    def as_dict(self) -> dict:
        return {"a": round(self.a, 4), "b": round(self.b, 4), "rms": round(self.rms, 4), "seconds": round(self.seconds)}


def command(m: Measurement, curve: MotorCurve | None, n_motors: int) -> float | None:
    """The command the rotor-wash signal reads from a THROTTLE or ACTUATOR record: the motor outputs'
    share of their working range where the log states the curve (:class:`MotorCurve`), else their
    mean; THROTTLE's value as it is. None where the record holds no finite command."""
    if m.kind is Kind.ACTUATOR:
        outputs = [x for x in m.value[:n_motors].tolist() if math.isfinite(x)]
        if not outputs:
            return None
        return curve.thrust(outputs) if curve is not None else sum(outputs) / len(outputs)
    if len(m.value) and math.isfinite(m.value[0]):
        return float(m.value[0])
    return None


def thrust_ratio(readings: Readings, curve: MotorCurve | None, n_motors: int) -> ThrustRatio | None:
    """The map from the wash signal's command to T / (m g) (module docstring), fitted on ``readings``
    (a log's readings with the accelerometer's block means, instance 0), or None where the log has no
    command, no accelerometer, or too short or too steady an airborne stretch to fit it on. One
    source of commands as :func:`~groundstation.estimation.routing.collective` takes it: the outputs
    where the log has them."""
    kinds = readings.kinds()
    source = Kind.ACTUATOR if Kind.ACTUATOR in kinds else Kind.THROTTLE
    if source not in kinds or Kind.ACCEL not in kinds:
        return None
    commands = readings.only({source})
    cmds = [(m.t, command(m, curve, n_motors)) for m in commands]
    tc = np.array([t for t, c in cmds if c is not None])
    c = np.array([c for _, c in cmds if c is not None])
    ta, fz = _body_z(readings.only({Kind.ACCEL}))
    if not len(tc) or not len(ta):
        return None
    ratio = -fz / G
    segments = ground_segments(commands)
    if len(segments) < 2:
        return None
    up, down = segments[0][1] + EDGE_S, segments[1][0] - EDGE_S
    # the accelerometer's mean over the window before each command (cumulative sums: one pass)
    csum = np.concatenate([[0.0], np.cumsum(ratio)])
    hi = np.searchsorted(ta, tc, side="right")
    lo = np.searchsorted(ta, tc - WINDOW_S, side="left")
    n = hi - lo
    airborne = (tc > up) & (tc < down) & (c >= AIRBORNE) & (n > 0)
    if airborne.sum() < 10 or down - up < MIN_AIRBORNE_S:
        return None
    y = (csum[hi] - csum[lo])[airborne] / n[airborne]
    # the command over the same window: its jitter, which the rotors do not follow, would flatten
    # the slope as noise in a regressor does
    ccum = np.concatenate([[0.0], np.cumsum(c)])
    chi = np.arange(1, len(c) + 1)
    clo = np.searchsorted(tc, tc - WINDOW_S, side="left")
    x = ((ccum[chi] - ccum[clo]) / (chi - clo))[airborne]
    if float(np.std(x)) < MIN_SPREAD:
        return None
    a, b = np.polyfit(x, y, 1)
    if not (math.isfinite(a) and math.isfinite(b)) or a <= 0.0:
        return None
    rms = float(np.sqrt(np.mean((a * x + b - y) ** 2)))
    return ThrustRatio(float(a), float(b), rms, float(down - up))


def _body_z(acc: Readings) -> tuple[np.ndarray, np.ndarray]:
    """The first accelerometer's times and body-z specific force, in time order."""
    t, f = [], []
    for k, s in enumerate(acc.streams):
        if s.instance == 0 and s.values.ndim == 2 and s.values.shape[1] >= 3:
            rows = acc.stream == k
            t.append(acc.t[rows])
            f.append(s.values[acc.row[rows], 2])
    if not t:
        return np.zeros(0), np.zeros(0)
    ta, fa = np.concatenate(t), np.concatenate(f).astype(float)
    order = np.argsort(ta, kind="stable")
    return ta[order], fa[order]
