"""The models by name: what ``--model NAME`` means everywhere.

Each :class:`ModelSpec` says which design document the model comes from, its factory (whose
keyword options are what a vehicle file may set), how its live estimator is built from the
declared effects and a vehicle file, and which sensors it needs. The command line's choices,
the vehicle files' sections, the dashboard and the diagnosis
(:data:`groundstation.diagnosis.models.DIAGNOSABLE`, which adds each diagnosable model's
catalogue) all read :data:`MODELS`.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from groundstation.core.measurement import Kind

from .estimator import KalmanEstimator
from .model_names import CLI_MODELS
from .models.altitude import altitude_model
from .models.attitude_drag import attitude_drag_model
from .models.base import LinearModel, with_measurement_noise
from .models.contact import contact_range, ground_contact
from .models.ground import on_ground
from .models.heli3dof import heli3dof_model
from .models.horizontal import horizontal_model
from .models.quad_thrust import quad_thrust_model
from .models.range_gate import range_gate
from .routing import (
    altitude_estimator,
    attitude_estimator,
    heli3dof_estimator,
    horizontal_estimator,
    quad_thrust_estimator,
)
from .vehicles import range_offset, vehicle_effects, vehicle_file

#: (declared effect names, the declared effects, measurement covariances by sensor, vehicle-file params)
Builder = Callable[[set, list[dict], "dict[str, np.ndarray] | None", dict], KalmanEstimator]

BARO = frozenset({Kind.BARO_PRESSURE, Kind.BARO_ALTITUDE})


@dataclass(frozen=True)
class ModelSpec:
    name: str
    title: str  #: one line: what it estimates, from what
    document: str  #: the design document and chapter it implements
    model: Callable[..., LinearModel]  #: the factory; its keywords are a vehicle file's options
    build: Builder  #: the live estimator
    inputs: frozenset[Kind]  #: what drives its prediction (all of them needed)
    updates: frozenset[Kind]  #: what corrects it (at least one needed)
    #: offered by ``--model`` of connect, replay, evaluate and noise
    cli: bool = True

    def missing(self, kinds: set[Kind]) -> str | None:
        """Why a log with these kinds cannot feed the model, or None."""
        if not self.inputs <= kinds:
            return (
                f"the {self.name} model's input ({', '.join(sorted(k.value for k in self.inputs - kinds))}) is missing"
            )
        if not self.updates & kinds:
            return f"the {self.name} model has none of its sensors ({', '.join(sorted(k.value for k in self.updates))})"
        return None


def _altitude(names: set, declared: list[dict], noise, params: dict) -> KalmanEstimator:
    # landed, the ground holds the vehicle (models.ground; fed by the throttle, where the link sends one),
    # and a range reading there is no height until the vehicle climbs (models.range_gate)
    model = altitude_model(range_tilt="range_tilt" in names, range_offset=range_offset(declared), **params)
    # a noise file is the operator's word on R; without one, the baro's is read from the still stretch
    return altitude_estimator(with_measurement_noise(range_gate(on_ground(model)), noise), still_noise=not noise)


def _quad_thrust(names: set, declared: list[dict], noise, params: dict) -> KalmanEstimator:
    # a vehicle file's thrust curve, drag, noise and range limits (sim_quad, apm2_sonar)
    floor = params.get("range_limits", (0.0, math.inf))[0]
    # the ground's constraints as resets of z and vz: its stop says nothing of the thrust coefficients
    # (as full updates a simulated landing moved alpha, beta from 19.8, 0.4 to 16.0, 3.2); and with the
    # rotors turning, in contact, the ground holds the vehicle up (models.contact): driven by a touchdown's
    # throttle, the model sank 1.5 m below the ground in the 1.5 s after each landing of a simulated quad
    model = quad_thrust_model(range_tilt="range_tilt" in names, range_offset=range_offset(declared), **params)
    gated = range_gate(contact_range(ground_contact(on_ground(model))), floor=floor)
    return quad_thrust_estimator(with_measurement_noise(gated, noise), still_noise=not noise)


def _heli3dof(names: set, declared: list[dict], noise, params: dict) -> KalmanEstimator:
    return heli3dof_estimator(heli3dof_model(R=noise, **params))


def _attitude(names: set, declared: list[dict], noise, params: dict) -> KalmanEstimator:
    return attitude_estimator(attitude_drag_model(**params))


def _horizontal(names: set, declared: list[dict], noise, params: dict) -> KalmanEstimator:
    return horizontal_estimator(horizontal_model(**params))


MODELS: dict[str, ModelSpec] = {
    spec.name: spec
    for spec in (
        ModelSpec(
            "altitude",
            "height, vertical speed and the accelerometer's bias; accelerometer as input, range/baro/GPS updates",
            "coaxial-helicopter document, ch. 9 (eq. 9.1-9.26)",
            altitude_model,
            _altitude,
            frozenset({Kind.ACCEL}),
            frozenset({Kind.RANGE, Kind.GPS}) | BARO,
        ),
        ModelSpec(
            "quad_thrust",
            "height, vertical speed, thrust curve a = alpha tau + beta, baro and ToF offsets; throttle as input",
            "quadcopter altitude document (eq. 1-2, the baro and ToF biases)",
            quad_thrust_model,
            _quad_thrust,
            frozenset(),
            frozenset({Kind.RANGE, Kind.GPS}) | BARO,
        ),
        ModelSpec(
            "heli3dof",
            "pitch, elevation, travel and their rates; motor voltages as input, encoders and IMU updates",
            "3-DOF lab helicopter document (eq. 27-38, 59)",
            heli3dof_model,
            _heli3dof,
            frozenset(),
            frozenset({Kind.ENCODERS, Kind.GYRO, Kind.ACCEL}),
        ),
        ModelSpec(
            "attitude",
            "roll, pitch and body velocity of a multirotor from its IMU (rotor drag)",
            "Leishman et al. 2014 (the documents' complementary filter sees gravity; this sees the drag)",
            attitude_drag_model,
            _attitude,
            frozenset({Kind.GYRO}),
            frozenset({Kind.ACCEL}),
            cli=False,
        ),
        ModelSpec(
            "horizontal",
            "north and east position and velocity, GPS errors as Gauss-Markov states; the dashboard's 3D place",
            "none of the documents: the horizontal place they leave out",
            horizontal_model,
            _horizontal,
            frozenset({Kind.ACCEL}),
            frozenset({Kind.GPS}),
            cli=False,
        ),
    )
}

#: the names ``--model`` offers for a live estimator (model_names.py holds them for the command line,
#: which reads them before anything numerical is loaded)
assert CLI_MODELS == tuple(name for name, spec in MODELS.items() if spec.cli), "model_names.CLI_MODELS"


def spec(name: str) -> ModelSpec:
    """The model of that name, or a one-line error naming the known ones."""
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(f"unknown model {name!r}; known: {', '.join(MODELS)}") from None


def model_options(name: str) -> set[str]:
    """The keyword options of a model's factory: what its section of a vehicle file may set."""
    return set(inspect.signature(spec(name).model).parameters)


def vehicle_config(vehicle: str | None, model: str) -> dict:
    """A vehicle's parameters for one model (its section of ``groundstation/vehicles/<vehicle>.json``),
    or none. A name the model does not take is a one-line error here, not a TypeError from deep in
    the model's factory."""
    if not vehicle:
        return {}
    params = dict(vehicle_file(vehicle).get(model, {}))
    known = model_options(model)
    unknown = sorted(set(params) - known)
    if unknown:
        raise ValueError(
            f"vehicle configuration {vehicle!r}: {model} takes no {', '.join(map(repr, unknown))}; "
            f"it takes {', '.join(sorted(known))}"
        )
    return params


def effects_used(declared: Sequence[dict], vehicle: str | None, stated: Sequence[dict] = ()) -> list[dict]:
    """The effects an estimator is built with: the session's, the vehicle file's, and those the log
    states of itself where neither declares one of that name (a declaration is the operator's word)."""
    out = list(declared) + vehicle_effects(vehicle)
    named = {e.get("name") for e in out}
    return out + [e for e in stated if e.get("name") not in named]


def build_estimator(
    name: str,
    declared: Sequence[dict] = (),
    noise: dict | None = None,
    vehicle: str | None = None,
    *,
    vehicle_geometry: bool = True,
    stated: Sequence[dict] = (),
) -> KalmanEstimator:
    """The live estimator of model ``name``. ``declared``: effects the session declares;
    ``noise``: measurement covariances by sensor (``groundstation noise``'s output);
    ``vehicle``: a vehicle file (noise densities, sensor noise and, unless
    ``vehicle_geometry=False``, its known effects such as a range sensor's mounting offset);
    ``stated``: effects the log states of itself (the range's ground clearance,
    :attr:`.logs.BlockedLog.stated`), each taken where neither the session nor the vehicle
    declares an effect of that name (a declaration is the operator's word on it)."""
    s = spec(name)
    declared = effects_used(declared, vehicle if vehicle_geometry else None, stated)
    names = {e.get("name") for e in declared}
    return s.build(names, declared, noise, vehicle_config(vehicle, name))
