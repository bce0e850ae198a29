"""Recursive least squares: coaxial-helicopter document, chapter 7.

Model ``y = phi^T theta`` (eq. 7.1-7.4); the recursion (eq. 7.18, 7.19), with
a forgetting factor lambda (lambda = 1 is the document's filter)::

    K(k)     = P(k-1) phi(k) / (lambda + phi(k)^T P(k-1) phi(k))
    theta(k) = theta(k-1) + K(k) (y(k) - phi(k)^T theta(k-1))           (7.19/7.20)
    P(k)     = (P(k-1) - K(k) phi(k)^T P(k-1)) / lambda                 (7.18)

A limit of the method the document does not mention: the regressor (the
pressure) is itself noisy, and least squares then flattens the slope by
``var(p) / (var(p) + sigma_p^2)`` (regression dilution); over a flight of one
or two metres with a 4 Pa barometer that is 10-20 %.

Corrections to the document: the cost (7.5) lacks its square,
``V = sum (y - y_hat)^2``; below (7.14) the matrix-inversion lemma is applied
with ``D = phi^T(k)``, not ``phi^T(k-1)``.

:class:`BaroRangeCalibration` is the document's use of it: the barometer
calibrated against the range sensor, ``altitude = a * pressure + b``. The
pressure regressor is centred on the first reading: raw pressures near 1e5 Pa
make phi phi^T ill-conditioned, and centring changes b, not the fit.
"""

from __future__ import annotations

import numpy as np

from groundstation.core.measurement import Kind, Measurement


class RecursiveLeastSquares:
    def __init__(self, n: int, *, lam: float = 1.0, P0: float = 1e6, theta0=None) -> None:
        if not 0.0 < lam <= 1.0:
            raise ValueError("forgetting factor must be in (0, 1]")
        self.lam = lam
        self.theta = np.zeros(n) if theta0 is None else np.asarray(theta0, dtype=float).copy()
        self.P = np.eye(n) * P0
        self.k = 0

    def covariance(self, sigma2: float) -> np.ndarray:
        """Cov(theta) = sigma^2 P for white measurement noise of variance sigma^2 and an exact
        regressor (lambda = 1, P0 large): what NEES is measured against."""
        return sigma2 * self.P

    def update(self, phi, y: float) -> float:
        """One sample; returns the a-priori residual y - phi^T theta(k-1)."""
        phi = np.asarray(phi, dtype=float)
        Pphi = self.P @ phi
        K = Pphi / (self.lam + phi @ Pphi)
        e = float(y - phi @ self.theta)
        self.theta = self.theta + K * e
        P = (self.P - np.outer(K, Pphi)) / self.lam
        self.P = 0.5 * (P + P.T)  # rounding makes it drift from symmetric, then unstable
        self.k += 1
        return e


def least_squares(Phi_T: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """The offline solution (eq. 7.10), theta = (Phi Phi^T)^-1 Phi Y, via lstsq."""
    return np.linalg.lstsq(Phi_T, Y, rcond=None)[0]


class BaroRangeCalibration:
    """Pressure -> altitude, fitted online against the range sensor (eq. 7.1, 7.2).

    Range readings are paired with the barometer sample nearest in time
    (within ``max_dt``); ``altitude(p)`` applies the current fit.
    """

    def __init__(self, *, lam: float = 1.0, max_dt: float = 0.02) -> None:
        self.rls = RecursiveLeastSquares(2, lam=lam)
        self.max_dt = max_dt
        self.p_ref: float | None = None
        self._baro: tuple[float, float] | None = None
        self.pairs = 0

    @property
    def a(self) -> float:
        return float(self.rls.theta[0])

    @property
    def b(self) -> float:
        """Altitude at the reference pressure ``p_ref``."""
        return float(self.rls.theta[1])

    def altitude(self, p: float) -> float:
        return self.a * (p - (self.p_ref or 0.0)) + self.b

    def handle(self, m: Measurement) -> float | None:
        if m.kind is Kind.BARO_PRESSURE:
            if self.p_ref is None:
                self.p_ref = float(m.value[0])
            self._baro = (m.t, float(m.value[0]))
        elif m.kind is Kind.RANGE and self._baro is not None and abs(m.t - self._baro[0]) <= self.max_dt:
            self.pairs += 1
            p_ref = self.p_ref if self.p_ref is not None else self._baro[1]
            return self.rls.update([self._baro[1] - p_ref, 1.0], float(m.value[0]))
        return None
