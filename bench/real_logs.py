"""The closed loop on the measured logs, end to end: what it finds, against what the data README
describes, and how long it takes (as a multiple of the log's own duration: the baseline is real
time, 1x).

    python bench/real_logs.py [--only NAME ...]

Reads ``$GROUNDSTATION_DATA/real`` (default ``../shared/data/real``); a log that is not there is
listed as skipped. The test suite checks each finding's first step on these logs in seconds
(tests/test_crazyflie.py, tests/test_diagnosis.py); this runs the whole loop, which on
``underpowered.log`` adds five effects in turn and takes about 20 minutes here.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from groundstation.diagnosis.engine import diagnose  # noqa: E402
from groundstation.diagnosis.report.report import as_json  # noqa: E402
from groundstation.estimation.logs import load_measurements  # noqa: E402
from groundstation.estimation.truth import truth_from  # noqa: E402

REAL = Path(os.environ.get("GROUNDSTATION_DATA") or ROOT.parent / "shared" / "data") / "real"

#: (name, file, model, vehicle, what the data README (or Vicon) says is there)
CASES = [
    (
        "0422-log00",
        "crazyflie_util/0422-log00",
        "altitude",
        None,
        "baro_thrust (+8.7 m at spin-up), baro_bias_drift 0.09-0.13 m/s; ToF offset -3.3 to -4.0 cm against Vicon",
    ),
    ("0425-traj4", "crazyflie_util/0425-traj4", "altitude", None, "range_tilt (tilts to 18 deg), the baro's drift"),
    ("0425-traj6", "crazyflie_util/0425-traj6", "altitude", None, "the baro's drift; the ToF offset against Vicon"),
    (
        "underpowered",
        "ardupilot_dataflash/ardupilot_loganalyzer_underpowered.log",
        "quad_thrust",
        "apm2_sonar",
        "thrust loss as the pack sags (n ~ 1.7), baro climb 0.0125 m/s, the baro's dip at spin-up",
    ),
]


def fmt(effect: dict) -> str:
    p = ", ".join(
        f"{k} = {v:.3g}" for k, v in effect["params"].items() if isinstance(v, float) and not k.startswith("sigma")
    )
    return f"{effect['name']}" + (f" ({p})" if p else "")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", help="run these cases only")
    args = ap.parse_args()
    print(f"{'log':<14}{'model':<13}{'seconds':>9}{'wall':>8}{'x real time':>13}  found | expected")
    for name, rel, model, vehicle, expected in CASES:
        if args.only and name not in args.only:
            continue
        path = REAL / rel
        if not path.exists():
            print(f"{name:<14}skipped: {path} is absent")
            continue
        t0 = time.perf_counter()
        ms, _, implied = load_measurements(path)
        d = diagnose(
            ms, source=str(path), model_name=model, vehicle=vehicle or implied, truth=truth_from(ms, path, None)
        )
        wall = time.perf_counter() - t0
        j = as_json(d)
        seconds = d.before.t[-1] - d.before.t[0] if len(d.before.t) else float("nan")
        found = "; ".join(fmt(e) for e in j["effects"]) or "nothing"
        err = j["before"].get("rmse_vs_truth"), j["after"].get("rmse_vs_truth")
        truth = f"; error vs truth {100 * err[0]:.2f} -> {100 * err[1]:.2f} cm" if None not in err else ""
        print(
            f"{name:<14}{model:<13}{seconds:>9.0f}{wall:>8.0f}{seconds / wall:>13.2f}  {found}{truth} | {expected}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
