"""No task dies silently: each long-running task of a session is supervised.

A task that raises is reported in one line on stderr and started again; one that fails
:data:`MAX_FAILURES` times within :data:`WINDOW_S` seconds stops the session with that line
as its error (exit status 1), since restarting it is then only hiding a fault.
"""

from __future__ import annotations

import asyncio
import sys
import time
from collections.abc import Awaitable, Callable

MAX_FAILURES = 5
WINDOW_S = 10.0


class Supervisor:
    def __init__(self, stop: Callable[[], None], *, out=None) -> None:
        """``stop()`` ends the session (a stop event's ``set``, a simulator's ``close``)."""
        self.stop = stop
        self.out = out if out is not None else sys.stderr
        self.failures: dict[str, list[float]] = {}
        #: the line that stopped the session, if one did
        self.fatal: str | None = None

    def start(self, name: str, run: Callable[[], Awaitable[None]]) -> asyncio.Task:
        """Run ``run()`` as a task named ``name``, restarted when it raises."""
        return asyncio.get_running_loop().create_task(self._keep(name, run), name=name)

    async def _keep(self, name: str, run: Callable[[], Awaitable[None]]) -> None:
        while True:
            try:
                await run()
                return
            except asyncio.CancelledError:
                raise
            except Exception as e:  # noqa: BLE001 - any failure of a task is reported, none is swallowed
                now = time.monotonic()
                recent = [t for t in self.failures.get(name, []) if now - t < WINDOW_S] + [now]
                self.failures[name] = recent
                line = f"{name} failed: {type(e).__name__}: {e}"
                if len(recent) >= MAX_FAILURES:
                    self.fatal = f"{line} ({len(recent)} times in {WINDOW_S:g} s; stopping)"
                    print(f"groundstation: error: {self.fatal}", file=self.out, flush=True)
                    self.stop()
                    return
                print(f"groundstation: {line}; restarted", file=self.out, flush=True)
