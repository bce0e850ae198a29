"""Commands into bytes on the vehicle's own link.

* :class:`BoardMotors`: the sensor-board protocol's MOTORS frame (id 0x10,
  ``t_us, V_f, V_b`` as float32), for the 3-DOF helicopter's motor board;
* :class:`ManualControl`: MAVLink MANUAL_CONTROL (x, y, r in -1000..1000,
  z in 0..1000), for the coaxial helicopter's collective (z);
* :class:`AttitudeTarget`: MAVLink SET_ATTITUDE_TARGET, level attitude and
  the collective as ``thrust`` (0..1), for the quadcopter.

Pymavlink packs the MAVLink messages; the board frame is packed from
:mod:`drivers.board_protocol`'s own table.
"""

from __future__ import annotations

import abc
import time

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers import board_protocol as bp


class Uplink(abc.ABC):
    #: what the command vector holds
    command_names: tuple[str, ...] = ()

    def __init__(self) -> None:
        self.sent = 0
        self.last_sent_wall: float | None = None

    def send(self, command: np.ndarray, t: float) -> None:
        """Send one command (``t``: vehicle time it is computed for)."""
        self._send(command, t)
        self.sent += 1
        self.last_sent_wall = time.monotonic()

    @abc.abstractmethod
    def _send(self, command: np.ndarray, t: float) -> None:
        """Encode and hand the bytes to the link."""


class BoardMotors(Uplink):
    command_names = ("V_f", "V_b")

    def __init__(self, board) -> None:
        super().__init__()
        self.board = board
        self.seq = 0

    def _send(self, command, t):
        payload = bp.PAYLOADS[bp.MOTORS][1].pack(int(round(t * 1e6)) & 0xFFFFFFFF, float(command[0]), float(command[1]))
        self.board.send(bp.frame(bp.MOTORS, self.seq, payload))
        self.seq = (self.seq + 1) & 0xFF


class ManualControl(Uplink):
    command_names = ("collective",)

    def __init__(self, link, target_system: int = 1) -> None:
        super().__init__()
        self.link, self.target = link, target_system

    def _send(self, command, t):
        z = int(round(1000 * min(1.0, max(0.0, float(command[0])))))
        self.link.send(mavlink.MAVLink_manual_control_message(self.target, 0, 0, z, 0, 0))


class AttitudeTarget(Uplink):
    command_names = ("collective",)
    #: ignore body roll and pitch rates; attitude and thrust are flown, yaw rate 0
    TYPE_MASK = 0b00000011

    def __init__(self, link, target_system: int = 1, target_component: int = 1) -> None:
        super().__init__()
        self.link, self.target, self.component = link, target_system, target_component

    def _send(self, command, t):
        thrust = min(1.0, max(0.0, float(command[0])))
        self.link.send(
            mavlink.MAVLink_set_attitude_target_message(
                int(t * 1000) & 0xFFFFFFFF,
                self.target,
                self.component,
                self.TYPE_MASK,
                [1.0, 0.0, 0.0, 0.0],
                0.0,
                0.0,
                0.0,
                thrust,
            )
        )
