"""``groundstation fleet diagnose ARCHIVE_DIR --out DIR``: every log in a folder tree diagnosed on
Dask (``dask.distributed``), resumable, with one table and a fleet report (:mod:`groundstation.
diagnosis.fleet`).

A ``LocalCluster`` of worker processes by default (``--workers``, one thread each: a diagnosis is
numpy-bound, and processes keep one log's failure from touching another); ``--scheduler
tcp://HOST:PORT`` sends the logs to a cluster already running. Exit status 0 when every log was
diagnosed, 1 when some failed (each reported with its error), 2 for a usage error.
"""

from __future__ import annotations

import os
import sys
import time

from groundstation.diagnosis import fleet


class _Bar:
    """A progress line: a bar on a terminal, one line per log otherwise."""

    def __init__(self, total: int) -> None:
        self.total, self.n, self.failed, self.t0 = total, 0, 0, time.monotonic()
        self.tty = sys.stderr.isatty()

    def __call__(self, result: dict) -> None:
        self.n += 1
        self.failed += "error" in result
        what = f"{result['log']}: " + (f"failed: {result['error']}" if "error" in result else "done")
        if self.tty:
            k = 30 * self.n // max(self.total, 1)
            print(
                f"\r[{'#' * k}{'.' * (30 - k)}] {self.n}/{self.total} ({self.failed} failed) "
                f"{time.monotonic() - self.t0:6.0f} s  {what[:60]:<60}",
                end="" if self.n < self.total else "\n",
                file=sys.stderr,
                flush=True,
            )
        else:
            print(f"[{self.n}/{self.total}] {what}", file=sys.stderr, flush=True)


def _client(args):
    from dask.distributed import Client, LocalCluster  # the fleet's own dependency, loaded when it runs

    if args.scheduler:
        try:
            return Client(args.scheduler, timeout="10s"), None
        except (OSError, TimeoutError) as e:
            raise OSError(f"{args.scheduler}: cannot reach the Dask scheduler: {e}") from None
    n = args.workers or os.cpu_count() or 1
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
    return Client(cluster), cluster


def cmd_fleet(args) -> int:
    if not args.archive.is_dir():
        raise OSError(f"{args.archive}: not a folder")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers {args.workers}: at least 1")
    args.out.mkdir(parents=True, exist_ok=True)
    jobs = fleet.find_logs(args.archive, args.out, args.model)
    if not jobs:
        raise ValueError(f"{args.archive}: no log in it (tlog, DataFlash, ULog or Crazyflie, by content)")
    todo = [j for j in jobs if not fleet.is_done(j)]
    print(f"{len(jobs)} logs under {args.archive}: {len(jobs) - len(todo)} already diagnosed, {len(todo)} to do")
    if todo:
        from dask.distributed import as_completed

        client, cluster = _client(args)
        try:
            where = args.scheduler or f"a local cluster of {len(client.scheduler_info()['workers'])} workers"
            print(f"on {where}", flush=True)
            bar = _Bar(len(todo))
            futures = client.map(fleet.diagnose_one, todo, pure=False)
            job_of = {f.key: j for f, j in zip(futures, todo)}
            for fut in as_completed(futures):
                try:
                    result = fut.result()
                except Exception as e:  # the task's worker died (killed, out of memory) or it raised
                    result = fleet.failed(job_of[fut.key], f"its worker failed: {type(e).__name__}: {e}"[:300])
                bar(result)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    done, failed = fleet.collect(jobs)
    fleet.write_table(fleet.fleet_table(done), args.out)
    fleet.write_fleet_report(done, failed, args.out)
    for f in failed:
        print(f"failed: {f['log']}: {f['error']}")
    print(fleet.summary_line(done, failed))
    print(f"table: {args.out / 'fleet.parquet'} and fleet.csv; report: {args.out / 'report.html'}")
    return 1 if failed else 0
