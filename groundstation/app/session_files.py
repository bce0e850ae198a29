"""The files a session records into when the user names none: one per run, never shared."""

from __future__ import annotations

import contextlib
import datetime as _dt
from pathlib import Path


def fresh_path(p: Path) -> Path:
    """``p``, or ``p`` with ``-2``, ``-3``, ... before the suffix when a file of that name exists:
    created here, empty, exclusively, so that two runs started in the same second (two vehicles'
    sessions, two demos) never take the same name and interleave their records in one tlog, which
    the recorder appends to."""
    p.parent.mkdir(parents=True, exist_ok=True)
    candidate, n = p, 1
    while True:
        try:
            with open(candidate, "x"):
                return candidate
        except FileExistsError:
            n += 1
            candidate = p.with_name(f"{p.stem}-{n}{p.suffix}")


def session_path(folder: str, prefix: str = "") -> Path:
    """A fresh ``folder/PREFIXyyyymmdd-HHMMSS.tlog`` for a session begun now (:func:`fresh_path`)."""
    return fresh_path(Path(folder) / f"{prefix}{_dt.datetime.now():%Y%m%d-%H%M%S}.tlog")


def discard_if_empty(p: Path) -> None:
    """Remove ``p`` if it holds nothing (a fresh file whose session never began), and its folder if
    that is then empty: a connection that failed leaves no trace."""
    with contextlib.suppress(OSError):  # not there, not empty, or not ours to remove: left as it is
        if p.stat().st_size == 0:
            p.unlink()
            p.parent.rmdir()
