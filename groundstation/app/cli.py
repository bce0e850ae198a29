"""``groundstation``'s commands that run a filter beside the dashboard or the control station (the
entry, :mod:`.main`, runs the others from their own modules, ``main.ALONE``):

    groundstation connect URL [--record FILE] [--export OUT.csv] [--model NAME] [--no-web]
    groundstation replay FILE.tlog [--speed X|max] [--start S] [--loop] [--export OUT.csv] [--no-web]
    groundstation demo

Every failure the user can cause (bad connection string, missing device,
unreadable or foreign file) ends in one line on stderr and exit status 2,
never a traceback.
"""

from __future__ import annotations

import asyncio
import math
import os
import sys
import time

from drivers.connection import ConnectionStringError, parse_connection
from drivers.logs.crazyflie import CrazyflieLogError, is_crazyflie_log
from drivers.logs.dataflash import DataFlashError, is_dataflash
from drivers.logs.ulog import ULogError, is_ulog
from drivers.mavlink.commands import CommandError
from drivers.mavlink.link import GCS_SYSTEM_ID, LinkState, MavlinkLink
from drivers.mavlink.log_transfer import LogTransferError
from drivers.mavlink.params import ParamError
from drivers.replay import Replay
from drivers.tlog import TlogError
from drivers.transports import TransportError
from groundstation.control.station import ControlStation
from groundstation.estimation.logs import IMU_BLOCK_S, load_blocked, load_measurements
from groundstation.estimation.registry import vehicle_config
from groundstation.estimation.vehicles import declared_beside
from sim_bridge.scenario import ScenarioError
from web.dashboard import Dashboard

from .console import REPLAY_HELP, print_control_notes, print_link_events, replay_command
from .demo_cli import run_demo
from .interrupts import is_interrupt
from .options import key_of
from .outputs import Outputs, VehicleOutputs
from .session_files import discard_if_empty, session_path
from .signals import on_stop_signal
from .supervise import Supervisor


def run(args) -> int:
    """Run the parsed command: its one-line errors as exit status 2."""
    try:
        return _run(args)
    except BrokenPipeError:  # output piped into `head` and closed: not an error
        sys.stdout = open(os.devnull, "w")
        return 0


def _run(args) -> int:
    try:
        if args.command == "demo":
            return asyncio.run(run_demo(args))
        if args.vehicle:
            vehicle_config(args.vehicle, args.model)  # an unknown one is a one-line error before anything starts
        if args.command == "replay" and args.speed == math.inf and args.no_web and not args.loop:
            return replay_in_batch(args)  # (outside an event loop: Ctrl-C interrupts it at once)
        runner = {"connect": run_connect, "replay": run_replay}[args.command]
        return asyncio.run(runner(args))
    except BrokenPipeError:
        raise
    except (
        TlogError,
        TransportError,
        ConnectionStringError,
        ScenarioError,
        CrazyflieLogError,
        DataFlashError,
        ULogError,
        ParamError,
        LogTransferError,
        CommandError,
        OSError,
        ValueError,
    ) as e:
        print(f"groundstation: error: {e}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, SystemError) as e:
        if not is_interrupt(e):
            raise
        return 130


# ---------------------------------------------------------------- helpers
def _install_stop(stop: asyncio.Event) -> None:
    on_stop_signal(stop.set)


def _start_dashboard(args):
    if getattr(args, "no_web", True):
        return None
    dash = Dashboard(host=args.host, port=args.port, allow_remote=args.allow_remote)
    print(f"dashboard: {dash.url}", flush=True)
    print_control_address(dash)
    return dash


def print_control_address(dash) -> None:
    """The address whose tab may command (the Vehicle and Control panels) and start a diagnosis:
    printed for every session with a dashboard, as Jupyter prints its token."""
    print(f"control: {dash.control_url} (this address carries the session's token)", flush=True)


def link_markdown(state: str, counters, rates: dict[str, float], shed: int = 0, notes=()) -> str:
    """The dashboard's link panel: state, loss, errors, what was dropped or shed, what the vehicle
    and the stream requests said last (``notes``), rates by message."""
    top = sorted(rates.items(), key=lambda kv: -kv[1])[:8]
    lines = "\n".join(f"| {k} | {v:.1f} |" for k, v in top)
    load = "".join(
        f" · {text}"
        for n, text in (
            (counters.kernel_dropped, f"{counters.kernel_dropped} datagrams dropped by this machine"),
            (counters.dropped, f"{counters.dropped} measurements a consumer fell behind on"),
            (shed, f"{shed} readings decimated under load"),
        )
        if n
    )
    said = "".join(f"\n\n{n}" for n in notes)
    return (
        f"**{state}** · loss {counters.loss_percent:.1f} % · CRC errors {counters.crc_errors} · "
        f"garbage {counters.bad_data}{load}{said}\n\n| message | Hz |\n|---|---|\n{lines}"
    )


class RateMeter:
    """Messages per second by type, from the counters' differences."""

    def __init__(self) -> None:
        self._last: dict[str, int] = {}
        self._t: float | None = None

    def __call__(self, by_type) -> dict[str, float]:
        now = time.monotonic()
        dt = (now - self._t) if self._t else 1.0
        rates = {k: (v - self._last.get(k, 0)) / dt for k, v in by_type.items()}
        self._last, self._t = dict(by_type), now
        return rates


async def _consume(sub, out: Outputs | VehicleOutputs) -> None:
    """A recording's measurements, every one (the replay waits for the consumer)."""
    async for batch in sub.batches():
        for m in batch:
            out.see(m)


async def _consume_live(sub, out: Outputs | VehicleOutputs) -> None:
    """A live link's measurements, a batch at a time (yielding the event loop between batches)."""
    async for batch in sub.batches():
        out.see_live(batch)


# ---------------------------------------------------------------- connect
def _short_buffer(transport) -> str:
    """A UDP receive buffer smaller than asked, as the status line's clause (else nothing): bursts
    beyond it are dropped by the kernel (counted as kernel drops)."""
    granted, asked = getattr(transport, "receive_buffer", 0), getattr(transport, "rcvbuf", 0)
    if not granted or granted >= asked:
        return ""
    return (
        f"; UDP receive buffer {granted / 1e6:.1f} MB of {asked / 1e6:.1f} MB asked "
        "(raise net.core.rmem_max for bursts)"
    )


async def run_connect(args) -> int:
    endpoint = parse_connection(args.url)
    record = None
    if not args.no_record:
        record = args.record or session_path("sessions")  # one file a session, even two begun at once
    link = MavlinkLink(
        endpoint, record=record, lost_after=args.lost_after, max_rate=args.max_rate, signing_key=key_of(args)
    )
    sub = link.measurements()
    events = link.events()
    try:
        await link.open()
    except BaseException:
        if record is not None and not args.record:
            discard_if_empty(record)  # the session's fresh file, when its link never opened
        raise
    where = link.transport.local_address if link.transport else None
    print(
        f"link open: {endpoint}"
        + (f" (bound to {where[0]}:{where[1]})" if where else "")
        + (f"; recording to {record}" if record else "")
        + _short_buffer(link.transport),
        flush=True,
    )
    stop = asyncio.Event()
    _install_stop(stop)
    supervisor = Supervisor(stop.set)
    dash = _start_dashboard(args)
    outs = VehicleOutputs(
        args,
        args.declared,
        dash,
        args.vehicle,
        is_vehicle=link.is_vehicle,
        on_new=dash.set_vehicles if dash is not None else None,
    )
    if dash is not None:
        dash.on_vehicle = outs.show
    rates = RateMeter()

    async def print_status():
        while True:
            await asyncio.sleep(1.0)
            shown = outs.by_id.get(outs.shown) if outs.shown is not None else outs.first
            if dash is not None:
                shed = shown.loop.counters.shed if shown is not None else 0
                notes = [*list(link.status_texts)[-3:], *list(link.stream_notes)[-1:]]
                dash.set_link_status(
                    link_markdown(link.state.value, link.counters, rates(link.counters.by_type), shed, notes)
                )
            if not args.quiet:
                outs.print_status(link.state.value, link.counters)

    tasks = [
        supervisor.start("estimation", lambda: _consume_live(sub, outs)),
        supervisor.start("link events", lambda: print_link_events(events)),
        supervisor.start("status line", print_status),
    ]
    station = None
    if getattr(args, "control", None):
        station = ControlStation(args.control, link)
        control_sub, notes = link.measurements(), station.notes.subscribe()
        tasks += [
            supervisor.start("control feedback", lambda: station.follow(control_sub)),
            supervisor.start("control", station.run),
            supervisor.start("control notes", lambda: print_control_notes(notes)),
        ]
        if dash is not None:
            dash.add_control(station)
    if dash is not None:
        dash.add_vehicle_panel(link)
        tasks.append(supervisor.start("dashboard", dash.run))
    try:
        if args.duration:
            try:
                await asyncio.wait_for(stop.wait(), args.duration)
            except TimeoutError:
                pass
        else:
            await stop.wait()
    finally:
        if station is not None:
            station.stop()
        for t in tasks[2:]:
            t.cancel()
        await link.close()
        await asyncio.gather(*tasks, return_exceptions=True)
        if dash is not None:
            dash.stop()
        written = outs.close()
    c = link.counters
    print(
        f"closed: {c.messages} messages, {c.crc_errors} CRC errors, loss {c.loss_percent:.1f}%"
        + (
            (
                f"; {link.recorder.error}"
                if link.recorder.error
                else f"; recorded {link.recorder.records} frames to {record}"
            )
            if link.recorder
            else ""
        )
        + (f"; {written}" if written else ""),
        flush=True,
    )
    if supervisor.fatal:
        return 1
    return 0 if link.state is LinkState.CLOSED else 1


# ---------------------------------------------------------------- replay
def _open_replay(args) -> tuple[Replay, str, str | None]:
    """A tlog replays through the live receive path; DataFlash, ULog and Crazyflie logs through their readers."""

    if is_dataflash(args.file) or is_crazyflie_log(args.file) or is_ulog(args.file):
        ms, desc, vehicle = load_measurements(args.file)
        rp = Replay(args.file, speed=args.speed, loop=args.loop, start=args.start, measurements=ms)
        return rp, desc, vehicle
    rp = Replay(args.file, speed=args.speed, loop=args.loop, start=args.start)
    return rp, f"{len(rp.index)} records, {rp.duration:.1f} s", None


def replay_in_batch(args) -> int:
    """A replay at max speed with no dashboard: every record estimated in one synchronous pass, no
    event loop round trip per record, so that Ctrl-C stops it at once (KeyboardInterrupt), with what
    was estimated so far written and the last line saying where it stopped (exit status 130).

    Without ``--start`` or ``--export-measurements`` the log is read as columns and its IMU taken in
    10 ms blocks (:func:`~groundstation.estimation.logs.load_blocked`), three times faster than
    reading by reading; a log of several vehicles is read by reading, as the other cases are."""
    log = None if args.start or args.export_measurements else load_blocked(args.file)
    if log is not None:
        out = _replay_outputs(args, None, log.vehicle, log.ground_stations, in_time_order=True, stated=log.stated)
        print(f"replaying {args.file} at max speed: {log.description}", flush=True)
        if log.clearance is not None:
            print(_clearance_line(log.clearance), flush=True)
        at = _estimate_all(out, log.measurements)
        blocks = f"the IMU's in {IMU_BLOCK_S * 1e3:g} ms blocks"
        count = (
            f"{log.readings} measurements ({blocks}, as {len(log.measurements)})"
            if at is None
            else f"{out.count} of {len(log.measurements)} measurements ({blocks})"
        )
        damage = log.damage
    else:
        rp, desc, vehicle = _open_replay(args)
        out = _replay_outputs(args, None, vehicle, _ground_stations(rp))
        print(f"replaying {args.file} at max speed: {desc}", flush=True)
        at = _estimate_all(out, rp.iter_measurements())
        count = f"{out.count} measurements from {rp.receiver.counters.messages} messages"
        damage = rp.skipped_summary()
    written = out.close()
    print(
        ("done: " if at is None else f"stopped (Ctrl-C) at t {at:.1f} s: " if at == at else "stopped (Ctrl-C): ")
        + count
        + (f"; {damage}" if damage else "")
        + (f"; {written}" if written else ""),
        flush=True,
    )
    return 0 if at is None else 130


def _estimate_all(out: VehicleOutputs, ms) -> float | None:
    """Every measurement of ``ms`` estimated; None, or the vehicle time Ctrl-C stopped it at."""
    t = math.nan
    try:
        for m in ms:
            t = m.t
            out.see(m)
    except (KeyboardInterrupt, SystemError) as e:
        if not is_interrupt(e):
            raise
        return t
    return None


def _ground_stations(rp: Replay) -> set[int]:
    """The system ids a tlog's decoder has heard a ground station's heartbeat from: its own set,
    which grows as the replay reads (none for a log read by another reader)."""
    decoder = getattr(rp.receiver, "decoder", None)
    return decoder.ground_stations if decoder is not None else set()


def _clearance_line(c) -> str:
    """One line: the range's ground clearance a replay or an evaluation takes off its readings."""
    return (
        f"range: its reading on the ground, {c.metres * 100:.1f} cm from {c.source}, taken as its mounting "
        "offset (a range_offset declared for the session or the vehicle is used instead)"
    )


def _replay_outputs(
    args, dash, vehicle: str | None, stations, *, in_time_order: bool = False, stated=()
) -> VehicleOutputs:
    """The outputs of a replay: one estimator per vehicle, none for a ground station (ours or one
    recorded in the log: its own frames are in a tlog too, some before its first heartbeat);
    ``stated``: what the log states of its sensors (the range's ground clearance)."""
    return VehicleOutputs(
        args,
        args.declared or declared_beside(args.file),
        dash,
        args.vehicle or vehicle,
        is_vehicle=lambda sysid: sysid not in stations and sysid != GCS_SYSTEM_ID,
        on_new=dash.set_vehicles if dash is not None else None,
        in_time_order=in_time_order,
        stated=stated,
    )


async def run_replay(args) -> int:
    """A paced replay, or one with a dashboard (a max-speed one without is :func:`replay_in_batch`)."""
    rp, desc, vehicle = _open_replay(args)
    dash = _start_dashboard(args)
    out = _replay_outputs(args, dash, vehicle, _ground_stations(rp))
    if dash is not None:
        dash.on_vehicle = out.show
    print(f"replaying {args.file} at {'max' if rp.speed == math.inf else f'{rp.speed:g}x'} speed: {desc}", flush=True)
    stop = asyncio.Event()
    _install_stop(stop)
    supervisor = Supervisor(stop.set)
    sub = rp.measurements()
    consumer = supervisor.start("estimation", lambda: _consume(sub, out))
    player = asyncio.create_task(rp.run())

    rates = RateMeter()

    async def print_status():
        while True:
            await asyncio.sleep(1.0)
            if dash is not None:
                dash.set_link_status(
                    link_markdown(
                        f"replay {rp.status.state.value} · t {rp.position:.1f} / {rp.duration:.1f} s",
                        rp.receiver.counters,
                        rates(rp.receiver.counters.by_type),
                    )
                )
            if not args.quiet:
                out.print_status(
                    rp.status.state.value, rp.receiver.counters, f"t {rp.position:.1f}/{rp.duration:.1f} s"
                )

    printer = supervisor.start("status line", print_status)
    web = None
    if dash is not None:
        dash.attach_replay(rp)
        web = supervisor.start("dashboard", dash.run)
    if sys.stdin is not None and sys.stdin.isatty():
        print(REPLAY_HELP, flush=True)

        def on_stdin():
            reply = replay_command(sys.stdin.readline(), rp, stop)
            if reply:
                print(reply, flush=True)

        asyncio.get_running_loop().add_reader(sys.stdin.fileno(), on_stdin)
    stopper = asyncio.create_task(stop.wait())
    await asyncio.wait({player, stopper}, return_when=asyncio.FIRST_COMPLETED)
    if dash is not None and not stop.is_set():
        print(f"replay ended; the dashboard stays at {dash.url} until Ctrl-C", flush=True)
        await stop.wait()
    for t in (printer, stopper, player, *([web] if web else [])):
        t.cancel()
    await asyncio.gather(player, *([web] if web else []), return_exceptions=True)
    rp.close()
    await consumer
    if dash is not None:
        dash.stop()
    written = out.close()
    damage = rp.skipped_summary()
    print(
        f"done: {out.count} measurements from {rp.receiver.counters.messages} messages"
        + (f"; {damage}" if damage else "")
        + (f"; {written}" if written else ""),
        flush=True,
    )
    return 0
