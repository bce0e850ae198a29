"""What a log says of its sensors and motors besides their readings: the downward rangefinder's
ground clearance (from the vehicle standing on its gear or, failing that, from the autopilot's
parameters) and the motors' thrust curve (from the autopilot's parameters).

**Ground clearance.**

A downward rangefinder sits some centimetres above the floor when the vehicle stands on its gear:
it reads that much where the height the estimators mean (0 on the ground) is zero, and that much
too much in flight. Autopilots are told it: ArduPilot's ``RNGFND1_GNDCLEAR`` [cm] ("distance from
the range finder to the ground when the vehicle is landed"), PX4's ``EKF2_MIN_RNG`` [m] ("expected
rangefinder reading when on ground"). Left in, it is a constant offset on the one precise absolute
height, which no other sensor can show: a lidar 5 cm above the floor put a 5 cm error on every
estimate of a flight whose filter was otherwise within a centimetre.

The readings themselves say it best, where the log has them: on the ground, before take-off and
after landing, the sensor reads its clearance, usually below its own minimum distance, so the
readers leave those readings out of the measurements (``range_not_good``, ``range_out_of_bounds``)
while the log's records keep them (ArduPilot ``RFND`` with status OutOfRangeLow, PX4
``distance_sensor``, MAVLink ``DISTANCE_SENSOR``). Their median is the clearance where they are
steady (a spread of a few centimetres) and are not a clamp: a sonar that reads its floor (one value,
or the stated minimum) for anything closer says nothing of the distance. Where the data and the
parameter disagree, the data is used and the disagreement is said: the parameter is then a setting
to correct.

**The motors' working range.** A motor makes thrust between the output its autopilot spins it at
when armed and idle and its full output: ArduPilot's ``MOT_SPIN_MIN``/``MOT_SPIN_MAX`` within
``MOT_PWM_MIN``/``MOT_PWM_MAX`` (``AP_MotorsMulticopter::thrust_to_actuator``), PX4's
``PWM_MAIN_MINn``/``PWM_MAIN_MAXn`` of the first motor's output (``PWM_MAIN_FUNCn`` says which),
or with DShot ESCs ``DSHOT_MIN`` to the protocol's full throttle.
The rotor wash on a static port scales with the thrust, so its signal is the motors' mean output
as a fraction of that range, zero at idle: with the raw output, a vehicle idling on the ground at
``MOT_SPIN_ARM`` (0.1) showed a wash that was not there, and on another generator's flight a
correlate of the battery current was claimed in its place. The
autopilots also state a thrust curve over that range (ArduPilot's ``MOT_THST_EXPO``, PX4's
``THR_MDL_FAC``: thrust = e r^2 + (1 - e) r). It is read and reported, not applied: it is what the
autopilot was told (often its default), and on that generator's flights, whose thrust is linear in
the command, the wash fitted through the stated 0.65 left 14.3 cm of height error where the linear
range left 11.2 cm (7.4 cm for a filter that knows the effect).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drivers.logs.frame import px4_dshot_idle, px4_dshot_outputs, px4_motor_columns
from drivers.logs.tables import LogTables
from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings

#: a throttle at or above this carries the vehicle (models.ground.TAU_GROUND: below it the ground does)
TAU_AIRBORNE = 0.15
#: [s] the ground segments end this long before the throttle first carries the vehicle and begin this
#: long after it last did: the spool-up and the touchdown are neither ground nor flight
MARGIN_S = 1.0
#: the least of ground readings a clearance is read from
MIN_READINGS = 10
#: [m] ground readings steadier than this (their interquartile range) are a distance, and a clearance
#: is at most MAX_CLEARANCE (a rangefinder on a landing gear, not a sensor looking at something else)
MAX_SPREAD = 0.03
MAX_CLEARANCE = 0.5
#: a share of identical readings at least this is a sensor clamped at one value, not a distance
CLAMP_SHARE = 0.8
#: the data and the parameter agree within this [m]
AGREE = 0.02
#: the message types a tlog's clearance is read from: the rangefinder, the parameters (and the
#: heartbeats that tell a ground station's own from the vehicle's, which the reader adds)
STATED_TABLES = ("DISTANCE_SENSOR", "PARAM_VALUE")
#: the readings the ground segments are read from (:func:`ground_segments`)
GROUND_KINDS = (Kind.THROTTLE, Kind.ACTUATOR)


@dataclass(frozen=True)
class MotorCurve:
    """The motors' working range in ``Kind.ACTUATOR``'s normalised output ``(us - 1000) / 1000``, and
    the thrust curve the autopilot states over it (module docstring)."""

    expo: float  #: the stated curve's e (reported, not applied)
    low: float  #: the normalised output at which the motors begin to make thrust (the spin minimum)
    high: float  #: ... at full thrust
    source: str  #: the parameters it was read from

    def thrust(self, outputs: list[float], *, clip: bool = True) -> float:
        """The motors' mean output as a fraction of their working range, 0 at idle; with ``clip``
        off, below 0 under the spin minimum (the motors stopped, or turning at ArduPilot's
        ``MOT_SPIN_ARM``) and above 1 over the spin maximum."""
        r = (sum(outputs) / len(outputs) - self.low) / (self.high - self.low)
        return min(max(r, 0.0), 1.0) if clip else r

    def as_dict(self) -> dict:
        return {"expo": self.expo, "low": round(self.low, 4), "high": round(self.high, 4), "from": self.source}


def _param(params: dict[str, float], name: str, default: float | None = None) -> float | None:
    v = params.get(name)
    return float(v) if v is not None and math.isfinite(v) else default


def motor_curve(params: dict[str, float]) -> MotorCurve | None:
    """The motors' thrust curve the autopilot's parameters state (ArduPilot's ``MOT_THST_EXPO`` with
    its spin range and PWM range, PX4's ``THR_MDL_FAC`` with its PWM range), or None."""
    expo = _param(params, "MOT_THST_EXPO")
    if expo is not None and -1.0 <= expo <= 1.0:
        pwm_lo = _param(params, "MOT_PWM_MIN", 0.0) or 1000.0  # 0: the RC3 range, 1000-2000 as usual
        pwm_hi = _param(params, "MOT_PWM_MAX", 0.0) or 2000.0
        spin_lo = _param(params, "MOT_SPIN_MIN", 0.15) or 0.0
        spin_hi = _param(params, "MOT_SPIN_MAX", 0.95) or 1.0
        if pwm_hi > pwm_lo and 0.0 <= spin_lo < spin_hi <= 1.0:
            lo = (pwm_lo + spin_lo * (pwm_hi - pwm_lo) - 1000.0) / 1000.0
            hi = (pwm_lo + spin_hi * (pwm_hi - pwm_lo) - 1000.0) / 1000.0
            return MotorCurve(expo, lo, hi, f"MOT_THST_EXPO {expo:g}, MOT_SPIN_MIN/MAX {spin_lo:g}/{spin_hi:g}")
    fac = _param(params, "THR_MDL_FAC")
    if fac is not None and 0.0 <= fac <= 1.0 and px4_dshot_outputs(params):
        # DShot ESCs: from DSHOT_MIN's idle to the protocol's full throttle (no pulse widths)
        return MotorCurve(fac, px4_dshot_idle(params), 1.0, f"THR_MDL_FAC {fac:g}, DShot")
    if fac is not None and 0.0 <= fac <= 1.0:
        # the first motor's output (its function says which: ``PWM_MAIN_FUNCn``), else output 1
        n = (px4_motor_columns(params) or [0])[0] + 1
        main_lo = _param(params, f"PWM_MAIN_MIN{n}", _param(params, "PWM_MAIN_MIN"))
        main_hi = _param(params, f"PWM_MAIN_MAX{n}", _param(params, "PWM_MAIN_MAX"))
        low, high = main_lo if main_lo is not None else 1000.0, main_hi if main_hi is not None else 2000.0
        if high > low:
            return MotorCurve(fac, (low - 1000.0) / 1000.0, (high - 1000.0) / 1000.0, f"THR_MDL_FAC {fac:g}")
    return None


@dataclass(frozen=True)
class Stated:
    """What the log states besides its readings (the module's docstring)."""

    clearance: RangeClearance | None = None
    motors: MotorCurve | None = None

    def as_dict(self) -> dict:
        return {
            "range_clearance": self.clearance.as_dict() if self.clearance is not None else None,
            "motor_curve": self.motors.as_dict() if self.motors is not None else None,
        }


def stated_by(tables: LogTables, ms: Sequence[Measurement]) -> Stated:
    """What ``tables`` (a log's records and parameters) and its measurements state."""
    return Stated(range_clearance(tables, ms), motor_curve(tables.params))


@dataclass(frozen=True)
class RangeClearance:
    """The downward rangefinder's reading with the vehicle on its gear [m], and where it comes from."""

    metres: float
    source: str  #: one line: "the ground segments (412 readings)", "RNGFND1_GNDCLEAR = 5 cm"
    parameter: str | None = None  #: the autopilot's parameter that states it, if the log has one
    parameter_metres: float | None = None  #: its value [m]
    readings: int = 0  #: ground readings it was read from (0: the parameter alone)

    @property
    def disagrees(self) -> bool:
        """The data says other than the parameter: the parameter is a setting to correct."""
        return (
            self.readings > 0 and self.parameter_metres is not None and abs(self.metres - self.parameter_metres) > AGREE
        )

    def as_dict(self) -> dict:
        d: dict = {"m": round(self.metres, 4), "from": self.source}
        if self.parameter is not None:
            d["parameter"] = {"name": self.parameter, "m": self.parameter_metres}
        return d


def clearance_effect(c: RangeClearance) -> dict:
    """The clearance as the effect an estimator takes it as: a range mounting offset ``o`` [m]
    (catalogue ``range_offset``; the altitude model subtracts it from every range reading)."""
    return {"name": "range_offset", "params": {"o": c.metres}, "stated": c.source}


def stated_clearance(params: dict[str, float]) -> tuple[str, float] | None:
    """The clearance the autopilot's parameters state: (name, metres), or None."""
    for name in ("RNGFND1_GNDCLEAR", "RNGFND_GNDCLEAR"):  # ArduPilot [cm]
        v = params.get(name)
        if v is not None and math.isfinite(v) and 0 <= v <= 100 * MAX_CLEARANCE:
            return name, float(v) / 100.0
    v = params.get("EKF2_MIN_RNG")  # PX4 [m]
    if v is not None and math.isfinite(v) and 0 <= v <= MAX_CLEARANCE:
        return "EKF2_MIN_RNG", float(v)
    return None


def raw_range(tables: LogTables) -> tuple[np.ndarray, np.ndarray, float | None] | None:
    """Every downward rangefinder reading the log's records hold, whatever its status: (t [s],
    distance [m], the sensor's stated minimum [m] or None)."""
    rf = tables.get("RFND")
    if rf is not None:  # ArduPilot: Dist [m] (3.x: Dist1 [cm]), Orient 25 down
        d = rf.numeric("Dist")
        if d is None:
            d1 = rf.numeric("Dist1")
            d = d1 / 100.0 if d1 is not None else None
        if d is None:
            return None
        keep = _downward(rf.numeric("Orient"), len(rf)) & _first(rf.numeric("Instance"), len(rf))
        lo = next((tables.params.get(p + "MIN_CM") for p in ("RNGFND1_", "RNGFND_")), None)
        return rf.t[keep], d[keep], lo / 100.0 if lo is not None else None
    ds = tables.get("distance_sensor")
    if ds is not None:  # PX4: current_distance, min_distance [m]
        d = ds.numeric("current_distance")
        if d is None:
            return None
        keep = _downward(ds.numeric("orientation"), len(ds))
        mins = ds.numeric("min_distance")
        return ds.t[keep], d[keep], _typical(mins[keep]) if mins is not None else None
    dm = tables.get("DISTANCE_SENSOR")
    if dm is not None:  # MAVLink: current_distance, min_distance [cm]
        d = dm.numeric("current_distance")
        if d is None:
            return None
        keep = _downward(dm.numeric("orientation"), len(dm)) & _first(dm.numeric("id"), len(dm))
        mins = dm.numeric("min_distance")
        lo_cm = _typical(mins[keep]) if mins is not None else None
        return dm.t[keep], d[keep] / 100.0, lo_cm / 100.0 if lo_cm is not None else None
    return None


def _downward(orient: np.ndarray | None, n: int) -> np.ndarray:
    """MAV_SENSOR_ROTATION_PITCH_270 (25): facing down; a log without the field has only that one."""
    return np.ones(n, bool) if orient is None else orient == 25


def _first(instance: np.ndarray | None, n: int) -> np.ndarray:
    if instance is None or not np.isfinite(instance).any():
        return np.ones(n, bool)
    return instance == np.nanmin(instance)


def _typical(v: np.ndarray) -> float | None:
    v = v[np.isfinite(v)]
    return float(np.median(v)) if len(v) else None


def ground_segments(ms: Sequence[Measurement], recording_origin: float | None = None) -> list[tuple[float, float]]:
    """The log's stretches on the ground by its throttle: from its start to :data:`MARGIN_S` before
    the throttle first carries the vehicle, and from that long after it last did to the end. None
    without a logged throttle, or one that never carries the vehicle. On the vehicle's clock, or
    with ``recording_origin`` (a tlog's tables' :attr:`~drivers.logs.tables.LogTables.origin`) on
    the recording's, where a tlog's records are: its vehicle's clock began at boot, not with it."""
    r = Readings.of(ms)
    t, t_rx, v = r.columns((Kind.THROTTLE, Kind.ACTUATOR))
    # a THROTTLE's one value, an ACTUATOR's first eight outputs; their median, of those that are numbers
    v = np.where(np.isfinite(v[:, :8]), v[:, :8], np.nan)
    v[~r.only((Kind.THROTTLE, Kind.ACTUATOR)).is_kind((Kind.ACTUATOR,)), 1:] = np.nan
    at = t if recording_origin is None else t_rx - recording_origin
    keep = np.isfinite(v).any(axis=1) & np.isfinite(at)
    if not keep.any():
        return []
    ta, va = at[keep], np.nanmedian(v[keep], axis=1)
    up = np.flatnonzero(va >= TAU_AIRBORNE)
    if not len(up):
        return []
    return [(float(ta[0]), float(ta[up[0]]) - MARGIN_S), (float(ta[up[-1]]) + MARGIN_S, float(ta[-1]))]


def range_clearance(tables: LogTables, ms: Sequence[Measurement]) -> RangeClearance | None:
    """The downward rangefinder's ground clearance (the module's docstring), or None when the log
    has no rangefinder reading on the ground and no parameter that states it."""
    stated = stated_clearance(tables.params)
    raw = raw_range(tables)
    if raw is not None:
        t, d, lo = raw
        on = np.zeros(len(t), bool)
        origin = tables.origin if tables.clock == "recording" else None
        for a, b in ground_segments(ms, origin):
            on |= (t >= a) & (t <= b)
        g = d[on & np.isfinite(d) & (d >= 0)]
        if lo is not None:
            g = g[np.abs(g - lo) > 0.005]  # the floor a sonar clamps to is no distance
        if len(g) >= MIN_READINGS:
            _, counts = np.unique(g, return_counts=True)
            q25, med, q75 = np.percentile(g, [25, 50, 75])
            if counts.max() < CLAMP_SHARE * len(g) and q75 - q25 <= MAX_SPREAD and med <= MAX_CLEARANCE:
                return RangeClearance(
                    float(med),
                    f"the rangefinder on the ground ({len(g)} readings)",
                    stated[0] if stated else None,
                    stated[1] if stated else None,
                    len(g),
                )
    if stated is not None:
        name, metres = stated
        return RangeClearance(metres, f"{name} (the log's parameter)", name, metres)
    return None
