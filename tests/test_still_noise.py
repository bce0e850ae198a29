"""The baro's noise from the still stretch before the first take-off (estimation.still_noise): read
while the motors are stopped, from consecutive readings' differences, and used in flight only, only
without a range sensor, only where it differs from the model's by more than the sampling error."""

import numpy as np

from groundstation.core.measurement import Kind, Measurement
from groundstation.estimation import still_noise
from groundstation.estimation.context import Context

R_MODEL = np.array([[0.338**2]])


def _still_stretch(sigma: float, n: int, *, drift: float = 0.0, seed: int = 1) -> Context:
    """``n`` baro altitudes at 25 Hz with the motors stopped: white noise of ``sigma`` [m] on a slow
    drift of ``drift`` [m/s]."""
    rng = np.random.default_rng(seed)
    ctx = Context()
    ctx.throttle = 0.0
    for k in range(n):
        t = 0.04 * k
        still_noise.see(
            Measurement(t, Kind.BARO_ALTITUDE, np.array([100.0 + drift * t + rng.normal(0, sigma)]), "b"), ctx
        )
    return ctx


def _in_flight(ctx: Context, t: float) -> Context:
    ctx.throttle, ctx.lifted_at, ctx.t = 0.5, t - 2.0, t
    return ctx


def test_the_level_is_the_white_part_and_a_slow_drift_does_not_reach_it():
    ctx = _still_stretch(0.07, 200, drift=0.5)  # 0.5 m/s of drift: 4 m over the 8 s
    v = still_noise.level(Kind.BARO_ALTITUDE, ctx)
    assert v is not None and 0.07 / 1.15 < v**0.5 < 0.07 * 1.15


def test_used_in_flight_only_and_only_where_it_differs_from_the_model():
    ctx = _still_stretch(0.07, 100)
    assert still_noise.still_R(Kind.BARO_ALTITUDE, R_MODEL, ctx) is None  # on the ground
    R = still_noise.still_R(Kind.BARO_ALTITUDE, R_MODEL, _in_flight(ctx, 20.0))
    assert R is not None and 0.07 / 1.2 < R[0, 0] ** 0.5 < 0.07 * 1.2
    ctx.t = ctx.lifted_at + 0.5  # within a second of the lift-off the range may yet read
    assert still_noise.still_R(Kind.BARO_ALTITUDE, R_MODEL, ctx) is None
    # a baro whose noise the model has right keeps the model's level exactly
    assert still_noise.still_R(Kind.BARO_ALTITUDE, R_MODEL, _in_flight(_still_stretch(0.338, 100), 20.0)) is None


def test_a_range_sensor_keeps_the_models_level():
    ctx = _in_flight(_still_stretch(0.07, 100), 20.0)
    ctx.range_read_at = 19.5
    assert still_noise.still_R(Kind.BARO_ALTITUDE, R_MODEL, ctx) is None


def test_too_few_pairs_no_throttle_or_a_stretch_that_ended_give_nothing():
    assert still_noise.level(Kind.BARO_ALTITUDE, _still_stretch(0.07, still_noise.MIN_PAIRS)) is None
    ctx2 = Context()  # a log with no throttle: no stretch it can be sure of
    for k in range(100):
        still_noise.see(Measurement(0.04 * k, Kind.BARO_ALTITUDE, np.array([100.0 + 0.1 * (k % 2)]), "b"), ctx2)
    assert still_noise.level(Kind.BARO_ALTITUDE, ctx2) is None
    # the motors spun up: the stretch is over for good, whatever comes after
    ctx3 = _still_stretch(0.07, 10)
    ctx3.throttle = 0.2
    still_noise.see(Measurement(1.0, Kind.BARO_ALTITUDE, np.array([100.0]), "b"), ctx3)
    ctx3.throttle = 0.0
    for k in range(100):
        still_noise.see(Measurement(2.0 + 0.04 * k, Kind.BARO_ALTITUDE, np.array([100.0 + 0.1 * (k % 2)]), "b"), ctx3)
    assert ctx3.still_over and still_noise.level(Kind.BARO_ALTITUDE, ctx3) is None
