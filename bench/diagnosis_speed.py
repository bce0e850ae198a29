"""``diagnose`` through the base filter's gains against a filter run per candidate, on the same logs in
the same run: time, peak memory, the ratio, the multiple of real time, and whether the findings
are the same.

    python bench/diagnosis_speed.py [--jobs N] [--only NAME ...] [--minutes 10]
    python bench/diagnosis.py --speed

The baseline is ``diagnose --jobs 1`` with GROUNDSTATION_TRACE=runs: every candidate scored by
filter runs of its own, every value of a delay's grid and every refinement run, one after another
(``groundstation/diagnosis/scoring/trials.py``), as the diagnosis ran before the two-stage filter
(``groundstation/diagnosis/runs/signature.py``). Then the default path on one core and on every core.
Each run is the command line in a fresh process, as a user runs it (reading the log included),
its peak memory that process's. The findings compared (:func:`same_findings`): the effects added,
in order, with their parameters (within 5 % or half a standard error), and the candidates turned
away. Logs: a 60 s simulated quadcopter flight with a late range sensor and rotor wash on the
baro, and a 10-minute one with a 1 kHz IMU, baro, range and GPS (both written here); a foreign
flight (``../shared/data/foreign``), a Crazyflie log and a 23-minute ArduPilot tlog
(``../shared/data/real``), and the 10-minute flight written as DataFlash and as ULog, and two foreign flights as
DataFlash and ULog (``../shared/data/foreign2``); one that is not there is listed as skipped.

Beside the baseline, the plain read of each file (pymavlink's ``recv_match`` loop, pyulog's
``ULog``) in a fresh process: what reading the log alone costs a user's script, and a second of
flight's diagnosis against the 10-minute tlog's (its DataFlash twin must find the same).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from groundstation.core.cores import available_cores  # noqa: E402

DATA = Path(os.environ.get("GROUNDSTATION_DATA") or ROOT.parent / "shared" / "data")

#: (name, the log: a str names one written here)
LOGS: list[tuple[str, Path | str]] = [
    ("sim quad 60 s", "sim60"),
    ("sim quad 10 min, 1 kHz IMU", "sim600"),
    ("the same flight as DataFlash .bin", "sim600bin"),
    ("the same flight as ULog .ulg", "sim600ulg"),
    ("foreign baro_thermal_s1", DATA / "foreign" / "baro_thermal_s1.tlog"),
    ("crazyflie 0425-traj4", DATA / "real" / "crazyflie_util" / "0425-traj4"),
    ("dronekit tlog 23 min", DATA / "real" / "mavlink_tlog" / "dronekit_flight_replay_flight.tlog"),
    ("foreign2 clean_s1.bin", DATA / "foreign2" / "clean_s1.bin"),
    ("foreign2 clean_s2.ulg", DATA / "foreign2" / "clean_s2.ulg"),
]


def simulated(folder: Path, which: str, minutes: float) -> Path:
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    log = folder / (f"{which[:-3]}.{which[-3:]}" if which.endswith(("bin", "ulg")) else f"{which}.tlog")
    if which == "sim60":
        sc = Scenario.from_args(
            "quad", 7, 60.0, ["range_tilt"], ["sensor_delay:sensor=range,seconds=0.06", "baro_thrust:k=2.5"]
        )
    else:
        spec = folder / "long.json"
        spec.write_text(
            json.dumps(
                {
                    "vehicle": "quad",
                    "seed": 3,
                    "duration": minutes * 60.0,
                    "sensors": {"rates": {"imu": 1000, "baro": 50, "range": 20}},
                }
            )
        )
        sc = Scenario.load(spec)
    run_fast(sc, log, log.with_suffix(".csv"))
    return log


#: the plain third-party read of a log, as a user's script does it: pymavlink's ``recv_match`` loop
#: over a tlog or a DataFlash log, pyulog's ``ULog`` over a ULog (a Crazyflie log has none); it
#: prints the records it read
_DECODE = """
import sys
path = sys.argv[1]
if path.endswith(".ulg"):
    from pyulog import ULog
    print(sum(len(d.data["timestamp"]) for d in ULog(path).data_list))
else:
    from pymavlink import mavutil
    conn = mavutil.mavlink_connection(path)
    n = 0
    while conn.recv_match() is not None:
        n += 1
    print(n)
"""


def bare_decode(log: Path) -> float | None:
    """Wall seconds of the plain read of ``log`` in a fresh process (imports included, as in
    ``diagnose``'s), or None where there is no such reader."""
    if log.is_dir() or log.suffix.lower() not in (".tlog", ".bin", ".log", ".ulg"):
        return None
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", _DECODE, str(log)], check=True, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if int(r.stdout.split()[-1]) == 0:
        raise RuntimeError(f"{log}: the plain read read nothing")  # its time would mean nothing
    return seconds


#: runs the command line and reports its peak resident memory (this wrapper's only child)
_MEASURED = (
    "import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); sys.exit(r.returncode)"
)


def diagnose(log: Path, out: Path, jobs: int, by_runs: bool = False) -> tuple[float, float, dict]:
    """(wall seconds, peak memory [MB], report.json) of ``diagnose`` in a fresh process."""
    env = {**os.environ, "GROUNDSTATION_TRACE": "runs" if by_runs else "gains"}
    cmd = [sys.executable, "-m", "groundstation", "diagnose", str(log), "--out", str(out), "--jobs", str(jobs)]
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", _MEASURED, *cmd], capture_output=True, text=True, cwd=ROOT, env=env)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"{log}: diagnose failed: {r.stderr.strip().splitlines()[-2:]}")
    peak_mb = float(r.stderr.strip().splitlines()[-1]) / 1024.0
    return wall, peak_mb, json.loads((out / "report.json").read_text())


def _close(a, b, sigma) -> bool:
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    if not (isinstance(a, (int, float)) and isinstance(b, (int, float))):
        return a == b
    tol = max(0.05 * max(abs(a), abs(b)), 0.5 * sigma if sigma and math.isfinite(sigma) else 0.0, 1e-4)
    return abs(a - b) <= tol


def same_findings(a: dict, b: dict) -> tuple[bool, str]:
    """Whether two report.json say the same: the effects added in the same order with the same
    parameters (each within 5 % or half its standard error), and the same candidates turned away
    (at their hold-out, or before it by a screen whose bound could not be claimed: said so). The
    second item says what differs."""
    ea, eb = a.get("effects", []), b.get("effects", [])
    if [e["name"] for e in ea] != [e["name"] for e in eb]:
        return False, f"effects {[e['name'] for e in ea]} vs {[e['name'] for e in eb]}"
    for x, y in zip(ea, eb):
        for k, v in x["params"].items():
            if k.startswith("sigma_") or k not in y["params"]:
                continue
            sigma = x["params"].get(f"sigma_{k}")
            if not _close(v, y["params"][k], sigma):
                return False, f"{x['name']} {k}: {v} vs {y['params'][k]}"
    ra = {e["name"] for e in a.get("rejected", [])}
    rb = {e["name"] for e in b.get("rejected", [])}
    if ra != rb:
        # turned away by both, one at its hold-out, the other before it (at its screen, its bound not
        # claimable): the same findings, said
        ranked_b = {name.split("(")[0] for ranking in b.get("ranking", []) for name, _ in ranking}
        ranked_a = {name.split("(")[0] for ranking in a.get("ranking", []) for name, _ in ranking}
        if ra - rb <= ranked_b and rb - ra <= ranked_a:
            only = sorted((ra - rb) | (rb - ra))
            return True, f"same (turned away before its hold-out: {', '.join(only)})"
        return False, f"rejected {sorted(ra)} vs {sorted(rb)}"
    return True, "same"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=available_cores(), help="the processes of the new path")
    ap.add_argument("--only", nargs="*", help="these logs only (names as printed)")
    ap.add_argument("--minutes", type=float, default=10.0, help="the long simulated flight's length")
    ap.add_argument("--no-baseline", action="store_true", help="skip the run per candidate (the slowest)")
    args = ap.parse_args()
    rows = []
    #: the long simulated tlog's seconds of diagnosis a second of flight, and its report: the
    #: reference of the per-second column, and of the same flight written as DataFlash
    reference: dict = {}
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        for name, path in LOGS:
            if args.only and name not in args.only:
                continue
            log = simulated(folder, path, args.minutes) if isinstance(path, str) else path
            if not log.exists():
                rows.append(f"| {name} | skipped: {log} is not there |" + " |" * 11)
                continue
            size = sum(p.stat().st_size for p in ([log] if log.is_file() else log.rglob("*") if log.is_dir() else []))
            decode = bare_decode(log)
            t1, m1, j1 = diagnose(log, folder / f"{len(rows)}-1", 1)
            tn, mn, jn = diagnose(log, folder / f"{len(rows)}-n", args.jobs)
            seconds = sum(s["t_end"] - s["t_start"] for s in j1.get("segments_used") or [])  # what was fitted
            checks = [same_findings(j1, jn)]
            if args.no_baseline:
                t0 = m0 = math.nan
            else:
                t0, m0, j0 = diagnose(log, folder / f"{len(rows)}-0", 1, by_runs=True)
                checks.append(same_findings(j0, j1))
            if path == "sim600":
                reference.update(cost=tn / seconds, report=j1)
            if path in ("sim600bin", "sim600ulg") and reference:
                same, why = same_findings(reference["report"], j1)
                checks.append((same, f"against the tlog: {why}"))
            wrong = [why for same, why in checks if not same]
            verdict = "same" if not wrong else f"**differ**: {wrong[0]}"
            per_s = tn / seconds if seconds else math.nan
            rel = f"{per_s / reference['cost']:.2f}" if reference and seconds else "–"
            rows.append(
                f"| {name} | {seconds:.0f} | {size / 1e6:.1f} | "
                + (f"{decode:.1f}" if decode else "–")
                + f" | {t0:.1f} | {t1:.1f} ({seconds / t1:.1f}x) | {tn:.1f} ({seconds / tn:.1f}x) | "
                + f"{t0 / t1:.1f} | {t0 / tn:.1f} | "
                + (f"**{tn / decode:.2f}**" if decode else "–")
                + f" | {60 * per_s:.1f} | {rel} | {m1:.0f} / {mn:.0f} | {verdict} |"
            )
            print(rows[-1], flush=True)
    print(
        f"\ndiagnose through the gains on 1 and {args.jobs} processes, against a run per candidate on one"
        f" (the baseline) and against the plain read of the same file, on {available_cores()} cores"
    )
    print(
        "| log | fitted [s] | log [MB] | plain read [s] | baseline [s] | --jobs 1 [s] (x real time) | "
        f"--jobs {args.jobs} [s] | baseline ratio, 1 | baseline ratio, {args.jobs} | "
        f"--jobs {args.jobs} / plain read | s a flight minute | per second / the 10-minute tlog's | "
        "peak memory, 1 / new [MB] | findings |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
