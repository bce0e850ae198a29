"""What the simulated vehicle answers a ground station beyond its telemetry, as an ArduPilot
vehicle does: parameters, commands with addressed acknowledgements, flight modes, arming,
its version, ping and the mission (:mod:`.mission`).

* **Parameters**: the vehicle model's physical constants and the sensors' noise and rates, as
  ``SIM_*`` parameters (REAL32), plus ``SYSID_THISMAV`` and the ArduPilot parameters a diagnosis
  writes (:mod:`.autopilot_params`: a value outside its documented range is refused, the echo
  carrying the value kept); PARAM_REQUEST_LIST streams them all,
  PARAM_REQUEST_READ reads one by name or index, PARAM_SET changes the running simulation and
  echoes the new value (an unknown name gets no answer, as ArduPilot gives none).
* **Commands** (COMMAND_LONG and COMMAND_INT), each answered with a COMMAND_ACK addressed to the
  sender: arm/disarm (disarming in flight is refused unless forced with 21196, as ArduPilot does),
  takeoff (refused unless armed), land, DO_SET_MODE (ArduCopter's mode numbers), message interval
  (the streams, :mod:`.mavlink_out`), REQUEST_MESSAGE and REQUEST_AUTOPILOT_CAPABILITIES
  (AUTOPILOT_VERSION, HOME_POSITION); anything else UNSUPPORTED.
* **PING** answered to its sender; **MAVFTP** refused (no files: :meth:`VehicleProtocol.on_file_transfer`).

On the guided flight (``flight="guided"``, :class:`~sim_bridge.profile.GuidedProfile`) the
commands fly the vehicle, as on ArduCopter SITL: it waits on the ground until armed; takeoff
climbs to the altitude asked (param7, above home; GUIDED); LAND and RTL come down (RTL over
home first) and disarm on touching down; AUTO flies the mission; MISSION_START (300) is AUTO.
On the built-in flights the flight stays the simulator's (its profile, or the ground station's
MANUAL_CONTROL / SET_ATTITUDE_TARGET): arming and modes there are what the vehicle *reports*.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.mavlink.commands import MODE_NUMBERS

from .autopilot_params import AutopilotParams
from .mavlink_out import FramePacker
from .mission import Mission
from .profile import GuidedProfile

#: the ArduCopter flight modes (drivers.mavlink.commands.COPTER_MODES) the simulated vehicle accepts
ACCEPTED_MODES = {
    MODE_NUMBERS[n] for n in ("STABILIZE", "ALT_HOLD", "AUTO", "GUIDED", "LOITER", "RTL", "LAND", "POSHOLD")
}
MODE_GUIDED, MODE_LAND, MODE_LOITER = MODE_NUMBERS["GUIDED"], MODE_NUMBERS["LAND"], MODE_NUMBERS["LOITER"]
MODE_AUTO, MODE_RTL = MODE_NUMBERS["AUTO"], MODE_NUMBERS["RTL"]
#: MAVFTP (https://mavlink.io/en/services/ftp.html): opcodes and error codes used here
FTP_TERMINATE_SESSION, FTP_RESET_SESSIONS, FTP_ACK, FTP_NAK = 1, 2, 128, 129
FTP_OPENS = frozenset((3, 4, 6, 11))  # ListDirectory, OpenFileRO, CreateFile, OpenFileWO
FTP_ERR_UNKNOWN_COMMAND, FTP_ERR_FILE_NOT_FOUND = 7, 10
TAKEOFF_DEFAULT = 2.5  # [m] a takeoff without an altitude climbs this high (as MAVSDK's default)
FORCE_DISARM = 21196  # ArduPilot's magic number for a disarm in flight
FIRMWARE_VERSION = (4 << 24) | (5 << 16) | (0 << 8) | 255  # reported as 4.5.0 (official)


@dataclasses.dataclass
class _Param:
    name: str
    get: Callable[[], float]
    set: Callable[[float], None] | None  # None: read-only


class VehicleProtocol:
    def __init__(
        self,
        sim,
        packer: FramePacker,
        send: Callable[[bytes], None],
        sysid: int,
        autopilot: AutopilotParams | None = None,
    ) -> None:
        self.sim = sim
        #: the ArduPilot parameters a diagnosis writes, kept within their documented ranges
        self.autopilot = autopilot or AutopilotParams()
        self.packer = packer
        self.send = send
        self.sysid = sysid
        self.armed_cmd: bool | None = None  # arming by command overrides the flight profile's
        #: the guided flight, which the commands fly (None: the built-in flight, reported only)
        self.guided = sim.profile if isinstance(sim.profile, GuidedProfile) else None
        self.mode = MODE_GUIDED if self.guided is not None else MODE_LOITER
        self.params = self._parameters()
        self.home: tuple[float, float, float] | None = None  # lat, lon [deg], alt AMSL [m]
        self.mission = Mission(packer, send, sysid, self._home_or_origin)

    # -- parameters -----------------------------------------------------------------------------
    def _parameters(self) -> list[_Param]:
        out = [_Param("SYSID_THISMAV", lambda: float(self.sysid), None)]
        for owner, prefix in ((getattr(self.sim.vehicle, "p", None), "SIM_"), (self.sim.sensors.cfg, "SIM_S_")):
            if owner is None or not dataclasses.is_dataclass(owner):
                continue
            for f in dataclasses.fields(owner):
                v = getattr(owner, f.name)
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    continue
                name = (prefix + f.name.upper())[:16]
                out.append(_Param(name, _getter(owner, f.name), _setter(owner, f.name, type(v))))
        for stream in sorted(self.sim.sensors.rates):
            name = f"SIM_RATE_{stream.upper()}"[:16]
            out.append(_Param(name, _rate_getter(self.sim, stream), _rate_setter(self.sim, stream)))
        for name in sorted(self.autopilot.values):
            out.append(_Param(name, _autopilot_getter(self.autopilot, name), _autopilot_setter(self.autopilot, name)))
        return out

    def _param_value(self, k: int) -> bytes:
        p = self.params[k]
        return self.packer.pack(
            "PARAM_VALUE",
            param_id=p.name.encode(),
            param_value=float(p.get()),
            param_type=mavlink.MAV_PARAM_TYPE_REAL32,
            param_count=len(self.params),
            param_index=k,
        )

    def _index(self, name: str) -> int | None:
        for k, p in enumerate(self.params):
            if p.name == name:
                return k
        return None

    def on_param_request_list(self, m) -> None:
        if _for_me(m, self.sysid):
            for k in range(len(self.params)):
                self.send(self._param_value(k))

    def on_param_request_read(self, m) -> None:
        if not _for_me(m, self.sysid):
            return
        k = _name(m.param_id) if m.param_index < 0 else m.param_index
        idx = self._index(k) if isinstance(k, str) else (k if 0 <= k < len(self.params) else None)
        if idx is not None:
            self.send(self._param_value(idx))

    def on_param_set(self, m) -> None:
        if not _for_me(m, self.sysid):
            return
        idx = self._index(_name(m.param_id))
        if idx is None or not math.isfinite(m.param_value):
            return  # unknown or not a number: no answer, as ArduPilot (the sender sees no echo)
        p = self.params[idx]
        if p.set is not None:
            p.set(float(m.param_value))
        self.send(self._param_value(idx))

    # -- commands -------------------------------------------------------------------------------
    def ack(self, m, result: int) -> None:
        src_sys, src_comp = _sender(m)
        self.send(
            self.packer.pack(
                "COMMAND_ACK", command=m.command, result=result, target_system=src_sys, target_component=src_comp
            )
        )

    def command(self, m, message_interval: Callable[[object], int]) -> None:
        """A COMMAND_LONG or COMMAND_INT addressed to us: act and acknowledge."""
        if not _for_me(m, self.sysid):
            return
        c = m.command
        if c == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = message_interval(m)
        elif c == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            result = self._arm(m)
        elif c == mavlink.MAV_CMD_DO_SET_MODE:
            mode = int(m.param2)
            if mode in ACCEPTED_MODES and int(m.param1) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                result = self.set_mode(mode)
            else:
                result = mavlink.MAV_RESULT_DENIED
        elif c == mavlink.MAV_CMD_MISSION_START:
            result = self.set_mode(MODE_AUTO)
        elif c == mavlink.MAV_CMD_NAV_TAKEOFF:
            result = self._takeoff(m.param7)
        elif c == mavlink.MAV_CMD_NAV_LAND:
            result = self.set_mode(MODE_LAND)
        elif c == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self.send(self.autopilot_version())
            result = mavlink.MAV_RESULT_ACCEPTED
        elif c == mavlink.MAV_CMD_REQUEST_MESSAGE:
            frame = self.message(int(m.param1))
            if frame is not None:
                self.send(frame)
            result = mavlink.MAV_RESULT_ACCEPTED if frame is not None else mavlink.MAV_RESULT_UNSUPPORTED
        else:
            result = mavlink.MAV_RESULT_UNSUPPORTED
        self.ack(m, result)

    def _arm(self, m) -> int:
        if m.param1 == 1:
            self.armed_cmd = True
            if self.guided is not None:
                self.guided.armed = True
            return mavlink.MAV_RESULT_ACCEPTED
        if not self.on_ground and int(m.param2) != FORCE_DISARM:
            return mavlink.MAV_RESULT_DENIED  # in flight: only a forced disarm stops the motors
        self.armed_cmd = False
        if self.guided is not None:
            self.guided.armed = self.guided.flying = self.guided.landing = False
        return mavlink.MAV_RESULT_ACCEPTED

    def _takeoff(self, altitude: float) -> int:
        """Refused unless armed; on the guided flight, refused outside GUIDED (as ArduCopter)."""
        if not self.armed:
            return mavlink.MAV_RESULT_DENIED
        if self.guided is None:
            self.mode = MODE_GUIDED
            return mavlink.MAV_RESULT_ACCEPTED
        if self.mode != MODE_GUIDED:
            return mavlink.MAV_RESULT_DENIED
        height = altitude if math.isfinite(altitude) and altitude > 0 else TAKEOFF_DEFAULT
        if self.guided.flying:
            self.guided.climb_to(self.sim.t, height)
        else:
            self.guided.takeoff(self.sim.t, height)
        return mavlink.MAV_RESULT_ACCEPTED

    def set_mode(self, mode: int) -> int:
        """Change the flight mode; on the guided flight it acts: LAND comes down where it is, RTL
        over home first, AUTO flies the mission from its current item (refused without one past
        home, as ArduCopter refuses it), GUIDED holds where it is."""
        g = self.guided
        if g is not None and mode == MODE_AUTO and len(self.mission.items) < 2:
            return mavlink.MAV_RESULT_DENIED
        if g is not None and mode != self.mode:
            t = self.sim.t
            if mode == MODE_LAND:
                g.land(t)
            elif mode == MODE_RTL:
                g.go_to(t, 0.0, 0.0)
            elif mode == MODE_AUTO:
                self.mission.resume()
            elif g.flying and not g.landing:
                sp = g(t)
                g.climb_to(t, sp.height)
                g.go_to(t, sp.north, sp.east)
        self.mode = mode
        return mavlink.MAV_RESULT_ACCEPTED

    def tick(self) -> None:
        """Each step of the bridge: the mission's uploads time out; on the guided flight, AUTO
        flies on, RTL comes down once over home, and a landing ends disarmed."""
        t = self.sim.t
        self.mission.timeouts(t)
        g = self.guided
        if g is None:
            return
        kin = self.sim.vehicle.kin
        position = (float(kin.pos[0]), float(kin.pos[1]))
        if self.mode == MODE_AUTO and g.armed:
            self.mission.fly(g, t, self.on_ground, position)
        elif self.mode == MODE_RTL and g.flying and not g.landing and g.arrived(t):
            g.land(t)
        if g.landed(t, self.on_ground):
            self.armed_cmd = False

    def _home_or_origin(self) -> tuple[float, float, float]:
        """Home: the first fix; before one, the GPS model's origin on the ground."""
        if self.home is not None:
            return self.home
        cfg = self.sim.sensors.cfg
        return (*cfg.gps_origin, cfg.ground_alt)

    @property
    def on_ground(self) -> bool:
        return bool(getattr(self.sim.vehicle, "on_ground", True))

    @property
    def armed(self) -> bool:
        if self.guided is not None:
            return self.guided.armed
        if self.armed_cmd is not None:
            return self.armed_cmd
        return bool(self.sim.profile(self.sim.t).armed or self.sim.externally_commanded)

    #: the messages :meth:`message` makes (sent on request, or at an interval asked for)
    ON_REQUEST = frozenset(
        (
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
        )
    )

    def message(self, msgid: int) -> bytes | None:
        """The protocol message with this id, as the vehicle sends it now (None: not one it sends)."""
        if msgid == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return self.autopilot_version()
        if msgid == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
            return self.home_position()
        if msgid == mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
            return self.extended_sys_state()
        return None

    def autopilot_version(self) -> bytes:
        caps = (
            mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
        )
        return self.packer.pack(
            "AUTOPILOT_VERSION",
            capabilities=caps,
            flight_sw_version=FIRMWARE_VERSION,
            middleware_sw_version=0,
            os_sw_version=0,
            board_version=0,
            flight_custom_version=b"\0" * 8,
            middleware_custom_version=b"\0" * 8,
            os_custom_version=b"\0" * 8,
            vendor_id=0,
            product_id=0,
            uid=self.sysid,
        )

    def home_position(self) -> bytes:
        lat, lon, alt = self._home_or_origin()
        return self.packer.pack(
            "HOME_POSITION",
            latitude=int(round(lat * 1e7)),
            longitude=int(round(lon * 1e7)),
            altitude=int(round(alt * 1e3)),
            x=0.0,
            y=0.0,
            z=0.0,
            q=[1.0, 0.0, 0.0, 0.0],
            approach_x=0.0,
            approach_y=0.0,
            approach_z=0.0,
        )

    def extended_sys_state(self) -> bytes:
        landed = mavlink.MAV_LANDED_STATE_ON_GROUND if self.on_ground else mavlink.MAV_LANDED_STATE_IN_AIR
        g = self.guided
        if g is not None and g.landing:
            landed = mavlink.MAV_LANDED_STATE_LANDING
        elif g is not None and g.flying and self.on_ground:
            landed = mavlink.MAV_LANDED_STATE_TAKEOFF
        return self.packer.pack("EXTENDED_SYS_STATE", vtol_state=0, landed_state=landed)

    def on_file_transfer(self, m) -> None:
        """MAVFTP: no file system here. Opening or listing anything is answered NAK FileNotFound
        (so a ground station fetching ``@PARAM/param.pck`` turns to the parameter protocol at
        once instead of after its timeouts), ending sessions ACK, anything else NAK UnknownCommand."""
        if getattr(m, "target_system", 0) not in (0, self.sysid):
            return
        req = bytes(m.payload)
        seq, session, opcode = int.from_bytes(req[0:2], "little"), req[2], req[3]
        if opcode in (FTP_TERMINATE_SESSION, FTP_RESET_SESSIONS):
            reply, data = FTP_ACK, b""
        else:
            error = FTP_ERR_FILE_NOT_FOUND if opcode in FTP_OPENS else FTP_ERR_UNKNOWN_COMMAND
            reply, data = FTP_NAK, bytes((error,))
        header = ((seq + 1) & 0xFFFF).to_bytes(2, "little") + bytes((session, reply, len(data), opcode, 0, 0))
        payload = header + bytes(4) + data  # offset 0
        src_sys, src_comp = _sender(m)
        self.send(
            self.packer.pack(
                "FILE_TRANSFER_PROTOCOL",
                target_network=0,
                target_system=src_sys,
                target_component=src_comp,
                payload=list(payload.ljust(251, b"\0")),
            )
        )

    def on_ping(self, m) -> None:
        if m.target_system == 0:  # a request (a reply names its target)
            src_sys, src_comp = _sender(m)
            self.send(
                self.packer.pack(
                    "PING", time_usec=m.time_usec, seq=m.seq, target_system=src_sys, target_component=src_comp
                )
            )


def _for_me(m, sysid: int) -> bool:
    return getattr(m, "target_system", 0) in (0, sysid)


def _sender(m) -> tuple[int, int]:
    return m.get_srcSystem(), m.get_srcComponent()


def _name(raw) -> str:
    return (raw.decode("latin-1") if isinstance(raw, bytes) else str(raw)).split("\0", 1)[0]


def _getter(owner, field: str) -> Callable[[], float]:
    return lambda: float(getattr(owner, field))


def _setter(owner, field: str, kind: type) -> Callable[[float], None]:
    def set_(v: float) -> None:
        setattr(owner, field, kind(round(v)) if kind is int else kind(v))

    return set_


def _autopilot_getter(params: AutopilotParams, name: str) -> Callable[[], float]:
    return lambda: params[name]


def _autopilot_setter(params: AutopilotParams, name: str) -> Callable[[float], None]:
    def set_(v: float) -> None:
        params.set(name, v)  # refused outside its documented range: the echo carries the value kept

    return set_


def _rate_getter(sim, stream: str) -> Callable[[], float]:
    return lambda: float(sim.sensors.rates.get(stream, 0.0))


def _rate_setter(sim, stream: str) -> Callable[[float], None]:
    return lambda v: sim.sensors.set_rate(stream, max(0.0, v))
