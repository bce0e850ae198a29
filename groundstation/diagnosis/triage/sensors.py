"""Vibration, clipping and IMU-to-IMU mismatch.

Vibration is the autopilot's own metric where the log has it (ArduPilot's VIBE and MAVLink's
VIBRATION: the standard deviation of the accelerometer above about 5 Hz, m/s^2; PX4's
``vehicle_imu_status.accel_vibration_metric``), and the same statistic from the raw accelerometer
where it does not. ArduPilot's guidance (the page in :data:`DOCS`): below 30 m/s^2 is normally
acceptable, above 60 m/s^2 nearly always brings problems with position or altitude hold.
Clipping is the autopilot's count of samples at the sensor's range, or, from the raw
accelerometer, runs of readings stuck at the log's largest magnitude.

IMU mismatch uses ArduPilot's pre-arm limits: accelerometers more than 0.75 m/s^2 apart, gyros
more than 5 deg/s apart (``AP_Arming``'s ``ins_checks``), held for a second (1 s means).
"""

from __future__ import annotations

import numpy as np

from drivers.logs.tables import LogTables
from groundstation.core.imu import ImuColumns, ImuSeries
from groundstation.core.measurement import Kind

from .finding import DOCS, PX4_DOCS, TriageFinding, runs

VIBE_WARN, VIBE_BAD = 30.0, 60.0  # m/s^2
ACCEL_MISMATCH, GYRO_MISMATCH = 0.75, np.radians(5.0)  # m/s^2, rad/s
RAW_VIBE_HIGHPASS_HZ = 5.0
VIBE_JOIN_S, CLIP_JOIN_S = 10.0, 10.0  # stretches this close are one episode
CLIP_FLAT_TOP = 3  # readings at the same largest magnitude: a clipped sensor's flat top


def _vibe_tables(tables: LogTables):
    """(t, worst axis level [m/s^2], clipping counts (cumulative, a column per counter) or None,
    source) per IMU."""
    vibe = tables.get("VIBE")
    if vibe is not None and vibe.numeric("VibeX") is not None:
        inst = vibe.numeric("IMU")
        for k in np.unique(inst) if inst is not None else [None]:
            sel = inst == k if inst is not None else np.ones(len(vibe), bool)
            lvl = np.nanmax(np.column_stack([vibe.floats(f"Vibe{a}")[sel] for a in "XYZ"]), axis=1)
            clips = [c for c in [vibe.numeric(f"Clip{i}") for i in range(3)] + [vibe.numeric("Clip")] if c is not None]
            clip = np.column_stack([c[sel] for c in clips]) if clips else None
            yield vibe.t[sel], lvl, clip, "VIBE" + (f" IMU {int(k)}" if k is not None else "")
        return
    v = tables.get("VIBRATION")
    if v is not None:
        lvl = np.nanmax(np.column_stack([v.floats(f"vibration_{a}") for a in "xyz"]), axis=1)
        clip = np.column_stack([v.floats(f"clipping_{i}") for i in range(3)])
        yield v.t, lvl, clip, "VIBRATION"
        return
    for name, tb in tables.starting("vehicle_imu_status"):
        lvl = tb.numeric("accel_vibration_metric")
        if lvl is None:
            continue
        clips = [c for i in range(3) if (c := tb.numeric(f"accel_clipping[{i}]")) is not None]
        clip = np.column_stack(clips) if len(clips) == 3 else None
        yield tb.t, lvl, clip, name


def check_vibration(tables: LogTables, imu: ImuColumns) -> list[TriageFinding]:
    docs = PX4_DOCS if tables.autopilot == "px4" else DOCS
    out: list[TriageFinding] = []
    found = False
    for t, lvl, clip, src in _vibe_tables(tables):
        found = True
        out += _levels(t, lvl, src, docs)
        if clip is not None:
            out += _clipping(t, clip, src, docs)
    if not found:
        out += _raw(imu.get(Kind.ACCEL, 0), docs)
    return out


def _levels(t: np.ndarray, lvl: np.ndarray, src: str, docs: dict) -> list[TriageFinding]:
    out = []
    for a, b, i, j in runs(lvl > VIBE_WARN, t, join=VIBE_JOIN_S):
        k = i + int(np.argmax(lvl[i : j + 1]))
        bad = lvl[k] > VIBE_BAD
        out.append(
            TriageFinding(
                "vibration",
                a,
                b,
                "error" if bad else "warning",
                f"{src}: up to {lvl[k]:.1f} m/s^2 at {t[k]:.1f} s (above {VIBE_BAD if bad else VIBE_WARN:.0f} m/s^2), "
                f"{b - a:.1f} s above {VIBE_WARN:.0f}",
                docs.get("vibration", DOCS["vibration"]),
                cuts=bool(bad),
            )
        )
    return out


def _clipping(t: np.ndarray, clip: np.ndarray, src: str, docs: dict) -> list[TriageFinding]:
    """Clip counts only grow (until a reboot resets them): the stretches where they grow."""
    d = np.diff(clip, axis=0, prepend=clip[:1])
    d[d < 0] = 0  # a reboot
    grew = d.sum(axis=1)
    spans = runs(grew > 0, t, join=CLIP_JOIN_S)
    if not spans:
        return []
    totals = ", ".join(f"counter {i}: {int(d[:, i].sum())}" for i in range(d.shape[1]) if d[:, i].sum() > 0)
    worst = max(spans, key=lambda s: grew[s[2] : s[3] + 1].sum())
    return [
        TriageFinding(
            "clipping",
            a,
            b,
            "error",
            f"{src}: the accelerometer hit its range {int(grew[i : j + 1].sum())} times here "
            f"({totals} over the log; the most, {int(grew[worst[2] : worst[3] + 1].sum())}, "
            f"at {worst[0]:.0f}-{worst[1]:.0f} s)",
            docs.get("clipping", DOCS["clipping"]),
            cuts=True,
        )
        for a, b, i, j in spans
    ]


def _raw(acc: ImuSeries | None, docs: dict) -> list[TriageFinding]:
    if acc is None or len(acc) < 100:
        return []
    t = acc.t
    rate = (len(t) - 1) / max(t[-1] - t[0], 1e-9)
    if rate < 4 * RAW_VIBE_HIGHPASS_HZ:
        return []
    # high-pass: minus a moving mean over one period of the cut-off; then 1 s RMS per axis. One axis
    # at a time: a 1-hour 1 kHz log's samples are 86 MB an array of three axes, and this takes several
    w = max(3, int(round(rate / RAW_VIBE_HIGHPASS_HZ)))
    kernel = np.ones(w) / w
    n = max(1, int(round(rate)))
    m = len(t) // n
    if m < 2:
        return []
    lvl = np.zeros(m)
    peak = np.zeros(3)
    for i in range(3):
        a = acc.value[:, i].astype(np.float64)
        hp = a - np.convolve(a, kernel, mode="same")
        lvl = np.maximum(lvl, np.sqrt((hp[: m * n] ** 2).reshape(m, n).mean(axis=1)))
        peak[i] = np.abs(a).max()
    tw = t[: m * n].reshape(m, n)[:, 0]
    src = f"raw accelerometer at {rate:.0f} Hz" + (" (aliased: below 200 Hz)" if rate < 200 else "")
    out = _levels(tw, lvl, src, docs)
    # clipping: readings stuck at the largest magnitude the log has, if that is a sensor range (>= 7.8 g)
    for i in range(3):
        if peak[i] < 76.0:
            continue
        stuck = np.abs(acc.value[:, i].astype(np.float64)) >= 0.995 * peak[i]
        if stuck.sum() < CLIP_FLAT_TOP:  # one reading at the peak is an impact, not a sensor's range
            continue
        for s, e, _, _ in runs(stuck, t, join=1.0):
            out.append(
                TriageFinding(
                    "clipping",
                    s,
                    e,
                    "error",
                    f"raw accelerometer {'xyz'[i]} at its largest magnitude {peak[i]:.0f} m/s^2 "
                    f"({int(stuck.sum())} readings)",
                    docs.get("clipping", DOCS["clipping"]),
                    cuts=True,
                )
            )
    return out


def check_imu_mismatch(tables: LogTables, imu: ImuColumns) -> list[TriageFinding]:
    """Two IMUs that disagree: 1 s means compared (vibration and timing jitter average out)."""
    by = imu.series
    out = []
    for kind, limit, unit, scale in (
        (Kind.ACCEL, ACCEL_MISMATCH, "m/s^2", 1.0),
        (Kind.GYRO, GYRO_MISMATCH, "deg/s", float(np.degrees(1.0))),
    ):
        insts = sorted(i for k, i in by if k is kind)
        if len(insts) < 2:
            continue
        a, b = by[(kind, insts[0])], by[(kind, insts[1])]
        if not len(a) or not len(b):
            continue
        ta, va = a.t, a.values()
        tb, vb = b.t, b.values()
        lo, hi = max(ta[0], tb[0]), min(ta[-1], tb[-1])
        if hi - lo < 2.0:
            continue
        edges = np.arange(lo, hi, 1.0)
        ma = _bin_mean(ta, va, edges)
        mb = _bin_mean(tb, vb, edges)
        diff = np.linalg.norm(ma - mb, axis=1)
        tc = edges[:-1]
        for s, e, i, j in runs(diff > limit, tc, join=2.0, min_len=1.0):
            k = i + int(np.nanargmax(diff[i : j + 1]))
            out.append(
                TriageFinding(
                    "imu_mismatch",
                    s,
                    e + 1.0,
                    "warning",
                    f"{kind.value} {insts[0]} and {insts[1]} differ by up to {diff[k] * scale:.2f} {unit} "
                    f"(1 s means; limit {limit * scale:.2f})",
                    DOCS["imu_mismatch"],
                )
            )
    return out


def _bin_mean(t: np.ndarray, v: np.ndarray, edges: np.ndarray) -> np.ndarray:
    idx = np.searchsorted(edges, t, side="right") - 1
    ok = (idx >= 0) & (idx < len(edges) - 1)
    n = np.bincount(idx[ok], minlength=len(edges) - 1).astype(float)
    s = np.column_stack([np.bincount(idx[ok], weights=v[ok, i], minlength=len(edges) - 1) for i in range(v.shape[1])])
    with np.errstate(invalid="ignore", divide="ignore"):
        return s / n[:, None]
