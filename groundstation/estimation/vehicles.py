"""Files that describe a vehicle and a session: vehicle parameter files and declared effects.

A vehicle file (``groundstation/vehicles/<name>.json``, or any ``.json`` path) gives an airframe's constants per model
(its sensors' noise, a thrust curve, a sonar's range) and the effects known for it (a range
sensor's mounting offset); :func:`groundstation.estimation.registry.vehicle_config` checks a
model's section against what that model takes. A session's ``*.declared.json`` (or
``--declared FILE``) lists the effects the ground station has been told of; undeclared effects
are, by definition, not there: finding them is the diagnosis's job.
"""

from __future__ import annotations

import json
from pathlib import Path

VEHICLE_CONFIGS = Path(__file__).resolve().parents[1] / "vehicles"


def vehicle_names() -> list[str]:
    return sorted(p.stem for p in VEHICLE_CONFIGS.glob("*.json"))


def vehicle_file(vehicle: str) -> dict:
    """The whole file of a vehicle: a known name, or the path of a ``.json`` file (what
    ``diagnose --model heli3dof`` writes for a rig); a one-line error naming the known ones."""
    p = VEHICLE_CONFIGS / f"{vehicle}.json"
    if vehicle.endswith(".json"):
        p = Path(vehicle)
        if not p.is_file():
            raise ValueError(f"no vehicle file {vehicle}")
    if not p.exists():
        known = ", ".join(sorted(x.stem for x in VEHICLE_CONFIGS.glob("*.json")))
        raise ValueError(f"no vehicle configuration {vehicle!r}; known: {known}")
    try:
        return json.loads(p.read_text())
    except ValueError as e:
        raise ValueError(f"vehicle configuration {p}: not JSON: {e}") from None


def vehicle_effects(vehicle: str | None) -> list[dict]:
    """Effects known for a vehicle (its geometry, calibrations): declared like a scenario's."""
    return list(vehicle_file(vehicle).get("effects", [])) if vehicle else []


def declared_effects(path: Path | None) -> list[dict]:
    """The effects a ``*.declared.json`` file declares; none where there is no file."""
    if path is None or not path.exists():
        return []
    try:
        return list(json.loads(path.read_text()).get("effects", []))
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: cannot read declared effects: {e}") from None


def declared_beside(log: Path) -> Path:
    """Where a log's declared effects are looked for by default: ``LOG.declared.json``."""
    return log.with_suffix(".declared.json")


def range_offset(effects: list[dict]) -> float:
    """The range sensor's mounting offset ``o`` [m] among declared effects (d_meas = d + o)."""
    return sum(float(e.get("params", {}).get("o", 0.0)) for e in effects if e.get("name") == "range_offset")
