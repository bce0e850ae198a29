"""Triage: what the log says happened, before any model is fitted to it.

A flight that crashed, flipped, vibrated, lost its GPS or fell back to a failsafe is not a flight
the physical model describes; fitting effects to it explains a mechanical failure as sensor
error. :func:`triage` reads the log's own records (:class:`drivers.logs.tables.LogTables`) and
its measurements, and states what happened, worst first: crash and flip, failsafes and the
autopilot's errors, GPS, logging gaps, vibration and clipping, IMU mismatch, motors, the
autopilot's own EKF, the battery, configuration risks. :func:`usable` then cuts the stretches
where the model does not hold out of the fit, and lists what it cut.

Each check is a module: :mod:`.events` (ERR, EV, MODE, MSG/STATUSTEXT, PX4 status),
:mod:`.flight` (attitude, gaps, battery, GPS fix), :mod:`.sensors` (vibration, clipping, IMU
mismatch), :mod:`.motors`, :mod:`.ekf`, :mod:`.config`, :mod:`.power` (a log that ends in the air,
the board's supply), :mod:`.records` (NaN, duplicated blocks, slow loops, no flight),
:mod:`.handling` (lean angle, thrust margin, autotune), :mod:`.navigation` (GPS quality, compass,
baro glitch). docs/triage.md maps each of ArduPilot's LogAnalyzer tests to these.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drivers.logs.tables import LogTables
from groundstation.core.imu import IMU_KINDS, ImuColumns
from groundstation.core.measurement import Measurement
from groundstation.core.readings import Readings

from .config import check_config
from .ekf import check_ekf
from .events import check_events
from .finding import SEVERITIES, TriageFinding
from .flight import check_attitude, check_battery, check_gaps, check_gps
from .handling import check_handling
from .motors import check_motors
from .navigation import check_navigation
from .power import check_power
from .records import check_records
from .sensors import check_imu_mismatch, check_vibration


@dataclass
class Triage:
    findings: list[TriageFinding]  # worst first
    clock: str  # "vehicle" or "recording" (see drivers.logs.tables)
    span: tuple[float, float]  # the log's first and last time on that clock [s]
    seconds: float  # how long the triage took
    origin: float = 0.0  # recording clock: its zero as a receive time [s, UNIX]
    records: int = 0  # the log's records and measurements the checks read

    @property
    def cut(self) -> list[TriageFinding]:
        return [f for f in self.findings if f.cuts]

    def as_json(self) -> list[dict]:
        return [f.as_json() for f in self.findings]

    def summary(self, limit: int = 12) -> str:
        """Every finding, worst first: the repeats of one kind folded into its worst instance with
        their count and span (80 imu_mismatch lines on one log were one story), the info-level ones
        last, a line per kind. With ``limit`` groups shown, the rest are counted and named."""
        lines, groups = [], _folded([f for f in self.findings if f.severity != "info"])
        for worst, same in groups[:limit]:
            line = worst.line()
            if len(same) > 1:
                a, b = min(f.t_start for f in same), max(f.t_end for f in same)
                line += f"  (and {len(same) - 1} more like it, {a:.1f}-{b:.1f} s)"
            lines.append(line)
        if len(groups) > limit:
            rest = groups[limit:]
            names = ", ".join(dict.fromkeys(w.name for w, _ in rest))
            lines.append(f"... and {sum(len(s) for _, s in rest)} more findings ({names}): report.json")
        info: dict[str, list[TriageFinding]] = {}
        for f in self.findings:
            if f.severity == "info":
                info.setdefault(f.name, []).append(f)
        for name, same in info.items():
            first = same[0]
            more = f" (x{len(same)}, {first.t_start:.1f}-{same[-1].t_end:.1f} s)" if len(same) > 1 else ""
            lines.append(f"{'INFO':8s} {name:16s} {first.t_start:>14.1f} s  {first.evidence}{more}")
        clock = "seconds since the recording began" if self.clock == "recording" else "seconds of the vehicle's clock"
        head = f"triage ({len(self.findings)} findings, {self.seconds:.1f} s; times in {clock}):"
        empty = "nothing wrong found in the log's own records" if self.records else "the log has no records to check"
        return "\n".join([head] + (lines or [empty]))


def _folded(findings: list[TriageFinding]) -> list[tuple[TriageFinding, list[TriageFinding]]]:
    """Findings (worst first) grouped by severity and kind: each group's first is its worst."""
    groups: dict[tuple[str, str], list[TriageFinding]] = {}
    for f in findings:
        groups.setdefault((f.severity, f.name), []).append(f)
    return [(same[0], same) for same in groups.values()]


def triage(tables: LogTables, ms: Sequence[Measurement], imu: ImuColumns | None = None) -> Triage:
    """The log's findings, worst first; ``imu``: its raw IMU as columns (else read from ``ms``)."""
    start = time.monotonic()
    counted = len(imu) if imu is not None else 0  # (in ``ms`` they are counted with it)
    if imu is None:
        _, imu = ImuColumns.split(m for m in ms if m.kind in IMU_KINDS)
    t0, t1 = tables.span
    if ms and tables.clock == "vehicle":
        t0, t1 = min(t0, ms[0].t) if tables.tables else ms[0].t, max(t1, ms[-1].t) if tables.tables else ms[-1].t
    found: list[TriageFinding] = []
    found += check_events(tables, t1)
    if tables.clock == "recording":  # the raw IMU on the tables' clock: its receive times
        imu = imu.on_receive_clock(tables.origin)
    found += check_attitude(tables, t1, imu)
    crashed = min((f.t_start for f in found if f.name in ("crash", "flip", "estimator_divergence")), default=np.inf)
    found += check_gaps(tables)
    found += check_battery(tables, t1)
    found += check_gps(tables)
    found += check_vibration(tables, imu)
    found += check_imu_mismatch(tables, imu)
    found += check_motors(tables, until=crashed)
    found += check_ekf(tables)
    found += check_config(tables, t0)
    found += check_power(tables, t1, crashed)
    found += check_records(tables, t0, t1)
    found += check_handling(tables, until=crashed)
    found += check_navigation(tables, t1)
    found.sort(key=lambda f: f.rank)
    records = len(ms) + counted + sum(len(tb) for tb in tables.tables.values())
    return Triage(found, tables.clock, (t0, t1), time.monotonic() - start, tables.origin, records)


def _time_of(m: Measurement, tr: Triage) -> float:
    return m.t_rx - tr.origin if tr.clock == "recording" else m.t


def _merged_cuts(tr: Triage) -> tuple[list, list[list[float]]]:
    """The stretches the triage cuts, sorted, and merged where they overlap."""
    cuts = sorted(((f.t_start, f.t_end, f) for f in tr.cut), key=lambda c: (c[0], c[1]))
    merged: list[list[float]] = []
    for a, b, _ in cuts:
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    return cuts, merged


def _inside(t: np.ndarray, merged: list[list[float]]) -> np.ndarray:
    starts = np.array([a for a, _ in merged])
    ends = np.array([b for _, b in merged])
    k = np.searchsorted(starts, t, side="right") - 1
    return (k >= 0) & (t <= ends[np.clip(k, 0, None)])


def usable(
    ms: Sequence[Measurement], tr: Triage
) -> tuple[Sequence[Measurement], list[tuple[float, float]], list[dict]]:
    """The measurements outside every stretch the triage cuts, the stretches used [(t0, t1)], and
    what was cut and why ([{name, t_start, t_end, why}]), all on the triage's clock."""
    cuts, merged = _merged_cuts(tr)
    if not merged or not ms:
        return ms, [tr.span] if ms else [], []
    if isinstance(ms, Readings):  # on its columns
        kept: Sequence[Measurement] = ms.where(
            ~_inside(ms.t_rx - tr.origin if tr.clock == "recording" else ms.t, merged)
        )
    else:
        inside = _inside(np.array([_time_of(m, tr) for m in ms]), merged)
        kept = [m for m, cut in zip(ms, inside) if not cut]
    used, lo = [], tr.span[0]
    for a, b in merged:
        if a > lo:
            used.append((lo, a))
        lo = max(lo, b)
    if lo < tr.span[1]:
        used.append((lo, tr.span[1]))
    why = [{"name": f.name, "t_start": round(a, 3), "t_end": round(b, 3), "why": f.evidence} for a, b, f in cuts]
    return kept, [(round(a, 3), round(b, 3)) for a, b in used], why


def usable_imu(imu: ImuColumns, tr: Triage) -> ImuColumns:
    """The raw IMU outside every stretch the triage cuts (:func:`usable`'s, for the columns)."""
    _, merged = _merged_cuts(tr)
    if not merged:
        return imu
    return imu.masked(lambda s: ~_inside(s.t_rx - tr.origin if tr.clock == "recording" else s.t, merged))


__all__ = ["SEVERITIES", "Triage", "TriageFinding", "triage", "usable", "usable_imu"]
