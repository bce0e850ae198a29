"""Clean stops on SIGINT/SIGTERM for the command line's asyncio runs."""

from __future__ import annotations

import asyncio
import signal


def on_stop_signal(callback) -> bool:
    """Call ``callback`` on SIGINT/SIGTERM (a clean stop instead of a traceback).

    False where the loop cannot take signals (Windows, a thread other than the
    main one): Ctrl-C then raises KeyboardInterrupt, which ``main`` turns into
    exit status 130 after the ``finally`` blocks have closed files and links."""
    loop = asyncio.get_running_loop()
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, callback)
    except (NotImplementedError, RuntimeError):
        return False
    return True
