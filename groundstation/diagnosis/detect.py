"""Step 2, detect: is a sensor's innovation sequence what the model promises?

For a correct model the normalised innovations ``e_k = nu_k / sqrt(S_k)`` are
white, zero-mean and of unit variance (Mehra 1970; Bar-Shalom et al. 2001,
sec. 5.4), so each test below asks one way in which they are not:

* NIS: its mean against the chi-square band of the sample size;
* mean: ``mean(e) sqrt(n_eff)`` against N(0, 1), with ``n_eff`` the sample
  size shrunk by the lag-1 autocorrelation (an effect makes e correlated,
  which would otherwise inflate every test);
* whiteness: Ljung-Box over 20 lags, and the fraction of autocorrelations
  outside +-1.96/sqrt(n);
* cross-correlation with the inputs and the logged signals (throttle, tilt,
  temperature, voltage...), against +-1.96/sqrt(n_eff);
* spectral peak: the periodogram's largest bin over its median (a vibration
  or an oscillating error), with its frequency;
* CUSUM on e (Page 1954): the largest standardised excursion of the
  cumulative sum marks a step or a drift, and where it is.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.stats import chi2, norm

from ..evaluate import ljung_box


@dataclass
class Finding:
    sensor: str
    test: str
    passed: bool
    statistic: float
    threshold: str
    where: str = ""            # time or signal the failure points at

    def as_dict(self) -> dict:
        return asdict(self)


def effective_size(e: np.ndarray) -> float:
    """How many independent samples ``e`` is worth, from its lag-1 autocorrelation r
    (AR(1): n (1 - r) / (1 + r); negative r counts as 0)."""
    if len(e) < 3:
        return float(len(e))
    r1 = float(np.corrcoef(e[:-1], e[1:])[0, 1])
    r1 = min(max(r1, 0.0), 0.99)
    return len(e) * (1 - r1) / (1 + r1)


def detect(sensor: str, t: np.ndarray, e: np.ndarray, nis: np.ndarray, dim: int,
           signals: dict[str, np.ndarray]) -> list[Finding]:
    """All tests on one sensor's normalised innovations ``e`` (first component) and NIS."""
    out: list[Finding] = []
    n = len(e)
    if n < 30:
        return [Finding(sensor, "too few updates", True, float(n), ">= 30")]
    lo, hi = chi2.ppf([0.025, 0.975], dim * n) / n
    m_nis = float(np.mean(nis))
    out.append(Finding(sensor, "NIS mean", bool(lo <= m_nis <= hi), m_nis, f"[{lo:.2f}, {hi:.2f}]"))
    ne = effective_size(e)
    z = float(np.mean(e) * np.sqrt(ne))
    out.append(Finding(sensor, "innovation mean", bool(abs(z) < norm.ppf(0.995)), z, "|z| < 2.58"))
    p = ljung_box(e)
    out.append(Finding(sensor, "Ljung-Box whiteness", bool(p > 0.05), p, "p > 0.05"))
    lags = min(50, n // 4)
    ec = e - e.mean()
    acf = np.array([np.dot(ec[:-k], ec[k:]) for k in range(1, lags + 1)]) / np.dot(ec, ec)
    frac = float(np.mean(np.abs(acf) > 1.96 / np.sqrt(n)))
    out.append(Finding(sensor, "autocorrelation bounds", frac <= 0.1, frac, "<= 10 % of lags outside"))
    bound = 1.96 / np.sqrt(ne)
    for name, s in signals.items():
        ok = np.isfinite(s)
        if ok.sum() < 30 or np.std(s[ok]) < 1e-9:
            continue
        r = float(np.corrcoef(e[ok], s[ok])[0, 1])
        out.append(Finding(sensor, f"cross-correlation with {name}", bool(abs(r) < bound), r, f"|r| < {bound:.3f}",
                           name))
    # mean spacing: a median is 0 when most updates share a stamp with another (a demo recording did)
    dt = float(t[-1] - t[0]) / (n - 1) if n > 1 else 0.0
    if n >= 64 and dt > 0:
        f = np.fft.rfftfreq(n, dt)[1:]
        P = np.abs(np.fft.rfft(ec))[1:] ** 2
        k = int(np.argmax(P))
        ratio = float(P[k] / np.median(P))
        # a white sequence's periodogram bins are ~ exponential: max/median < ln(n)/ln 2 + margin
        thr = 3.0 * np.log(len(P)) / np.log(2)
        out.append(Finding(sensor, "spectral peak", ratio < thr, ratio, f"max/median < {thr:.0f}",
                           f"{f[k]:.2f} Hz"))
    c = np.cumsum(e)
    k = int(np.argmax(np.abs(c)))
    # var(S_n) = n^2 / n_eff for AR(1)-like e; max_k |S_k| of a Brownian path over [0, 1]
    # exceeds 2.24 standard deviations with probability 5 %
    stat = float(abs(c[k]) * np.sqrt(ne) / n)
    out.append(Finding(sensor, "CUSUM", stat < 2.24, stat, "< 2.24", f"t = {t[k]:.1f} s"))
    return out
