"""The autopilot's own navigation filter: its innovation test ratios and lane switches.

A test ratio is an innovation's square over the gate the filter allows (ArduPilot's EKF: SV
velocity, SP position, SH height, SM / SMX.. magnetometer, SVT airspeed; PX4's ``*_test_ratio``).
Above 1 the filter rejects the measurement; ArduPilot's EKF failsafe watches them against
``FS_EKF_THRESH`` (0.8 by default). MAVLink's EKF_STATUS_REPORT carries the same ratios
(``velocity_variance`` ... are ratios, not variances, in ArduPilot's implementation).

Lane switches: ArduPilot's EKF3/EKF2 run one filter per IMU and log the primary (XKF4/NKF4 ``PI``
with a core index ``C``; ERR subsystem 24); a change in flight is a switch.
"""

from __future__ import annotations

import numpy as np

from drivers.logs.tables import LogTables

from .finding import DOCS, PX4_DOCS, TriageFinding, runs

REJECT = 1.0
FS_EKF_THRESH = 0.8

#: per source table: its test-ratio fields and what they test
RATIOS = {
    "EKF4": {"SV": "velocity", "SP": "position", "SH": "height", "SMX": "magnetometer x", "SMY": "magnetometer y",
             "SMZ": "magnetometer z", "SVT": "airspeed"},
    "NKF4": {"SV": "velocity", "SP": "position", "SH": "height", "SM": "magnetometer", "SVT": "airspeed"},
    "XKF4": {"SV": "velocity", "SP": "position", "SH": "height", "SM": "magnetometer", "SVT": "airspeed"},
    "EKF_STATUS_REPORT": {"velocity_variance": "velocity", "pos_horiz_variance": "horizontal position",
                          "pos_vert_variance": "vertical position", "compass_variance": "compass",
                          "terrain_alt_variance": "terrain height"},
    "estimator_status": {"vel_test_ratio": "velocity", "pos_test_ratio": "position", "hgt_test_ratio": "height",
                         "mag_test_ratio": "magnetometer", "tas_test_ratio": "airspeed",
                         "hagl_test_ratio": "height above ground"},
}  # fmt: skip


def check_ekf(tables: LogTables) -> list[TriageFinding]:
    docs = PX4_DOCS if tables.autopilot == "px4" else DOCS
    doc = docs.get("ekf_innovation", DOCS["ekf_innovation"])
    thresh = tables.params.get("FS_EKF_THRESH") or FS_EKF_THRESH
    out: list[TriageFinding] = []
    for name, fields in RATIOS.items():
        tb = tables.get(name)
        if tb is None:
            continue
        core = tb.numeric("C")
        for col, what in fields.items():
            v = tb.numeric(col)
            if v is None:
                continue
            v = np.where(np.isfinite(v), v, np.nan)  # inf/NaN: that measurement was not being fused
            for a, b, i, j in runs(v > min(thresh, REJECT), tb.t, join=2.0):
                k = i + int(np.nanargmax(v[i : j + 1]))
                rejected = v[k] > REJECT
                lane = f" (core {int(core[k])})" if core is not None else ""
                out.append(
                    TriageFinding(
                        "ekf_innovation",
                        a,
                        b,
                        "error" if rejected else "warning",
                        f"{name}.{col}: the EKF's {what} test ratio{lane} up to {v[k]:.2f} at {tb.t[k]:.1f} s "
                        + ("(measurements rejected above 1)" if rejected else f"(failsafe threshold {thresh:.2f})"),
                        doc,
                    )
                )
    for name in ("XKF4", "NKF4"):
        tb = tables.get(name)
        if tb is None or (pi := tb.numeric("PI")) is None:
            continue
        core = tb.numeric("C")
        sel = core == core[0] if core is not None else np.ones(len(tb), bool)  # one row per time, not per core
        t, p = tb.t[sel], pi[sel]
        for k in (np.flatnonzero(np.diff(p) != 0) + 1).tolist():
            out.append(
                TriageFinding(
                    "lane_switch",
                    float(t[k]),
                    float(t[k]),
                    "warning",
                    f"{name}: the EKF's primary lane switched from {int(p[k - 1])} to {int(p[k])}",
                    DOCS["lane_switch"],
                )
            )
    ti = tables.get("estimator_innovation_test_ratios")
    if ti is not None:
        for col in ti.cols:
            v = ti.numeric(col)
            if v is None or col.startswith(("timestamp", "_")):
                continue
            v = np.where(np.isfinite(v), v, np.nan)  # inf/NaN: that measurement was not being fused
            for a, b, i, j in runs(np.abs(v) > REJECT, ti.t, join=2.0):
                k = i + int(np.nanargmax(np.abs(v[i : j + 1])))
                out.append(
                    TriageFinding(
                        "ekf_innovation",
                        a,
                        b,
                        "error",
                        f"estimator_innovation_test_ratios.{col} up to {abs(v[k]):.2f} at {ti.t[k]:.1f} s "
                        "(measurements rejected above 1)",
                        doc,
                    )
                )
    return out
