"""Step 5, report: ``report.json`` for machines, ``report.html`` for people, estimates before/after.

report.json::

    {"source", "model", "vehicle",       # the airframe file the model started from (--vehicle), or null
     "airframe",                         # the thrust curve read from the accelerometer (airframe.py: alpha,
                                         # beta, drag, n, tc, sigma, ..., "used": the model's prior; with a
                                         # vehicle file, read beside it: file_alpha, file_beta), or null
     "effects": [{"name", "params", "evidence"}, ...],     # in the order added
     "modelled": [...], "measured_against_truth": [...], "discovered": [...],
     "rejected": [...],                  # fitted better, but failed out of sample or against truth
     "unobservable": {name: why}, "ranking": [[[candidate, delta_bic], ...] per iteration],
     "detectable": [{"name", "size": {param: value}, "delta_bic"}, ...],   # each candidate not found: the
                                         # size this log would claim it at about half the time (trace.py)
     "noise": [...],                     # each sensor's noise from the log, beside the model's
     "unusable_readings": {"<kind>_<problem>": count},   # not finite or out of range: left out
     "range_clearance": {"m", "from", "parameter"} or null,   # the range's reading on the ground,
                                         # taken off its readings (estimation/stated.py)
     "before": {...}, "after": {...}}

with ``before``/``after`` per sensor: innovation RMS, NIS mean, Ljung-Box p,
failed tests, and ``skipped_spurious`` (a count) and ``skipped_spurious_at`` ([first, last]
spans in s) where readings were skipped as spurious (the thrust model's range echoes on the
ground, ``thrust.LIFTOFF_REACH``); and, when truth exists,
``rmse_vs_truth`` of the height [m] or, for the attitude model, of roll and pitch together
[rad] (``rmse_of`` says which), and for the height whether its sigma is honest:
``within_2sigma`` (the share of its errors within 2 sigma; 0.95 if honest) and ``nees`` (1 if
honest; :meth:`~groundstation.estimation.truth.Truth.consistency`).
An effect's evidence: ``delta_bic``, ``delta_bic_effective`` and ``innovation_colour``
(the same at the innovations' effective sample size, and n / n_eff per sensor: see
trace.py), ``sensor``, ``loglik_gain``, ``gain_per_update`` over ``support`` updates (those the
effect acts on: trace.py), ``runner_up`` and its ΔBIC, ``alternative`` ({name, params, delta_bic}) when
that runner-up would have been claimed too and is less than very strongly worse (search.CLOSE_CALL), and,
when an effect added later moved its estimate, ``params_when_added`` (``params`` are the final
model's joint estimate: joint.joint_params).
A discovered effect is ``{"name": "discovered", "params": {"regressor", "coefficient", "sensor"},
"evidence": {"r2", "terms", "ljung_box_p": {"innovations", "without_the_fit"}}}``; a rejected one's evidence
has ``delta_bic``, ``against`` (the truth's source), ``quantity``, ``error_before`` and
``error_with`` (in the quantity's SI unit).
Figures are matplotlib (Agg) SVG, inlined so the HTML is one file.
"""

from __future__ import annotations

import html
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from groundstation.estimation.export import EstimateCsvWriter
from groundstation.estimation.identity import Vehicle
from groundstation.estimation.models.ground import LANDED
from groundstation.estimation.whiteness import ljung_box

from .autopilot_params import ParamSuggestion
from .catalogue import unit_of
from .engine import Diagnosis
from .run import Run
from .search import CLOSE_CALL
from .thrust import LIFTOFF_REACH, ThrustContext
from .triage import Triage


def _summary(run: Run, findings, truth, t0: float, t1: float, delays: dict[str, float] | None = None) -> dict:
    """``delays``: a sensor's delay in this run's model, to give its skipped readings' times as the
    log stamps them (the model takes a late sensor's readings as of when they were measured)."""
    out: dict[str, Any] = {"sensors": {}}
    for s, tr in run.sensors.items():
        if s == LANDED:  # the on-ground constraint, not a sensor
            continue
        k = tr.t >= tr.t[0] + 5.0
        e = tr.nu_normalised[k]
        out["sensors"][s] = {
            "n": int(k.sum()),
            "innovation_rms": float(np.sqrt(np.mean(tr.nu[k, 0] ** 2))),
            "nis_mean": float(np.mean(tr.nis[k])),
            "ljung_box_p": float(ljung_box(e)),
            "failed": [f.test for f in findings if f.sensor == s and not f.passed],
        }
        ctx = run.ctx
        spurious = ctx.range_spurious if isinstance(ctx, ThrustContext) and s == "range" else ()
        if spurious:  # thrust.LIFTOFF_REACH
            out["sensors"][s]["skipped_spurious"] = len(spurious)
            late = (delays or {}).get(s, 0.0)
            out["sensors"][s]["skipped_spurious_at"] = _spans([t + late for t in spurious])
    if truth is not None:
        e = truth.error(run, t0, t1)
        if math.isfinite(e):
            out["rmse_vs_truth"] = e
            out["rmse_of"] = truth.quantity(run)
            out["truth"] = truth.source
        if "z" in run.model.states and len(run.t):
            i = run.model.index("z")
            sigma = np.concatenate(  # a few thousand rows at a time: a covariance left for later stays so
                [
                    np.sqrt(np.clip(run.P_rows(slice(a, a + 4096))[:, i, i], 0.0, None))
                    for a in range(0, len(run.t), 4096)
                ]
            )
            within, nees = truth.consistency(run.t, run.x[:, i], sigma, t0, t1)
            if math.isfinite(nees):
                out["within_2sigma"], out["nees"] = within, nees
    return out


def _spans(times, gap: float = 1.0) -> list[list[float]]:
    """Instants as [first, last] spans, a new span after ``gap`` s without one."""
    spans: list[list[float]] = []
    for t in sorted(times):
        if spans and t - spans[-1][1] <= gap:
            spans[-1][1] = round(t, 2)
        else:
            spans.append([round(t, 2), round(t, 2)])
    return spans


def as_json(d: Diagnosis) -> dict:
    t0, t1 = d.before.t[0] + 5.0, d.before.t[-1]
    eff = [{"name": e.name, "params": e.params, "evidence": e.evidence} for e in d.effects if e.name != "discovered"]
    added = {e.evidence.get("sensor"): e for e in d.effects if e.name == "discovered"}
    disc = [
        {
            "name": "discovered",
            "params": {
                "sensor": x.sensor,
                "regressor": x.expression,
                "coefficient": x.coefficient,
                # as the filter estimates it, in the model (discovered.add_discovery)
                **{k: v for k, v in added[x.sensor].params.items() if k != "expression"},
            }
            if x.sensor in added
            else {"sensor": x.sensor, "regressor": x.expression, "coefficient": x.coefficient},
            "evidence": {
                **(added[x.sensor].evidence if x.sensor in added else {}),
                "r2": x.r2,
                "terms": [{"regressor": a, "coefficient": b} for a, b in x.terms],
                # null where the test could not run (strict JSON has no NaN)
                "ljung_box_p": {
                    k: v if math.isfinite(v) else None
                    for k, v in zip(("innovations", "without_the_fit"), x.ljung_box_p)
                },
            },
        }
        for x in d.discoveries
    ]
    return {
        "source": d.source,
        "model": d.model,
        "vehicle": d.vehicle,
        "airframe": d.airframe,
        "effects": eff + disc + [{"name": e.name, "params": e.params, "evidence": e.evidence} for e in d.beside],
        "modelled": [{"name": e.name, "params": e.params, "evidence": e.evidence} for e in d.modelled],
        "measured_against_truth": [
            {"name": e.name, "params": e.params, "evidence": e.evidence} for e in d.against_truth
        ],
        "rejected": [{"name": e.name, "params": e.params, "evidence": e.evidence} for e in d.rejected],
        "unobservable": d.unobservable,
        "noise": [n.as_dict() for n in d.noise],
        "unusable_readings": d.unusable,
        "range_clearance": d.clearance.as_dict() if d.clearance is not None else None,
        "detectable": d.detectable,
        "left_out": [lo.as_dict() for lo in d.left_out],
        "ranking": [[[n, b] for n, b in it] for it in d.ranking],
        "before": _summary(d.before, d.findings_before, d.truth, t0, t1),
        "after": _summary(
            d.after,
            d.findings_after,
            d.truth,
            t0,
            t1,
            {e.params["sensor"]: e.params["seconds"] for e in d.effects if e.name == "sensor_delay"},
        ),
        "findings_before": [f.as_dict() for f in d.findings_before],
        "findings_after": [f.as_dict() for f in d.findings_after],
    }


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
    return [
        "The log's own noise differs from the model's, and the diagnosis used the log's: "
        + "; ".join(f"{n.sensor} {n.sigma_data:.3g}, the model had {n.sigma_model:.3g}" for n in differs)
        + " (covariance matching on the innovations). A mis-set noise level is a finding of its own, "
        "not an effect."
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
    parts = [
        "No effect in the catalogue improves the model by strong evidence"
        + (
            ", but the innovations follow something outside it (below)."
            if d.discoveries
            else ": as far as these data can tell, the model is complete."
        )
    ]
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


def _outside_said(d: Diagnosis) -> list[str]:
    """What the model's own states carry, the range's offset against truth, and what lies outside the
    catalogue."""
    parts = [
        f"The model's own state {e.evidence['state']} carries {e.name}: {format_params(e.name, e.params)}."
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
    """``name (k = v, ...)``, or the name alone for an effect without parameters (range_tilt)."""
    p = format_params(e.name, e.params)
    return f"{e.name} ({p})" if p else e.name


def format_params(name: str, p: dict) -> str:
    """``k = v unit`` for each parameter of effect ``name`` (catalogue.UNITS; a ``unit`` entry in ``p``
    overrides it), sigmas left out."""

    def unit(k):
        u = p.get("unit") or unit_of(name, k)
        return f" {u}" if u else ""

    return ", ".join(
        f"{k} = {v:.4g}{unit(k)}" if isinstance(v, float) else f"{k} = {v}"
        for k, v in p.items()
        if not k.startswith("sigma_") and k != "unit"
    )


def _broken_at_gaps(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``t, y`` with a NaN in each gap of over 0.5 s and five typical intervals, so that a plotted line
    breaks there (a range sensor out of reach for 15 s was drawn as one straight line across)."""
    if len(t) < 3:
        return t, y
    dt = np.diff(t)
    gaps = np.flatnonzero(dt > max(0.5, 5.0 * float(np.median(dt)))) + 1
    return np.insert(t.astype(float), gaps, np.nan), np.insert(y.astype(float), gaps, np.nan)


def _figures(d: Diagnosis) -> str:
    from matplotlib.figure import Figure  # (here: a second of every command's start-up otherwise)

    out = []
    for s in sorted((set(d.before.sensors) & set(d.after.sensors)) - {LANDED}):
        # matplotlib's object API: no pyplot, so no global backend or figure registry to manage
        fig = Figure(figsize=(11, 3.0))
        ax = fig.subplots(1, 2)
        for run, label, col in ((d.before, "before", "#c0392b"), (d.after, "after", "#2e7d32")):
            tr = run.sensors[s]
            ax[0].plot(*_broken_at_gaps(tr.t, tr.nu[:, 0]), lw=0.6, color=col, label=label, alpha=0.8)
            e = tr.nu_normalised[tr.t >= tr.t[0] + 5.0]
            ec = e - e.mean()
            lags = min(50, len(e) // 4)
            acf = [np.dot(ec[:-k], ec[k:]) / np.dot(ec, ec) for k in range(1, lags + 1)]
            ax[1].plot(range(1, lags + 1), acf, marker=".", lw=0.8, color=col, label=label)
        n = len(d.after.sensors[s].t)
        for sign in (-1, 1):
            ax[1].axhline(sign * 1.96 / math.sqrt(max(n, 1)), color="#888", lw=0.8, ls="--")
        ax[0].set_title(f"{s}: innovation")
        ax[0].set_xlabel("t [s]")
        ax[1].set_title(f"{s}: autocorrelation of the normalised innovation (±1.96/√n)")
        ax[1].set_xlabel("lag")
        ax[0].legend(loc="upper right", fontsize=8)
        fig.tight_layout()
        buf = io.StringIO()
        fig.savefig(buf, format="svg")
        out.append(buf.getvalue()[buf.getvalue().index("<svg") :])
    return "\n".join(out)


def _evidence_html(name: str, ev: dict) -> str:
    """An effect's evidence as a person reads it, a line per item (report.json keeps the numbers)."""
    lines = []
    if "delta_bic" in ev:
        on = f" on the {ev['sensor']}" if ev.get("sensor") else ""
        lines.append(
            f"Delta BIC {ev['delta_bic']:+.1f}{on}"
            + (
                f" ({ev['delta_bic_effective']:+.1f} at the effective sample size)"
                if ev.get("delta_bic_effective") not in (None, ev["delta_bic"])
                else ""
            )
        )
    if "loglik_gain" in ev:
        lines.append(
            f"log-likelihood gain {ev['loglik_gain']:.1f}: {ev['gain_per_update']:.3g} per update over the "
            f"{ev['support']} updates it acts on"
        )
    coloured = {k: v for k, v in ev.get("innovation_colour", {}).items() if v >= COLOURED}
    if coloured:
        lines.append(
            "coloured innovations: "
            + ", ".join(f"each {k} one worth 1/{v:.0f} of a sample" for k, v in coloured.items())
        )
    if "held_out_gain" in ev:
        z = ", ".join(f"{k} at {v:.1f} sigma" for k, v in ev.get("z", {}).items())
        lines.append(
            f"held out: log-likelihood gain {ev['held_out_gain']:+.1f} on blocks it was not fitted on "
            f"({', '.join(f'{g:+.1f}' for g in ev.get('held_out_gain_by_block', []))})" + (f"; {z}" if z else "")
        )
    if ev.get("reason"):
        lines.append(f"not claimed: {ev['reason']}")
    if ev.get("runner_up"):
        lines.append(f"runner-up {ev['runner_up']} ({ev['runner_up_delta_bic']:+.1f})")
    alt = ev.get("alternative")
    if alt:
        p = format_params(alt["name"], {k: v for k, v in alt["params"].items() if k != "sensor"})
        lines.append(f"barely told from {alt['name']}{f' ({p})' if p else ''}: read the finding as either")
    if "params_when_added" in ev:
        lines.append(f"when added: {format_params(name, ev['params_when_added'])}")
    if "error_before" in ev:
        k, unit = (100.0, "cm") if ev["quantity"].startswith("height") else (math.degrees(1.0), "deg")
        lines.append(
            f"error against the {ev['against']}: {ev['error_before'] * k:.2f} {unit} without it, "
            f"{ev['error_with'] * k:.2f} {unit} with it"
        )
    elif "against" in ev:
        lines.append(f"measured against the {ev['against']} over {ev.get('n', '?')} readings")
    if "state" in ev:
        lines.append(f"the model's state {ev['state']}, {ev.get('z_over_sigma', math.nan):.1f} sigma from 0")
    if "note" in ev:
        lines.append(ev["note"])
    if "r2" in ev:  # discovered: the sparse regression's fit to the raw innovations (discover.py)
        terms = " + ".join(f"{t['coefficient']:.3g} {t['regressor']}" for t in ev.get("terms", ()))
        lines.append(f"{ev['r2']:.0%} of the innovations' variance" + (f": {terms}" if terms else ""))
        lb = ev.get("ljung_box_p", {})
        if lb and None not in lb.values():
            lines.append(f"Ljung-Box p {lb['innovations']:.2g}, without the fit {lb['without_the_fit']:.2g}")
    return "<br>".join(html.escape(x) for x in lines)


class _Html(str):
    """A table cell that is HTML already (escaped where it was built)."""


def _table(rows: list[list], head: list[str]) -> str:
    th = "".join(f"<th>{html.escape(h)}</th>" for h in head)
    body = "".join(
        "<tr>" + "".join(f"<td>{c if isinstance(c, _Html) else html.escape(str(c))}</td>" for c in r) + "</tr>"
        for r in rows
    )
    return f"<table><tr>{th}</tr>{body}</table>"


def write(
    d: Diagnosis,
    out: Path,
    *,
    triage: Triage | None = None,
    used: list[tuple[float, float]] | None = None,
    cut: list[dict] | None = None,
    parameters: list[ParamSuggestion] | None = None,
    vehicle: Vehicle | None = None,
    model_chosen: str = "",
    not_described: str | None = None,
) -> dict:
    """report.json, report.html and the estimates' CSVs in ``out``. With the triage: what the log
    says happened opens both, with the stretches the fit used and those it cut; with parameters:
    what to set on the autopilot for each effect found; with the vehicle, what wrote the log, why the
    model was chosen, and (``not_described``) why the model does not describe it and no parameter is
    written."""
    out.mkdir(parents=True, exist_ok=True)
    j = _report_json(d, triage, used, cut, parameters, vehicle, model_chosen, not_described)
    (out / "report.json").write_text(json.dumps(j, indent=2, default=float))
    for run, name in ((d.before, "estimates_before.csv"), (d.after, "estimates_after.csv")):
        w = EstimateCsvWriter(out / name, "x", run.model.states)
        for t, x, P in zip(run.t, run.x, run.P):
            w.write(_Snap(t, x, np.sqrt(np.clip(np.diag(P), 0, None))))
        w.close()
    (out / "report.html").write_text(_report_html(d, j, triage, parameters))
    return j


def _report_json(
    d: Diagnosis,
    triage: Triage | None,
    used: list[tuple[float, float]] | None,
    cut: list[dict] | None,
    parameters: list[ParamSuggestion] | None,
    vehicle: Vehicle | None,
    model_chosen: str,
    not_described: str | None,
) -> dict:
    """report.json's content (:func:`write`'s arguments), the conclusion opened by what the triage and
    the vehicle say."""
    j = as_json(d)
    j["conclusion"] = conclusion(d, j)
    if vehicle is not None:
        j["vehicle_type"] = vehicle.as_dict()
    if model_chosen:
        j["model_chosen"] = model_chosen
    if not_described:
        j["not_described"] = not_described
        j["conclusion"] = (
            f"The {d.model} model does not describe this vehicle: {not_described}. What follows is a finding "
            "about the model, and no parameter is written. " + j["conclusion"]
        )
    if triage is not None:
        j["triage"] = triage.as_json()
        j["triage_clock"] = triage.clock
        j["segments_used"] = [{"t_start": a, "t_end": b} for a, b in used or []]
        j["segments_cut"] = cut or []
        j["conclusion"] = triage_headline(triage, used or [], cut or []) + j["conclusion"]
    if parameters is not None:
        j["parameters"] = [p.as_json() for p in parameters]
    return j


def _report_html(d: Diagnosis, j: dict, triage: Triage | None, parameters: list[ParamSuggestion] | None) -> str:
    """report.html: the conclusion, the triage, the error against truth, the effects and what to set,
    then the evidence, section by section."""
    ranking = "".join(
        f"<p>iteration {i + 1}: " + ", ".join(f"{n} ({b:+.1f})" for n, b in it) + "</p>"
        for i, it in enumerate(j["ranking"])
    )
    failed, still = (
        _table(
            [[f.sensor, f.test, f"{f.statistic:.3g}", f.threshold, f.where] for f in fs if not f.passed]
            or [["(none)", "", "", "", ""]],
            ["sensor", "test", "statistic", "threshold", "where"],
        )
        for fs in (d.findings_before, d.findings_after)
    )
    detectable = _table(
        [[x["name"], format_params(x["name"], x["size"]), f"{x['delta_bic']:+.1f}"] for x in j["detectable"]]
        or [["(none)", "", ""]],
        ["effect", "size", "Delta BIC on this log"],
    )
    unobs = "".join(f"<li><b>{html.escape(k)}</b>: {html.escape(v)}</li>" for k, v in d.unobservable.items())
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>diagnosis: {html.escape(d.source)}</title>
<style>body{{font-family:system-ui,sans-serif;max-width:1150px;margin:2em auto;color:#222}}
table{{border-collapse:collapse;margin:0.5em 0 1.5em}}td,th{{border:1px solid #ccc;padding:3px 8px;font-size:13px}}
th{{background:#f3f3f3}}.concl{{background:#f6fbf6;border-left:4px solid #2e7d32;padding:0.6em 1em}}</style></head>
<body><h1>Diagnosis of {html.escape(d.source)}</h1><p>model: {html.escape(d.model)}{_vehicle_line(d)}</p>
<div class="concl"><p>{html.escape(j["conclusion"])}</p></div>{_triage_html(triage, j)}{_truth_html(j)}
<h2>Effects found</h2>{_effects_html(j)}{_parameters_html(parameters)}
<h2>Evidence: candidates ranked (Delta BIC, negative is better)</h2>{ranking}
<h2>Each absolute sensor predicted by the others (left out of the filter; its unit, m)</h2>{_left_out_html(j)}
<h2>Residuals before and after</h2>{_sensors_html(j)}{_figures(d)}
<h2>Tests that failed before</h2>{failed}
<h2>Tests that still fail after</h2>{still}
<h2>What this log could have shown: the size of each effect not found that it would claim about half the time</h2>
{detectable}
<h2>Not observable with these sensors</h2><ul>{unobs}</ul></body></html>"""


def _sensors_html(j: dict) -> str:
    rows = []
    for s in sorted(j["before"]["sensors"]):
        b, a = j["before"]["sensors"][s], j["after"]["sensors"].get(s, {})
        rows.append(
            [
                s,
                f"{b['innovation_rms']:.4g}",
                f"{a.get('innovation_rms', math.nan):.4g}",
                f"{b['nis_mean']:.2f}",
                f"{a.get('nis_mean', math.nan):.2f}",
                f"{b['ljung_box_p']:.3g}",
                f"{a.get('ljung_box_p', math.nan):.3g}",
            ]
        )
    return _table(
        rows, ["sensor", "innovation RMS before", "after", "NIS before", "after", "Ljung-Box p before", "after"]
    )


def _effects_html(j: dict) -> str:
    """The effects found (and those the model carries, and those measured against truth), then the
    rejected ones with why."""
    effects = _table(
        [
            [e["name"], format_params(e["name"], e["params"]), _Html(_evidence_html(e["name"], e["evidence"]))]
            for e in j["effects"] + j["modelled"] + j["measured_against_truth"]
        ]
        or [["(none)", "", ""]],
        ["effect", "parameters", "evidence"],
    )
    if j["rejected"]:
        effects += "<h3>Rejected: a better fit that does not hold (out of sample, or against truth)</h3>" + _table(
            [
                [e["name"], format_params(e["name"], e["params"]), _Html(_evidence_html(e["name"], e["evidence"]))]
                for e in j["rejected"]
            ],
            ["effect", "parameters", "evidence"],
        )
    return effects


def _left_out_html(j: dict) -> str:
    return _table(
        [
            [lo["sensor"], f"{lo['rms_before']:.4f}", f"{lo['rms_after']:.4f}", lo["n"]]
            + (
                [f"{lo['height_rmse_before']:.4f}", f"{lo['height_rmse_after']:.4f}"]
                if "height_rmse_before" in lo
                else ["", ""]
            )
            for lo in j["left_out"]
        ]
        or [["(none)", "", "", "", "", ""]],
        ["left out", "RMS before", "RMS after", "readings", "height vs truth before [m]", "after [m]"],
    )


def _truth_html(j: dict) -> str:
    if "rmse_vs_truth" not in j["before"]:
        return ""
    b, a = j["before"], j["after"]
    what, unit, scale = (
        ("Height", "m", 1.0) if b["rmse_of"].startswith("height") else ("Roll and pitch", "deg", math.degrees(1.0))
    )
    truth = (
        f"<p>{what} RMSE against the {html.escape(b['truth'])}: "
        f"<b>{b['rmse_vs_truth'] * scale:.4f} {unit}</b> before, <b>{a['rmse_vs_truth'] * scale:.4f} {unit}</b> "
        f"after.</p>"
    )
    if "nees" in b and "nees" in a:
        truth += (
            f"<p>Truth within the height's 2 sigma: <b>{b['within_2sigma']:.0%}</b> of the time before, "
            f"<b>{a['within_2sigma']:.0%}</b> after (95 % if the sigma is honest); NEES {b['nees']:.2f} "
            f"before, {a['nees']:.2f} after (1 if honest).</p>"
        )
    return truth


def triage_headline(tr: Triage, used: list[tuple[float, float]], cut: list[dict]) -> str:
    """The conclusion's first sentences: what went wrong in the flight, and what the fit left out."""
    serious = [f for f in tr.findings if f.severity in ("critical", "error")]
    if not serious:
        return ""
    seen: dict[str, str] = {}
    for f in serious:
        seen.setdefault(f.name, f"{f.name.replace('_', ' ')} at {f.t_start:.1f} s")
    text = "The log shows " + "; ".join(list(seen.values())[:6]) + " (triage below). "
    if cut:
        spans = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in used) or "nothing"
        names = ", ".join(dict.fromkeys(c["name"] for c in cut))
        text += f"The model was fitted to {spans} only: the stretches of {names} were cut. "
    return text


def _triage_html(tr: Triage | None, j: dict) -> str:
    if tr is None:
        return ""
    clock = "seconds since the recording began" if tr.clock == "recording" else "seconds of the vehicle's clock"
    rows = [
        [
            f.severity,
            f.name,
            f"{f.t_start:.1f}" + (f"-{f.t_end:.1f}" if f.t_end - f.t_start >= 0.05 else ""),
            f.evidence + (" (cut from the fit)" if f.cuts else ""),
            _Html(f'<a href="{html.escape(f.doc)}">docs</a>') if f.doc else "",
        ]
        for f in tr.findings
    ] or [["", "(nothing)", "", "nothing wrong in the log's own records", ""]]
    used = ", ".join(f"{s['t_start']:.1f}-{s['t_end']:.1f} s" for s in j.get("segments_used", []))
    return (
        f"<h2>What the log says happened (triage, {tr.seconds:.2f} s)</h2><p>Times in {clock}. "
        f"The fit used {html.escape(used or 'the whole log')}.</p>"
        + _table(rows, ["severity", "finding", "when [s]", "evidence", ""])
    )


def _parameters_html(ps: list[ParamSuggestion] | None) -> str:
    if not ps:
        return ""
    rows = [[p.autopilot, p.name or "(none)", "" if p.value is None else f"{p.value:g}", p.effect, p.why] for p in ps]
    return (
        "<h2>Parameters to set on the autopilot</h2><p>Also written as params_ardupilot.param and "
        "params_px4.params; review each before loading.</p>"
        + _table(rows, ["autopilot", "parameter", "value", "effect", "why"])
    )


def _vehicle_line(d: Diagnosis) -> str:
    a = d.airframe
    if a and not a.get("used", True):
        return (
            f", the airframe's constants from <code>groundstation/vehicles/{html.escape(d.vehicle or '')}.json</code> "
            f"(alpha = {a['file_alpha']:.2f} m/s&sup2;; the log's accelerometer reads {a['alpha']:.2f} &plusmn; "
            f"{a['sigma']['alpha']:.2f})"
        )
    if not d.vehicle and a:
        return (
            f" (no airframe file: the thrust curve from the log's accelerometer, alpha = {a['alpha']:.2f} "
            f"&plusmn; {a['sigma']['alpha']:.2f} m/s&sup2;, beta = {a['beta']:.2f} &plusmn; "
            f"{a['sigma']['beta']:.2f} m/s&sup2;, drag {a['drag']:.2f} /s, over {a['seconds']:.0f} s of flight)"
        )
    if not d.vehicle:
        return " (the vehicle's constants from the log: no airframe file)"
    return f", the airframe's constants from <code>groundstation/vehicles/{html.escape(d.vehicle)}.json</code>"


class _Snap:
    estimator = "x"

    def __init__(self, t, x, sigma) -> None:
        self.t, self.x, self.sigma = t, x, sigma
