"""What a filter's measurement models and input rules may read besides the state: a
:class:`Context` with one named field per quantity.

The routing rules (:mod:`.routing`) write it as the measurements arrive (the tilt, the
throttle, the vehicle's type), the estimator writes the estimate before each update, and the
measurement models read and keep their own small state here (a barometer's zero, the range
gate, the ground contact). A rollback copies it with :meth:`Context.copy`: every field holds an
immutable value (numbers, tuples) or is replaced, never changed in place, so a shallow copy is
a snapshot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

#: the body z axis's row of A_IB for a level vehicle (its down component)
LEVEL = (0.0, 0.0, 1.0)


class Zero(NamedTuple):
    """An absolute sensor's zero against the estimate (:func:`.models.base.relative_to_estimate`):
    the running sum of reading minus estimate over ``n`` readings, and the zero once fixed.
    ``held``: a zero given before the run (taken by an earlier run over the same log), which the
    calibrating readings then end in instead of their own mean: every run reads the same readings
    against the same zero."""

    total: float = 0.0
    n: int = 0
    ref: float | None = None
    held: float | None = None


@dataclass(eq=False, kw_only=True)
class Context:
    # -- the measurement being handled and the estimate (the estimator sets them) ------------------
    t: float | None = None  #: the measurement's time [s]
    z: float = 0.0  #: the state vector's first element before the update (a height, for the height models)
    x: np.ndarray | None = None  #: the state vector (the filter's own array)
    u: np.ndarray | None = None  #: the held input vector
    skip_why: str | None = None  #: a measurement model's reason for returning no reading (counted)

    # -- attitude (ATTITUDE, ATTITUDE_QUATERNION, and the rates that carry it forward) -------------
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    #: the rows of A_IB (coaxial doc. eq. 3.10), kept with the attitude (50 Hz) rather than per IMU sample
    north_row: tuple[float, float, float] = (1.0, 0.0, 0.0)
    east_row: tuple[float, float, float] = (0.0, 1.0, 0.0)
    down_row: tuple[float, float, float] = LEVEL
    attitude_t: float | None = None  #: when the attitude was measured
    roll_rate: float | None = None  #: body rates p, q that came with it [rad/s]
    pitch_rate: float | None = None

    # -- throttle and motors -----------------------------------------------------------------------
    throttle: float | None = None  #: the collective 0..1 (None: the link has sent none)
    throttle_since: float | None = None  #: when it was written
    throttle_before: float | None = None  #: the one before (for a reading stamped at that instant)
    throttle_from_outputs: bool = False  #: the motor outputs are the log's throttle source
    motor_outputs: int = 4  #: how many of the first actuator outputs drive rotors

    # -- the vertical velocity the attitude model reads (VELOCITY_NED, CLIMB_RATE) -----------------
    v_d: float = math.nan  #: NED down [m/s]
    v_d_t: float = -math.inf

    # -- auxiliary signals the catalogue's regressors read -----------------------------------------
    temperature: float | None = None  #: [K]
    temperature_0: float | None = None  #: the first reading [K]
    voltage: float | None = None  #: battery [V]
    current: float | None = None  #: battery [A]
    ground_speed: float | None = None  #: horizontal speed over the ground [m/s] (the GNSS velocity)
    throttle_lp: float | None = None  #: the throttle low-passed (rotor wash)
    throttle_lp_t: float | None = None
    #: the throttle low-passed at each rotor-wash time constant [s] the model asks for (its
    #: ``options["throttle_tcs"]``, :func:`groundstation.diagnosis.catalogue.altitude.baro_thrust`) -> value
    throttle_lps: dict[float, float] = field(default_factory=dict)
    throttle_lps_t: float | None = None
    #: the rotors' thrust over the weight the command makes (estimation.thrust_ratio), where the log
    #: shows the map; and its low-passes, as ``throttle_lps`` (same time constants, same time)
    thrust_ratio: float | None = None
    thrust_lps: dict[float, float] = field(default_factory=dict)
    thrust_lps_t: float | None = None
    #: the thrust over the weight the latest command makes (ThrustRatio.of); where the accelerometer
    #: reads more than the most it can make (ThrustRatio.most), the ground holds part of the weight
    thrust_map: float | None = None
    f_lp: float | None = None  #: |f| low-passed over 1 s
    f_lp_t: float | None = None
    vibration: float | None = None  #: (|f| - f_lp)^2 low-passed: the rotors' vibration
    vibration_t: float | None = None
    f_z: float | None = None  #: the latest body-z specific force [m/s^2] (the attitude model's mounting term)
    #: the latest specific force along the world's up [m/s^2]: g held up at rest, 0 falling freely
    f_up: float | None = None

    # -- the barometer's and GPS's zeros against the estimate --------------------------------------
    zeros: dict[str, Zero] = field(default_factory=dict)
    baro_has_pressure: bool = False  #: the log gives the baro as a pressure (its altitude form is then not used)
    gps_origin: tuple[float, float] | None = None  #: lat, lon [deg] of the horizontal filter's origin
    #: the still stretch's readings of each sensor by kind (estimation.still_noise): the last reading's
    #: time and height, the pairs and their summed squared differences
    still_noise: dict[str, tuple[float, float, int, float]] = field(default_factory=dict)
    still_over: bool = False  #: the still stretch before the first take-off has ended

    # -- the range sensor and the ground (models.ground, models.contact, models.range_gate) --------
    range_read_at: float | None = None  #: the last reading used
    range_on_ground_at: float | None = None  #: the last reading the range gate skipped
    range_off_ground_at: float = -math.inf  #: the last reading that saw the vehicle off the ground
    range_gate: str = "unsure"
    range_track: tuple[float, float, float, float] | None = None  #: (t0, d0, t_last, d_last)
    in_contact: bool | None = None  #: None before the first decision
    landed: bool | None = None  #: models.ground's decision at the last throttle (None before the first)
    lifted_at: float | None = None  #: the last lift-off by that decision [s]
    been_up: bool = False

    # -- the 3-DOF helicopter's estimate, for its gyro's and accelerometer's measurement functions --
    p_hat: float = 0.0
    p_dot_hat: float = 0.0
    e_hat: float = 0.0
    e_dot_hat: float = 0.0
    lambda_dot_hat: float = 0.0
    u_s: float = 0.0
    u_d: float = 0.0

    def copy(self) -> Context:
        """A snapshot for a rollback (the module docstring says why shallow is enough)."""
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        new.zeros = dict(self.zeros)
        new.still_noise = dict(self.still_noise)
        new.throttle_lps = dict(self.throttle_lps)
        new.thrust_lps = dict(self.thrust_lps)
        return new

    def set_to(self, snapshot: Context) -> None:
        """Back to a snapshot taken with :meth:`copy`, in place (whoever holds this context keeps it)."""
        self.__dict__.update(snapshot.__dict__)
        self.zeros = dict(snapshot.zeros)
        self.still_noise = dict(snapshot.still_noise)
        self.throttle_lps = dict(snapshot.throttle_lps)
        self.thrust_lps = dict(snapshot.thrust_lps)

    @property
    def tau(self) -> float:
        """The throttle, 0 where none was sent."""
        return self.throttle if self.throttle is not None else 0.0
