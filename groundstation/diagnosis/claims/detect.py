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
  cumulative sum marks a step or a drift, and where it is;
* excursion: the ``EXCURSION_S`` windows whose innovations' sum is furthest
  from 0 for its spread (a scan statistic), against a Bonferroni bound over the
  log's windows. CUSUM sees what lasts; this sees a transient and says when it
  was, and what the throttle did then (ArduPilot's underpowered.log: the baro
  reads 2.8 m low over 53.8-55.7 s as the motors spin up on the ground, the
  data README's dip).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.stats import chi2, norm

from groundstation.estimation.models.ground import LANDED
from groundstation.estimation.whiteness import effective_size, lag1, ljung_box

if TYPE_CHECKING:
    from groundstation.diagnosis.runs.run import Run


@dataclass
class Finding:
    sensor: str
    test: str
    passed: bool
    statistic: float
    threshold: str
    where: str = ""  # time or signal the failure points at

    def as_dict(self) -> dict:
        return asdict(self)


#: s: the excursion test's window (a spin-up, a touchdown, a gust)
EXCURSION_S = 2.0
#: how many of the worst windows beyond the bound (not overlapping) the finding names
EXCURSIONS_SHOWN = 3


def ar1_sum_variance(m: np.ndarray, r: float) -> np.ndarray:
    """Var(e_1 + ... + e_m) for a unit-variance AR(1) sequence with lag-1 correlation r:
    m (1 + r) / (1 - r) - 2 r (1 - r^m) / (1 - r)^2. Shorter than the correlation time, a sum
    varies less than m times the long-run factor (1 + r) / (1 - r) says: 20 samples at
    r = 0.95, 292 against 780."""
    m = np.asarray(m, dtype=float)
    return m * (1 + r) / (1 - r) - 2 * r * (1 - r**m) / (1 - r) ** 2


def detect(
    sensor: str,
    t: np.ndarray,
    e: np.ndarray,
    nis: np.ndarray,
    dim: int,
    signals: dict[str, np.ndarray],
    nu: np.ndarray | None = None,
) -> list[Finding]:
    """All tests on one sensor's normalised innovations ``e`` (first component) and NIS; ``nu``,
    the innovations in the sensor's units, sizes the excursion."""
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
        out.append(
            Finding(sensor, f"cross-correlation with {name}", bool(abs(r) < bound), r, f"|r| < {bound:.3f}", name)
        )
    # mean spacing: a median is 0 when most updates share a stamp with another (a demo recording did)
    dt = float(t[-1] - t[0]) / (n - 1) if n > 1 else 0.0
    if n >= 64 and dt > 0:
        f = np.fft.rfftfreq(n, dt)[1:]
        P = np.abs(np.fft.rfft(ec))[1:] ** 2
        k = int(np.argmax(P))
        ratio = float(P[k] / np.median(P))
        # a white sequence's periodogram bins are ~ exponential: max/median < ln(n)/ln 2 + margin
        thr = 3.0 * np.log(len(P)) / np.log(2)
        out.append(Finding(sensor, "spectral peak", ratio < thr, ratio, f"max/median < {thr:.0f}", f"{f[k]:.2f} Hz"))
    c = np.cumsum(e)
    k = int(np.argmax(np.abs(c)))
    # var(S_n) = n^2 / n_eff for AR(1)-like e; max_k |S_k| of a Brownian path over [0, 1]
    # exceeds 2.24 standard deviations with probability 5 %
    stat = float(abs(c[k]) * np.sqrt(ne) / n)
    out.append(Finding(sensor, "CUSUM", stat < 2.24, stat, "< 2.24", f"t = {t[k]:.1f} s"))
    x = excursion(sensor, t, e, lag1(e), nu, signals.get("throttle"))
    if x is not None:
        out.append(x)
    return out


def excursion(
    sensor: str,
    t: np.ndarray,
    e: np.ndarray,
    r: float = 0.0,
    nu: np.ndarray | None = None,
    throttle: np.ndarray | None = None,
    window: float = EXCURSION_S,
) -> Finding | None:
    """The scan statistic: over every ``window`` s of updates, z = sum(e) / sd(sum), the sum's
    spread that of an AR(1) sequence with the innovations' lag-1 correlation ``r``
    (:func:`ar1_sum_variance`: the colour counted at the window's length; the long-run factor
    n / n_eff, as the mean test counts it, hid underpowered.log's 2 s baro dip at spin-up behind a
    whole log's colour: z -3.0, against -6.1 with it); the largest |z| against the
    two-sided 5 % bound shared among the log's duration / window windows (Bonferroni). Its
    ``where`` names the worst windows beyond the bound (up to :data:`EXCURSIONS_SHOWN`, not
    overlapping, worst first), each with the innovations' mean over it in the sensor's units
    and the throttle at its ends."""
    span = float(t[-1] - t[0]) if len(t) else 0.0
    if span < 2 * window:
        return None
    c = np.concatenate([[0.0], np.cumsum(e)])
    j = np.minimum(np.searchsorted(t, t + window, side="left"), len(t))  # window k: updates k .. j[k] - 1
    n_w = j - np.arange(len(t))
    full = (t + window <= t[-1]) & (n_w >= 3)
    if not full.any():
        return None
    z = np.where(full, (c[j] - c[:-1]) / np.sqrt(ar1_sum_variance(np.maximum(n_w, 1), r)), 0.0)
    bound = float(norm.ppf(1.0 - 0.025 * window / span))
    order = np.argsort(-np.abs(z))
    worst = int(order[0])
    places: list[tuple[float, str]] = []
    for k in order:
        if abs(z[k]) < bound or len(places) == EXCURSIONS_SHOWN:
            break
        if any(abs(t[k] - u) < window for u, _ in places):
            continue
        last = int(j[k]) - 1
        where = f"t = {t[k]:.1f}-{t[last]:.1f} s"
        if nu is not None:
            where += f", mean {float(np.mean(nu[k : last + 1])):+.2f}"
        if throttle is not None and np.isfinite(throttle[[k, last]]).all():
            where += f", throttle {float(throttle[k]):.2f} -> {float(throttle[last]):.2f}"
        places.append((float(t[k]), where))
    where = "; ".join(w for _, w in places) or f"t = {t[worst]:.1f} s"
    return Finding(sensor, "excursion", bool(abs(z[worst]) < bound), float(z[worst]), f"|z| < {bound:.2f}", where)


def sensor_findings(run: Run) -> list[Finding]:
    """Every sensor's tests on a run's innovations, from 5 s in (the filter settling); the ground's
    pseudo-sensor is no sensor."""
    out = []
    for s, tr in run.sensors.items():
        if s == LANDED:
            continue
        k = tr.t >= tr.t[0] + 5.0
        sig = {n: v[k] for n, v in tr.signals.items() if n not in ("throttle_lp",)}
        out += detect(s, tr.t[k], tr.nu_normalised[k], tr.nis[k], tr.nu.shape[1], sig, nu=tr.nu[k, 0])
    return out


def residuals_pass(findings: list[Finding]) -> bool:
    """The residuals pass: NIS in its band and white (the diagnosis's stopping rule)."""
    return all(f.passed for f in findings if f.test in ("NIS mean", "Ljung-Box whiteness"))
