"""Arming, the fixed-rate command loop, and stopping on link loss.

Rules, in the order :meth:`Commander.tick` applies them:

1. Nothing is sent unless the user armed control (:meth:`Commander.arm`), and
   arming is refused, with one line saying why, when the link is not alive or
   the feedback has no fresh state.
2. Commands go out at a fixed rate (``rate``, default 100 Hz) on the link the
   data comes in on (:mod:`.uplink`).
3. A state the controller reads that is not finite or outside its plausible range
   (:attr:`~.controllers.Controller.state_limits`: a NaN from one bad frame, a vehicle
   upside down), or a command that is not finite or outside its range, disarms at once
   with the value named. Python's ``min``/``max`` drop NaN, so the check is on the state
   before the controller sees it, and on the command after.
4. Link loss disarms at once: a LOST or CLOSED event from the link, or no
   measurement for the feedback within ``stale_after`` seconds (0.25 s: a
   lost link is noticed within that plus one tick). Commanding stops; the
   vehicle, no longer commanded, falls back to its own safe state after its
   command timeout (the simulator's: 0.5 s, like ArduPilot's failsafes).
   Control stays disarmed until the user arms again.

Each tick publishes a :class:`ControlRecord` (reference, state, command) on
:attr:`Commander.records` for the dashboard's plots and the session export.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from drivers.link_state import LinkEvent, LinkState
from groundstation.core.broadcast import Broadcast
from groundstation.core.measurement import Kind, Measurement

from .controllers import Controller
from .feedback import Feedback
from .uplink import BoardMotors, Uplink

COMMAND_SOURCE = "command"


class ArmRefused(Exception):
    """Control cannot be armed now (one-line reason)."""


@dataclass(frozen=True)
class ControlRecord:
    t: float  # vehicle time the command is for [s]
    wall: float  # clock() when it was sent
    reference: dict[str, float]
    state: dict[str, float]
    command: np.ndarray
    u: np.ndarray
    saturated: bool


def state_problem(controller: Controller, x: Mapping[str, float]) -> str | None:
    """What is wrong with the state ``x`` for ``controller``, in one line, or None: a value it
    needs missing, or any value it reads not finite or outside its plausible range."""
    for name in controller.needs:
        if name not in x:
            return f"no {name}"
    for name in (*controller.needs, *(k for k in controller.state_limits if k not in controller.needs)):
        if name not in x:
            continue
        v = float(x[name])
        if not math.isfinite(v):
            return f"{name} = {v} is not finite"
        lo, hi = controller.state_limits.get(name, (-math.inf, math.inf))
        if not lo <= v <= hi:
            return f"{name} = {v:.4g} is outside its plausible range [{lo:.4g}, {hi:.4g}]"
    return None


def command_problem(controller: Controller, command: np.ndarray) -> str | None:
    """What is wrong with a command, in one line, or None: not finite, or outside its range."""
    c = np.asarray(command, dtype=float)
    if not np.all(np.isfinite(c)):
        return f"command {np.array2string(c, precision=4)} is not finite"
    lo, hi = controller.command_limits
    if np.any(c < lo) or np.any(c > hi):
        return f"command {np.array2string(c, precision=4)} is outside [{lo:g}, {hi:g}]"
    return None


class Commander:
    def __init__(
        self,
        controller: Controller,
        feedback: Feedback,
        uplink: Uplink,
        *,
        rate: float = 100.0,
        stale_after: float = 0.25,
        link=None,
        clock: Callable[[], float] = time.monotonic,
        on_command: Callable[[Measurement], None] | None = None,
        notes: Broadcast[str] | None = None,
    ) -> None:
        self.controller, self.feedback, self.uplink = controller, feedback, uplink
        self.rate, self.stale_after = rate, stale_after
        self.link = link
        self.clock = clock
        #: called with the command as a measurement (the 3-DOF filter's input, the recording)
        self.on_command = on_command
        self.reference = dict(controller.references)
        self.armed = False
        self.status = "disarmed"
        self.history: list[tuple[float, str]] = []  # (clock, what happened)
        self.records: Broadcast[ControlRecord] = Broadcast(10_000)
        #: arm and disarm notes as they happen (the terminal, the dashboard's status line, tests)
        self.notes: Broadcast[str] = notes if notes is not None else Broadcast(1000)
        self._last_rx: float | None = None
        self._t_vehicle = -math.inf
        self._stop = asyncio.Event()

    # -- inputs --------------------------------------------------------------------------------
    def feed(self, m: Measurement) -> None:
        """A measurement from the link (or replay): to the feedback, and as a sign of life."""
        self.feedback.feed(m)
        if m.source != COMMAND_SOURCE and m.kind in self.feedback.kinds:
            self._last_rx = self.clock()
            if m.t > self._t_vehicle:
                self._t_vehicle = m.t

    def link_event(self, ev: LinkEvent) -> None:
        if ev.state in (LinkState.LOST, LinkState.CLOSED):
            self.disarm(f"link {ev.state.value}: {ev.reason}")

    def set_reference(self, **values: float) -> None:
        for k, v in values.items():
            if k not in self.reference:
                raise ValueError(f"{self.controller.name} has no reference {k!r} (it has {', '.join(self.reference)})")
            if not math.isfinite(float(v)):
                raise ValueError(f"reference {k} must be a finite number, not {v!r}")
            self.reference[k] = float(v)

    # -- arming ----------------------------------------------------------------------------------
    def arm_refusal(self) -> str | None:
        """Why arming would be refused now, or None when it would be accepted."""
        if self.link is not None and getattr(self.link, "state", LinkState.ALIVE) is not LinkState.ALIVE:
            return f"link is {self.link.state.value}, not alive"
        age = self._age()
        if age is None or age > self.stale_after:
            return f"no fresh {self.feedback.name} feedback" + (
                "" if age is None else f" (last measurement {age:.2f} s ago)"
            )
        x = self.feedback.state()
        if x is None or any(k not in x for k in self.controller.needs):
            return f"{self.feedback.name} feedback has no state for {self.controller.name} yet"
        bad = state_problem(self.controller, x)
        if bad is not None:
            return f"{self.feedback.name} feedback: {bad}"
        return None

    def arm(self) -> None:
        why = self.arm_refusal()
        if why is not None:
            raise ArmRefused(why)
        self.controller.reset()
        self.armed = True
        self._note(f"armed: {self.controller.name} on {self.feedback.name}")

    def disarm(self, reason: str = "by the user") -> None:
        if self.armed:
            self.armed = False
            self._note(f"disarmed: {reason}")

    def _note(self, text: str) -> None:
        self.status = text
        self.history.append((self.clock(), text))
        self.notes.publish(text)

    def _age(self) -> float | None:
        return None if self._last_rx is None else self.clock() - self._last_rx

    # -- the loop ----------------------------------------------------------------------------------
    def tick(self) -> ControlRecord | None:
        """One control step; sends only while armed and the link is alive."""
        if not self.armed:
            return None
        age = self._age()
        if age is None or age > self.stale_after:
            self.disarm(f"link lost: no measurement for {self.stale_after:g} s")
            return None
        x = self.feedback.state()
        if x is None:
            self.disarm(f"{self.feedback.name} feedback has no state")
            return None
        bad = state_problem(self.controller, x)
        if bad is not None:
            self.disarm(f"{self.feedback.name} feedback: {bad}")
            return None
        out = self.controller.update(x, self.reference, 1.0 / self.rate)
        bad = command_problem(self.controller, out.command)
        if bad is not None:
            self.disarm(f"{self.controller.name}: {bad}")
            return None
        t = self._t_vehicle
        self.uplink.send(out.command, t)
        if isinstance(self.uplink, BoardMotors):
            echo = Measurement(t, Kind.MOTOR_VOLTAGE, out.command.copy(), COMMAND_SOURCE, time.time())
            self.feedback.feed(echo)
            if self.on_command is not None:
                self.on_command(echo)
        rec = ControlRecord(t, self.clock(), dict(self.reference), dict(x), out.command, out.u, out.saturated)
        self.records.publish(rec)
        return rec

    async def run(self) -> None:
        """Tick at ``rate`` on a fixed schedule (a late tick does not shift the next ones)
        and listen to the link's events, until :meth:`stop`."""
        events = watcher = None
        if self.link is not None and hasattr(self.link, "events"):
            events = self.link.events()
            watcher = asyncio.get_running_loop().create_task(self._watch(events))
        period = 1.0 / self.rate
        loop = asyncio.get_running_loop()
        due = loop.time()
        try:
            while not self._stop.is_set():
                self.tick()
                due += period
                now = loop.time()
                if due < now:  # fell behind: skip, do not burst
                    due = now + period - (now - due) % period
                try:
                    await asyncio.wait_for(self._stop.wait(), due - now)
                except TimeoutError:
                    continue
        finally:
            if events is not None and watcher is not None:
                events.close()
                await watcher

    async def follow(self, measurements) -> None:
        """Feed every measurement of a link's subscription (until it closes)."""
        async for batch in measurements.batches():
            for m in batch:
                self.feed(m)

    async def _watch(self, events) -> None:
        async for ev in events:
            self.link_event(ev)

    def stop(self) -> None:
        self.disarm("ground station stopping")
        self._stop.set()
