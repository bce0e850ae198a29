"""Recursive least squares (coaxial-helicopter document, ch. 7): the barometer calibrated against
the range sensor, ``altitude = a * pressure + b``, on a simulated flight.

    python examples/02_recursive_least_squares.py [--seconds 60]

The standard atmosphere's slope at the simulated field's 120 m is -1 / (rho g) = -0.0842 m/Pa.
Least squares with a noisy regressor flattens it by var(p) / (var(p) + sigma_p^2) (regression
dilution, which the document does not mention): the expected value is printed beside the fit.
"""

import argparse
import tempfile
from pathlib import Path

import numpy as np

from drivers.replay import Replay
from groundstation.core.measurement import Kind
from groundstation.estimation.rls import BaroRangeCalibration
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario

SIGMA_P = 4.0  # the simulated barometer's noise [Pa]


def main(seconds: float) -> None:
    out = Path(tempfile.mkdtemp(prefix="gs-example-"))
    run_fast(Scenario("quad", seed=5, duration=seconds), out / "q.tlog")
    cal = BaroRangeCalibration()
    pressures = []
    for m in Replay(out / "q.tlog").iter_measurements():
        cal.handle(m)
        if m.kind is Kind.BARO_PRESSURE:
            pressures.append(float(m.value[0]))
    var_p = float(np.var(pressures))
    print(f"{cal.pairs} baro-range pairs")
    print(f"fitted slope a = {cal.a:.4f} m/Pa, offset b = {cal.b:.3f} m at {cal.p_ref:.0f} Pa")
    print(
        f"the atmosphere's slope -0.0842 m/Pa, diluted by the pressure's noise: "
        f"{-0.0842 * var_p / (var_p + SIGMA_P**2):.4f} m/Pa"
    )


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    main(ap.parse_args().seconds)
