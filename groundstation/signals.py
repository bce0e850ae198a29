"""Clean stops on SIGINT/SIGTERM for the command line's asyncio runs."""
from __future__ import annotations

import asyncio
import signal


def on_stop_signal(callback) -> None:
    """Call ``callback`` on SIGINT/SIGTERM (a clean stop instead of a traceback)."""
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, callback)
        except (NotImplementedError, RuntimeError):
            pass
