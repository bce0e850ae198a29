"""Commands a user sends a vehicle: arm, disarm, mode, takeoff, land, each a COMMAND_LONG sent
until its COMMAND_ACK comes back (or the tries run out), with a one-line result.

ArduCopter's flight modes (``Mode::Number``) are here, the one table the ground station, the
triage of logs and the simulated vehicle share.
"""

from __future__ import annotations

import asyncio

from pymavlink.dialects.v20 import ardupilotmega as mavlink

COPTER_MODES = {
    0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 5: "LOITER", 6: "RTL", 7: "CIRCLE",
    9: "LAND", 11: "DRIFT", 13: "SPORT", 14: "FLIP", 15: "AUTOTUNE", 16: "POSHOLD", 17: "BRAKE", 18: "THROW",
    19: "AVOID_ADSB", 20: "GUIDED_NOGPS", 21: "SMART_RTL", 22: "FLOWHOLD", 23: "FOLLOW", 24: "ZIGZAG",
    25: "SYSTEMID", 26: "AUTOROTATE", 27: "AUTO_RTL",
}  # fmt: skip
MODE_NUMBERS = {name: number for number, name in COPTER_MODES.items()}
RESULTS = {
    mavlink.MAV_RESULT_ACCEPTED: "accepted",
    mavlink.MAV_RESULT_TEMPORARILY_REJECTED: "temporarily rejected",
    mavlink.MAV_RESULT_DENIED: "denied",
    mavlink.MAV_RESULT_UNSUPPORTED: "unsupported",
    mavlink.MAV_RESULT_FAILED: "failed",
    mavlink.MAV_RESULT_IN_PROGRESS: "in progress",
}
RETRIES = 3


class CommandError(RuntimeError):
    """A command the vehicle did not accept, or never answered (one line)."""


async def command_long(link, sysid: int, compid: int, command: int, *params: float, timeout: float = 1.0) -> int:
    """Send until acknowledged; the ACK's result, or CommandError when no ACK comes."""
    p = [float(x) for x in params] + [0.0] * (7 - len(params))
    for attempt in range(RETRIES):
        fut = link.expect_ack(sysid, command)
        link.send(mavlink.MAVLink_command_long_message(sysid, compid, command, attempt, *p))
        done, _ = await asyncio.wait({fut}, timeout=timeout)  # (wait_for can swallow a cancellation)
        if fut in done:
            return int(fut.result())
        timeout *= 1.5
    name = mavlink.enums["MAV_CMD"][command].name if command in mavlink.enums["MAV_CMD"] else str(command)
    raise CommandError(f"{name}: no COMMAND_ACK from vehicle {sysid} after {RETRIES} tries")


def mode_number(name: str) -> int:
    try:
        return MODE_NUMBERS[name.upper()]
    except KeyError:
        raise CommandError(f"mode {name!r}: not an ArduCopter mode; known: {', '.join(MODE_NUMBERS)}") from None


async def run_command(link, sysid: int, compid: int, what: str, arg: float | str | None = None) -> str:
    """``arm``, ``disarm``, ``mode NAME``, ``takeoff ALT``, ``land``: the one-line result; raises
    CommandError when the vehicle refuses or does not answer."""
    params: tuple[float, ...]
    if what == "arm":
        cmd, params = mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1,)
    elif what == "disarm":
        cmd, params = mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (0,)
    elif what == "mode":
        cmd, params = mavlink.MAV_CMD_DO_SET_MODE, (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode_number(str(arg)))
    elif what == "takeoff":
        alt = float(arg if arg is not None else 0.0)
        if not 0.0 < alt <= 120.0:
            raise CommandError(f"takeoff {alt:g} m: an altitude in (0, 120] m")
        cmd, params = mavlink.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, alt)
    elif what == "land":
        cmd, params = mavlink.MAV_CMD_NAV_LAND, ()
    else:
        raise CommandError(f"unknown command {what!r}: arm, disarm, mode NAME, takeoff ALT, land")
    result = await command_long(link, sysid, compid, cmd, *params)
    said = RESULTS.get(result, f"result {result}")
    line = f"{what}{f' {arg}' if arg is not None else ''}: {said} by vehicle {sysid}"
    if result != mavlink.MAV_RESULT_ACCEPTED:
        raise CommandError(line)
    return line
