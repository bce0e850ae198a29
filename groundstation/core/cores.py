"""The cores this process may run on."""

from __future__ import annotations

import os


def available_cores() -> int:
    """The cores this process may run on (a container's or a ``taskset``'s share, not the machine's)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1
