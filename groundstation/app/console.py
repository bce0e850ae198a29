"""A one-line-per-second terminal status for headless sessions (``--no-web``)."""

from __future__ import annotations

import math
import sys
import time
from typing import TextIO

from drivers.mavlink.receiver import LinkCounters
from groundstation.core.measurement import Kind, Measurement

#: The kinds whose latest value the status line shows, with format and unit.
_SHOWN = (
    (Kind.ALTITUDE, "alt {:.1f} m"),
    (Kind.RANGE, "range {:.2f} m"),
    (Kind.BARO_PRESSURE, "baro {:.0f} Pa"),
    (Kind.BATTERY_VOLTAGE, "batt {:.2f} V"),
    (Kind.THROTTLE, "thr {:.0%}"),
)


class StatusLine:
    """Keeps the latest values; :meth:`line` renders them with the link's rates."""

    def __init__(self, out: TextIO = sys.stdout) -> None:
        self.out = out
        self.latest: dict[Kind, float] = {}
        self.count = 0
        self._last = (time.monotonic(), 0, 0)

    def see(self, m: Measurement) -> None:
        self.count += 1
        if m.kind in _SHOWN_KINDS:
            self.latest[m.kind] = float(m.value[0])

    def line(self, state: str, counters: LinkCounters, extra: str = "") -> str:
        now = time.monotonic()
        t0, msgs0, meas0 = self._last
        dt = max(now - t0, 1e-9)
        self._last = (now, counters.messages, self.count)
        parts = [
            f"[{state}]",
            f"{(counters.messages - msgs0) / dt:.0f} msg/s",
            f"{(self.count - meas0) / dt:.0f} meas/s",
            f"loss {counters.loss_percent:.1f}%",
            f"crc {counters.crc_errors}",
        ]
        if counters.dropped:
            parts.append(f"consumer dropped {counters.dropped}")
        parts += [fmt.format(self.latest[k]) for k, fmt in _SHOWN if k in self.latest]
        if extra:
            parts.append(extra)
        return "  ".join(parts)

    def print(self, state: str, counters: LinkCounters, extra: str = "") -> None:
        print(self.line(state, counters, extra), file=self.out, flush=True)


_SHOWN_KINDS = {k for k, _ in _SHOWN}


async def print_link_events(events) -> None:
    """One line per link state change, until the stream ends."""
    async for ev in events:
        print(f"link {ev.state.value}: {ev.reason}", flush=True)


async def print_control_notes(notes) -> None:
    """One line per arming and disarming (with its reason), until the stream ends."""
    async for text in notes:
        print(f"control {text}", flush=True)


REPLAY_HELP = "replay controls: p = pause/resume, s SECONDS = seek, x SPEED = speed (0.1..100 or max), q = quit"


def replay_command(line: str, replay, stop) -> str:
    """Apply one typed replay command; returns what to print.

    The same :class:`~drivers.replay.Replay` methods the dashboard's
    controls call, for headless use.
    """

    words = line.strip().split()
    if not words:
        return ""
    cmd, arg = words[0].lower(), words[1] if len(words) > 1 else ""
    try:
        if cmd == "p":
            if replay.status.state.value == "paused":
                replay.resume()
                return "resumed"
            replay.pause()
            return "paused"
        if cmd == "s":
            replay.seek(float(arg))
            return f"at {replay.position:.1f} s"
        if cmd == "x":
            replay.set_speed(math.inf if arg.lower() == "max" else float(arg))
            return f"speed {arg}"
        if cmd == "q":
            stop.set()
            return "quitting"
    except ValueError as e:
        return f"? {e}"
    return f"? {REPLAY_HELP}"
