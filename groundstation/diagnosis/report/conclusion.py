"""The diagnosis's conclusion in sentences (report.json's ``conclusion``, the report's first
paragraph): what was found and how strongly, what was turned away and why, and the error before
and after; and an effect's parameters as the report writes them (:func:`format_params`)."""

from __future__ import annotations

import math

from groundstation.diagnosis.catalogue.candidate import unit_of
from groundstation.diagnosis.catalogue.thrust_model import LIFTOFF_REACH
from groundstation.diagnosis.claims.search import CLOSE_CALL
from groundstation.diagnosis.engine import Diagnosis
from groundstation.diagnosis.scoring.noise_match import PROCESS_LEVEL


def _colour(e) -> tuple[str, float]:
    """The effect's sensor and its innovations' colour n / n_eff; for an effect on several
    sensors (sensor None, e.g. thrust_voltage), the most coloured of them."""
    colour = e.evidence["innovation_colour"]
    sensor = e.evidence.get("sensor")
    if sensor in colour:
        return sensor, colour[sensor]
    return max(colour.items(), key=lambda kv: kv[1])


def conclusion(d: Diagnosis, j: dict) -> str:
    """The report's conclusion: what was found and how strongly, what was turned away and why, and
    the error before and after, in sentences."""
    return " ".join(
        [
            *_noise_said(d),
            *_effects_said(d),
            *_beside_said(d),
            *_rejected_said(d),
            *_outside_said(d),
            *_errors_said(d, j),
        ]
    )


def _noise_said(d: Diagnosis) -> list[str]:
    differs = [n for n in d.noise if n.differs]
    if not differs:
        return []
    process = any(n.sensor == PROCESS_LEVEL for n in differs)
    return [
        "The log's own noise differs from the model's, and the diagnosis used the log's: "
        + "; ".join(f"{n.sensor} {n.sigma_data:.3g}, the model had {n.sigma_model:.3g}" for n in differs)
        + " (covariance matching on the innovations"
        + ("; the acceleration's, the vertical speed's process noise, by the likelihood" if process else "")
        + "). A mis-set noise level is a finding of its own, not an effect."
    ]


def _effects_said(d: Diagnosis) -> list[str]:
    """The catalogue's effects added, their evidence at the innovations' colour and their close calls;
    or that none was, and the sizes the log could have shown."""
    catalogued = [e for e in d.effects if e.name != "discovered"]
    if not catalogued:
        return _nothing_said(d)
    found = "; ".join(_named(e) for e in catalogued)
    parts = [
        f"The model was missing {len(catalogued)} effect{'s' * (len(catalogued) > 1)}: {found}. "
        f"Each was added with its parameters estimated from this log, and each improved the "
        f"likelihood of the measurements by very strong evidence (Delta BIC < -10), by at least "
        f"3 standard errors, and on stretches of the log it was not fitted on."
    ]
    coloured = [(e, *_colour(e)) for e in catalogued if e.evidence.get("innovation_colour")]
    coloured = [(e, s, f) for e, s, f in coloured if f >= COLOURED]
    if coloured:
        parts.append(
            "That evidence assumes white innovations. Counted at their effective sample size, "
            + "; ".join(
                f"{e.name} scores Delta BIC {e.evidence['delta_bic_effective']:.0f} (with it, "
                f"each {s} innovation is worth 1/{f:.0f} of an independent "
                f"sample)"
                for e, s, f in coloured
            )
            + ". Weigh those findings with care: the colour comes from something the model still lacks."
        )
    for e in catalogued:
        alt = e.evidence.get("alternative")
        if alt:
            p = format_params(alt["name"], {k: v for k, v in alt["params"].items() if k != "sensor"})
            parts.append(
                f"This log barely tells {e.name} from {alt['name']}{f' ({p})' if p else ''}: that one "
                f"would have been claimed too, at Delta BIC {alt['delta_bic']:.1f} against "
                f"{e.evidence['delta_bic']:.1f}, and a difference under {CLOSE_CALL:.0f} is not very "
                f"strong evidence. Read the finding as either; a flight that tells them apart settles it."
            )
    return parts


def _nothing_said(d: Diagnosis) -> list[str]:
    if d.discoveries:
        tail = ", but the innovations follow something outside it (below)."
    elif any(e.evidence.get("implausible") for e in d.rejected):
        # a fit the physics turns away still says the model lacks something: not "complete"
        tail = (
            ", but what fits best is no such effect at its size (below): the model lacks something the "
            "catalogue does not describe."
        )
    else:
        tail = ": as far as these data can tell, the model is complete."
    parts = ["No effect in the catalogue improves the model by strong evidence" + tail]
    if d.detectable:
        parts.append(
            "The smallest sizes they would have shown about half the time: "
            + "; ".join(
                f"{x['name']} " + ", ".join(_size(x["name"], k, v) for k, v in x["size"].items()) for x in d.detectable
            )
            + "."
        )
    return parts


def _beside_said(d: Diagnosis) -> list[str]:
    """What was found beside the model, and the thrust curve the accelerometer reads against the vehicle
    file's and against the effects' sizes."""
    parts = []
    for e in d.beside:
        ev = e.evidence
        parts.append(
            f"Beside the model, which takes the accelerometer as its input and so never predicts thrust, the "
            f"{ev['model']} shows {_named(e)}: the thrust the throttle buys falls with the pack's voltage. Its "
            f"residual thrust went from {ev['thrust_rms_before']:.3g} to {ev['thrust_rms_after']:.3g} m/s^2 "
            f"(Delta BIC {ev['delta_bic']:.0f}, and on each third of the flight when fitted on the other two)."
        )
    a = d.airframe
    if a and not a.get("used", True) and abs(a["alpha"] - a["file_alpha"]) > CURVE_MISMATCH * a["file_alpha"]:
        parts.append(
            f"The vehicle file's thrust curve (alpha = {a['file_alpha']:.3g}, beta = {a['file_beta']:.3g} "
            f"m/s^2) is not this log's: its accelerometer reads alpha = {a['alpha']:.3g} ± "
            f"{a['sigma']['alpha']:.1g}, beta = {a['beta']:.3g} ± {a['sigma']['beta']:.1g}. The effects "
            f"above are sized against the file's; check it (other propellers, motors or battery?) or "
            f"diagnose without --vehicle."
        )
    cross = [
        (e, CURVE_PARAM[e.name])
        for e in d.effects
        if d.airframe and CURVE_PARAM.get(e.name) in e.params and CURVE_PARAM[e.name] in d.airframe
    ]
    if cross and d.airframe:
        airframe = d.airframe
        parts.append(
            "Read on its own from the accelerometer, which the thrust model does not use, the thrust "
            "curve (airframe) gives "
            + "; ".join(
                f"{k} = {airframe[k]:.3g} ± {airframe['sigma'][k]:.1g} for {e.name}'s {e.params[k]:.3g}"
                for e, k in cross
            )
            + "."
        )
    return parts


def _rejected_said(d: Diagnosis) -> list[str]:
    parts = []
    for e in d.rejected:
        ev = e.evidence
        if "reason" in ev:
            parts.append(
                f"{_named(e)} fitted the measurements better (Delta BIC {ev['delta_bic']:.0f}) but is not "
                f"claimed: {ev['reason']}."
            )
            continue
        k, unit = (100.0, "cm") if ev["quantity"].startswith("height") else (math.degrees(1.0), "deg")
        parts.append(
            f"{_named(e)} fitted the measurements better (Delta BIC "
            f"{ev['delta_bic']:.0f}) but was rejected: with it, the error against the {ev['against']} went "
            f"from {ev['error_before'] * k:.2f} to {ev['error_with'] * k:.2f} {unit}, so the better fit "
            f"comes from something the model lacks, not from {e.name}."
        )
    return parts


def _moved_said(moved: dict | None) -> str:
    if not moved:
        return ""
    return (
        f" It moved from {moved['from']:+.3f} to {moved['to']:+.3f} m/s^2 between {moved['t_from']:.0f} s and "
        f"{moved['t_to']:.0f} s ({moved['z']:.0f} standard errors): an accelerometer whose bias changes in "
        "flight, as an IMU's does as it warms, which the model's bias follows only over seconds. The IMU's "
        "temperature calibration (ArduPilot INS_TCAL, PX4 TC_A) takes that out; its offset alone does not."
    )


def _outside_said(d: Diagnosis) -> list[str]:
    """What the model's own states carry, the range's offset against truth, and what lies outside the
    catalogue."""
    parts = [
        f"The model's own state {e.evidence['state']} carries {e.name}: {format_params(e.name, e.params)}."
        + _moved_said(e.evidence.get("moved"))
        for e in d.modelled
    ]
    parts += [
        f"Against the {e.evidence['against']}, the range sensor reads with an offset of "
        f"{e.params['o'] * 100:+.1f} cm, which no sensor of the log could have shown."
        for e in d.against_truth
    ]
    for x in d.discoveries:
        p0, p1 = x.ljung_box_p
        white = f"; without it their Ljung-Box p goes from {p0:.2g} to {p1:.2g}" if p0 < 0.05 and p1 > p0 else ""
        parts.append(
            f"Outside the catalogue, the {x.sensor} innovations follow {x.expression} "
            f"(coefficient {x.coefficient:.3g}, {x.r2:.0%} of their variance on held-out stretches{white}); "
            f"added to the model as a regressor on the {x.sensor}, it held out of sample as a catalogued "
            f"effect must."
        )
    return parts


def _errors_said(d: Diagnosis, j: dict) -> list[str]:
    """The range's skipped echoes, the error before and after against truth and against the sensors
    left out, the sigma's honesty, and the sensors still failing."""
    parts = []
    b, a = j["before"], j["after"]
    rng = a["sensors"].get("range", {})
    if rng.get("skipped_spurious"):
        when = ", ".join(f"{t0:.1f}-{t1:.1f} s" if t1 > t0 else f"{t0:.1f} s" for t0, t1 in rng["skipped_spurious_at"])
        parts.append(
            f"{rng['skipped_spurious']} range readings were skipped as spurious echoes ({when}): with the "
            f"vehicle on the ground they read it more than {LIFTOFF_REACH:.0f} m up, where no lift-off "
            f"reaches between two readings."
        )
    if "rmse_vs_truth" in b and b["rmse_of"].startswith("height"):
        parts.append(
            f"Height error against the {b['truth']}: {b['rmse_vs_truth'] * 100:.2f} cm before, "
            f"{a['rmse_vs_truth'] * 100:.2f} cm after."
        )
    elif "rmse_vs_truth" in b:
        parts.append(
            f"Roll and pitch error against the {b['truth']}: {math.degrees(b['rmse_vs_truth']):.2f} deg "
            f"before, {math.degrees(a['rmse_vs_truth']):.2f} deg after."
        )
    if d.left_out and (d.effects or d.beside):
        parts.append(
            "Each absolute sensor predicted by the others (left out of the filter, before -> after): "
            + "; ".join(lo.line() for lo in d.left_out)
            + "."
        )
    if "nees" in b and "nees" in a:
        parts.append(
            f"The height's sigma held the truth within 2 sigma {b['within_2sigma']:.0%} of the time before and "
            f"{a['within_2sigma']:.0%} after (95 % for an honest sigma; NEES {b['nees']:.2f} and "
            f"{a['nees']:.2f}, 1 for an honest one)."
        )
    still = sorted(
        {f.sensor for f in d.findings_after if not f.passed and f.test in ("NIS mean", "Ljung-Box whiteness")}
    )
    parts.append(
        "After the changes every sensor's innovations pass the NIS and whiteness tests."
        if not still
        else f"Still failing NIS or whiteness: {', '.join(still)}."
    )
    return parts


def _size(name: str, param: str, v: float) -> str:
    u = unit_of(name, param)
    return f"{v:.2g} s" if u == "s" else f"|{param}| = {v:.2g}{' ' + u if u else ''}"


#: the thrust curve's parameter (airframe.ThrustCurve) that sizes the same effect: the conclusion sets them side by side
CURVE_PARAM = {"thrust_voltage": "n", "actuator_lag": "tc"}

#: the conclusion says a vehicle file's alpha is not the log's when the accelerometer's differs by more than this
#: fraction of it (the curve reads the simulated quadcopter's 22 as 22.2-23.0: 1-5 % high)
CURVE_MISMATCH = 0.1

#: n / n_eff from which the conclusion says an effect's sensor innovations are coloured
COLOURED = 3.0


def _named(e) -> str:
    """``name (k = v, ...)``, or the name alone for an effect without parameters (range_tilt); a rotor
    wash taken in its thrust form says so (catalogue.altitude: its other form is the usual one)."""
    p = format_params(e.name, e.params)
    if e.evidence.get("form") == "thrust":
        p += "; it follows the thrust over the weight"
    return f"{e.name} ({p})" if p else e.name


def format_params(name: str, p: dict) -> str:
    """``k = v unit`` for each parameter of effect ``name`` (candidate.UNITS; a ``unit`` entry in ``p``
    overrides it), sigmas left out."""

    def unit(k):
        u = p.get("unit") or unit_of(name, k)
        return f" {u}" if u else ""

    return ", ".join(
        f"{k} = {v:.4g}{unit(k)}" if isinstance(v, float) else f"{k} = {v}"
        for k, v in p.items()
        if not k.startswith("sigma_") and k != "unit"
    )
