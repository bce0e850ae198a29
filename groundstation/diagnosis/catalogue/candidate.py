"""A candidate effect as the catalogues hold it (:class:`Candidate`: how it changes the model, what it
reads, how it is scored), the change most candidates make (:func:`with_regressor`: a state acting on
one sensor through a regressor), and each effect's parameters' units."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

from groundstation.diagnosis.runs.run import Run
from groundstation.diagnosis.runs.signature import Column
from groundstation.estimation.models.base import LinearModel, pad_row


@dataclass
class Candidate:
    name: str
    k: int  # parameters it adds (BIC penalty)
    needs: set = field(default_factory=set)  # kinds the log must have
    sensor: str | None = None  # the measurement it acts on
    #: the model with the effect (``augment(model, shape)`` for a candidate with ``shapes``)
    augment: Callable[..., LinearModel] | None = None
    params: Callable[..., dict] | None = None  # (run) -> {name: value}
    delays: tuple[float, ...] = ()  # sensor_delay: the grid
    #: sensor_delay: the kinds its delay moves (None: all of its sensor's, catalogue.altitude.SENSOR_KINDS)
    shifts: frozenset | None = None
    #: (measurements, grid value) -> measurements, at 0 the measurements themselves (the base run is
    #: that trial); default: the sensor's readings shifted by the delay
    reshape: Callable | None = None
    #: (its run, scored from) -> the updates it can act on, for the materiality per update (scored.MATERIAL);
    #: default: its sensor's, or all. An effect that acts in part of a flight only (rotor ground
    #: effect, near the ground) would else have its gain spread over updates it cannot change
    support: Callable | None = None
    #: (measurements, size) -> the measurements with the effect acting at that size, for an effect on the
    #: input (no sensor of its own): its signature through the base filter gives the updates it acts on
    #: (trace.signature_support)
    perturb: Callable | None = None
    #: (its run, z) -> {parameter: the size a claim needs}, z = sqrt(2 x the gain it needs) (scored.smallest_claimed);
    #: default: each reported ``sigma_`` times z, for a parameter that is itself the state
    limit: Callable | None = None
    #: a shape parameter the model is not linear in (a ground effect's fall-off height), chosen from these
    #: by the likelihood: ``augment(model, shape)``, reported as ``params[shape_name]`` (one more parameter)
    shapes: tuple[float, ...] = ()
    shape_name: str = "shape"
    #: the shape is a continuous quantity (a time constant), not a choice among forms: the likelihood's
    #: profile over its logarithm is refined between the shapes as a delay's is between its grid's values
    refine_shape: bool = False
    #: once such a shape is chosen (``augment`` then binds it): the augment that takes it, for
    #: the shape to be chosen again with every effect found after it in the model (joint.joint_shapes)
    unshaped: Callable[..., LinearModel] | None = None
    # #: the effect's unknown constants as they act on the base model, linearly #: (``columns(model)``, or
    # ``columns(model, shape)`` with shapes; in the order of the states #: ``augment`` appends): the two-stage filter
    # (:mod:`~groundstation.diagnosis.runs.signature`) then scores it through the base #: run's gains, without a run of
    # its own
    columns: Callable[..., list[Column]] | None = None
    #: for an effect not linear in its parameters (a delay, a changed measurement function): linear
    #: stand-ins, each a list of columns, whose two-stage gains at their best fit bound the effect's;
    #: where none could be claimed, its own runs are not made. ``screen(model, None)``: those the run
    #: must probe; ``screen(model, run)``: those read off the base run itself
    screen: Callable[[LinearModel, Run | None], list[list[Column]]] | None = None
    #: one of an effect's forms (a rotor wash that follows the throttle or the thrust): each form its
    #: own candidate of the same name, the likelihood taking one, and the claim saying which
    form: str = ""
    #: the model option the candidate reads (``LinearModel.options``), without which it is not offered
    needs_option: str | None = None
    #: the parameters its states are (empty: every one in ``params``); the others restate them in another
    #: unit (a wash per unit thrust over weight, also per unit of the command) and add no evidence of size
    fitted: tuple[str, ...] = ()
    #: the physics' bar on the fitted parameters: (params) -> why they are no such effect, or None. A
    #: fit outside it is the model lacking something else that the candidate's state soaks up, a
    #: finding about the model, not a calibration to load
    plausible: Callable[[dict], str | None] | None = None


def with_regressor(
    model: LinearModel, sensor: str, state: str, regressor: Callable, P0: float, Q: float = 0.0
) -> LinearModel:
    """One more state c, acting on ``sensor`` as ``y = h(x) + c * regressor(ctx)``."""
    n = model.n
    meas = {}
    for key, mm in model.measurements.items():
        if mm.name == sensor:
            old = mm.row
            last: list = [None, None, None]  # (old's last H, the regressor's value, the row they made)

            def row(ctx, old=old, last=last):
                h, c = old(ctx), regressor(ctx)
                if h is not last[0] or c != last[1]:  # the same H and value: the same row (no one writes into an H)
                    r = pad_row(h, 1)
                    r[0, n] = c
                    last[0], last[1], last[2] = h, c, r
                return last[2]

            meas[key] = replace(mm, row=row)
    return model.augmented(states=[state], Qc_extra=[Q], x0_extra=[0.0], P0_extra=[P0], measurements=meas)


def state_param(name: str, state: str, scale: float = 1.0):
    def read(run) -> dict:
        v, s = run.final(state)
        return {name: v * scale, f"sigma_{name}": s * abs(scale)}

    return read


#: each catalogue parameter's unit, as the simulator's effects give it (sim_bridge/effects.py), for the
#: reports; a parameter not here is a pure number (a scale, an exponent)
UNITS = {
    ("accel_bias", "z"): "m/s^2",
    ("gyro_bias", "x"): "rad/s",
    ("gyro_bias", "y"): "rad/s",
    ("imu_misalignment", "roll"): "deg",
    ("imu_misalignment", "pitch"): "deg",
    ("baro_bias_drift", "rate"): "m/s",
    ("baro_thermal", "k"): "m/K",
    ("baro_thrust", "k"): "m per unit throttle",
    ("baro_thrust", "k_tw"): "m per unit thrust over weight",
    ("baro_thrust", "tc"): "s",
    ("baro_ground_effect", "A"): "m",
    ("baro_ground_effect", "h0"): "m",
    ("range_offset", "o"): "m",
    ("sensor_delay", "seconds"): "s",
    ("actuator_lag", "tc"): "s",
    ("thrust_ground_effect", "R"): "m",
}


def unit_of(name: str, param: str) -> str:
    """The unit of an effect's parameter ("" for a pure number); ``name`` may carry its sensor,
    ``sensor_delay(range)``."""
    return UNITS.get((name.split("(")[0], param), "")
