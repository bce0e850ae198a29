"""Simulator benchmark: faster-than-real-time recording, per vehicle.

    python bench/sim_speed.py [--seconds 120] [--repeat 3]

Runs ``groundstation sim --fast`` (in process) with every sensor of each
vehicle on, writing the tlog and the truth sidecar, and prints simulated
seconds per wall second. Target: >= 50x real time for the quadcopter.
The baseline of the ratio is real time itself (1.0x), so the machine's noise
shows only in the spread over repeats, printed beside the best.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from sim_bridge.fast import run_fast  # noqa: E402
from sim_bridge.scenario import Scenario  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print(f"{'vehicle':<10}{'frames':>9}{'best x real time':>18}{'worst':>8}   target")
    ok = True
    with tempfile.TemporaryDirectory() as d:
        for vehicle in ("quad", "coax", "heli3dof"):
            runs = [
                run_fast(Scenario(vehicle, seed=1, duration=args.seconds), Path(d) / "b.tlog", Path(d) / "b.csv")
                for _ in range(args.repeat)
            ]
            best = max(r.speedup for r in runs)
            worst = min(r.speedup for r in runs)
            target = ">= 50x" if vehicle == "quad" else "-"
            if vehicle == "quad":
                ok = best >= 50.0
                target += " met" if ok else " NOT met"
            print(f"{vehicle:<10}{runs[0].frames:>9}{best:>17.1f}x{worst:>7.1f}x   {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
