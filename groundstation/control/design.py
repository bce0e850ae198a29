"""Controller design from the 3-DOF lab document (part 2 and part 3).

Linear model for control (lab eq. 28-31), state ``x = (p, p_dot, e_dot)``,
input ``u = (V_s - V_s0, V_d)``::

    A = [[0, 1, 0], [0, 0, 0], [0, 0, 0]],   B = [[0, 0], [0, K1], [K2, 0]]

and with integral states ``gamma_dot = p - p_c``, ``zeta_dot = e_dot - e_dot_c``
(eq. 39-41). Gains:

* PD by pole placement (eq. 22-27): the closed loop ``s^2 + K1 K_pd s + K1 K_pp``
  gives ``K_pp = omega_0^2 / K1`` and ``K_pd = 2 zeta omega_0 / K1``, or from two
  poles ``K_pp = l1 l2 / K1``, ``K_pd = -(l1 + l2) / K1``.
* LQR (eq. 34): ``K = R^-1 B^T P`` with P from
  :func:`scipy.linalg.solve_continuous_are`, as MATLAB's ``lqr`` does.
* Reference feed-forward (eq. 37): ``F = (C (B K - A)^-1 B)^-1``.

Corrections, made knowingly:

* Sec. 2.2 gives the poles of ``K_pd = 0, K_pp = 2`` as "+-2/K1 i"; they are
  ``+-sqrt(K1 K_pp) i = +-sqrt(2 K1) i`` (5.2i with the lab's K1 = 13.5, which is
  the figure the lab quotes).
* The lab's K1 comes from K_f = 3.4 N/V, which rests on eq. 12's sign error
  (:mod:`sim_bridge.vehicles.heli3dof`). The plant the lab flew had the
  K_f its equilibrium voltage implies, 0.1248 N/V, so its real K1 was 27 times
  smaller than the one its gains were designed on: :data:`LAB_K_F` keeps the
  lab's value for reproducing its trials, :data:`~groundstation.estimation.models.heli3dof.K_F`
  is the corrected one.
* Eq. 43 says F can be anything once integral action is added. It can, for the
  steady state; for the transient we take the F of eq. 37 computed with the
  state part of K, so that the integrators hold only what the model gets
  wrong (disturbances), not the whole reference.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from groundstation.estimation.models.heli3dof import J_E, J_P, K_F, L_H, L_P

#: the lab's motor constant (sec. 1.2), kept to reproduce its gains
LAB_K_F = 3.4

#: the lab's weights (eq. 38, eq. 44, and eq. 92 for the Kalman-filter flight)
LAB_Q_FF = np.diag([20.0, 10.0, 30.0])
LAB_R_FF = np.eye(2)
LAB_Q_I = np.diag([30.0, 10.0, 10.0, 1.0, 1.0])
LAB_R_I = np.eye(2)
LAB_Q_KF = np.diag([35.0, 10.0, 30.0])
LAB_R_KF = np.diag([4.0, 1.0])


def k1_k2(K_f: float = K_F) -> tuple[float, float]:
    """K1 = l_p K_f / J_p, K2 = l_h K_f / J_e (eq. 17-18, with L1, L2 of eq. 9, 11)."""
    return L_P * K_f / J_P, L_H * K_f / J_E


def pitch_model(K_f: float = K_F) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A, B (eq. 31) and C picking the tracked outputs (p, e_dot)."""
    K1, K2 = k1_k2(K_f)
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    B = np.array([[0.0, 0.0], [0.0, K1], [K2, 0.0]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return A, B, C


def integral_model(K_f: float = K_F) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A, B, R_ref of eq. 41 (states p, p_dot, e_dot, gamma, zeta)."""
    A3, B3, C = pitch_model(K_f)
    A = np.zeros((5, 5))
    A[:3, :3] = A3
    A[3:, :3] = C
    B = np.vstack([B3, np.zeros((2, 2))])
    R_ref = np.vstack([np.zeros((3, 2)), -np.eye(2)])
    return A, B, R_ref


def pd_gains(K1: float, omega0: float, zeta: float) -> tuple[float, float]:
    """(K_pp, K_pd) for the closed loop of eq. 24 (eq. 25-26 solved for the gains)."""
    return omega0**2 / K1, 2.0 * zeta * omega0 / K1


def pd_from_poles(K1: float, l1: complex, l2: complex) -> tuple[float, float]:
    """(K_pp, K_pd) placing the poles of eq. 22 at l1, l2 (a real or conjugate pair)."""
    return float(np.real(l1 * l2)) / K1, -float(np.real(l1 + l2)) / K1


def omega_zeta(K1: float, K_pp: float, K_pd: float) -> tuple[float, float]:
    """omega_0 and zeta of the PD loop (eq. 25, 27)."""
    w = float(np.sqrt(K1 * K_pp))
    return w, (K1 * K_pd / (2.0 * w) if w > 0 else float("inf"))


def lqr(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """K minimising eq. 34: K = R^-1 B^T P, P the continuous Riccati solution."""
    P = scipy.linalg.solve_continuous_are(A, B, Q, R)
    return np.linalg.solve(R, B.T @ P)


def reference_feedforward(A: np.ndarray, B: np.ndarray, C: np.ndarray, K: np.ndarray) -> np.ndarray:
    """F = (C (B K - A)^-1 B)^-1 (eq. 37): y = r at equilibrium."""
    return np.linalg.inv(C @ np.linalg.solve(B @ K - A, B))
