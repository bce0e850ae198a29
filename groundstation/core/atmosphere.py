"""International Standard Atmosphere (ISO 2533), troposphere: pressure <-> altitude.

Used by the simulator to turn altitude into barometric pressure and by models
to turn pressure back into altitude, so both sides use one documented law.

    p(h) = p0 (1 - L h / T0) ^ (g M / (R L))
"""

from __future__ import annotations

import numpy as np

P0 = 101_325.0  # sea-level pressure [Pa]
T0 = 288.15  # sea-level temperature [K]
L = 0.0065  # temperature lapse rate [K/m]
G = 9.80665  # standard gravity [m/s^2]
M = 0.0289644  # molar mass of dry air [kg/mol]
R = 8.3144598  # universal gas constant [J/(mol K)]
_EXP = G * M / (R * L)  # 5.25588


def pressure_at(h, p0: float = P0):
    """Static pressure [Pa] at pressure altitude ``h`` [m]."""
    return p0 * (1.0 - L * np.asarray(h, dtype=float) / T0) ** _EXP


def altitude_at(p, p0: float = P0):
    """Pressure altitude [m] of static pressure ``p`` [Pa]; of a float, a float (read at every baro
    sample of a filter's run, where numpy's scalars cost more than the arithmetic)."""
    if type(p) is float:
        return T0 / L * (1.0 - (p / p0) ** (1.0 / _EXP))
    return T0 / L * (1.0 - (np.asarray(p, dtype=float) / p0) ** (1.0 / _EXP))
