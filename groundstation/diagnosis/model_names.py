"""The diagnosable models by name, and what each can find: the one list the command line offers
before anything numerical is loaded (:mod:`.models` builds :data:`~.models.DIAGNOSABLE` on it)."""

from __future__ import annotations

#: name -> what the model can find, for ``diagnose --help``
MODEL_HELP: dict[str, str] = {
    "altitude": "accelerometer as input: baro, range and accelerometer effects, sensor delays",
    "quad_thrust": "throttle as input: thrust-side effects (voltage, ground effect, actuator lag) and the baro's",
    "attitude": "raw IMU of a multirotor: gyro bias, IMU mounting",
}
#: the 3-DOF lab helicopter's rig (its own diagnosis: groundstation.diagnosis.rig)
RIG_MODEL_HELP: dict[str, str] = {
    "heli3dof": "3-DOF lab helicopter rig (encoders, motor voltages, IMU): the full equations, V_s0 and K_f, "
    "motor asymmetry and lag, friction, IMU biases and mounting, encoder offsets",
}
