"""A simulated flight through the altitude filter, as a replay runs it.

    python examples/01_replay_through_the_estimation_loop.py [--seconds 60]

The simulator writes a tlog and its truth; the replay decodes it through the same MAVLink
receiver a live link uses; the estimation loop runs the registry's ``altitude`` estimator (the
coaxial document's ch. 9 filter) and publishes a snapshot after every update. The height error
against truth is set beside the range sensor's own, and the estimate's sigma is checked against
the truth: an honest one holds it within 2 sigma 95 % of the time, at a NEES of 1.
"""

import argparse
import csv
import tempfile
from pathlib import Path

import numpy as np

from drivers.replay import Replay
from groundstation.core.measurement import Kind
from groundstation.estimation.loop import EstimationLoop
from groundstation.estimation.registry import build_estimator
from groundstation.estimation.truth import Truth
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario


def main(seconds: float) -> None:
    out = Path(tempfile.mkdtemp(prefix="gs-example-"))
    run_fast(Scenario.from_args("quad", 3, seconds, ["range_tilt"], []), out / "q.tlog", out / "q.csv")
    truth = list(csv.DictReader(open(out / "q.csv")))
    t_true = np.array([float(r["t"]) for r in truth])
    h_true = np.array([float(r["h"]) for r in truth])

    estimator = build_estimator("altitude", declared=[{"name": "range_tilt"}])
    loop = EstimationLoop([estimator])
    snapshots = loop.snapshots.subscribe()
    ranges = []
    for m in Replay(out / "q.tlog").iter_measurements():
        loop.push(m)
        if m.kind is Kind.RANGE:
            ranges.append((m.t, float(m.value[0])))
    snaps = snapshots.get_nowait()

    t = np.array([s.t for s in snaps])
    z = np.array([s.x[0] for s in snaps])
    air = np.interp(t, t_true, h_true) > 0.3
    err = z[air] - np.interp(t[air], t_true, h_true)
    r = np.array(ranges)
    r_air = np.interp(r[:, 0], t_true, h_true) > 0.3
    r_err = r[r_air, 1] - np.interp(r[r_air, 0], t_true, h_true)
    last = snaps[-1]
    print(
        f"{len(snaps)} estimates of {', '.join(last.states)}; last: "
        + ", ".join(f"{n} = {v:+.3f} ± {s:.3f}" for n, v, s in zip(last.states, last.x, last.sigma))
    )
    print(
        f"height RMSE in flight: estimate {1000 * np.sqrt(np.mean(err**2)):.1f} mm, "
        f"raw range {1000 * np.sqrt(np.mean(r_err**2)):.1f} mm (the slant under tilt included)"
    )
    sigma = np.array([s.sigma[0] for s in snaps])
    within, nees = Truth(t_true, h_true, "the simulator").consistency(t, z, sigma, t[0], t[-1])
    print(
        f"its sigma: the truth within 2 sigma {within:.0%} of the time (95 % if honest), NEES {nees:.2f} (1 if honest)"
    )
    print(f"the estimator skipped: {estimator.counters.rejected or 'nothing'}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    main(ap.parse_args().seconds)
