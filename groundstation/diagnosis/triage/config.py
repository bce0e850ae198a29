"""Configuration risks the log's parameters show: the autopilot's own safety checks turned off,
sensors never calibrated, failsafes disabled. ArduPilot and PX4 parameter names; each rule says
what it found.
"""

from __future__ import annotations

import math

from drivers.logs.tables import LogTables
from drivers.mavlink.param_ranges import DOCUMENTED, outside

from .finding import DOCS, PX4_DOCS, TriageFinding

#: calibration results that have a documented range (a value outside it is a calibration gone wrong)
CALIBRATIONS = [f"{kind}_{a}" for kind in ("INS_ACCSCAL", "INS_ACCOFFS", "COMPASS_MOT") for a in "XYZ"]
#: PX4's circuit breaker "disabled" magic numbers (``circuit_breaker.h``)
PX4_BREAKERS = {"CBRK_SUPPLY_CHK": 894281, "CBRK_IO_SAFETY": 22027, "CBRK_USB_CHK": 197848}


def _zero(params: dict, *names: str) -> bool:
    vals = [params.get(n) for n in names]
    return all(v is not None for v in vals) and all(abs(v) < 1e-9 for v in vals)  # type: ignore[arg-type]


def check_config(tables: LogTables, t0: float) -> list[TriageFinding]:
    p = tables.params
    risks: list[str] = []
    if p.get("ARMING_CHECK") == 0:
        risks.append("ARMING_CHECK = 0: every pre-arm check is off (it flew without the checks that catch the rest)")
    if p.get("COMPASS_USE", 1) and _zero(p, "COMPASS_OFS_X", "COMPASS_OFS_Y", "COMPASS_OFS_Z"):
        risks.append("COMPASS_OFS_X/Y/Z = 0 with COMPASS_USE on: the compass was never calibrated")
    if _zero(p, "INS_ACCOFFS_X", "INS_ACCOFFS_Y", "INS_ACCOFFS_Z"):
        risks.append("INS_ACCOFFS_X/Y/Z = 0: the accelerometer was never calibrated")
    if p.get("FS_THR_ENABLE") == 0:
        risks.append("FS_THR_ENABLE = 0: no radio failsafe (the vehicle keeps its last input if the radio is lost)")
    if p.get("BATT_MONITOR", 0) > 0 and (p.get("FS_BATT_ENABLE") == 0 or p.get("BATT_FS_LOW_ACT") == 0):
        risks.append("battery monitored but its failsafe off (FS_BATT_ENABLE / BATT_FS_LOW_ACT = 0)")
    # LogAnalyzer's TestParams (copter): the compass on, THR_MIN < 200, THR_MID within 300..700 (3.x)
    if p.get("MAG_ENABLE") == 0:
        risks.append("MAG_ENABLE = 0: no compass (a copter's heading then drifts)")
    if p.get("THR_MIN", 0) >= 200:
        risks.append(f"THR_MIN = {p['THR_MIN']:g}: the motors' idle at or above 20 % (a copter may not descend)")
    if "THR_MID" in p and not 300 <= p["THR_MID"] <= 700:
        risks.append(f"THR_MID = {p['THR_MID']:g}: the hover throttle outside 30-70 % (the vehicle's power is off)")
    if tables.autopilot == "px4":
        for name, off in PX4_BREAKERS.items():
            if p.get(name) == off:
                risks.append(f"{name} = {off}: that safety check is disabled")
        if p.get("CAL_MAG0_ID") == 0:
            risks.append("CAL_MAG0_ID = 0: the magnetometer was never calibrated")
        if p.get("CAL_ACC0_ID") == 0:
            risks.append("CAL_ACC0_ID = 0: the accelerometer was never calibrated")
    for name in CALIBRATIONS:
        v = p.get(name)
        if v is not None and math.isfinite(v) and outside(name, v):
            lo, hi, _ = DOCUMENTED[name]
            risks.append(
                f"{name} = {v:g}: a calibration outside its documented range {lo:g} to {hi:g} (calibrate again)"
            )
    doc = (PX4_DOCS if tables.autopilot == "px4" else DOCS)["config_risk"]
    sev = {True: "warning", False: "info"}
    found = [
        TriageFinding("config_risk", t0, t0, sev["ARMING_CHECK" in r or "never" in r or "calibrat" in r], r, doc)
        for r in risks
    ]
    bad = sorted(k for k, v in p.items() if not math.isfinite(v))
    if bad:
        found.append(
            TriageFinding(
                "bad_parameter",
                t0,
                t0,
                "error",
                f"{len(bad)} parameter(s) not a number: {', '.join(bad[:8])}{' ...' if len(bad) > 8 else ''} "
                "(an estimator that computes with one diverges; set them again, or reset them to defaults)",
                DOCS["bad_parameter"],
            )
        )
    return found
