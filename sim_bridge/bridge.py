"""The simulated vehicle in real time, on the transports real hardware uses.

A :class:`SimBridge` steps the :class:`~sim_bridge.simulator.Simulator` against
the wall clock and speaks MAVLink 2 over

* UDP, sending to the ground station's address (as SITL or a companion does
  towards ``udpin:0.0.0.0:14550``), answering whoever writes back, and/or
* a serial pseudo-terminal whose path it prints (the ground station opens it
  with pyserial like a USB radio).

Towards the ground station it behaves like an ArduPilot vehicle: HEARTBEAT and
EXTENDED_SYS_STATE at 1 Hz; parameters, commands with addressed ACKs, modes,
arming, AUTOPILOT_VERSION, PING and the mission list (:mod:`.vehicle_protocol`); a DataFlash
log of each flight, listed and downloaded over MAVLink's log protocol (:mod:`.log_server`);
``SET_MESSAGE_INTERVAL`` changes a stream's rate (COMMAND_ACK ACCEPTED, or
UNSUPPORTED for a message it does not send); ``REQUEST_DATA_STREAM`` sets the
rates of the ArduPilot stream groups; ``MANUAL_CONTROL`` and
``SET_ATTITUDE_TARGET`` fly the vehicle while they keep coming (stabilised: x, y
are attitude setpoints for the quad and the coax; for the 3-DOF rig z and y are
the sum and difference voltages), and it falls back to its own autopilot
``command_timeout`` seconds after the last one. On the 3-DOF rig's board port,
``MOTORS`` frames set the motor voltages the same way.

Link faults on demand (:class:`LinkFaults`): random frame loss, corrupted
bytes, loss bursts, and :meth:`SimBridge.disconnect` for a while.
"""

from __future__ import annotations

import asyncio
import ipaddress
import math
import random
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.board import BinaryBoardReceiver
from drivers.mavlink.framing import Framer
from drivers.mavlink.signing import SignatureCheck, SigningState
from drivers.transports import close_watched_socket
from groundstation.core.measurement import Kind

from .autopilot_params import AutopilotParams
from .board_out import BoardEncoder
from .fast import EPOCH
from .flight_log import FlightLogs
from .log_server import LogServer
from .mavlink_out import DERIVED_FROM, STREAM_OF_MESSAGE, MavlinkEncoder
from .names import UNASKED_RATE
from .onboard_height import OnboardHeight
from .profile import CoaxAutopilot
from .pty_port import PtyPort
from .scenario import Scenario
from .sensors import M_PER_DEG
from .simulator import Sample, Simulator
from .vehicle_protocol import VehicleProtocol
from .vehicles.heli3dof import Heli3dof, Heli3dofCommand
from .vehicles.quad import QuadCommand

#: [s] of the wall clock the simulated vehicle catches up at once; a longer stall pauses it (:meth:`SimBridge.run`)
MAX_CATCH_UP = 0.02
#: [s] the wall clock between two steps of the real-time loop (SimBridge.run)
TICK = 0.004

#: ArduPilot's REQUEST_DATA_STREAM groups -> our sensor streams
DATA_STREAM_GROUPS = {
    mavlink.MAV_DATA_STREAM_RAW_SENSORS: ("imu", "baro"),
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: ("battery",),
    mavlink.MAV_DATA_STREAM_RC_CHANNELS: ("actuators",),
    mavlink.MAV_DATA_STREAM_POSITION: ("gps",),
    mavlink.MAV_DATA_STREAM_EXTRA1: ("attitude", "encoders"),
    mavlink.MAV_DATA_STREAM_EXTRA3: ("range",),
}
MAX_TILT = math.radians(30.0)


def is_loopback(host: str) -> bool:
    """``host`` is this machine's own (a name that resolves elsewhere is not)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass
class LinkFaults:
    loss: float = 0.0  # probability a frame is lost
    corrupt: float = 0.0  # probability a frame has one byte flipped
    burst_every: float = 0.0  # mean seconds between loss bursts (0: none)
    burst_len: float = 0.0  # seconds each burst lasts


class SimBridge:
    def __init__(
        self,
        scenario: Scenario,
        *,
        udp_to: tuple[str, int] | None = None,
        pty: PtyPort | None = None,
        board: PtyPort | None = None,
        faults: LinkFaults | None = None,
        speed: float = 1.0,
        command_timeout: float = 0.5,
        sysid: int = 1,
        signing_key: bytes | None = None,
        unasked_rate: float | None = UNASKED_RATE,
    ) -> None:
        """``signing_key``: MAVLink 2 signing required, as a vehicle with its signing set up: its
        frames signed, and anything unsigned, signed with another key, replayed or reflected refused
        (:class:`~drivers.mavlink.signing.SignatureCheck`, as the ground station checks: pymavlink's
        own check let one forged frame block the valid stream, and kept nothing across restarts).
        Over UDP it answers ``udp_to``, from a socket bound to loopback when ``udp_to`` is loopback; a
        datagram from elsewhere moves its answers there only when it carries a correctly signed frame.
        ``unasked_rate`` [Hz]: each stream's rate until it is asked for (None: every stream at its
        sensor's rate from the start, as a radio set up to stream)."""
        self.scenario = scenario
        self.sim = Simulator(scenario, command_timeout=command_timeout)
        self.sim.keep_truth = False
        self.encoder = MavlinkEncoder(scenario.vehicle, sysid=sysid, ground_alt=scenario.sensors.ground_alt)
        #: [s] between frames: a stream's (its sensor's name) or a derived message's (its name),
        #: while nobody has asked for it, and for a derived message asked at a rate
        self._every: dict[str, float] = (
            {n: 1.0 / unasked_rate for n in [*self.sim.sensors.rates, *DERIVED_FROM]} if unasked_rate else {}
        )
        self._last_out: dict[str, float] = {}
        #: messages sent on a schedule of their own: msg id -> [interval, next due] [s]: the
        #: position estimate (at its default rate until asked) and protocol messages asked for
        self._periodic: dict[int, list[float]] = {}
        if "gps" in self.sim.sensors.rates:
            rate = unasked_rate or self.sim.sensors.rates["gps"]
            self._periodic[mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT] = [1.0 / rate, 0.0]
        #: the autopilot's own: its parameters, and the height estimate it makes with them and sends
        self.autopilot = AutopilotParams()
        self.onboard = OnboardHeight(self.autopilot) if "baro" in self.sim.sensors.rates else None
        self.protocol = VehicleProtocol(self.sim, self.encoder.packer, self._send, sysid, self.autopilot)
        #: a DataFlash log of each flight, served over MAVLink's log protocol
        self.flight_logs = FlightLogs(
            scenario.vehicle,
            EPOCH,
            lambda: ((p.name, p.get()) for p in self.protocol.params),
            lambda: self.protocol.mode,
            height=self._onboard_heights if self.onboard is not None else None,
        )
        self.log_server = LogServer(self.flight_logs, self.encoder.packer, self._send, sysid)
        self.udp_to = udp_to
        self.pty = pty
        #: the sensor board's own serial port: binary frames (3-DOF helicopter)
        #: or an NMEA GPS receiver (quadcopter, coaxial helicopter)
        self.board = board
        self.board_encoder = BoardEncoder(scenario.vehicle, EPOCH) if board is not None else None
        self._board_rx = BinaryBoardReceiver("motor_board")
        self.faults = faults or LinkFaults()
        self.speed = speed
        self._rng = random.Random(scenario.seed + 7)
        self._sock: socket.socket | None = None
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        #: MAVLink 2 signing: the check every incoming frame passes before pymavlink parses it
        self.signing: SignatureCheck | None = None
        self._accepted: list[bytes] = []
        self._framer = Framer(
            lambda spec, fields, sysid, compid, seq, frame: self._accepted.append(frame),
            lambda m, sysid, compid, seq, frame: self._accepted.append(frame),
            lambda: None,
            lambda: None,
        )
        if signing_key is not None:
            state = SigningState(signing_key, role=f"vehicle-{sysid}")
            self.signing = SignatureCheck(signing_key, own=(sysid, 1), state=state)
            self._framer.signing = self.signing
            self._framer.on_refused = self._refused
            self.encoder.packer.sign_with(signing_key, after=state.local())
        self.frames_sent = 0
        self.frames_dropped = 0
        self.send_errors = 0
        self.received: dict[str, int] = {}
        self.commands_received = 0
        self.addressed_elsewhere = 0  # messages received that name another system id
        self.signature_refused = 0
        self._down_until = 0.0
        self._burst_until = 0.0
        self._next_burst = math.inf
        self._stop = asyncio.Event()
        self.truth_sink: Callable[[dict], None] | None = None  # for a live truth sidecar

    # -- transports --------------------------------------------------------------------------
    async def open(self) -> None:
        loop = asyncio.get_running_loop()
        if self.udp_to is not None:
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1" if is_loopback(self.udp_to[0]) else "0.0.0.0", 0))
            s.setblocking(False)
            self._sock = s
            loop.add_reader(s.fileno(), self._udp_readable)
        if self.pty is not None:
            self.pty.on_data = self._incoming
            if self.pty.master is None:
                self.pty.plug()
        if self.board is not None:
            self.board.on_data = self._board_incoming
            if self.board.master is None:
                self.board.plug()
        if self.faults.burst_every > 0:
            self._next_burst = self._rng.expovariate(1.0 / self.faults.burst_every)

    def close(self) -> None:
        self._stop.set()
        self.flight_logs.close()
        if self.signing is not None:
            self.signing.state.save()  # the timestamps seen, for the next start to refuse replays
        close_watched_socket(self._sock)
        self._sock = None
        if self.pty is not None:
            self.pty.close()
        if self.board is not None:
            self.board.close()

    def _udp_readable(self) -> None:
        if self._sock is None:
            return
        try:
            data, addr = self._sock.recvfrom(65536)
        except (BlockingIOError, OSError):
            return
        authenticated = self._incoming(data)
        if addr != self.udp_to and authenticated:
            self.udp_to = addr  # a peer that holds the key: answered where it is

    def _send(self, frame: bytes) -> None:
        f, now = self.faults, time.monotonic()
        if now < self._down_until or now < self._burst_until or (f.loss and self._rng.random() < f.loss):
            self.frames_dropped += 1
            return
        if f.corrupt and self._rng.random() < f.corrupt:
            b = bytearray(frame)
            b[self._rng.randrange(1, len(b))] ^= 1 << self._rng.randrange(8)
            frame = bytes(b)
        if self._sock is not None and self.udp_to is not None:
            try:
                self._sock.sendto(frame, self.udp_to)
            except OSError:  # no listener yet (ICMP refused) or buffer full: counted
                self.send_errors += 1
        if self.pty is not None:
            self.pty.write(frame)
        self.frames_sent += 1

    def disconnect(self, seconds: float) -> None:
        """Go silent for ``seconds`` (a serial link is unplugged and plugged back)."""
        self._down_until = time.monotonic() + seconds
        if self.pty is not None:
            self.pty.unplug()
            asyncio.get_running_loop().call_later(seconds, self._replug)

    def _replug(self) -> None:
        if not self._stop.is_set() and self.pty is not None:
            self.pty.plug()

    # -- the ground station's messages --------------------------------------------------------
    def _refused(self) -> None:
        self.signature_refused += 1  # unsigned, another key's, replayed or our own come back

    def _incoming(self, data: bytes) -> bool:
        """Handle the ground station's bytes; whether they held a correctly signed frame."""
        if self.signing is not None:
            self._framer.feed(data)
            data, self._accepted = b"".join(self._accepted), []
            if not data:
                return False
        for m in self._parser.parse_buffer(data) or ():
            t = m.get_type()
            if t == "BAD_DATA":
                continue
            self.received[t] = self.received.get(t, 0) + 1
            if getattr(m, "target_system", 0) not in (0, self.protocol.sysid):
                self.addressed_elsewhere += 1  # for another vehicle: each one ignores the others'
            if t.startswith("MISSION_") and self.protocol.mission.on_message(m, self.sim.t):
                continue
            handler = getattr(self, "_on_" + t.lower(), None)
            if handler is not None:
                handler(m)
        return self.signing is not None  # (what got here passed the signature check)

    def _board_incoming(self, data: bytes) -> None:
        """The motor board's side: MOTORS frames (ground -> board) set the voltages
        while they keep coming (3-DOF helicopter); anything else is counted."""
        for m in self._board_rx.feed(data, time.time()):
            if m.kind is Kind.MOTOR_VOLTAGE and self.scenario.vehicle == "heli3dof":
                self.received["MOTORS"] = self.received.get("MOTORS", 0) + 1
                self.commands_received += 1
                self.sim.command(Heli3dofCommand(float(m.value[0]), float(m.value[1])))

    def _message_interval(self, m) -> int:
        """SET_MESSAGE_INTERVAL: a stream's rate (0: its default); UNSUPPORTED for a message it does not send."""
        cls = mavlink.mavlink_map.get(int(m.param1))
        name = cls.msgname if cls else ""
        rates = self.sim.sensors.rates
        interval = m.param2
        if DERIVED_FROM.get(name) in rates:
            if interval > 0:
                self._every[name] = interval * 1e-6
            elif interval == 0:
                self._every.pop(name, None)  # its default: with every sample of its sensor
            else:
                self._every[name] = math.inf
            return mavlink.MAV_RESULT_ACCEPTED
        stream = next((n for n in STREAM_OF_MESSAGE.get(name, ()) if n in rates), None)
        if stream is None:
            return self._protocol_interval(int(m.param1), interval)
        self._every.pop(stream, None)
        if interval > 0:
            self.sim.sensors.set_rate(stream, 1e6 / interval)
        elif interval == 0:
            self.sim.sensors.set_rate(stream, self.scenario.sensors.rates[stream])
        return mavlink.MAV_RESULT_ACCEPTED

    def _protocol_interval(self, msgid: int, interval_us: float) -> int:
        """A message on a schedule of its own (the position estimate; HOME_POSITION,
        EXTENDED_SYS_STATE, ... sent on request), now every ``interval_us`` (-1: never again; 0:
        its default: the position at the fix's rate, the others once a second)."""
        position = msgid == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT and "gps" in self.sim.sensors.rates
        if not (position or msgid in self.protocol.ON_REQUEST):
            return mavlink.MAV_RESULT_UNSUPPORTED  # (asked without making a frame: its sequence number)
        if interval_us < 0:
            self._periodic.pop(msgid, None)
        else:
            default = 1.0
            if msgid == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
                default = 1.0 / self.scenario.sensors.rates["gps"]
            self._periodic[msgid] = [interval_us * 1e-6 if interval_us > 0 else default, self.sim.t]
        return mavlink.MAV_RESULT_ACCEPTED

    def _periodic_frame(self, msgid: int) -> bytes | None:
        if msgid == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            return self._global_position() if "gps" in self.sim.sensors.rates else None
        return self.protocol.message(msgid)

    def _on_command_long(self, m) -> None:
        self.protocol.command(m, self._message_interval)

    def _on_command_int(self, m) -> None:
        self.protocol.command(m, self._message_interval)

    def _on_param_request_list(self, m) -> None:
        self.protocol.on_param_request_list(m)

    def _on_param_request_read(self, m) -> None:
        self.protocol.on_param_request_read(m)

    def _on_param_set(self, m) -> None:
        self.protocol.on_param_set(m)

    def _on_ping(self, m) -> None:
        self.protocol.on_ping(m)

    def _on_file_transfer_protocol(self, m) -> None:
        self.protocol.on_file_transfer(m)

    def _on_log_request_list(self, m) -> None:
        self.log_server.on_log_request_list(m)

    def _on_log_request_data(self, m) -> None:
        self.log_server.on_log_request_data(m)

    def _on_log_request_end(self, m) -> None:
        self.log_server.on_log_request_end(m)

    def _on_log_erase(self, m) -> None:
        self.log_server.on_log_erase(m)

    def _on_request_data_stream(self, m) -> None:
        groups = DATA_STREAM_GROUPS.values() if m.req_stream_id == mavlink.MAV_DATA_STREAM_ALL else ()
        streams = [n for g in groups for n in g] or DATA_STREAM_GROUPS.get(m.req_stream_id, ())
        for stream in streams:
            self._every.pop(stream, None)
            for name, sensor in DERIVED_FROM.items():
                if sensor == stream:
                    self._every.pop(name, None)
            if m.start_stop and m.req_message_rate > 0:
                self.sim.sensors.set_rate(stream, float(m.req_message_rate))
        position = (mavlink.MAV_DATA_STREAM_POSITION, mavlink.MAV_DATA_STREAM_ALL)
        if m.req_stream_id in position and m.start_stop and m.req_message_rate > 0:
            self._protocol_interval(mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 1e6 / m.req_message_rate)

    def _on_manual_control(self, m) -> None:
        if m.target not in (0, self.encoder.packer.sysid):
            return
        x, y, z, r = m.x / 1000.0, m.y / 1000.0, m.z / 1000.0, m.r / 1000.0
        v = self.scenario.vehicle
        cmd: QuadCommand | Heli3dofCommand
        if v == "quad":
            cmd = QuadCommand(z, y * MAX_TILT, -x * MAX_TILT, r * 2.0)
        elif v == "coax":
            # stabilised, as an autopilot flies MANUAL_CONTROL: collective, roll and pitch
            # setpoints, yaw rate; the coax's own inner loop turns them into flapping angles
            ap = self.sim.autopilot
            assert isinstance(ap, CoaxAutopilot)
            self.commands_received += 1
            self.sim.command(lambda t, dt: ap.stabilised(z, y * MAX_TILT, -x * MAX_TILT, r * 2.0))
            return
        else:
            rig = self.sim.vehicle
            assert isinstance(rig, Heli3dof)
            vs, vd = 2 * rig.p.V_max * z, rig.p.V_max * y
            cmd = Heli3dofCommand((vs - vd) / 2, (vs + vd) / 2)
        self.commands_received += 1
        self.sim.command(cmd)

    def _on_set_attitude_target(self, m) -> None:
        if m.target_system not in (0, self.encoder.packer.sysid) or self.scenario.vehicle != "quad":
            return
        w, x, y, z = m.q
        roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
        self.commands_received += 1
        self.sim.command(QuadCommand(m.thrust, roll, pitch, m.body_yaw_rate))

    # -- running -------------------------------------------------------------------------------
    def _tick(self, target_t: float) -> None:
        sim, enc = self.sim, self.encoder
        while sim.t + 0.5 * sim.dt < target_t:
            samples = [self._onboard(s) for s in sim.step()]
            self.flight_logs.step(sim.t, samples, self.protocol.armed)
            if sim.step_count % int(round(1.0 / sim.dt)) == 1:
                self._send(enc.heartbeat(self.protocol.armed, self.protocol.mode))
                self._send(self.protocol.extended_sys_state())
            for msgid, due in self._periodic.items():
                if sim.t >= due[1]:
                    due[1] += max(due[0], sim.dt)
                    frame = self._periodic_frame(msgid)
                    if frame is not None:
                        self._send(frame)
            for s in samples:
                if self._due(s.sensor, s.t):
                    for fr in enc.encode(s):
                        self._send(fr)
                if s.sensor == "battery" and self._due("BATTERY_STATUS", s.t):
                    self._send(enc.battery_status(*s.values))
                if self.board_encoder is not None and self.board is not None:
                    for fr in self.board_encoder.encode(s):
                        self.board.write(fr)
            if self.truth_sink is not None and sim.step_count % sim.truth_every == 0:
                self.truth_sink(sim.truth())
        self.protocol.tick()
        self.log_server.pump()
        if self.faults.burst_every > 0 and sim.t >= self._next_burst:
            self._burst_until = time.monotonic() + self.faults.burst_len
            self._next_burst = sim.t + self._rng.expovariate(1.0 / self.faults.burst_every)

    def _onboard(self, s: Sample) -> Sample:
        """What the autopilot makes of a sample: the IMU's z calibrated (``INS_ACCOFFS_Z``,
        ``INS_ACCSCAL_Z``: what it logs and sends), and its height estimate fed."""
        if s.sensor == "imu":
            v = list(s.values)
            v[2] = (v[2] - self.autopilot["INS_ACCOFFS_Z"]) * self.autopilot["INS_ACCSCAL_Z"]
            s = Sample(s.t, s.sensor, tuple(v))
            if self.onboard is not None:
                self.onboard.imu(s.t, v[:3], self.sim.vehicle.kin.R)
        elif s.sensor == "baro" and self.onboard is not None:
            self.onboard.baro(s.t, s.values[0], float(getattr(self.sim.vehicle, "throttle", 0.0)))
        return s

    def _onboard_heights(self) -> tuple[float, float]:
        assert self.onboard is not None
        return self.onboard.height, self.onboard.baro_height

    def _global_position(self) -> bytes:
        """The autopilot's position estimate: north and east the true state, which the simulator's
        autopilot flies on (profile.py), about the GPS model's origin, where it was switched on:
        home, set with the first estimate it sends; the height its own estimate
        (:mod:`.onboard_height`). LOCAL_POSITION_NED goes with it."""
        kin, cfg = self.sim.vehicle.kin, self.sim.sensors.cfg
        lat0, lon0 = cfg.gps_origin
        if self.protocol.home is None:
            self.protocol.home = (lat0, lon0, cfg.ground_alt)
        n, e, d = (float(v) for v in kin.pos)
        vel = [float(v) for v in kin.vel]
        if self.onboard is not None:
            d, vel[2] = -self.onboard.height, -self.onboard.climb_rate
        lat = lat0 + n / M_PER_DEG
        lon = lon0 + e / (M_PER_DEG * math.cos(math.radians(lat0)))
        self._send(self.encoder.local_position(self.sim.t, (n, e, d), vel))
        return self.encoder.global_position(self.sim.t, lat, lon, cfg.ground_alt - d, -d, vel)

    def _due(self, key: str, t: float) -> bool:
        """Whether a stream's sample, or a derived message, goes out at ``t`` (:attr:`_every`)."""
        every = self._every.get(key)
        if every is None:
            return True
        if t - self._last_out.get(key, -math.inf) < every - 1e-9:
            return False
        self._last_out[key] = t
        return True

    async def run(self, duration: float | None = None, tick: float = TICK, catch_up: float = MAX_CATCH_UP) -> None:
        """Run in real time (times ``speed``) until ``duration`` or :meth:`close`.

        The vehicle catches up at most ``catch_up`` s of the wall clock at once: a longer
        stall of the process (a loaded machine; the ground station shares it in tests and the demo)
        pauses the simulated world with it. Run on, it jumped on the last command, a latency the
        vehicle's controllers never had: a 0.2 s stall 0.5 s into the 3-DOF rig's PD step (designed
        omega 4 rad/s, zeta 0.7) had it fitted at 5.72 rad/s and 1.06; paused, 4.05-4.35 and 0.67-0.74
        over six stalls 0.2-0.7 s into it (4.11-4.33 and 0.70-0.74 without a stall). The world runs
        behind the wall clock after each stall, as a simulator whose real-time factor drops does.
        ``catch_up`` as short as a ``tick`` holds the world to its controller in lockstep: on a
        loaded machine each wait of the process, up to :data:`MAX_CATCH_UP` at the default, runs the
        vehicle on a command its controller had no chance to change, a latency a rig on its own
        hardware does not have (a test that measures a control loop's response wants none of it)."""
        start = time.monotonic()
        t0 = self.sim.t
        while not self._stop.is_set():
            target = t0 + (time.monotonic() - start) * self.speed
            lag = target - self.sim.t - catch_up * self.speed
            if lag > 0.0:  # a stall: the world paused with the process
                start += lag / self.speed
                target -= lag
            if duration is not None:
                target = min(target, t0 + duration)
            self._tick(target)
            if duration is not None and self.sim.t + 0.5 * self.sim.dt >= t0 + duration:
                break
            try:
                await asyncio.wait_for(self._stop.wait(), tick)
            except TimeoutError:
                pass
