"""Simulator samples to MAVLink 2 frames, as a flight controller would send them.

=========  ===================  ===========================================================
sensor     message              wire units
=========  ===================  ===========================================================
imu        HIGHRES_IMU          m/s^2, rad/s (fields_updated = accel + gyro)
baro       SCALED_PRESSURE      hPa, cdegC
range      DISTANCE_SENSOR      cm (so 1 cm quantisation), downward (PITCH_270), laser
gps        GPS_RAW_INT          1e-7 deg, mm AMSL, cm/s; h_acc/v_acc in mm
attitude   ATTITUDE             rad, rad/s
actuators  SERVO_OUTPUT_RAW     us (1000 + 1000 x output); VFR_HUD throttle every 5th
battery    SYS_STATUS           mV, cA, %
encoders   ATTITUDE             (3-DOF helicopter: roll = p, pitch = e, yaw = lambda is
                                exactly the arm frame's Euler angles)
=========  ===================  ===========================================================

Vehicle time is time since boot: ``time_boot_ms``/``time_usec`` from the
simulator's clock. Frames are packed here with pymavlink's own definitions
(payload ``struct``, CRC_EXTRA) and ``fastcrc``: building a pymavlink message
object per sample costs more than the whole simulation step. MAVLink 2 payloads
are zero-truncated as the protocol prescribes. Sequence numbers are real.
"""

from __future__ import annotations

import hashlib
import math
import struct

from fastcrc import crc16
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.mavlink.signing import timestamp_now
from groundstation.core.atmosphere import altitude_at

from .simulator import Sample

_HDR = struct.Struct("<BBBBBBBHB")
_CRC = struct.Struct("<H")


class FramePacker:
    """MAVLink 2 frames from field values in wire order, with real sequence numbers."""

    def __init__(self, sysid: int = 1, compid: int = 1) -> None:
        self.sysid, self.compid = sysid, compid
        self.seq = 0
        self._specs: dict[str, tuple] = {}
        #: MAVLink 2 signing (drivers.mavlink.signing): every frame signed with this key
        self.signing_key: bytes | None = None
        self._sign_ts = 0

    def sign_with(self, key: bytes | None, after: int = 0) -> None:
        """Sign every frame with ``key``, timestamps from now or, where later, from ``after`` (the
        timestamp stored when the key was last used: the specification's, across restarts)."""
        self.signing_key = key
        self._sign_ts = max(timestamp_now(), after)

    def _signed(self, frame: bytes) -> bytes:
        """The frame with its signature block: link id 0, the timestamp, SHA-256(key + all before)[:6]."""
        self._sign_ts += 1
        block = frame + b"\x00" + self._sign_ts.to_bytes(6, "little")
        return block + hashlib.sha256(self.signing_key + block).digest()[:6]  # type: ignore[operator]

    def _spec(self, name: str):
        s = self._specs.get(name)
        if s is None:
            cls = mavlink.mavlink_map[getattr(mavlink, f"MAVLINK_MSG_ID_{name}")]
            order = tuple(zip(cls.ordered_fieldnames, cls.lengths))
            s = self._specs[name] = (
                cls.id,
                cls.unpacker.pack,
                bytes([cls.crc_extra]),
                order,
                any(n > 1 for _, n in order),
            )
        return s

    def pack(self, name: str, **fields) -> bytes:
        msgid, pack, extra, order, has_arrays = self._spec(name)
        vals: list
        if has_arrays:  # array fields are several struct values
            vals = []
            for f, n in order:
                v = fields.get(f, 0)
                vals.extend(v if n > 1 and v else [0] * n) if n > 1 else vals.append(v)
        else:
            vals = [fields.get(f, 0) for f, _ in order]
        payload = pack(*vals).rstrip(b"\x00") or b"\x00"
        flags = 1 if self.signing_key is not None else 0
        hdr = _HDR.pack(0xFD, len(payload), flags, 0, self.seq, self.sysid, self.compid, msgid & 0xFFFF, msgid >> 16)
        self.seq = (self.seq + 1) & 0xFF
        body = hdr[1:] + payload
        crc = crc16.mcrf4xx(extra, crc16.mcrf4xx(body))
        frame = hdr[:1] + body + struct.pack("<H", crc)
        return self._signed(frame) if flags else frame

    def pack_ordered(self, name: str, values) -> bytes:
        """As :meth:`pack`, with every value given in wire order (the hot path)."""
        msgid, pack, extra, _, _ = self._spec(name)
        payload = pack(*values).rstrip(b"\x00") or b"\x00"
        flags = 1 if self.signing_key is not None else 0
        hdr = _HDR.pack(0xFD, len(payload), flags, 0, self.seq, self.sysid, self.compid, msgid & 0xFFFF, msgid >> 16)
        self.seq = (self.seq + 1) & 0xFF
        body = hdr[1:] + payload
        frame = hdr[:1] + body + _CRC.pack(crc16.mcrf4xx(extra, crc16.mcrf4xx(body)))
        return self._signed(frame) if flags else frame

    def pack_message(self, msg) -> bytes:
        """A pymavlink message object (rare messages: heartbeats, ACKs)."""
        enc = mavlink.MAVLink(None, self.sysid, self.compid)
        enc.seq = self.seq
        if self.signing_key is not None:
            self._sign_ts += 1
            enc.signing.secret_key, enc.signing.sign_outgoing, enc.signing.timestamp = (
                self.signing_key,
                True,
                self._sign_ts,
            )
        self.seq = (self.seq + 1) & 0xFF
        return bytes(msg.pack(enc))


#: The sensor stream each message is sent with, hence requested by (SET_MESSAGE_INTERVAL): the
#: first of these the vehicle has; a request for any other message is answered UNSUPPORTED.
STREAM_OF_MESSAGE: dict[str, tuple[str, ...]] = {
    "HIGHRES_IMU": ("imu",),
    "SCALED_PRESSURE": ("baro",),
    "DISTANCE_SENSOR": ("range",),
    "GPS_RAW_INT": ("gps",),
    "ATTITUDE": ("attitude", "encoders"),  # the 3-DOF rig's encoder angles go out as ATTITUDE
    "SERVO_OUTPUT_RAW": ("actuators",),
    "SYS_STATUS": ("battery",),
}

#: What an autopilot's battery monitor sends, here with the battery's readings: message -> that
#: sensor. Asked for, it goes out at its own rate, at most the sensor's, without changing the
#: sensor's. (The position estimate, GLOBAL_POSITION_INT, has a schedule of its own: bridge.py.)
DERIVED_FROM = {"BATTERY_STATUS": "battery"}


class MavlinkEncoder:
    def __init__(self, vehicle: str, *, sysid: int = 1, compid: int = 1, ground_alt: float = 120.0) -> None:
        self.vehicle = vehicle
        self.packer = FramePacker(sysid, compid)
        self.ground_alt = ground_alt
        self._n_act = 0
        self._last_baro_alt = 0.0

    def encode(self, s: Sample) -> list[bytes]:
        """The sensor's own messages (what a log of the sensors holds: ``sim --fast``)."""
        return getattr(self, "_" + s.sensor)(s)

    def heartbeat(self, armed: bool, mode: int = 0) -> bytes:
        """As an ArduPilot vehicle sends it: its type, ArduPilot's autopilot id (a ground station
        then reads ``mode`` as ArduCopter's mode number), armed in the base mode."""
        mav_type = {
            "quad": mavlink.MAV_TYPE_QUADROTOR,
            "coax": mavlink.MAV_TYPE_COAXIAL,
            "heli3dof": mavlink.MAV_TYPE_HELICOPTER,
        }[self.vehicle]
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
        state = mavlink.MAV_STATE_ACTIVE if armed else mavlink.MAV_STATE_STANDBY
        return self.packer.pack(
            "HEARTBEAT",
            type=mav_type,
            autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
            base_mode=base,
            custom_mode=mode,
            system_status=state,
            mavlink_version=3,
        )

    def _imu(self, s):
        v = s.values
        # wire order: time_usec, acc xyz, gyro xyz, mag xyz, abs/diff pressure, pressure_alt,
        # temperature, fields_updated (accel + gyro), id
        return [
            self.packer.pack_ordered(
                "HIGHRES_IMU",
                (int(round(s.t * 1e6)), v[0], v[1], v[2], v[3], v[4], v[5], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0x3F, 0),
            )
        ]

    def _baro(self, s):
        p, temp = s.values
        self._last_baro_alt = float(altitude_at(p))
        return [
            self.packer.pack(
                "SCALED_PRESSURE",
                time_boot_ms=int(round(s.t * 1e3)),
                press_abs=p / 100.0,
                temperature=int(round((temp - 273.15) * 100)),
            )
        ]

    def _range(self, s):
        d = s.values[0]
        return [
            self.packer.pack(
                "DISTANCE_SENSOR",
                time_boot_ms=int(round(s.t * 1e3)),
                min_distance=5,
                max_distance=400,
                current_distance=max(0, min(65535, int(round(d * 100)))),
                type=mavlink.MAV_DISTANCE_SENSOR_LASER,
                id=0,
                orientation=mavlink.MAV_SENSOR_ROTATION_PITCH_270,
                covariance=1,
            )
        ]

    def _gps(self, s):
        lat, lon, alt, vn, ve, vd, h_acc, v_acc = s.values
        return [
            self.packer.pack(
                "GPS_RAW_INT",
                time_usec=int(round(s.t * 1e6)),
                fix_type=3,
                lat=int(round(lat * 1e7)),
                lon=int(round(lon * 1e7)),
                alt=int(round(alt * 1e3)),
                eph=80,
                epv=120,
                vel=int(round(math.hypot(vn, ve) * 100)),
                cog=int(round(math.degrees(math.atan2(ve, vn)) % 360 * 100)),
                satellites_visible=12,
                alt_ellipsoid=int(round(alt * 1e3)),
                h_acc=int(h_acc * 1e3),
                v_acc=int(v_acc * 1e3),
            )
        ]

    def global_position(self, t: float, lat: float, lon: float, alt: float, height: float, vel) -> bytes:
        """GLOBAL_POSITION_INT: the autopilot's position estimate (lat, lon [deg], alt AMSL and
        height above home [m], NED velocity [m/s]), its heading from the course (cdeg)."""
        vn, ve, vd = (float(v) for v in vel)
        return self.packer.pack(
            "GLOBAL_POSITION_INT",
            time_boot_ms=int(round(t * 1e3)) & 0xFFFFFFFF,
            lat=int(round(lat * 1e7)),
            lon=int(round(lon * 1e7)),
            alt=int(round(alt * 1e3)),
            relative_alt=int(round(height * 1e3)),
            vx=int(round(vn * 100)),
            vy=int(round(ve * 100)),
            vz=int(round(vd * 100)),
            hdg=int(round(math.degrees(math.atan2(ve, vn)) % 360 * 100)) if math.hypot(vn, ve) > 0.5 else 65535,
        )

    def local_position(self, t: float, ned, vel) -> bytes:
        """LOCAL_POSITION_NED: the autopilot's estimate about its origin [m, m/s]."""
        (x, y, z), (vx, vy, vz) = ned, vel
        return self.packer.pack(
            "LOCAL_POSITION_NED", time_boot_ms=int(round(t * 1e3)) & 0xFFFFFFFF, x=x, y=y, z=z, vx=vx, vy=vy, vz=vz
        )

    def _attitude(self, s):
        r, p, y, wx, wy, wz = s.values
        return [
            self.packer.pack(
                "ATTITUDE",
                time_boot_ms=int(round(s.t * 1e3)),
                roll=r,
                pitch=p,
                yaw=y,
                rollspeed=wx,
                pitchspeed=wy,
                yawspeed=wz,
            )
        ]

    def _encoders(self, s):
        p, e, lam = s.values
        return [self.packer.pack("ATTITUDE", time_boot_ms=int(round(s.t * 1e3)), roll=p, pitch=e, yaw=lam)]

    def _actuators(self, s):
        pwm = {f"servo{i + 1}_raw": int(round(1000 + 1000 * min(1.0, max(0.0, v)))) for i, v in enumerate(s.values)}
        out = [self.packer.pack("SERVO_OUTPUT_RAW", time_usec=int(round(s.t * 1e6)) & 0xFFFFFFFF, port=0, **pwm)]
        self._n_act += 1
        if self._n_act % 5 == 0:
            thr = sum(s.values[:2]) / 2 if self.vehicle != "quad" else s.values[0]
            # VFR_HUD's altitude is the autopilot's: here the barometer's pressure altitude
            out.append(self.packer.pack("VFR_HUD", throttle=int(round(100 * thr)), alt=self._last_baro_alt))
        return out

    #: the sensors SYS_STATUS says are present, enabled and healthy (all of them: nothing fails here)
    SENSOR_BITS = (
        mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
        | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
        | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
        | mavlink.MAV_SYS_STATUS_SENSOR_GPS
        | mavlink.MAV_SYS_STATUS_SENSOR_LASER_POSITION
        | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
        | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
        | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
        | mavlink.MAV_SYS_STATUS_AHRS
        | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
        | mavlink.MAV_SYS_STATUS_PREARM_CHECK  # its pre-arm checks pass (what MAVSDK reads as armable)
    )

    def _battery(self, s):
        v, i, soc = s.values
        bits = self.SENSOR_BITS
        return [
            self.packer.pack(
                "SYS_STATUS",
                onboard_control_sensors_present=bits,
                onboard_control_sensors_enabled=bits,
                # ArduPilot reports the fence healthy (not breached) whether or not one is set up
                onboard_control_sensors_health=bits | mavlink.MAV_SYS_STATUS_GEOFENCE,
                voltage_battery=int(round(v * 1000)),
                current_battery=int(round(i * 100)),
                battery_remaining=percent(soc),
            )
        ]

    def battery_status(self, v: float, i: float, soc: float) -> bytes:
        return self.packer.pack(
            "BATTERY_STATUS",
            id=0,
            battery_function=mavlink.MAV_BATTERY_FUNCTION_ALL,
            type=mavlink.MAV_BATTERY_TYPE_LIPO,
            temperature=32767,  # unknown
            voltages=[min(65534, int(round(v * 1000)))] + [65535] * 9,
            current_battery=int(round(i * 100)),
            current_consumed=-1,
            energy_consumed=-1,
            battery_remaining=percent(soc),
        )


def percent(soc: float) -> int:
    """A state of charge as MAVLink's battery_remaining: a whole percent, 0 to 100."""
    return min(100, max(0, int(round(soc * 100))))
