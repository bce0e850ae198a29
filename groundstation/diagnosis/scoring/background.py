"""Runs begun early on the cores the diagnosis leaves idle, collected when their numbers are needed.

Between its parallel stretches a diagnosis runs one thing at a time (reading the thrust curve, the
report), and on two cores one of them waits. Runs that need only what is already known (each sensor
left out of the model, :mod:`~groundstation.diagnosis.claims.leave_one_out`) can go there:
:class:`Begun` forks processes for them at a lower priority (``os.nice``), so that they take a core
the diagnosis leaves idle and yield to the diagnosis on a busy one. Collected, each is the same run,
number for number, as it is made here with one worker.

A forked process holds every page its parent had at the fork, for as long as it lives: the parent's
pages it later frees or rewrites are then the child's alone, and count twice. A process forked
late in a diagnosis, from a heap of runs and rankings, costs that much memory. So :class:`Begun` can
fork *held*: early, while the heap holds little more than the log, with the runs' last few inputs
(a handful of numbers) sent when they are known (:meth:`Begun.go`).
"""

from __future__ import annotations

import gc
import multiprocessing
import os
from collections.abc import Callable, Iterable
from typing import Any, Generic, TypeVar

from threadpoolctl import threadpool_limits

T = TypeVar("T")
R = TypeVar("R")

#: the begun processes' niceness: under load the scheduler gives them about a tenth of a core each
#: beside a process at the default priority (the kernel's weights, 110 against 1024)
NICENESS = 10
#: [s] how often a held process, not yet started, looks whether its parent is still there
PARENT_CHECK_S = 0.5


class Begun(Generic[T, R]):
    """``[fn(*args, x) for x in items]``, begun now (or, ``held``, when :meth:`go` gives ``args``) and
    collected by :meth:`results`.

    Up to ``processes`` forked processes at :data:`NICENESS`, each making its share of the items one
    after another (so that no more runs are held at once than that, as :func:`.trials.fork_map` holds
    them); the processes inherit ``fn``, a closure over the log and the model (no pickle carries
    those); ``args`` and the results must pickle. With none, nothing runs until :meth:`results`, which
    then makes them here, in order. An error in a process reaches :meth:`results` as itself;
    :meth:`close` stops what still runs (a held process too).
    """

    def __init__(self, fn: Callable[..., R], items: Iterable[T], processes: int, *, held: bool = False) -> None:
        self._fn: Callable[..., R] = fn
        self._items: list[T] = list(items)
        self._args: tuple | None = None if held else ()
        self._running: list[tuple[Any, Any, Any]] = []  # (process, its results' pipe, its go pipe), a share each
        if processes < 1 or not self._items:
            return
        n = min(processes, len(self._items))
        ctx = multiprocessing.get_context("fork")
        # one BLAS thread in the children, as trials.fork_map (OpenBLAS's pool does not survive a fork);
        # the objects there are now out of the children's garbage collection, which would otherwise
        # write to (and so copy) every page of the parent's they hold
        gc.freeze()
        try:
            with threadpool_limits(limits=1, user_api="blas"):
                for k in range(n):
                    recv, send = ctx.Pipe(duplex=False)
                    go_recv, go_send = ctx.Pipe(duplex=False) if held else (None, None)
                    proc = ctx.Process(
                        target=self._work, args=(self._items[k::n], send, go_recv, os.getpid()), daemon=True
                    )
                    proc.start()
                    send.close()
                    if go_recv is not None:
                        go_recv.close()
                    self._running.append((proc, recv, go_send))
        finally:
            gc.unfreeze()

    def go(self, *args: Any) -> None:
        """A held one's runs started, each ``fn(*args, x)``."""
        if self._args is not None:
            raise RuntimeError("these runs were started already")
        self._args = args
        for _, _, go in self._running:
            go.send(args)
            go.close()

    def _work(self, share: list[T], send, go, parent: int) -> None:
        """In the child: at a lower priority, its share's results sent back (or the error that stopped it)."""
        os.nice(NICENESS)
        try:
            if go is not None:
                # held: until started, or until the parent is gone (killed, it closed nothing: the
                # pipe's other end lives on in the processes forked beside this one)
                while not go.poll(PARENT_CHECK_S):
                    if os.getppid() != parent:
                        return
            args = go.recv() if go is not None else ()
            out: object = [self._fn(*args, x) for x in share]
        except EOFError:
            return  # held, and never started: the parent let go of the runs
        except BaseException as e:  # noqa: BLE001 -- carried to the parent, raised there
            out = e
        send.send(out)
        send.close()

    def results(self) -> list[R]:
        """Each item's result, in order (waiting for those still running)."""
        if self._args is None:
            raise RuntimeError("held runs collected before they were started (Begun.go)")
        if not self._running:
            return [self._fn(*self._args, x) for x in self._items]
        n = len(self._running)
        out: list = [None] * len(self._items)
        try:
            for k in range(n):
                proc, recv, _ = self._running[0]
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
            proc, recv, go = self._running.pop()
            if proc.is_alive():
                proc.terminate()
            proc.join()
            recv.close()
            if go is not None:
                go.close()
