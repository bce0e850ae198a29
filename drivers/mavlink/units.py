"""MAVLink field units (as the message definitions name them) to SI.

The unit strings are exactly those of the XML definitions, which pymavlink
exposes as ``fieldunits_by_name``; the test suite checks every field the
decoder reads against them, so a unit is never assumed silently.
"""

from __future__ import annotations

import math

#: Standard gravity [m/s^2] (CGPM 1901), the 'G' of MAVLink's 'mG'.
G0 = 9.80665

#: unit -> (scale, offset): si = raw * scale + offset
UNIT_TO_SI: dict[str, tuple[float, float]] = {
    "m/s/s": (1.0, 0.0),
    "mG": (G0 / 1000.0, 0.0),
    "rad/s": (1.0, 0.0),
    "mrad/s": (1e-3, 0.0),
    "gauss": (1e-4, 0.0),  # 1 G = 1e-4 T
    "mgauss": (1e-7, 0.0),
    "hPa": (100.0, 0.0),
    "degC": (1.0, 273.15),  # temperatures in kelvin
    "cdegC": (0.01, 273.15),
    "m": (1.0, 0.0),
    "cm": (0.01, 0.0),
    "mm": (1e-3, 0.0),
    "cm^2": (1e-4, 0.0),
    "m/s": (1.0, 0.0),
    "cm/s": (0.01, 0.0),
    "rad": (1.0, 0.0),
    "deg": (math.pi / 180.0, 0.0),
    "cdeg": (math.pi / 18000.0, 0.0),
    "degE7": (1e-7, 0.0),  # latitude/longitude stay in degrees (WGS84)
    "mV": (1e-3, 0.0),
    "cA": (1e-2, 0.0),
    "%": (1e-2, 0.0),  # fractions 0..1
    "us": (1e-6, 0.0),
    "ms": (1e-3, 0.0),
}


def scale(unit: str) -> float:
    s, off = UNIT_TO_SI[unit]
    if off:
        raise ValueError(f"unit {unit!r} has an offset; use to_si()")
    return s
