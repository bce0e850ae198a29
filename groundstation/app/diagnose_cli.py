"""``groundstation diagnose LOG [--model NAME] [--out DIR]``: the closed loop from the command line,
after the triage (what the log says happened; the stretches the model does not hold in are cut), with
the effects found translated into autopilot parameters; ``groundstation triage LOG``: the triage alone."""

from __future__ import annotations

import html
import json
import sys
import time
from pathlib import Path

from groundstation.diagnosis import report
from groundstation.diagnosis.autopilot_params import suggest, suggest_notch, write_param_file
from groundstation.diagnosis.engine import diagnose, truth_from
from groundstation.diagnosis.models import DIAGNOSABLE
from groundstation.diagnosis.report import triage_headline
from groundstation.diagnosis.triage import Triage, triage, usable
from groundstation.estimation.logs import load_log
from groundstation.estimation.vehicles import declared_beside, declared_effects


def add_parser(sub) -> None:
    d = sub.add_parser("diagnose", help="find the effects the model lacks, add them, report before/after")
    d.add_argument("file", type=Path)
    d.add_argument(
        "--model",
        default="altitude",
        choices=tuple(DIAGNOSABLE),
        help="; ".join(f"{name}: {spec.help}" for name, spec in DIAGNOSABLE.items()) + " (default altitude)",
    )
    d.add_argument("--out", type=Path, help="report directory (default: LOG.diagnosis/)")
    d.add_argument("--declared", type=Path, help="effects the model is told of (default: LOG.declared.json)")
    d.add_argument(
        "--vehicle",
        help="vehicle parameter file for the noise (its known effects are NOT applied: finding them is the point)",
    )
    d.add_argument(
        "--truth",
        type=Path,
        help="truth CSV (t, h) for the error before/after (default: LOG.csv "
        "when it is a simulator sidecar; motion capture in the log is used)",
    )
    d.add_argument(
        "--no-truth-veto",
        action="store_true",
        help="keep an effect even when its fix makes the error against truth worse (default: rejected)",
    )


def add_triage_parser(sub) -> None:
    t = sub.add_parser(
        "triage", help="what the log says happened (crash, failsafes, vibration, motors, EKF), in seconds"
    )
    t.add_argument("file", type=Path)
    t.add_argument("--json", action="store_true", help="the findings as JSON on stdout")


def cmd_triage(args) -> int:
    if not args.file.exists():
        raise OSError(f"{args.file}: cannot read: no such file")
    log = load_log(args.file)
    tr = triage(log.tables, log.measurements)
    if args.json:
        print(json.dumps({"source": str(args.file), "clock": tr.clock, "findings": tr.as_json()}, indent=2))
        return 0
    print(f"{args.file}: {log.description}")
    print(tr.summary(limit=1000))
    return 0


class Progress:
    """A one-line progress bar on a terminal; plain lines otherwise."""

    def __init__(self, total_hint: int = 12) -> None:
        self.tty = sys.stderr.isatty()
        self.n, self.total, self.t0 = 0, total_hint, time.monotonic()

    def __call__(self, what: str) -> None:
        self.n += 1
        if self.tty:
            k = min(self.n, self.total)
            bar = "#" * (20 * k // self.total) + "." * (20 - 20 * k // self.total)
            print(
                f"\r[{bar}] {time.monotonic() - self.t0:5.1f} s  {what[:50]:<50}", end="", file=sys.stderr, flush=True
            )
        elif what.startswith(("added", "rejected")):
            print(f"  {what}", file=sys.stderr, flush=True)

    def done(self) -> None:
        if self.tty:
            print(file=sys.stderr)


def writable_folder(out: Path) -> None:
    """Make ``out`` and check that files can be written in it, before minutes of analysis: one
    line of error (OSError, as the command line reports it) if not."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".groundstation-write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise OSError(f"{out}: cannot write the report there: {e.strerror or e}") from None


#: the least of a log the fit is run on, after the triage's cuts [s]
MIN_FIT_SECONDS = 10.0


def cmd_diagnose(args) -> int:
    out = args.out or args.file.with_name(args.file.name + ".diagnosis")
    if not args.file.exists():
        raise OSError(f"{args.file}: cannot read: no such file")
    writable_folder(out)
    log = load_log(args.file)
    declared = declared_effects(args.declared or declared_beside(args.file))
    print(f"diagnosing {args.file}: {log.description}", flush=True)
    tr = triage(log.tables, log.measurements)
    print(tr.summary(), flush=True)
    ms, used, cut = usable(log.measurements, tr)
    if cut:
        spans = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in used) or "nothing"
        print(f"fitting the model to {spans}: {len(cut)} stretch(es) cut (report.json: segments_cut)", flush=True)
    fit_seconds = sum(b - a for a, b in used)
    if cut and fit_seconds < MIN_FIT_SECONDS:  # (a log short in itself is the engine's one-line error)
        write_triage_only(out, args.file, log.description, tr, used, cut)
        print(
            f"not fitted: {fit_seconds:.1f} s of the log is usable (at least {MIN_FIT_SECONDS:.0f} s needed); "
            f"the triage is in {out / 'report.json'}"
        )
        return 0
    bar = Progress()
    d = diagnose(
        ms,
        source=str(args.file),
        model_name=args.model,
        declared=declared,
        vehicle=args.vehicle or log.vehicle,
        truth=truth_from(ms, args.file, args.truth),
        progress=bar,
        veto_with_truth=not args.no_truth_veto,
    )
    bar.done()
    suggestions = []
    if log.tables.fmt != "crazyflie":  # its firmware takes neither ArduPilot's nor PX4's parameters
        suggestions = suggest(d, ms, log.tables.params, log.tables.autopilot) + suggest_notch(ms, log.tables.autopilot)
    j = report.write(d, out, triage=tr, used=used, cut=cut, parameters=suggestions)
    files = []
    for autopilot, name in (("ArduPilot", "params_ardupilot.param"), ("PX4", "params_px4.params")):
        if write_param_file(out / name, suggestions, autopilot, str(args.file)):
            files.append(name)
        else:
            (out / name).unlink(missing_ok=True)
    print(j["conclusion"])
    settable = [p for p in suggestions if p.name and p.value is not None]
    if settable:
        print("parameters to set: " + "; ".join(f"{p.autopilot} {p.name} = {p.value:g}" for p in settable))
    print(
        f"report: {out / 'report.html'} and report.json; estimates_before.csv, estimates_after.csv"
        + (f"; {', '.join(files)}" if files else "")
    )
    return 0


def write_triage_only(out: Path, source: Path, description: str, tr: Triage, used, cut) -> None:
    """report.json and report.html with the triage alone (nothing left to fit)."""
    j = {
        "source": str(source),
        "description": description,
        "triage": tr.as_json(),
        "triage_clock": tr.clock,
        "segments_used": [{"t_start": a, "t_end": b} for a, b in used],
        "segments_cut": cut,
        "parameters": [],
        "conclusion": triage_headline(tr, used, cut) + "Too little of the log is usable to fit the model.",
    }
    (out / "report.json").write_text(json.dumps(j, indent=2))
    (out / "report.html").write_text(
        f"<!doctype html><html><head><meta charset='utf-8'><title>triage: {html.escape(str(source))}</title></head>"
        f"<body><h1>Triage of {html.escape(str(source))}</h1><p>{html.escape(j['conclusion'])}</p>"
        f"<pre>{html.escape(tr.summary(limit=1000))}</pre></body></html>"
    )
