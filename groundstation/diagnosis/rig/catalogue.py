"""What the lab's linear model of the 3-DOF helicopter can lack, each as the parameters of the
rig's model (:mod:`.model`) it frees: the lab document's own list (its small-angle assumption, the
hand-found V_s0 and K_f, the IMU noise that "looks to be biased") and what any rig has."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RigCandidate:
    name: str
    params: tuple[str, ...]
    what: str  #: one line for the report
    imu: bool = False  #: it shows only against an IMU


CATALOGUE: tuple[RigCandidate, ...] = (
    RigCandidate("equilibrium_voltage", ("V_s0",), "the sum voltage that holds the rig level (eq. 12), found by hand"),
    RigCandidate("motor_constant", ("K_f",), "thrust per volt (eq. 4-5), found by hand from V_s0"),
    RigCandidate("motor_asymmetry", ("a",), "the two motors unlike: F_f = K_f (1 - a) V_f, F_b = K_f (1 + a) V_b"),
    RigCandidate(
        "elevation_trig", ("w_e",), "elevation's cos(p) and cos(e) (eq. 10 before the small-angle assumption)"
    ),
    RigCandidate("travel_lever_arm", ("w_l",), "travel's torque l_h cos(e) (F_f + F_b) sin(p) (eq. 13 in full)"),
    RigCandidate("viscous_friction(p)", ("c_p",), "friction against the pitch rate"),
    RigCandidate("viscous_friction(e)", ("c_e",), "friction against the elevation rate"),
    RigCandidate("viscous_friction(lambda)", ("c_l",), "friction against the travel rate"),
    RigCandidate("motor_lag", ("tc",), "the motors' thrust a first-order lag behind their voltage"),
    RigCandidate("gyro_bias", ("b_gx", "b_gy", "b_gz"), "a constant on each gyro axis", imu=True),
    RigCandidate("accel_bias", ("b_ax", "b_ay", "b_az"), "a constant on each accelerometer axis", imu=True),
    RigCandidate("imu_misalignment", ("m_roll", "m_pitch", "m_yaw"), "the IMU mounted rotated on the arm", imu=True),
    RigCandidate("encoder_offset", ("o_p", "o_e"), "the pitch and elevation encoders zeroed off level", imu=True),
)

#: what the rig's sessions cannot show, and why (reported, not guessed)
UNOBSERVABLE_RIG = {
    "encoder_offset(lambda)": "travel's zero is arbitrary: nothing in the equations or the IMU depends on it",
    "gyro_scale": "not in the catalogue: a gyro scale error would show as a rate-proportional gyro residual",
}


def rig_catalogue(has_imu: bool) -> list[RigCandidate]:
    return [c for c in CATALOGUE if has_imu or not c.imu]
