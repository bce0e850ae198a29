"""Peak memory of ``diagnose`` on a long simulated flight with a 1 kHz IMU, as a multiple of the
log's size (the target: under 3x for a 1-hour log; MAVExplorer needs about 20x).

Each run is a fresh process. Its memory is sampled every 0.1 s from ``/proc``: the command's own
resident set (RSS), and the proportional set size (PSS) summed over it and the trial processes it
forks, which counts each page shared with the parent once, so that a child's own copies count and
the pages it merely inherits do not. Both with one process (``--jobs 1``) and with one per core.

    python bench/memory.py                 # a 60-minute flight (written first: several minutes)
    python bench/memory.py --minutes 10
    python bench/memory.py --log FLIGHT.tlog
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnosis_speed import simulated  # noqa: E402

from groundstation.core.cores import available_cores  # noqa: E402


def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants."""
    out = [pid]
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/children") as f:
                for child in f.read().split():
                    out += _tree(int(child))
    except OSError:  # ended meanwhile: those found so far
        return out
    return out


def _kb(pid: int, file: str, key: str) -> int:
    """``key``'s value [kB] in the process's ``/proc`` file; 0 once the process has ended."""
    try:
        with open(f"/proc/{pid}/{file}") as f:
            return next((int(line.split()[1]) for line in f if line.startswith(key)), 0)
    except OSError:
        return 0


def measured(cmd: list[str]) -> tuple[float, float, float]:
    """(wall seconds, peak RSS of the command's process [MB], peak PSS of it and its children [MB])."""
    p = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    peak_pss = 0
    done = threading.Event()

    def sample() -> None:
        nonlocal peak_pss
        while not done.is_set():
            peak_pss = max(peak_pss, sum(_kb(q, "smaps_rollup", "Pss:") for q in _tree(p.pid)))
            done.wait(0.1)

    t0 = time.perf_counter()
    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    assert p.stderr is not None
    err = p.stderr.read()
    _, status, usage = os.wait4(p.pid, 0)  # the kernel's own high-water mark of the process's RSS
    wall = time.perf_counter() - t0
    done.set()
    sampler.join()
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        raise RuntimeError(f"diagnose failed: {err.strip().splitlines()[-1:]}")
    return wall, usage.ru_maxrss / 1024.0, peak_pss / 1024.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=60.0, help="the simulated flight's length (default 60)")
    ap.add_argument("--log", type=Path, help="a log of your own instead of a simulated flight")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        if args.log is not None:
            log = args.log.resolve()
        else:
            print(f"writing a {args.minutes:g}-minute simulated flight (1 kHz IMU) ...", flush=True)
            log = simulated(folder, "sim_long", args.minutes)
        size = log.stat().st_size / 1e6
        print(f"\n{log.name}: {size:.0f} MB\n")
        print("| jobs | wall [s] | peak RSS [MB] | x log | peak PSS, with its children [MB] | x log |")
        print("|---|---|---|---|---|---|")
        for jobs in dict.fromkeys((1, available_cores())):
            out = folder / f"out{jobs}"
            # the sidecar truth (NAME.csv) is read as the command line reads it
            cmd = [sys.executable, "-m", "groundstation", "diagnose", str(log), "--out", str(out), "--jobs", str(jobs)]
            wall, rss, pss = measured(cmd)
            print(
                f"| {jobs} | {wall:.0f} | {rss:.0f} | {rss / size:.1f}× | {pss:.0f} | {pss / size:.1f}× |", flush=True
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
