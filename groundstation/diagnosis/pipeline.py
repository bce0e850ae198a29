"""One log, end to end, as ``diagnose`` runs it: read, triage, cut, fit, report, parameters.

The command line (``groundstation diagnose``) and the fleet (:mod:`.fleet`, one of these per log on
a Dask worker) run this same function; ``say`` is where its lines go (the terminal, or nowhere).
"""

from __future__ import annotations

import html
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from groundstation.core.allocator import return_freed_arrays
from groundstation.core.imu import ImuColumns
from groundstation.core.measurement import Kind
from groundstation.diagnosis.engine import diagnose
from groundstation.diagnosis.model_names import RIG_MODEL_HELP
from groundstation.diagnosis.models import choose_model
from groundstation.diagnosis.report import report
from groundstation.diagnosis.report.autopilot_params import ParamSuggestion, suggest, suggest_notch, write_param_file
from groundstation.diagnosis.report.report import triage_headline
from groundstation.diagnosis.rig import report as rig_report
from groundstation.diagnosis.rig.diagnose import diagnose_rig
from groundstation.diagnosis.scoring.background import Begun
from groundstation.diagnosis.triage import Triage, triage, usable, usable_imu
from groundstation.estimation.identity import Vehicle, identify
from groundstation.estimation.logs import LoadedLog, load_log
from groundstation.estimation.models.heli3dof_rig import Heli3dofRig
from groundstation.estimation.registry import vehicle_config
from groundstation.estimation.stated import stated_by
from groundstation.estimation.truth import truth_from

#: the least of a log the fit is run on, after the triage's cuts [s]
MIN_FIT_SECONDS = 10.0


@dataclass
class LogDiagnosis:
    report: dict  # report.json as written
    description: str  # the reader's one line about the log
    duration: float  # [s]
    files: list[str]  # what was written in the output folder besides the reports


def _quiet(_: str) -> None:
    """Where the lines go when nobody reads them."""


def run(
    path: Path,
    out: Path,
    *,
    model: str = "auto",
    declared: list | None = None,
    vehicle: str | None = None,
    truth_csv: Path | None = None,
    veto_with_truth: bool = True,
    progress: Callable[[str], None] | None = None,
    say: Callable[[str], None] = _quiet,
    workers: int = 1,
) -> LogDiagnosis:
    """Diagnose ``path`` into the folder ``out`` (which must be writable). Raises the readers' and
    the engine's one-line errors (ValueError, OSError) for a log that cannot be diagnosed. ``model``
    "auto" picks the model the vehicle and the log's readings allow (:func:`.models.choose_model`);
    where none does, the report holds the triage and says why."""
    return_freed_arrays()  # a diagnosis's arrays of megabytes go back to the system when freed
    log = load_log(path, imu_columns=True)
    ms_all = log.measurements
    if not ms_all and (log.imu is None or not log.imu.series):
        raise ValueError(f"{path}: no reading could be read from it ({log.description})")
    duration = ms_all[-1].t - ms_all[0].t if ms_all else 0.0
    say(f"diagnosing {path}: {log.description}")
    if model in RIG_MODEL_HELP or (model == "auto" and is_rig_session(log)):
        return _rig(path, out, log, duration, vehicle, progress, say)
    tr = triage(log.tables, ms_all, log.imu)
    say(tr.summary())
    ms, used, cut = usable(ms_all, tr)
    if cut:
        spans = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in used) or "nothing"
        say(f"fitting the model to {spans}: {len(cut)} stretch(es) cut (report.json: segments_cut)")
    fit_seconds = sum(b - a for a, b in used)
    craft = vehicle_of(log)
    say(f"vehicle: {craft.name} ({craft.evidence})")
    if cut and fit_seconds < MIN_FIT_SECONDS:  # (a log short in itself is the engine's one-line error)
        why = "Too little of the log is usable to fit the model."
        j = write_triage_only(out, path, log.description, tr, used, cut, why, craft)
        say(
            f"not fitted: {fit_seconds:.1f} s of the log is usable (at least {MIN_FIT_SECONDS:.0f} s needed); "
            f"the triage is in {out / 'report.json'}"
        )
        return LogDiagnosis(j, log.description, duration, [])
    chose = ""
    if model == "auto":
        picked, chose = choose_model(_kinds(log), craft)
        if picked is None:
            j = write_triage_only(out, path, log.description, tr, used, cut, f"Not diagnosed: {chose}.", craft)
            say(f"not diagnosed: {chose}; the triage is in {out / 'report.json'}")
            return LogDiagnosis(j, log.description, duration, [])
        model = picked
        say(f"model: {chose}")
    j, suggestions = _diagnosed(
        path, out, log, tr, ms, used, cut, craft, model, chose, declared, vehicle, truth_csv, veto_with_truth,
        progress, workers,
    )  # fmt: skip
    files = _param_files(out, suggestions, path)
    if progress is not None:
        progress("done")
    say(j["conclusion"])
    settable = [p for p in suggestions if p.name and p.value is not None]
    if settable:
        say("parameters to set: " + "; ".join(f"{p.autopilot} {p.name} = {p.value:g}" for p in settable))
    say(
        f"report: {out / 'report.html'} and report.json; estimates_before.csv, estimates_after.csv"
        + (f"; {', '.join(files)}" if files else "")
    )
    return LogDiagnosis(j, log.description, duration, files)


def _diagnosed(
    path: Path,
    out: Path,
    log: LoadedLog,
    tr: Triage,
    ms,
    used: list[tuple[float, float]],
    cut: list[dict],
    craft: Vehicle,
    model: str,
    chose: str,
    declared: list | None,
    vehicle: str | None,
    truth_csv: Path | None,
    veto_with_truth: bool,
    progress: Callable[[str], None] | None,
    workers: int,
) -> tuple[dict, list[ParamSuggestion]]:
    """The usable readings ``ms`` diagnosed with ``model`` and the report written: report.json's
    content, and the parameters to set (none where the model does not describe the vehicle)."""
    ms_all = log.measurements
    describes = craft.describes(model) or craft.kind == "unknown"
    drawn: list[report.Drawn] = []  # the report's CSVs and figures, made while the left-out runs go

    # the rotors' notch read from the IMU's spectrum (a Crazyflie's firmware takes neither ArduPilot's nor PX4's
    # parameters): with cores to spare on the one the log's preparation leaves idle; else here, now, while the log
    # still holds its raw IMU (the diagnosis takes it out)
    def notch_of(_none: None = None) -> list[ParamSuggestion]:
        return suggest_notch(ms, log.tables.autopilot, _usable_imu(log, tr, keep=True))

    takes_params = log.tables.fmt != "crazyflie"
    notch = Begun(notch_of, [None], 1) if takes_params and workers > 1 else None
    notch_here = notch_of() if takes_params and notch is None else []
    try:
        d = diagnose(
            ms,
            source=str(path),
            model_name=model,
            declared=declared or [],
            vehicle=vehicle or log.vehicle,
            truth=truth_from(ms, path, truth_csv),
            progress=progress,
            veto_with_truth=veto_with_truth,
            workers=workers,
            imu=_usable_imu(log, tr, keep=False),
            stated=stated_by(log.tables, ms_all),
            meanwhile=lambda before, after: drawn.append(report.draw(before, after, out)),
        )
        suggestions = []
        if takes_params and describes:
            suggestions = suggest(d, ms, log.tables.params, log.tables.autopilot)
            suggestions += notch.results()[0] if notch is not None else notch_here
    finally:
        if notch is not None:
            notch.close()
    j = report.write(
        d,
        out,
        triage=tr,
        used=used,
        cut=cut,
        parameters=suggestions,
        vehicle=craft,
        model_chosen=chose,
        not_described=None if describes else craft.why_not(model),
        drawn=drawn[-1] if drawn else None,
    )
    return j, suggestions


HEIGHT_KINDS = frozenset({Kind.BARO_PRESSURE, Kind.BARO_ALTITUDE, Kind.GPS, Kind.RANGE})


def is_rig_session(log: LoadedLog) -> bool:
    """A 3-DOF rig's session: its board's encoders, or over MAVLink a helicopter that sends its
    angles and motor outputs and has no height sensor at all (nothing that flies logs none)."""
    kinds = _kinds(log)
    if Kind.ENCODERS in kinds:
        return True
    return (
        vehicle_of(log).kind == "helicopter"
        and not kinds & HEIGHT_KINDS
        and Kind.ATTITUDE in kinds
        and bool(kinds & {Kind.ACTUATOR, Kind.MOTOR_VOLTAGE})
    )


def _rig(
    path: Path,
    out: Path,
    log: LoadedLog,
    duration: float,
    vehicle: str | None,
    progress: Callable[[str], None] | None,
    say: Callable[[str], None],
) -> LogDiagnosis:
    """A 3-DOF helicopter session: the rig's own diagnosis (:mod:`.rig`), from the lab's model or
    from the vehicle file's constants of this rig."""
    craft, kinds = vehicle_of(log), _kinds(log)
    flies = kinds & HEIGHT_KINDS
    if Kind.ENCODERS not in kinds and (craft.kind not in ("helicopter", "unknown") or flies):
        what = f"a {craft.name} ({craft.evidence} says so)" + (
            ", with a barometer, GPS or rangefinder" if flies else ""
        )
        raise ValueError(
            f"this log was written by {what}: the 3-DOF rig's diagnosis reads a rig's encoders (its ENCODERS, "
            "or the ATTITUDE of a rig that reports itself a helicopter and has no height sensor)"
        )
    rig = vehicle_config(vehicle, "heli3dof").get("rig") if vehicle else None
    start = Heli3dofRig.from_vehicle(rig) if isinstance(rig, dict) else None
    d = diagnose_rig(log.measurements, log.imu, start=start, source=str(path), progress=progress)
    j = rig_report.write(d, out, str(path), log.description)
    if progress is not None:
        progress("done")
    say(j["conclusion"])
    say(f"report: {out / 'report.html'} and report.json; the rig's constants: {out / rig_report.RIG_FILE}")
    return LogDiagnosis(j, log.description, duration, [rig_report.RIG_FILE])


def _param_files(out: Path, suggestions: list[ParamSuggestion], path: Path) -> list[str]:
    """Each autopilot's parameter file of what to set, written where it has something to set (an old
    one of a diagnosis before taken away); the names written."""
    files = []
    for autopilot, name in (("ArduPilot", "params_ardupilot.param"), ("PX4", "params_px4.params")):
        if write_param_file(out / name, suggestions, autopilot, str(path)):
            files.append(name)
        else:
            (out / name).unlink(missing_ok=True)
    return files


def _usable_imu(log: LoadedLog, tr: Triage, *, keep: bool) -> ImuColumns | None:
    """The log's raw IMU outside the triage's cuts; without ``keep``, taken out of ``log``, so that
    once the diagnosis has averaged it into blocks nothing holds it (a 1-hour 1 kHz log's columns
    are 0.3 GB)."""
    imu = log.imu
    if not keep:
        log.imu = None
    return usable_imu(imu, tr) if imu is not None else None


def vehicle_of(log: LoadedLog) -> Vehicle:
    """What wrote the log (:func:`~groundstation.estimation.identity.identify`); a session of the 3-DOF
    rig by its encoders, which no flying vehicle logs."""
    if Kind.ENCODERS in _kinds(log):
        return Vehicle("rig", "3-DOF lab helicopter rig", "encoder readings")
    return identify(log.tables)


def _kinds(log: LoadedLog) -> set[Kind]:
    """The kinds of reading the log holds, its IMU columns' included."""
    ms = log.measurements
    kinds = ms.kinds() if hasattr(ms, "kinds") else {m.kind for m in ms}
    if log.imu is not None:
        kinds |= {k for k, _ in log.imu.series}
    return set(kinds)


def write_triage_only(
    out: Path, source: Path, description: str, tr: Triage, used, cut, why: str, vehicle: Vehicle | None = None
) -> dict:
    """report.json and report.html with the triage alone, and ``why`` nothing was fitted."""
    j = {
        "source": str(source),
        "description": description,
        "vehicle_type": vehicle.as_dict() if vehicle is not None else None,
        "triage": tr.as_json(),
        "triage_clock": tr.clock,
        "segments_used": [{"t_start": a, "t_end": b} for a, b in used],
        "segments_cut": cut,
        "effects": [],
        "parameters": [],
        "conclusion": triage_headline(tr, used, cut) + why,
    }
    (out / "report.json").write_text(json.dumps(j, indent=2))
    (out / "report.html").write_text(
        f"<!doctype html><html><head><meta charset='utf-8'><title>triage: {html.escape(str(source))}</title></head>"
        f"<body><h1>Triage of {html.escape(str(source))}</h1><p>{html.escape(j['conclusion'])}</p>"
        f"<pre>{html.escape(tr.summary(limit=1000))}</pre></body></html>"
    )
    return j
