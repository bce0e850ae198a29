"""The battery's load line, read from the log: the voltage between the battery's readings.

A pack under load reads ``V = V_oc(soc) - R_int I``, and a multirotor's current grows
as the square of its throttle (``I ~ i_0 + i_max tau^2``: rotor power ~ rpm^3, drawn
at the pack's voltage), so ``V ~ V_oc(t) - k tau^2`` with ``k = R_int i_max``. An
autopilot logs the voltage at 1-10 Hz (the simulator's SYS_STATUS: 5 Hz) and the
throttle at 50 Hz and more; held between readings, the voltage misses each sag as
the throttle rises. For ``thrust_voltage`` that miss was most of its residue: on a
simulated n = 2 thrust test flight the held reading put 0.30 m/s^2 RMS of error in
the thrust it predicts, against 0.022 m/s^2 with the true voltage (and the first-order
expansion in ``(V - V_ref) / V_ref`` that thrust.py then used; it now linearises
``(V / V_ref)^n`` about the estimate of n).

So the thrust model carries the latest reading forward by the throttle's change
since it, ``V(t) = V_k - k (tau(t)^2 - tau_k^2)``, with ``k`` fitted here from
consecutive readings: over 1 s ``V_oc`` moves by millivolts, so
``V_(k+1) - V_k = -k (tau_(k+1)^2 - tau_k^2)`` plus the readings' noise, a regression
through the origin. PX4 estimates the pack's internal resistance online for the
same reason (its battery module's ``BAT_R_INTERNAL``); none of numpy, scipy or
pymavlink has it, hence written here. A logged current is not used: it comes at the
voltage's rate, so it cannot fill in between the readings either.
"""
from __future__ import annotations

import math

import numpy as np

from ..measurement import Kind, Measurement

PAIR_GAP = 1.0       # s: consecutive readings further apart than this are not paired
MIN_PAIRS = 20
MIN_SIGNIFICANCE = 4.0   # k is used only this many standard errors above 0


def load_line(ms: list[Measurement], throttle: list[tuple[float, float]]) -> tuple[float, float] | None:
    """``(k, sigma_k)`` in volts per unit throttle^2, or None when the log cannot say (no
    voltage, too few readings, or no sag that stands above the readings' noise)."""
    volts = [(m.t, float(m.value[0])) for m in ms if m.kind is Kind.BATTERY_VOLTAGE and len(m.value)]
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
    t_v, v, s = t_v[ok], v[ok], tau[i[ok]] ** 2
    pair = np.diff(t_v) <= PAIR_GAP
    dv, ds = np.diff(v)[pair], np.diff(s)[pair]
    if len(dv) < MIN_PAIRS or not np.any(ds):
        return None
    k = -float(dv @ ds / (ds @ ds))
    resid = dv + k * ds
    sigma = math.sqrt(float(resid @ resid) / (len(dv) - 1) / float(ds @ ds))
    if k <= 0 or k < MIN_SIGNIFICANCE * sigma:
        return None
    return k, sigma


def loaded_voltage(volt: float, tau: float, values: dict) -> float:
    """The latest reading carried forward by the throttle's change since it (the module's
    docstring); ``values``: the filter's context, with the fitted ``voltage_sag`` k and
    the throttle at the reading, ``voltage_tau2``."""
    k = values.get("voltage_sag")
    s0 = values.get("voltage_tau2")
    if not k or s0 is None or volt <= 0.0 or not math.isfinite(tau):
        return volt
    return volt - k * (tau * tau - s0)
