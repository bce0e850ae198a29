"""A rig diagnosis as files: report.json, report.html, and the rig's constants as a vehicle file
(``heli3dof_rig.json``) that ``--vehicle`` gives the estimator and the controllers."""

from __future__ import annotations

import html
import json
import math
from pathlib import Path

from groundstation.estimation.models.heli3dof import J_E, J_L, J_P

from .catalogue import UNOBSERVABLE_RIG
from .diagnose import RigDiagnosis
from .identify import MIN_DELTA_BIC, Step
from .predict import AXES

RIG_FILE = "heli3dof_rig.json"
#: each fit parameter as a report names it: (name, unit, factor)
SHOWN = {
    "V_s0": ("V_s0", "V", 1.0),
    "K_f": ("K_f", "N/V", 1.0),
    "a": ("a", "", 1.0),
    "w_e": ("share", "", 1.0),
    "w_l": ("share", "", 1.0),
    "c_p": ("c", "1/s", 1.0),
    "c_e": ("c", "1/s", 1.0),
    "c_l": ("c", "1/s", 1.0),
    "tc": ("tc", "s", 1.0),
    "b_gx": ("x", "rad/s", 1.0),
    "b_gy": ("y", "rad/s", 1.0),
    "b_gz": ("z", "rad/s", 1.0),
    "b_ax": ("x", "m/s^2", 1.0),
    "b_ay": ("y", "m/s^2", 1.0),
    "b_az": ("z", "m/s^2", 1.0),
    "m_roll": ("roll", "deg", math.degrees(1.0)),
    "m_pitch": ("pitch", "deg", math.degrees(1.0)),
    "m_yaw": ("yaw", "deg", math.degrees(1.0)),
    "o_p": ("p", "deg", math.degrees(1.0)),
    "o_e": ("e", "deg", math.degrees(1.0)),
}
#: a friction's torque constant d = c J, as the rig's data sheet (and the simulator) gives it
INERTIA = {"c_p": J_P, "c_e": J_E, "c_l": J_L}
SENSOR_NAMES = {"gyro": "gyro", "accel": "accelerometer", "encoders": "encoders"}


def effect_json(step: Step, params: tuple[str, ...], what: str) -> dict:
    f = step.fit
    out: dict = {"name": step.name, "what": what, "params": {}, "sigma": {}, "units": {}}
    for k in params:
        name, unit, factor = SHOWN[k]
        out["params"][name] = f.values[k] * factor
        out["sigma"][name] = f.sigma.get(k, math.nan) * factor
        out["units"][name] = unit
        if k in INERTIA:
            out["params"]["d"] = f.values[k] * INERTIA[k]
            out["sigma"]["d"] = f.sigma.get(k, math.nan) * INERTIA[k]
            out["units"]["d"] = "N m s/rad"
    out["delta_bic"] = step.delta_bic
    out["evidence"] = {"delta_bic": step.delta_bic}  # where the fleet's table reads it
    return out


def as_json(d: RigDiagnosis, source: str, description: str) -> dict:
    by_name = {c.name: c for c in d.catalogue}
    effects = []
    for i, st in enumerate(d.search.claimed):
        cand = by_name[st.name]
        # its values and errors as the final model has them (fitted with every effect found after it)
        e = effect_json(Step(st.name, st.delta_bic, st.cross_validated, d.search.final), cand.params, cand.what)
        tried = d.search.tried[i]
        e["rivals"] = [
            {"name": o.name, "delta_bic": o.delta_bic}
            for o in tried
            if o.name != st.name
            and o.delta_bic <= -MIN_DELTA_BIC
            and o.delta_bic <= st.delta_bic + max(10.0, 0.05 * -st.delta_bic)
        ]
        effects.append(e)
    last = d.search.tried[-1] if d.search.tried else []
    claimed = {st.name for st in d.search.claimed}
    not_claimed = [
        {
            "name": o.name,
            "delta_bic": o.delta_bic,
            **({"cross_validated": o.cross_validated} if o.cross_validated is not None else {}),
            **({"confounded_with": o.confounded_with} if o.confounded_with else {}),
        }
        for o in last
        if o.name not in claimed
    ]
    s = d.session
    j = {
        "source": source,
        "description": description,
        "model": "heli3dof",
        "method": "equation error: each effect's parameters fitted to the encoders' accelerations and the IMU, "
        "kept by BIC on effective samples and two-fold cross-validation (docs/diagnosis_rig.md)",
        "session": {
            "seconds": float(s.t[-1] - s.t[0]),
            "seconds_free": s.seconds_free,
            "imu": s.gyro is not None and s.specific_force is not None,
            "notes": list(s.notes),
        },
        "effects": effects,
        "not_claimed": not_claimed,
        "unobservable": UNOBSERVABLE_RIG,
        "constants_before": d.before.as_vehicle(),
        "constants_after": d.after.as_vehicle(),
        "prediction_error": {"before": d.prediction[0].as_json(), "after": d.prediction[1].as_json()},
        "equation_residual_rms": {"before": d.residual_rms[0], "after": d.residual_rms[1]},
        "kalman_nis": None
        if d.nis is None
        else {
            "before": d.nis[0],
            "after": d.nis[1],
            "R": {k: [float(x) for x in v.diagonal()] for k, v in d.R.items()},
        },
        "rig_file": RIG_FILE,
    }
    j["conclusion"] = conclusion(j)
    return j


def _fmt(name: str, v: float, sigma: float, unit: str) -> str:
    digits = max(2, 1 - int(math.floor(math.log10(abs(sigma))))) if sigma and math.isfinite(sigma) else 3
    u = f" {unit}" if unit else ""
    return f"{name} = {v:.{digits}f} ± {sigma:.{digits}f}{u}"


def conclusion(j: dict) -> str:
    pe = j["prediction_error"]
    b, a = pe["before"]["rms_deg"], pe["after"]["rms_deg"]
    pred = ", ".join(f"{ax} {b[ax]:.3f} -> {a[ax]:.3f} deg" for ax in AXES)
    if not j["effects"]:
        best = j["not_claimed"][0] if j["not_claimed"] else None
        text = "The lab's model holds on this session: no effect in the catalogue improves it" + (
            f" (the closest, {best['name']}, at Delta BIC {best['delta_bic']:+.1f}; "
            f"{-MIN_DELTA_BIC:g} or less is needed)."
            if best
            else "."
        )
        return text + f" Its encoders predicted over {pe['before']['horizon_s']:g} s from the voltages: {pred} RMS."
    parts = []
    for e in j["effects"]:
        shown = [_fmt(k, v, e["sigma"][k], e["units"][k]) for k, v in e["params"].items() if k != "d"]
        rivals = f" (as well fitted by {', '.join(r['name'] for r in e['rivals'])})" if e["rivals"] else ""
        parts.append(f"{e['name']}: {', '.join(shown)}{rivals}")
    text = f"The lab's model lacks {len(parts)} effect(s) on this session: " + "; ".join(parts) + "."
    text += f" With them, the encoders predicted over {pe['before']['horizon_s']:g} s from the voltages: {pred} RMS."
    k = j.get("kalman_nis")
    if k:
        nis = ", ".join(
            f"{SENSOR_NAMES.get(s, s)} {k['before'][s]:.2f} -> {k['after'][s]:.2f}"
            for s in k["before"]
            if s in k["after"]
        )
        text += f" The Kalman filter's NIS (1 where model and noise hold): {nis}."
    return text + f" The rig's constants are in {j['rig_file']} (--vehicle PATH)."


def rig_vehicle_file(j: dict) -> dict:
    return {
        "_doc": "The 3-DOF helicopter rig's own constants as groundstation diagnose --model heli3dof found them in "
        f"{j['source']}: {j['conclusion']}",
        "heli3dof": {"rig": j["constants_after"]},
    }


def write(d: RigDiagnosis, out: Path, source: str, description: str) -> dict:
    j = as_json(d, source, description)
    (out / "report.json").write_text(json.dumps(j, indent=2, allow_nan=True))
    (out / RIG_FILE).write_text(json.dumps(rig_vehicle_file(j), indent=2))
    (out / "report.html").write_text(page(j))
    return j


def page(j: dict) -> str:
    rows = "".join(
        f"<tr><td>{html.escape(e['name'])}</td><td>{html.escape(e['what'])}</td><td>"
        + ", ".join(html.escape(_fmt(k, v, e["sigma"][k], e["units"][k])) for k, v in e["params"].items())
        + f"</td><td>{e['delta_bic']:.1f}</td></tr>"
        for e in j["effects"]
    )
    pe = j["prediction_error"]
    pred = "".join(
        f"<tr><td>{ax}</td><td>{pe['before']['rms_deg'][ax]:.4f}</td><td>{pe['after']['rms_deg'][ax]:.4f}</td></tr>"
        for ax in AXES
    )
    return (
        "<!doctype html><html><head><meta charset='utf-8'>"
        f"<title>rig diagnosis: {html.escape(j['source'])}</title></head><body>"
        f"<h1>3-DOF helicopter: {html.escape(j['source'])}</h1><p>{html.escape(j['description'])}</p>"
        f"<p>{html.escape(j['conclusion'])}</p>"
        "<h2>Effects found</h2><table border=1><tr><th>effect</th><th>what</th><th>parameters</th>"
        f"<th>&Delta;BIC</th></tr>{rows}</table>"
        f"<h2>Encoders predicted over {pe['before']['horizon_s']:g} s (RMS, deg)</h2>"
        f"<table border=1><tr><th>axis</th><th>lab's model</th><th>with the effects</th></tr>{pred}</table>"
        "</body></html>"
    )
