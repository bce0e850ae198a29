"""Horizontal position from the IMU and GPS, with GPS's correlated error as states.

None of the design documents estimates horizontal position; the dashboard
needs it (the vehicle's place and its covariance ellipsoid), so this is the
horizontal counterpart of the coaxial document's chapter 9 filter: the same
structure (acceleration as input, an absolute sensor as update), one axis pair.

State ``x = (n, e, vn, ve, b_n, b_e)``: position [m] in a local NED frame whose
origin is the first GPS fix, velocity [m/s], GPS position error [m]. Input:
the NED horizontal acceleration ``(a_n, a_e) = rows 1, 2 of A_IB f`` (gravity
has no horizontal component). Continuous model::

    n_dot = vn,  e_dot = ve,  vn_dot = a_n,  ve_dot = a_e
    b_dot = -b / tau_gps + w_b        (first-order Gauss-Markov, sigma_gps, tau_gps)

    GPS:  y = (n, e) + (b_n, b_e) + v,   v white (sigma_white)

Why the bias states: a GPS position error is correlated over tens of seconds
(atmosphere, multipath); taken as white it would make the filter believe the
average of a few fixes to centimetres. Here P says what is true, that GPS alone
pins the position to about sigma_gps. At the first fix the origin is defined by
a fix that carries its own error, so ``n = -b_n`` there: P0 carries that
correlation (-sigma_gps^2) rather than pretending the origin is exact.

Attitude errors enter through the input (g delta_theta of false acceleration):
``G_acc`` covers them.
"""

from __future__ import annotations

import math

import numpy as np

from groundstation.core.measurement import Kind

from .base import LinearModel, MeasurementModel

M_PER_DEG = 111_320.0  # metres per degree of latitude (and of longitude at the equator)


def local_ne(lat: float, lon: float, origin: tuple[float, float]) -> np.ndarray:
    """Local north/east [m] of a WGS84 point about ``origin`` (equirectangular: exact to
    millimetres over the few hundred metres a session covers)."""
    lat0, lon0 = origin
    return np.array([(lat - lat0) * M_PER_DEG, (lon - lon0) * M_PER_DEG * math.cos(math.radians(lat0))])


def horizontal_model(
    *, G_acc: float = 0.05, sigma_gps: float = 1.0, tau_gps: float = 20.0, sigma_white: float = 0.3
) -> LinearModel:
    """Defaults: the simulated receiver (1 m Gauss-Markov over 20 s, 0.3 m white), a
    typical single-frequency GPS; ``G_acc`` [(m/s^2)^2/Hz] for attitude and IMU errors."""
    A = np.zeros((6, 6))
    A[0, 2] = A[1, 3] = 1.0
    A[4, 4] = A[5, 5] = -1.0 / tau_gps
    B = np.zeros((6, 2))
    B[2, 0] = B[3, 1] = 1.0
    q_b = 2.0 * sigma_gps**2 / tau_gps
    H = np.array([[1.0, 0, 0, 0, 1.0, 0], [0, 1.0, 0, 0, 0, 1.0]])
    P0 = np.diag([sigma_gps**2 + 0.01, sigma_gps**2 + 0.01, 0.1**2, 0.1**2, sigma_gps**2, sigma_gps**2])
    P0[0, 4] = P0[4, 0] = P0[1, 5] = P0[5, 1] = -(sigma_gps**2)

    def gps(m, ctx):
        lat, lon = float(m.value[0]), float(m.value[1])
        if ctx.gps_origin is None:
            ctx.gps_origin = (lat, lon)
        return local_ne(lat, lon, ctx.gps_origin)

    meas = {"gps": MeasurementModel("gps", Kind.GPS, gps, lambda ctx: H, np.eye(2) * sigma_white**2)}
    return LinearModel(
        name="horizontal",
        states=["n", "e", "vn", "ve", "b_n", "b_e"],
        inputs=["a_n", "a_e"],
        A=lambda u: A,
        B=B,
        Qc=np.diag([0.0, 0.0, G_acc, G_acc, q_b, q_b]),
        x0=np.zeros(6),
        P0=P0,
        measurements=meas,
        doc=__doc__,
    )
