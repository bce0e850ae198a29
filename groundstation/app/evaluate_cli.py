"""``groundstation evaluate LOG`` and ``groundstation noise LOG``: a log run through the estimators
and scored, and the sensors' noise read from its still stretch. Neither draws anything, so they load
no dashboard and no control station (loaded alone: ``main.ALONE``)."""

from __future__ import annotations

import json
import math

import numpy as np

from drivers.replay import Replay
from groundstation.estimation.evaluate import evaluate
from groundstation.estimation.noise import first_arming, stationary_noise
from groundstation.estimation.registry import build_estimator

#: [s] the stationary window ends this long before the arming: an arming's own checks and the motors'
#: spin-up are not at rest
ARMING_MARGIN_S = 0.2


def cmd_evaluate(args) -> int:
    """The estimators on the log: each sensor's error against truth, NIS and whiteness (the truth
    file named, or the one beside the log; ``main`` has checked a named one is there)."""
    print(evaluate(args.file, args.model, vehicle=args.vehicle, truth_csv=args.truth).table())
    return 0


def cmd_noise(args) -> int:
    """Each sensor's measurement covariance R from the stretch ``--start``..``--end`` (by default,
    from the start to just before the first arming: the vehicle stands still)."""
    est = build_estimator(args.model)
    ms = list(Replay(args.file, speed=math.inf).iter_measurements())
    end = args.end
    if end is None:
        # before the vehicle arms it stands still; a log that states no arming: its first 1.9 s
        armed = first_arming(ms)
        end = armed - ARMING_MARGIN_S if armed is not None and armed - ARMING_MARGIN_S > args.start else 1.9
    args.end = end
    result = stationary_noise(ms, est, args.start, end)
    if not result:
        raise ValueError(
            f"{args.file}: no measurements of the {args.model} model between {args.start:g} s and {end:g} s"
        )
    for name, r in result.items():
        R = np.array(r["R"])
        print(
            f"{name} ({r['n']} samples, {args.start:g}-{args.end:g} s): R ="
            + (f"  [{r['note']}]" if "note" in r else "")
        )
        print("  " + np.array2string(R, precision=3, separator=", ", prefix="  "))
    if args.out:
        args.out.write_text(json.dumps(result, indent=2))
        print(f"wrote {args.out} (use with --noise)")
    return 0
