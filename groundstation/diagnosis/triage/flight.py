"""The flight as the log shows it: upside down, attitude not followed, gaps in the log, the
battery, the GPS fix.

Thresholds are the autopilots' own where they have one: ArduCopter's crash check declares a
crash after 2 s of an attitude error above 30 degrees (``Copter/crash_check.cpp``, ``CRASH_CHECK
_ANGLE_DEVIATION_DEG``); a lithium cell is critical below 3.3 V (ArduPilot's ``BATT_CRT_VOLT``
advice per cell) and low below 3.5 V, or at the log's own ``BATT_LOW_VOLT`` / ``FS_BATT_VOLTAGE``.
"""

from __future__ import annotations

import math

import numpy as np

from drivers.logs.tables import LogTables
from groundstation.core.imu import ImuColumns
from groundstation.core.measurement import Kind

from .events import end_of_flight, flights
from .finding import DOCS, TriageFinding, cell_count, runs

TRACKING_ERROR_DEG = 30.0  # ArduCopter's CRASH_CHECK_ANGLE_DEVIATION_DEG
TRACKING_TIME_S = 1.0  # the crash check waits 2 s; a second already is a loss of control worth stating
CELL_CRITICAL_V, CELL_LOW_V = 3.3, 3.5
BATTERY_JOIN_S = 30.0  # sag under load comes and goes: stretches this close are one event
GAP_MIN_S = 1.0  # a pause in a stream shorter than this is a logging hiccup, not a gap


def _attitude(tables: LogTables) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(t, roll, pitch [deg], desired roll, desired pitch [deg] or None) from the log's attitude."""
    att = tables.get("ATT")
    if att is not None and (r := att.numeric("Roll")) is not None and (p := att.numeric("Pitch")) is not None:
        dr, dp = att.numeric("DesRoll"), att.numeric("DesPitch")
        if dr is None and (ri := att.numeric("RollIn")) is not None and (pi := att.numeric("PitchIn")) is not None:
            dr, dp = ri, pi  # ArduCopter 3.0-3.1: the attitude asked for [deg]
        return att.t, r, p, dr, dp
    a = tables.get("ATTITUDE")
    if a is not None:
        r, p = np.degrees(a.floats("roll")), np.degrees(a.floats("pitch"))
        return a.t, r, p, None, None
    va = tables.get("vehicle_attitude")
    if va is not None and all(f"q[{i}]" in va for i in range(4)):
        w, x, y, z = (va.floats(f"q[{i}]") for i in range(4))
        r = np.degrees(np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)))
        p = np.degrees(np.arcsin(np.clip(2 * (w * y - z * x), -1, 1)))
        sp = tables.get("vehicle_attitude_setpoint")
        if sp is not None and "roll_body" in sp and "pitch_body" in sp and len(sp) > 1:
            dr = np.interp(va.t, sp.t, np.degrees(sp.floats("roll_body")))
            dp = np.interp(va.t, sp.t, np.degrees(sp.floats("pitch_body")))
            return va.t, r, p, dr, dp
        return va.t, r, p, None, None
    return np.zeros(0), np.zeros(0), np.zeros(0), None, None


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + 180.0) % 360.0 - 180.0


def check_attitude(tables: LogTables, t_end: float, imu: ImuColumns | None = None) -> list[TriageFinding]:
    """Flip and crash as the autopilot's attitude shows them; where the raw IMU says the vehicle sat
    level and still through it, an estimator that diverged instead (:func:`diverged`)."""
    found = _attitude_findings(tables, t_end)
    if imu is None:
        return found
    out: list[TriageFinding] = []
    for f in found:
        d = diverged(f, imu, tables)
        if d is None:
            out.append(f)
        elif not any(o.name == d.name and o.t_start <= d.t_end and d.t_start <= o.t_end for o in out):
            out.append(d)  # a flip and a crash over one divergence are one finding
    return out


#: the raw IMU says "level and still": gravity within this of the body's z axis, rotation below this
LEVEL_DEG = 10.0
STILL_RAD_S = 0.2
#: ... for this share of the stretch's samples, with at least this many of them
HELD_SHARE = 0.9
MIN_SAMPLES = 20


def diverged(f: TriageFinding, imu: ImuColumns, tables: LogTables) -> TriageFinding | None:
    """An estimator divergence in place of flip or crash ``f``, when the raw sensors contradict the
    attitude it rests on: through the stretch the accelerometer reads gravity along the body's z axis
    (within :data:`LEVEL_DEG`) and the gyros no rotation (below :data:`STILL_RAD_S`). A vehicle does not
    turn over without turning; an estimate fed a bad calibration does (an ArduCopter 3.1 log sat at
    idle on the ground, its baro within 0.3 m, while its roll estimate ran to 95 deg and its altitude
    to -54 m: the triage had called it a flip and a crash). The parameters that are not numbers, if
    any, are named as the likely cause. None: the raw sensors agree with the estimate, or say nothing."""
    acc, gyr = imu.get(Kind.ACCEL, 0), imu.get(Kind.GYRO, 0)
    if acc is None or f.name not in ("flip", "crash"):
        return None
    a = (acc.t >= f.t_start) & (acc.t <= f.t_end)
    if a.sum() < MIN_SAMPLES:
        return None
    fa = acc.values(a)
    norm = np.linalg.norm(fa, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        off_z = np.degrees(np.arccos(np.clip(-fa[:, 2] / norm, -1.0, 1.0)))
    level = float(np.mean(off_z < LEVEL_DEG))
    still = 1.0
    if gyr is not None:
        g = (gyr.t >= f.t_start) & (gyr.t <= f.t_end)
        if g.sum() >= MIN_SAMPLES:
            still = float(np.mean(np.linalg.norm(gyr.values(g), axis=1) < STILL_RAD_S))
    if level < HELD_SHARE or still < HELD_SHARE:
        return None
    bad = sorted(k for k, v in tables.params.items() if not math.isfinite(v))
    cause = (
        f"; the log's parameters {', '.join(bad[:6])}{' and more' if len(bad) > 6 else ''} are not numbers, "
        "which the estimator computes with: the likely cause"
        if bad
        else ""
    )
    return TriageFinding(
        "estimator_divergence",
        f.t_start,
        f.t_end,
        "error",
        f"the autopilot's attitude says {f.name} ({f.evidence}), but the accelerometer read gravity along the "
        f"body's z axis within {LEVEL_DEG:.0f} deg and the gyros below {STILL_RAD_S} rad/s for "
        f"{min(level, still):.0%} of the stretch: the vehicle sat level and still, and its attitude estimate "
        f"diverged{cause}",
        DOCS["estimator_divergence"],
        cuts=True,
    )


def _attitude_findings(tables: LogTables, t_end: float) -> list[TriageFinding]:
    t, r, p, dr, dp = _attitude(tables)
    out: list[TriageFinding] = []
    if not len(t):
        return out
    # upside down: the body's z axis points up, cos(roll) cos(pitch) < 0; one finding per flight
    up_z = np.cos(np.radians(r)) * np.cos(np.radians(p))
    up = up_z < 0
    tilt = np.degrees(np.arccos(np.clip(up_z, -1.0, 1.0)))
    for end, group in _by_flight(tables, runs(up, t, join=1.0), t_end).items():
        i, j = group[0][2], group[-1][3]
        k = i + int(np.argmax(np.abs(r[i : j + 1])))
        # the roll-over began where the tilt last passed the crash check's angle: cut from there
        s = i
        while s > 0 and tilt[s - 1] > TRACKING_ERROR_DEG:
            s -= 1
        again = f", {len(group)} times over {group[-1][1] - group[0][0]:.1f} s" if len(group) > 1 else ""
        over = f"tilting past {TRACKING_ERROR_DEG:.0f} deg from {t[s]:.1f} s, " if s < i else ""
        out.append(
            TriageFinding(
                "flip",
                float(t[s]),
                end,
                "critical",
                f"{over}upside down from {group[0][0]:.1f} s{again} "
                f"(roll {r[k]:.0f} deg at {t[k]:.1f} s, pitch {p[k]:.0f} deg)",
                DOCS["flip"],
                cuts=True,
            )
        )
    if dr is not None and dp is not None:
        err = np.maximum(np.abs(_wrap(dr - r)), np.abs(_wrap(dp - p)))
        spans = flights(tables, t_end)
        armed = _in(t, spans) if spans else np.ones(len(t), bool)
        lost = runs((err > TRACKING_ERROR_DEG) & armed, t, join=0.5, min_len=TRACKING_TIME_S)
        # one finding per flight: from the first loss of control, with the worst of them
        for end, group in _by_flight(tables, lost, t_end).items():
            i = group[0][2]
            j = group[-1][3]
            k = i + int(np.argmax(err[i : j + 1]))
            total = sum(b - a for a, b, _, _ in group)
            out.append(
                TriageFinding(
                    "crash",
                    group[0][0],
                    end,
                    "critical",
                    f"attitude not followed: error above {TRACKING_ERROR_DEG:.0f} deg for {total:.1f} s "
                    f"from {group[0][0]:.1f} s, up to {err[k]:.0f} deg at {t[k]:.1f} s "
                    f"(asked roll {dr[k]:.0f} / pitch {dp[k]:.0f}, got {r[k]:.0f} / {p[k]:.0f} deg)",
                    DOCS["crash"],
                    cuts=True,
                )
            )
    return out


def _by_flight(tables: LogTables, spans: list, t_end: float) -> dict[float, list]:
    """Runs grouped by the flight they start in (keyed by its end)."""
    out: dict[float, list] = {}
    for span in spans:
        out.setdefault(end_of_flight(tables, span[0], t_end), []).append(span)
    return out


def _in(t: np.ndarray, spans: list[tuple[float, float]]) -> np.ndarray:
    m = np.zeros(len(t), bool)
    for a, b in spans:
        m |= (t >= a) & (t <= b)
    return m


def check_gaps(tables: LogTables) -> list[TriageFinding]:
    """A pause in the log's fastest regular stream longer than both GAP_MIN_S and 20 of its periods."""
    best = None
    for name, tb in tables.tables.items():
        if len(tb) < 50 or name in ("logged_messages", "PARAM_VALUE", "STATUSTEXT"):
            continue
        t = tb.t[np.isfinite(tb.t)]
        if len(t) < 50:
            continue
        rate = len(t) / max(t[-1] - t[0], 1e-9)
        if best is None or rate > best[0]:
            best = (rate, name, np.sort(t))
    if best is None:
        return []
    rate, name, t = best
    dt = np.diff(t)
    limit = max(GAP_MIN_S, 20.0 / rate)
    out = []
    what = "telemetry received" if tables.clock == "recording" else "records logged"
    for k in np.flatnonzero(dt > limit):
        out.append(
            TriageFinding(
                "logging_gap",
                float(t[k]),
                float(t[k + 1]),
                "error" if dt[k] > 5.0 else "warning",
                f"no {name} {what} for {dt[k]:.1f} s (it runs at {rate:.0f} Hz)",
                DOCS["logging_gap"],
            )
        )
    return out


def _battery(tables: LogTables) -> tuple[np.ndarray, np.ndarray] | None:
    for name, col, scale in (
        ("BAT", "Volt", 1.0),
        ("CURR", "Volt", None),
        ("SYS_STATUS", "voltage_battery", 1e-3),
        ("battery_status", "voltage_v", 1.0),
    ):
        tb = tables.get(name)
        if tb is None or (v := tb.numeric(col)) is None:
            continue
        if scale is None:  # CURR: volts x 100 in old logs
            scale = 0.01 if np.nanmax(v) > 100 else 1.0
        v = v * scale
        ok = (v > 1.0) & (v < 100.0)  # 0: no monitor; 65.535: "unknown"
        if ok.sum() > 2:
            return tb.t[ok], v[ok]
    return None


def check_battery(tables: LogTables, t_end: float) -> list[TriageFinding]:
    tv = _battery(tables)
    if tv is None:
        return []
    t, v = tv
    cells = cell_count(float(np.percentile(v, 99)))
    params = tables.params
    low = next((params[k] for k in ("BATT_LOW_VOLT", "FS_BATT_VOLTAGE") if params.get(k, 0) > 0), cells * CELL_LOW_V)
    crit = params.get("BATT_CRT_VOLT", 0) or cells * CELL_CRITICAL_V
    out = []
    for level, limit, sev in (("critical", crit, "error"), ("low", low, "warning")):
        spans = runs(v < limit, t, join=BATTERY_JOIN_S, min_len=1.0)
        if spans:
            a, b = spans[0][0], spans[-1][1]
            k = int(np.argmin(np.where((t >= a) & (t <= b), v, np.inf)))
            out.append(
                TriageFinding(
                    "battery",
                    a,
                    b,
                    sev,
                    f"battery {level}: {v[k]:.2f} V at {t[k]:.0f} s ({v[k] / cells:.2f} V a cell of {cells}S; "
                    f"{level} below {limit:.2f} V; {len(spans)} stretch(es) to {b:.0f} s)",
                    DOCS["battery"],
                )
            )
        if out:  # the critical stretches said, the low ones around them add nothing
            break
    return out


def check_gps(tables: LogTables) -> list[TriageFinding]:
    """The 3-D fix lost after it was had (a GPS failsafe's cause)."""
    for name, col in (("GPS", "Status"), ("GPS_RAW_INT", "fix_type"), ("vehicle_gps_position", "fix_type")):
        tb = tables.get(name)
        if tb is None or (fix := tb.numeric(col)) is None:
            continue
        had = np.flatnonzero(fix >= 3)
        if not len(had):
            return []
        t, fix = tb.t[had[0] :], fix[had[0] :]
        nsat = tb.numeric("NSats", "satellites_visible")
        out = []
        for a, _, i, j in runs(fix < 3, t, join=2.0):
            end = t[min(j + 1, len(t) - 1)]
            sats = f", {int(np.nanmin(nsat[had[0] :][i : j + 1]))} satellites" if nsat is not None else ""
            out.append(
                TriageFinding(
                    "gps_glitch",
                    a,
                    float(end),
                    "error" if end - a > 5.0 else "warning",
                    f"3-D fix lost for {end - a:.1f} s (fix type {int(np.nanmin(fix[i : j + 1]))}{sats})",
                    DOCS["gps_glitch"],
                )
            )
        return out
    return []
