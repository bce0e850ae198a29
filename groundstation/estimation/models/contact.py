"""The ground under the thrust model: a vehicle standing on it with its rotors turning.

The quadcopter document's eq. 1-2 hold in flight: the throttle's thrust, less the weight, is
the vertical acceleration. On the ground the ground's reaction cancels both, and nothing in
the document says so. Driven by the throttle there, the model flies through the ground. A
touchdown does it every time: the vehicle stops while its throttle is still 0.2-0.4 (a
controller settling, a pilot's stick coming down), which buys less than the weight. The live
filter on a simulated quad sank to 1.5 m below the ground at 2 m/s over the 1.5 s after each
touchdown (the range reads nothing there: it is below its floor), and the diagnosis fitted
its thrust coefficients to that (alpha, beta = 13.7, 3.0 against the simulator's 22, -1.2).

*In contact*: entered at the start, or from above (a touchdown) at an estimated height at or
below :data:`CONTACT_H` while the thrust does not lift the vehicle; left when it does, or
when a range reading sees the vehicle above the ground (:func:`note_range`). In contact the
model's inputs are off and z and vz are *reset* to 0 (:func:`ground_contact`), whatever the
other states are: as Kalman updates, a touchdown's vz = 0 against an estimate still sinking
at 0.8 m/s was "explained" through the correlations. Used by the live thrust filter
(:func:`groundstation.estimation.routing.thrust_input_on_ground`, through :func:`contact_range`) and its diagnosis
(:func:`groundstation.diagnosis.catalogue.thrust_model._input`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..context import Context
from .base import Extract, LinearModel, state_row
from .ground import LANDED

#: m: range readings below this are not used. A driver drops the readings under the sensor's
#: minimum (MAVLink's min_distance), so near it only the upper tail of the noise is left: a landed
#: simulated quad "read" 5-8 cm, and held the estimated height off the ground. The diagnosis sets
#: it; the live filter skips such readings only in contact (:func:`contact_range`)
RANGE_FLOOR = 0.1
#: m: at or below this estimated height, with the thrust not lifting the vehicle, it is on the
#: ground; below RANGE_FLOOR no sensor can say otherwise
CONTACT_H = 0.1
CONTACT_MARGIN = 0.05  # m: a range reading this far above CONTACT_H says the vehicle has left the ground
CONTACT_SIGMA = 0.02  # m: the height on the ground (landing gear, uneven ground)
#: s: a range reading above CONTACT_H keeps the model off the ground this long, whatever its
#: estimate. Without it a touchdown's estimate, reaching CONTACT_H a little early, was reset to the
#: ground while the range still read the vehicle 5-10 cm up (simulated R = 0.15 m flight: 2.7 mm RMS
#: error over the landing's 5 s, 10.8 mm without); and with it counting only readings above
#: CONTACT_H + CONTACT_MARGIN, a lagged model hovering at 0.15-0.2 m was set on the ground in
#: mid-air (an actuator lag's likelihood jumped by 300 between 0.18 and 0.2 s)
RANGE_SAYS_AIRBORNE = 0.2


def note_range(z: np.ndarray | None, t: float, ctx) -> np.ndarray | None:
    """A range reading ``z`` used at ``t``: above :data:`CONTACT_H` it says the vehicle is off the
    ground (for :data:`RANGE_SAYS_AIRBORNE` s), and above the margin it ends the contact now."""
    if z is not None and z[0] > CONTACT_H:
        ctx.range_off_ground_at = t
        if z[0] > CONTACT_H + CONTACT_MARGIN:
            ctx.in_contact = False
    return z


def in_contact(ctx: Context, t: float, h: float, lifts: bool, *, known: bool = True) -> bool:
    """Whether the vehicle stands on the ground at ``t`` (module docstring), kept in the context
    ``ctx``: ``h`` the estimated height, ``lifts`` the estimated thrust above the weight,
    ``known`` False before the filter has an estimate.

    Entered at the start or from above: a take-off whose thrust estimate dipped below the weight
    for a moment, still under CONTACT_H, was set back on the ground and held there until the range
    read it 15 cm up (a clean simulated quad: d_tof 4 mm off, 5 mm of height error through the
    flight). Without the hysteresis the state flickered at CONTACT_H, and each flicker let the model
    fall for a step."""
    seen_up = t - ctx.range_off_ground_at < RANGE_SAYS_AIRBORNE
    was = ctx.in_contact
    if not was and (seen_up or h > CONTACT_H + CONTACT_MARGIN):
        ctx.been_up = True
    ctx.in_contact = (
        known and not lifts and not seen_up and (bool(was) or (h <= CONTACT_H and (was is None or ctx.been_up)))
    )
    if ctx.in_contact:
        ctx.been_up = False
    return ctx.in_contact


def ground_contact(model: LinearModel) -> LinearModel:
    """``model`` (with :func:`~groundstation.estimation.models.ground.on_ground`'s constraints) with those
    constraints as resets, and z = 0 (:data:`CONTACT_SIGMA`) reset in contact.

    Landed below ground idle or in contact, vz is reset to 0, and z to 0 where ``on_ground`` says
    the range has gone quiet; in contact z is reset to 0 too. Resets (:class:`MeasurementModel`'s
    ``corrects`` and ``reset``) because the ground stops the vehicle whatever the other states are.
    As full updates the touchdown's stop went into the effects' states (a rotor radius R = 0.15 m:
    R^2 0.025 -> 0.034 at touchdown, the value reported) and held the estimate 0.15 m up on the
    ground (12 cm RMS over the last 5 s of a simulated flight; 3 mm as resets). As repeated Schmidt
    updates (the other states left alone, but the information piling up) z's variance went to
    nothing on the ground, and at the take-off the range's first readings went into the ToF offset
    instead (d_tof 1.1 cm, a 1 cm height error through the flight)."""
    iz, iv = model.index("z"), model.index("vz")
    meas = dict(model.measurements)
    for key, mm in model.measurements.items():
        if mm.name != LANDED:
            continue
        if key.startswith("on_ground_"):  # z = 0 with the range quiet; in contact, contact_ says it
            meas[key] = replace(mm, extract=_not_in_contact(mm.extract), corrects=(iz,), reset=True)
        else:
            meas[key] = replace(mm, extract=_zero_in_contact(mm.extract), corrects=(iv,), reset=True)
            meas[f"contact_{mm.kind.value}"] = replace(
                mm,
                extract=_zero_in_contact(None),
                row=state_row(model.n, iz),
                R=np.array([[CONTACT_SIGMA**2]]),
                corrects=(iz,),
                reset=True,
            )
    return replace(model, measurements=meas)


def _not_in_contact(idle: Extract) -> Extract:
    """``idle``'s reading, none in contact."""

    def extract(m, ctx: Context):
        return None if ctx.in_contact else idle(m, ctx)

    return extract


def _zero_in_contact(idle: Extract | None) -> Extract:
    """0 in contact; out of it ``idle``'s reading, or none."""

    def extract(m, ctx: Context):
        if ctx.in_contact:
            return np.array([0.0])
        return idle(m, ctx) if idle is not None else None

    return extract


def contact_range(model: LinearModel) -> LinearModel:
    """``model`` whose range readings end the contact (:func:`note_range`), and whose readings up to
    :data:`CONTACT_MARGIN` above CONTACT_H are skipped in contact, counted (``range_in_contact``). The
    contact resets z, so such a reading has only the ToF offset to go into: on a simulated quad whose
    model, climbing ahead of a slow take-off on the baro, fell back into contact while the vehicle was
    3-6 cm up, the ToF offset (then 2 cm a priori) took 4 cm from the first readings, a 3.7 cm height
    error through the flight. The diagnosis uses no reading below :data:`RANGE_FLOOR` instead."""
    rng = model.measurements["range"]

    def range_read(m, ctx, extract=rng.extract):
        z = extract(m, ctx)
        if z is not None and ctx.in_contact and z[0] <= CONTACT_H + CONTACT_MARGIN:
            ctx.skip_why = "in_contact"
            return None
        return note_range(z, m.t, ctx)

    meas = dict(model.measurements)
    meas["range"] = replace(rng, extract=range_read)
    # the live estimator's input then keeps the contact (routing.thrust_input_on_ground)
    return replace(model, measurements=meas, options={**model.options, "ground_contact": True})
