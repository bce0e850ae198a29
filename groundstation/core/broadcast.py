"""Fan-out of a stream to independent, bounded subscribers.

The producer never waits: each subscriber has its own bounded buffer, and a
subscriber that falls behind loses its *oldest* items (counted in
``dropped``), never the producer's time or another subscriber's items. This is
how the estimation loop feeds the dashboard, the recorder and exporters.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import AsyncIterator, Callable, Iterable
from typing import Generic, TypeVar

T = TypeVar("T")

_CLOSED = object()


class Subscription(Generic[T]):
    """One subscriber's bounded buffer.

    ``lossy`` subscribers (a dashboard) lose their oldest items when full.
    Lossless ones (an exporter) are waited for by producers that can wait
    (:meth:`Broadcast.wait_for_space`, used by replays); a live link cannot
    wait, so there they lose items too, counted in ``dropped``.
    """

    def __init__(
        self, owner: Broadcast[T], maxlen: int, lossy: bool, accept: Callable[[T], bool] | None = None
    ) -> None:
        """``accept``: the items this subscriber wants (None: all)."""
        self._owner = owner
        self._accept = accept
        self._buf: deque = deque(maxlen=maxlen)
        self._maxlen = maxlen
        self._event = asyncio.Event()
        self._space = asyncio.Event()
        self.lossy = lossy
        self.dropped = 0
        self._closed = False

    @property
    def backlog(self) -> int:
        return len(self._buf)

    def _push(self, item) -> None:
        if self._accept is not None and not self._accept(item):
            return
        buf = self._buf
        if len(buf) == buf.maxlen:
            self.dropped += 1
        buf.append(item)
        self._event.set()

    def _push_many(self, items: list) -> None:
        if self._accept is not None:
            items = [x for x in items if self._accept(x)]
            if not items:
                return
        buf = self._buf
        over = len(buf) + len(items) - self._maxlen
        if over > 0:
            self.dropped += over
        buf.extend(items)
        self._event.set()

    def __aiter__(self) -> AsyncIterator[T]:
        return self

    async def __anext__(self) -> T:
        buf = self._buf
        while not buf:
            if self._closed:
                raise StopAsyncIteration
            self._event.clear()
            await self._event.wait()
        item = buf.popleft()
        if len(buf) < self._maxlen // 2:
            self._space.set()
        if item is _CLOSED:
            self._closed = True
            raise StopAsyncIteration
        return item

    async def batches(self) -> AsyncIterator[list[T]]:
        """``async for`` over everything buffered, one list per turn: the consumer yields the event
        loop between lists (iterating item by item never yields while the buffer holds any, so a
        backlog starved every other task)."""
        while True:
            while not self._buf:
                if self._closed:
                    return
                self._event.clear()
                await self._event.wait()
            items = self.get_nowait()
            if items:
                yield items
            if self._closed:
                return
            await asyncio.sleep(0)

    def get_nowait(self) -> list[T]:
        """Everything buffered now (for consumers that poll at their own rate)."""
        if not self._buf:  # (whoever emptied it set the space: a replay polls after every reading)
            return []
        items = [x for x in self._buf if x is not _CLOSED]
        if len(items) != len(self._buf):
            self._closed = True
        self._buf.clear()
        self._space.set()
        return items

    def close(self) -> None:
        self._owner._subs.discard(self)
        self._closed = True
        self._event.set()
        self._space.set()


class Broadcast(Generic[T]):
    def __init__(self, maxlen: int = 100_000) -> None:
        self.maxlen = maxlen
        self._subs: set[Subscription[T]] = set()
        self.closed = False

    def subscribe(
        self, maxlen: int | None = None, *, lossy: bool = False, accept: Callable[[T], bool] | None = None
    ) -> Subscription[T]:
        """A new subscriber; ``accept``: the items it wants (None: all)."""
        s: Subscription[T] = Subscription(self, maxlen or self.maxlen, lossy, accept)
        if self.closed:
            s._closed = True
        self._subs.add(s)
        return s

    def publish(self, item: T) -> None:
        for s in self._subs:
            s._push(item)

    def publish_many(self, items: Iterable[T]) -> None:
        items = list(items)
        if items:
            for s in self._subs:
                s._push_many(items)

    def needs_wait(self) -> bool:
        """True if a lossless subscriber's buffer is more than half full."""
        for s in self._subs:
            if not s.lossy and not s._closed and len(s._buf) > s._maxlen // 2:
                return True
        return False

    async def wait_for_space(self) -> None:
        """Wait until every lossless subscriber's buffer is at most half full."""
        for s in list(self._subs):
            while not s.lossy and not s._closed and len(s._buf) > s._maxlen // 2:
                s._space.clear()
                await s._space.wait()

    @property
    def dropped(self) -> int:
        return sum(s.dropped for s in self._subs)

    def close(self) -> None:
        """End every subscriber's iteration once it has drained its buffer."""
        self.closed = True
        for s in self._subs:
            s._buf.append(_CLOSED)
            s._event.set()
