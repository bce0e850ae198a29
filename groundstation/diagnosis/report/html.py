"""report.html: the conclusion, the triage, the error against truth, the effects and what to set
on the autopilot, the evidence, and the figures (matplotlib, Agg, as inlined SVG so that the page
is one file)."""

from __future__ import annotations

import html
import io
import math

import numpy as np

from groundstation.diagnosis.engine import Diagnosis
from groundstation.diagnosis.report.autopilot_params import ParamSuggestion
from groundstation.diagnosis.report.conclusion import COLOURED, format_params
from groundstation.diagnosis.runs.run import Run
from groundstation.diagnosis.triage import Triage
from groundstation.estimation.models.ground import LANDED


def _broken_at_gaps(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``t, y`` with a NaN in each gap of over 0.5 s and five typical intervals, so that a plotted line
    breaks there (a range sensor out of reach for 15 s was drawn as one straight line across)."""
    if len(t) < 3:
        return t, y
    dt = np.diff(t)
    gaps = np.flatnonzero(dt > max(0.5, 5.0 * float(np.median(dt)))) + 1
    return np.insert(t.astype(float), gaps, np.nan), np.insert(y.astype(float), gaps, np.nan)


def figures(before: Run, after: Run) -> str:
    """The figures of each sensor's innovations and their autocorrelation, before and after, as SVG."""
    from matplotlib.figure import Figure  # (here: a second of every command's start-up otherwise)

    out = []
    for s in sorted((set(before.sensors) & set(after.sensors)) - {LANDED}):
        # matplotlib's object API: no pyplot, so no global backend or figure registry to manage
        fig = Figure(figsize=(11, 3.0))
        ax = fig.subplots(1, 2)
        for run, label, col in ((before, "before", "#c0392b"), (after, "after", "#2e7d32")):
            tr = run.sensors[s]
            ax[0].plot(*_broken_at_gaps(tr.t, tr.nu[:, 0]), lw=0.6, color=col, label=label, alpha=0.8)
            e = tr.nu_normalised[tr.t >= tr.t[0] + 5.0]
            ec = e - e.mean()
            lags = min(50, len(e) // 4)
            acf = [np.dot(ec[:-k], ec[k:]) / np.dot(ec, ec) for k in range(1, lags + 1)]
            ax[1].plot(range(1, lags + 1), acf, marker=".", lw=0.8, color=col, label=label)
        n = len(after.sensors[s].t)
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


def report_html(
    d: Diagnosis, j: dict, triage: Triage | None, parameters: list[ParamSuggestion] | None, drawn: str | None = None
) -> str:
    """report.html: the conclusion, the triage, the error against truth, the effects and what to set,
    then the evidence, section by section; ``drawn``: its :func:`figures`, where drawn already."""
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
<h2>Residuals before and after</h2>{_sensors_html(j)}{figures(d.before, d.after) if drawn is None else drawn}
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
