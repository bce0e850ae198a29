"""The airframe's thrust curve from the log's own accelerometer: the thrust model's prior without a vehicle file.

The quadcopter document's thrust model, ``a_T = alpha tau + beta`` (eq. 2), wants alpha and beta
"estimated offline" (sec. 1). Without a vehicle file the diagnosis read them from the hover throttle,
``alpha0 = g / tau_hover`` with beta held at 0, since at a steady hover only ``alpha tau + beta`` shows.
On the simulated quadcopter (22 m/s^2, -1.2 m/s^2) that made alpha 10 % low, and every thrust effect was
then sized against a throttle that buys too little thrust: a 0.05 s actuator lag was not found, 0.1 s
read 0.084-0.086 s, a voltage exponent of 1 read 0.65-0.76 (README, "from the log alone").

The accelerometer measures the thrust directly. Along the body's z axis (FRD) its specific force is the
thrust and the airframe's drag, ``-f_z = a_T - mu (v_up c)`` to first order in the tilt, whatever the
vehicle's height does; the thrust model itself never reads the IMU (its input is the throttle), so this
is an independent reading of the curve. Fitted, here, by equation error over the flight:

    tau = u + tc du/dt,   u = ((y + mu v c) (V / V_ref)^-n - beta) / alpha,   y = -(f_z - b_z)

with ``y`` and ``tau`` averaged over ``WINDOW`` s on a 20 Hz grid, ``v`` the vertical speed from the range
sensor's height ``r c`` (a local quadratic over the window), ``b_z`` the accelerometer's bias from the
ground before the spin-up (where it reads ``-g c``), ``V`` the pack's voltage between its readings
(battery.py: the smoothed open-circuit voltage less the load line) and ``V_ref`` the voltage alpha is
read at (the thrust model's, :func:`~.thrust_model.hover_prior`). ``n`` (``thrust_voltage``) and ``tc``
(``actuator_lag``, a first-order lag: ``tau = tau_applied + tc dtau_applied/dt``) are fitted along,
as nuisance parameters: held at 0, a simulated n = 1 flight read alpha 17.4 and beta +1.0. Which
effects the log has is the diagnosis' question, answered by its own filter and criterion; this fit
only gives it the curve to start from. Ground effect is kept out by height (``H_MIN``), the tilt's
horizontal drag (which the model lacks) by tilt (``C_MIN``).

Why the throttle is the fitted side ("reverse" regression): the logged throttle is a sample of a faster
controller's output, and the samples' aliasing is an error in it that the window's mean does not remove
(on a clean simulated flight 3-5 % of its variance at every window from 0.2 to 4 s). As the regressor,
that error flattened the curve, alpha 21.3-21.6 for 22 (errors in variables); as the fitted variable it
is noise, and the accelerometer's own, averaged over the window, is 0.01 m/s^2.

Measured on eight simulated thrust test flights (clean twice, n = 1, 1.5, 2, lag 0.05 and 0.1 s, R = 0.25 m),
as the diagnosis prepares them: alpha 22.2-23.0 for 22, beta -1.31 to -1.79 for -1.2, drag 0.34-0.35 for
0.35 (the hover prior: 19.8, 0, 0.3); n 1.05, 1.67, 2.22 and tc 0.051, 0.103 s on the way. Fed the
simulator's true throttle instead, a clean flight reads 22.24: the simulated accelerometer's variation is
1 % larger than the thrust's, and that much of alpha's excess is the simulator's. Least squares on the
model above is scipy's (``least_squares``); nothing in numpy, scipy or filterpy fits this equation, hence
written here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings

G = 9.80665
#: s: the window the accelerometer and throttle are averaged over (and the range's speed fitted in)
WINDOW = 0.5
#: s: the grid's step
STEP = 0.05
#: m: only heights above this are fitted: 4 rotor radii for R = 0.19 m, where ground effect adds 0.4 %
#: of the thrust (0.25 m: 0.7 %; Cheeseman-Bennett)
H_MIN = 0.75
#: cos(roll) cos(pitch) at least this (5.7 deg): tilted, the body's z axis sees the horizontal drag
#: the model lacks. Kept in, a clean flight's tilt manoeuvres (at the end of the flight, the pack at its
#: lowest) read n = 0.08-0.14 for 0
C_MIN = 0.995
#: the fit is used with at least this many grid points (10 s in the air) ...
MIN_POINTS = 200
#: ... and alpha's standard error at most this fraction of it (a flight at one throttle cannot
#: tell alpha from beta)
MAX_REL_SIGMA = 0.03
#: (m/s^2)^2/Hz: the thrust model's acceleration noise with the curve from the log. The diagnosis'
#: 0.006 (thrust_model.DIAGNOSIS_G_ACC) covers a curve read from the hover throttle, 10 % off; with the curve
#: read here the model is as good as with the airframe file, and takes its noise (sim_quad.json: 0.0001,
#: chosen by the whiteness of 8 clean simulated flights' range innovations). On four thrust test flights
#: (clean seeds 1012 and 1018, n = 1, lag 0.05 s) the range's Ljung-Box p after the fix was 0.000-0.019
#: with 0.006, 0.002-0.126 with 0.0005 and 0.135-0.76 with 0.0001, and the 0.05 s lag was found only
#: below 0.006; the base model's likelihood on the clean two peaks at 0.00003-0.0001. It is not fitted per
#: log: with an effect in the data the likelihood grows with G_acc up to 0.003 and beyond (the noise
#: takes up the effect). A vehicle file's G_acc overrides it (a field vehicle in gusts has more)
CURVE_G_ACC = 0.0001
#: s: lift-off and touchdown are left out (the ground's reaction, the contact's transients)
EDGE = 2.0


@dataclass(frozen=True)
class ThrustCurve:
    """``a_T = (alpha tau + beta) (V / V_ref)^n`` through a lag ``tc``, with vertical drag ``drag``, as
    the accelerometer reads it; ``sigma``: standard errors (the window's overlap counted), ``points``
    and ``seconds``: how much of the flight was fitted, ``bias_z``: the accelerometer's z bias taken out."""

    alpha: float
    beta: float
    drag: float
    n: float
    tc: float
    sigma: dict
    points: int
    seconds: float
    bias_z: float

    def prior(self) -> dict:
        """The thrust model's constants from it (:func:`~.thrust_model.thrust_model`'s parameters)."""
        return {
            "alpha0": self.alpha,
            "beta0": self.beta,
            "drag": self.drag,
            "sigma_alpha0": 0.2 * self.alpha,
            "sigma_beta0": max(0.05, self.sigma["beta"]),
            "G_acc": CURVE_G_ACC,
        }

    def as_dict(self) -> dict:
        return {
            "source": "accelerometer",
            "alpha": round(self.alpha, 3),
            "beta": round(self.beta, 3),
            "drag": round(self.drag, 3),
            "n": round(self.n, 3),
            "tc": round(self.tc, 4),
            "sigma": {k: round(v, 4) for k, v in self.sigma.items()},
            "G_acc": CURVE_G_ACC,
            "points": self.points,
            "seconds": round(self.seconds, 1),
            "bias_z": round(self.bias_z, 4),
        }


def _window_mean(t: np.ndarray, x: np.ndarray, grid: np.ndarray, w: float) -> np.ndarray:
    """The mean of the samples ``x(t)`` within ``w / 2`` of each grid point (NaN where none)."""
    c = np.concatenate([[0.0], np.cumsum(x)])
    lo, hi = np.searchsorted(t, grid - w / 2), np.searchsorted(t, grid + w / 2)
    n = hi - lo
    return np.where(n > 0, (c[hi] - c[lo]) / np.maximum(n, 1), np.nan)


def _held(t: np.ndarray, x: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``x`` held from each sample to the next (as the filter holds its input), at times ``at``."""
    return x[np.clip(np.searchsorted(t, at, side="right") - 1, 0, None)]


def _height_and_speed(t: np.ndarray, h: np.ndarray, grid: np.ndarray, w: float) -> tuple[np.ndarray, np.ndarray]:
    """Height and vertical speed at each grid point: a quadratic through the readings within ``w / 2``."""
    hh, vv = np.full(len(grid), np.nan), np.full(len(grid), np.nan)
    lo, hi = np.searchsorted(t, grid - w / 2), np.searchsorted(t, grid + w / 2)
    for k in np.flatnonzero(hi - lo >= 5):
        s = slice(lo[k], hi[k])
        p = np.polyfit(t[s] - grid[k], h[s], 2)
        vv[k], hh[k] = p[1], p[2]
    return hh, vv


@dataclass(frozen=True)
class CurvePoints:
    """The equation-error fit's data on its grid (:func:`curve_points`): the throttle ``tau`` and the
    body-z specific force ``y`` averaged over each window, the drag's regressor ``vc`` (vertical speed
    times cos_tilt), the voltage's ``lr = ln(V / V_ref)``, which points have every value (``finite``)
    and which are fitted (``keep``)."""

    grid: np.ndarray
    tau: np.ndarray
    y: np.ndarray
    vc: np.ndarray
    lr: np.ndarray
    finite: np.ndarray
    keep: np.ndarray
    bias: float
    with_voltage: bool

    def residual(self, p: Sequence[float], at: np.ndarray) -> np.ndarray:
        """tau - (u + tc du/dt) at the points ``at`` (a mask), for p = (alpha, beta, mu, n, tc)."""
        alpha, beta, mu, n, tc = p
        u = ((self.y + mu * self.vc) * np.exp(-n * self.lr) - beta) / alpha
        du = np.gradient(np.where(self.finite, u, 0.0), self.grid)  # the zeros reach no kept point
        return (self.tau - (u + tc * du))[at]


def curve_points(
    ms: Sequence[Measurement],
    throttle: list[tuple[float, float]],
    t_spin: float,
    t_lift: float,
    t_end: float,
    *,
    voltage=None,
    voltage_ref: float | None = None,
    range_limits: tuple[float, float] = (0.05, math.inf),
    height: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    bias_track: tuple[np.ndarray, np.ndarray] | None = None,
) -> CurvePoints | None:
    """The fit's data (:func:`thrust_curve` says what each argument is), or None when the log cannot
    give it. ``height``: (t, h, v_up) of an estimate to take the height and vertical speed from,
    instead of the range sensor's readings (an altitude filter's run, where the log has no range).
    ``bias_track``: (t, b_z) of an estimate of the accelerometer's body-z bias [m/s^2] through the
    flight (the altitude filter's ``b_acc``, which the height sensors hold to the accelerometer): its
    change from the spin-up on is taken out of the specific force as the bias measured on the ground
    is, so that a bias moving as the IMU warms is not read as the thrust changing."""
    r = Readings.of(ms)
    t, _, v = r.columns(Kind.ACCEL)
    acc = np.column_stack([t, v[:, 2]])[np.isfinite(v[:, 2])] if v.shape[1] >= 3 else np.zeros((0, 2))
    t, _, v = r.columns(Kind.ATTITUDE)
    att = np.column_stack([t, v[:, :2]])[np.isfinite(v[:, :2]).all(axis=1)] if v.shape[1] >= 2 else np.zeros((0, 3))
    t, _, v = r.columns(Kind.RANGE)
    rng = np.zeros((0, 2))
    if v.shape[1]:
        rng = np.column_stack([t, v[:, 0]])[(v[:, 0] >= range_limits[0]) & (v[:, 0] <= range_limits[1])]
    if len(acc) < 100 or len(att) < 10 or (height is None and len(rng) < 50):
        return None
    th = np.array([(t, v) for t, v in throttle if math.isfinite(t) and math.isfinite(v)])
    if len(th) < 50:
        return None
    for a in (acc, att, rng, th):
        if len(a):
            a[:] = a[np.argsort(a[:, 0], kind="stable")]

    def c_of(t):  # cos(roll) cos(pitch) at times t
        return np.cos(np.interp(t, att[:, 0], att[:, 1])) * np.cos(np.interp(t, att[:, 0], att[:, 2]))

    # without 50 samples before the spin-up (a log that starts in the air) the bias is taken as 0: it
    # then moves beta by itself
    ground = acc[:, 0] < t_spin
    bias = float(np.mean(acc[ground, 1] + G * c_of(acc[ground, 0]))) if ground.sum() >= 50 else 0.0
    grid = np.arange(t_lift + EDGE, t_end - EDGE, STEP)
    if len(grid) < MIN_POINTS:
        return None
    fine = np.arange(grid[0] - WINDOW, grid[-1] + WINDOW, 0.005)  # the held throttle, sampled finely
    tau_fine = _held(th[:, 0], th[:, 1], fine)
    tau = _window_mean(fine, tau_fine, grid, WINDOW)
    drift = np.zeros(len(acc))
    if bias_track is not None and len(bias_track[0]):
        bt, bz = bias_track
        drift = np.interp(acc[:, 0], bt, bz) - float(np.interp(t_spin, bt, bz))
    y = _window_mean(acc[:, 0], -(acc[:, 1] - bias - drift), grid, WINDOW)
    c = c_of(grid)
    if height is None:
        h, v = _height_and_speed(rng[:, 0], rng[:, 1] * c_of(rng[:, 0]), grid, WINDOW)
    else:
        ht, hh, hv = height
        h, v = _window_mean(ht, hh, grid, WINDOW), _window_mean(ht, hv, grid, WINDOW)
    lr = np.zeros(len(grid))
    if voltage is not None and voltage_ref:
        volts = np.array([voltage(t, u) for t, u in zip(fine, tau_fine)])
        with np.errstate(divide="ignore", invalid="ignore"):
            lr = _window_mean(fine, np.log(volts / voltage_ref), grid, WINDOW)
    finite = np.isfinite(y) & np.isfinite(v) & np.isfinite(lr)
    # du/dt is taken between neighbours: both must be there
    keep = finite & np.roll(finite, 1) & np.roll(finite, -1) & np.isfinite(tau) & (h >= H_MIN) & (c >= C_MIN)
    keep[[0, -1]] = False
    if keep.sum() < MIN_POINTS:
        return None
    return CurvePoints(grid, tau, y, v * c, lr, finite, keep, bias, voltage is not None and bool(voltage_ref))


def fit_curve(
    pts: CurvePoints, at: np.ndarray | None = None, *, free_n: bool | None = None, need_alpha: bool = True
) -> ThrustCurve | None:
    """The curve by least squares over the points ``at`` (default: every kept point), ``n`` free where
    the points have the voltage (``free_n`` False holds it at 0); None where the fit fails or (with
    ``need_alpha``, as a prior needs) cannot tell alpha from beta. A fit held to compare against
    another is taken whatever its alpha's spread (``need_alpha`` False): a curve that lacks an effect
    the data has fits worse, and its alpha is the less certain for it."""
    at = pts.keep if at is None else at & pts.keep
    free_n = pts.with_voltage if free_n is None else free_n and pts.with_voltage
    if at.sum() < MIN_POINTS // 2:
        return None
    tau_h = float(np.median(pts.tau[at]))
    if not tau_h > 0:
        return None
    x0 = [min(max(G / tau_h, 0.5), 200.0), 0.0, 0.3, 0.0, 0.0]
    lo = [0.5, -G, 0.0, -3.0 if free_n else -1e-9, 0.0]
    hi = [200.0, G, 3.0, 5.0 if free_n else 1e-9, 0.5]
    fit = least_squares(lambda p: pts.residual(p, at), x0, bounds=(lo, hi), x_scale=[G / tau_h, 1.0, 0.3, 1.0, 0.1])
    if not fit.success:
        return None
    r = fit.fun
    free = [0, 1, 2, 3, 4] if free_n else [0, 1, 2, 4]
    J = fit.jac[:, free]
    try:
        # the windows overlap: WINDOW / STEP grid points per independent one
        cov = np.linalg.inv(J.T @ J) * float(r @ r) / max(len(r) - len(free), 1) * (WINDOW / STEP)
    except np.linalg.LinAlgError:
        return None
    sd = np.zeros(5)
    sd[free] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    alpha, beta, mu, n, tc = (float(x) for x in fit.x)
    if need_alpha and not sd[0] <= MAX_REL_SIGMA * alpha:
        return None
    sigma = dict(zip(("alpha", "beta", "drag", "n", "tc"), (float(s) for s in sd)))
    return ThrustCurve(
        alpha, beta, mu, n if free_n else 0.0, tc, sigma, int(at.sum()), float(at.sum()) * STEP, pts.bias
    )


def thrust_curve(
    ms: Sequence[Measurement],
    throttle: list[tuple[float, float]],
    t_spin: float,
    t_lift: float,
    t_end: float,
    *,
    voltage=None,
    voltage_ref: float | None = None,
    range_limits: tuple[float, float] = (0.05, math.inf),
) -> ThrustCurve | None:
    """The curve (module docstring) from ``t_lift + EDGE`` to ``t_end - EDGE``, the accelerometer's bias
    from before the spin-up at ``t_spin`` (the vehicle leaves the ground before its range sensor reads
    above its floor, so taken up to the lift-off it read the climb: -0.03 m/s^2), or None when the log
    cannot give it: no accelerometer, attitude or range sensor, too little flight above ``H_MIN``, or a
    throttle too steady to tell alpha from beta. ``voltage(t, tau)``: the pack's voltage (with
    ``voltage_ref``), or None to fit without the voltage term."""
    pts = curve_points(
        ms, throttle, t_spin, t_lift, t_end, voltage=voltage, voltage_ref=voltage_ref, range_limits=range_limits
    )
    return fit_curve(pts) if pts is not None else None
