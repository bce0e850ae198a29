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
ground, ``thrust_model.LIFTOFF_REACH``); and, when truth exists,
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

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from groundstation.diagnosis.catalogue.thrust_model import ThrustContext
from groundstation.diagnosis.engine import Diagnosis
from groundstation.diagnosis.report.autopilot_params import ParamSuggestion
from groundstation.diagnosis.report.conclusion import conclusion
from groundstation.diagnosis.report.html import figures, report_html
from groundstation.diagnosis.runs.run import Run
from groundstation.diagnosis.triage import Triage
from groundstation.estimation.export import EstimateCsvWriter
from groundstation.estimation.identity import Vehicle
from groundstation.estimation.models.ground import LANDED
from groundstation.estimation.whiteness import ljung_box


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
        if spurious:  # thrust_model.LIFTOFF_REACH
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
    drawn: Drawn | None = None,
) -> dict:
    """report.json, report.html and the estimates' CSVs in ``out``. With the triage: what the log
    says happened opens both, with the stretches the fit used and those it cut; with parameters:
    what to set on the autopilot for each effect found; with the vehicle, what wrote the log, why the
    model was chosen, and (``not_described``) why the model does not describe it and no parameter is
    written. ``drawn``: the CSVs and figures of ``d``'s runs, made already (:func:`draw`)."""
    if drawn is None or drawn.before is not d.before or drawn.after is not d.after:
        drawn = draw(d.before, d.after, out)
    j = _report_json(d, triage, used, cut, parameters, vehicle, model_chosen, not_described)
    (out / "report.json").write_text(json.dumps(j, indent=2, default=float))
    (out / "report.html").write_text(report_html(d, j, triage, parameters, drawn.figures))
    return j


@dataclass
class Drawn:
    """What :func:`draw` made of the runs before and after."""

    before: Run
    after: Run
    figures: str  #: report.html's figures, as SVG


def draw(before: Run, after: Run, out: Path) -> Drawn:
    """The parts of the report made of the runs before and after alone: the estimates' CSVs in ``out``
    and the figures (made while the runs the rest of the report reads are still going,
    ``engine.diagnose``'s ``meanwhile``)."""
    out.mkdir(parents=True, exist_ok=True)
    for run, name in ((before, "estimates_before.csv"), (after, "estimates_after.csv")):
        w = EstimateCsvWriter(out / name, "x", run.model.states)
        sigma = np.sqrt(np.clip(np.diagonal(run.P, axis1=1, axis2=2), 0, None))
        for t, x, s in zip(run.t, run.x, sigma):
            w.write(_Snap(t, x, s))
        w.close()
    return Drawn(before, after, figures(before, after))


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


class _Snap:
    estimator = "x"

    def __init__(self, t, x, sigma) -> None:
        self.t, self.x, self.sigma = t, x, sigma
