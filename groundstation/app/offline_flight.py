"""The control loop against the simulator, stepped as fast as it goes.

Same bytes both ways as the live setup: the simulated vehicle's frames are
decoded by the ground station's receivers (board protocol or MAVLink), the
:class:`~.commander.Commander` with its controller, feedback and uplink runs
at its fixed rate, and the uplink's bytes go into the simulated vehicle's own
parser (:class:`sim_bridge.bridge.SimBridge`). Only the operating system's
transport and the wall clock are left out, so 60 s flights take a second or
two: the lab's trials and feedback comparison (``bench/control.py``) and the
fast tests run here; the tests over real ptys and UDP sockets run live.

``latency``: seconds between a command being computed and the vehicle
applying it (a serial link and a USB frame: a few ms).
"""

from __future__ import annotations

import collections
import inspect
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.board import BinaryBoardReceiver
from drivers.mavlink.receiver import MavlinkReceiver
from groundstation.control.commander import Commander, ControlRecord
from groundstation.control.controllers import Controller
from groundstation.control.feedback import Feedback
from groundstation.control.uplink import AttitudeTarget, BoardMotors, ManualControl
from sim_bridge.board_out import BoardEncoder
from sim_bridge.bridge import SimBridge
from sim_bridge.fast import EPOCH
from sim_bridge.mavlink_out import MavlinkEncoder
from sim_bridge.scenario import Scenario


@dataclass
class Flight:
    t: np.ndarray  # tick times [s]
    truth: dict[str, np.ndarray]  # the simulator's state at each tick
    records: list[ControlRecord] = field(default_factory=list)
    armed: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    history: list = field(default_factory=list)

    def command(self) -> np.ndarray:
        return np.array([r.command for r in self.records])

    def reference(self, name: str) -> np.ndarray:
        return np.array([r.reference[name] for r in self.records])


class _Wire:
    """Uplink bytes straight into the simulated vehicle's parsers (after ``latency``)."""

    def __init__(self, deliver: Callable[[bytes], object], mav: bool) -> None:
        self.deliver = deliver
        self.queue: collections.deque[tuple[float, bytes]] = collections.deque()
        self.now = 0.0
        self.latency = 0.0
        self._mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190) if mav else None

    def send(self, msg) -> None:
        data = msg.pack(self._mav) if self._mav is not None else msg
        self.queue.append((self.now + self.latency, data))

    def pump(self, now: float) -> None:
        while self.queue and self.queue[0][0] <= now + 1e-9:
            self.deliver(self.queue.popleft()[1])


def fly(
    scenario: Scenario,
    controller: Controller,
    feedback: Feedback,
    *,
    seconds: float,
    rate: float = 100.0,
    arm_at: float = 0.5,
    reference: Callable[..., dict] | None = None,
    latency: float = 0.004,
    stale_after: float = 0.25,
    tamper: Callable[[bytes, float], bytes] | None = None,
) -> Flight:
    """Fly ``seconds`` of simulated time; control is armed at ``arm_at``.

    ``tamper(frame, t)``: what the link delivers in place of each frame the vehicle sends at
    simulated time t (a corrupted reading, a fault injected on the wire).

    ``reference(t)`` or ``reference(t, truth)``: the reference at time t; the
    second form sees the vehicle's true state, as an operator watching the rig
    does (the lab's joystick closes the elevation loop by eye).
    """
    sees_truth = reference is not None and len(inspect.signature(reference).parameters) >= 2
    bridge = SimBridge(scenario, command_timeout=0.5)
    sim = bridge.sim
    sim.keep_truth = False
    board = scenario.vehicle == "heli3dof"
    enc: BoardEncoder | MavlinkEncoder
    rx: BinaryBoardReceiver | MavlinkReceiver
    uplink: BoardMotors | AttitudeTarget | ManualControl
    if board:
        enc = BoardEncoder("heli3dof", EPOCH)
        rx = BinaryBoardReceiver("board")
        wire = _Wire(bridge._board_incoming, mav=False)
        uplink = BoardMotors(wire)
    else:
        enc = bridge.encoder
        rx = MavlinkReceiver("mav")
        wire = _Wire(bridge._incoming, mav=True)
        uplink = AttitudeTarget(wire) if scenario.vehicle == "quad" else ManualControl(wire)
    wire.latency = latency
    cmd = Commander(controller, feedback, uplink, rate=rate, stale_after=stale_after, clock=lambda: sim.t)
    every = max(1, int(round(1.0 / (rate * sim.dt))))
    n = int(round(seconds / sim.dt))
    ts, rows, armed, records = [], [], [], []
    t_rx = time.time()
    for k in range(n):
        wire.now = sim.t
        wire.pump(sim.t)
        for s in sim.step():
            for fr in enc.encode(s):
                if tamper is not None:
                    fr = tamper(fr, sim.t)
                for m in rx.feed(fr, t_rx):
                    cmd.feed(m)
        if k % every == 0:
            # armed once, as soon as the feedback has a state (then it stays the user's call)
            if not cmd.armed and sim.t >= arm_at and not cmd.history and cmd.arm_refusal() is None:
                cmd.arm()
            if reference is not None:
                cmd.set_reference(**(reference(sim.t, sim.vehicle.truth()) if sees_truth else reference(sim.t)))
            rec = cmd.tick()
            if rec is not None:
                records.append(rec)
            ts.append(sim.t)
            rows.append(sim.truth())
            armed.append(cmd.armed)
    truth = {k: np.array([r[k] for r in rows]) for k in rows[0]} if rows else {}
    return Flight(np.array(ts), truth, records, np.array(armed), cmd.history)
