"""How the vehicle flew: leaning past its limit in the air, throttle that does not lift it, and
how an autotune ended.

Thresholds are LogAnalyzer's (ArduPilot ``Tools/LogAnalyzer/tests``): ``TestPitchRollCoupling``
fails a roll or pitch beyond ``ANGLE_MAX`` (45° where the log lacks it) plus 10° while more than
2 m up; ``TestThrust`` and ``TestUnderpowered`` take throttle above 70 % for more than 50 CTUN
records (5 s at its 10 Hz) with the tilt under 20°, and fail an average climb rate below 50 cm/s
(warn below 100 cm/s); ``TestAutotune`` reads the autotune events (EV 30-37, ``ArduCopter/defines.h``).
A lean past the limit after a crash or flip is part of that story and is not said again.
"""

from __future__ import annotations

import numpy as np

from drivers.logs.tables import LogTables

from .finding import DOCS, TriageFinding, runs

LEAN_MARGIN_DEG, ALOFT_M = 10.0, 2.0  # (TestPitchRollCoupling)
HIGH_THROTTLE, MAX_TILT_DEG, HIGH_FOR_S = 0.70, 20.0, 5.0  # (TestThrust)
CLIMB_FAIL, CLIMB_WARN = 0.5, 1.0  # [m/s]
AUTOTUNE = {30: "initialised", 31: "off", 32: "restart", 33: "success", 34: "failed", 35: "reached limit",
            36: "pilot testing", 37: "saved gains"}  # fmt: skip


def check_handling(tables: LogTables, until: float = np.inf) -> list[TriageFinding]:
    return [*_lean(tables, until), *_thrust(tables, until), *_autotune(tables)]


def _lean(tables: LogTables, until: float) -> list[TriageFinding]:
    att, ctun = tables.get("ATT"), tables.get("CTUN")
    if att is None or ctun is None or (h := ctun.numeric("BAlt", "BarAlt")) is None:
        return []
    r, p = att.numeric("Roll"), att.numeric("Pitch")
    if r is None or p is None:
        return []
    limit = tables.params.get("ANGLE_MAX", 4500.0) / 100.0 + LEAN_MARGIN_DEG
    aloft = np.interp(att.t, ctun.t, h) > ALOFT_M
    lean = np.maximum(np.abs(r), np.abs(p))
    over = (lean > limit) & aloft & (att.t < until)
    spans = runs(over, att.t, join=1.0)
    if not spans:
        return []
    k = int(np.argmax(np.where(over, lean, -np.inf)))
    return [
        TriageFinding(
            "lean_angle",
            spans[0][0],
            spans[-1][1],
            "error",
            f"leaned past ANGLE_MAX + {LEAN_MARGIN_DEG:g} = {limit:.0f} deg in the air: roll {r[k]:.0f} / pitch "
            f"{p[k]:.0f} deg at {att.t[k]:.1f} s, {len(spans)} time(s) (a mechanical fault, or the tuning)",
            DOCS["lean_angle"],
        )
    ]


def _thrust(tables: LogTables, until: float) -> list[TriageFinding]:
    ctun, att = tables.get("CTUN"), tables.get("ATT")
    if ctun is None or att is None or (thr := ctun.numeric("ThO", "ThrOut")) is None:
        return []
    climb = ctun.numeric("CRt", "CRate")
    r, p = att.numeric("Roll"), att.numeric("Pitch")
    if climb is None or r is None or p is None:
        return []
    thr = thr / 1000.0 if np.nanmax(thr) > 1.5 else thr  # ArduCopter 3.x: 0..1000
    tilt = np.maximum(np.abs(np.interp(ctun.t, att.t, r)), np.abs(np.interp(ctun.t, att.t, p)))
    high = (thr > HIGH_THROTTLE) & (tilt < MAX_TILT_DEG) & (ctun.t < until)
    worst: TriageFinding | None = None
    for a, b, i, j in runs(high, ctun.t):
        if b - a < HIGH_FOR_S:
            continue
        rate = float(np.nanmean(climb[i : j + 1])) / 100.0  # cm/s
        if rate >= CLIMB_WARN:
            continue
        f = TriageFinding(
            "thrust_margin",
            a,
            b,
            "error" if rate < CLIMB_FAIL else "warning",
            f"throttle {100 * float(np.nanmean(thr[i : j + 1])):.0f} % for {b - a:.1f} s climbing "
            f"{100 * rate:.0f} cm/s: the vehicle is underpowered or lost thrust (heavy, a weak battery, a failing "
            "motor or propeller)",
            DOCS["thrust_margin"],
        )
        if worst is None or f.rank < worst.rank:
            worst = f
    return [worst] if worst is not None else []


def _autotune(tables: LogTables) -> list[TriageFinding]:
    ev = tables.get("EV")
    if ev is None or (ids := ev.numeric("Id")) is None:
        return []
    keep = np.isin(ids, list(AUTOTUNE))
    if not keep.any():
        return []
    t, ids = ev.t[keep], ids[keep].astype(int)
    sessions, start = [], 0
    for k in range(1, len(ids) + 1):
        if k == len(ids) or ids[k] == 30:
            sessions.append((t[start], t[k - 1], set(ids[start:k].tolist())))
            start = k
    out = []
    for a, b, got in sessions:
        if 33 in got or 37 in got:
            sev, said = "info", "succeeded" + (" and the gains were saved" if 37 in got else "")
        elif 34 in got:
            sev, said = "warning", "failed"
        elif 35 in got:
            sev, said = "warning", "reached a limit"
        else:
            sev, said = "info", "ended without a result"
        out.append(
            TriageFinding(
                "autotune",
                float(a),
                float(b),
                sev,
                f"autotune {said} ({', '.join(AUTOTUNE[i] for i in sorted(got))})",
                DOCS["autotune"],
            )  # fmt: skip
        )
    return out
