"""``groundstation param CONNECTION fetch|get|set|load``: a vehicle's parameters, as MAVProxy's
``param`` command gives them (:mod:`drivers.mavlink.params`)."""

from __future__ import annotations

import asyncio
import contextlib
import sys

from drivers.mavlink.link import MavlinkLink
from drivers.mavlink.params import ParamClient, ParamError, load, save

from .options import key_of

WAIT_FOR_VEHICLE_S = 10.0


async def wait_for_vehicle(link: MavlinkLink, sysid: int | None) -> tuple[int, int]:
    loop = asyncio.get_running_loop()
    end = loop.time() + WAIT_FOR_VEHICLE_S
    events = link.events()
    while True:
        vehicles = link.vehicles
        if sysid is None and vehicles:
            return next(iter(vehicles.items()))
        if sysid is not None and sysid in vehicles:
            return sysid, vehicles[sysid]
        left = end - loop.time()
        if left <= 0:
            who = f"vehicle {sysid}" if sysid is not None else "a vehicle"
            refused = link.counters.signature_refused
            why = f" ({refused} frames refused by MAVLink 2 signing: another key?)" if refused else ""
            raise OSError(f"{link.endpoint}: no heartbeat from {who} within {WAIT_FOR_VEHICLE_S:g} s{why}")
        # a link event wakes the check at once; a heartbeat is looked for again every 0.2 s
        with contextlib.suppress(TimeoutError, StopAsyncIteration):
            await asyncio.wait_for(events.__anext__(), min(left, 0.2))


#: its errors that are one line on the command line (beside ValueError and OSError)
ONE_LINE_ERRORS = (ParamError,)


def cmd_param(args) -> int:
    return asyncio.run(run_param(args))


async def run_param(args) -> int:
    if args.param_command == "load":
        wanted = load(args.file)  # a bad file is an error before anything is sent
    link = MavlinkLink(args.connection, streams={}, signing_key=key_of(args))
    await link.open()
    try:
        sysid, compid = await wait_for_vehicle(link, args.sysid)
        client = ParamClient(link, sysid, compid)
        if args.param_command == "fetch":

            def progress(n: int, total: int) -> None:
                if sys.stderr.isatty():
                    print(f"\r{n}/{total} parameters", end="", file=sys.stderr, flush=True)

            values = await client.fetch_all(progress)
            if sys.stderr.isatty():
                print(file=sys.stderr)
            if args.out:
                save(args.out, values, qgc=args.qgc, sysid=sysid, compid=compid, types=client.types)
                print(f"{len(values)} parameters of vehicle {sysid} written to {args.out}")
            else:
                for n, v in sorted(values.items()):
                    print(f"{n:<16s} {v:.7g}")
        elif args.param_command == "get":
            for n in args.names:
                print(f"{n:<16s} {await client.get(n):.7g}")
        elif args.param_command == "set":
            print(f"{args.name:<16s} {await client.set(args.name, args.value):.7g} (confirmed by the vehicle)")
        else:
            for n, v in wanted.items():
                await client.set(n, v)
            print(f"{len(wanted)} parameters set and confirmed from {args.file}")
        client.close()
    finally:
        await link.close()
    return 0
