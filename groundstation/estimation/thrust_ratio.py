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

**The thrust at idle.** Fitted where the vehicle flies, the line says little of the idle on the
ground: the airborne commands span a tenth of the range, and a line through the truth's own thrust
in the air put the idle at 0.24, 0.12, 0.56 and -0.11 of the weight on four flights of one airframe
whose rotors made 0.053 there.
The rotors say it themselves: a blade's thrust goes with its speed squared (T = C_T rho n^2 D^4,
momentum theory's static thrust), and the speed shows in the accelerometer's spectrum as the
rotors' own vibration (the peak a harmonic notch is set on). :func:`idle_thrust` reads that
frequency on the ground at idle and in the air, and T/(m g) at idle = T/(m g) in the air x
(f_idle / f_air)^2: 15.4 Hz and 66.0 Hz on those flights, 0.054 of the weight. Below the airborne
commands the map then runs from that point to the line, and to nothing as the motors stop, with the
rotors' speed straight in the command between them and the thrust as its square; where the spectrum
shows no rotor (a slow or filtered IMU, no idle on the ground), it is the line alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from groundstation.core.imu import ImuColumns
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
#: the airborne command's percentile below which the line is not read (where the idle point is known)
LOW_PERCENTILE = 2.0
#: the rotors' frequency (:func:`rotor_frequency`): its peak must stand this far above the spectrum's
#: median, at or above this frequency (below: the airframe's own motion), in this much data [s]
ROTOR_PROMINENCE = 20.0
ROTOR_MIN_HZ = 5.0
ROTOR_MIN_S = 1.0
#: a command this far above the stopped motors' turns them; one within IDLE_BAND of the ground's
#: median such command is the idle; airborne, one within AIR_BAND of the airborne median is the hover
TURNING = 0.03
IDLE_BAND = 0.01
AIR_BAND = 0.03


@dataclass(frozen=True)
class ThrustRatio:
    """T / (m g) = a c + b for a command c > 0, 0 at c <= 0; with the thrust at idle known
    (``idle``, ``idle_tw``), below the airborne commands (``low``) the rotors' speed runs straight
    from the line's lowest to the idle's and on to nothing at the stopped motors' command
    (``zero``), and the thrust goes as its square (module docstring)."""

    a: float
    b: float
    rms: float  #: the fit's residual over the airborne stretch [T / (m g)]
    seconds: float  #: the airborne stretch it was fitted on [s]
    low: float = math.nan  #: the least airborne command the line is read at (:data:`LOW_PERCENTILE`)
    zero: float = 0.0  #: the command of the motors stopped
    idle: float | None = None  #: the command at idle on the ground
    idle_tw: float | None = None  #: T / (m g) there, from the rotors' frequency (:func:`idle_thrust`)
    rotor_hz: tuple[float, float] | None = None  #: (at idle, in the air) [Hz], as read

    def of(self, command: float) -> float:
        if self.idle is None or self.idle_tw is None or not command < self.low:
            return max(self.a * command + self.b, 0.0) if command > 0.0 else 0.0
        if command > self.idle:
            # the rotors' speed runs straight from the idle's to the line's lowest, the thrust as its square
            at_low = max(self.a * self.low + self.b, 0.0)
            r = math.sqrt(self.idle_tw / at_low) if at_low > 0.0 else 1.0
            u = (command - self.idle) / (self.low - self.idle)
            return at_low * (r + (1.0 - r) * u) ** 2
        if command > self.zero:
            return self.idle_tw * ((command - self.zero) / (self.idle - self.zero)) ** 2
        return 0.0

    def most(self, command: float) -> float:
        """The most thrust over the weight ``command`` makes: the map's, and :data:`SPREAD_SIGMAS` times
        its residual above it (at least :data:`SPREAD_FLOOR`). Where the accelerometer reads more, the
        ground carries part of the weight: touching down, the gear takes it while the throttle winds
        down, before any land detector says so, and the accelerometer then measures the thrust no
        longer (:func:`~groundstation.diagnosis.runs.signals.add_signal_rules` takes the map's there)."""
        return self.of(command) + self.spread

    @property
    def spread(self) -> float:
        """How far above the map the thrust may read in the air (:meth:`most`)."""
        return SPREAD_SIGMAS * max(self.rms, SPREAD_FLOOR)

    def as_dict(self) -> dict:
        d: dict = {"a": round(self.a, 4), "b": round(self.b, 4), "rms": round(self.rms, 4)}
        d["seconds"] = round(self.seconds)
        if self.idle is not None and self.idle_tw is not None and self.rotor_hz is not None:
            d |= {
                "idle_command": round(self.idle, 4),
                "idle_thrust_over_weight": round(self.idle_tw, 4),
                "rotor_hz_idle_air": [round(f, 2) for f in self.rotor_hz],
            }
        return d


def command(m: Measurement, curve: MotorCurve | None, n_motors: int, *, clip: bool = True) -> float | None:
    """The command the rotor-wash signal reads from a THROTTLE or ACTUATOR record: the motor outputs'
    share of their working range where the log states the curve (:class:`MotorCurve`; with ``clip``
    off, below 0 under the spin minimum: the map's own command, which tells the idle from the
    motors stopped), else their mean; THROTTLE's value as it is. None where the record holds no
    finite command."""
    if m.kind is Kind.ACTUATOR:
        outputs = [x for x in m.value[:n_motors].tolist() if math.isfinite(x)]
        if not outputs:
            return None
        return curve.thrust(outputs, clip=clip) if curve is not None else sum(outputs) / len(outputs)
    if len(m.value) and math.isfinite(m.value[0]):
        return float(m.value[0])
    return None


def thrust_ratio(
    readings: Readings, curve: MotorCurve | None, n_motors: int, imu: ImuColumns | None = None
) -> ThrustRatio | None:
    """The map from the wash signal's command to T / (m g) (module docstring), fitted on ``readings``
    (a log's readings with the accelerometer's block means, instance 0), or None where the log has no
    command, no accelerometer, or too short or too steady an airborne stretch to fit it on. One
    source of commands as :func:`~groundstation.estimation.routing.collective` takes it: the outputs
    where the log has them. ``imu``: the raw accelerometer, whose spectrum says the thrust at idle
    (:func:`idle_thrust`)."""
    kinds = readings.kinds()
    source = Kind.ACTUATOR if Kind.ACTUATOR in kinds else Kind.THROTTLE
    if source not in kinds or Kind.ACCEL not in kinds:
        return None
    commands = readings.only({source})
    cmds = [(m.t, command(m, curve, n_motors, clip=False)) for m in commands]
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
    zero = 0.0
    if source is Kind.ACTUATOR and curve is not None:
        zero = curve.thrust([0.0], clip=False)
    line = ThrustRatio(float(a), float(b), rms, float(down - up), float(np.percentile(x, LOW_PERCENTILE)), zero)
    sensor = imu.get(Kind.ACCEL, 0) if imu is not None else None
    if sensor is None:
        return line
    airborne_c = c[airborne]
    idle = idle_thrust(line, tc, c, (sensor.t, sensor.values()), segments, (up, down), float(np.median(airborne_c)))
    return line if idle is None else idle


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


def idle_thrust(
    line: ThrustRatio,
    tc: np.ndarray,
    c: np.ndarray,
    accel: tuple[np.ndarray, np.ndarray],
    segments: list[tuple[float, float]],
    air: tuple[float, float],
    hover: float,
) -> ThrustRatio | None:
    """``line`` with the thrust at idle (module docstring), or None where the spectrum does not show
    the rotors both on the ground at idle and in the air. ``tc``, ``c``: the commands and their
    times; ``accel``: the raw accelerometer's times and samples; ``segments``: the ground's stretches;
    ``air``: the airborne stretch the line was fitted on; ``hover``: its median command."""
    ta, f = accel
    if len(ta) < 2:
        return None
    rate = (len(ta) - 1) / max(float(ta[-1] - ta[0]), 1e-9)
    # each accelerometer sample's command: the one last written before it
    at = np.searchsorted(tc, ta, side="right") - 1
    known = at >= 0
    cmd = np.where(known, c[np.maximum(at, 0)], np.nan)
    ground = np.zeros(len(ta), bool)
    for g0, g1 in segments:
        ground |= (ta >= g0) & (ta <= g1)
    turning = ground & (cmd > line.zero + TURNING) & (cmd < AIRBORNE)
    if not turning.any():
        return None
    idle = float(np.median(cmd[turning]))
    at_idle = turning & (np.abs(cmd - idle) <= IDLE_BAND)
    in_air = (ta > air[0]) & (ta < air[1]) & (np.abs(cmd - hover) <= AIR_BAND)
    f_idle = rotor_frequency(f[at_idle], rate)
    f_air = rotor_frequency(f[in_air], rate)
    if f_idle is None or f_air is None or not f_idle < f_air:
        return None
    air_tw = line.a * hover + line.b
    idle_tw = air_tw * (f_idle / f_air) ** 2
    at_low = line.a * line.low + line.b
    if not (math.isfinite(idle_tw) and 0.0 < idle_tw < at_low and line.zero < idle < line.low):
        return None
    return ThrustRatio(
        line.a, line.b, line.rms, line.seconds, line.low, line.zero, idle, float(idle_tw), (f_idle, f_air)
    )


def rotor_frequency(x: np.ndarray, rate: float) -> float | None:
    """The rotors' frequency [Hz] in the accelerometer samples ``x`` (rows; they need not be
    contiguous: a stretch's samples, its gaps joined), or None where no peak stands out
    (:data:`ROTOR_PROMINENCE`) or there are fewer than :data:`ROTOR_MIN_S` of them. SciPy's Welch PSD,
    summed over the axes; its strongest peak, refined by the parabola through the log-PSD at the
    peak and its neighbours. On the flights measured the strongest is the rotors' own frequency on the
    ground at idle and in the air alike (its second harmonic 14 times weaker at idle). Where a frame
    made the blades' passing the stronger in both, the ratio would hold; in one alone it would not,
    and what guards that is :func:`idle_thrust`'s check that the idle's thrust lies between nothing
    and the line's lowest."""
    from scipy.signal import welch  # the standard spectrum estimate

    if len(x) < max(ROTOR_MIN_S * rate, 64):
        return None
    n = int(min(1024, 2 ** math.floor(math.log2(len(x) / 2))))
    freq, psd = welch(x - x.mean(axis=0), fs=rate, nperseg=n, axis=0)
    p = psd.sum(axis=1) if psd.ndim == 2 else psd
    band = (freq >= ROTOR_MIN_HZ) & (freq <= 0.45 * rate)
    if band.sum() < 5:
        return None
    floor = float(np.median(p[band]))
    k = int(np.argmax(np.where(band, p, 0.0)))
    if not p[k] >= ROTOR_PROMINENCE * floor:
        return None
    df = freq[1] - freq[0]
    if not 0 < k < len(p) - 1:
        return float(freq[k])
    lo, mid, hi = np.log(np.maximum(p[k - 1 : k + 2], 1e-300))
    den = lo - 2.0 * mid + hi
    shift = 0.5 * (lo - hi) / den if den < 0 else 0.0
    return float(freq[k] + max(min(shift, 0.5), -0.5) * df)
