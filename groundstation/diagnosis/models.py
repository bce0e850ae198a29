"""The models a diagnosis can start from, by the registry's names, and how each is set up.

Each :class:`DiagnosisSpec` extends a model of :data:`groundstation.estimation.registry.MODELS`
with what the closed loop needs: how the log is prepared and the base model built from it
(:func:`setup`), the estimator the loop runs, the catalogue of candidate effects the model can
show, and the effects it cannot show with the reason. ``diagnose --model``, the dashboard's
Diagnosis panel and the benchmarks read :data:`DIAGNOSABLE`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from groundstation.core.imu import ImuColumns
from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings
from groundstation.diagnosis.catalogue.altitude import (
    BARO_WANDER,
    UNOBSERVABLE,
    altitude_catalogue,
    baro_zero,
    gps_in_altitude,
)
from groundstation.diagnosis.catalogue.attitude import UNOBSERVABLE_ATTITUDE, attitude_catalogue
from groundstation.diagnosis.catalogue.candidate import Candidate
from groundstation.diagnosis.catalogue.thrust import UNOBSERVABLE_THRUST, thrust_catalogue
from groundstation.diagnosis.catalogue.thrust_model import hover_prior, main_flight, thrust_estimator, thrust_model
from groundstation.diagnosis.model_names import MODEL_HELP
from groundstation.diagnosis.runs.outputs import interval_means
from groundstation.diagnosis.runs.run import CONTEXT_KINDS, Prepared, prepare, run_model
from groundstation.diagnosis.scoring.noise_match import GPS_SLOW
from groundstation.estimation.estimator import KalmanEstimator
from groundstation.estimation.identity import Vehicle
from groundstation.estimation.models.altitude import altitude_model
from groundstation.estimation.models.attitude_drag import attitude_drag_model
from groundstation.estimation.models.base import LinearModel
from groundstation.estimation.models.contact import RANGE_FLOOR
from groundstation.estimation.models.ground import on_ground
from groundstation.estimation.registry import MODELS, ModelSpec, vehicle_config
from groundstation.estimation.routing import altitude_estimator, attitude_estimator, motor_outputs_of
from groundstation.estimation.stated import RangeClearance, Stated
from groundstation.estimation.thrust_ratio import thrust_ratio

#: a GPS altitude's slow error [m] and its correlation time [s] (first-order Gauss-Markov): the
#: floor of noise_match.GPS_SLOW while effects are traced, then the level the log picks; its white
#: part is matched to the log (noise_match.py)
GPS_ERROR = (GPS_SLOW[0], 60.0)
#: s: a shorter log is not diagnosed (the likelihood is scored from 5 s in, once the filter settles)
MIN_SECONDS = 10.0
HEIGHT_SENSORS = frozenset({Kind.RANGE, Kind.BARO_PRESSURE, Kind.BARO_ALTITUDE})


@dataclass(frozen=True)
class Base:
    """What a model's setup gives the loop: the prepared log, the base model, and (the thrust
    model) the thrust curve read from the log (``airframe.ThrustCurve.as_dict``)."""

    prep: Prepared
    model: LinearModel
    airframe: dict | None = None


@dataclass(frozen=True)
class DiagnosisSpec:
    model: ModelSpec  #: the registry's entry
    help: str  #: what the model can find, for ``diagnose --help``
    #: (measurements, declared names, vehicle, the raw IMU as columns or None)
    base: Callable[[Sequence[Measurement], set, str | None, ImuColumns | None], Base]
    make: Callable[[LinearModel], KalmanEstimator]  #: the estimator the loop runs each candidate model in
    catalogue: Callable[[set[Kind]], list[Candidate]]  #: the candidates, given the log's kinds
    unobservable: dict[str, str]  #: effects it cannot show, and why
    needs: frozenset[Kind]  #: what the log must have: all of them, or with ``needs_any`` one of them
    needs_why: str  #: the one line said when it has not
    needs_any: bool = False
    needs_height: bool = True  #: a range sensor or a barometer to diagnose against
    #: its filter's gains do not depend on the data (no rule reads the estimate), so the two-stage
    #: filter's score of a linear candidate is its augmented run's (trace.rank)
    exact_gains: bool = True


@dataclass
class Setup:
    """What a diagnosis runs: the measurements it uses, prepared, the base model and its spec."""

    prep: Prepared
    model: LinearModel
    spec: DiagnosisSpec
    declared: set
    airframe: dict | None = None
    #: the range's ground clearance taken off its readings (estimation.stated), if the log has one
    clearance: RangeClearance | None = None

    @property
    def make(self) -> Callable[[LinearModel], KalmanEstimator]:
        return self.spec.make


def altitude_base(prep: Prepared, names: set, vehicle: str | None) -> LinearModel:
    """The altitude model a diagnosis starts from: the vehicle's noise, the declared slant, and what a
    person would set right before suspecting any effect (the ground, the baro's zero)."""
    config = vehicle_config(vehicle, "altitude")
    if gps_in_altitude(prep.kinds) and "use_gps" not in config:
        # the GPS is the absolute height the baro is seen against when no range sensor is: with its
        # slow error as a state
        config = {**config, "use_gps": True, "gps_error": GPS_ERROR}
        # the receiver's own vertical velocity, where the log has it (a DataFlash GPS record's VZ, a
        # ULog's vel_d_m_s; a tlog's GPS_RAW_INT has none)
        if "gps_velocity" not in config and Kind.GPS_VD in prep.kinds:
            config = {**config, "gps_velocity": True}
    model = altitude_model(range_tilt="range_tilt" in names, **config)
    if prep.logged_throttle:
        # a logged throttle only: a stand-in derived from the range or the vibration would feed
        # the filter's own sensors back as a constraint (on 0422-log00: 0.69 -> 0.82 cm, and a
        # "throttle" pattern in the range innovations)
        model = on_ground(model, reset=True, range_in_log=Kind.RANGE in prep.kinds)
    if prep.kinds & {Kind.BARO_PRESSURE, Kind.BARO_ALTITUDE}:
        if Kind.RANGE in prep.kinds:
            model = baro_zero(model)
        elif Kind.GPS in prep.kinds:
            model = baro_zero(model, BARO_WANDER)
    return model


def _altitude(ms: Sequence[Measurement], names: set, vehicle: str | None, imu: ImuColumns | None) -> Base:
    prep = prepare(ms, imu=imu, imu_kinds=(Kind.ACCEL,))
    return Base(prep, altitude_base(prep, names, vehicle))


def _quad_thrust(ms: Sequence[Measurement], names: set, vehicle: str | None, imu: ImuColumns | None) -> Base:
    window = main_flight(ms)
    if window is not None:
        ms = [m for m in ms if window[0] <= m.t <= window[1] + 5.0]
        if imu is not None:
            imu = imu.masked(lambda s: (s.t >= window[0]) & (s.t <= window[1] + 5.0))
    # the throttle between its records (outputs.py)
    prep = prepare(interval_means(ms), imu=imu, imu_kinds=(Kind.ACCEL,))
    params = vehicle_config(vehicle, "quad_thrust")
    if "range_limits" in params:
        params["range_limits"] = tuple(params["range_limits"])
    prior = hover_prior(prep, params.get("range_limits", (RANGE_FLOOR, math.inf)))
    curve = prior.pop("curve", None)
    airframe = None
    if curve is not None and "alpha0" not in params:
        prior.update(curve.prior())  # the log's thrust curve (airframe.py) over the hover's
        airframe = {**curve.as_dict(), "used": True}
    elif curve is not None:
        # the file's curve is used; the accelerometer's is read beside it, to say when it is not this log's
        airframe = {
            **curve.as_dict(),
            "used": False,
            "file_alpha": params["alpha0"],
            "file_beta": params.get("beta0", 0.0),
        }
    params = {**prior, **params}
    return Base(prep, thrust_model(range_tilt="range_tilt" in names, **params), airframe)


def _attitude(ms: Sequence[Measurement], names: set, vehicle: str | None, imu: ImuColumns | None) -> Base:
    prep = prepare(ms, imu=imu)
    model = attitude_drag_model(**vehicle_config(vehicle, "attitude"))
    if {Kind.GYRO, Kind.ACCEL} <= prep.kinds:
        prep = with_vertical_velocity(prep, names, vehicle)
    return Base(prep, model)


def with_vertical_velocity(prep: Prepared, names: set, vehicle: str | None) -> Prepared:
    """The attitude model's v_d input (models.attitude_drag: the q w and p w terms): the altitude
    filter run over the same prepared log, its vertical speed as CLIMB_RATE (source "altitude model").
    The log's own vertical velocity (VELOCITY_NED, CLIMB_RATE) is used only where that filter cannot
    run (no accelerometer or no height sensor): the simulator's VFR_HUD climb is 0 throughout, and an
    autopilot's estimate comes from a filter whose tuning the log does not say."""
    if Kind.ACCEL not in prep.kinds or not prep.kinds & HEIGHT_SENSORS:
        return prep
    model = altitude_base(prep, names, vehicle)
    run = run_model(model, prep, altitude_estimator)
    if not len(run.t):
        return prep
    up = run.x[:, model.index("vz")]
    derived = [
        Measurement(float(t), Kind.CLIMB_RATE, np.array([float(v)]), "altitude model") for t, v in zip(run.t, up)
    ]
    rest = prep.measurements.without({Kind.VELOCITY_NED, Kind.CLIMB_RATE})
    return replace(
        prep, measurements=(rest + derived).in_time_order(CONTEXT_KINDS), kinds=prep.kinds | {Kind.CLIMB_RATE}
    )


DIAGNOSABLE: dict[str, DiagnosisSpec] = {
    "altitude": DiagnosisSpec(
        MODELS["altitude"],
        MODEL_HELP["altitude"],
        _altitude,
        altitude_estimator,
        altitude_catalogue,
        UNOBSERVABLE["altitude"],
        frozenset({Kind.ACCEL}),
        "the altitude model takes the accelerometer as its input and this log has none; the thrust "
        "model needs only the throttle: --model quad_thrust",
    ),
    "quad_thrust": DiagnosisSpec(
        MODELS["quad_thrust"],
        MODEL_HELP["quad_thrust"],
        _quad_thrust,
        thrust_estimator,
        thrust_catalogue,
        UNOBSERVABLE_THRUST,
        frozenset({Kind.THROTTLE, Kind.ACTUATOR}),
        "the thrust model takes the throttle as its input and this log has none (no THROTTLE, "
        "SERVO_OUTPUT_RAW or RCOU)",
        needs_any=True,
        # the ground contact and the range's spurious echoes are read against the estimate
        exact_gains=False,
    ),
    "attitude": DiagnosisSpec(
        MODELS["attitude"],
        MODEL_HELP["attitude"],
        _attitude,
        attitude_estimator,
        attitude_catalogue,
        UNOBSERVABLE_ATTITUDE,
        frozenset({Kind.GYRO, Kind.ACCEL}),
        "the attitude model runs on the raw IMU (gyro and accelerometer) and this log has no raw IMU",
        needs_height=False,
    ),
}


def setup(
    ms: Sequence[Measurement],
    *,
    source: str = "",
    model_name: str = "altitude",
    declared: Sequence[dict] = (),
    vehicle: str | None = None,
    imu: ImuColumns | None = None,
    stated: Stated | None = None,
) -> Setup:
    """The model a diagnosis starts from, with the declared effects in it (one line of error if the log
    cannot feed it). ``stated``: what the log states besides its readings
    (:mod:`groundstation.estimation.stated`): the range's reading on the ground, taken off every range
    reading so that the range reads the height every model means, 0 on the gear; the motors' thrust
    curve, which the rotor wash's signal is read through (``options["motor_curve"]``). Where the log has a
    throttle of its own, the map from it to the thrust over the weight that the accelerometer shows in
    the air (:mod:`groundstation.estimation.thrust_ratio`, ``options["thrust_ratio"]``): what a rotor
    wash follows."""
    clearance = stated.clearance if stated is not None else None
    spec = DIAGNOSABLE.get(model_name)
    if spec is None:
        raise ValueError(f"diagnose: model {model_name!r} is not supported (use {', '.join(DIAGNOSABLE)})")
    names = {e.get("name") for e in declared}
    readings = Readings.of(ms)
    if clearance is not None and clearance.metres and Kind.RANGE in readings.kinds():
        c = clearance.metres
        ms = readings.with_values(Kind.RANGE, lambda v: v - c)
    else:
        clearance = None
    base = spec.base(ms, names, vehicle, imu)
    prep = base.prep
    has = bool(spec.needs & prep.kinds) if spec.needs_any else spec.needs <= prep.kinds
    if not has:
        raise ValueError(f"{source or 'log'}: {spec.needs_why}")
    if spec.needs_height and not prep.kinds & HEIGHT_SENSORS:
        raise ValueError(f"{source or 'log'}: no range sensor or barometer: nothing to diagnose the altitude with")
    if prep.duration < MIN_SECONDS:
        # the likelihood is scored from 5 s in (the filter settling): a shorter log scores nothing,
        # and "no effect improves the model" would be said of no data at all
        raise ValueError(
            f"{source or 'log'}: {prep.duration:.1f} s of data; a diagnosis needs at least "
            f"{MIN_SECONDS:.0f} s (the first 5 s settle the filter)"
        )
    model = base.model
    curve = stated.motors if stated is not None else None
    if curve is not None:
        model = replace(model, options={**model.options, "motor_curve": curve})
    if prep.logged_throttle and model.f is None:  # a nonlinear model is rebuilt from its options
        motors = motor_outputs_of(prep.measurements.only({Kind.VEHICLE_STATUS}))
        if imu is None:  # the raw accelerometer among the readings: its spectrum says the idle's thrust
            imu = ImuColumns.split(readings.only((Kind.ACCEL,)))[1]
        ratio = thrust_ratio(prep.measurements, curve, motors, imu)
        if ratio is not None:
            model = replace(model, options={**model.options, "thrust_ratio": ratio})
    return Setup(prep, model, spec, names, base.airframe, clearance)


#: ``diagnose --model auto``: the first of these the vehicle is described by and the log can feed. The
#: altitude model first (the accelerometer as input is what every autopilot's height filter takes); the
#: thrust model where the log has a throttle but no accelerometer (an ArduCopter 3.0 text log); the
#: attitude model where the log has a raw IMU and no height sensor
AUTO_ORDER = ("altitude", "quad_thrust", "attitude")


def can_feed(spec: DiagnosisSpec, kinds: set[Kind]) -> bool:
    """The log's kinds feed the model: what it needs, and a height sensor where it needs one."""
    has = bool(spec.needs & kinds) if spec.needs_any else spec.needs <= kinds
    return has and (not spec.needs_height or bool(kinds & HEIGHT_SENSORS))


def choose_model(kinds: set[Kind], vehicle: Vehicle) -> tuple[str | None, str]:
    """The model ``diagnose --model auto`` runs on a log with these kinds of readings, written by this
    vehicle, and one line saying why; None (with the reason) where no model describes the vehicle or
    the log feeds none that does."""
    if not vehicle.models:
        return None, vehicle.why_not("altitude")
    for name in AUTO_ORDER:
        if vehicle.describes(name) and can_feed(DIAGNOSABLE[name], kinds):
            return name, f"{name}: {DIAGNOSABLE[name].help}"
    missing = []
    if Kind.ACCEL not in kinds:
        missing.append("no accelerometer")
    if not kinds & {Kind.THROTTLE, Kind.ACTUATOR}:
        missing.append("no throttle or motor outputs")
    if not kinds & HEIGHT_SENSORS:
        missing.append("no barometer or range sensor")
    return None, (
        f"no model can be run on it ({', '.join(missing) or 'not enough of what the models read'}): the altitude "
        "model takes the accelerometer as its input, the thrust model the throttle, and both diagnose against a "
        "barometer or a range sensor"
    )
