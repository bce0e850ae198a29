"""The ArduPilot parameters the simulated vehicle keeps: those a diagnosis writes
(``params_ardupilot.param``), each with ArduPilot's default and its documented range
(:mod:`drivers.mavlink.param_ranges`). A value outside the range, or not a number, is refused: the
vehicle echoes the value it keeps, so the ground station sees the set unconfirmed.

What the vehicle does with them (:mod:`.onboard_height`, :mod:`.bridge`):

==================  =========  ===============================================================
parameter           default    used for
==================  =========  ===============================================================
BARO1_THST_SCALE    0 Pa       the baro's pressure less the scale times the throttle (4.5+)
EK3_HGT_DELAY       0 ms       the baro fused against the height that long ago (ArduPilot's
                               default is 60 ms; this vehicle's barometer has no lag of its own)
EK3_ALT_M_NSE       2.0 m      the baro's noise in the height estimate
INS_ACCOFFS_Z       0 m/s²     the IMU's z reading less the offset (logged and sent corrected)
INS_ACCSCAL_Z       1          then times the scale
others              see below  kept and logged (GPS delay and noise, range noise, ground effect,
                               motor voltage scaling, harmonic notch): this vehicle's height
                               estimate uses the baro alone, as ArduCopter's by default
                               (``EK3_SRC1_POSZ`` 1)
==================  =========  ===============================================================
"""

from __future__ import annotations

import math

from drivers.mavlink.param_ranges import DOCUMENTED

#: name -> ArduPilot's default (EK3_HGT_DELAY: this vehicle's, see the module's docstring)
DEFAULTS: dict[str, float] = {
    "BARO1_THST_SCALE": 0.0,
    "EK3_HGT_DELAY": 0.0,
    "EK3_ALT_M_NSE": 2.0,
    "EK3_RNG_M_NSE": 0.5,
    "EK3_POSNE_M_NSE": 0.5,
    "EK3_GND_EFF_DZ": 4.0,
    "GPS_DELAY_MS": 0.0,
    "INS_ACCOFFS_Z": 0.0,
    "INS_ACCSCAL_Z": 1.0,
    "MOT_BAT_VOLT_MAX": 0.0,
    "MOT_BAT_VOLT_MIN": 0.0,
    "INS_HNTCH_ENABLE": 0.0,
    "INS_HNTCH_MODE": 1.0,
    "INS_HNTCH_FREQ": 80.0,
    "INS_HNTCH_BW": 40.0,
    "INS_HNTCH_REF": 0.0,
}
#: ArduPilot's "0: disabled" where the documented range starts above zero
DISABLED_ALLOWED = {"MOT_BAT_VOLT_MAX", "MOT_BAT_VOLT_MIN"}


class AutopilotParams:
    """The values, by name; :meth:`set` refuses what the autopilot's documentation does."""

    def __init__(self) -> None:
        self.values = dict(DEFAULTS)

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def accepts(self, name: str, value: float) -> bool:
        if not math.isfinite(value):
            return False
        if name in DISABLED_ALLOWED and value == 0.0:
            return True
        lim = DOCUMENTED.get(name)
        return lim is None or lim[0] <= value <= lim[1]

    def set(self, name: str, value: float) -> bool:
        """Keep ``value`` if the autopilot would; whether it did."""
        if not self.accepts(name, value):
            return False
        self.values[name] = float(value)
        return True
