"""Thrust lost as the battery sags, traced beside the altitude model from the accelerometer.

The altitude model takes the accelerometer as its input, so it never predicts thrust: a thrust the
throttle no longer buys leaves nothing in its residuals (``UNOBSERVABLE["altitude"]``). The thrust
model does predict it (the quadcopter document's ``a = alpha tau + beta``), but through the height
sensors twice integrated: outdoors, beside wind and a mission's horizontal legs, its filter read a
voltage exponent of 1.35 ± 0.13 on a flight whose ESCs hold the rotor speed whatever the voltage,
and -0.24 ± 0.03 on another.

The accelerometer measures the thrust itself. Its specific force along the body's z axis is the
thrust and the airframe's drag, ``-f_z = a_T - mu v c``, less the accelerometer's bias as the
altitude filter tracks it through the flight (the height sensors hold its ``b_acc`` to the truth: a
bias moving 0.03 m/s^2 per K as the IMU warms 10 K had read as n = 1.5 without it, on indoor flights
of another generator whose ESCs hold the rotor speed), and :mod:`.airframe` fits the thrust curve
``a_T = (alpha tau + beta) (V / V_ref)^n`` to it by equation error, with ``n`` free. Here that fit is
the test of ``thrust_voltage`` (``n``, the simulator's and the catalogue's exponent), against the same
curve with n = 0, on the altitude filter's own height and vertical speed (so a log without a range
sensor is read too):

* evidence: Delta BIC of the two fits' residuals, counted at one independent point a window
  (:data:`.airframe.WINDOW` / :data:`.airframe.STEP` grid points), below -10 (very strong, as the
  catalogue's claims);
* size: n at least 3 standard errors from 0;
* out of sample: fitted on two of three time blocks, the third's residuals fall in sum and on no
  block does the log-likelihood fall by more than 2 (the pack is lowest in the last block: the fit
  must extrapolate there, as it would on the next flight);
* physics: ``n`` within :data:`PLAUSIBLE_N`. A motor's thrust goes with the square of its speed and,
  with an open-loop ESC, its speed with the voltage: n near 2, less with the motor's own losses.
  Thrust that *rises* as the pack sags, or falls with its fourth power, is not this effect: it is
  reported as a finding about the model (something thrust-side it lacks), not claimed;
* the accelerometer's bias: the thrust the fitted n takes from the battery over the fitted stretch
  (``n ln(V_end / V_start) g``) at least :data:`BIAS_FACTOR` times what the accelerometer's bias moved
  by over it, as the altitude filter tracks it. A pack's voltage and an IMU's temperature both move one
  way through a flight, and the filter's bias follows a warming IMU with a lag: a bias moving
  0.03 m/s^2 per K (0.12-0.14 m/s^2 over the stretch) left n = 0.57-0.69 after the tracked bias was
  taken out, a change of 0.08-0.10 m/s^2, on indoor flights of another generator whose ESCs hold the
  rotor speed; the battery's real effect there made 0.63-0.76 m/s^2, beside a bias that moved
  0.01-0.03. Twice: a filter that follows none of the bias's move leaves all of it in the thrust, and
  its estimate at the stretch's ends is uncertain too.

"Before" and "after" are the curve's residual thrust [m/s^2] without and with the effect.
"""

from __future__ import annotations

import math

import numpy as np

from groundstation.core.measurement import Kind
from groundstation.diagnosis.catalogue.airframe import STEP, WINDOW, CurvePoints, G, curve_points, fit_curve
from groundstation.diagnosis.catalogue.battery import loaded_voltage
from groundstation.diagnosis.catalogue.thrust_model import hover_prior, lift_off, throttle_series
from groundstation.diagnosis.effect import Effect
from groundstation.diagnosis.runs.run import Prepared, Run
from groundstation.estimation.models.contact import RANGE_FLOOR
from groundstation.estimation.models.ground import TAU_GROUND

#: the exponent a battery's sag can have on a rotor's thrust (module docstring)
PLAUSIBLE_N = (0.3, 4.0)
#: the least ratio of the thrust change the fitted n makes over the flight to the accelerometer's bias
#: change over it (module docstring)
BIAS_FACTOR = 2.0
#: the claim's bars, as the catalogue's (scored.STRONG, holdout)
STRONG = -10.0
MIN_Z = 3.0
MAX_BLOCK_LOSS = 2.0
BLOCKS = 3


def _rss(pts: CurvePoints, curve, at: np.ndarray) -> float:
    """The squared residuals as thrust [(m/s^2)^2]: the fit's are throttle, alpha times that thrust."""
    r = pts.residual((curve.alpha, curve.beta, curve.drag, curve.n, curve.tc), at) * curve.alpha
    return float(r @ r)


def _independent(points: int) -> float:
    """The grid points' worth in independent samples: a window's points overlap."""
    return max(points * STEP / WINDOW, 1.0)


def voltage_effect(prep: Prepared, run: Run | None) -> Effect | None:
    """``thrust_voltage`` from the accelerometer's thrust curve (module docstring): an Effect with
    ``evidence["claimed"]`` True when it passes every bar, False (with ``evidence["reason"]``) when
    the fit finds it but a bar turns it away; None where the log cannot say (no logged throttle,
    battery voltage, accelerometer or attitude, or too little flight)."""
    kinds = prep.kinds
    if not prep.logged_throttle or not {Kind.BATTERY_VOLTAGE, Kind.ACCEL, Kind.ATTITUDE} <= kinds:
        return None
    th = throttle_series(prep.measurements)
    flying = [(t, v) for t, v in th if v >= TAU_GROUND]
    if len(flying) < 10:
        return None
    prior = hover_prior(prep, curve=False)
    oc, v_ref = prior.get("voltage_oc"), prior.get("voltage_ref")
    if oc is None or not v_ref:
        return None

    def volt(t, tau):
        return loaded_voltage(oc.at(t), tau, sag=prior.get("voltage_sag"), oc=oc, t=t)

    height = bias = None
    if run is not None and {"z", "vz"} <= set(run.model.states) and len(run.t):
        height = (run.t, run.x[:, run.model.index("z")], run.x[:, run.model.index("vz")])
        if "b_acc" in run.model.states:  # on gamma_z, up: the body-z bias is its negative
            bias = (run.t, -run.x[:, run.model.index("b_acc")])
    t_lift = lift_off(prep.measurements, flying[0][0], (RANGE_FLOOR, math.inf))
    pts = curve_points(
        prep.measurements,
        th,
        flying[0][0],
        t_lift,
        flying[-1][0],
        voltage=volt,
        voltage_ref=v_ref,
        height=height,
        bias_track=bias,
    )
    if pts is None:
        return None
    with_n, without = fit_curve(pts, need_alpha=False), fit_curve(pts, free_n=False, need_alpha=False)
    if with_n is None or without is None:
        return None
    n_eff = _independent(int(pts.keep.sum()))
    rss1, rss0 = _rss(pts, with_n, pts.keep), _rss(pts, without, pts.keep)
    delta_bic = n_eff * math.log(rss1 / rss0) + math.log(n_eff)
    held = _held_out(pts)
    n, sigma_n = with_n.n, with_n.sigma["n"]
    points = int(pts.keep.sum())
    evidence: dict = {
        "model": "thrust curve from the accelerometer",
        "delta_bic": round(delta_bic, 1),
        "z": {"n": round(abs(n) / sigma_n, 1) if sigma_n > 0 else 0.0},
        "thrust_rms_before": round(math.sqrt(rss0 / points), 4),
        "thrust_rms_after": round(math.sqrt(rss1 / points), 4),
        "seconds": round(points * STEP, 1),
        "height_from": "the altitude filter's estimate" if height is not None else "the range sensor",
        # the size this flight would claim about half the time (scored.smallest_claimed, one parameter)
        "n_50": round(sigma_n * math.sqrt(max(math.log(n_eff) - STRONG, 0.0)), 3),
    }
    if held:  # (a fit on two blocks that fails leaves none)
        evidence["held_out_gain"] = round(sum(held), 1)
        evidence["held_out_gain_by_block"] = [round(g, 1) for g in held]
    # what n makes of the voltage's fall over the fitted stretch, as thrust at hover, beside how far the
    # accelerometer's bias moved over it (the physics' second bar, module docstring)
    ends = np.flatnonzero(pts.keep)[[0, -1]]
    thrust_change = abs(n * float(pts.lr[ends[1]] - pts.lr[ends[0]])) * G
    evidence["thrust_change"] = round(thrust_change, 4)
    bias_change = 0.0
    if bias is not None:
        b0, b1 = np.interp(pts.grid[ends], bias[0], bias[1])
        bias_change = abs(float(b1 - b0))
        evidence["bias_change"] = round(bias_change, 4)
    params = {"n": round(n, 4), "sigma_n": round(sigma_n, 4)}
    reason = None
    if delta_bic >= STRONG:
        reason = f"Delta BIC {delta_bic:+.1f} is not very strong evidence"
    elif sigma_n <= 0 or abs(n) < MIN_Z * sigma_n:
        reason = f"n = {n:.3g} ± {sigma_n:.2g} is within {MIN_Z:.0f} standard errors of 0"
    elif not held or sum(held) <= 0 or min(held) < -MAX_BLOCK_LOSS:
        reason = (
            "on stretches of the flight it was not fitted on it does not hold ("
            + (", ".join(f"{g:+.1f}" for g in held) if held else "the fit fails on two thirds of the flight")
            + ")"
        )
    elif not PLAUSIBLE_N[0] <= n <= PLAUSIBLE_N[1]:
        reason = (
            f"n = {n:.3g} ± {sigma_n:.2g} is no battery's effect on a rotor (thrust goes with up to the square of "
            f"the voltage, n in {PLAUSIBLE_N[0]:g}-{PLAUSIBLE_N[1]:g}): the thrust curve lacks something else that "
            "changed over the flight"
        )
    elif thrust_change < BIAS_FACTOR * bias_change:
        reason = (
            f"the thrust n = {n:.3g} takes from the battery, {thrust_change:.2g} m/s^2 over the flight, is not "
            f"{BIAS_FACTOR:g} times the {bias_change:.2g} m/s^2 the accelerometer's bias moved by: the thrust curve "
            "cannot tell a battery's sag from the IMU's bias moving as it warms"
        )
    evidence["claimed"] = reason is None
    if reason is not None:
        evidence["reason"] = reason
    return Effect("thrust_voltage", params, evidence)


def _held_out(pts: CurvePoints) -> list[float]:
    """Per time block, the log-likelihood gained on it by n fitted on the other blocks (at one
    independent point a window); empty where a fit fails."""
    idx = np.flatnonzero(pts.keep)
    gains = []
    for block in np.array_split(idx, BLOCKS):
        test = np.zeros(len(pts.keep), bool)
        test[block] = True
        train = pts.keep & ~test
        with_n, without = fit_curve(pts, train, need_alpha=False), fit_curve(pts, train, free_n=False, need_alpha=False)
        if with_n is None or without is None:
            return []
        r1, r0 = _rss(pts, with_n, test), _rss(pts, without, test)
        gains.append(0.5 * _independent(len(block)) * math.log(r0 / r1))
    return gains
