"""``groundstation command CONNECTION arm|disarm|mode NAME|takeoff ALT|land``: what a user opens
MAVProxy for, one command at a time, each with the vehicle's COMMAND_ACK as a one-line result
(:mod:`drivers.mavlink.commands`). Arming and takeoff start the motors: they need ``--yes``, as the
dashboard's ARM asks for a confirmation."""

from __future__ import annotations

from drivers.mavlink.commands import CommandError, run_command
from drivers.mavlink.link import MavlinkLink

from .options import key_of
from .param_cli import wait_for_vehicle

#: commands that start the motors: only with --yes
STARTS_MOTORS = {"arm", "takeoff"}


async def run_command_cli(args) -> int:
    if args.what in STARTS_MOTORS and not args.yes:
        raise CommandError(f"{args.what} starts the motors: add --yes to confirm")
    if args.what in ("mode", "takeoff") and args.arg is None:
        raise CommandError(f"{args.what} needs {'a mode name' if args.what == 'mode' else 'an altitude [m]'}")
    arg: str | float | None = args.arg
    if args.what == "takeoff":
        try:
            arg = float(args.arg)
        except ValueError:
            raise CommandError(f"takeoff {args.arg!r}: an altitude in metres") from None
    link = MavlinkLink(args.connection, streams={}, signing_key=key_of(args))
    await link.open()
    try:
        sysid, compid = await wait_for_vehicle(link, args.sysid)
        print(await run_command(link, sysid, compid, args.what, arg))
    finally:
        await link.close()
    return 0
