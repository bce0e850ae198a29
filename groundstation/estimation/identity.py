"""Which vehicle wrote a log, from what the log says of itself, and which models describe it.

The models come from rotorcraft documents: a coaxial helicopter's and a quadcopter's altitude and
thrust in air, a lab helicopter on a rig. Run on a submarine's log, the altitude model took its
depth sensor (water pressure, 0.1 m of depth per kPa) for a barometer (12 Pa per metre of air) and
"found" an accelerometer scale of 1.31 and a baro noise of 36 m: a finding about the model, not
about the vehicle. So the vehicle is recognised first, in the order the log is most explicit:

1. the autopilot's own heartbeat (MAVLink ``HEARTBEAT.type``, a ``MAV_TYPE``; a tlog's rows of
   autopilot components only, not a camera's or a companion computer's) or PX4's
   ``vehicle_status.system_type`` and its ``MAV_TYPE`` parameter;
2. the firmware's banner (``ArduCopter``, ``ArduPlane``, ``ArduSub``, ``ArduRover``; a DataFlash
   ``VER``/``MSG``, a text log's header, a STATUSTEXT), refined by its parameters (ArduCopter's
   ``FRAME_CLASS`` 6 is a traditional helicopter, ArduPlane's ``Q_ENABLE`` a quadplane, ArduRover's
   ``FRAME_CLASS`` 2 a boat);
3. the format itself (a Crazyflie's uSD log is a quadrotor's).

MAV_TYPE numbers are MAVLink's common.xml ``MAV_TYPE`` enumeration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.logs.tables import LogTables

#: MAV_TYPE -> (the kind of vehicle, its name)
MAV_TYPES: dict[int, tuple[str, str]] = {
    1: ("fixed_wing", "fixed wing"),
    2: ("multirotor", "quadrotor"),
    3: ("coaxial", "coaxial helicopter"),
    4: ("helicopter", "helicopter"),
    10: ("rover", "ground rover"),
    11: ("boat", "surface boat"),
    12: ("submarine", "submarine"),
    13: ("multirotor", "hexarotor"),
    14: ("multirotor", "octorotor"),
    15: ("multirotor", "tricopter"),
    19: ("vtol", "VTOL tailsitter (duo)"),
    20: ("vtol", "VTOL tailsitter (quad)"),
    21: ("vtol", "VTOL tiltrotor"),
    22: ("vtol", "VTOL fixed rotor"),
    23: ("vtol", "VTOL tailsitter"),
    24: ("vtol", "VTOL tiltwing"),
    29: ("multirotor", "dodecarotor"),
    35: ("multirotor", "decarotor"),
}
#: MAVLink's MAV_AUTOPILOT_INVALID: a component that is not an autopilot (gimbal, camera, companion)
MAV_AUTOPILOT_INVALID = 8
MAV_TYPE_GCS = 6

#: which of the diagnosable models describe each kind of vehicle, and why the others do not
DESCRIBED_BY: dict[str, tuple[str, ...]] = {
    "multirotor": ("altitude", "quad_thrust", "attitude"),
    "coaxial": ("altitude", "quad_thrust", "attitude"),
    "helicopter": ("altitude", "attitude"),
    "fixed_wing": ("altitude",),
    "vtol": ("altitude",),
    "rig": ("heli3dof",),
    "unknown": ("altitude", "quad_thrust", "attitude"),
}
NOT_DESCRIBED: dict[str, str] = {
    "submarine": "its pressure sensor reads water depth, not an altitude in air, and no model here has "
    "a submarine's dynamics (buoyancy, hydrodynamic drag)",
    "rover": "a ground vehicle's height follows the terrain: no model here has its dynamics",
    "boat": "a surface vessel's height follows the water: no model here has its dynamics",
}
WHY_NOT: dict[str, str] = {
    "quad_thrust": "thrust as a = alpha tau + beta is a fixed-pitch rotor's; a helicopter's collective "
    "pitch and a wing's lift are not",
    "attitude": "the attitude model's drag is a multirotor's",
}


@dataclass(frozen=True)
class Vehicle:
    """What wrote the log: its kind (a key of :data:`DESCRIBED_BY` or :data:`NOT_DESCRIBED`), a name
    for people, and the evidence it rests on."""

    kind: str
    name: str
    evidence: str
    firmware: str = ""

    @property
    def models(self) -> tuple[str, ...]:
        """The diagnosable models that describe this vehicle (none for a submarine, a rover, a boat)."""
        return DESCRIBED_BY.get(self.kind, ())

    def describes(self, model: str) -> bool:
        return model in self.models

    def why_not(self, model: str) -> str:
        """One line: why ``model`` does not describe this vehicle."""
        if self.kind in NOT_DESCRIBED:
            return f"the log is a {self.name}'s ({self.evidence}): {NOT_DESCRIBED[self.kind]}"
        return f"the log is a {self.name}'s ({self.evidence}): {WHY_NOT.get(model, 'not a model of it')}"

    def as_dict(self) -> dict:
        return {"kind": self.kind, "name": self.name, "evidence": self.evidence, "firmware": self.firmware}


UNKNOWN = Vehicle("unknown", "vehicle of unknown type", "the log does not say")


def _of_mav_type(mav_type: int, evidence: str, firmware: str) -> Vehicle | None:
    known = MAV_TYPES.get(mav_type)
    if known is None:
        return None
    return Vehicle(known[0], known[1], evidence, firmware)


def _heartbeat_type(tables: LogTables) -> int | None:
    hb = tables.get("HEARTBEAT")
    if hb is None or "type" not in hb or "autopilot" not in hb:
        return None
    types, pilots = hb.numeric("type"), hb.numeric("autopilot")
    if types is None or pilots is None:
        return None
    mine = types[(pilots != MAV_AUTOPILOT_INVALID) & (types != MAV_TYPE_GCS) & np.isfinite(types)]
    if not len(mine):
        return None
    values, counts = np.unique(mine.astype(int), return_counts=True)
    return int(values[np.argmax(counts)])


def _px4_type(tables: LogTables) -> int | None:
    vs = tables.get("vehicle_status")
    if vs is not None:
        st = vs.numeric("system_type")
        if st is not None and np.isfinite(st).any():
            return int(np.nanmedian(st))
    v = tables.params.get("MAV_TYPE")
    return int(v) if v is not None and np.isfinite(v) else None


def _of_firmware(firmware: str, params: dict[str, float]) -> Vehicle | None:
    f = firmware.lower()
    frame = params.get("FRAME_CLASS")
    said = f"firmware {firmware.split('(')[0].strip()}"
    if "copter" in f:
        if "heli" in f or frame == 6:
            return Vehicle(
                "helicopter", "traditional helicopter", said + (", FRAME_CLASS 6" if frame == 6 else ""), firmware
            )
        return Vehicle("multirotor", "multirotor", said, firmware)
    if "plane" in f:
        if params.get("Q_ENABLE"):
            return Vehicle("vtol", "quadplane", said + ", Q_ENABLE 1", firmware)
        return Vehicle("fixed_wing", "fixed wing", said, firmware)
    if "sub" in f:
        return Vehicle("submarine", "submarine", said, firmware)
    if "rover" in f:
        if frame == 2:
            return Vehicle("boat", "boat", said + ", FRAME_CLASS 2", firmware)
        return Vehicle("rover", "ground rover", said, firmware)
    return None


def identify(tables: LogTables) -> Vehicle:
    """The vehicle a log's records and parameters say wrote it (the module's docstring)."""
    fw = tables.firmware
    if tables.fmt == "crazyflie":
        return Vehicle("multirotor", "quadrotor (Crazyflie)", "a Crazyflie uSD log")
    t = _heartbeat_type(tables)
    if t is not None:
        v = _of_mav_type(t, f"HEARTBEAT type {t}", fw)
        if v is not None:
            return v
    if tables.autopilot == "px4" or tables.fmt == "ulog":
        t = _px4_type(tables)
        if t is not None:
            v = _of_mav_type(t, f"vehicle_status system_type {t}", fw)
            if v is not None:
                return v
    if fw:
        v = _of_firmware(fw, tables.params)
        if v is not None:
            return v
    return UNKNOWN
