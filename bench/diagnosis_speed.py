"""``diagnose`` with the trials that cannot change a finding left out, on one core and on every core,
against every trial on one, on the same logs in the same run: time, the ratios, the multiple of
real time, and whether the findings are the same.

    python bench/diagnosis_speed.py [--jobs N] [--only NAME ...]
    python bench/diagnosis.py --speed

The baseline is ``diagnose --jobs 1`` with every grid value and every refinement run
(GROUNDSTATION_EXHAUSTIVE_GRID=1: the trials as made before ``trials.scan_grid`` and the
parabola's gate left out the runs that cannot change a finding), one after another, as the
diagnosis ran before it spread them over the cores (``groundstation/diagnosis/trials.py``). Then
the same with the scan and the gate, on one core and on every core. Each run is the command line
in a fresh process, as a user runs it (the reading of the log included). The findings compared:
the effects added with their parameters, the rejected ones with their reasons, and each
iteration's claims (the candidates of its ranking at Delta BIC < -10, with it) in report.json.
Logs: a 60 s simulated quadcopter flight with a late range sensor and rotor wash on the baro
(written here), a foreign flight (``../shared/data/foreign``), a Crazyflie log and a 23-minute
ArduPilot tlog (``../shared/data/real``); one that is not there is listed as skipped.
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


def diagnose(log: Path, out: Path, jobs: int, exhaustive: bool = False) -> tuple[float, dict]:
    env = {**os.environ, "GROUNDSTATION_EXHAUSTIVE_GRID": "1" if exhaustive else "0"}
    t0 = time.perf_counter()
    r = subprocess.run(
        [sys.executable, "-m", "groundstation", "diagnose", str(log), "--out", str(out), "--jobs", str(jobs)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
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
        [[(label, dbic) for label, dbic in r if dbic < -10.0] for r in j.get("ranking") or []],
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
                rows.append(f"| {name} | skipped: {log} is not there | | | | | | |")
                continue
            t0, j0 = diagnose(log, folder / f"{len(rows)}-0", 1, exhaustive=True)
            t1, j1 = diagnose(log, folder / f"{len(rows)}-1", 1)
            tn, jn = diagnose(log, folder / f"{len(rows)}-n", args.jobs)
            seconds = sum(s["t_end"] - s["t_start"] for s in j1.get("segments_used") or [])  # what was fitted
            same = "same" if findings(j0) == findings(j1) == findings(jn) else "**differ**"
            old, one, new = (f"{t:.1f} ({seconds / t:.1f}x)" for t in (t0, t1, tn))
            rows.append(f"| {name} | {seconds:.0f} | {old} | {one} | {new} | {t0 / t1:.2f} | {t0 / tn:.2f} | {same} |")
            print(rows[-1], flush=True)
    print(
        f"\ndiagnose with the scan and the gate, on 1 and {args.jobs} processes, against every grid run on one"
        f" (the baseline), on {available_cores()} cores"
    )
    print(
        "| log | fitted [s] | baseline [s] (x real time) | --jobs 1 [s] | "
        f"--jobs {args.jobs} [s] | ratio, 1 | ratio, {args.jobs} | findings |"
    )
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
