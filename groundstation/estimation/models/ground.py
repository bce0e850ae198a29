"""The ground under a landed vehicle, as pseudo-measurements of the height filters.

None of the design documents models the ground: their equations of motion hold in
flight. On the ground an autopilot's estimator holds the vehicle still instead.
This module gives the altitude filter the same two constraints, read at each
throttle message (:func:`landed` says when), at the filter's own time
(``MeasurementModel.untimed``: a throttle message's time may lead the sensors'):

* ``vz = 0`` (sigma 5 cm/s) while landed: the vehicle does not move;
* ``z = 0`` (sigma 3 cm) while landed *and* the range sensor has gone quiet after
  reading at least once, or reads what :mod:`.range_gate` skips as no height (a sonar's
  steady echo with the motors stopped): below its minimum distance it reports nothing (the
  MAVLink drivers drop a DISTANCE_SENSOR reading outside [min, max]). The height is
  then between 0 and that minimum. This is PX4 EKF2's on-ground range: with the
  range sensor sending but invalid on the ground, it synthesises a reading at the
  ground clearance (``EKF2_MIN_RNG``). In this model z is the height the range
  sensor measures, so the ground is z = 0 wherever the vehicle lands. The same z = 0 from a
  lift-off until the range's first reading after it (at most :data:`UNSEEN_S`): the vehicle
  is still within the range's minimum distance of the floor. Without it, the vertical speed let
  go there (below) and a baro that the rotors' wash holds low near the ground (another
  generator's, 45 cm low) drew the estimate 17 and 41 cm under the floor it had just left.
  Decided from the throttle and the range's timing, not from the estimate, so that every
  candidate's filter holds the ground at the same updates (the two-stage filter's exactness).

When the vehicle leaves the ground, the model lets go of its vertical speed: the ground held it
at zero, and what the motors and the ground did in the instant of lift-off (a spring-off, a jump
in thrust between two accelerometer blocks) is an impulse the accelerometer-driven dynamics do not
hold. The filter adds :data:`SIGMA_LIFTOFF` of uncertainty to vz there (``LinearModel.impulses``):
held at 5 cm/s by the ground, it lagged a take-off that left the ground at 0.5 m/s by 13 cm with
sigma_z at 4 mm, and took 40 s to settle. The same at touchdown, where the ground stops the vehicle
in an instant the accelerometer's blocks may not hold (another generator's vehicle stops between
two samples): held at the flight's few mm/s by the range sensor, the estimate's vz kept the descent's
-0.18 m/s through the ground's first updates and sank 3 cm below the floor with sigma_z at 5 mm.

Without the first, the height floats on the ground wherever the range sensor reads
nothing (a simulated coax's estimate wandered 0.24 m in the 2 s before take-off);
without the second, a landing's last half-metre is integrated from the
accelerometer and held there on the baro alone (the demo's live estimate stood at
-0.115 m after landing). Both are pseudo-sensors named :data:`LANDED`: their
innovations say how well the model keeps to an assumption, not to a measurement,
and they are not scored, tested or plotted as a sensor's.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from groundstation.core.measurement import Kind
from groundstation.core.units import G

from ..context import Context
from .base import LinearModel, MeasurementModel, state_row

#: below this throttle the vehicle is taken to stand on the ground (the ground,
#: not the thrust model, carries its weight); the thrust model is for flight
TAU_GROUND = 0.15
#: ... but only with the estimate near the ground: above it, a throttle below ground idle is a
#: fast descent. The thrust test flight's descent from 3.6 m cut the throttle to 0.11 for 40 ms;
#: taken as landed, the model stopped the vehicle in mid-air (no thrust, no gravity, vz held at 0),
#: and a 20 ms "actuator lag", smoothing the dip away, gained 50 in log-likelihood on a clean flight
H_LANDED = 0.5
#: below this the motors are stopped (disarmed, spinning down): landed wherever the estimate is. An
#: autopilot does not stop them in flight, and an estimate may be far off at touchdown (ArduPilot's
#: underpowered.log: 5 m, on the baro alone before its effects are known); flying that estimate on
#: with the motors off dropped it through the last seconds and moved the fitted thrust_voltage n
#: from 1.31 to 0.81
TAU_STOPPED = 0.05


#: [m/s^2] a body is held up (by the ground, with the motors stopped) while the specific force along
#: the world's up exceeds half of g: at rest it is g, falling with the motors stopped about 0. The
#: motors are cut in the air too: another generator's flights end in a throttle cut at 15 m and a
#: fall at up to 2 g (a specific force of -11 m/s^2), which the ground's vz = 0 held at zero speed,
#: and the estimate rose 5 m while the vehicle fell; half of g is the midpoint, not a fitted value
F_HELD_UP = G / 2


def landed(ctx: Context) -> bool:
    """The vehicle stands on the ground: held up (:data:`F_HELD_UP`, where the accelerometer is
    read) with the motors stopped, or with the throttle below ground idle and the estimated height
    (the state vector's first element, ``x``, kept in the context) within :data:`H_LANDED`."""
    tau = ctx.tau
    if tau >= TAU_GROUND:
        return False
    if ctx.f_up is not None and ctx.f_up < F_HELD_UP:
        return False
    if tau < TAU_STOPPED:
        return True
    x = ctx.x
    return x is None or float(x[0]) <= H_LANDED


#: the pseudo-sensor's name (in the filter's innovation log, beside the sensors')
LANDED = "landed"
#: [m/s] the landed vehicle's vertical speed, and [m] its height with the range sensor quiet
SIGMA_STILL = 0.05
SIGMA_ON_GROUND = 0.03
#: [m/s] the vertical speed's uncertainty released at lift-off: diffuse against the climb rates a
#: multirotor takes off at, so the height sensors, not the ground's vz = 0, say how fast it goes
SIGMA_LIFTOFF = 1.0
#: [s] no range reading for this long: the sensor reads below its minimum (it sends at 10-50 Hz)
RANGE_QUIET = 0.3
#: [s] after a lift-off, the ground holds the height until the range reads, at most this long: a
#: multirotor climbing at 0.5 m/s clears a 10-20 cm minimum distance in well under it
UNSEEN_S = 1.0


def rising_unseen(ctx: Context, t: float) -> bool:
    """The vehicle left the ground less than :data:`UNSEEN_S` before ``t`` and the range has read
    nothing since: it is still within the range's minimum distance of the ground."""
    lifted = ctx.lifted_at
    if lifted is None or t - lifted >= UNSEEN_S:
        return False
    return ctx.range_read_at is None or ctx.range_read_at < lifted


def on_ground(
    model: LinearModel, *, height: bool = True, reset: bool = False, range_in_log: bool = False
) -> LinearModel:
    """``model`` with the landed constraints (module docstring); ``height=False`` leaves out z = 0
    (the thrust model has its own ground contact, :func:`groundstation.estimation.models.contact.ground_contact`).
    ``range_in_log``: the log is known to have range readings (a diagnosis reads the whole log
    first), so the ground holds the height at the first lift-off, before the range's first reading.

    ``reset=True``: each constraint *sets* its state (vz, or z) to the ground's value with the
    constraint's variance, uncorrelated with the rest, and the other states keep what the sensors
    told them (``MeasurementModel.reset``). The altitude diagnosis sets it: it estimates constants
    over the whole log, and "landed" begins with a touchdown the model lacks (the throttle cut while
    the vehicle still sinks, the ground's impulse). As full updates, vz = 0 there was explained
    through the correlations: an accel_scale of 0.02, read 0.0195 at 50 s on a simulated quadcopter
    (seed 1041), fell to 0.0165 over the landing; the final estimates of six flights at 0.02 and 0.04
    were 10-17 % low. As repeated Schmidt updates of z and vz (the other states left alone, the
    information piling up at 50 Hz) the ground's hold depended on how uncertain the rest was, so an
    effect's state changed what the ground did: on another generator's flight with a rotor wash
    of 2.02 m per unit throttle, the wash read 2.21 (1.99 as resets, at the same 0.15 s time
    constant) and an accelerometer scale the flight does not have gained 67 in log-likelihood (as
    resets it loses 4.5). As resets the ground does the same whatever the model's effects are, and the
    diagnosis's two-stage filter (:mod:`groundstation.diagnosis.runs.signature`) is exact through it. The
    live filter keeps full updates: on the pad, vz = 0 is what teaches it the accelerometer's bias
    before take-off."""
    iz, iv = model.index("z"), model.index("vz")
    meas = dict(model.measurements)

    def still(m, ctx):
        return np.array([0.0]) if landed(ctx) else None

    def on_the_ground(m, ctx):
        # the sensor has sent (a reading used, or one models.range_gate skipped) and none used lately
        sent = ctx.range_read_at is not None or ctx.range_on_ground_at is not None
        last = ctx.range_read_at if ctx.range_read_at is not None else -math.inf
        quiet = m.t - last > RANGE_QUIET
        # landed with the range gone quiet; or just lifted off, the range not yet read since (before
        # its first reading only where the log is known to have a range sensor)
        if sent or range_in_log:
            landed_now = landed(ctx)
            if (sent and quiet and landed_now) or (not landed_now and rising_unseen(ctx, m.t)):
                return np.array([0.0])
        return None

    def lift_off_or_touchdown(m, ctx):
        now = landed(ctx)
        was, ctx.landed = ctx.landed, now
        if was and not now:
            ctx.lifted_at = m.t
        return {"vz": SIGMA_LIFTOFF**2} if was is not None and was != now else None

    impulses = dict(model.impulses)
    for kind in (Kind.THROTTLE, Kind.ACTUATOR):
        impulses[kind] = (*impulses.get(kind, ()), lift_off_or_touchdown)
        meas[f"landed_{kind.value}"] = MeasurementModel(
            LANDED,
            kind,
            still,
            state_row(model.n, iv),
            np.array([[SIGMA_STILL**2]]),
            untimed=True,
            corrects=(iv,) if reset else None,
            reset=reset,
        )
        if height and "range" in meas:
            meas[f"on_ground_{kind.value}"] = MeasurementModel(
                LANDED,
                kind,
                on_the_ground,
                state_row(model.n, iz),
                np.array([[SIGMA_ON_GROUND**2]]),
                untimed=True,
                corrects=(iz,) if reset else None,
                reset=reset,
            )
    if height and "range" in meas:
        rng = meas["range"]

        def range_read(m, ctx, extract=rng.extract):
            z = extract(m, ctx)
            if z is not None:
                ctx.range_read_at = m.t
            return z

        meas["range"] = replace(rng, extract=range_read)
    return replace(model, measurements=meas, impulses=impulses)
