"""The navigation sensors' quality: the GPS's satellites and HDOP in flight, the compass's
offsets and field, the optical flow's scale, and a barometer that jumps where nothing else moved.

GPS and compass thresholds are LogAnalyzer's (ArduPilot ``Tools/LogAnalyzer/tests``):
``TestGPSGlitch`` warns under 6 satellites or above HDOP 3 and fails under 5 or above HDOP 10 (here
only while armed: every log starts without a fix); ``TestCompass`` warns at offsets longer than
300 and fails above 500 (milligauss), and warns at a field strength that changes by more than 25 %
over the log (fails above 35 %: motor or power-wire interference).

A baro glitch: the baro's height stepping more than :data:`BARO_STEP_M` within
:data:`BARO_STEP_S` while the GPS's height moved less than a third of it and the vertical
accelerometer never saw the acceleration such a step needs (2·Δh/Δt², against 3 g), i.e. a step
no motion explains: a static-pressure disturbance (the wash of a prop, a door, a gust on an
unshielded port) or the sensor's fault.
"""

from __future__ import annotations

import numpy as np

from drivers.logs.tables import LogTables

from .events import flights
from .finding import DOCS, TriageFinding, runs

SATS_WARN, SATS_FAIL, HDOP_WARN, HDOP_FAIL = 6, 5, 3.0, 10.0  # (TestGPSGlitch)
OFS_WARN, OFS_FAIL = 300.0, 500.0  # [mGauss] (TestCompass)
FIELD_WARN, FIELD_FAIL = 0.25, 0.35  # (TestCompass)
BARO_STEP_M, BARO_STEP_S, G = 3.0, 0.3, 9.80665
FLOW_QUALITY, FLOW_MAX_RATE, FLOW_MIN_POINTS, FLOW_MAX_SE, FLOW_MAX_SCALER = 124, 2.0, 100, 0.005, 200.0  # (TestFlow)
FLOW_TOLERANCE = 0.05  # a slope within 5 % of 1 needs no change


def check_navigation(tables: LogTables, t_end: float) -> list[TriageFinding]:
    return [*_gps_quality(tables, t_end), *_compass(tables), *_baro_glitch(tables), *_optical_flow(tables)]


def _optical_flow(tables: LogTables) -> list[TriageFinding]:
    """The flow sensor's scale against the gyro, as LogAnalyzer's TestFlow fits it: flow rate against
    body rate where the quality is over 124 and the rate between 0 and 2 rad/s, a slope per axis
    (at least 100 points, its standard error under 0.005); the scaler that makes it 1 is
    ``1000 ((1 + FLOW_FXSCALER/1000) / slope - 1)``, and beyond ±200 the sensor is set up wrong."""
    of = tables.get("OF")
    if of is None or (q := of.numeric("Qual")) is None:
        return []
    out = []
    for axis in "XY":
        flow, body = of.numeric(f"flow{axis}"), of.numeric(f"body{axis}")
        if flow is None or body is None:
            continue
        use = (q > FLOW_QUALITY) & (np.abs(body) > 0.0) & (np.abs(body) < FLOW_MAX_RATE) & np.isfinite(flow)
        if use.sum() < FLOW_MIN_POINTS:
            continue
        (slope, _), cov = np.polyfit(body[use], flow[use], 1, cov=True)
        if not slope or np.sqrt(cov[0, 0]) > FLOW_MAX_SE:
            continue  # too little rocking to say
        old = tables.params.get(f"FLOW_F{axis}SCALER", 0.0)
        new = 1000.0 * ((1.0 + 0.001 * old) / slope - 1.0)
        if abs(slope - 1.0) <= FLOW_TOLERANCE:
            continue
        bad = abs(new) > FLOW_MAX_SCALER
        t = of.t[use]
        out.append(
            TriageFinding(
                "flow_scale",
                float(t[0]),
                float(t[-1]),
                "error" if bad else "warning",
                f"the optical flow reads {slope:.3f} x the gyro's rate on {axis} ({int(use.sum())} readings): "
                + (
                    f"the scaler it needs ({new:.0f}) is beyond +-{FLOW_MAX_SCALER:g}: the sensor's setup (its "
                    "orientation, its focus) is wrong"
                    if bad
                    else f"set FLOW_F{axis}SCALER to {new:.0f} (it is {old:g})"
                ),
                DOCS["flow_scale"],
            )
        )
    return out


def _gps_quality(tables: LogTables, t_end: float) -> list[TriageFinding]:
    gps = tables.get("GPS", "GPS_RAW_INT", "vehicle_gps_position")
    if gps is None:
        return []
    sats = gps.numeric("NSats", "satellites_visible")
    if "GPS_RAW_INT" in tables and gps is tables["GPS_RAW_INT"]:
        hdop = gps.numeric("eph")  # HDOP x 100, 65535 unknown
        hdop = None if hdop is None else np.where(hdop >= 65535, np.nan, hdop / 100.0)
    else:
        hdop = gps.numeric("HDop", "hdop")  # (PX4's eph is metres, not a dilution)
    if sats is None and hdop is None:
        return []
    spans = flights(tables, t_end)
    armed = np.zeros(len(gps.t), bool)
    for a, b in spans:
        armed |= (gps.t >= a) & (gps.t <= b)
    if not armed.any():
        return []
    bad, worst = [], "warning"
    if sats is not None and np.isfinite(sats[armed]).any():
        low = float(np.nanmin(sats[armed]))
        if low < SATS_WARN:
            bad.append(f"{low:.0f} satellites at the fewest")
            worst = "error" if low < SATS_FAIL else worst
    if hdop is not None and np.isfinite(hdop[armed]).any():
        high = float(np.nanmax(hdop[armed]))
        if high > HDOP_WARN:
            bad.append(f"HDOP {high:.1f} at the worst")
            worst = "error" if high > HDOP_FAIL else worst
    if not bad:
        return []
    ta, tb = float(gps.t[armed][0]), float(gps.t[armed][-1])
    return [
        TriageFinding(
            "gps_quality",
            ta,
            tb,
            worst,
            f"a weak GPS in flight: {', '.join(bad)} (want {SATS_WARN}+ satellites and HDOP under {HDOP_WARN:g}: "
            "an obstructed sky, interference from the video transmitter or the power wiring)",
            DOCS["gps_quality"],
        )
    ]


def _compass(tables: LogTables) -> list[TriageFinding]:
    out: list[TriageFinding] = []
    p = tables.params
    t0 = tables.span[0]
    ofs = [p.get(f"COMPASS_OFS_{a}") for a in "XYZ"]
    if all(v is not None and np.isfinite(v) for v in ofs):
        n = float(np.linalg.norm(ofs))  # type: ignore[arg-type]
        if n > OFS_WARN:
            out.append(
                TriageFinding(
                    "compass",
                    t0,
                    t0,
                    "error" if n > OFS_FAIL else "warning",
                    f"compass offsets {n:.0f} mGauss long (COMPASS_OFS_X/Y/Z {ofs[0]:.0f}, {ofs[1]:.0f}, {ofs[2]:.0f}; "
                    f"over {OFS_WARN:g} the compass sits near iron or a current: move it, calibrate again)",
                    DOCS["compass"],
                )
            )
    mag = tables.get("MAG")
    if mag is not None and all(mag.numeric(c) is not None for c in ("MagX", "MagY", "MagZ")):
        field = np.sqrt(sum(np.square(mag.floats(c)) for c in ("MagX", "MagY", "MagZ")))
        ok = np.isfinite(field) & (field > 0)
        if ok.sum() > 10:
            f, t = field[ok], mag.t[ok]
            lo, hi = float(np.min(f)), float(np.max(f))
            change = (hi - lo) / lo
            if change > FIELD_WARN:
                out.append(
                    TriageFinding(
                        "compass",
                        float(t[0]),
                        float(t[-1]),
                        "error" if change > FIELD_FAIL else "warning",
                        f"the magnetic field's strength changed {100 * change:.0f} % ({lo:.0f}-{hi:.0f} mGauss; "
                        "a compass reads the motors' or the battery's current: COMPASS_MOT calibration, or move it)",
                        DOCS["compass"],
                    )
                )
    return out


def _baro_glitch(tables: LogTables) -> list[TriageFinding]:
    baro = tables.get("BARO")
    if baro is None or (h := baro.numeric("Alt")) is None or len(h) < 10:
        return []
    if (inst := baro.numeric("I")) is not None and (inst != inst[0]).any():
        keep = inst == inst[0]
        t, h = baro.t[keep], h[keep]
    else:
        t = baro.t
    lag = max(1, int(np.searchsorted(t, t[0] + BARO_STEP_S) - 0))
    if lag >= len(h):
        return []
    step = h[lag:] - h[:-lag]
    jumps = runs(np.abs(step) > BARO_STEP_M, t[lag:], join=1.0)
    if not jumps:
        return []
    gps = tables.get("GPS")
    gps_alt = gps.numeric("Alt") if gps is not None else None
    imu = tables.get("IMU")
    acc_z = imu.numeric("AccZ") if imu is not None else None
    out = []
    for _, _, i, j in jumps:
        k = i + int(np.argmax(np.abs(step[i : j + 1])))
        dh, ta, tb = float(step[k]), float(t[k]), float(t[k + lag])
        said = []
        if gps is not None and gps_alt is not None and len(gps_alt) > 2:
            g = np.interp([ta - 0.5, tb + 0.5], gps.t, gps_alt)
            moved = float(g[1] - g[0])
            if abs(moved) > abs(dh) / 3:
                continue  # the GPS saw the vehicle move: a real climb or drop
            said.append(f"the GPS moved {moved:+.1f} m")
        if imu is not None and acc_z is not None:
            w = (imu.t >= ta - 0.2) & (imu.t <= tb + 0.2)
            if w.any():
                peak = float(np.nanmax(np.abs(acc_z[w] + G)))
                needed = 2 * abs(dh) / max(tb - ta, 1e-3) ** 2
                if peak > min(needed, 3 * G):
                    continue  # the accelerometer saw a motion that could do it
                said.append(f"the vertical accelerometer at most {peak / G:.1f} g (the step needs {needed / G:.0f} g)")
        if not said:
            continue  # nothing to hold it against: not stated
        out.append(
            TriageFinding(
                "baro_glitch",
                ta,
                tb,
                "warning",
                f"the baro's height jumped {dh:+.1f} m in {tb - ta:.2f} s while {' and '.join(said)}: a pressure "
                "disturbance or a sensor fault, not a motion",
                DOCS["baro_glitch"],
            )
        )
    return out
