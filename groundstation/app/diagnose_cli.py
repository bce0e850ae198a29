"""``groundstation diagnose LOG [--model NAME] [--out DIR]``: the closed loop from the command line,
after the triage (what the log says happened; the stretches the model does not hold in are cut), with
the effects found translated into autopilot parameters; ``groundstation triage LOG``: the triage alone."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from groundstation.diagnosis import pipeline
from groundstation.estimation.vehicles import declared_beside, declared_effects


class Progress:
    """A one-line progress bar on a terminal; plain lines otherwise."""

    def __init__(self, total_hint: int = 12) -> None:
        self.tty = sys.stderr.isatty()
        self.n, self.total, self.t0 = 0, total_hint, time.monotonic()
        self.open = False  # the bar's line is on the terminal, unfinished

    def __call__(self, what: str) -> None:
        self.n += 1
        if self.tty:
            self.open = True
            k = min(self.n, self.total)
            bar = "#" * (20 * k // self.total) + "." * (20 - 20 * k // self.total)
            print(
                f"\r[{bar}] {time.monotonic() - self.t0:5.1f} s  {what[:50]:<50}", end="", file=sys.stderr, flush=True
            )
        elif what.startswith(("added", "rejected")):
            print(f"  {what}", file=sys.stderr, flush=True)

    def done(self) -> None:
        if self.open:
            print(file=sys.stderr)
            self.open = False


def writable_folder(out: Path) -> bool:
    """Make ``out`` and check that files can be written in it, before minutes of analysis: one
    line of error (OSError, as the command line reports it) if not. Returns whether it made it."""
    made = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".groundstation-write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise OSError(f"{out}: cannot write the report there: {e.strerror or e}") from None
    return made


def cmd_diagnose(args) -> int:
    out = args.out or args.file.with_name(args.file.name + ".diagnosis")
    if not args.file.exists():
        raise OSError(f"{args.file}: cannot read: no such file")
    made = writable_folder(out)
    bar = Progress()

    def say(line: str) -> None:
        bar.done()  # the bar's line ends before the next line is printed
        print(line, flush=True)

    try:
        pipeline.run(
            args.file,
            out,
            model=args.model,
            declared=declared_effects(args.declared or declared_beside(args.file)),
            vehicle=args.vehicle,
            truth_csv=args.truth,
            veto_with_truth=not args.no_truth_veto,
            progress=bar,
            say=say,
            workers=args.jobs,
        )
    except BaseException:
        if made and not any(out.iterdir()):
            out.rmdir()  # a log that could not be diagnosed leaves no empty report folder beside it
        raise
    return 0
