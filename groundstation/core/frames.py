"""Frames and rotations, as MAVLink and the coaxial-helicopter document (ch. 3) define them.

Tait-Bryan angles eta = (psi, theta, phi) (yaw, pitch, roll); the body frame B
is FRD and the inertial frame I is NED, so ``A_IB`` (doc eq. 3.10) maps body
to NED: ``v_I = A_IB @ v_B``. Quaternions are (w, x, y, z) of the same rotation.
"""

from __future__ import annotations

import math

import numpy as np


def a_ib(phi: float, theta: float, psi: float) -> np.ndarray:
    """A_IB = A_I1(psi) A_12(theta) A_2B(phi), coaxial document eq. (3.10)."""
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    return np.array(
        [
            [cp * ct, cp * sf * st - cf * sp, sf * sp + cf * cp * st],
            [ct * sp, cf * cp + sf * sp * st, cf * sp * st - cp * sf],
            [-st, ct * sf, cf * ct],
        ]
    )


def euler_from_matrix(r: np.ndarray) -> tuple[float, float, float]:
    """(roll phi, pitch theta, yaw psi) of A_IB."""
    theta = -math.asin(max(-1.0, min(1.0, r[2, 0])))
    phi = math.atan2(r[2, 1], r[2, 2])
    psi = math.atan2(r[1, 0], r[0, 0])
    return phi, theta, psi


def skew(w) -> np.ndarray:
    """The cross-product matrix w~ of doc eq. (6.9)."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def exp_so3(w: np.ndarray, dt: float) -> np.ndarray:
    """Rotation by body rate ``w`` [rad/s] over ``dt`` (Rodrigues)."""
    a = w * dt
    th = math.sqrt(a @ a)
    k = skew(a)
    if th < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + math.sin(th) / th * k + (1 - math.cos(th)) / th**2 * (k @ k)


def quaternion_from_matrix(r: np.ndarray) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation matrix (Shepperd's method)."""
    t = r[0, 0] + r[1, 1] + r[2, 2]
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        return 0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s
    i = int(np.argmax([r[0, 0], r[1, 1], r[2, 2]]))
    if i == 0:
        s = math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
        return (r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s
    if i == 1:
        s = math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
        return (r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s
    s = math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
    return (r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s


def quaternion_from_euler(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of A_IB(roll, pitch, yaw)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quaternion(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of the rotation (w, x, y, z); pitch held to [-90, 90] deg."""
    return (
        math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)),
        math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x)))),
        math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)),
    )


def accel_attitude(f) -> tuple[float, float]:
    """(roll, pitch) of gravity's direction in a specific force ``f`` (FRD; at rest f = -g_body)."""
    fx, fy, fz = f
    return math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))


def euler_rates(roll: float, pitch: float, w) -> tuple[float, float]:
    """(roll_dot, pitch_dot) from the body rates ``w = (p, q, r)`` (doc eq. 3.14's first two rows)."""
    p, q, r = w
    return (p + (q * math.sin(roll) + r * math.cos(roll)) * math.tan(pitch), q * math.cos(roll) - r * math.sin(roll))
