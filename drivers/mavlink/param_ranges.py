"""The ranges the autopilots document for the parameters a diagnosis writes (and the simulated
vehicle keeps, refusing a value outside them).

A value outside its parameter's documented range is never written to a parameter file: the
autopilot would refuse or clamp it, and a fix that large says more about the model than about the
vehicle (a submarine's depth sensor read as a barometer "needed" an accelerometer scale of 1.31).
The suggestion stays in the report, without a value, saying so.

Each range is the ``@Range`` of ArduPilot's parameter definition or the ``@min``/``@max`` of PX4's,
as their sources give them (ArduPilot: ``libraries/AP_NavEKF3/AP_NavEKF3.cpp``,
``AP_InertialSensor.cpp``, ``AP_Baro.cpp``, ``AP_RangeFinder_Params.cpp``,
``AP_MotorsMulticopter.cpp``, ``AP_InertialSensor/AP_InertialSensor_HarmonicNotch``; PX4:
``src/modules/ekf2/ekf2_params.c``). Where a parameter documents no range of its own (PX4's
accelerometer calibration), the physical bound of its sibling is used and named as such.
"""

from __future__ import annotations

#: name -> (low, high, where the range is documented)
DOCUMENTED: dict[str, tuple[float, float, str]] = {
    # ArduPilot
    "EK3_ALT_M_NSE": (0.1, 100.0, "AP_NavEKF3 @Range"),
    "EK3_RNG_M_NSE": (0.1, 10.0, "AP_NavEKF3 @Range"),
    "EK3_POSNE_M_NSE": (0.1, 10.0, "AP_NavEKF3 @Range"),
    "EK3_VELD_M_NSE": (0.05, 5.0, "AP_NavEKF3 @Range [m/s]"),
    "EK3_HGT_DELAY": (0.0, 250.0, "AP_NavEKF3 @Range [ms]"),
    "EK3_GND_EFF_DZ": (0.0, 10.0, "AP_NavEKF3 @Range [m]"),
    "GPS_DELAY_MS": (0.0, 250.0, "AP_GPS @Range [ms]"),
    "INS_ACCSCAL_Z": (0.8, 1.2, "AP_InertialSensor @Range"),
    "INS_ACCOFFS_Z": (-3.5, 3.5, "AP_InertialSensor @Range [m/s^2]"),
    "INS_ACCSCAL_X": (0.8, 1.2, "AP_InertialSensor @Range"),
    "INS_ACCSCAL_Y": (0.8, 1.2, "AP_InertialSensor @Range"),
    "INS_ACCOFFS_X": (-3.5, 3.5, "AP_InertialSensor @Range [m/s^2]"),
    "INS_ACCOFFS_Y": (-3.5, 3.5, "AP_InertialSensor @Range [m/s^2]"),
    "COMPASS_MOT_X": (-1000.0, 1000.0, "AP_Compass @Range [mGauss/A]"),
    "COMPASS_MOT_Y": (-1000.0, 1000.0, "AP_Compass @Range [mGauss/A]"),
    "COMPASS_MOT_Z": (-1000.0, 1000.0, "AP_Compass @Range [mGauss/A]"),
    "BARO1_THST_SCALE": (-300.0, 300.0, "AP_Baro @Range [Pa]"),
    "RNGFND1_GNDCLEAR": (5.0, 127.0, "AP_RangeFinder_Params @Range [cm]"),
    "MOT_BAT_VOLT_MAX": (6.0, 53.0, "AP_MotorsMulticopter @Range [V]"),
    "MOT_BAT_VOLT_MIN": (6.0, 42.0, "AP_MotorsMulticopter @Range [V]"),
    "INS_HNTCH_FREQ": (10.0, 495.0, "AP_InertialSensor harmonic notch @Range [Hz]"),
    "INS_HNTCH_BW": (5.0, 250.0, "AP_InertialSensor harmonic notch @Range [Hz]"),
    "INS_HNTCH_REF": (0.0, 1.0, "AP_InertialSensor harmonic notch @Range"),
    # PX4
    "EKF2_BARO_DELAY": (0.0, 300.0, "ekf2_params.c @min/@max [ms]"),
    "EKF2_GPS_DELAY": (0.0, 300.0, "ekf2_params.c @min/@max [ms]"),
    "EKF2_RNG_DELAY": (0.0, 300.0, "ekf2_params.c @min/@max [ms]"),
    "EKF2_BARO_NOISE": (0.01, 15.0, "ekf2_params.c @min/@max [m]"),
    "EKF2_GPS_P_NOISE": (0.01, 10.0, "ekf2_params.c @min/@max [m]"),
    "EKF2_GPS_V_NOISE": (0.01, 5.0, "ekf2_params.c @min/@max [m/s]"),
    "EKF2_RNG_NOISE": (0.01, float("inf"), "ekf2_params.c @min [m]"),
    "EKF2_GND_EFF_DZ": (0.0, 10.0, "ekf2_params.c @min/@max [m]"),
    "EKF2_GND_MAX_HGT": (0.0, 5.0, "ekf2_params.c @min/@max [m]"),
    "EKF2_MIN_RNG": (0.01, float("inf"), "ekf2_params.c @min [m]"),
    "CAL_ACC0_ZSCALE": (0.8, 1.2, "no range of its own: ArduPilot's INS_ACCSCAL_Z bound"),
}


def outside(name: str, value: float) -> str | None:
    """Why ``value`` cannot be written to ``name`` (one line), or None where it can."""
    lim = DOCUMENTED.get(name)
    if lim is None:
        return None
    lo, hi, where = lim
    if lo <= value <= hi:
        return None
    return (
        f"{value:.4g} is outside {name}'s documented range {lo:g} to {hi:g} ({where}): not written; a fix "
        "that large is a finding about the model, not a parameter to load"
    )
