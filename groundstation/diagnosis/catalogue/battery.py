"""The battery's load line, read from the log: the voltage between the battery's readings.

A pack under load reads ``V = V_oc(soc) - R_int I``, and a multirotor's current grows
as the square of its throttle (``I ~ i_0 + i_max tau^2``: rotor power ~ rpm^3, drawn
at the pack's voltage), so ``V ~ V_oc(t) - k tau^2`` with ``k = R_int i_max``. An
autopilot logs the voltage at 1-10 Hz (the simulator's SYS_STATUS: 5 Hz) and the
throttle at 50 Hz and more; held between readings, the voltage misses each sag as
the throttle rises. For ``thrust_voltage`` that miss was most of its residue: on a
simulated n = 2 thrust test flight the held reading put 0.30 m/s^2 RMS of error in
the thrust it predicts, against 0.022 m/s^2 with the true voltage (and a first-order
expansion in ``(V - V_ref) / V_ref``; thrust.py linearises ``(V / V_ref)^n`` about the
estimate of n instead).

So the thrust model carries the latest reading forward by the throttle's change
since it, ``V(t) = V_k - k (tau(t)^2 - tau_k^2)``, with ``k`` fitted here from
consecutive readings: over 1 s ``V_oc`` moves by millivolts, so
``V_(k+1) - V_k = -k (tau_(k+1)^2 - tau_k^2)`` plus the readings' noise, a regression
through the origin. PX4 estimates the pack's internal resistance online for the
same reason (its battery module's ``BAT_R_INTERNAL``); none of numpy, scipy or
pymavlink has it, hence written here. A logged current is not used: it comes at the
voltage's rate, so it cannot fill in between the readings either.

Carried forward as it was read, each reading's noise stays in the thrust until the next:
the simulator's 20 mV at 5 Hz, through ``(V / V_ref)^2``, is 0.035 m/s^2 held for 0.2 s,
process noise of 2.4e-4 (m/s^2)^2/Hz that the thrust model (G_acc 2e-4 with the airframe
known) does not have. On simulated n = 2 flights the range innovations after the fix
failed Ljung-Box (p 0.000 on 2 of 3); without the readings' noise they pass (p 0.64). So
the open-circuit voltage ``V_k + k tau_k^2`` each reading implies is smoothed
(:class:`OpenCircuitVoltage`: level and drift, as the pack discharges) and the voltage
between readings is ``V_oc(t) - k tau(t)^2``.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings

PAIR_GAP = 1.0  # s: consecutive readings further apart than this are not paired
MIN_PAIRS = 20
MIN_SIGNIFICANCE = 4.0  # k is used only this many standard errors above 0


def _readings(
    ms: Sequence[Measurement], throttle: list[tuple[float, float]]
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The battery's readings (t, V) and the throttle^2 in effect at each, or None without enough of either."""
    t, _, values = Readings.of(ms).columns(Kind.BATTERY_VOLTAGE)
    volts = list(zip(t.tolist(), values[:, 0].tolist(), strict=True)) if values.shape[1] else []
    volts = [(t, v) for t, v in volts if math.isfinite(v) and v > 0]
    th = [(t, v) for t, v in throttle if math.isfinite(v)]
    if len(volts) <= MIN_PAIRS or len(th) < 2:
        return None
    t_th = np.array([t for t, _ in th])
    tau = np.array([v for _, v in th])
    t_v = np.array([t for t, _ in volts])
    v = np.array([x for _, x in volts])
    # the throttle in effect at each reading: written before it (one written at the reading's
    # instant has not yet drawn its current; estimator.throttle_at_reading)
    i = np.searchsorted(t_th, t_v, side="left") - 1
    ok = i >= 0
    return t_v[ok], v[ok], tau[i[ok]] ** 2


def _pairs(ms: Sequence[Measurement], throttle: list[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray] | None:
    """Consecutive readings' voltage change and their throttles' change in tau^2."""
    readings = _readings(ms, throttle)
    if readings is None:
        return None
    t_v, v, s = readings
    pair = np.diff(t_v) <= PAIR_GAP
    dv, ds = np.diff(v)[pair], np.diff(s)[pair]
    return (dv, ds) if len(dv) >= MIN_PAIRS else None


def load_line(ms: Sequence[Measurement], throttle: list[tuple[float, float]]) -> tuple[float, float] | None:
    """``(k, sigma_k)`` in volts per unit throttle^2, or None when the log cannot say (no
    voltage, too few readings, or no sag that stands above the readings' noise)."""
    pairs = _pairs(ms, throttle)
    if pairs is None or not np.any(pairs[1]):
        return None
    dv, ds = pairs
    k = -float(dv @ ds / (ds @ ds))
    resid = dv + k * ds
    sigma = math.sqrt(float(resid @ resid) / (len(dv) - 1) / float(ds @ ds))
    if k <= 0 or k < MIN_SIGNIFICANCE * sigma:
        return None
    return k, sigma


def reading_sigma(ms: Sequence[Measurement], throttle: list[tuple[float, float]], k: float = 0.0) -> float | None:
    """One reading's noise [V]: consecutive readings differ by the load line's step plus two
    readings' noise (V_oc moves by millivolts between them); the median absolute residual, so that
    the throttle's steps between readings (where the pairing is least sure) do not count as noise."""
    pairs = _pairs(ms, throttle)
    if pairs is None:
        return None
    dv, ds = pairs
    return float(np.median(np.abs(dv + k * ds)) / 0.6745 / math.sqrt(2.0))


#: the open-circuit voltage's drift rate changes as the current does [V^2/s^3]: a 3-cell pack
#: discharging at 10-20 A drifts 3-6 mV/s, and the rate moves by that over seconds
DRIFT_CHANGE = 2.5e-5


class OpenCircuitVoltage:
    """The pack's open-circuit voltage over the whole log, from its readings ``V_k + k tau_k^2``:
    level and drift rate (a constant-velocity Kalman filter; the drift keeps the level from
    lagging a discharging pack), run forward over every reading and back (filterpy's RTS
    smoother), so that a reading's noise is not carried to the next.

    Smoothed, not filtered: a diagnosis has the whole log. Filtered forward only, the level is
    7.5 mV RMS off the simulator's on a thrust test flight (seed 1015), smoothed 4.3 mV; through
    ``(V / V_ref)^1.5`` that is 0.010 against 0.006 m/s^2 of thrust, held for seconds. With the
    throttle held at its interval's mean (outputs.py) and a tight G_acc (0.00005), the forward-only
    level was the largest error left: that flight's range innovations after the fix failed Ljung-Box
    (p 0.000, positively autocorrelated out to lag 15; 0.56 with the simulator's true voltage)."""

    def __init__(self, t: np.ndarray, v_oc: np.ndarray, sigma: float) -> None:
        kf = KalmanFilter(dim_x=2, dim_z=1)
        kf.x = np.array([v_oc[0], 0.0])
        kf.P = np.diag([sigma**2, 0.01**2])
        kf.H = np.array([[1.0, 0.0]])
        kf.R = np.array([[sigma**2]])
        xs, Ps, Fs, Qs = [], [], [], []
        for j, (tj, z) in enumerate(zip(t, v_oc)):
            dt = tj - t[j - 1] if j else 0.0
            F = np.array([[1.0, dt], [0.0, 1.0]])
            Q = Q_discrete_white_noise(2, dt, DRIFT_CHANGE) if dt > 0 else np.zeros((2, 2))
            if dt > 0:
                kf.predict(F=F, Q=Q)
            kf.update(np.array([z]))
            xs.append(kf.x.copy())
            Ps.append(kf.P.copy())
            Fs.append(F)
            Qs.append(Q)
        x = kf.rts_smoother(np.array(xs), np.array(Ps), np.array(Fs), np.array(Qs))[0]
        self.t = np.asarray(t, dtype=float)
        self.level, self.drift = x[:, 0], x[:, 1]
        self._t, self._level = self.t.tolist(), self.level.tolist()  # read by :meth:`at` at every step

    @classmethod
    def from_log(
        cls, ms: Sequence[Measurement], throttle: list[tuple[float, float]], k: float, sigma: float
    ) -> OpenCircuitVoltage | None:
        """From the log's readings, each with the throttle in effect at it; None without enough of them."""
        readings = _readings(ms, throttle)
        if readings is None or not sigma:
            return None
        t, v, s = readings
        return cls(t, v + k * s, sigma)

    def at(self, t: float) -> float:
        """The level at ``t``: between readings on the line between theirs, beyond the last on its drift."""
        ts, level = self._t, self._level
        if t >= ts[-1]:
            return float(self.level[-1] + self.drift[-1] * (t - ts[-1]))
        # np.interp's arithmetic on floats: a thrust model reads this at every step
        j = bisect_right(ts, t)
        if j == 0:
            return level[0]
        t0, v0 = ts[j - 1], level[j - 1]
        return (level[j] - v0) / (ts[j] - t0) * (t - t0) + v0


def loaded_voltage(
    volt: float,
    tau: float,
    *,
    sag: float | None = None,
    oc: OpenCircuitVoltage | None = None,
    tau2: float | None = None,
    t: float | None = None,
) -> float:
    """The voltage at throttle ``tau`` (the module's docstring): with the fitted load line's
    ``sag`` k, either the smoothed open-circuit voltage ``oc`` at time ``t``, or the latest reading
    ``volt`` taken at throttle^2 ``tau2`` and carried forward to ``tau``; the reading as it is
    without a load line."""
    if not math.isfinite(tau) or volt <= 0.0:
        return volt
    if oc is not None and t is not None:
        return oc.at(t) - (sag or 0.0) * tau * tau
    if not sag or tau2 is None:
        return volt
    return volt - sag * (tau * tau - tau2)
