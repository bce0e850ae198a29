"""``groundstation command CONNECTION arm|disarm|mode NAME|takeoff ALT|land``: what a user opens
MAVProxy for, one command at a time, each with the vehicle's COMMAND_ACK as a one-line result
(:mod:`drivers.mavlink.commands`). Arming and takeoff start the motors: they need ``--yes``, as the
dashboard's ARM asks for a confirmation."""

from __future__ import annotations

import asyncio

from drivers.mavlink.commands import CommandError, run_command
from drivers.mavlink.link import MavlinkLink

from .options import key_of
from .param_cli import wait_for_vehicle
from .parser import command_usage_problem

#: its errors that are one line on the command line (beside ValueError and OSError)
ONE_LINE_ERRORS = (CommandError,)


def cmd_command(args) -> int:
    return asyncio.run(run_command_cli(args))


async def run_command_cli(args) -> int:
    why = command_usage_problem(args)
    if why is not None:
        raise CommandError(why)
    arg: str | float | None = float(args.arg) if args.what == "takeoff" else args.arg
    link = MavlinkLink(args.connection, streams={}, signing_key=key_of(args))
    await link.open()
    try:
        sysid, compid = await wait_for_vehicle(link, args.sysid)
        print(await run_command(link, sysid, compid, args.what, arg))
    finally:
        await link.close()
    return 0
