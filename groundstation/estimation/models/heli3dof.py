"""3-DOF lab helicopter: the lab document's linear model and its Kalman filter.

State ``x = (p, p_dot, e, e_dot, lambda, lambda_dot)`` [rad, rad/s], input
``u = (V_s - V_s0, V_d)`` [V] (eq. 45). Linearised around the equilibrium
(eq. 14-20)::

    p_dd = K1 V_d,   e_dd = K2 (V_s - V_s0),   lambda_dd = K3 p
    K1 = l_p K_f / J_p,  K2 = l_h K_f / J_e,  K3 = l_h K_f V_s0 / J_lambda

discretised exactly at the IMU's 500 Hz (the lab's ``c2d(sys, 0.002)``).

Measurements, each its own model (the lab's C_gyro, eq. 47, and C_IMU, eq. 57):

* ``gyro``: (p_dot, e_dot, lambda_dot) from the body rates through the Euler-rate
  transform (the lab's "Euler block"; the IMU sits on the arm, so its rates are
  the Euler rates only when level);
* ``accel``: (p, e) from the gravity direction (eq. 51, 52:
  ``p = atan2(-f_y, -f_z)``, ``e = atan2(f_x, sqrt(f_y^2 + f_z^2))`` in FRD).
  The lab reads eq. 51-52 from the raw specific force, which holds only at rest:
  the IMU sits ``l_h`` out on the arm, so in flight it also feels the arm's
  centripetal and tangential accelerations (0.1-0.5 m/s^2, i.e. 0.01-0.05 rad of
  false attitude, several sigma of the sensor). With ``arm_acceleration=True``
  (default) they are removed first, from the prior estimate::

      a_N = l_h (-ce (e_d^2 + l_d^2) - se e_dd,  -2 se e_d l_d + ce l_dd,  se e_d^2 - ce e_dd)   (NED, lambda = 0)
      f_gravity = f - R_IB(p, e, 0)^T a_N,   e_dd = K2 (V_s - V_s0),  l_dd = K3 p

  (the point's acceleration, ``sim_bridge.vehicles.heli3dof``'s kinematics,
  at travel 0: the body-frame result does not depend on travel);
* ``encoders``: (p, e, lambda), from the encoder board or MAVLink ATTITUDE.

R: from the covariance of stationary data (``groundstation noise``), as the lab
does (eq. 59). Q: the model's error, mostly the linearisation.

Corrections: K_f = 0.1248 N/V, not 3.4 (see ``sim_bridge.vehicles.heli3dof``:
the lab's eq. 12 has the counterweight's sign wrong); eq. 59 labels its first
rows p_dd, e_dd where it means p_dot, e_dot; and sec. 4.3's "when we measure
velocity the system is controllable; if we measured position it would be
observable but not controllable" confuses the two: controllability does not
depend on what is measured.
"""

from __future__ import annotations

import math

import numpy as np

from groundstation.core.measurement import Kind

from .base import LinearModel, MeasurementModel, observability_rank
from .heli3dof_rig import J_E, J_L, J_P, K_F, L_H, L_P, V_S0, Heli3dofRig, dynamics, voltages

STATES = ["p", "p_dot", "e", "e_dot", "lambda", "lambda_dot"]


def gains(K_f: float = K_F, V_s0: float = V_S0) -> tuple[float, float, float]:
    return L_P * K_f / J_P, L_H * K_f / J_E, L_H * K_f * V_s0 / J_L


def matrices(K_f: float = K_F, V_s0: float = V_S0):
    K1, K2, K3 = gains(K_f, V_s0)
    A = np.zeros((6, 6))
    A[0, 1] = A[2, 3] = A[4, 5] = 1.0
    A[5, 0] = K3
    B = np.zeros((6, 2))
    B[1, 1] = K1
    B[3, 0] = K2
    return A, B


C_GYRO = np.array([[0, 1, 0, 0, 0, 0], [0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 0, 1]], dtype=float)
C_ACCEL = np.array([[1, 0, 0, 0, 0, 0], [0, 0, 1, 0, 0, 0]], dtype=float)
C_ENC = np.array([[1, 0, 0, 0, 0, 0], [0, 0, 1, 0, 0, 0], [0, 0, 0, 0, 1, 0]], dtype=float)

#: default measurement noise (stationary, simulated IMU); replace with ``groundstation noise``
R_DEFAULT = {
    "gyro": np.diag([0.005**2] * 3),
    "accel": np.diag([0.009**2] * 2),
    "encoders": np.diag([(2 * math.pi / 4096) ** 2 / 12] * 3),
}


def euler_rates(p: float, e: float, w) -> np.ndarray:
    """(p_dot, e_dot, lambda_dot) of body rates w, arm frame yaw=lambda, pitch=e, roll=p."""
    wx, wy, wz = w
    sp, cp = math.sin(p), math.cos(p)
    ce = max(math.cos(e), 0.2)
    return np.array([wx + (wy * sp + wz * cp) * math.tan(e), wy * cp - wz * sp, (wy * sp + wz * cp) / ce])


def arm_acceleration_body(p: float, e: float, e_dot: float, l_dot: float, e_dd: float, l_dd: float) -> np.ndarray:
    """The IMU point's acceleration (l_h out on the arm) in the IMU's FRD frame [m/s^2]."""
    se, ce, sp, cp = math.sin(e), math.cos(e), math.sin(p), math.cos(p)
    a = L_H * np.array(
        [-ce * (e_dot**2 + l_dot**2) - se * e_dd, -2 * se * e_dot * l_dot + ce * l_dd, se * e_dot**2 - ce * e_dd]
    )
    # R_IB(roll p, pitch e, yaw 0) = Ry(e) Rx(p); its transpose takes NED to body
    ay = np.array([ce * a[0] - se * a[2], a[1], se * a[0] + ce * a[2]])  # Ry(e)^T a
    return np.array([ay[0], cp * ay[1] + sp * ay[2], -sp * ay[1] + cp * ay[2]])  # Rx(p)^T


def heli3dof_model(
    *,
    R: dict | None = None,
    G_acc: float = 3e-3,
    K_f: float = K_F,
    arm_acceleration: bool = True,
    rig: Heli3dofRig | dict | None = None,
) -> LinearModel:
    """The lab's filter; with ``rig`` (a vehicle file's ``heli3dof.rig``, or what ``diagnose --model
    heli3dof`` found: :class:`~.heli3dof_rig.Heli3dofRig`) on that rig's own constants. A rig whose
    dynamics the linear model cannot hold (the full equations, a motor lag, a V_s0 other than the
    input's reference) makes it an extended Kalman filter on ``heli3dof_rig.dynamics``; its IMU's
    biases and mounting and its encoders' offsets are taken off the readings before they are used."""
    if isinstance(rig, dict):
        rig = Heli3dofRig.from_vehicle(rig)
    rig = rig if rig is not None else Heli3dofRig(K_f=K_f)
    K_f = rig.K_f
    A, B = matrices(K_f)
    A[1, 1], A[3, 3], A[5, 5] = -rig.c_p, -rig.c_e, -rig.c_l
    K1, K2, K3 = gains(K_f)
    R = {**R_DEFAULT, **(R or {})}
    nonlinear = not (rig.linear_dynamics and rig.V_s0 == V_S0)
    f_jac = dynamics(rig) if nonlinear else None
    n = 8 if nonlinear and rig.tc > 0 else 6
    C_mount_T = rig.mounting().T  # f = C^T f_m
    b_g, b_a = np.asarray(rig.gyro_bias), np.asarray(rig.accel_bias)
    offset = np.array([*rig.encoder_offset, 0.0])
    lab_imu = rig.gyro_bias == (0.0, 0.0, 0.0) and rig.accel_bias == (0.0, 0.0, 0.0) and rig.imu_mounting == (0.0,) * 3

    def pad(C: np.ndarray) -> np.ndarray:
        return np.hstack([C, np.zeros((C.shape[0], n - 6))]) if n > 6 else C

    c_gyro, c_accel, c_enc = pad(C_GYRO), pad(C_ACCEL), pad(C_ENC)

    def arm_terms(ctx) -> tuple[float, float]:
        """(e_dd, lambda_dd) the model expects now, for the arm's own acceleration."""
        if not nonlinear:
            return K2 * ctx.u_s, K3 * ctx.p_hat
        V_f, V_b = voltages((ctx.u_s, ctx.u_d))
        _, edd, ldd = rig.accelerations(
            ctx.p_hat, ctx.e_hat, ctx.p_dot_hat, ctx.e_dot_hat, ctx.lambda_dot_hat, V_f, V_b
        )
        return edd, ldd

    def gyro(m, ctx):
        w = m.value if lab_imu else C_mount_T @ (np.asarray(m.value, dtype=float) - b_g)
        return euler_rates(ctx.p_hat, ctx.e_hat, w)

    def accel(m, ctx):
        f = np.asarray(m.value, dtype=float)
        if not lab_imu:
            f = C_mount_T @ (f - b_a)
        if arm_acceleration:
            edd, ldd = arm_terms(ctx)
            f = f - arm_acceleration_body(ctx.p_hat, ctx.e_hat, ctx.e_dot_hat, ctx.lambda_dot_hat, edd, ldd)
        fx, fy, fz = f
        return np.array([math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))])

    def encoders(m, ctx):
        return np.array(m.value[:3], dtype=float) - offset

    meas = {
        "gyro": MeasurementModel("gyro", Kind.GYRO, gyro, lambda ctx: c_gyro, np.asarray(R["gyro"])),
        "accel": MeasurementModel("accel", Kind.ACCEL, accel, lambda ctx: c_accel, np.asarray(R["accel"])),
        "encoders": MeasurementModel("encoders", Kind.ENCODERS, encoders, lambda ctx: c_enc, np.asarray(R["encoders"])),
        "encoders_mav": MeasurementModel(
            "encoders", Kind.ATTITUDE, encoders, lambda ctx: c_enc, np.asarray(R["encoders"])
        ),
    }
    extra = n - 6  # the motors' voltages (a lag's states)
    return LinearModel(
        name="heli3dof",
        states=list(STATES) + ["V_f", "V_b"][:extra],
        inputs=["Vs_tilde", "V_d"],
        A=lambda u: A,
        B=B if n == 6 else np.zeros((n, 2)),
        Qc=np.diag([0.0, G_acc, 0.0, G_acc, 0.0, G_acc] + [0.0] * extra),
        x0=np.array([0.0, 0.0, -0.5, 0.0, 0.0, 0.0] + [0.0] * extra),
        P0=np.diag([0.05, 0.05, 0.1, 0.05, 0.05, 0.05] + [1.0] * extra),
        measurements=meas,
        doc=__doc__,
        f=f_jac[0] if f_jac else None,
        jacobian=f_jac[1] if f_jac else None,
        options=dict(R=R, G_acc=G_acc, arm_acceleration=arm_acceleration, rig=rig),
    )


def observability_report() -> dict[str, int]:
    A, _ = matrices()
    return {
        "gyro": observability_rank(A, C_GYRO),
        "gyro+accel": observability_rank(A, np.vstack([C_GYRO, C_ACCEL])),
        "encoders": observability_rank(A, C_ENC),
        "states": 6,
    }
