"""A barometer's noise from the still stretch before the first take-off, for the live estimators.

The altitude models' baro noise (``sigma_baro``, :mod:`.models.altitude`) is our simulator's
sensor's; another airframe's baro is another part behind other filtering, at another rate. Set
five times too wide, the estimate leans on the accelerometer's integral and follows its errors:
another generator's clean .bin flight without a rangefinder came out 9.1 cm off the truth with the
model's 0.34 m, 4.8 cm with the 0.07 m its own still stretch shows (a plain filter: 6.3 cm). Before
the vehicle arms it stands still, so the baro's scatter there is its noise: the lab document's
eq. 59 (``R_d`` as the covariance of stationary data), read while the session runs instead of from a
file (``groundstation noise``).

The level is read from the first differences of consecutive readings, ``E[(y_k - y_(k-1))^2] / 2``,
the white part alone: a slow pressure change (weather, the board warming up while it waits) barely
reaches it, and a filter's R is the white part (a slow error is an effect, the diagnosis's to find).
It is taken only when it differs from the model's by more than :data:`DIFFERS` either way, from at
least :data:`MIN_PAIRS` pairs: the sampling error of the level over that many pairs is under 13 %,
so a sensor whose noise the model has right keeps the model's level exactly.

Still means: a throttle has been sent and the motors are stopped (below
:data:`~.models.ground.TAU_STOPPED`: disarmed), the accelerometer holds the vehicle up where it is
read, and no lift-off has happened yet. A log with no throttle never shows the estimator a still
stretch it can be sure of, and its model keeps its own level.

The level is used in flight only, from :data:`~.models.ground.UNSEEN_S` after the lift-off, and only
where no range sensor has read by then. With a range sensor the height is the range's, and the
baro's R weighs its slow errors near the ground (rotor wash, ground effect) against the range: set
to the white part, the baro pulled the estimate off the range on another generator's lidar flights
(0.90 to 1.08 cm, 1.70 to 2.79 cm). On the ground the ground's own constraints hold the height."""

from __future__ import annotations

import math

import numpy as np

from groundstation.core.atmosphere import altitude_at
from groundstation.core.measurement import Kind, Measurement

from .context import Context
from .models.ground import F_HELD_UP, TAU_STOPPED, UNSEEN_S

#: the still level is taken where it is this many times the model's, or less than 1/this
#: (diagnosis.scoring.noise_match reports a ratio outside the same band as a finding)
DIFFERS = 1.5
#: fewest consecutive pairs of readings the level is taken from
MIN_PAIRS = 30
#: [s] two readings further apart than this are not a pair (a dropout)
MAX_PAIR_GAP_S = 0.5

#: the sensors read, as the height [m] each reading gives (its zero does not matter to a difference)
HEIGHT_OF = {
    Kind.BARO_PRESSURE: lambda m: altitude_at(float(m.value[0])),
    Kind.BARO_ALTITUDE: lambda m: float(m.value[0]),
}


def still(ctx: Context) -> bool:
    """The vehicle stands still before its first take-off, its motors stopped (module docstring)."""
    if ctx.throttle is None or ctx.tau >= TAU_STOPPED or ctx.lifted_at is not None:
        return False
    return ctx.f_up is None or ctx.f_up >= F_HELD_UP


def see(m: Measurement, ctx: Context) -> None:
    """Take ``m`` into its sensor's still level while the vehicle is still; the stretch ends for good
    at the first reading taken while it is not."""
    if ctx.still_over:
        return
    if not still(ctx):
        if ctx.throttle is not None:
            ctx.still_over = True
        return
    y = HEIGHT_OF[m.kind](m)
    if not math.isfinite(y):
        return
    key = m.kind.value
    last = ctx.still_noise.get(key)
    if last is None:
        ctx.still_noise[key] = (m.t, y, 0, 0.0)
        return
    t0, y0, n, s = last
    if 0.0 < m.t - t0 <= MAX_PAIR_GAP_S:
        n, s = n + 1, s + (y - y0) ** 2
    ctx.still_noise[key] = (m.t, y, n, s)


def level(kind: Kind, ctx: Context) -> float | None:
    """The still stretch's variance [m^2] of ``kind``'s readings, or None before :data:`MIN_PAIRS`."""
    entry = ctx.still_noise.get(kind.value)
    if entry is None or entry[2] < MIN_PAIRS:
        return None
    return entry[3] / (2.0 * entry[2])


def still_R(kind: Kind, R: np.ndarray, ctx: Context) -> np.ndarray | None:
    """The R to use in place of the model's ``R`` for a reading of ``kind``, or None to keep it (module
    docstring): only in flight, :data:`~.models.ground.UNSEEN_S` after the lift-off, with no range
    reading until then."""
    if ctx.range_read_at is not None or ctx.range_on_ground_at is not None:
        return None
    if ctx.lifted_at is None or ctx.t is None or ctx.t - ctx.lifted_at < UNSEEN_S:
        return None
    v = level(kind, ctx)
    if v is None or v <= 0.0:
        return None
    r = float(R[0, 0])
    if 1.0 / DIFFERS**2 <= v / r <= DIFFERS**2:
        return None
    return np.array([[v]])


def note(kinds: frozenset[Kind], R_of: dict[Kind, np.ndarray], ctx: Context) -> str:
    """What the still stretch gave, in a line for a person ("" where it gave nothing): the level read
    and whether the model's was kept, and why."""
    out = []
    for kind in sorted(kinds, key=lambda k: k.value):
        v = level(kind, ctx)
        if v is None or (kind is Kind.BARO_ALTITUDE and ctx.baro_has_pressure):  # read from its pressure
            continue
        r = float(R_of[kind][0, 0])
        said = f"baro noise {v**0.5:.3g} m before take-off (the model's {r**0.5:.3g} m)"
        if ctx.range_read_at is not None or ctx.range_on_ground_at is not None:
            said += ": the model's kept, a range sensor reads"
        elif 1.0 / DIFFERS**2 <= v / r <= DIFFERS**2:
            said += ": the model's kept, within its sampling error"
        else:
            said += ": used in flight"
        out.append(said)
    return "; ".join(out)
