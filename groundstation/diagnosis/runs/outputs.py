"""The throttle between its records, for the thrust model's diagnosis: each record held at its interval's mean.

An autopilot computes its outputs at 250-400 Hz and logs them at 10-50 Hz (the simulator's
SERVO_OUTPUT_RAW: 50 Hz from a 250 Hz controller). The thrust model takes the throttle as its
input and holds each record until the next (the filter's zero-order hold), so while the
throttle moves, the held value is up to one record behind it: a lag of half a record period
on average, 10 ms at 50 Hz. That was the base model's last mismatch on the simulated thrust
test flights:

* the range innovations' excursion after a throttle step (the throttle climbing back from 0.20
  at 0.75/s, held 0.0075 low on average: 0.17 m/s^2 of thrust for 0.3 s, +1 cm of height), in
  every such flight, clean or not; with ``thrust_voltage`` n = 2 on seed 1018 it failed the
  range's Ljung-Box after the fix (p 0.013; with the simulator's true throttle at 100 Hz, 0.062);
* ``actuator_lag`` read 4-8 ms short at every size (README, the thrust table): the hold's own
  lag given back.

With the whole log at hand (a diagnosis is not causal) each record is held at the mean of the
straight line to the next one, ``(tau_k + tau_k+1) / 2``: what the throttle did over the
interval, to second order, for a throttle that moves smoothly between records. A *jump* is
not spread: a change several times its neighbours' (:data:`JUMP_FACTOR`, and above the PWM's
1 us quantum, :data:`JUMP_FLOOR`) is taken at the record that first shows it, as the hold
takes it. Interpolating every record (a first-order hold) spreads the
thrust test flight's height steps, which fall on the records' grid, 10 ms early, and breaks
``thrust_voltage`` (range NIS 2.16 on an n = 2 flight). A real autopilot's jump between
records is then placed up to one period late, as the hold places it. Records more than
:data:`MAX_GAP` apart (a dropout) are held as logged.

The live filter keeps the hold: it cannot know the next record. numpy's and scipy's
interpolators have no notion of a jump to keep, hence this.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from groundstation.core.measurement import Kind, Measurement

#: a record-to-record change this many times the larger of its neighbours' is a jump
JUMP_FACTOR = 3.0
#: and above this (5 PWM quanta: the outputs are whole microseconds, 0.001 of the range)
JUMP_FLOOR = 0.005
#: s: records further apart than this are not bridged
MAX_GAP = 0.2


def interval_means(
    ms: Sequence[Measurement], kinds: tuple[Kind, ...] = (Kind.ACTUATOR, Kind.THROTTLE)
) -> list[Measurement]:
    """``ms`` with each logged output record (ACTUATOR, THROTTLE) held at its interval's mean: see the
    module's docstring. Each kind and instance is its own sequence; a stand-in throttle (``derived/``)
    is a 0/1 signal and stays as it is."""
    out = list(ms)
    for kind in kinds:
        by_instance: dict[int, list[int]] = {}
        for i, m in enumerate(out):
            if m.kind is kind and not m.source.startswith("derived"):
                by_instance.setdefault(m.instance, []).append(i)
        for idx in by_instance.values():
            widths = {len(out[i].value) for i in idx}
            if len(idx) < 3 or len(widths) != 1:
                continue
            t = np.array([out[i].t for i in idx])
            v = np.array([out[i].value for i in idx], dtype=float)
            held = _interval_means(t, v)
            for j, i in enumerate(idx):
                out[i] = out[i]._replace(value=held[j])
    return out


def _interval_means(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(n, k) records at times t -> the same, each at the mean of the line to the next unless a jump, a
    gap or a missing value lies between them."""
    d = np.diff(v, axis=0)  # (n - 1, k)
    a = np.abs(d)
    a = np.where(np.isfinite(a), a, 0.0)
    before = np.vstack([np.zeros((1, a.shape[1])), a[:-1]])
    after = np.vstack([a[1:], np.zeros((1, a.shape[1]))])
    jump = a > JUMP_FACTOR * np.maximum(before, after) + JUMP_FLOOR
    bridge = ~jump & np.isfinite(d) & (np.diff(t) <= MAX_GAP)[:, None]
    held = v.copy()
    held[:-1] = np.where(bridge, v[:-1] + 0.5 * d, v[:-1])
    return held
