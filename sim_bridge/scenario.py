"""A scenario: which vehicle, which effects exist, which are declared, the seed.

Scenario files are JSON::

    {"vehicle": "quad", "seed": 3, "duration": 60, "flight": "standard",
     "effects":    [{"name": "baro_thrust", "params": {"k": 3.0}}],
     "undeclared": [{"name": "sensor_delay", "params": {"sensor": "range", "seconds": 0.04}}],
     "sensors": {"rates": {"imu": 250}}}

``effects`` are declared: the ground station may be told of them (they are
written to the ``*.declared.json`` beside a recording). ``undeclared`` effects
act on the simulated physics and sensors only; they reach the ground station
by no channel at all (not the link, not the declared file). The truth sidecar
(``*.truth.csv`` and ``*.truth.json``) records everything, for scoring.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from .effects import Effect, parse_effect
from .names import FLIGHTS, RIG_FLIGHTS, VEHICLES
from .sensors import ESC_PROTOCOLS, SensorConfig


class ScenarioError(ValueError):
    """A scenario that cannot be used (one-line message)."""


@dataclass
class Scenario:
    vehicle: str = "quad"
    seed: int = 0
    duration: float = 60.0
    declared: list[Effect] = field(default_factory=list)
    undeclared: list[Effect] = field(default_factory=list)
    sensors: SensorConfig = field(default_factory=SensorConfig)
    flight: str = "standard"  # the built-in flight's manoeuvres (sim_bridge/profile.py)

    def __post_init__(self) -> None:
        if self.vehicle not in VEHICLES:
            raise ScenarioError(f"unknown vehicle {self.vehicle!r}; use one of {', '.join(VEHICLES)}")
        if self.flight not in FLIGHTS:
            raise ScenarioError(f"unknown flight {self.flight!r}; use one of {', '.join(FLIGHTS)}")
        if self.flight == "guided" and self.vehicle == "heli3dof":
            raise ScenarioError("the 3-DOF rig is on its stand: it flies no guided flight")
        if self.flight in RIG_FLIGHTS and self.vehicle != "heli3dof":
            raise ScenarioError(f"the {self.flight} flight is the 3-DOF helicopter's: use --vehicle heli3dof")
        if self.sensors.esc not in ESC_PROTOCOLS:
            raise ScenarioError(f"unknown ESC protocol {self.sensors.esc!r}; use one of {', '.join(ESC_PROTOCOLS)}")

    @property
    def effects(self) -> list[Effect]:
        return self.declared + self.undeclared

    @classmethod
    def from_args(
        cls,
        vehicle: str,
        seed: int,
        duration: float,
        effects: list[str],
        undeclared: list[str],
        file: str | Path | None = None,
        flight: str = "standard",
    ) -> Scenario:
        base = cls.load(file) if file else cls(vehicle=vehicle, seed=seed, duration=duration, flight=flight)
        try:
            base.declared += [parse_effect(s) for s in effects]
            base.undeclared += [parse_effect(s) for s in undeclared]
        except ValueError as e:
            raise ScenarioError(str(e)) from None
        return base

    @classmethod
    def load(cls, path: str | Path) -> Scenario:
        p = Path(path)
        try:
            d = json.loads(p.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise ScenarioError(f"{p}: cannot read scenario: {e}") from None

        def effects(key):
            out = []
            for item in d.get(key, []):
                params = item.get("params", {})
                spec = item["name"] + (":" + ",".join(f"{k}={v}" for k, v in params.items()) if params else "")
                out.append(parse_effect(spec))
            return out

        try:
            cfg = SensorConfig()
            for k, v in d.get("sensors", {}).items():
                if k == "rates":
                    cfg.rates.update(v)
                elif hasattr(cfg, k):
                    setattr(cfg, k, v)
                else:
                    raise ScenarioError(f"{p}: unknown sensor setting {k!r}")
            return cls(
                vehicle=d.get("vehicle", "quad"),
                seed=int(d.get("seed", 0)),
                duration=float(d.get("duration", 60.0)),
                declared=effects("effects"),
                undeclared=effects("undeclared"),
                sensors=cfg,
                flight=d.get("flight", "standard"),
            )
        except (KeyError, ValueError, TypeError) as e:
            raise ScenarioError(f"{p}: {e}") from None

    def declared_json(self) -> dict:
        """What the ground station may know: vehicle and declared effects only."""
        return {"vehicle": self.vehicle, "effects": [e.describe() for e in self.declared]}

    def truth_json(self) -> dict:
        return {
            "vehicle": self.vehicle,
            "seed": self.seed,
            "duration": self.duration,
            "flight": self.flight,
            "declared": [e.describe() for e in self.declared],
            "undeclared": [e.describe() for e in self.undeclared],
        }
