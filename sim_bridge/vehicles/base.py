"""What every simulated vehicle offers the simulator (sensors, truth, profile)."""

from __future__ import annotations

import abc
from dataclasses import dataclass, field

import numpy as np

G = 9.80665


@dataclass
class Kinematics:
    """The truth the sensors read, in MAVLink frames (NED world, FRD body)."""

    pos: np.ndarray = field(default_factory=lambda: np.zeros(3))  # NED [m], z down
    vel: np.ndarray = field(default_factory=lambda: np.zeros(3))  # NED [m/s]
    R: np.ndarray = field(default_factory=lambda: np.eye(3))  # A_IB (body -> NED)
    omega: np.ndarray = field(default_factory=lambda: np.zeros(3))  # body rates FRD [rad/s]
    specific_force: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -G]))  # body FRD [m/s^2]

    @property
    def height(self) -> float:
        """Height above the ground plane (z up) [m]."""
        return -float(self.pos[2])


class Vehicle(abc.ABC):
    """A vehicle: ``step(dt, command)`` advances the physics by ``dt``."""

    name = "vehicle"
    kin: Kinematics

    @abc.abstractmethod
    def step(self, dt: float, command) -> None:
        """Advance by ``dt`` seconds with ``command`` (the vehicle's own command type)."""

    @abc.abstractmethod
    def truth(self) -> dict[str, float]:
        """Every state by name, for the truth sidecar."""

    def imu_truth(self) -> tuple[float, float, float, float, float, float]:
        """Specific force and body rates (FRD) as floats, for the IMU."""
        k = self.kin
        return (*k.specific_force.tolist(), *k.omega.tolist())

    @property
    def throttle(self) -> float:
        """Collective throttle 0..1 as the outputs show it (for rotor-wash effects)."""
        return 0.0

    @property
    def motors_running(self) -> bool:
        return self.throttle > 0.05
