"""``groundstation demo``: the simulated vehicle and the ground station in one process, over real
loopback UDP: the estimate, the dashboard and (``--control``) the operator's control of it."""

from __future__ import annotations

import asyncio

from drivers.board import BoardLink
from drivers.mavlink.link import MavlinkLink
from groundstation.control.station import ControlStation
from groundstation.estimation.loop import EstimationLoop
from groundstation.estimation.models.heli3dof_rig import Heli3dofRig
from groundstation.estimation.registry import build_estimator, vehicle_config
from sim_bridge.bridge import SimBridge
from sim_bridge.pty_port import PtyPort
from sim_bridge.scenario import Scenario
from sim_bridge.simulator import truth_pose
from web.dashboard import Dashboard

from .console import StatusLine, print_control_notes, print_link_events
from .session_files import session_path
from .signals import on_stop_signal
from .supervise import Supervisor


def rig_constants(path: str | None) -> Heli3dofRig | None:
    """A rig file's constants (``heli3dof.rig``), or None without one; a one-line error for a file
    that holds none."""
    if path is None:
        return None
    section = vehicle_config(path, "heli3dof").get("rig")
    if not isinstance(section, dict):
        raise ValueError(f"{path}: no heli3dof.rig section (the file diagnose --model heli3dof writes has one)")
    return Heli3dofRig.from_vehicle(section)


async def run_demo(args) -> int:
    """Bridge and ground station in one process, over real loopback UDP."""

    if args.record is None:  # one run per file: a tlog appended to run after run reads as one flight with gaps
        args.record = session_path("out", "demo-")
    link = MavlinkLink("udpin:127.0.0.1:0", record=args.record)
    sub, events = link.measurements(), link.events()
    await link.open()
    dash = None
    if not args.no_web:
        dash = Dashboard(host=args.host, port=args.port, allow_remote=args.allow_remote)
        print(f"dashboard: {dash.url}", flush=True)
        print(f"control: {dash.control_url} (this address carries the session's token)", flush=True)
    model = "heli3dof" if args.vehicle == "heli3dof" else "altitude"
    declared = [{"name": "range_tilt"}] if model == "altitude" else []
    rig_file = str(args.rig) if getattr(args, "rig", None) and model == "heli3dof" else None
    rig = rig_constants(rig_file)
    estimators = [build_estimator(model, declared, vehicle=rig_file)]
    if dash is not None:
        dash.attach_session(model=model, declared=declared, counters=estimators[0].counters, vehicle=rig_file)
    if dash is not None and args.vehicle != "heli3dof":  # the rig is bolted to the table
        estimators.append(build_estimator("horizontal"))
    loop = EstimationLoop(estimators)
    snaps = loop.snapshots.subscribe(lossy=True, maxlen=1000)
    loop.attach_link(link)
    where = link.transport.local_address if link.transport is not None else None
    if where is None:
        raise OSError("the demo's UDP port did not open")
    port = where[1]
    scenario = Scenario(vehicle=args.vehicle, seed=args.seed, duration=args.duration)
    board_port = board = station = None
    if getattr(args, "control", False) and args.vehicle == "heli3dof":
        board_port = PtyPort()
    bridge = SimBridge(scenario, udp_to=("127.0.0.1", port), board=board_port)
    if dash is not None and args.vehicle != "heli3dof":
        # the simulator's truth as a motion-capture arena gives it, to the dashboard alone (never to an
        # estimator): the ghost, and the height's error against it with whether its sigma holds it
        bridge.truth_sink = lambda row: dash.feed_measurement(truth_pose(row))
    await bridge.open()
    supervisor = Supervisor(bridge.close)
    control_tasks = []
    if getattr(args, "control", False):
        if board_port is not None:
            board = BoardLink(f"{board_port.path},921600", "binary", lost_after=0.3)
            board_sub = board.measurements()
            await board.open()
            station = ControlStation("heli3dof", board, on_command=loop.push, rig=rig)
            control_tasks.append(asyncio.create_task(station.follow(board_sub)))
            print(f"demo: motor board on {board_port.path}", flush=True)
        else:
            station = ControlStation(args.vehicle, link)
            control_tasks.append(asyncio.create_task(station.follow(link.measurements())))
        control_tasks.append(asyncio.create_task(station.run()))
        control_tasks.append(asyncio.create_task(print_control_notes(station.notes.subscribe())))
        if dash is not None:
            dash.add_control(station)
        print(
            f"demo: control ready ({', '.join(station.controllers)}); take control and arm it from the "
            "dashboard's Control panel at the control address",
            flush=True,
        )
    print(
        f"demo: simulated {args.vehicle} -> udp 127.0.0.1:{port} -> ground station; recording {args.record}; "
        f"runs {args.duration:g} s of flight (--duration; Ctrl-C stops it sooner)",
        flush=True,
    )
    status = StatusLine()

    async def consume():
        async for batch in sub.batches():
            for m in batch:
                status.see(m)
                if dash is not None:
                    dash.feed_measurement(m)
            if dash is not None:
                for s in snaps.get_nowait():
                    dash.feed_snapshot(s)

    async def show_status():
        while True:
            await asyncio.sleep(1.0)
            z = loop.latest.get(model)
            extra = f"sim t {bridge.sim.t:.0f} s" + (
                f"  est {z.states[0]} {z.x[0]:+.3f} ±{z.sigma[0]:.3f}" if z else ""
            )
            status.print(link.state.value, link.counters, extra)
            if dash is not None:
                dash.set_link_status(
                    f"**{link.state.value}** · {link.counters.messages} messages · "
                    f"loss {link.counters.loss_percent:.2f} % · simulated {args.vehicle}, t {bridge.sim.t:.0f} s"
                )

    tasks = [
        supervisor.start("dashboard feed", consume),
        supervisor.start("link events", lambda: print_link_events(events)),
        supervisor.start("status line", show_status),
    ]
    if dash is not None:
        tasks.append(supervisor.start("dashboard", dash.run))
    on_stop_signal(bridge.close)
    try:
        await bridge.run(args.duration)
    finally:
        if station is not None:
            station.stop()
        bridge.close()
        for t in tasks[2:]:
            t.cancel()
        if board is not None:
            await board.close()
        await link.close()
        await asyncio.gather(*control_tasks, return_exceptions=True)
        await asyncio.gather(*tasks, return_exceptions=True)
        if dash is not None:
            dash.stop()
    c = link.counters
    recorded = (link.recorder.error if link.recorder is not None else None) or f"recorded {args.record}"
    print(
        f"demo: {c.messages} messages, loss {c.loss_percent:.2f}%, streams via "
        f"{link.stream_method.get(1, 'none')}; {recorded}",
        flush=True,
    )
    return 1 if supervisor.fatal else 0
