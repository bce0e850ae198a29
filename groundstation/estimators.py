"""Which estimator ``--model NAME`` means, configured by the declared effects.

A simulated session's ``*.declared.json`` (or ``--declared FILE``) lists the
effects the ground station has been told of; each known one changes the model
(``range_tilt`` gives the altitude filter its slant-range measurement).
Undeclared effects are, by definition, not here: finding them is the diagnosis's job.
"""
from __future__ import annotations

import json
from pathlib import Path

from .estimator import KalmanEstimator, altitude_estimator, heli3dof_estimator, quad_thrust_estimator
from .models.altitude import altitude_model
from .models.quad_thrust import quad_thrust_model

MODELS = ("altitude", "quad_thrust", "heli3dof")


def declared_effects(path: Path | None) -> list[dict]:
    if path is None or not path.exists():
        return []
    try:
        return list(json.loads(path.read_text()).get("effects", []))
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: cannot read declared effects: {e}") from None


VEHICLE_CONFIGS = Path(__file__).parent / "vehicles"


def vehicle_config(vehicle: str | None, model: str) -> dict:
    """A vehicle's model parameters (``groundstation/vehicles/<vehicle>.json``), or none."""
    if not vehicle:
        return {}
    p = VEHICLE_CONFIGS / f"{vehicle}.json"
    if not p.exists():
        known = ", ".join(sorted(x.stem for x in VEHICLE_CONFIGS.glob("*.json")))
        raise ValueError(f"no vehicle configuration {vehicle!r}; known: {known}")
    return dict(json.loads(p.read_text()).get(model, {}))


def build_estimator(name: str, declared: list[dict] = (), noise: dict | None = None,
                    vehicle: str | None = None) -> KalmanEstimator:
    """``noise``: measurement covariances by sensor (``groundstation noise``'s output);
    ``vehicle``: a per-vehicle parameter file (noise densities, sensor noise)."""
    names = {e.get("name") for e in declared}
    params = vehicle_config(vehicle, name)
    if name == "altitude":
        return altitude_estimator(altitude_model(range_tilt="range_tilt" in names, **params))
    if name == "heli3dof":
        from .models.heli3dof import heli3dof_model
        return heli3dof_estimator(heli3dof_model(R=noise))
    if name == "quad_thrust":
        return quad_thrust_estimator(quad_thrust_model(range_tilt="range_tilt" in names))
    raise ValueError(f"unknown model {name!r}; known: {', '.join(MODELS)}")


def declared_beside(log: Path) -> Path:
    return log.with_suffix(".declared.json")
