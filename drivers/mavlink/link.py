"""A live MAVLink link to a vehicle, as an asyncio ``async for`` stream.

>>> async with MavlinkLink("udpin:0.0.0.0:14550", record="flight.tlog") as link:
...     async for m in link.measurements():
...         print(m.describe())

The link

* opens any transport of :mod:`drivers.connection` (UDP, TCP, serial), MAVLink 1 and 2;
* sends a GCS HEARTBEAT at 1 Hz, in the protocol version the vehicle speaks;
* asks each vehicle for the streams it needs with SET_MESSAGE_INTERVAL until they
  come at the rates asked (each request until acknowledged, short streams asked
  again, everything again after a restart), within the link's budget (a serial
  link's baud), and falls back to REQUEST_DATA_STREAM when the vehicle does not
  accept it (:mod:`.streams`);
* knows whether it is alive: any valid message proves it, ``lost_after``
  seconds of silence (or the device vanishing) lose it; state changes are
  :class:`LinkEvent` records on :meth:`events`;
* keeps :class:`~drivers.mavlink.receiver.LinkCounters`;
* records every valid frame, in and out, to a MAVProxy-compatible ``.tlog``.

Measurements reach the consumers a burst at a time: all a UDP wake-up drained
(or one TCP or serial read), so an estimator that sheds load sees its backlog.
"""

from __future__ import annotations

import asyncio
import collections
import sys
import time
from collections.abc import Callable
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.connection import Endpoint, parse_connection
from drivers.link_state import LinkEvent, LinkState
from drivers.tlog import TlogWriter
from drivers.transports import Transport, UdpTransport, open_transport
from groundstation.core.broadcast import Broadcast, Subscription
from groundstation.core.measurement import Measurement

from .receiver import LinkCounters, MavlinkReceiver
from .signing import SignatureCheck
from .streams import StreamRequester

#: Streams requested from a vehicle: message name -> rate [Hz].
#: What the estimators need most comes first (IMU, baro, range), then the rest.
DEFAULT_STREAMS: dict[str, float] = {
    "HIGHRES_IMU": 250.0,
    "SCALED_IMU": 50.0,
    "RAW_IMU": 50.0,
    "SCALED_PRESSURE": 50.0,
    "DISTANCE_SENSOR": 25.0,
    "ATTITUDE": 50.0,
    "ATTITUDE_QUATERNION": 50.0,
    "GPS_RAW_INT": 5.0,
    "GLOBAL_POSITION_INT": 10.0,
    "LOCAL_POSITION_NED": 10.0,
    "VFR_HUD": 10.0,
    "SERVO_OUTPUT_RAW": 50.0,
    "RC_CHANNELS": 10.0,
    "SYS_STATUS": 5.0,
    "BATTERY_STATUS": 5.0,
    "EKF_STATUS_REPORT": 2.0,
}

#: REQUEST_DATA_STREAM groups used when SET_MESSAGE_INTERVAL is refused.
FALLBACK_DATA_STREAMS: dict[int, float] = {
    mavlink.MAV_DATA_STREAM_RAW_SENSORS: 50.0,
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: 2.0,
    mavlink.MAV_DATA_STREAM_RC_CHANNELS: 10.0,
    mavlink.MAV_DATA_STREAM_POSITION: 10.0,
    mavlink.MAV_DATA_STREAM_EXTRA1: 50.0,
    mavlink.MAV_DATA_STREAM_EXTRA2: 10.0,
    mavlink.MAV_DATA_STREAM_EXTRA3: 10.0,
}

#: our system id on the link, as MAVProxy's and QGroundControl's
GCS_SYSTEM_ID = 255

_GCS_TYPES = {mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER}


#: the vehicles one link follows (asks for streams, answers); further system ids are counted
MAX_VEHICLES = 16
#: MAV_SEVERITY, as a person reads it
STATUS_SEVERITY = {
    0: "emergency",
    1: "alert",
    2: "critical",
    3: "error",
    4: "warning",
    5: "notice",
    6: "info",
    7: "debug",
}


class MavlinkLink:
    def __init__(
        self,
        url: str | Endpoint,
        *,
        name: str = "mav",
        lost_after: float = 3.0,
        heartbeat_hz: float = 1.0,
        streams: dict[str, float] | None = DEFAULT_STREAMS,
        record: str | Path | None = None,
        system_id: int = GCS_SYSTEM_ID,
        component_id: int = 190,
        buffer: int = 20_000,
        ack_timeout: float = 1.0,
        max_rate: float | None = None,
        check_every: float = 5.0,
        signing_key: bytes | None = None,
    ) -> None:
        """``max_rate``: the link's budget [bytes/s] the streams are fitted to (default: a serial
        link's baud / 10, unlimited otherwise); ``check_every`` [s]: how often the streams' rates
        are compared with those asked; ``signing_key``: MAVLink 2 signing required, our frames signed
        and every incoming one checked (:mod:`.signing`)."""
        self.endpoint = url if isinstance(url, Endpoint) else parse_connection(url)
        self.name = name
        self.lost_after = lost_after
        self.heartbeat_hz = heartbeat_hz
        self.streams = dict(streams or {})
        self.ack_timeout = ack_timeout
        if max_rate is None and self.endpoint.scheme == "serial":
            max_rate = self.endpoint.baud / 10.0  # 8N1: ten bits a byte
        self.max_rate = max_rate
        self.record_path = Path(record) if record else None
        self.recorder: TlogWriter | None = None
        self._mav_out = mavlink.MAVLink(None, system_id, component_id)
        self.receiver = MavlinkReceiver(name, on_frame=self._frame_in, on_message=self._message_in)
        #: the signature check, with the timestamps it keeps across restarts (None: no signing)
        self.signing: SignatureCheck | None = None
        if signing_key is not None:
            self.signing = SignatureCheck(signing_key, own=(system_id, component_id))
            self._mav_out.signing.secret_key = signing_key
            self._mav_out.signing.sign_outgoing = True
            # after every timestamp this key has used or seen, here or before a restart (the spec)
            self._mav_out.signing.timestamp = self.signing.state.local() + 1
            self.receiver.require_signing(self.signing)
        self.message_hooks: list[Callable[[object, float], None]] = []
        #: called synchronously with each batch of new measurements, before the
        #: ``async for`` subscribers see them: the estimation loop attaches here
        #: (``EstimationLoop.attach_link``) to estimate with no task hop
        self.sinks: list[Callable[[list[Measurement]], None]] = []
        self._measurements: Broadcast[Measurement] = Broadcast(buffer)
        self._events: Broadcast[LinkEvent] = Broadcast(1000)
        self.state = LinkState.CLOSED
        self.transport: Transport | None = None
        self._last_valid = 0.0
        self._tasks: list[asyncio.Task] = []
        self._vehicles: dict[int, int] = {}  # sysid -> autopilot compid
        self._address_of: dict[int, tuple] = {}  # udpin: sysid -> the address its heartbeats come from
        self._ground_stations: set[int] = set()  # sysids heard with a ground station's heartbeat
        #: sysid -> (armed, custom mode) as its last heartbeat says
        self.vehicle_state: dict[int, tuple[bool, int]] = {}
        self.requester = StreamRequester(
            self.send,
            lambda: self.receiver.counters.by_type,
            self.streams,
            ack_timeout=ack_timeout,
            check_every=check_every,
            budget=max_rate,
            fallback=FALLBACK_DATA_STREAMS,
            on_note=self._stream_note,
        )
        self._sink_faults: set[str] = set()
        self._command_acks: dict[tuple[int, int], asyncio.Future] = {}  # (sysid, command) -> its ACK
        self._lost_since_heartbeat: dict[int, bool] = {}  # sysid -> the link was lost since its last heartbeat
        self._clock_restarts: dict[int, int] = {}  # sysid -> its clock's restarts at its last heartbeat
        #: system ids heard past MAX_VEHICLES, not followed
        self.vehicles_ignored: set[int] = set()
        #: what the stream requests noticed (streams fallen below their rates), newest last
        self.stream_notes: collections.deque[str] = collections.deque(maxlen=20)
        #: what the vehicles said (STATUSTEXT), newest last
        self.status_texts: collections.deque[str] = collections.deque(maxlen=50)
        self._burst: list[Measurement] = []  # measurements of the transport's current burst
        self._bursts = False  # the transport calls on_burst_end (UDP)

    # -- public API -----------------------------------------------------------
    @property
    def counters(self) -> LinkCounters:
        return self.receiver.counters

    def measurements(self, maxlen: int | None = None, *, sysid: int | None = None) -> Subscription[Measurement]:
        """An ``async for`` stream of measurements (subscribe before data flows); with ``sysid``,
        one vehicle's alone (as MAVSDK gives each system its own telemetry)."""
        if sysid is None:
            return self._measurements.subscribe(maxlen)
        prefix = f"{self.name}/{sysid}."  # the decoder's source names: link/system.component
        return self._measurements.subscribe(maxlen, accept=lambda m: m.source.startswith(prefix))

    def events(self) -> Subscription[LinkEvent]:
        """An ``async for`` stream of link state changes."""
        return self._events.subscribe()

    @property
    def vehicles(self) -> dict[int, int]:
        return dict(self._vehicles)

    @property
    def ground_stations(self) -> set[int]:
        """System ids heard with a ground station's (or companion's) heartbeat: not vehicles."""
        return set(self._ground_stations)

    def is_vehicle(self, sysid: int) -> bool:
        """Not a ground station on the link (a vehicle, or not yet known as anything else)."""
        return sysid not in self._ground_stations

    @property
    def stream_method(self) -> dict[int, str]:
        """sysid -> how its streams were requested (SET_MESSAGE_INTERVAL or REQUEST_DATA_STREAM)."""
        return {s: v.method for s, v in self.requester.vehicles.items() if v.method}

    async def open(self) -> None:
        """Open the transport; raises :class:`drivers.transports.TransportError`."""
        tr = open_transport(self.endpoint)
        tr.on_data = self._data
        tr.on_disconnect = self._disconnected
        tr.on_connect = self._connected
        if isinstance(tr, UdpTransport):
            self._bursts = True  # it says when a wake-up's burst ends
            tr.on_burst_end = self._burst_end
        await tr.open()
        self.transport = tr
        if self.record_path is not None:
            self.recorder = TlogWriter(self.record_path, on_error=self._recording_failed)
        self._set_state(LinkState.CONNECTING, f"opened {self.endpoint}")
        loop = asyncio.get_running_loop()
        self._tasks = [loop.create_task(self._heartbeat_task()), loop.create_task(self._watchdog_task())]
        if self.recorder is not None:
            self._tasks.append(loop.create_task(self._flush_task()))

    async def close(self) -> None:
        self._tasks += self.requester.close()
        for t in self._tasks:
            t.cancel()
        # the link's own tasks end by cancellation; anything else is a bug to show
        for r in await asyncio.gather(*self._tasks, return_exceptions=True):
            if isinstance(r, Exception):
                print(f"groundstation: link task failed: {type(r).__name__}: {r}", file=sys.stderr)
        self._tasks = []
        if self.transport is not None:
            await self.transport.close()
        if self.recorder is not None:
            self.recorder.close()
        if self.signing is not None:
            self.signing.state.timestamp = max(self.signing.state.timestamp, self._mav_out.signing.timestamp)
            self.signing.state.save()
        self._set_state(LinkState.CLOSED, "closed")
        self._measurements.close()
        self._events.close()

    async def __aenter__(self) -> MavlinkLink:
        await self.open()
        return self

    async def __aexit__(self, *exc) -> None:
        await self.close()

    def expect_ack(self, sysid: int, command: int) -> asyncio.Future:
        """A future for the next COMMAND_ACK of ``command`` from ``sysid`` (its result code)."""
        fut = asyncio.get_running_loop().create_future()
        self._command_acks[(sysid, command)] = fut
        return fut

    def send(self, msg, *, force_mavlink1: bool | None = None) -> None:
        """Encode and send a pymavlink message (recorded like MAVProxy does)."""
        if self.transport is None:
            return
        v1 = self._peer_is_v1() if force_mavlink1 is None else force_mavlink1
        buf = msg.pack(self._mav_out, force_mavlink1=v1)
        self._mav_out.seq = (self._mav_out.seq + 1) % 256
        tr = self.transport
        if isinstance(tr, UdpTransport) and self._address_of:
            # udpin with vehicles heard: a message for one goes to its address, the rest to each
            target = getattr(msg, "target_system", 0)
            addrs = [self._address_of[target]] if target in self._address_of else set(self._address_of.values())
            for addr in addrs:
                tr.send_to(buf, addr)
        else:
            tr.send(buf)
        if self.recorder is not None:
            self.recorder.write(buf, time.time())

    # -- receive path ------------------------------------------------------------
    def _data(self, data: bytes, t_rx: float) -> None:
        c = self.receiver.counters
        n_before = c.messages
        out = self.receiver.feed(data, t_rx)
        # only a message whose CRC was checked proves the link alive (an unknown id's cannot be)
        if c.messages != n_before:
            self._last_valid = time.monotonic()
            if self.state is not LinkState.ALIVE:
                self._set_state(LinkState.ALIVE, "valid message received")
        if out:
            self._burst += out
        if not self._bursts:
            self._burst_end()

    def _burst_end(self) -> None:
        """The burst's measurements to the sinks and subscribers, as one batch."""
        batch, self._burst = self._burst, []
        if isinstance(self.transport, UdpTransport):
            self.receiver.counters.kernel_dropped = self.transport.kernel_drops
        if not batch:
            return
        for sink in self.sinks:
            try:
                sink(batch)
            except Exception as e:  # noqa: BLE001 - a consumer's fault must not stop the link
                self._sink_failed(sink, e)
        self._measurements.publish_many(batch)
        self.receiver.counters.dropped = self._measurements.dropped

    def _frame_in(self, frame: bytes, t_rx: float) -> None:
        if self.recorder is not None:
            self.recorder.write(frame, t_rx)

    def _message_in(self, m, t_rx: float) -> None:
        mtype = m.get_type()
        if mtype == "HEARTBEAT":
            self._heartbeat_in(m)
        elif mtype == "STATUSTEXT":
            self._status_text_in(m)
        elif mtype == "COMMAND_ACK":
            self.requester.ack(m._header.srcSystem, m.command, m.result)
            fut = self._command_acks.pop((m._header.srcSystem, m.command), None)
            if fut is not None and not fut.done():
                fut.set_result(m.result)
        for hook in self.message_hooks:
            try:
                hook(m, t_rx)
            except Exception as e:  # noqa: BLE001 - one consumer's fault must not stop the others
                self._sink_failed(hook, e)

    def _status_text_in(self, m) -> None:
        """What the vehicle says (STATUSTEXT: "PreArm: Need 3D Fix", "Low Battery!"), kept and on the
        event stream, so the event line and the dashboard show it as it comes."""
        sysid = m._header.srcSystem
        if sysid in self._ground_stations:
            return
        text = m.text if isinstance(m.text, str) else bytes(m.text).split(b"\0", 1)[0].decode("latin-1")
        text = "".join(c for c in text.strip() if c.isprintable())[:200]
        if not text:
            return
        severity = STATUS_SEVERITY.get(int(getattr(m, "severity", 6)), "info")
        line = f"vehicle {sysid} says ({severity}): {text}"
        self.status_texts.append(line)
        self._events.publish(LinkEvent(self.state, time.time(), line))

    def _stream_note(self, line: str) -> None:
        """What the stream requests found (streams overridden by another ground station), on the
        event stream: the event line and the dashboard say it."""
        self.stream_notes.append(line)
        self._events.publish(LinkEvent(self.state, time.time(), line))

    def _heartbeat_in(self, m) -> None:
        hdr = m._header
        sysid = hdr.srcSystem
        if m.type in _GCS_TYPES or m.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
            self._ground_stations.add(sysid)
            return
        tr = self.transport
        if isinstance(tr, UdpTransport) and tr.endpoint.scheme == "udpin" and tr.source is not None:
            self._address_of[sysid] = tr.source  # answered there, whoever wrote last
        new = sysid not in self._vehicles
        if new and len(self._vehicles) >= MAX_VEHICLES:
            # a link's budget of vehicles: more system ids (254 forged ones had each been asked for
            # streams and given files of their own) are counted, not followed
            self.vehicles_ignored.add(sysid)
            return
        clock = self.receiver.decoder.clocks.get(sysid)
        restarts = clock.restarts if clock is not None else 0
        # heard again after the link was lost, or its clock went back (a reboot): it starts over
        # at its default rates, so everything is asked again
        restarted = not new and restarts > self._clock_restarts.get(sysid, 0)
        again = not new and (self._lost_since_heartbeat.get(sysid) or restarted)
        if restarted:
            why = f"vehicle {sysid} restarted (its clock went back): a new flight segment, its streams asked again"
            self._events.publish(LinkEvent(self.state, time.time(), why))
        self._vehicles[sysid] = hdr.srcComponent
        self.vehicle_state[sysid] = (bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED), int(m.custom_mode))
        self._lost_since_heartbeat[sysid] = False
        self._clock_restarts[sysid] = restarts
        if self.streams and (new or again):
            self.requester.start(sysid, hdr.srcComponent)

    def _peer_is_v1(self) -> bool:
        peers = self.receiver.peer_mavlink1
        keys = [k for k in peers if k[0] in self._vehicles] or list(peers)
        return bool(keys) and all(peers[k] for k in keys)

    # -- link state ----------------------------------------------------------------
    def _set_state(self, state: LinkState, reason: str) -> None:
        if state is self.state:
            return
        self.state = state
        if state is LinkState.LOST:
            for sysid in self._lost_since_heartbeat:
                self._lost_since_heartbeat[sysid] = True
        self._events.publish(LinkEvent(state, time.time(), reason))

    def _sink_failed(self, sink, e: Exception) -> None:
        """A synchronous consumer (the estimation loop) raised: counted, said once per kind of fault
        on the event stream, and the link goes on delivering."""
        self.receiver.counters.sink_errors += 1
        why = f"a consumer of the link failed: {type(e).__name__}: {e}"
        if why not in self._sink_faults:
            self._sink_faults.add(why)
            self._events.publish(LinkEvent(self.state, time.time(), why))

    def _recording_failed(self, why: str) -> None:
        """A write error stopped the recording; the link goes on (its state unchanged)."""
        self._events.publish(LinkEvent(self.state, time.time(), why))

    def _disconnected(self, reason: str) -> None:
        self._set_state(LinkState.LOST, reason)

    def _connected(self, reason: str) -> None:
        if self.state is not LinkState.ALIVE:
            self._set_state(LinkState.CONNECTING, reason)

    async def _watchdog_task(self) -> None:
        period = max(0.02, self.lost_after / 10)
        while True:
            await asyncio.sleep(period)
            if self.state is LinkState.ALIVE and time.monotonic() - self._last_valid > self.lost_after:
                self._set_state(LinkState.LOST, f"no valid message for {self.lost_after:g} s")

    async def _heartbeat_task(self) -> None:
        hb = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
        )
        while True:
            if self.transport is not None and self.transport.has_peer:
                self.send(hb)
            await asyncio.sleep(1.0 / self.heartbeat_hz)

    async def _flush_task(self) -> None:
        while self.recorder is not None and not self.recorder.closed:
            await asyncio.sleep(self.recorder.flush_s)
            self.recorder.flush()
