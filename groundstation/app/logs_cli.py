"""``groundstation logs CONNECTION list|download N|latest|erase``: a vehicle's onboard logs over
MAVLink's log protocol (:mod:`drivers.mavlink.log_transfer`), as MAVProxy's ``log`` command gets
them after a flight; a download is written whole or not at all (what came of an incomplete one is
kept beside it as ``.part``)."""

from __future__ import annotations

import asyncio
import os
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

from drivers.mavlink.link import MavlinkLink
from drivers.mavlink.log_transfer import LogClient, LogEntry, LogTransferError

from .options import key_of
from .param_cli import wait_for_vehicle


def _when(e: LogEntry) -> str:
    return datetime.fromtimestamp(e.time_utc, UTC).strftime("%Y-%m-%d %H:%M:%S UTC") if e.time_utc else "time unknown"


def default_name(e: LogEntry) -> Path:
    stamp = datetime.fromtimestamp(e.time_utc, UTC).strftime("-%Y%m%d-%H%M%S") if e.time_utc else ""
    return Path(f"log{e.id}{stamp}.bin")


class Progress:
    """A one-line progress bar on a terminal's stderr; nothing when stderr is not one."""

    def __init__(self, entry: LogEntry) -> None:
        self.entry = entry
        self.start = time.monotonic()
        self.tty = sys.stderr.isatty()
        self._last = 0.0

    def __call__(self, got: int, total: int) -> None:
        now = time.monotonic()
        if not self.tty or (now - self._last < 0.1 and got < total):
            return
        self._last = now
        frac = got / total if total else 1.0
        bar = "#" * int(30 * frac)
        rate = got / max(now - self.start, 1e-3) / 1e3
        line = f"log {self.entry.id}: [{bar:<30s}] {100 * frac:3.0f}% {got // 1000}/{total // 1000} kB {rate:.0f} kB/s"
        print("\r" + line, end="", file=sys.stderr, flush=True)

    def done(self) -> None:
        if self.tty:
            print(file=sys.stderr)


#: its errors that are one line on the command line (beside ValueError and OSError)
ONE_LINE_ERRORS = (LogTransferError,)


def cmd_logs(args) -> int:
    return asyncio.run(run_logs(args))


async def run_logs(args) -> int:
    if args.logs_command == "erase" and not args.yes:
        raise LogTransferError("erase removes every log on the vehicle: add --yes to confirm")
    link = MavlinkLink(args.connection, streams={}, signing_key=key_of(args))
    await link.open()
    try:
        sysid, compid = await wait_for_vehicle(link, args.sysid)
        client = LogClient(link, sysid, compid)
        try:
            if args.logs_command == "erase":
                await client.erase()
                print(f"erase sent to vehicle {sysid}")
                return 0
            entries = await client.list()
            if args.logs_command == "list":
                _print_list(entries, client.num_logs or 0, sysid)
                return 0
            if not entries:
                raise LogTransferError(f"vehicle {sysid} has no logs")
            entry = entries[-1] if args.logs_command == "latest" else _by_number(entries, args.number)
            await _download(client, entry, args.out or default_name(entry))
        finally:
            client.close()
    finally:
        await link.close()
    return 0


def _print_list(entries: list[LogEntry], num_logs: int, sysid: int) -> None:
    if not entries:
        print(f"vehicle {sysid}: no logs")
        return
    print(f"vehicle {sysid}: {num_logs} logs" + ("" if len(entries) == num_logs else f" ({len(entries)} listed)"))
    for e in entries:
        print(f"  {e.id:4d}  {_when(e)}  {e.size:>12,d} bytes")


def _by_number(entries: list[LogEntry], number: int) -> LogEntry:
    for e in entries:
        if e.id == number:
            return e
    have = ", ".join(str(e.id) for e in entries)
    raise LogTransferError(f"no log {number} on the vehicle (it has {have})")


async def _download(client: LogClient, entry: LogEntry, out: Path) -> None:
    progress = Progress(entry)
    try:
        data = await client.download(entry, progress)
    except LogTransferError as e:
        progress.done()
        partial = e.partial
        if partial:
            part = out.with_name(out.name + ".part")
            part.write_bytes(partial)
            raise LogTransferError(f"{e}; its first {len(partial):,d} bytes kept in {part}") from None
        raise
    progress.done()
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, out)
    took = time.monotonic() - progress.start
    rate = len(data) / max(took, 1e-3) / 1e3
    print(f"log {entry.id}: {len(data):,d} bytes in {took:.1f} s ({rate:.0f} kB/s) -> {out}")
