"""``groundstation sim``'s arguments read into what the simulator takes, with their one-line errors.

Loaded by the entry (:mod:`.main`) before the simulator's transports, the filters and the dashboard:
a mistyped effect, a scenario file the simulator cannot fly or a bad ``--udp`` is said in a tenth of
a second, not after a second and a half of imports. Only the scenario's effects need numpy."""

from __future__ import annotations

import math

from sim_bridge.effects import catalogue_markdown
from sim_bridge.scenario import Scenario

__all__ = ["catalogue_markdown", "checked", "problem", "scenario_from", "sysid", "udp_target", "unasked_rate"]


def scenario_from(args) -> Scenario:
    duration = args.duration if args.duration else 60.0
    return Scenario.from_args(
        args.vehicle, args.seed, duration, args.effect, args.undeclared, args.scenario, args.flight
    )


def udp_target(text: str) -> tuple[str, int] | None:
    """``--udp HOST:PORT`` as an address; None for ``none``."""
    if text.lower() == "none":
        return None
    host, _, port = text.rpartition(":")
    if not port.isdigit():
        raise ValueError(f"--udp {text!r}: expected HOST:PORT")
    return host or "127.0.0.1", int(port)


def unasked_rate(hz: float) -> float | None:
    """The bridge's ``unasked_rate``: None for 0 (every stream at its sensor's rate from the start)."""
    if not (math.isfinite(hz) and hz >= 0.0):
        raise ValueError(f"--unasked-rate {hz}: a rate in Hz, 0 or more")
    return hz if hz > 0 else None


def sysid(n: int) -> int:
    if not 1 <= n <= 255:
        raise ValueError(f"--sysid {n}: a MAVLink system id is 1-255")
    return n


def checked(args) -> Scenario:
    """The scenario ``sim``'s arguments make (effects, scenario file, vehicle and flight), with the
    rest of them checked: ``--fast`` without its log, the system id, and in real time the UDP target
    and the unasked streams' rate. A ValueError (a ScenarioError is one) says what is wrong."""
    scenario = scenario_from(args)
    if args.fast and args.log is None:
        raise ValueError("--fast needs --log OUT.tlog")
    sysid(args.sysid)
    if not args.fast:
        udp_target(args.udp)
        unasked_rate(args.unasked_rate)
    return scenario


def problem(args) -> str | None:
    """Why ``sim``'s arguments cannot run (one line, :func:`checked`'s), or None."""
    if args.list_effects:
        return None
    try:
        checked(args)
    except ValueError as e:
        return str(e)
    return None
