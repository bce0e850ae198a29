"""A diagnosis composed from its parts: a catalogue of two candidates, and the search that scores
them through the filter's gains and claims one on the catalogue's terms. The flight is a short
simulated one.

    python examples/07_a_diagnosis_from_its_parts.py [--seconds 60]   (60 s at least: the high
    flight's climb, sine and descent take a minute)

``groundstation diagnose`` puts the same parts together, with the whole catalogue, around
``groundstation.diagnosis.engine.diagnose``. Here each part is named:

* ``models.setup``: the log prepared for the altitude model, with the declared effect in it;
* the catalogue: two of the altitude model's candidates, the rotor wash on the baro
  (``baro_thrust``) and a baro drifting in time (``baro_bias_drift``);
* ``search.Search.begin``: the model run on the log with the log's own noise (the error before);
* ``Search.run``: the candidates ranked through the base run's gains (``trace.rank``). The best is
  added if it is strong evidence (Delta BIC < -10), at least 3 sigma, and holds on held-out
  stretches (``holdout.check``). Then again, until the residuals pass or nothing more is claimed.

The simulated quadcopter's barometer reads the rotor wash (k = 3 m per unit throttle); nobody
tells the diagnosis. The example prints what the search claimed, what it turned away, and the
height error against the simulator's truth before and after.
"""

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path

from drivers.replay import Replay
from groundstation.diagnosis.catalogue.altitude import altitude_catalogue
from groundstation.diagnosis.claims.search import Search
from groundstation.diagnosis.models import setup
from groundstation.estimation.truth import truth_from
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario

#: the catalogue of this example: two of the altitude model's candidates
TWO = ("baro_thrust", "baro_bias_drift")


def two_candidates(kinds: set) -> list:
    """The altitude catalogue cut to :data:`TWO` (each candidate needs the kinds it reads)."""
    return [c for c in altitude_catalogue(kinds) if c.name in TWO]


def main(seconds: float) -> None:
    out = Path(tempfile.mkdtemp(prefix="gs-example-"))
    log = out / "q.tlog"
    run_fast(
        Scenario.from_args("quad", 7, seconds, ["range_tilt"], ["baro_thrust:k=3"], flight="high"), log, out / "q.csv"
    )
    ms = list(Replay(log).iter_measurements())
    truth = truth_from(ms, log, None)
    su = setup(ms, source=str(log), declared=[{"name": "range_tilt"}])
    su = replace(su, spec=replace(su.spec, catalogue=two_candidates))
    search = Search.begin(su, say=lambda line: print(f"  {line}"), workers=1, truth=None)
    search.run()
    for e in search.effects:
        sized = ", ".join(f"{k} = {v:.3g}" for k, v in e.params.items() if isinstance(v, float) and "sigma" not in k)
        print(f"claimed {e.name}: {sized} (Delta BIC {e.evidence['delta_bic']:.0f})")
    for e in search.rejected:
        print(f"turned away {e.name}: {e.evidence.get('reason', 'contradicted by truth')}")
    if truth is not None:
        t0, t1 = search.first.t[0] + 5.0, search.first.t[-1]
        before, after = truth.error(search.first, t0, t1), truth.error(search.base, t0, t1)
        print(f"height error against the truth: {before * 100:.1f} cm before, {after * 100:.1f} cm after")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    if args.seconds < 60.0:
        ap.error("--seconds: the high flight needs 60 s at least")
    main(args.seconds)
