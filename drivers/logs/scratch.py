"""Scratch copies of a damaged log, for the third-party readers that take only a file name
(pymavlink's DFReader maps the file it is given).

A reader that cleans a damaged log writes the cleaned copy here and deletes it when done; a process
killed in between (a fleet worker out of memory, a Ctrl-C at the wrong instant) cannot, so each
process writes into a folder named by its PID, and every new scratch copy first removes the
folders of processes that are no longer running.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

PREFIX = "groundstation-scratch-"


def _root() -> Path:
    return Path(tempfile.gettempdir())


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        return True
    return True


def clean_stale() -> int:
    """Remove the scratch folders of processes no longer running; how many were removed."""
    n = 0
    for d in _root().glob(PREFIX + "*"):
        try:
            pid = int(d.name[len(PREFIX) :])
        except ValueError:
            continue
        if pid != os.getpid() and not _alive(pid):
            shutil.rmtree(d, ignore_errors=True)
            n += 1
    return n


@contextlib.contextmanager
def scratch_copy(data: bytes, suffix: str) -> Iterator[Path]:
    """``data`` written to a scratch file for as long as the block runs, then removed."""
    clean_stale()
    folder = _root() / f"{PREFIX}{os.getpid()}"
    folder.mkdir(exist_ok=True)
    fd, name = tempfile.mkstemp(suffix=suffix, dir=folder)
    path = Path(name)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        yield path
    finally:
        path.unlink(missing_ok=True)
