"""Physical constants, defined once."""

from __future__ import annotations

#: standard gravity [m/s^2] (CGPM 1901); also the 'G' of MAVLink's 'mG'
G = 9.80665
