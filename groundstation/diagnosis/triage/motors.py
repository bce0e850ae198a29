"""Motor outputs in flight: one motor working harder than the rest (a weak or damaged motor or
propeller, a centre of gravity off, a twisted arm), and motors at the end of their range (the
controller has no authority left: thrust loss, overweight, a failing motor).

Outputs are PWM [us]: ArduPilot RCOU (``C1``.. or ``Ch1``..) or MOT (ArduCopter 3.1's motor
records), MAVLink SERVO_OUTPUT_RAW, PX4 ``actuator_outputs``. Only samples with every motor above
its idle (in flight) count. Thresholds follow ArduPilot's LogAnalyzer motor-balance test: a
motor's mean 50 us off the others' is worth a look, 75 us is a fault.
"""

from __future__ import annotations

import numpy as np

from drivers.logs.tables import LogTables

from .finding import DOCS, TriageFinding, runs

IMBALANCE_WARN, IMBALANCE_BAD = 50.0, 75.0  # us
SATURATION_FRACTION = 0.02  # of the output range, from its top
SATURATION_WARN = 0.05  # of the flight's samples

#: MAV_TYPE -> motors (quad, hexa, octo, tri, coaxial, helicopter)
MOTORS_OF_TYPE = {2: 4, 13: 6, 14: 8, 15: 3, 3: 2, 4: 1}
#: ArduCopter FRAME_CLASS -> motors (1 quad, 2 hexa, 3 octa, 4 octaquad, 5 Y6, 7 tri)
MOTORS_OF_FRAME_CLASS = {1: 4, 2: 6, 3: 8, 4: 8, 5: 6, 7: 3}


def _motor_count(tables: LogTables) -> int:
    fc = tables.params.get("FRAME_CLASS")
    if fc is not None and int(fc) in MOTORS_OF_FRAME_CLASS:
        return MOTORS_OF_FRAME_CLASS[int(fc)]
    hb = tables.get("HEARTBEAT")
    if hb is not None and (ty := hb.numeric("type")) is not None and len(ty):
        vals, counts = np.unique(ty, return_counts=True)
        return MOTORS_OF_TYPE.get(int(vals[np.argmax(counts)]), 4)
    msg = tables.get("MSG")
    if msg is not None and "Message" in msg:
        for text in msg["Message"]:
            for word, n in (("HEXA", 6), ("OCTA", 8), ("Y6", 6), ("TRI", 3), ("QUAD", 4)):
                if f"Frame: {word}" in str(text).upper().replace("FRAME: ", "Frame: "):
                    return n
    return 4


def _outputs(tables: LogTables, n: int) -> tuple[np.ndarray, np.ndarray, str] | None:
    """(t, PWM [samples x motors], source)."""
    for name, pattern in (
        ("RCOU", "C{}"),
        ("RCOU", "Ch{}"),
        ("MOT", "Mot{}"),
        ("SERVO_OUTPUT_RAW", "servo{}_raw"),
        ("actuator_outputs", "output[{}]"),
    ):
        tb = tables.get(name)
        if tb is None:
            continue
        base = 0 if name == "actuator_outputs" else 1
        cols = [tb.numeric(pattern.format(base + i)) for i in range(n)]
        if all(c is not None for c in cols):
            return tb.t, np.column_stack(cols), name  # type: ignore[arg-type]
    return None


def _range(tables: LogTables, pwm: np.ndarray) -> tuple[float, float]:
    p = tables.params
    lo = p.get("MOT_PWM_MIN") or p.get("RC3_MIN") or p.get("PWM_MAIN_MIN1") or 1000.0
    hi = p.get("MOT_PWM_MAX") or p.get("RC3_MAX") or p.get("PWM_MAIN_MAX1") or 2000.0
    if not 800 <= lo < hi <= 2200:
        lo, hi = 1000.0, 2000.0
    return float(lo), float(hi)


def check_motors(tables: LogTables, until: float = np.inf) -> list[TriageFinding]:
    """The motors up to ``until`` [s] (a crash's onset: after it the outputs say nothing of the airframe)."""
    n = _motor_count(tables)
    got = _outputs(tables, n)
    if got is None:
        return []
    t, pwm, src = got
    t, pwm = t[t < until], pwm[t < until]
    lo, hi = _range(tables, pwm)
    idle = lo + 0.1 * (hi - lo)
    flying = np.all((pwm > idle) & (pwm < 2500), axis=1)
    if flying.sum() < 20:
        return []
    fp, ft = pwm[flying], t[flying]
    means = fp.mean(axis=0)
    out: list[TriageFinding] = []
    # each motor against the mean of the others
    dev = np.array([means[k] - np.delete(means, k).mean() for k in range(n)])
    k = int(np.argmax(np.abs(dev)))
    if abs(dev[k]) >= IMBALANCE_WARN:
        out.append(
            TriageFinding(
                "motor_imbalance",
                float(ft[0]),
                float(ft[-1]),
                "error" if abs(dev[k]) >= IMBALANCE_BAD else "warning",
                f"{src}: motor {k + 1} {abs(dev[k]):.0f} us {'above' if dev[k] > 0 else 'below'} the others in flight "
                f"(means {', '.join(f'{m:.0f}' for m in means)} us over {flying.sum()} samples)",
                DOCS["motor_imbalance"],
                detail={"motor": k + 1, "offset_us": float(dev[k])},
            )
        )
    top = hi - SATURATION_FRACTION * (hi - lo)
    sat = np.any(fp >= top, axis=1)
    frac = float(sat.mean())
    if frac >= SATURATION_WARN:
        which = np.bincount(np.argmax(fp, axis=1)[sat], minlength=n)
        spans = runs(sat, ft, join=1.0)
        out.append(
            TriageFinding(
                "motor_saturation",
                spans[0][0],
                spans[-1][1],
                "error" if frac >= 4 * SATURATION_WARN else "warning",
                f"{src}: a motor at the top of its range ({top:.0f} us or more) in {frac:.0%} of the flight, "
                f"most often motor {int(np.argmax(which)) + 1}",
                DOCS["motor_saturation"],
            )
        )
    return out
