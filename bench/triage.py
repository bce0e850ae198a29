"""Triage time per log: reading the log (measurements and tables) and the checks, against the floor
every Python log tool pays, pymavlink reading the same file message by message (LogAnalyzer and
the MAVLink tools start there), measured in the same run.

    .venv/bin/python bench/triage.py [LOG ...]     (default: the real logs and the fixtures)

The target is under 10 s a log on this machine.
"""

from __future__ import annotations

import sys
import time
from collections import deque
from pathlib import Path

from pymavlink import DFReader, mavutil

from drivers.logs.dataflash import is_dataflash
from drivers.logs.ulog import is_ulog
from groundstation.diagnosis.triage import triage
from groundstation.estimation.logs import load_log

REPO = Path(__file__).resolve().parents[1]
DEFAULT = [
    *sorted((REPO.parent / "shared" / "data" / "real" / "ardupilot_dataflash").glob("*")),
    REPO / "tests" / "fixtures" / "dronekit_flight.tlog",
    REPO / "tests" / "fixtures" / "ardusub_small.tlog",
    REPO / "tests" / "fixtures" / "px4_sitl_events.ulg",
]


def pymavlink_read(p: Path) -> float | None:
    """Seconds for pymavlink to hand over every message (None for a ULog: not its format)."""
    if is_ulog(p):
        return None
    t0 = time.perf_counter()
    if is_dataflash(p):
        binary = p.read_bytes()[:2] == b"\xa3\x95"
        r = DFReader.DFReader_binary(str(p)) if binary else DFReader.DFReader_text(str(p))
    else:
        r = mavutil.mavlink_connection(str(p))
    deque(iter(r.recv_msg, None), maxlen=0)  # every message, none kept
    return time.perf_counter() - t0


def main(paths: list[Path]) -> None:
    head = ("read [s]", "checks [s]", "triage [s]", "pymavlink [s]", "ratio")
    print(f"{'log':44s} " + " ".join(f"{h:>{w}s}" for h, w in zip(head, (9, 10, 10, 13, 6))) + "  top finding")
    for p in paths:
        if not p.exists():
            print(f"{p.name:44s} (absent)")
            continue
        t0 = time.perf_counter()
        log = load_log(p)
        t1 = time.perf_counter()
        tr = triage(log.tables, log.measurements)
        t2 = time.perf_counter()
        base = pymavlink_read(p)
        top = f"{tr.findings[0].severity} {tr.findings[0].name}" if tr.findings else "(nothing)"
        ratio = f"{(t2 - t0) / base:6.2f}" if base else "     -"
        print(
            f"{p.name[:44]:44s} {t1 - t0:9.2f} {t2 - t1:10.3f} {t2 - t0:10.2f} "
            f"{base if base is not None else float('nan'):13.2f} {ratio}  {top}"
        )


if __name__ == "__main__":
    main([Path(a) for a in sys.argv[1:]] or DEFAULT)
