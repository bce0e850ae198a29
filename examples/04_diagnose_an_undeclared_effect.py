"""The closed loop from Python: a flight with an effect nobody declared, diagnosed.

    python examples/04_diagnose_an_undeclared_effect.py [--seconds 60]   (60 s at least: the high
    flight's climb, sine and descent take a minute)

The simulated quadcopter's barometer reads the rotor wash (``baro_thrust``, k = 3 m per unit
throttle) on a high flight, where the baro alone carries the height above the range sensor's
4 m. The diagnosis is told nothing of it: it finds the effect, sizes it, adds it to the model and
reports the height error against the simulator's truth before and after. ``groundstation
diagnose LOG`` does the same from the command line and writes report.html.
"""

import argparse
import tempfile
from pathlib import Path

from drivers.replay import Replay
from groundstation.diagnosis.engine import diagnose
from groundstation.diagnosis.report.conclusion import conclusion
from groundstation.diagnosis.report.report import as_json
from groundstation.estimation.truth import truth_from
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario


def main(seconds: float) -> None:
    out = Path(tempfile.mkdtemp(prefix="gs-example-"))
    log = out / "q.tlog"
    run_fast(
        Scenario.from_args("quad", 7, seconds, ["range_tilt"], ["baro_thrust:k=3"], flight="high"), log, out / "q.csv"
    )
    ms = list(Replay(log).iter_measurements())
    d = diagnose(ms, source=str(log), declared=[{"name": "range_tilt"}], truth=truth_from(ms, log, None))
    j = as_json(d)
    for e in j["effects"]:
        print(
            f"found {e['name']}: "
            + ", ".join(
                f"{k} = {v:.3g}" for k, v in e["params"].items() if isinstance(v, float) and not k.startswith("sigma")
            )
        )
    print(conclusion(d, j))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    if args.seconds < 60.0:
        ap.error("--seconds: the high flight needs 60 s at least")
    main(args.seconds)
