"""A request-and-answer exchange with one vehicle over a link: what the parameter and log clients
share. The subclass's ``_on_message`` sees every message the link decodes (it is one of the link's
``message_hooks`` until :meth:`close`) and calls :meth:`_changed_now` when something it waits on
came; :meth:`_wait_change` waits for that, or a timeout."""

from __future__ import annotations

import abc
import asyncio


class Exchange(abc.ABC):
    def __init__(self, link, sysid: int, compid: int = 1, *, timeout: float = 1.0) -> None:
        self.link = link
        self.sysid, self.compid = sysid, compid
        self.timeout = timeout
        self._changed = asyncio.Event()
        link.message_hooks.append(self._on_message)

    def close(self) -> None:
        if self._on_message in self.link.message_hooks:
            self.link.message_hooks.remove(self._on_message)

    @abc.abstractmethod
    def _on_message(self, m, _t_rx: float) -> None:
        """Take what this exchange waits on from the link's message ``m``; :meth:`_changed_now` if it came."""

    def _changed_now(self) -> None:
        self._changed.set()

    async def _wait_change(self, timeout: float) -> bool:
        """Whether an answer came within ``timeout`` [s] of this call."""
        self._changed.clear()
        try:
            await asyncio.wait_for(self._changed.wait(), timeout)
            return True
        except TimeoutError:
            return False
