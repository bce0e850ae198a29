"""Bulk loading benchmark: a whole log into numpy arrays per type, against pymavlink's recv_match loop.

    python bench/bulk.py [--messages 200000]

Contenders, on the same file, measured in one run (interleaved, best of 3):
  * baseline: ``mavutil.mavlink_connection(path)`` and ``recv_match()`` until None
    (for a ``.bin`` that is pymavlink's DFReader);
  * ours: :func:`drivers.logs.bulk.load`, every message type as a structured array.
Files: a synthetic 1 kHz-style tlog (``--messages`` frames), the committed real
tlogs, and the real binary DataFlash logs when ``../shared/data/real`` is there.
Target: ours >= 10x the baseline's messages per second on every file.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from pymavlink import mavutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
from ingest import make_stream, write_tlog  # noqa: E402

from drivers.logs.bulk import load  # noqa: E402

REAL = Path(os.environ.get("GROUNDSTATION_DATA") or ROOT.parent / "shared" / "data") / "real"


def recv_match_all(path: Path) -> int:
    conn = mavutil.mavlink_connection(str(path))
    n = 0
    while (m := conn.recv_match()) is not None:
        if m.get_type() not in ("BAD_DATA", "FMT"):
            n += 1
    return n


def timed(fn) -> tuple[float, int]:
    t0 = time.perf_counter()
    n = fn()
    return time.perf_counter() - t0, n


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--messages", type=int, default=200_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        synth = Path(d) / f"synthetic_{args.messages}.tlog"
        write_tlog(make_stream(args.messages), synth)
        files = [synth, ROOT / "tests/fixtures/dronekit_flight.tlog", ROOT / "tests/fixtures/ardusub_small.tlog"]
        files += [
            REAL / "ardupilot_dataflash" / n
            for n in ("erle_pxf_copter_Loiter_RTL.bin", "pyflightcoach_pilot_0004.BIN")
            if (REAL / "ardupilot_dataflash" / n).exists()
        ]
        print(f"{'file':<40}{'messages':>10}{'recv_match msg/s':>18}{'bulk msg/s':>14}{'ratio':>8}  target >= 10x")
        worst = float("inf")
        for f in files:
            best_base = best_bulk = float("inf")
            for _ in range(args.repeat):
                dt, n_base = timed(lambda f=f: recv_match_all(f))
                best_base = min(best_base, dt)
                dt, n_bulk = timed(lambda f=f: load(f).count)
                best_bulk = min(best_bulk, dt)
            ratio = (n_bulk / best_bulk) / (n_base / best_base)
            worst = min(worst, ratio)
            print(
                f"{f.name:<40}{n_bulk:>10,}{n_base / best_base:>18,.0f}{n_bulk / best_bulk:>14,.0f}"
                f"{ratio:>8.1f}  {'met' if ratio >= 10 else 'NOT met'}"
            )
        if not (REAL / "ardupilot_dataflash").exists():
            print(f"(binary DataFlash files skipped: {REAL} is absent)")
        print(f"worst ratio {worst:.1f}x: target {'met' if worst >= 10 else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
