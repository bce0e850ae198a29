"""``groundstation sim`` without ``--fast``: the simulated vehicle in real time (or ``--speed`` times
it) on UDP, a pseudo-terminal or both, with a sensor board beside it, until ``--duration`` or Ctrl-C."""

from __future__ import annotations

import asyncio
import csv
import json

from sim_bridge.bridge import LinkFaults, SimBridge
from sim_bridge.pty_port import PtyPort
from sim_bridge.scenario import Scenario

from .options import key_of
from .signals import on_stop_signal
from .sim_args import sysid, udp_target, unasked_rate


def run(args, scenario: Scenario) -> int:
    return asyncio.run(_run_realtime(args, scenario))


async def _run_realtime(args, scenario: Scenario) -> int:
    pty = PtyPort(args.serial_link) if (args.serial or args.serial_link) else None
    board = PtyPort() if args.board else None
    bridge = SimBridge(
        scenario,
        udp_to=udp_target(args.udp),
        pty=pty,
        board=board,
        speed=args.speed,
        faults=LinkFaults(loss=args.loss / 100.0, corrupt=args.corrupt / 100.0),
        sysid=sysid(args.sysid),
        signing_key=key_of(args),
        unasked_rate=unasked_rate(args.unasked_rate),
    )
    truth_file = None
    if args.truth:
        truth_file = open(args.truth, "w", newline="")
        writer = None

        def sink(row):
            nonlocal writer
            if writer is None:
                writer = csv.DictWriter(truth_file, fieldnames=list(row))
                writer.writeheader()
            writer.writerow(row)

        bridge.truth_sink = sink
        args.truth.with_suffix(".truth.json").write_text(json.dumps(scenario.truth_json(), indent=2))
    await bridge.open()
    where = []
    if bridge.udp_to:
        where.append(f"UDP to {bridge.udp_to[0]}:{bridge.udp_to[1]} (connect with udpin:0.0.0.0:{bridge.udp_to[1]})")
    if pty is not None:
        where.append(f"serial {pty.path}")
    if board is not None:
        kind = "binary frames" if scenario.vehicle == "heli3dof" else "NMEA GPS"
        where.append(f"sensor board ({kind}) {board.path}")
    print(f"sim: {scenario.vehicle} seed {scenario.seed} speaking MAVLink on " + " and ".join(where), flush=True)
    on_stop_signal(bridge.close)
    try:
        await bridge.run(args.duration)
    finally:
        bridge.close()
        if truth_file is not None:
            truth_file.close()
    print(
        f"sim: stopped at t = {bridge.sim.t:.1f} s; {bridge.frames_sent} frames sent, "
        f"{bridge.frames_dropped} dropped by fault injection",
        flush=True,
    )
    return 0
