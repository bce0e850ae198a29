"""Range readings of a vehicle standing on the ground that are not its height.

None of the design documents has a range sensor on the ground: their range is the height in
flight. A real one on a landed vehicle reads steadily what is not the ground under it. ArduPilot's
``underpowered.log`` (shared/data/real/ardupilot_dataflash): its MaxBotix sonar read 1.98 m for
the first 28 s with the motors stopped and the baro at 0.0 m, then 2-7.6 m as the motors spun up
on the ground; at the take-off it reads the climb from its 0.2 m floor up. The live filters took
the echoes: a replay showed the standing vehicle 1.9 m up (altitude model) and
1.5-6 m up (thrust model) for the first minute.

The gate closes while the motors are stopped (throttle below
:data:`~groundstation.estimation.models.ground.TAU_STOPPED`: disarmed or spinning down; an autopilot does not stop
them in flight). That is a fact from the link, not the estimate, so the gate cannot lock a range
sensor out in flight, which is the risk of an estimate-keyed gate: after a stretch on the baro
alone the estimate may sit on the ground while the vehicle flies. While it is closed, a reading
within :data:`LIFTOFF_REACH` of the sensor's floor is used (the ground under landing gear, a
sonar's floor), and one further away is skipped and counted (``range_on_ground``): a range
reading is believed that far up only once the range has followed the vehicle up. The gate opens
when it sees the vehicle leave the ground, which it does continuously from the sensor's floor at
10-50 readings a second:

* a *track* is readings that follow each other within :data:`TRACK_GAP` s and within a climb's
  step of the last (:data:`CLIMB_SPEED` times the interval, plus :data:`STEP_NOISE`); a reading
  that does not starts a new one;
* the gate opens, at the reading that does it, once a track that started within
  :data:`LIFTOFF_REACH` of the floor has risen :data:`CLIMB_RISE` above its start.

A steady floor reading does not open it (underpowered.log read 0.21 m four times in spin-up, then
2.57 m and 7.61 m: on the ground, in prop wash); its take-off at 61.1 s reads 0.23, 0.27, 0.34,
0.41 m and opens the gate at 61.7 s. Nothing of a take-off is lost: its first readings are within
reach. Should the motors stop in the air (a pilot's stick fully down, on a log whose throttle is
the autopilot's demand), a track that holds :data:`CLOSED_HOLD` s opens it too.

At the start (a log's, or a link joined at any time) the gate is *unsure*: the motors running
says neither that the vehicle flies nor that it stands. Readings beyond reach are skipped there
too, until a track, from any height, has held :data:`UNSURE_HOLD` s (the vehicle flies) or climbed
from the ground; the motors seen stopped close it. Without a throttle on the link there is no
gate.

A range sensor whose minimum is above :data:`LIFTOFF_REACH` (none of the small rotorcraft's sonars
and time-of-flight sensors here) needs its floor given (``floor``, from a vehicle file's
``range_limits``); without it, its gate opens only :data:`CLOSED_HOLD` s into each flight.
"""

from __future__ import annotations

import math
from dataclasses import replace

from ..context import Context
from .base import LinearModel
from .ground import TAU_STOPPED

#: the counted skip's name (``KalmanEstimator.counters.skipped``: ``range_on_ground``)
ON_GROUND = "on_ground"
#: [m] above the sensor's floor: a take-off's first reading is nearer the ground than this
LIFTOFF_REACH = 1.0
#: [m] the rise above the track's first reading that says the vehicle climbs: a sonar's noise on the
#: ground in prop wash is several cm (underpowered.log: 0.22-0.29 m at its 0.2 m floor)
CLIMB_RISE = 0.15
#: [m/s] faster than a small rotorcraft climbs or sinks near the ground (ArduCopter's pilot and
#: waypoint climb rates default to 2.5 m/s)
CLIMB_SPEED = 5.0
#: [m] a reading's noise, allowed on top of a climb's step
STEP_NOISE = 0.1
#: [s] a longer silence drops the track: the sensor reads at 10-50 Hz in flight
TRACK_GAP = 0.5
#: [s] before the motors have been seen stopped: readings beyond reach that follow each other this
#: long say the vehicle flies (a link joined in flight). underpowered.log's first 1.2 s, at ground
#: idle, read a steady 1.98 m before its motors stopped
UNSURE_HOLD = 2.0
#: [s] ... and after the motors were seen stopped: the way out if they stop in the air (a pilot's
#: stick fully down, on a log whose throttle is the autopilot's demand). On the ground with the
#: motors running, underpowered.log's sonar held a steady echo for 3.1 s at most (23.1-26.2 s)
CLOSED_HOLD = 10.0
#: the gate's states (``range_gate`` in the context): not yet sure the vehicle flies (at the start, with
#: the motors running), closed (the motors were seen stopped), open (the range has seen it fly)
UNSURE, CLOSED, OPEN = "unsure", "closed", "open"


def range_gate(model: LinearModel, *, floor: float = 0.0) -> LinearModel:
    """``model`` with its range readings beyond reach of the ground skipped from the motors stopping
    until the range sees a take-off, and at the start until it is sure (module docstring).
    ``floor`` [m]: the range sensor's minimum, if above 0."""
    rng = model.measurements["range"]
    reach = floor + LIFTOFF_REACH

    def range_off_ground(m, ctx, extract=rng.extract):
        d = float(m.value[0])
        if ctx.throttle is None:
            return extract(m, ctx)  # no motors' state on the link: nothing to gate on
        state = ctx.range_gate
        if ctx.throttle < TAU_STOPPED:
            state, ctx.range_track = CLOSED, None
        elif state != OPEN and _leaves_ground(ctx, m.t, d, reach, sure=state == CLOSED):
            state = OPEN
        ctx.range_gate = state
        if state == OPEN or d <= reach:
            return extract(m, ctx)
        ctx.skip_why = ON_GROUND
        ctx.range_on_ground_at = m.t
        return None

    meas = dict(model.measurements)
    meas["range"] = replace(rng, extract=range_off_ground)
    return replace(model, measurements=meas)


def _leaves_ground(ctx: Context, t: float, d: float, reach: float, *, sure: bool) -> bool:
    """Extend (or start, or drop) the track with the reading ``d`` at ``t``; True when it says the
    vehicle is in the air: it has climbed :data:`CLIMB_RISE` from within ``reach`` of the ground, or
    it has held :data:`UNSURE_HOLD` s (:data:`CLOSED_HOLD` s when ``sure`` the vehicle stood on the
    ground). The track is a tuple (t0, d0, t_last, d_last), replaced, not changed: a checkpoint's
    shallow copy of the context must not share it."""
    if not math.isfinite(d):
        return False
    track = ctx.range_track
    if track is not None:
        t0, d0, t_last, d_last = track
        dt = t - t_last
        if 0.0 <= dt <= TRACK_GAP and abs(d - d_last) <= CLIMB_SPEED * dt + STEP_NOISE:
            if (d0 <= reach and d - d0 >= CLIMB_RISE) or t - t0 >= (CLOSED_HOLD if sure else UNSURE_HOLD):
                ctx.range_track = None
                return True
            ctx.range_track = (t0, d0, t, d)
            return False
    ctx.range_track = (t, d, t, d)
    return False
