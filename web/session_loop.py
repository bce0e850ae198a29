"""The session's event loop, for work the dashboard's panels hand it.

viser awaits a GUI callback on its own event loop, in its server's thread, not on the loop the
session runs on (the link, the commander, the estimators). A command sent from there touched the
link's asyncio objects from another thread. The panels hand such work to :meth:`SessionLoop.call`,
which runs it on the session's loop and waits there for its result (as
``asyncio.run_coroutine_threadsafe`` is meant to be used), or runs it in place when the caller is
already on that loop (a test driving a panel directly).
"""

from __future__ import annotations

import asyncio
import inspect
from collections.abc import Callable
from typing import Any


class SessionLoop:
    def __init__(self) -> None:
        self.loop: asyncio.AbstractEventLoop | None = None

    def bind(self) -> None:
        """Take the running loop as the session's (called on it)."""
        self.loop = asyncio.get_running_loop()

    def bind_if_running(self) -> None:
        """As :meth:`bind`, where a loop is running and none is bound yet."""
        if self.loop is None:
            try:
                self.loop = asyncio.get_running_loop()
            except RuntimeError:
                pass

    async def call(self, fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)`` (awaited if it is a coroutine function) on the session's loop; its result."""
        try:
            here = asyncio.get_running_loop()
        except RuntimeError:
            here = None
        if self.loop is None or self.loop is here or self.loop.is_closed():
            out = fn(*args)
            return await out if inspect.isawaitable(out) else out

        async def on_session() -> Any:
            out = fn(*args)
            return await out if inspect.isawaitable(out) else out

        return await asyncio.wrap_future(asyncio.run_coroutine_threadsafe(on_session(), self.loop))
