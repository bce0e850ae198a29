"""Is an innovation sequence white? The statistics the evaluation and the diagnosis share.

For a correct model the normalised innovations are white, zero-mean and of unit variance
(Mehra 1970; Bar-Shalom, Li and Kirubarajan 2001, sec. 5.4): Ljung-Box asks the first, and the
lag-1 autocorrelation says how many independent samples a correlated sequence is worth.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2


def ljung_box(x: np.ndarray, lags: int = 20) -> float:
    """p-value of the Ljung-Box test that ``x`` is white (no autocorrelation up to ``lags``)."""
    return float(chi2.sf(ljung_box_q(x, lags), lags))


def ljung_box_q(x: np.ndarray, lags: int = 20) -> float:
    """The Ljung-Box statistic Q = n (n + 2) sum_k rho_k^2 / (n - k), k = 1..lags (chi^2 with ``lags``
    degrees of freedom for white ``x``); NaN for a sequence too short or constant."""
    x = np.asarray(x, dtype=float)
    n = len(x)
    if n <= lags + 1:
        return float("nan")
    x = x - x.mean()
    d = x @ x
    if d == 0:
        return float("nan")
    rho = np.array([x[:-k] @ x[k:] / d for k in range(1, lags + 1)])
    return float(n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, lags + 1))))


def lag1(e: np.ndarray) -> float:
    """The lag-1 autocorrelation, held to [0, 0.99] (negative r counts as 0)."""
    if len(e) < 3:
        return 0.0
    return min(max(float(np.corrcoef(e[:-1], e[1:])[0, 1]), 0.0), 0.99)


def effective_size(e: np.ndarray) -> float:
    """How many independent samples ``e`` is worth, from its lag-1 autocorrelation r
    (AR(1): n (1 - r) / (1 + r))."""
    r1 = lag1(e)
    return len(e) * (1 - r1) / (1 + r1)
