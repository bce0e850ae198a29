"""Motor outputs in flight: one motor working harder than the rest (a weak or damaged motor or
propeller, a centre of gravity off, a twisted arm), and motors at the end of their range (the
controller has no authority left: thrust loss, overweight, a failing motor).

Outputs are PWM [us]: ArduPilot RCOU (``C1``.. or ``Ch1``..) or MOT (ArduCopter 3.1's motor
records), MAVLink SERVO_OUTPUT_RAW, PX4 ``actuator_outputs`` (DShot's values, 0 to 1999, read as
the pulse of the same share of the range: :func:`drivers.logs.frame.px4_output_fraction`). Only
samples with every motor above its idle (in flight) count. Thresholds follow ArduPilot's
LogAnalyzer motor-balance test: a motor's mean 50 us off the others' is worth a look, 75 us is a
fault.
"""

from __future__ import annotations

import numpy as np

from drivers.logs.frame import (
    MOTOR_OUTPUTS,
    mav_type_of_params,
    mav_type_of_text,
    px4_dshot_outputs,
    px4_logs_mav_type,
    px4_motor_columns,
    px4_output_fraction,
)
from drivers.logs.tables import LogTables

from .finding import DOCS, TriageFinding, runs

IMBALANCE_WARN, IMBALANCE_BAD = 50.0, 75.0  # us
SATURATION_FRACTION = 0.02  # of the output range, from its top
SATURATION_WARN = 0.05  # of the flight's samples


def _motor_count(tables: LogTables) -> int:
    """The motors the log's frame has (:mod:`drivers.logs.frame`; a tlog's HEARTBEAT), else four."""
    mav_type = mav_type_of_params(tables.params)
    if mav_type is None and tables.autopilot == "px4":
        mav_type = px4_logs_mav_type(tables)
    hb = tables.get("HEARTBEAT")
    if mav_type is None and hb is not None and (ty := hb.numeric("type")) is not None and len(ty):
        vals, counts = np.unique(ty, return_counts=True)
        mav_type = int(vals[np.argmax(counts)])
    msg = tables.get("MSG")
    if mav_type is None and msg is not None and "Message" in msg:
        mav_type = next((m for text in msg["Message"] if (m := mav_type_of_text(str(text))) is not None), None)
    return MOTOR_OUTPUTS.get(mav_type, 4) if mav_type is not None else 4


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
        if name == "actuator_outputs":  # PX4's motors are where their output functions put them
            columns = (px4_motor_columns(tables.params) or list(range(n)))[:n]
        else:
            columns = list(range(1, n + 1))
        cols = [tb.numeric(pattern.format(i)) for i in columns]
        if all(c is not None for c in cols):
            pwm = np.column_stack(cols)  # type: ignore[arg-type]
            if name == "actuator_outputs" and px4_dshot_outputs(tables.params):
                return tb.t, 1000.0 + 1000.0 * px4_output_fraction(pwm, dshot=True), f"{name} (DShot)"
            return tb.t, pwm, name
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
