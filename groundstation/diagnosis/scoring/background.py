"""Runs begun early on the cores the diagnosis leaves idle, collected when their numbers are needed.

Between its parallel stretches a diagnosis runs one filter at a time (the ranking's base run, an
effect taken, the report), and on two cores one of them waits. Runs that need only what is already
known (each sensor left out of the model before, :mod:`~groundstation.diagnosis.claims.leave_one_out`)
can go there: :class:`Begun` forks a process for each at a lower priority (``os.nice``), so that it
takes a core the diagnosis leaves idle and yields to the diagnosis's own runs on a busy one.
Collected, each is the same run, number for number, as it is made here with one worker.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterable
from typing import Generic, TypeVar

from threadpoolctl import threadpool_limits

T = TypeVar("T")
R = TypeVar("R")

#: the begun processes' niceness: under load the scheduler gives them about a tenth of a core each
#: beside a process at the default priority (the kernel's weights, 110 against 1024)
NICENESS = 10


class Begun(Generic[T, R]):
    """``[fn(x) for x in items]``, begun now and collected by :meth:`results`.

    With ``workers`` > 1, one forked process an item, at :data:`NICENESS` (the processes inherit
    ``fn``, a closure over the log and the model: no pickle carries those; the results must pickle).
    With one worker nothing runs until :meth:`results`, which then makes them here, in order. An
    error in a process reaches :meth:`results` as itself; :meth:`close` stops what still runs.
    """

    def __init__(self, fn: Callable[[T], R], items: Iterable[T], workers: int) -> None:
        self._fn: Callable[[T], R] = fn
        self._items: list[T] = list(items)
        self._running: list[tuple] = []  # (process, its pipe's reading end), an item each
        if workers <= 1 or not self._items:
            return
        ctx = multiprocessing.get_context("fork")
        # one BLAS thread in the children, as trials.fork_map (OpenBLAS's pool does not survive a fork)
        with threadpool_limits(limits=1, user_api="blas"):
            for item in self._items:
                recv, send = ctx.Pipe(duplex=False)
                proc = ctx.Process(target=self._work, args=(item, send), daemon=True)
                proc.start()
                send.close()
                self._running.append((proc, recv))

    def _work(self, item: T, send) -> None:
        """In the child: at a lower priority, the item's result sent back (or the error that stopped it)."""
        os.nice(NICENESS)
        try:
            out: object = self._fn(item)
        except BaseException as e:  # noqa: BLE001 -- carried to the parent, raised there
            out = e
        send.send(out)
        send.close()

    def results(self) -> list[R]:
        """Each item's result, in order (waiting for those still running)."""
        if not self._running:
            return [self._fn(x) for x in self._items]
        out: list[R] = []
        try:
            while self._running:
                proc, recv = self._running.pop(0)
                try:
                    got = recv.recv()
                except EOFError:
                    raise RuntimeError("a run begun on a forked process ended without its result") from None
                finally:
                    recv.close()
                    proc.join()
                if isinstance(got, BaseException):
                    raise got
                out.append(got)
        finally:
            self.close()
        return out

    def close(self) -> None:
        """Stop whatever still runs (its results no longer wanted, or an error came first)."""
        while self._running:
            proc, recv = self._running.pop()
            if proc.is_alive():
                proc.terminate()
            proc.join()
            recv.close()
