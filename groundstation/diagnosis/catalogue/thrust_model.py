"""The thrust-model filter as a diagnosis model: where thrust-side effects can show.

The altitude filter takes the accelerometer as its input, so it never predicts
thrust and cannot see thrust loss. The quadcopter document's filter predicts
the vertical acceleration from the throttle, ``a = alpha tau + beta`` (eq. 2,
along the body axis, times ``c = cos(roll) cos(pitch)``), so anything that
changes the thrust the throttle buys leaves a residual in the baro and range
innovations. For diagnosis its coefficients are constants estimated from the
log (alpha, beta, the baro and ToF offsets: zero process noise): as random
walks (the live filter's setting) they would absorb a slow thrust loss, which
is exactly what is looked for here.

Input ``u = (tau c, c, g, V, h, alpha_hat tau + beta_hat, V_ref, n_hat, a_V)``: the
document's three, then what the effects' couplings read (battery voltage, the
height, the current thrust estimate, the voltage alpha's prior was read at,
thrust_voltage's exponent as estimated and its thrust change beyond the
linearisation), linearised about the current estimate as an EKF does.

**Airframe drag, added to the document's model.** Eq. (1)-(2) have no drag: the
vertical acceleration is the thrust alone. A multirotor climbing or sinking at
1 m/s loses 0.2-0.5 m/s^2 to drag (the simulated quadcopter: 0.35 /s, as its
horizontal drag), a residual correlated with the vertical speed; without a drag
term a clean flight's diagnosis credited it to ``thrust_voltage`` (3 of 5 clean
simulated flights) and the sparse regression named ``vz`` every time. So the
base model carries ``vz_dot -= mu_z vz`` with ``mu_z`` a known constant
(``drag``, 0.3 /s unless the vehicle file says otherwise). Estimated as a state it
was linearised about ``vz_hat`` (``mu_z vz`` is bilinear), and on ArduPilot's
underpowered.log that gave the filter a knob: a persistent ``vz_hat`` of 0.3 m/s
times a negative ``mu_z`` stood in for the sagging thrust.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings
from groundstation.core.units import G
from groundstation.diagnosis.catalogue.airframe import thrust_curve
from groundstation.diagnosis.catalogue.battery import OpenCircuitVoltage, load_line, loaded_voltage, reading_sigma
from groundstation.diagnosis.runs.run import SETTLE_S
from groundstation.estimation.context import Context
from groundstation.estimation.estimator import KalmanEstimator
from groundstation.estimation.models.base import LinearModel
from groundstation.estimation.models.contact import (
    CONTACT_H,
    RANGE_FLOOR,
    ground_contact,
    in_contact,
    note_range,
)
from groundstation.estimation.models.ground import TAU_GROUND, landed, on_ground
from groundstation.estimation.models.quad_thrust import DRAG, quad_thrust_model
from groundstation.estimation.routing import (
    THRUST_CONTEXT,
    motor_outputs_of,
    read_specific_force,
    throttle_at_reading,
)

GE_MIN_H = 0.1  # m: below this the first-order ground-effect term is not used


#: s after the model leaves the ground during which the ground-effect term is not used. The model's
#: lift-off is late: held on the ground until its thrust without ground effect lifts it or the range
#: reads it 5 cm up, while a vehicle in ground effect rises earlier (at h <= R its thrust is 1/16 up).
#: Released at rest with the vehicle climbing, the model caught up through the 1/h^2 term itself: on
#: a simulated R = 0.15 m the take-off gave half the likelihood gain (+43 of +86) and R read 0.20 m;
#: 0.18 m without it. With the ground contact's resets (ground_contact) R reads 0.155 m, 0.167 m
#: without this
GE_SETTLE = 1.0


#: m: with the estimate on the ground (at or below CONTACT_H), a range reading further up than this is a
#: spurious echo, skipped and its time kept (``range_spurious``, a tuple in the context): a vehicle leaves the ground
#: continuously, and a range sensor reads it at 5-50 Hz, so its first readings after a lift-off are
#: within a few tenths of a metre of its floor. ArduPilot's underpowered.log: its sonar read 1.9-6.5 m
#: for 0.9 s as the motors spun up on the ground, and the model, taking them, flew to 8 m at 28 m/s
LIFTOFF_REACH = 1.0


#: s: the range reads inside its limits this long without a break: the vehicle is in the air (lift_off)
LIFTOFF_HOLD = 2.0


#: m: the ToF offset d_tof is held at its prior (0) to this. No sensor reads it: below RANGE_FLOOR
#: the range is not used, so on the ground nothing ties the range to z = 0, and left free (2 cm
#: a priori) d_tof was set by the take-off alone, wherever the model's climb and the range's
#: disagreed there, and carried through the flight: +1 cm on a clean simulated quad (height error
#: 1.23 cm, 0.55 cm held), +7 cm with rotor ground effect lifting it early (6.9 cm, 0.59 cm held).
#: A constant range offset is unobservable here, as in the altitude model (measured against truth
#: when the log has it)
TOF_HELD = 0.002


#: the thrust model's acceleration noise in the diagnosis [(m/s^2)^2/Hz], unless the vehicle file says or
#: the thrust curve comes from the accelerometer (airframe.CURVE_G_ACC)
DIAGNOSIS_G_ACC = 0.006


def thrust_model(
    *,
    drag: float = DRAG,
    voltage_ref: float | None = None,
    voltage_sag: float | None = None,
    voltage_oc: OpenCircuitVoltage | None = None,
    **params,
) -> LinearModel:
    """The quadcopter document's filter with constant coefficients, airframe drag (see the
    module's docstring) and the input widened for the
    couplings."""
    params.setdefault("range_limits", (RANGE_FLOOR, math.inf))
    # the diagnosis' own setting (its alpha and beta constants from the log; the live filter's
    # random walks take up part of what this covers), kept when the live default went to 0.002
    params.setdefault("G_acc", DIAGNOSIS_G_ACC)
    params.setdefault("sigma_tof0", TOF_HELD)
    m = quad_thrust_model(G_alpha=0.0, G_beta=0.0, G_bar=0.0, G_tof=0.0, drag=drag, **params)
    meas = dict(m.measurements)
    rng = meas["range"]

    def range_airborne(mm, ctx, extract=rng.extract):
        # landed (rotors not carrying): a sonar reads its floor or its no-echo maximum
        if landed(ctx):
            return None
        z = extract(mm, ctx)
        on_the_ground = ctx.z <= CONTACT_H  # the estimate's height (the estimator sets it)
        if z is not None and on_the_ground and z[0] > LIFTOFF_REACH:
            # a tuple, replaced: a checkpoint's shallow copy of the context must not share it
            ctx.range_spurious = ctx.range_spurious + (mm.t,)
            return None
        # a reading at all (on the ground the sensor reads below its floor, and none is used)
        return note_range(z, mm.t, ctx)

    meas["range"] = replace(rng, extract=range_airborne)

    B = np.hstack([m.B, np.zeros((m.n, 6))])
    B[m.index("vz"), -1] = 1.0  # a_V: thrust_voltage's term (0 in the base model)
    m = replace(m, B=B, inputs=list(m.inputs) + ["V", "h", "a_T", "V_ref", "n_hat", "a_V"], measurements=meas)
    m = ground_contact(on_ground(m, height=False))
    options = {"voltage_ref": voltage_ref, "voltage_sag": voltage_sag, "voltage_oc": voltage_oc}
    return replace(m, options={k: v for k, v in options.items() if v})


def throttle_series(ms: Sequence[Measurement]) -> list[tuple[float, float]]:
    """(t, collective 0..1): the mean of the motor outputs (ACTUATOR), or THROTTLE in a log without
    them (one source, as :func:`groundstation.estimation.routing.collective` takes it)."""
    r = Readings.of(ms)
    t, _, v = r.columns(Kind.ACTUATOR)
    v = v[:, : motor_outputs_of(r)]
    ok = np.isfinite(v).any(axis=1)
    if ok.any():
        return list(zip(t[ok].tolist(), np.nanmean(v[ok], axis=1).tolist(), strict=True))
    t, _, v = r.columns(Kind.THROTTLE)
    return list(zip(t.tolist(), v[:, 0].tolist(), strict=True)) if v.shape[1] else []


def main_flight(
    ms: Sequence[Measurement], gap: float = 1.0, before: float = SETTLE_S + 3.0
) -> tuple[float, float] | None:
    """The longest stretch with the rotors carrying the vehicle (throttle at or above
    ground idle, no drop below it for more than ``gap`` s), from ``before`` s ahead
    of it to its end. Ground handling around it (motor tests, hops, a
    sonar reading its floor or nothing on the ground) says nothing about thrust.
    ``before`` is 3 s longer than the filter settles before the likelihood is scored
    (:data:`~groundstation.diagnosis.runs.run.SETTLE_S`), so the spin-up is scored: with 3 s, the first 2 s of
    underpowered.log's baro dip at spin-up (the data README's -2.7 m) were not."""
    th = throttle_series(ms)
    best, start, last_up = None, None, None
    for t, v in th:
        if v >= TAU_GROUND:
            if start is None or (last_up is not None and t - last_up > gap):
                start = t
            last_up = t
            if best is None or last_up - start > best[1] - best[0]:
                best = (start, last_up)
    if best is None:
        return None
    return best[0] - before, best[1]


def lift_off(
    ms: Sequence[Measurement],
    t_spin: float,
    limits: tuple[float, float] = (RANGE_FLOOR, math.inf),
    hold: float = LIFTOFF_HOLD,
) -> float:
    """When the vehicle left the ground: the first range reading within its ``limits`` (the
    vehicle file's ``range_limits``: a sonar's no-echo maximum is above them) from which the range
    keeps reading within them for ``hold`` s, after the spin-up at ``t_spin``; ``t_spin`` itself
    when that never happens (a log without a range sensor).

    On the ground a range sensor reads below its floor or nothing, so this is where the rotors
    first carry the vehicle. The throttle alone does not say it: ArduPilot's underpowered.log sits
    on the ground for 6 s at 0.62-0.72 (its hover throttle is 0.73), and a sonar there reads
    spurious echoes of 1.9-6.5 m for 0.9 s as the motors spin up."""
    start = None
    last = t_spin
    t, _, d = Readings.of(ms).columns(Kind.RANGE)
    if not d.shape[1]:
        return t_spin
    for tm, dm in zip(t.tolist(), d[:, 0].tolist(), strict=True):
        if tm < t_spin:
            continue
        up = limits[0] <= dm <= limits[1]
        if not up or tm - last > 1.0:  # a second without a reading breaks the hold
            start = None
        if up:
            start = tm if start is None else start
            if tm - start >= hold:
                return start
        last = tm
    return t_spin


def hover_prior(prep, range_limits: tuple[float, float] = (RANGE_FLOOR, math.inf), *, curve: bool = True) -> dict:
    """The a priori thrust coefficients (document sec. 1: "estimated offline"), from the log
    itself: alpha0 = g / tau_hover, the median throttle over the first 10 s in the air (from
    :func:`lift_off`), and beta fixed near 0 (the document's own way out of alpha and
    beta's near-collinearity). Without it a slow thrust loss is fitted as "thrust does
    not depend on the throttle" (alpha -> 0, beta -> g). Read from the spin-up instead (the
    first throttle at ground idle), underpowered.log's 6 s on the ground at 0.62-0.72 made its
    hover throttle 0.65 and alpha0 12 % high: the model lifted off at spin-up and flew 2 m up
    while the vehicle sat on the ground.

    With ``curve`` and a log with an accelerometer, attitude and range sensor, the thrust curve read
    from the accelerometer is under ``"curve"`` (:mod:`.airframe`; beta held at 0 made alpha 10 % low on
    the simulated quadcopter): the caller puts its :meth:`~.airframe.ThrustCurve.prior` over these when
    no vehicle file gives the airframe, and reads it beside the file's otherwise."""
    th = throttle_series(prep.measurements)
    flying = [(t, v) for t, v in th if v >= TAU_GROUND]
    if len(flying) < 10:
        return {}
    t0 = lift_off(prep.measurements, flying[0][0], range_limits)
    tau_h = float(np.median([v for t, v in flying if t0 <= t <= t0 + 10.0]))
    alpha0 = G / tau_h
    prior: dict[str, Any] = {"alpha0": alpha0, "beta0": 0.0, "sigma_alpha0": 0.2 * alpha0, "sigma_beta0": 0.05}
    t, _, v = Readings.of(prep.measurements).columns(Kind.BATTERY_VOLTAGE)
    volts = v[(t >= t0) & (t <= t0 + 10.0), 0].tolist() if v.shape[1] else []
    volts = [v for v in volts if math.isfinite(v) and v > 0]
    if volts:
        # thrust_voltage's V_ref: the voltage alpha0 was read at. Taken at the first sample with the
        # rotors carrying the vehicle (a lighter load, a higher voltage), it put a constant
        # (V_ref' / V_ref)^n between alpha0 and the thrust at hover, which n then absorbed
        prior["voltage_ref"] = float(np.median(volts))
    sag = load_line(prep.measurements, th)
    if sag is not None:
        prior["voltage_sag"] = sag[0]  # the voltage between the battery's readings (battery.py)
    k = sag[0] if sag is not None else 0.0
    sigma = reading_sigma(prep.measurements, th, k)
    oc = OpenCircuitVoltage.from_log(prep.measurements, th, k, sigma) if sigma else None
    if oc is not None:
        prior["voltage_oc"] = oc  # the readings' open-circuit voltage, smoothed (battery.py)
    if curve:
        # the voltage the thrust model's input will see (battery.loaded_voltage), at each throttle
        def volt(t, tau, oc=oc):
            return loaded_voltage(oc.at(t), tau, sag=prior.get("voltage_sag"), oc=oc, t=t)

        fit = thrust_curve(
            prep.measurements,
            th,
            flying[0][0],
            t0,
            flying[-1][0],
            voltage=volt,
            voltage_ref=prior.get("voltage_ref"),
            range_limits=range_limits,
        )
        if fit is not None:
            prior["curve"] = fit
    return prior


@dataclass(eq=False, kw_only=True)
class ThrustContext(Context):
    """The thrust diagnosis model's context: the battery's load line and the states its input reads."""

    voltage_ref: float | None = None  #: the voltage alpha's prior was read at [V]
    voltage_sag: float | None = None  #: the load line's k: V = V_oc - k tau^2 (battery.py)
    voltage_oc: OpenCircuitVoltage | None = None  #: the readings' open-circuit voltage, smoothed
    voltage_tau2: float | None = None  #: tau^2 at the latest battery reading
    i_n_voltage: int | None = None  #: thrust_voltage's state index, when the model has it
    i_R2_rotor: int | None = None  #: thrust_ground_effect's state index, likewise
    left_ground_at: float | None = None  #: when the model last left the ground
    range_spurious: tuple[float, ...] = ()  #: the times of range echoes skipped on the ground


def _input(m: Measurement, ctx: Context) -> np.ndarray:
    assert isinstance(ctx, ThrustContext)  # thrust_estimator gives its filter one
    tau = ctx.tau
    volt = ctx.voltage if ctx.voltage is not None else 0.0  # 0 until a reading: u must stay finite (B u)
    if not math.isfinite(volt):
        volt = 0.0
    # between the battery's readings
    volt = loaded_voltage(volt, tau, sag=ctx.voltage_sag, oc=ctx.voltage_oc, tau2=ctx.voltage_tau2, t=m.t)
    x = ctx.x
    h = float(x[0]) if x is not None else 0.0
    c = ctx.down_row[2]
    a_t = float(x[2]) * tau + float(x[3]) if x is not None else G
    # the thrust the model flies with: with thrust_voltage, times (V / V_ref)^n at the estimate. Judged
    # without it, a throttle blip after a touchdown "lifted" a vehicle whose modelled thrust was below
    # its weight, and the model fell through the ground (1.2 m in 1.5 s, a simulated n = 1.5 flight)
    v_ref = ctx.voltage_ref if ctx.voltage_ref is not None else 0.0
    n_hat, a_v = _voltage_terms(x, ctx.i_n_voltage, volt, v_ref, a_t * c)
    r_n = (volt / v_ref) ** n_hat if n_hat and volt > 0.0 and v_ref > 0.0 else 1.0
    lifts = a_t * c * r_n > G  # or a range reading above the ground (thrust_model's range_airborne)
    # on the ground (models.contact): reached at CONTACT_H with the thrust not lifting the vehicle, left
    # when it does or a range reading sees the vehicle up
    contact = in_contact(ctx, m.t, h, lifts, known=x is not None)
    if contact or landed(ctx):
        # on the ground: its reaction cancels thrust and weight (eq. 1-2 do not say so); driven
        # by them, the model would fly through the ground, and the constant thrust coefficients
        # would be fitted to that (a clean simulated quad's 0.8 m/s touchdown with the throttle
        # at 0.36: alpha, beta = 13.7, 3.0 without the ground, 22.02, -1.20 with it, beta left
        # free; the simulator's are 22, -1.2)
        ctx.left_ground_at = None
        return np.array([0.0, 0.0, 0.0, volt, h, 0.0, v_ref, 0.0, 0.0])
    if ctx.voltage_ref is None and volt > 0:
        ctx.voltage_ref = volt  # without a prior's: when the rotors first carry the vehicle
    if ctx.left_ground_at is None:
        ctx.left_ground_at = m.t
    if m.t - ctx.left_ground_at < GE_SETTLE:
        h = 0.0  # thrust_ground_effect's term not used yet (GE_SETTLE)
    elif h >= GE_MIN_H and ctx.i_R2_rotor is not None and x is not None:
        q = max(float(x[ctx.i_R2_rotor]), 0.0)
        h = max(h, math.sqrt(q))  # (R/4h)^2 holds for h >= R
        # 1 / (1 - s) - 1, s = R^2 / 16 h^2, linearised about R^2's estimate (thrust_ground_effect): the
        # coupling's slope through an effective height, the rest through a_V
        s = min(q / (16.0 * h * h), GE_S_MAX)
        h *= 1.0 - s
        a_v -= a_t * c * s * s / (1.0 - s) ** 2
    if v_ref <= 0.0 and ctx.voltage_ref is not None:
        v_ref = ctx.voltage_ref  # set just above: r = 1, so n_hat's terms are 0 this step
    return np.array([tau * c, c, G, volt, h, a_t, v_ref, n_hat, a_v])


#: s = (R/4h)^2 at most this in the linearisation (h >= R gives 1/16; the cap keeps a wild first estimate of
#: R^2 from 1 / (1 - s)'s pole)
GE_S_MAX = 0.25


#: thrust_voltage's exponent as the linearisation point is held to this range (a first update far off
#: must not put r^n out of reach of the next)
N_HAT_RANGE = (-4.0, 6.0)


def _voltage_terms(x, i_n, volt: float, v_ref: float, a_tc: float) -> tuple[float, float]:
    """thrust_voltage about the estimate n^ (an EKF's step, :func:`thrust_voltage`): n^ and
    ``a_V = a_T c (r^n^ - 1 - n^ r^n^ ln r)``, r = V / V_ref, the thrust change the term
    n a_T c r^n^ ln r of the coupling does not give at n = n^. 0, 0 without the state."""
    if i_n is None or x is None or volt <= 0.0 or v_ref <= 0.0:
        return 0.0, 0.0
    n = min(max(float(x[i_n]), N_HAT_RANGE[0]), N_HAT_RANGE[1])
    r = volt / v_ref
    rn = r**n
    return n, a_tc * (rn - 1.0 - n * rn * math.log(r))


def _battery_voltage(m: Measurement, ctx: Context) -> None:
    """The throttle at the battery's reading: without the log's smoothed open-circuit voltage
    (``voltage_oc``, from :func:`hover_prior`) the load line carries the reading from it to the
    throttle of each step (battery.loaded_voltage)."""
    assert isinstance(ctx, ThrustContext)
    tau = throttle_at_reading(ctx, m.t)
    if tau is not None and math.isfinite(tau):
        ctx.voltage_tau2 = tau * tau


def thrust_estimator(model: LinearModel) -> KalmanEstimator:
    est = KalmanEstimator(
        model,
        inputs={Kind.ACTUATOR: _input, Kind.THROTTLE: _input, Kind.ATTITUDE: _input},
        context={**THRUST_CONTEXT, Kind.ACCEL: read_specific_force, Kind.BATTERY_VOLTAGE: _battery_voltage},
    )
    opts = model.options
    est.filter.ctx = ThrustContext(
        voltage_ref=opts.get("voltage_ref") or None,
        voltage_sag=opts.get("voltage_sag") or None,
        voltage_oc=opts.get("voltage_oc") or None,
        i_n_voltage=model.index("n_voltage") if "n_voltage" in model.states else None,
        i_R2_rotor=model.index("R2_rotor") if "R2_rotor" in model.states else None,
    )
    return est
