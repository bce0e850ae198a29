"""Each effect found, as what the user's autopilot would take: parameters to set, and a file
the ground station loads (Mission Planner, MAVProxy and QGroundControl read ``NAME,VALUE``
lines with ``#`` comments).

The translation, per effect (``k`` as the catalogue gives it; rho g is the air's weight per
metre at the log's own pressure and temperature, about 12 Pa/m at sea level):

==================  ======================================  ======================================
effect              ArduPilot                               PX4
==================  ======================================  ======================================
sensor_delay(baro)  EK3_HGT_DELAY [ms]                      EKF2_BARO_DELAY [ms]
sensor_delay(gps)   GPS_DELAY_MS [ms] (GPS1_DELAY_MS 4.6+)  EKF2_GPS_DELAY [ms]
sensor_delay(range) (no EKF parameter)                      EKF2_RNG_DELAY [ms]
accel_scale s       INS_ACCSCAL_Z / (1 + s)                 CAL_ACC0_ZSCALE / (1 + s)
accel_bias z b      INS_ACCOFFS_Z + b                       CAL_ACC0_ZOFF + b
baro_thrust k       BARO1_THST_SCALE = -rho g k [Pa per     (no parameter)
                    unit throttle; ArduPilot 4.5+]
baro_ground_effect  EK3_GND_EFF_DZ = |A| [m]                EKF2_GND_EFF_DZ = |A|, EKF2_GND_MAX_HGT
                                                            = 3 h0 [m]
baro_thermal k      (no parameter: AP's TCAL is for IMUs)   TC_B0_X1 = -rho g k [Pa/K], TC_B_ENABLE 1
thrust_voltage      MOT_BAT_VOLT_MAX / _MIN from the pack   MC_BAT_SCALE_EN = 1
vibration peak      INS_HNTCH_* (throttle-referenced)       IMU_GYRO_NF0_FRQ / _BW
range clearance     RNGFND1_GNDCLEAR [cm], where the        EKF2_MIN_RNG [m], likewise
                    ground readings say other than it
noise (sensor)      EK3_ALT_M_NSE (baro), EK3_RNG_M_NSE,    EKF2_BARO_NOISE, EKF2_RNG_NOISE,
                    EK3_POSNE_M_NSE (GPS) [m]               EKF2_GPS_P_NOISE [m]
==================  ======================================  ======================================

No value outside the range its autopilot documents is written (:mod:`drivers.mavlink.param_ranges`).

Signs: the catalogue's effects add to the reading (a baro ``k`` > 0 reads high as throttle
rises); ArduPilot subtracts ``BARO1_THST_SCALE`` times throttle from the pressure, so a baro
that reads high (pressure low) takes a negative scale. An effect with no parameter anywhere
(a range sensor's tilt, which both EKFs already model; a drift) is listed with the reason.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.mavlink.param_ranges import outside
from groundstation.core.imu import IMU_KINDS, ImuColumns
from groundstation.core.measurement import Kind, Measurement
from groundstation.diagnosis.catalogue.thrust_model import throttle_series
from groundstation.diagnosis.effect import Effect
from groundstation.diagnosis.engine import Diagnosis
from groundstation.diagnosis.triage.finding import cell_count
from groundstation.estimation.stated import TAU_AIRBORNE

G = 9.80665
R_AIR = 287.05  # J/(kg K)


#: [s] a rotor wash's lag past which a compensation proportional to the throttle leaves some of it
#: (the simulated autopilot's height with the scale set: 17 cm RMS after 151 with a 0.48 s lag, 6-7
#: cm without the wash)
LAG_UNCOMPENSATED_S = 0.1


@dataclass
class ParamSuggestion:
    autopilot: str  # "ArduPilot" or "PX4"
    name: str  # the parameter, or "" when there is none
    value: float | None
    effect: str
    why: str

    def as_json(self) -> dict:
        return {
            "autopilot": self.autopilot,
            "name": self.name,
            "value": self.value,
            "effect": self.effect,
            "why": self.why,
        }


def _mean(ms: Sequence[Measurement], kind: Kind) -> float | None:
    v = [float(m.value[0]) for m in ms if m.kind is kind]
    return float(np.mean(v)) if v else None


def rho_g(ms: Sequence[Measurement]) -> float:
    """rho g [Pa/m] at the log's mean pressure and temperature (ISA sea level if it has neither)."""
    p, t = _mean(ms, Kind.BARO_PRESSURE), _mean(ms, Kind.TEMPERATURE)
    if p and t and p > 1e4 and t > 150:
        return p / (R_AIR * t) * G
    return 1.225 * G


def _current(params: dict, name: str, default: float) -> float:
    v = params.get(name)
    return float(v) if v is not None and math.isfinite(v) and v != 0 else default


#: (which autopilot, name, value or None, effect, why): a suggestion's adder (:func:`suggest`)
Add = Callable[[str, str, "float | None", str, str], None]


@dataclass(frozen=True)
class _LogFacts:
    """What an effect's parameters are scaled by: the log's own parameters, its air's rho g [Pa/m],
    and its measurements (the pack's voltage)."""

    params: dict[str, float]
    rho_g: float
    ms: Sequence[Measurement]


def suggest(
    d: Diagnosis, ms: Sequence[Measurement], params: dict[str, float], autopilot: str = ""
) -> list[ParamSuggestion]:
    """What to set for each effect found and each noise level that differs from the model's.
    ``ms``: the log's measurements (air density, the pack); ``params``: the log's own parameters
    (for values that scale what is set now); ``autopilot``: "ardupilot", "px4" or "" (both)."""
    out: list[ParamSuggestion] = []
    ap, px = autopilot in ("ardupilot", ""), autopilot in ("px4", "")

    def add(which: str, name: str, value: float | None, effect: str, why: str) -> None:
        if (which == "ArduPilot" and ap) or (which == "PX4" and px):
            v = None if value is None else float(f"{value:.4g}")
            refused = outside(name, v) if v is not None and name else None
            if refused is not None:  # kept in the report, with why, and written to no file
                why, v = f"{why}; {refused}", None
            out.append(ParamSuggestion(which, name, v, effect, why))

    facts = _LogFacts(params, rho_g(ms), ms)
    for e in [*d.effects, *d.beside]:
        base, _, sensor = e.name.partition("(")
        sensor = sensor.rstrip(")") or str(e.evidence.get("sensor", ""))
        for_effect = _FOR_EFFECT.get(base)
        if for_effect is None or not for_effect(add, e, sensor, facts):
            add("ArduPilot", "", None, e.name, "no autopilot parameter for this effect")
            add("PX4", "", None, e.name, "no autopilot parameter for this effect")
    c = d.clearance
    if c is not None and c.readings and (c.disagrees or (c.parameter is None and c.metres >= 0.005)):
        why = f"on the ground the rangefinder reads {c.metres * 100:.1f} cm ({c.readings} readings)" + (
            f"; {c.parameter} says {c.parameter_metres * 100:.1f} cm" if c.parameter_metres is not None else ""
        )
        add("ArduPilot", "RNGFND1_GNDCLEAR", round(c.metres * 100.0), "range_clearance", why + " [cm]")
        add("PX4", "EKF2_MIN_RNG", c.metres, "range_clearance", why + " [m]")
    names = {"baro": ("EK3_ALT_M_NSE", "EKF2_BARO_NOISE"), "range": ("EK3_RNG_M_NSE", "EKF2_RNG_NOISE"),
             "gps": ("EK3_POSNE_M_NSE", "EKF2_GPS_P_NOISE"),
             "gps_vz": ("EK3_VELD_M_NSE", "EKF2_GPS_V_NOISE")}  # fmt: skip
    for n in d.noise:
        if n.differs and n.sensor in names:
            unit = "m/s" if n.sensor == "gps_vz" else "m"
            why = f"{n.sensor} noise in this log {n.sigma_data:.3g} {unit} (the model had {n.sigma_model:.3g})"
            add("ArduPilot", names[n.sensor][0], n.sigma_data, f"noise({n.sensor})", why)
            add("PX4", names[n.sensor][1], n.sigma_data, f"noise({n.sensor})", why)
    return out


# Each effect's parameters (the module's table): add what to set for ``e`` and say True, or False
# when its parameters hold nothing to set (the effect is then said to have no autopilot parameter).


def _sensor_delay(add: Add, e: Effect, sensor: str, facts: _LogFacts) -> bool:
    p = e.params
    if "seconds" not in p:
        return False
    ms_ = round(1000.0 * p["seconds"])
    why = f"{sensor} lags the accelerometer by {p['seconds'] * 1000:.0f} ms"
    if sensor == "baro":
        add("ArduPilot", "EK3_HGT_DELAY", ms_, e.name, why)
        add("PX4", "EKF2_BARO_DELAY", ms_, e.name, why)
    elif sensor == "gps" and e.evidence.get("form") == "height":
        # the height late and the velocity of the same fix on time: the EKFs' one GPS delay would make
        # the velocity late instead
        why += ", its vertical velocity on time; the EKF's GPS delay moves both, so none is set"
        add("ArduPilot", "", None, e.name, why)
        add("PX4", "", None, e.name, why)
    elif sensor == "gps":
        add("ArduPilot", "GPS_DELAY_MS", ms_, e.name, why + " (GPS1_DELAY_MS from ArduPilot 4.6)")
        add("PX4", "EKF2_GPS_DELAY", ms_, e.name, why)
    elif sensor == "range":
        add("ArduPilot", "", None, e.name, why + "; ArduPilot's EKF has no rangefinder delay parameter")
        add("PX4", "EKF2_RNG_DELAY", ms_, e.name, why)
    return True


def _accel_scale(add: Add, e: Effect, sensor: str, facts: _LogFacts) -> bool:
    if "s" not in e.params:
        return False
    s, params = e.params["s"], facts.params
    why = f"the accelerometer reads {s:+.2%} along z; the calibration's scale divided by 1 + s"
    add("ArduPilot", "INS_ACCSCAL_Z", _current(params, "INS_ACCSCAL_Z", 1.0) / (1 + s), e.name, why)
    add("PX4", "CAL_ACC0_ZSCALE", _current(params, "CAL_ACC0_ZSCALE", 1.0) / (1 + s), e.name, why)
    return True


def _accel_bias(add: Add, e: Effect, sensor: str, facts: _LogFacts) -> bool:
    if "z" not in e.params:
        return False
    b, params = e.params["z"], facts.params
    why = f"the accelerometer reads {b:+.3f} m/s^2 along z; the offset is subtracted from the reading"
    add("ArduPilot", "INS_ACCOFFS_Z", params.get("INS_ACCOFFS_Z", 0.0) + b, e.name, why)
    add("PX4", "CAL_ACC0_ZOFF", params.get("CAL_ACC0_ZOFF", 0.0) + b, e.name, why)
    return True


def _baro_thrust(add: Add, e: Effect, sensor: str, facts: _LogFacts) -> bool:
    p, rho_g = e.params, facts.rho_g
    if "k" not in p:
        return False
    why = (
        f"the baro reads {p['k']:+.2f} m high per unit throttle; ArduPilot 4.5+ subtracts the scale times "
        f"throttle from the pressure ({rho_g:.2f} Pa/m here)"
    )
    if "k_tw" in p:
        # the thrust form (catalogue.altitude.baro_thrust_by_thrust): k is k_tw through the throttle's map
        why += f"; the wash follows the thrust ({p['k_tw']:+.2f} m per unit thrust over weight)"
    if p.get("tc", 0.0) > LAG_UNCOMPENSATED_S:
        # the compensation is proportional to the throttle as it is now: the wash's lag stays
        why += (
            f"; the wash lags the throttle by {p['tc']:.2f} s, which the compensation does not follow "
            "(what is left shows in climbs and descents)"
        )
    add("ArduPilot", "BARO1_THST_SCALE", -rho_g * p["k"], e.name, why)
    add("PX4", "", None, e.name, "PX4 has no throttle compensation of the baro")
    return True


def _baro_ground_effect(add: Add, e: Effect, sensor: str, facts: _LogFacts) -> bool:
    p = e.params
    if "A" not in p:
        return False
    why = f"the baro is off by {p['A']:+.2f} m near the ground (falling off over {p.get('h0', math.nan):.2f} m)"
    add("ArduPilot", "EK3_GND_EFF_DZ", min(abs(p["A"]), 10.0), e.name, why + "; the EKF's dead zone there")
    add("PX4", "EKF2_GND_EFF_DZ", abs(p["A"]), e.name, why)
    if "h0" in p:
        add("PX4", "EKF2_GND_MAX_HGT", 3.0 * p["h0"], e.name, "where the ground effect has fallen to 5 %")
    return True


def _baro_thermal(add: Add, e: Effect, sensor: str, facts: _LogFacts) -> bool:
    if "k" not in e.params:
        return False
    k = e.params["k"]
    why = f"the baro drifts {k:+.3f} m per K of its temperature"
    add("ArduPilot", "", None, e.name, why + "; ArduPilot's temperature calibration (TCAL) covers the IMUs only")
    add("PX4", "TC_B0_X1", -facts.rho_g * k, e.name, why + " (Pa/K; with TC_B_ENABLE = 1)")
    add("PX4", "TC_B_ENABLE", 1, e.name, "turns the baro's temperature compensation on")
    return True


def _thrust_voltage(add: Add, e: Effect, sensor: str, facts: _LogFacts) -> bool:
    why = f"thrust falls with the pack's voltage (exponent {e.params.get('n', math.nan):.2f})"
    volts = [float(m.value[0]) for m in facts.ms if m.kind is Kind.BATTERY_VOLTAGE]
    if volts:
        cells = cell_count(float(np.percentile(volts, 99)))
        add("ArduPilot", "MOT_BAT_VOLT_MAX", 4.2 * cells, e.name, why + f"; {cells}S pack, full")
        add("ArduPilot", "MOT_BAT_VOLT_MIN", 3.3 * cells, e.name, why + f"; {cells}S pack, empty")
    add("PX4", "MC_BAT_SCALE_EN", 1, e.name, why)
    return True


_FOR_EFFECT: dict[str, Callable[[Add, Effect, str, _LogFacts], bool]] = {
    "sensor_delay": _sensor_delay,
    "accel_scale": _accel_scale,
    "accel_bias": _accel_bias,
    "baro_thrust": _baro_thrust,
    "baro_ground_effect": _baro_ground_effect,
    "baro_thermal": _baro_thermal,
    "thrust_voltage": _thrust_voltage,
}


#: PX4 parameters that are integers (the rest are floats), for QGroundControl's file's type column
_PX4_INTEGERS = {"TC_B_ENABLE", "MC_BAT_SCALE_EN"}
MAV_PARAM_TYPE_INT32, MAV_PARAM_TYPE_REAL32 = 6, 9


def write_param_file(path: Path, suggestions: list[ParamSuggestion], autopilot: str, source: str) -> int:
    """The settable suggestions for one autopilot, as its ground stations load them: ArduPilot's
    ``NAME,VALUE`` (Mission Planner, MAVProxy), PX4's QGroundControl file (``sysid compid NAME
    VALUE type``, tab-separated). Each value follows a comment saying why. Returns how many."""
    rows = [s for s in suggestions if s.autopilot == autopilot and s.name and s.value is not None]
    lines = [f"# {autopilot} parameters from the diagnosis of {source}", "# review each before loading"]
    for s in rows:
        lines.append(f"# {s.effect}: {s.why}")
        if autopilot == "PX4":
            integer = s.name in _PX4_INTEGERS
            value = f"{int(round(s.value))}" if integer else f"{s.value:.6g}"  # type: ignore[arg-type]
            kind = MAV_PARAM_TYPE_INT32 if integer else MAV_PARAM_TYPE_REAL32
            lines.append(f"1\t1\t{s.name}\t{value}\t{kind}")
        else:
            lines.append(f"{s.name},{s.value:g}")
    path.write_text("\n".join(lines) + "\n")
    return len(rows)


#: the rotor harmonic must stand this far above the spectrum's median to set a notch on it
NOTCH_PROMINENCE = 50.0
NOTCH_MIN_HZ = 20.0  # below: the airframe's own motion, not the rotors


def notch_from_imu(ms: Sequence[Measurement], imu: ImuColumns | None = None) -> tuple[float, float, float, str] | None:
    """The IMU's vibration peak in flight, for a harmonic notch: (frequency [Hz], its prominence
    over the spectrum's median, the median throttle there, the sensor it stands out on), or None
    when the IMU is too slow to show rotor harmonics (below 200 Hz) or no peak stands out. Welch's
    PSD per axis, summed, of the gyro and of the accelerometer (a rotor harmonic shows on both,
    more or less), over the samples with the throttle above idle. A log without a throttle record
    (a ULog with neither ``actuator_controls_0`` nor ``vehicle_thrust_setpoint``) is masked by its
    motor outputs' mean carrying the vehicle (:data:`~groundstation.estimation.stated.TAU_AIRBORNE`),
    as its ground segments are: over every sample, a long armed idle's own harmonic outweighed the
    flight's. The outputs are not the autopilot's throttle scale, so no hover throttle is read from
    them.
    ``imu``: the raw IMU as columns (else read from ``ms``)."""
    if imu is None:
        _, imu = ImuColumns.split(m for m in ms if m.kind in IMU_KINDS)
    thr = [(m.t, float(m.value[0])) for m in ms if m.kind is Kind.THROTTLE]
    idle, on_throttle_scale = 0.1, bool(thr)
    if not thr:
        thr, idle = throttle_series(ms), TAU_AIRBORNE
    best: tuple[float, float, float, str] | None = None
    for kind in (Kind.GYRO, Kind.ACCEL):
        sensor = imu.get(kind, 0)
        if sensor is None or len(sensor) < 2048:
            continue
        t = sensor.t
        rate = (len(t) - 1) / max(t[-1] - t[0], 1e-9)
        if rate < 200.0:
            continue
        flying, hover = np.ones(len(t), bool), math.nan
        if thr:
            tt, tv = np.array(thr).T
            u = np.interp(t, tt, tv)
            flying = u > idle
            hover = float(np.median(u[flying])) if flying.any() and on_throttle_scale else math.nan
        if flying.sum() < 2048:
            continue
        x = sensor.values(flying)
        f, psd = _welch_summed(x, x.mean(axis=0), rate)
        band = (f >= NOTCH_MIN_HZ) & (f <= 0.45 * rate)
        if not band.any():
            continue
        k = int(np.argmax(np.where(band, psd, 0.0)))
        prominence = float(psd[k] / np.median(psd[band]))
        if prominence >= NOTCH_PROMINENCE and (best is None or prominence > best[1]):
            best = (float(f[k]), prominence, hover, "gyro" if kind is Kind.GYRO else "accelerometer")
    return best


#: Welch segments [samples] (half overlapping), and how many of them are transformed at once
NOTCH_SEGMENT = 1024
_SEGMENTS_AT_ONCE = 256


def _welch_summed(x: np.ndarray, mean: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """SciPy's Welch PSD of ``x - mean`` (samples by rows), summed over the columns: the mean of the
    segments' periodograms, taken :data:`_SEGMENTS_AT_ONCE` segments at a time. ``welch`` over the
    whole record would hold every segment detrended, windowed and transformed at once: a 1-hour
    1 kHz gyro's are 0.6 GB."""
    from scipy.signal import welch  # SciPy's Welch estimate: the standard spectrum of a long record

    step = NOTCH_SEGMENT // 2
    n_seg = (len(x) - NOTCH_SEGMENT) // step + 1
    f, total = np.zeros(0), np.zeros(0)
    for s0 in range(0, n_seg, _SEGMENTS_AT_ONCE):
        s1 = min(s0 + _SEGMENTS_AT_ONCE, n_seg)
        part = x[s0 * step : (s1 - 1) * step + NOTCH_SEGMENT] - mean  # segments s0 .. s1-1, whole
        f, pxx = welch(part, fs=rate, nperseg=NOTCH_SEGMENT, axis=0)
        total = pxx.sum(axis=1) * (s1 - s0) + (total if len(total) else 0.0)
    return f, total / max(n_seg, 1)


def suggest_notch(
    ms: Sequence[Measurement], autopilot: str = "", imu: ImuColumns | None = None
) -> list[ParamSuggestion]:
    """A throttle-referenced harmonic notch on the gyro's rotor peak (ArduPilot INS_HNTCH_*, mode 1:
    the frequency scales with the square root of the throttle from INS_HNTCH_REF; PX4's static
    notch IMU_GYRO_NF0_*), bandwidth half the frequency as ArduPilot's guide advises."""
    peak = notch_from_imu(ms, imu)
    if peak is None:
        return []
    freq, prominence, hover, sensor = peak
    why = f"the {sensor}'s vibration peaks at {freq:.0f} Hz in flight ({prominence:.0f} times the spectrum's median)"
    out = []
    if autopilot in ("ardupilot", ""):
        out += [
            ParamSuggestion("ArduPilot", "INS_HNTCH_ENABLE", 1, "vibration", why),
            ParamSuggestion("ArduPilot", "INS_HNTCH_MODE", 1, "vibration", "the notch follows the throttle"),
            ParamSuggestion("ArduPilot", "INS_HNTCH_FREQ", float(f"{freq:.4g}"), "vibration", why),
            ParamSuggestion("ArduPilot", "INS_HNTCH_BW", float(f"{freq / 2:.4g}"), "vibration", "half the frequency"),
        ]
        if math.isfinite(hover):
            out.append(
                ParamSuggestion("ArduPilot", "INS_HNTCH_REF", float(f"{hover:.3g}"), "vibration", "the hover throttle")
            )
    if autopilot in ("px4", ""):
        out += [
            ParamSuggestion("PX4", "IMU_GYRO_NF0_FRQ", float(f"{freq:.4g}"), "vibration", why),
            ParamSuggestion("PX4", "IMU_GYRO_NF0_BW", float(f"{freq / 2:.4g}"), "vibration", "half the frequency"),
        ]
    return out
