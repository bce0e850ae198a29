"""A replay's speed: how many times real time, within what a replay can pace."""

from __future__ import annotations

import math

MIN_SPEED, MAX_SPEED = 0.1, 100.0


def check_speed(speed: float) -> float:
    """``speed`` if a replay can run at it (``inf``: as fast as it reads); ValueError otherwise."""
    if speed == math.inf:
        return speed
    if not MIN_SPEED <= speed <= MAX_SPEED:
        raise ValueError(f"speed {speed:g} outside {MIN_SPEED:g}..{MAX_SPEED:g} (or 'max')")
    return float(speed)
