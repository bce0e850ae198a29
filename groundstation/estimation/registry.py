"""Which estimator ``--model NAME`` means, configured by the declared effects.

A simulated session's ``*.declared.json`` (or ``--declared FILE``) lists the
effects the ground station has been told of; each known one changes the model
(``range_tilt`` gives the altitude filter its slant-range measurement).
Undeclared effects are, by definition, not here: finding them is the diagnosis's job.
"""

from __future__ import annotations

import inspect
import json
import math
from pathlib import Path

from .estimator import KalmanEstimator
from .models.altitude import altitude_model
from .models.attitude_drag import attitude_drag_model
from .models.contact import contact_range, ground_contact
from .models.ground import on_ground
from .models.heli3dof import heli3dof_model
from .models.quad_thrust import quad_thrust_model
from .models.range_gate import range_gate
from .routing import altitude_estimator, heli3dof_estimator, quad_thrust_estimator

MODELS = ("altitude", "quad_thrust", "heli3dof")


def declared_effects(path: Path | None) -> list[dict]:
    if path is None or not path.exists():
        return []
    try:
        return list(json.loads(path.read_text()).get("effects", []))
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: cannot read declared effects: {e}") from None


VEHICLE_CONFIGS = Path(__file__).resolve().parents[1] / "vehicles"


def _vehicle_file(vehicle: str) -> dict:
    p = VEHICLE_CONFIGS / f"{vehicle}.json"
    if not p.exists():
        known = ", ".join(sorted(x.stem for x in VEHICLE_CONFIGS.glob("*.json")))
        raise ValueError(f"no vehicle configuration {vehicle!r}; known: {known}")
    return json.loads(p.read_text())


def vehicle_config(vehicle: str | None, model: str) -> dict:
    """A vehicle's model parameters (``groundstation/vehicles/<vehicle>.json``), or none. A name the
    model does not take is a one-line error here, not a TypeError from deep in the model's factory."""
    if not vehicle:
        return {}
    params = dict(_vehicle_file(vehicle).get(model, {}))
    known = _model_options(model)
    unknown = sorted(set(params) - known) if known else []
    if unknown:
        raise ValueError(
            f"vehicle configuration {vehicle!r}: {model} takes no {', '.join(map(repr, unknown))}; "
            f"it takes {', '.join(sorted(known))}"
        )
    return params


def _model_options(model: str) -> set[str]:
    """The keyword options of a model's factory (empty: a model a vehicle file cannot configure)."""
    factory = {"altitude": altitude_model, "quad_thrust": quad_thrust_model, "attitude": attitude_drag_model}.get(model)
    return set(inspect.signature(factory).parameters) if factory else set()


def vehicle_effects(vehicle: str | None) -> list[dict]:
    """Effects known for a vehicle (its geometry, calibrations): declared like a scenario's."""
    return list(_vehicle_file(vehicle).get("effects", [])) if vehicle else []


def range_offset(effects: list[dict]) -> float:
    """The range sensor's mounting offset ``o`` [m] among declared effects (d_meas = d + o)."""
    return sum(float(e.get("params", {}).get("o", 0.0)) for e in effects if e.get("name") == "range_offset")


def build_estimator(
    name: str,
    declared: list[dict] = (),
    noise: dict | None = None,
    vehicle: str | None = None,
    *,
    vehicle_geometry: bool = True,
) -> KalmanEstimator:
    """``noise``: measurement covariances by sensor (``groundstation noise``'s output);
    ``vehicle``: a per-vehicle parameter file (noise densities, sensor noise and,
    unless ``vehicle_geometry=False``, its known effects such as a range sensor's
    mounting offset)."""
    declared = list(declared) + (vehicle_effects(vehicle) if vehicle_geometry else [])
    names = {e.get("name") for e in declared}
    params = vehicle_config(vehicle, name)
    if name == "altitude":
        # landed, the ground holds the vehicle (models.ground; fed by the throttle, where the link sends one),
        # and a range reading there is no height until the vehicle climbs (models.range_gate)
        return altitude_estimator(
            range_gate(
                on_ground(
                    altitude_model(range_tilt="range_tilt" in names, range_offset=range_offset(declared), **params)
                )
            )
        )
    if name == "heli3dof":
        return heli3dof_estimator(heli3dof_model(R=noise))
    if name == "quad_thrust":
        # a vehicle file's thrust curve, drag, noise and range limits (sim_quad, apm2_sonar)
        floor = params.get("range_limits", (0.0, math.inf))[0]
        # the ground's constraints as resets of z and vz: its stop says nothing of the thrust coefficients
        # (as full updates a simulated landing moved alpha, beta from 19.8, 0.4 to 16.0, 3.2); and with the
        # rotors turning, in contact, the ground holds the vehicle up (models.contact): driven by a touchdown's
        # throttle, the model sank 1.5 m below the ground in the 1.5 s after each landing of a simulated quad
        model = quad_thrust_model(range_tilt="range_tilt" in names, **params)
        return quad_thrust_estimator(range_gate(contact_range(ground_contact(on_ground(model))), floor=floor))
    raise ValueError(f"unknown model {name!r}; known: {', '.join(MODELS)}")


def declared_beside(log: Path) -> Path:
    return log.with_suffix(".declared.json")
