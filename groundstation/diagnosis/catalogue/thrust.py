"""The thrust-model filter's candidates: where thrust-side effects can show. The filter itself, the
quadcopter document's with the airframe's drag added, is :mod:`.thrust_model`; the altitude filter
takes the accelerometer as its input, so it never predicts thrust and cannot see thrust loss.

Candidates:

* ``thrust_voltage``: no voltage compensation in the ESCs, ``a_T = a_T0 (V / V_ref)^n``
  (V_ref: the voltage alpha0 was read at), one state n, linearised about its estimate
  as an EKF does (:func:`thrust_voltage`); V between the battery's readings follows
  the throttle (battery.py);
* ``thrust_ground_effect``: Cheeseman-Bennett, ``a_T / (1 - (R / 4h)^2)``, one state q = R^2
  (h >= 0.1 m, rotors carrying), linearised about its estimate (:func:`thrust_ground_effect`);
* ``actuator_lag``: the thrust follows the throttle through a first-order lag,
  profiled over its time constant like a sensor delay;
* the barometer's effects of the altitude catalogue, which act on the same
  baro measurement, and the range's slant under tilt;
* ``sensor_delay`` of the range, profiled over 0-0.5 s: a late range reading, which the
  baro does not share (a lagged thrust reaches both).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from groundstation.core.measurement import Kind, Measurement
from groundstation.diagnosis.catalogue.altitude import UNOBSERVABLE, altitude_catalogue, sensor_delay
from groundstation.diagnosis.catalogue.candidate import Candidate, state_param
from groundstation.diagnosis.catalogue.thrust_model import GE_MIN_H
from groundstation.estimation.models.base import LinearModel


# -- the thrust-side candidates ------------------------------------------------------------------
def thrust_voltage(model: LinearModel) -> LinearModel:
    """``vz_dot += a_T c (r^n - 1)``, ``r = V / V_ref``, linearised about the estimate n^:
    ``a_T c (r^n^ - 1 - n^ r^n^ ln r)`` (the input a_V, :func:`.thrust_model._voltage_terms`) plus
    ``n a_T c r^n^ ln r`` (the coupling). The first-order expansion in (V - V_ref) / V_ref
    used before read n = 2 as 1.77-1.87 on simulated thrust test flights: the pack sags by
    up to 20 % at the throttle steps, where r^2 and 1 + 2 (r - 1) differ by 4 % of the thrust."""
    iv = model.index("vz")

    def coupling(u):
        # a pure function of u: the filter probes A with test inputs
        c = np.zeros((model.n, 1))
        if u is None or len(u) < 9 or u[1] == 0.0 or u[3] <= 0.0 or u[6] <= 0.0:
            return c
        r = u[3] / u[6]
        c[iv, 0] = u[5] * u[1] * r ** u[7] * math.log(r)
        return c

    return model.augmented(states=["n_voltage"], coupling=coupling, Qc_extra=[0.0], x0_extra=[0.0], P0_extra=[3.0**2])


def thrust_ground_effect(model: LinearModel) -> LinearModel:
    """``vz_dot += a_T c (1 / (1 - s) - 1)``, ``s = (R / 4h)^2`` (Cheeseman and Bennett), the state
    R^2, linearised about its estimate as an EKF does: the coupling's column is the slope
    ``a_T c / (16 h^2 (1 - s)^2)`` (:func:`_input` passes the height as ``h (1 - s)``) and the rest,
    ``-a_T c s^2 / (1 - s)^2``, goes in through a_V. The first order, ``a_T c s``, is 0.4 % of the
    thrust short at h = R; with the throttle between its records, the smoothed voltage and a tight
    G_acc (0.00005) it read R = 0.25 m 3-7 % high with the range's Ljung-Box p at 0.000-0.004 on all
    three flights. The formula holds for h >= R (the simulator's
    too); below, the height it is given is R's estimate, so the term stays at its h = R value. With
    1/h^2 carried on below R, a quadcopter hovering at 0.17 m with R = 0.25 m had its ground effect
    predicted at 14 % of the thrust for 6.7 %, and R read 10 % low (0.226 m) with the range's NIS at
    1.15."""
    iv = model.index("vz")

    def coupling(u):
        c = np.zeros((model.n, 1))
        if u is None or len(u) < 9 or u[1] == 0.0 or u[4] < GE_MIN_H:
            return c
        c[iv, 0] = u[5] * u[1] / (16.0 * u[4] ** 2)
        return c

    return model.augmented(states=["R2_rotor"], coupling=coupling, Qc_extra=[0.0], x0_extra=[0.0], P0_extra=[0.1**2])


def _near_the_ground(run, t_from: float) -> int:
    """thrust_ground_effect's support: the scored baro and range updates below two fitted rotor
    radii (there the first-order term adds >= 1.6 % of thrust; above, it fades as 1/h^2)."""
    r = math.sqrt(max(run.final("R2_rotor")[0], 0.0))
    iz = run.model.index("z")
    n = 0
    for name in ("baro", "range"):
        tr = run.sensors.get(name)
        if tr is not None and len(tr.t):
            z = np.interp(tr.t, run.t, run.x[:, iz])
            n += int(((tr.t >= t_from) & (z >= GE_MIN_H) & (z < 2.0 * r)).sum())
    return n


def _rotor_radius(run) -> dict:
    q, s = run.final("R2_rotor")
    r = math.sqrt(max(q, 0.0))
    return {"R": r, "sigma_R": s / (2 * r) if r > 0 else math.inf}


def _rotor_radius_limit(run, z: float) -> dict:
    """The state is R^2: its size z sigma_R2 is where the gain is, then R = sqrt of it (sigma_R, a
    linearisation at the estimate, is no guide near R = 0)."""
    return {"R": math.sqrt(z * run.final("R2_rotor")[1])}


def lag_throttle(ms: Sequence[Measurement], tc: float) -> Sequence[Measurement]:
    """The throttle as the rotors follow it through a first-order lag of time constant tc, for
    each stream of outputs (a throttle and the PWM outputs each their own: one state shared between
    them was reset at every switch) and each output within it (unused outputs are NaN and stay so:
    one NaN once reset the whole filter at every sample, and no lag was ever found).

    A logged output x_k is what was written at t_k and held to the next one, as the model holds
    its inputs (zero-order hold). Over [t_k, t_k+1) the lag's state y moves from y_k towards x_k,

        y(t_k + s) = x_k + (y_k - x_k) e^(-s/tc),

    and the record put in its place is that motion's mean over the interval,

        y_bar_k = x_k + (y_k - x_k) (tc/D) (1 - e^(-D/tc)),   D = t_k+1 - t_k,

    so that the held input gives the velocity change the lagged thrust gives (exact for a held
    input). tc -> 0 gives x_k back: the base model. (Updating the lag's state with x_k as if written
    at t_k-1, and holding y_k, reads a step written at t_k 20 ms early: a 0.05 s lag read
    0.042-0.056 s as the simulator's outputs changed timing.)"""
    if tc <= 0:
        return ms
    out: list[Measurement] = []
    state: dict[Kind, tuple[np.ndarray, np.ndarray, float]] = {}
    nxt = _next_times(ms)
    for i, m in enumerate(ms):
        if m.kind in (Kind.THROTTLE, Kind.ACTUATOR):
            x = np.asarray(m.value, dtype=float)
            last = state.get(m.kind)
            if last is None or len(last[0]) != len(x):
                y = x.copy()
            else:
                y, x_last, t_last = last
                a = 1.0 - math.exp(-max(m.t - t_last, 0.0) / tc)
                y = np.where(np.isfinite(y) & np.isfinite(x_last), y + (x_last - y) * a, x)
                y = np.where(np.isfinite(x), y, x)
            state[m.kind] = (y, x, m.t)
            d = nxt[i] - m.t
            w = tc / d * (1.0 - math.exp(-d / tc)) if d > 0 else 1.0
            m = m._replace(value=x + (y - x) * w)
        out.append(m)
    return out


def _next_times(ms: Sequence[Measurement]) -> list[float]:
    """For each record, the time of the next of its kind (its own time for the last)."""
    out = [0.0] * len(ms)
    nxt: dict = {}
    for i in range(len(ms) - 1, -1, -1):
        m = ms[i]
        out[i] = nxt.get(m.kind, m.t)
        nxt[m.kind] = m.t
    return out


#: s: the range delays the thrust model's profile starts from (its sonar's can be tenths of a second)
RANGE_DELAYS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)


def thrust_catalogue(kinds: set) -> list[Candidate]:
    has_throttle = bool(kinds & {Kind.THROTTLE, Kind.ACTUATOR})
    cands = []
    if has_throttle:
        if Kind.BATTERY_VOLTAGE in kinds:
            cands.append(
                Candidate(
                    "thrust_voltage", 1, {Kind.BATTERY_VOLTAGE}, None, thrust_voltage, state_param("n", "n_voltage")
                )
            )
        cands.append(
            Candidate(
                "thrust_ground_effect",
                1,
                set(),
                None,
                thrust_ground_effect,
                _rotor_radius,
                support=_near_the_ground,
                limit=_rotor_radius_limit,
            )
        )
        cands.append(
            Candidate(
                "actuator_lag",
                1,
                set(),
                "throttle",
                None,
                None,
                delays=(0.0, 0.03, 0.06, 0.12, 0.24, 0.4),
                reshape=lag_throttle,
            )
        )
    # the barometer's own effects act on the same measurement in this model, and so does the ToF's slant
    # under tilt (a simulated thrust test flight, nothing declared: the slant went unnamed, 3.8 cm height
    # error)
    cands += [c for c in altitude_catalogue(kinds) if c.sensor == "baro" or c.name == "range_tilt"]
    # the range's own delay, on a grid to half a second: a lagged thrust reaches the baro too, a late
    # range reading does not. On underpowered.log, with four effects in, the range innovations still
    # followed the vertical speed 0.3 s earlier (49 % of their variance), and a delayed range scored
    # Delta BIC -970 against the lag's -898 (ArduCopter 3.0 passes its sonar through a 5-sample mode filter)
    cands.append(sensor_delay("range", RANGE_DELAYS, {Kind.RANGE}))
    return [c for c in cands if c.needs <= kinds]


UNOBSERVABLE_THRUST = {
    "accel_bias": "the thrust model does not use the accelerometer",
    "accel_scale": "the thrust model does not use the accelerometer",
    "gyro_bias": "acts on the attitude, which this model takes as given: run the attitude model",
    "imu_misalignment": "acts on the IMU, which this model does not use: run the attitude model",
    "range_offset": UNOBSERVABLE["altitude"]["range_offset"] + " (this model holds its ToF offset state d_tof at 0)",
}
