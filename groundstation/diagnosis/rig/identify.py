"""The rig's effects found from a session: each candidate frees parameters of the rig's model
(:mod:`.model`), fitted by weighted nonlinear least squares (``scipy.optimize.least_squares``), and
kept by the Bayesian information criterion, forward, the largest first.

Why not the engine the flying vehicles' diagnosis runs (a Kalman filter per candidate, scored by
its innovations): the rig has its state measured. The encoders give the angles at 1.5 mrad and
500 Hz, so the equations of motion and the IMU's can be checked at every sample, equation by
equation (equation-error identification), and the lab's model is linear in most of what it lacks.

The likelihood, per group g of residuals (an axis's acceleration, a gyro or accelerometer axis),
with its variance profiled out: ``-2 ln L = sum_g n_g ln(RSS_g / n_g)``. The residuals of a
filtered signal are correlated over the filter's window and over what the model still lacks, so
each group counts as its effective number of samples, ``n / tau`` with ``tau = 1 + 2 sum rho_k``
(the integrated autocorrelation time of its residuals). An effect is kept where

* it lowers the criterion by ``MIN_DELTA_BIC`` or more: ΔBIC (the model with it, less the model
  without; negative where it is better, as the engine reports it) at most -10, ``k ln n_eff`` charged for its k
  parameters), and
* fitted on either half of the session it predicts the other half better (a two-fold
  cross-validation: a term that fits one stretch's peculiarity does not carry over), and
* the session can tell its parameters from those already found (no correlation of the estimates
  over ``SEPARABLE``): an IMU mounted rolled and a pitch encoder zeroed off level read the same in
  the IMU, and only the travel's dynamics part them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .catalogue import RigCandidate
from .model import BOUNDS, PARAMETERS, Columns, residuals
from .session import RigSession

MIN_DELTA_BIC = 10.0  #: Kass and Raftery's "very strong" evidence, as the engine's claims
SEPARABLE = 0.98  #: the largest correlation of a new parameter's estimate with a found one's
ROW_STRIDE_S = 0.02  #: [s] between the rows a fit reads (the filter spans four)


def rows_of(s: RigSession, keep: np.ndarray | None = None) -> np.ndarray:
    """Every ``ROW_STRIDE_S`` of free flight (and of ``keep``, where given)."""
    free = s.free if keep is None else s.free & keep
    stride = max(1, int(round(ROW_STRIDE_S / s.dt)))
    idx = np.flatnonzero(free)
    return idx[idx % stride == 0]


def tau(r: np.ndarray, gaps: np.ndarray) -> float:
    """Integrated autocorrelation time of ``r`` (in rows), summed until the correlation first falls
    under 0.05. ``gaps``: True at a row that starts a stretch; a pair of rows with a stretch's start
    between them is not a lag of one stretch, and is not counted."""
    r = r - r.mean()
    var = float(r @ r)
    if var <= 0 or len(r) < 20:
        return 1.0
    starts = np.cumsum(gaps)
    out = 1.0
    for k in range(1, min(len(r) // 4, 400)):
        same = starts[k:] == starts[:-k]
        a, b = r[k:][same], r[:-k][same]
        if len(a) < 10:
            break
        rho = float(a @ b) / var * len(r) / len(a)
        if rho < 0.05:
            break
        out += 2.0 * rho
    return out


@dataclass
class Fit:
    """One model fitted: its parameter values, the residuals' sums of squares and counts per group,
    and its free parameters' standard errors and correlations."""

    values: dict[str, float]
    free: tuple[str, ...]
    rss: dict[str, float]
    n: dict[str, int]
    sigma: dict[str, float] = field(default_factory=dict)  #: the free parameters' standard errors
    #: the free parameters' estimates' correlations, in the order of ``free``
    corr: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def neg2lnl(self, n_eff: dict[str, float]) -> float:
        return sum(n_eff[g] * math.log(self.rss[g] / self.n[g]) for g in self.rss if self.rss[g] > 0)


def fit(
    c: Columns,
    start: dict[str, float],
    free: tuple[str, ...],
    scale: dict[str, float],
) -> Fit:
    """``free`` fitted from ``start``, each group's residuals weighted by ``scale`` (its noise)."""
    values = dict(start)
    if free:
        x0 = np.array([values[k] for k in free])
        lo = np.array([BOUNDS.get(k, (-np.inf, np.inf))[0] for k in free])
        hi = np.array([BOUNDS.get(k, (-np.inf, np.inf))[1] for k in free])
        # a parameter at a bound starts a step inside it: the finite differences need room (a lag
        # of exactly 0 has no slope on one side)
        typical = np.array([PARAMETERS[k][1] for k in free])
        x0 = np.where(x0 <= lo, lo + 0.2 * typical, x0)
        x0 = np.clip(x0, lo, hi)

        def fun(x):
            for k, xi in zip(free, x):
                values[k] = float(xi)
            r = residuals(values, c)
            return np.concatenate([r[g] / scale[g] for g in scale])

        sol = least_squares(fun, x0, bounds=(lo, hi), x_scale=typical, method="trf", max_nfev=200, diff_step=1e-4)
        for k, xi in zip(free, sol.x):
            values[k] = float(xi)
        sigma, corr = _standard_errors(sol.jac, sol.fun, free)
    else:
        sigma, corr = {}, np.zeros((0, 0))
    r = residuals(values, c)
    return Fit(
        values, free, {g: float(v @ v) for g, v in r.items()}, {g: len(v) for g, v in r.items()}, sigma=sigma, corr=corr
    )


def _standard_errors(J: np.ndarray, f: np.ndarray, free: tuple[str, ...]) -> tuple[dict[str, float], np.ndarray]:
    """The parameters' standard errors from the Jacobian of the weighted residuals (their variance
    scaled to the fit's), and their correlations."""
    try:
        cov = np.linalg.pinv(J.T @ J)
    except np.linalg.LinAlgError:
        return {}, np.zeros((0, 0))
    dof = max(1, len(f) - len(free))
    s2 = float(f @ f) / dof
    d = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    sigma = {k: float(math.sqrt(max(0.0, cov[i, i] * s2))) for i, k in enumerate(free)}
    return sigma, cov / np.outer(d, d)


def confounded(f: Fit, found: tuple[str, ...], new: tuple[str, ...]) -> str | None:
    """A found parameter whose estimate the new ones' correlate with beyond ``SEPARABLE`` (the
    session cannot tell them apart), or None."""
    if f.corr.shape != (len(f.free), len(f.free)):
        return None
    idx = {k: i for i, k in enumerate(f.free)}
    for a in new:
        for b in found:
            if abs(f.corr[idx[a], idx[b]]) > SEPARABLE:
                return b
    return None


def effective(fit: Fit, c: Columns, gaps: np.ndarray) -> dict[str, float]:
    """Each group's effective number of samples at ``fit``."""
    r = residuals(fit.values, c)
    return {g: len(v) / tau(v, gaps) for g, v in r.items()}


def noise_scale(fit: Fit) -> dict[str, float]:
    return {g: math.sqrt(max(fit.rss[g] / fit.n[g], 1e-18)) for g in fit.rss}


@dataclass
class Step:
    """One candidate tried at one step of the search."""

    name: str
    delta_bic: float  #: the model with it less the model without: negative where it is better
    cross_validated: bool | None  #: None: not checked (its criterion did not pass)
    fit: Fit
    #: the found parameter it cannot be told from (then it is not claimed)
    confounded_with: str | None = None


@dataclass
class Search:
    """The forward search's record: the lab's model, each effect as it was claimed, and what was
    tried at each step."""

    base: Fit
    final: Fit
    claimed: list[Step] = field(default_factory=list)
    tried: list[list[Step]] = field(default_factory=list)


def _gaps(rows: np.ndarray, stride: int) -> np.ndarray:
    """True at a row that does not follow the one before it by the stride."""
    g = np.ones(len(rows), dtype=bool)
    g[1:] = np.diff(rows) != stride
    return g


def search(s: RigSession, catalogue: list[RigCandidate], start: dict[str, float]) -> Search:
    """The forward search over ``catalogue`` from the model ``start`` (the lab's, or a rig file's)."""
    rows = rows_of(s)
    stride = max(1, int(round(ROW_STRIDE_S / s.dt)))
    c = Columns(rows, s)
    gaps = _gaps(rows, stride)
    half = s.t[rows[len(rows) // 2]] if len(rows) else 0.0
    folds = [(s.t < half, s.t >= half), (s.t >= half, s.t < half)]
    fold_cols = [(Columns(rows_of(s, a), s), Columns(rows_of(s, b), s)) for a, b in folds]

    base = fit(c, start, (), {})
    current = base
    free: tuple[str, ...] = ()
    left = list(catalogue)
    record = Search(base, base)
    while left:
        scale = noise_scale(current)
        n_eff = effective(current, c, gaps)
        n_all = sum(n_eff.values())
        steps = []
        for cand in left:
            f = fit(c, current.values, free + cand.params, scale)
            delta = f.neg2lnl(n_eff) - current.neg2lnl(n_eff) + len(cand.params) * math.log(n_all)
            steps.append(Step(cand.name, delta, None, f))
        steps.sort(key=lambda st: st.delta_bic)
        record.tried.append(steps)
        taken = None
        for st in steps:
            if st.delta_bic > -MIN_DELTA_BIC:
                break
            cand = next(x for x in left if x.name == st.name)
            st.confounded_with = confounded(st.fit, free, cand.params)
            if st.confounded_with is not None:
                continue
            st.cross_validated = _carries_over(fold_cols, current, free, cand.params, scale, n_eff)
            if st.cross_validated:
                taken = (st, cand)
                break
        if taken is None:
            break
        st, cand = taken
        free = free + cand.params
        current = st.fit
        record.claimed.append(st)
        left = [x for x in left if x.name != cand.name and not set(x.params) & set(free)]
    record.final = current
    return record


def _carries_over(folds, current: Fit, free, params, scale, n_eff) -> bool:
    """Fitted on each half, the model with the effect predicts the other half better than without."""
    for fit_on, test_on in folds:
        if not len(fit_on.rows) or not len(test_on.rows):
            return False
        without = fit(fit_on, current.values, free, scale)
        with_ = fit(fit_on, current.values, free + params, scale)
        r0, r1 = residuals(without.values, test_on), residuals(with_.values, test_on)
        gain = 0.0
        for g in r0:
            a, b = float(r0[g] @ r0[g]), float(r1[g] @ r1[g])
            if a > 0 and b > 0:
                gain += n_eff[g] * math.log(a / b) * 0.5  # half the session's samples
        if gain <= 0:
            return False
    return True
