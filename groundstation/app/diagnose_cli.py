"""``groundstation diagnose LOG [--model NAME] [--out DIR]``: the closed loop from the command line."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from groundstation.diagnosis import report
from groundstation.diagnosis.engine import diagnose, truth_from
from groundstation.diagnosis.models import DIAGNOSABLE
from groundstation.estimation.logs import load_measurements
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


def cmd_diagnose(args) -> int:
    out = args.out or args.file.with_name(args.file.name + ".diagnosis")
    if not args.file.exists():
        raise OSError(f"{args.file}: cannot read: no such file")
    writable_folder(out)
    ms, desc, vehicle = load_measurements(args.file)
    declared = declared_effects(args.declared or declared_beside(args.file))
    print(f"diagnosing {args.file}: {desc}", flush=True)
    bar = Progress()
    d = diagnose(
        ms,
        source=str(args.file),
        model_name=args.model,
        declared=declared,
        vehicle=args.vehicle or vehicle,
        truth=truth_from(ms, args.file, args.truth),
        progress=bar,
        veto_with_truth=not args.no_truth_veto,
    )
    bar.done()
    j = report.write(d, out)
    print(j["conclusion"])
    print(f"report: {out / 'report.html'} and report.json; estimates_before.csv, estimates_after.csv")
    return 0
