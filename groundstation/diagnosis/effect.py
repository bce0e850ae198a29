"""An effect as the diagnosis reports it: its catalogue name, its parameters as estimated from the
log (with their standard errors as ``sigma_<name>``), and the evidence it was claimed or turned
away on."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Effect:
    name: str
    params: dict
    evidence: dict
