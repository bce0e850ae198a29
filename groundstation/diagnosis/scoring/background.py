"""Runs begun early on the cores the diagnosis leaves idle, collected when their numbers are needed.

Between its parallel stretches a diagnosis runs one thing at a time (reading the thrust curve, the
report), and on two cores one of them waits. Runs that need only what is already known (each sensor
left out of the model, :mod:`~groundstation.diagnosis.claims.leave_one_out`) can go there:
:class:`Begun` forks processes for them at a lower priority (``os.nice``), so that they take a core
the diagnosis leaves idle and yield to the diagnosis on a busy one. Collected, each is the same run,
number for number, as it is made here with one worker.
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

    With ``workers`` > 1, up to ``workers`` forked processes at :data:`NICENESS`, each making its share
    of the items one after another (so that no more runs are held at once than ``workers``, as
    :func:`.trials.fork_map` holds them); the processes inherit ``fn``, a closure over the log and the
    model (no pickle carries those), and the results must pickle. With one worker nothing runs until
    :meth:`results`, which then makes them here, in order. An error in a process reaches
    :meth:`results` as itself; :meth:`close` stops what still runs.
    """

    def __init__(self, fn: Callable[[T], R], items: Iterable[T], workers: int) -> None:
        self._fn: Callable[[T], R] = fn
        self._items: list[T] = list(items)
        self._running: list[tuple] = []  # (process, its pipe's reading end), a share each
        if workers <= 1 or not self._items:
            return
        n = min(workers, len(self._items))
        ctx = multiprocessing.get_context("fork")
        # one BLAS thread in the children, as trials.fork_map (OpenBLAS's pool does not survive a fork)
        with threadpool_limits(limits=1, user_api="blas"):
            for k in range(n):
                recv, send = ctx.Pipe(duplex=False)
                proc = ctx.Process(target=self._work, args=(self._items[k::n], send), daemon=True)
                proc.start()
                send.close()
                self._running.append((proc, recv))

    def _work(self, share: list[T], send) -> None:
        """In the child: at a lower priority, its share's results sent back (or the error that stopped it)."""
        os.nice(NICENESS)
        try:
            out: object = [self._fn(x) for x in share]
        except BaseException as e:  # noqa: BLE001 -- carried to the parent, raised there
            out = e
        send.send(out)
        send.close()

    def results(self) -> list[R]:
        """Each item's result, in order (waiting for those still running)."""
        if not self._running:
            return [self._fn(x) for x in self._items]
        n = len(self._running)
        out: list = [None] * len(self._items)
        try:
            for k in range(n):
                proc, recv = self._running[0]
                try:
                    got = recv.recv()
                except EOFError:
                    raise RuntimeError("a run begun on a forked process ended without its result") from None
                finally:
                    self._running.pop(0)
                    recv.close()
                    proc.join()
                if isinstance(got, BaseException):
                    raise got
                out[k::n] = got
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
