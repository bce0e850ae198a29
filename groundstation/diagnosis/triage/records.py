"""The log as a record of the autopilot's own health: values that are not numbers, data written
twice, a main loop running late, a log with no flight in it.

LogAnalyzer's checks (ArduPilot ``Tools/LogAnalyzer/tests``) and their thresholds: ``TestNaN`` (any
NaN in a record), ``TestDupeLogData`` (20 attitude samples in a row found again elsewhere: the
logger wrote a block twice), ``TestPerformance`` (the share of slow loops, PM.NLon / PM.NLoop,
above 6 % warns; above 10 %, or more than 6 records above 6 %, fails), ``TestEmpty`` (a log with no
flight). NaN is checked in DataFlash logs only: PX4 and MAVLink use NaN for "no value".
"""

from __future__ import annotations

import numpy as np

from drivers.logs.tables import LogTables

from .events import flights
from .finding import DOCS, TriageFinding

DUPE_RUN = 20  # samples in a row that must match (TestDupeLogData)
DUPE_PROBES = 10
SLOW_WARN, SLOW_FAIL, SLOW_RECORDS = 6.0, 10.0, 6  # [%], [%], records (TestPerformance)


def check_records(tables: LogTables, t0: float, t_end: float) -> list[TriageFinding]:
    return [*_nan(tables, t0), *_duplicates(tables), *_slow_loops(tables), *_no_flight(tables, t0, t_end)]


def _nan(tables: LogTables, t0: float) -> list[TriageFinding]:
    if tables.fmt != "dataflash":
        return []
    where: list[str] = []
    first = np.inf
    for name, tb in sorted(tables.tables.items()):
        for col, v in tb.cols.items():
            if v.dtype.kind == "f" and len(v) and np.isnan(v).any():
                where.append(f"{name}.{col}")
                first = min(first, float(tb.t[int(np.argmax(np.isnan(v)))]))
    if not where:
        return []
    return [
        TriageFinding(
            "nan_in_records",
            first if np.isfinite(first) else t0,
            first if np.isfinite(first) else t0,
            "warning",
            f"not-a-number values in {len(where)} field(s): {', '.join(where[:6])}{' ...' if len(where) > 6 else ''} "
            "(a computation upstream failed: a NaN calibration parameter or a sensor driver)",
            DOCS["nan_in_records"],
        )
    ]


def _duplicates(tables: LogTables) -> list[TriageFinding]:
    att = tables.get("ATT", "ATTITUDE")
    if att is None or (p := att.numeric("Pitch", "pitch")) is None or len(p) < 12 * DUPE_RUN:
        return []
    p = np.ascontiguousarray(p, dtype=np.float64)
    data, step = p.tobytes(), len(p) // (DUPE_PROBES + 1)
    for k in range(step, len(p) - DUPE_RUN, step)[:DUPE_PROBES]:
        window = p[k : k + DUPE_RUN]
        if np.all(window == window[0]):
            continue  # a still stretch repeats by nature
        needle, at = window.tobytes(), 0
        while (at := data.find(needle, at)) != -1:
            j = at // 8
            if at % 8 == 0 and j != k:
                return [
                    TriageFinding(
                        "duplicate_data",
                        float(att.t[min(k, j)]),
                        float(att.t[max(k, j)]),
                        "error",
                        f"{DUPE_RUN} attitude samples at {att.t[k]:.1f} s written again at {att.t[j]:.1f} s: the "
                        "logger duplicated a block (the log's data there cannot be trusted)",
                        DOCS["duplicate_data"],
                    )
                ]
            at += 1
    return []


def _slow_loops(tables: LogTables) -> list[TriageFinding]:
    pm = tables.get("PM")
    if pm is None or (lon := pm.numeric("NLon")) is None or (loop := pm.numeric("NLoop")) is None:
        return []
    with np.errstate(divide="ignore", invalid="ignore"):
        pct = np.where(loop > 0, 100.0 * lon / loop, 0.0)
    slow = pct > SLOW_WARN
    if not slow.any():
        return []
    k = int(np.argmax(pct))
    bad = pct[k] > SLOW_FAIL or slow.sum() > SLOW_RECORDS
    return [
        TriageFinding(
            "slow_loops",
            float(pm.t[np.argmax(slow)]),
            float(pm.t[len(slow) - 1 - np.argmax(slow[::-1])]),
            "error" if bad else "warning",
            f"the main loop ran late: {int(slow.sum())} PM record(s) above {SLOW_WARN:g} % slow loops, worst "
            f"{pct[k]:.1f} % at {pm.t[k]:.1f} s (an overloaded CPU: logging rate, scripts, a slow SD card)",
            DOCS["slow_loops"],
        )
    ]


def _no_flight(tables: LogTables, t0: float, t_end: float) -> list[TriageFinding]:
    """Armed never, where the log states the arming state all along (ArduPilot's ARM records,
    HEARTBEAT, PX4's vehicle_status; EV's arming events are not enough: a log can begin armed)."""
    says = any(n in tables for n in ("ARM", "HEARTBEAT", "vehicle_status"))
    if not says or flights(tables, t_end):
        return []
    return [
        TriageFinding(
            "no_flight",
            t0,
            t_end,
            "info",
            "the vehicle never armed in this log: nothing flew (a bench or a boot log)",
            DOCS["no_flight"],
        )
    ]
