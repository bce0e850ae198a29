"""Stream requests that converge: what the link asks a vehicle to send, until it sends it.

A real autopilot starts at low default rates, and a radio loses frames, commands and their
acknowledgements alike. So each SET_MESSAGE_INTERVAL is sent until its COMMAND_ACK comes back,
with an exponential backoff (:data:`RETRIES` tries); a vehicle that answers none of the first
stream's tries does not take the command and gets REQUEST_DATA_STREAM instead. Then every
``check_every`` seconds the rate each message arrives at is compared with the rate asked, and a
stream arriving at less than :data:`SHORT` of it is asked again, for as long as the link lives,
with the wait before the next ask doubling while it stays short (up to :data:`MAX_BACKOFF_S`; a
vehicle without that sensor never sends it, and is asked once a minute) and starting over once it
comes. A stream that had come at its rate and then fell (another ground station's requests: a
MAVProxy router left at its default ``streamrate`` asks every stream at 4 Hz again and again, and
had silently taken the telemetry to a tenth; QGroundControl's, a companion's) is said, with its
rate, through ``on_note`` (the link's event line and the dashboard), and asked again. One that
had come and runs a little under its rate (between :data:`SHORT` and :data:`HELD`: a router's
4 Hz for a 5 Hz stream, which had held the GPS and the battery at 80 % behind a default MAVProxy
for ten minutes) is asked again quietly every :data:`TOP_UP_EVERY_S`. When the vehicle restarts
(its clock goes back, or it is heard again after the link was lost) everything is asked again.

A **link budget** (bytes per second: a serial link's baud / 10, or ``--max-rate``) scales the
rates down to fit, the estimator's needs first: the streams are asked in priority order, and the
ones further down are slowed before the first ones are (:func:`fit_budget`).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

RETRIES = 5  # tries of one SET_MESSAGE_INTERVAL before it counts as unanswered
BACKOFF = 1.5  # each try waits this much longer for its ACK
SHORT = 0.5  # a stream below this share of its asked rate is asked again ...
MAX_BACKOFF_S = 60.0  # ... after a wait that doubles while it stays short, up to this
HELD = 0.9  # a stream at this share of its rate or more has come: a fall after it is said
NOTE_EVERY_S = 60.0  # [s] a fall is said at most this often (a router's asks again every 10-20 s)
TOP_UP_EVERY_S = 5.0  # [s] a stream that had come and runs between SHORT and HELD of it is asked again this often
QUICK_S = 0.5  # [s] the fast streams' watch ...
QUICK_COUNT = 10  # ... of those that send this many frames in it
MIN_RATE = 0.5  # [Hz] no stream is slowed below this by the budget
PRIORITY = 6  # the first streams (the estimators' sensors) are slowed last
#: MAVLink 2 framing around a payload: header 10, checksum 2 [bytes]
FRAME_OVERHEAD = 12


def frame_bytes(name: str) -> int:
    """A message's length on the wire (MAVLink 2, its full payload) [bytes]."""
    cls = getattr(mavlink, f"MAVLink_{name.lower()}_message", None)
    payload = getattr(cls, "unpacker", None)
    return FRAME_OVERHEAD + (payload.size if payload is not None else 32)


def fit_budget(streams: dict[str, float], budget: float | None) -> dict[str, float]:
    """The rates scaled to ``budget`` [bytes/s] (None: as asked). The first :data:`PRIORITY`
    streams keep their rates while the rest can be slowed to fit; only if they alone do not fit
    are they slowed too, all by one factor, and everything else goes to :data:`MIN_RATE`."""
    if budget is None or budget <= 0:
        return dict(streams)
    names = list(streams)
    cost = {n: streams[n] * frame_bytes(n) for n in names}
    first, rest = names[:PRIORITY], names[PRIORITY:]
    c_first = sum(cost[n] for n in first)
    c_rest = sum(cost[n] for n in rest)
    if c_first + c_rest <= budget:
        return dict(streams)
    out = dict(streams)
    if c_first < budget:
        f = (budget - c_first) / c_rest if c_rest else 1.0
        for n in rest:
            out[n] = max(MIN_RATE, streams[n] * f)
        return out
    floor = sum(MIN_RATE * frame_bytes(n) for n in rest)
    f = max(0.0, budget - floor) / c_first
    for n in first:
        out[n] = max(MIN_RATE, streams[n] * f)
    for n in rest:
        out[n] = MIN_RATE
    return out


@dataclass
class VehicleStreams:
    """What was asked of one vehicle and how it went."""

    sysid: int
    compid: int
    asked: dict[str, float]  # message -> rate [Hz]
    method: str = ""  # "SET_MESSAGE_INTERVAL" or "REQUEST_DATA_STREAM"
    acked: set = field(default_factory=set)  # messages the vehicle acknowledged
    refused: set = field(default_factory=set)  # ... or refused (it lacks the sensor)
    unanswered: set = field(default_factory=set)  # ... or never answered
    reasked: dict = field(default_factory=dict)  # message -> times asked again for being short
    rates: dict = field(default_factory=dict)  # message -> rate received at the last check [Hz]
    requests: int = 0  # request rounds (the first, and one per restart)
    next_ask: dict = field(default_factory=dict)  # message -> monotonic time it may be asked again
    came: set = field(default_factory=set)  # messages that have come at their rate since last asked
    topped_up: dict = field(default_factory=dict)  # message -> when it may next be asked again while a little short
    overridden: int = 0  # times streams that had come fell below their rate (someone else asked)
    noted_at: float | None = None  # when that was last said, and how many times it had been by then
    noted_count: int = 0


class StreamRequester:
    """Asks each vehicle of a link for its streams and keeps them coming (see the module)."""

    def __init__(
        self,
        send: Callable[[object], None],
        counts: Callable[[], dict[str, int]],
        streams: dict[str, float],
        *,
        ack_timeout: float = 1.0,
        check_every: float = 5.0,
        budget: float | None = None,
        fallback: dict[int, float] | None = None,
        on_note: Callable[[str], None] | None = None,
    ) -> None:
        """``on_note(line)``: told when streams that had come fall below their rates."""
        self.on_note = on_note or (lambda _line: None)
        self.send = send
        self.counts = counts  # message name -> frames received so far (the link's counters)
        self.streams = fit_budget(streams, budget)
        self.ack_timeout = ack_timeout
        self.check_every = check_every
        self.fallback = fallback or {}
        self.vehicles: dict[int, VehicleStreams] = {}
        self._acks: dict[tuple[int, int], asyncio.Future] = {}
        self._tasks: dict[int, asyncio.Task] = {}

    # -- the link tells it ----------------------------------------------------------------
    def ack(self, sysid: int, command: int, result: int) -> None:
        fut = self._acks.get((sysid, command))
        if fut is not None and not fut.done():
            fut.set_result(result)

    def start(self, sysid: int, compid: int) -> None:
        """A vehicle seen for the first time, or again after a restart: ask for everything."""
        v = self.vehicles.get(sysid)
        if v is None:
            v = self.vehicles[sysid] = VehicleStreams(sysid, compid, dict(self.streams))
        v.compid = compid
        old = self._tasks.pop(sysid, None)
        if old is not None:
            old.cancel()
        self._tasks[sysid] = asyncio.get_running_loop().create_task(self._run(v))

    def close(self) -> list[asyncio.Task]:
        tasks = list(self._tasks.values())
        for t in tasks:
            t.cancel()
        self._tasks.clear()
        return tasks

    # -- asking --------------------------------------------------------------------------
    async def _interval(self, v: VehicleStreams, name: str, hz: float) -> int | None:
        """SET_MESSAGE_INTERVAL until acknowledged; its result, or None if never answered."""
        cmd = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
        msg_id = getattr(mavlink, f"MAVLINK_MSG_ID_{name}")
        wait = self.ack_timeout
        for _ in range(RETRIES):
            fut = asyncio.get_running_loop().create_future()
            self._acks[(v.sysid, cmd)] = fut
            self.send(mavlink.MAVLink_command_long_message(v.sysid, v.compid, cmd, 0, msg_id, 1e6 / hz, 0, 0, 0, 0, 0))
            try:
                # asyncio.wait, not wait_for: wait_for (3.11) swallows a cancellation that comes as
                # the ACK does, and the link's close then waited on a task that never ended
                done, _ = await asyncio.wait({fut}, timeout=wait)
            finally:
                self._acks.pop((v.sysid, cmd), None)
            if fut in done:
                return fut.result()
            wait *= BACKOFF
        return None

    async def _ask(self, v: VehicleStreams, names: list[str]) -> None:
        for name in names:
            result = await self._interval(v, name, v.asked[name])
            if result is None:
                v.unanswered.add(name)
                if not v.acked and not v.refused:  # nothing ever answered: the command is not taken
                    return
            elif result == mavlink.MAV_RESULT_ACCEPTED:
                v.method = "SET_MESSAGE_INTERVAL"
                v.acked.add(name)
                v.unanswered.discard(name)
            else:
                v.refused.add(name)  # a refusal for one message: the vehicle lacks that sensor
                v.unanswered.discard(name)  # answered at last (a loaded link can lose five tries' answers)

    async def _run(self, v: VehicleStreams) -> None:
        v.requests += 1
        v.method = ""
        v.acked.clear()
        v.refused.clear()
        v.unanswered.clear()
        v.reasked.clear()
        await self._ask(v, list(v.asked))
        if not v.acked:
            v.method = "REQUEST_DATA_STREAM"
            for stream_id, hz in self.fallback.items():
                self.send(mavlink.MAVLink_request_data_stream_message(v.sysid, v.compid, stream_id, int(hz), 1))
            return
        v.came.clear()
        v.next_ask.clear()
        # the fast streams are also watched over QUICK_S: one that had come and falls is asked again
        # within a second, not at the next check (a router's 4 Hz came every 10-20 s)
        quick = min(QUICK_S, self.check_every)
        fast = [n for n, hz in v.asked.items() if hz * quick >= QUICK_COUNT]
        before, t0 = dict(self.counts()), time.monotonic()
        q_before, q_t0 = before, t0
        while True:
            await asyncio.sleep(quick)
            now, t1 = dict(self.counts()), time.monotonic()
            q_rates = {n: (now.get(n, 0) - q_before.get(n, 0)) / max(t1 - q_t0, 1e-6) for n in fast}
            q_before, q_t0 = now, t1
            fell = [n for n in fast if n in v.came and q_rates[n] < SHORT * v.asked[n]]
            if not fell and t1 - t0 < self.check_every:
                continue
            dt = max(t1 - t0, 1e-6)
            v.rates = {n: (now.get(n, 0) - before.get(n, 0)) / dt for n in v.asked}
            v.rates.update({n: q_rates[n] for n in fell})  # as it is now, not as it was on average
            short = self._short(v, t1)
            if short:
                await self._ask(v, short)
                now, t1 = dict(self.counts()), time.monotonic()  # the asking took time: measure afresh
                q_before, q_t0 = now, t1
            before, t0 = now, t1

    def _short(self, v: VehicleStreams, now: float) -> list[str]:
        """The streams to ask again now (the module's docstring), and the note of any that fell."""
        fell, out = [], []
        for n, asked in v.asked.items():
            rate = v.rates[n]
            if n in v.refused:
                continue
            if rate >= HELD * asked:
                v.came.add(n)
                v.reasked[n] = 0
                v.next_ask.pop(n, None)
                continue
            if rate >= SHORT * asked:
                # had its rate and now a little under it: another asker's lower rate (a router's 4 Hz for
                # a 5 Hz stream) or loss; asked again quietly, at most every TOP_UP_EVERY_S (loss alone
                # then costs a command a stream every few seconds)
                if n in v.came and now >= v.topped_up.get(n, 0.0):
                    v.topped_up[n] = now + TOP_UP_EVERY_S
                    out.append(n)
                continue
            if n in v.came:
                fell.append(f"{n} {rate:.1f} Hz of {asked:g}")
                v.came.discard(n)
                v.next_ask.pop(n, None)  # fallen: asked at once
            if now < v.next_ask.get(n, 0.0):
                continue
            k = v.reasked.get(n, 0) + 1
            v.reasked[n] = k
            v.next_ask[n] = now + min(self.check_every * 2.0 ** (k - 1), MAX_BACKOFF_S)
            out.append(n)
        if fell:
            v.overridden += 1
            if v.noted_at is None or now - v.noted_at >= NOTE_EVERY_S:
                again = v.overridden - v.noted_count
                v.noted_at, v.noted_count = now, v.overridden
                self.on_note(
                    f"vehicle {v.sysid}: streams fell below their rates ({', '.join(fell)}): another ground "
                    "station's requests (a router's streamrate, QGroundControl's) may have changed them; asking "
                    "again" + (f" ({again} falls since this was last said)" if again > 1 else "")
                )
        return out
