"""Vehicle time for every MAVLink message.

Messages with a ``time_boot_ms``/``time_usec`` field carry the vehicle's clock.
Messages without one (HEARTBEAT, SYS_STATUS, VFR_HUD, ...) are stamped on the
same clock through the offset between vehicle time and receive time, estimated
from the timestamped messages of the same system.

The offset estimate is the *largest* recent value of ``t_vehicle - t_rx``:
transport delay only ever makes ``t_rx`` later, so the least-delayed message
gives the best estimate. It is allowed to decay by 100 ppm (crystal drift) and
is reset outright when it moves by more than ``jump_s`` (reboot, clock jump);
the estimation loop sees the jump in the message timestamps themselves.

An untimed message is also never stamped later than the newest timed one plus
the receive time since it. The delay can grow faster than 100 ppm: a radio link
that buffers, or the simulated vehicle on a loaded machine, whose clock falls
behind the wall clock (1.6 s over a 60 s demo recorded while the test suite ran).
On the offset alone, SERVO_OUTPUT_RAW and VFR_HUD were then stamped up to 1 s
(``jump_s``, where the offset resets) ahead of the sensors sent with them, and
the estimation loop, ordering by time, dropped 25 141 of that recording's
measurements as late: the altitude filter took no baro or range reading at all,
and the thrust filter ended 37 m up. With the bound none is late, and every baro
and range reading is used. A recording made on an idle machine (0.22 s behind
after 60 s) loses 577 as late without the bound, 31 with it.
"""

from __future__ import annotations

import math

#: ``time_usec`` above this is a UNIX-epoch time (MAVLink lets senders use
#: either); 1e15 us is about 31 years of uptime.
EPOCH_THRESHOLD_US = 1e15
#: [s] a vehicle time this far behind the newest one seen is a restart, not a late message ...
RESTART_BACK_S = 0.5
#: ... once this many timed messages in a row say so and agree with one another (within ``jump_s``):
#: one message's time is no evidence (a corrupt or forged one had started a new flight segment, and
#: a new export file, each time); a rebooted vehicle's every message says it
RESTART_CONFIRM = 3


class VehicleClock:
    __slots__ = (
        "offset",
        "_last_rx",
        "jump_s",
        "drift",
        "resets",
        "restarts",
        "assumed",
        "_newest",
        "_newest_rx",
        "outliers",
        "_back",
        "_back_n",
    )

    def __init__(self, jump_s: float = 1.0, drift: float = 1e-4) -> None:
        self.offset = math.nan
        self._last_rx = math.nan
        self.jump_s = jump_s
        self.drift = drift
        self.resets = 0
        self.restarts = 0  # times the vehicle's clock went back (a reboot): RESTART_BACK_S or more
        self.assumed = False  # True while running on receive time (no time field seen)
        self._newest = math.nan  # the newest timed message's vehicle time, and when it came
        self._newest_rx = math.nan
        self.outliers = 0  # timed messages far behind the newest that no others confirmed
        self._back = math.nan  # the newest time of the messages in a row behind it, and how many
        self._back_n = 0

    def observe(self, t_vehicle: float, t_rx: float) -> bool:
        """Take a timestamped message into the offset estimate; True if it shows a restart."""
        new = t_vehicle - t_rx
        off = self.offset
        if self.assumed:  # a real time field at last: replace the assumption
            self.assumed = False
            self.resets += 1
            off = math.nan
        if off != off:  # nan: first sample
            self.offset = new
        else:
            if t_rx > self._last_rx:  # (several messages of one read share a receive time)
                off -= self.drift * (t_rx - self._last_rx)
            d = new - off
            if d > 0.0:  # less delayed than the estimate: the better one (or a jump forward)
                if d > self.jump_s:
                    self.resets += 1
                off = new
            elif d < -self.jump_s:  # a jump back
                self.resets += 1
                off = new
            self.offset = off
        self._last_rx = t_rx
        newest = self._newest
        if not t_vehicle <= newest:  # the newest yet (the first: NaN): most messages, checked first
            self._newest, self._newest_rx = t_vehicle, t_rx
            self._end_back()
            return False
        if t_vehicle >= newest - RESTART_BACK_S:  # in order, or a little late
            self._end_back()
            return False
        # far behind the newest: its uptime went back (a restart), once others say so too
        if self._back_n and abs(t_vehicle - self._back) <= self.jump_s:
            self._back_n += 1
            self._back = max(self._back, t_vehicle)
        else:
            self._end_back()
            self._back, self._back_n = t_vehicle, 1
        if self._back_n < RESTART_CONFIRM:
            return False
        self.restarts += 1
        self._newest, self._newest_rx = self._back, t_rx
        self._back, self._back_n = math.nan, 0
        return True

    def _end_back(self) -> None:
        """Messages behind the newest that stopped before they confirmed a restart were outliers."""
        if self._back_n:
            self.outliers += self._back_n
            self._back, self._back_n = math.nan, 0

    def assume_receive_time(self) -> None:
        """Give up waiting for a time field: stamp with receive time (offset 0)."""
        self.offset = 0.0
        self.assumed = True

    @property
    def newest(self) -> float:
        """The newest vehicle time a timed message has carried [s] (NaN before the first)."""
        return self._newest

    def vehicle_time(self, t_rx: float) -> float:
        """Vehicle time for a message without a time field (nan until known): by the offset, and
        no later than the newest timed message carried forward by receive time (module docstring)."""
        t = t_rx + self.offset
        if self._newest == self._newest:
            t = min(t, self._newest + max(0.0, t_rx - self._newest_rx))
        return t
