"""Roll and pitch of a multirotor from its IMU alone, as a declared model the diagnosis can extend.

The dynamics are those of :mod:`groundstation.estimation.attitude_filters` (Leishman, Macdonald,
Beard and McLain, IEEE Control Systems Magazine 34(1), 2014): on a multirotor the
accelerometer sees the rotor drag of the horizontal body velocity, not gravity, and
the velocity's dynamics carry the tilt. State ``x = (phi, theta, u, v)``: roll,
pitch [rad], body-frame (FRD) horizontal velocity [m/s]. Input: the gyro's rates
``(p_m, q_m, r_m)`` [rad/s] and, where known, the vertical velocity ``v_d`` [m/s,
NED] (NaN where not). With the true rates ``(p, q, r)``::

    phi_dot   = p + (q sin(phi) + r cos(phi)) tan(theta)
    theta_dot = q cos(phi) - r sin(phi)
    u_dot     = -g sin(theta) + r v - q w - mu u
    v_dot     =  g sin(phi) cos(theta) - r u + p w - mu v

    accelerometer:  f_x = -mu u,   f_y = -mu v        (thrust acts along body z only)

The body's vertical velocity ``w`` is not a state: no IMU sensor sees it. It comes
from the world's vertical velocity ``v_d`` (NED, down), a fourth input where one is
known, through ``v_d = -sin(theta) u + sin(phi) cos(theta) v + cos(phi) cos(theta) w``::

    w = (v_d + sin(theta) u - sin(phi) cos(theta) v) / (cos(phi) cos(theta))

Without ``v_d`` the ``q w`` and ``p w`` terms are left out. They
are not small: on simulated quadcopter flights with climbs and tilt manoeuvres they
were the clean flights' accelerometer NIS of 2.10-2.11 (band [1.94, 2.06] for 5000
two-component updates), and Ljung-Box p = 0.000 on the one at 2.10; with them, 1.97-2.02 and
p = 0.56-0.79. The diagnosis feeds ``v_d`` from its own altitude filter run over the same log
(:func:`groundstation.diagnosis.models.with_vertical_velocity`); any other user of
:func:`groundstation.estimation.routing.attitude_estimator` gets it from a logged ``VELOCITY_NED`` or
``CLIMB_RATE``.

The base model takes the measured rates for the true ones. Two catalogue effects
change that, each a rebuild of this model with one more option:

* ``gyro_bias=True``: ``w_m = w + b``, states ``b_p, b_q`` (random walks, the IMU's
  bias instability). A yaw-rate bias is left out: gravity and drag say nothing of yaw.
* ``misalignment=True``: the IMU mounted rotated by small angles ``delta = (d_phi,
  d_theta, 0)`` (the simulator's ``f_m = C f, w_m = C w``, ``C = A_IB(delta)^T ~ I -
  [delta x]``), states ``m_roll, m_pitch`` (constants). To first order
  ``w = w_m + delta x w_m`` and::

      f_m,x = -mu u - d_theta f_z,    f_m,y = -mu v + d_phi f_z

  with ``f_z`` the measured body-z specific force. In steady hover ``f_z = -g`` and
  the mounting is exactly an attitude offset with a velocity offset ``g delta / mu``
  (the base model then reads the IMU's own tilt); only thrust changes (climbs,
  descents) and the rate coupling separate the two, which is why this effect needs
  a flight with vertical manoeuvres to be found. The mounting's yaw component is
  not observable from the IMU and is not estimated.

A horizontal accelerometer bias is not among the options: it is exactly a tilt
with a velocity offset, ``b = g delta`` (a simulated 0.2 m/s^2 bias, modelled as two
more states, raised the log-likelihood by 1 over 5000 updates), so it shows only
against an external attitude reference.

The model is a multirotor's: a coaxial helicopter steers with its flapping lower
rotor, whose tilted thrust, not drag, is what its accelerometer sees sideways.

It runs as an extended Kalman filter in :class:`~groundstation.estimation.filters.ModelFilter`
(the measurement is linear; the dynamics relinearised each step). The rates
are small-angle in the mounting only; the attitude itself is kept nonlinear.
"""

from __future__ import annotations

import math

import numpy as np

from groundstation.core.measurement import Kind

from .base import LinearModel, MeasurementModel

G = 9.80665


#: below this cos(roll) cos(pitch) (a tilt beyond 60 deg, no multirotor's flight) the q w, p w terms
#: are left out: their 1 / (cos(roll) cos(pitch)) made a candidate that had run away (a gyro bias
#: of 0.96 rad/s on Crazyflie 0425-traj4) diverge to pitch -90 deg instead of coming back
MIN_TILT_COS = 0.5


def body_w(vd: float, sf: float, cf: float, st: float, ct: float, u: float, v: float) -> float:
    """The body's vertical velocity (FRD z) from the world's (NED down) and the body's horizontal one."""
    return (vd + st * u - sf * ct * v) / (cf * ct)


def _with_w(u, cf: float, ct: float) -> bool:
    return len(u) > 3 and math.isfinite(u[3]) and cf * ct >= MIN_TILT_COS


def attitude_drag_model(
    *,
    mu: float = 0.35,
    gyro_noise: float = 2.2e-4,
    G_v: float = 2e-4,
    sigma_accel: float = 0.08,
    bias_walk: float = 3e-6,
    P0_angle: float = 0.05,
    P0_bias: float = 0.05,
    P0_mount: float = 0.1,
    P0_v: float = 0.2,
    gyro_bias: bool = False,
    misalignment: bool = False,
) -> LinearModel:
    """The drag attitude model. Noise as densities: ``gyro_noise`` [rad/s/sqrt(Hz)], ``G_v``
    [(m/s^2)^2/Hz] for what the velocity model leaves out (the ``q w`` terms, gusts),
    ``bias_walk`` [rad/s/sqrt(s)]; ``sigma_accel`` [m/s^2] per accelerometer sample: an update
    is a 10 ms block mean of n samples (:func:`groundstation.diagnosis.runs.run.prepare`), read with
    R = sigma^2 / n. 0.08 is the simulator's white noise. A fixed R per block (0.0335^2, right for
    the simulator's 500 Hz IMU, 5-6 samples) is 1.7 times too small for a live recording's 250 Hz
    one."""
    states = ["roll", "pitch", "u", "v"]
    if gyro_bias:
        states += ["b_p", "b_q"]
    if misalignment:
        states += ["m_roll", "m_pitch"]
    n = len(states)
    ib = states.index("b_p") if gyro_bias else None
    im = states.index("m_roll") if misalignment else None

    def rates(x, u):
        """The true body rates from the measured ones, and d(p, q, r)/dx."""
        pm, qm, rm = float(u[0]), float(u[1]), float(u[2])
        D = np.zeros((3, n))
        if ib is not None:
            pm, qm = pm - x[ib], qm - x[ib + 1]
            D[0, ib], D[1, ib + 1] = -1.0, -1.0
        p, q, r = pm, qm, rm
        if im is not None:
            dphi, dth = x[im], x[im + 1]
            p, q, r = pm + dth * rm, qm - dphi * rm, rm + dphi * qm - dth * pm
            D[0, im + 1], D[1, im], D[2, im], D[2, im + 1] = rm, -rm, qm, -pm
            if ib is not None:
                D[2, ib], D[2, ib + 1] = dth, -dphi
        return p, q, r, D

    def f(x, u):
        phi, th, vu, vv = x[0], x[1], x[2], x[3]
        p, q, r, _ = rates(x, u)
        sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(th), math.cos(th)
        xd = np.zeros(n)
        xd[0] = p + (q * sf + r * cf) * st / ct
        xd[1] = q * cf - r * sf
        xd[2] = -G * st + r * vv - mu * vu
        xd[3] = G * sf * ct - r * vu - mu * vv
        if _with_w(u, cf, ct):
            w = body_w(float(u[3]), sf, cf, st, ct, vu, vv)
            xd[2] -= q * w
            xd[3] += p * w
        return xd

    def jacobian(x, u):
        phi, th, vu, vv = x[0], x[1], x[2], x[3]
        p, q, r, D = rates(x, u)
        sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(th), math.cos(th)
        tt = st / ct
        J = np.zeros((n, n))
        J[0, 0], J[0, 1] = (q * cf - r * sf) * tt, (q * sf + r * cf) / ct**2
        J[1, 0] = -q * sf - r * cf
        J[2, 1], J[2, 2], J[2, 3] = -G * ct, -mu, r
        J[3, 0], J[3, 1], J[3, 2], J[3, 3] = G * cf * ct, -G * sf * st, -r, -mu
        w = 0.0
        if _with_w(u, cf, ct):
            vd = float(u[3])
            w = body_w(vd, sf, cf, st, ct, vu, vv)
            # dw / d(phi, theta, u, v)
            dW = np.array(
                [(vd * sf / ct + st / ct * vu * sf - vv) / cf**2, (vd * st + vu) / (cf * ct**2), tt / cf, -sf / cf]
            )
            J[2, :4] -= q * dW
            J[3, :4] += p * dW
        # through the rates: d x_dot / d(p, q, r) times d(p, q, r) / dx
        dw = np.array([[1.0, sf * tt, cf * tt], [0.0, cf, -sf], [0.0, -w, vv], [w, 0.0, -vu]])
        J[:4] += dw @ D
        return J

    def accel_xy(m, ctx):
        if m.instance != 0:
            return None
        ctx.f_z = float(m.value[2])
        return np.array([float(m.value[0]), float(m.value[1])])

    def accel_row(ctx):
        H = np.zeros((2, n))
        H[0, 2] = H[1, 3] = -mu
        if im is not None:
            fz = ctx.f_z if ctx.f_z is not None else -G
            H[0, im + 1], H[1, im] = -fz, fz
        return H

    q = [gyro_noise**2] * 2 + [G_v] * 2 + [bias_walk**2] * 2 * gyro_bias + [0.0] * 2 * misalignment
    p0 = [P0_angle**2] * 2 + [P0_v**2] * 2 + [P0_bias**2] * 2 * gyro_bias + [P0_mount**2] * 2 * misalignment
    meas = {
        "accel": MeasurementModel(
            "accel", Kind.ACCEL, accel_xy, accel_row, np.eye(2) * sigma_accel**2, instance=0, per_sample=True
        )
    }
    options = dict(
        mu=mu,
        gyro_noise=gyro_noise,
        G_v=G_v,
        sigma_accel=sigma_accel,
        bias_walk=bias_walk,
        P0_angle=P0_angle,
        P0_bias=P0_bias,
        P0_mount=P0_mount,
        P0_v=P0_v,
        gyro_bias=gyro_bias,
        misalignment=misalignment,
    )
    return LinearModel(
        name="attitude",
        states=states,
        inputs=["p", "q", "r", "v_d"],
        A=lambda u: np.zeros((n, n)),
        B=np.zeros((n, 4)),
        Qc=np.diag(q),
        x0=np.zeros(n),
        P0=np.diag(p0),
        measurements=meas,
        doc=__doc__,
        f=f,
        jacobian=jacobian,
        options=options,
    )
