"""Roll and pitch three ways on one simulated quadcopter flight: the complementary filter of the
coaxial-helicopter document (ch. 8), an EKF on the accelerometer's gravity direction, and the
rotor-drag EKF (Leishman et al. 2014).

    python examples/03_attitude_filters.py [--seconds 60]

On a multirotor in flight the accelerometer reads thrust and drag, not gravity: the two gravity
filters are off by the tilt itself, and the drag model reads the tilt through the body velocity
the drag reveals.
"""

import argparse
import csv
import math
import tempfile
from pathlib import Path

import numpy as np

from drivers.replay import Replay
from groundstation.core.frames import accel_attitude
from groundstation.core.measurement import Kind
from groundstation.estimation.attitude_filters import AttitudeEKF, ComplementaryFilter, DragAttitudeEKF
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario


def main(seconds: float) -> None:
    out = Path(tempfile.mkdtemp(prefix="gs-example-"))
    run_fast(Scenario("quad", seed=4, duration=seconds), out / "q.tlog", out / "q.csv")
    rows = list(csv.DictReader(open(out / "q.csv")))
    tt = np.array([float(r["t"]) for r in rows])
    truth = {k: np.array([float(r[k]) for r in rows]) for k in ("roll", "pitch")}
    filters = {
        "complementary (ch. 8)": ComplementaryFilter(w_c=1.0),
        "gravity EKF": AttitudeEKF(),
        "rotor-drag EKF": DragAttitudeEKF(),
    }
    err: dict[str, list] = {name: [] for name in [*filters, "accelerometer alone"]}
    for m in Replay(out / "q.tlog").iter_measurements():
        for f in filters.values():
            f.handle(m)
        if m.kind is Kind.ACCEL and 6.0 < m.t < seconds - 10.0:
            true = np.array([np.interp(m.t, tt, truth["roll"]), np.interp(m.t, tt, truth["pitch"])])
            for name, f in filters.items():
                if f.x is not None:
                    err[name].append(f.x - true)
            err["accelerometer alone"].append(np.array(accel_attitude(m.value)) - true)
    print(f"roll and pitch RMSE against truth, {seconds:.0f} s flight:")
    for name, e in err.items():
        print(f"  {name:<22} {math.degrees(float(np.sqrt(np.mean(np.square(e))))):6.2f} deg")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    main(ap.parse_args().seconds)
