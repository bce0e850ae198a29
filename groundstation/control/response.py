"""Reading a closed-loop response: fitted omega_0 and zeta, and the lab's words for it.

:func:`step_fit` fits the normalised step response of eq. 24,
``omega_0^2 / (s^2 + 2 zeta omega_0 s + omega_0^2)`` with a small dead time,
to a measured step (scipy's ``least_squares`` on the closed-form response).
:func:`classify` names a response as the lab's Table 2 does (unstable, undamped, underdamped,
critically damped, overdamped) from its envelope and overshoot.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares


def second_order_step(t: np.ndarray, omega0: float, zeta: float) -> np.ndarray:
    """Unit step response of eq. 24, ``1 + (s2 e^{s1 t} - s1 e^{s2 t}) / (s1 - s2)``
    with s1,2 its poles (complex arithmetic covers every zeta; zeta = 1 is nudged)."""
    if abs(zeta - 1.0) < 1e-6:
        zeta = 1.0 + 1e-6
    r = omega0 * np.sqrt(complex(zeta * zeta - 1.0))
    s1, s2 = -zeta * omega0 + r, -zeta * omega0 - r
    return np.real(1.0 + (s2 * np.exp(s1 * t) - s1 * np.exp(s2 * t)) / (s1 - s2))


def step_fit(t: np.ndarray, y: np.ndarray, t_step: float, y0: float, y1: float) -> tuple[float, float, float]:
    """(omega_0, zeta, dead time) of the second-order step best matching y after t_step."""
    m = t >= t_step
    tt, yy = t[m] - t_step, (y[m] - y0) / (y1 - y0)

    def model(q):
        w, z, d = q
        return np.where(tt > d, second_order_step(np.maximum(tt - d, 0.0), w, z), 0.0)

    sol = least_squares(
        lambda q: model(q) - yy,
        [3.0, 0.8, 0.01],
        bounds=([0.05, 0.01, 0.0], [60.0, 5.0, 0.3]),
        diff_step=1e-3,
        x_scale=[1.0, 0.1, 0.01],
    )
    w0, zeta, delay = (float(v) for v in sol.x)
    return w0, zeta, delay


def classify(t: np.ndarray, y: np.ndarray, t_step: float, y0: float, y1: float, *, limit: float = 1.0) -> str:
    """The lab's words for a step response of y from y0 to y1 starting at t_step.

    unstable: it leaves ``limit`` rad (or hits an end stop) or its oscillation
    grows; undamped: it oscillates with no visible decay (the last peaks keep
    > 80 % of the first); underdamped: overshoot above 2 %; critically damped:
    overshoot up to 2 % and a rise as steep as zeta <= 1.15 gives; overdamped:
    a flatter rise (zeta above 1.15).
    """
    m = t >= t_step
    tt, e = t[m] - t_step, (y[m] - y1) / (y1 - y0)  # normalised error, -1 at the start
    if not np.all(np.isfinite(y[m])) or np.max(np.abs(y[m])) > limit:
        return "unstable"
    # oscillation envelope: peaks of |e| after the first crossing of zero
    cross = np.nonzero(np.diff(np.sign(e)) != 0)[0]
    if len(cross) >= 3:
        peaks = [np.max(np.abs(e[a : b + 1])) for a, b in zip(cross[:-1], cross[1:])]
        if len(peaks) >= 3 and peaks[-1] > 1.2 * peaks[0] and peaks[-1] > 0.05:
            return "unstable"
        if len(peaks) >= 3 and peaks[-1] > 0.8 * peaks[0] and peaks[0] > 0.05:
            return "undamped"
    overshoot = float(np.max(e))
    if overshoot > 0.02:
        return "underdamped"
    # the shape of the rise tells critically from overdamped: t90 / t10 is 7.3 for
    # zeta = 1, 8.5 for zeta = 1.15, 10.3 for zeta = 1.38 and 22 for a first-order lag
    above10, above90 = np.nonzero(e >= -0.9)[0], np.nonzero(e >= -0.1)[0]
    if len(above90) == 0 or tt[above10[0]] <= 0:
        return "overdamped"
    return "critically damped" if tt[above90[0]] / tt[above10[0]] <= 8.5 else "overdamped"
