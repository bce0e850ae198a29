"""``diagnose`` on every core against one, on the same logs in the same run: time, the ratio, the
multiple of real time, and whether the findings are the same.

    python bench/diagnosis_speed.py [--jobs N] [--only NAME ...]
    python bench/diagnosis.py --speed

The baseline is ``diagnose --jobs 1``: every candidate's filter runs one after another, as the
diagnosis ran before it spread them over the cores (``groundstation/diagnosis/trials.py``). Each
run is the command line in a fresh process, as a user runs it (the reading of the log included).
The findings compared: the effects added with their parameters, the rejected ones with their
reasons, and each iteration's ranking (report.json). Logs: a 60 s simulated quadcopter flight with
a late range sensor and rotor wash on the baro (written here), a foreign flight
(``../shared/data/foreign``), a Crazyflie log and a 23-minute ArduPilot tlog
(``../shared/data/real``); one that is not there is listed as skipped.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from groundstation.diagnosis.trials import available_cores  # noqa: E402

DATA = Path(os.environ.get("GROUNDSTATION_DATA") or ROOT.parent / "shared" / "data")

#: (name, the log: None for the simulated flight written here)
LOGS = [
    ("sim quad 60 s", None),
    ("foreign baro_thermal_s1", DATA / "foreign" / "baro_thermal_s1.tlog"),
    ("crazyflie 0425-traj4", DATA / "real" / "crazyflie_util" / "0425-traj4"),
    ("dronekit tlog 23 min", DATA / "real" / "mavlink_tlog" / "dronekit_flight_replay_flight.tlog"),
]


def simulated(folder: Path) -> Path:
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    log = folder / "sim.tlog"
    sc = Scenario.from_args(
        "quad", 7, 60.0, ["range_tilt"], ["sensor_delay:sensor=range,seconds=0.06", "baro_thrust:k=2.5"]
    )
    run_fast(sc, log, log.with_suffix(".csv"))
    return log


def diagnose(log: Path, out: Path, jobs: int) -> tuple[float, dict]:
    t0 = time.perf_counter()
    r = subprocess.run(
        [sys.executable, "-m", "groundstation", "diagnose", str(log), "--out", str(out), "--jobs", str(jobs)],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"{log}: diagnose failed: {r.stderr.strip().splitlines()[-1:]}")
    return wall, json.loads((out / "report.json").read_text())


def findings(j: dict) -> tuple:
    """What a diagnosis concluded, without the report's own timings."""
    return (
        [(e["name"], e["params"]) for e in j.get("effects", [])],
        [(e["name"], e.get("evidence", {}).get("reason")) for e in j.get("rejected", [])],
        j.get("ranking"),
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=available_cores(), help="the processes of the new path")
    ap.add_argument("--only", nargs="*", help="these logs only (names as printed)")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        for name, path in LOGS:
            if args.only and name not in args.only:
                continue
            log = simulated(folder) if path is None else path
            if not log.exists():
                rows.append(f"| {name} | skipped: {log} is not there | | | | | |")
                continue
            t1, j1 = diagnose(log, folder / f"{len(rows)}-1", 1)
            tn, jn = diagnose(log, folder / f"{len(rows)}-n", args.jobs)
            seconds = sum(s["t_end"] - s["t_start"] for s in j1.get("segments_used") or [])  # what was fitted
            same = "same" if findings(j1) == findings(jn) else "**differ**"
            one, new = (f"{t:.1f} ({seconds / t:.1f}x)" for t in (t1, tn))
            rows.append(f"| {name} | {seconds:.0f} | {one} | {new} | {t1 / tn:.2f} | {same} |")
            print(rows[-1], flush=True)
    print(f"\ndiagnose --jobs {args.jobs} against --jobs 1 (the baseline), on {available_cores()} cores")
    print("| log | fitted [s] | --jobs 1 [s] (x real time) | new [s] (x real time) | ratio | findings |")
    print("|---|---|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
