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

Candidates (names as in the issue's catalogue):

* ``thrust_voltage``: no voltage compensation in the ESCs, ``a_T = a_T0 (V / V_ref)^n``
  (V_ref: the voltage alpha0 was read at), one state n, linearised about its estimate
  as an EKF does (:func:`thrust_voltage`); V between the battery's readings follows
  the throttle (battery.py);
* ``thrust_ground_effect``: Cheeseman-Bennett, ``a_T / (1 - (R / 4h)^2)``, one state q = R^2
  (h >= 0.1 m, rotors carrying), linearised about its estimate (:func:`thrust_ground_effect`);
* ``actuator_lag``: the thrust follows the throttle through a first-order lag,
  profiled over its time constant like a sensor delay;
* the barometer's effects of the altitude catalogue, which act on the same
  baro measurement, and the range's slant under tilt;
* ``sensor_delay`` of the range, profiled over 0-0.5 s: a late range reading, which the
  baro does not share (a lagged thrust reaches both).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from groundstation.core.measurement import Kind, Measurement
from groundstation.core.units import G
from groundstation.diagnosis.catalogue.airframe import thrust_curve
from groundstation.diagnosis.catalogue.altitude import (
    UNOBSERVABLE,
    Candidate,
    altitude_catalogue,
    sensor_delay,
    state_param,
)
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
    motor_outputs,
    read_angular_rate,
    read_attitude,
    read_quaternion,
    read_specific_force,
    read_throttle,
    read_vehicle_status,
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


def _motor_outputs_of(ms: Sequence[Measurement]) -> int:
    for m in ms:
        if m.kind is Kind.VEHICLE_STATUS:
            ctx = Context()
            read_vehicle_status(m, ctx)
            return motor_outputs(ctx)
    return 4


def throttle_series(ms: Sequence[Measurement]) -> list[tuple[float, float]]:
    """(t, collective 0..1): the mean of the motor outputs (ACTUATOR), or THROTTLE in a log without
    them (one source, as :func:`groundstation.estimation.routing.collective` takes it)."""
    n = _motor_outputs_of(ms)
    outputs = [
        (m.t, float(np.nanmean(m.value[:n]))) for m in ms if m.kind is Kind.ACTUATOR and np.isfinite(m.value[:n]).any()
    ]
    return outputs or [(m.t, float(m.value[0])) for m in ms if m.kind is Kind.THROTTLE and len(m.value)]


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
    for m in ms:
        if m.kind is not Kind.RANGE or m.t < t_spin or not len(m.value):
            continue
        up = limits[0] <= float(m.value[0]) <= limits[1]
        if not up or m.t - last > 1.0:  # a second without a reading breaks the hold
            start = None
        if up:
            start = m.t if start is None else start
            if m.t - start >= hold:
                return start
        last = m.t
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
    volts = [
        float(m.value[0])
        for m in prep.measurements
        if m.kind is Kind.BATTERY_VOLTAGE and t0 <= m.t <= t0 + 10.0 and len(m.value)
    ]
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
        context={
            Kind.ACCEL: read_specific_force,
            Kind.ATTITUDE: read_attitude,
            Kind.ATTITUDE_QUATERNION: read_quaternion,
            Kind.ANGULAR_RATE: read_angular_rate,
            Kind.ACTUATOR: read_throttle,
            Kind.THROTTLE: read_throttle,
            Kind.VEHICLE_STATUS: read_vehicle_status,
            Kind.BATTERY_VOLTAGE: _battery_voltage,
        },
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


# -- the thrust-side candidates ------------------------------------------------------------------
def thrust_voltage(model: LinearModel) -> LinearModel:
    """``vz_dot += a_T c (r^n - 1)``, ``r = V / V_ref``, linearised about the estimate n^:
    ``a_T c (r^n^ - 1 - n^ r^n^ ln r)`` (the input a_V, :func:`_voltage_terms`) plus
    ``n a_T c r^n^ ln r`` (the coupling). The first-order expansion in (V - V_ref) / V_ref
    used before read n = 2 as 1.77-1.87 on simulated thrust test flights: the pack sags by
    up to 20 % at the throttle steps, where r^2 and 1 + 2 (r - 1) differ by 4 % of the thrust."""
    iv = model.index("vz")

    def coupling(u):
        # a pure function of u: the filter probes A with test inputs
        c = np.zeros((model.n, 1))
        if u is None or len(u) < 9 or u[1] == 0.0 or u[3] <= 0.0 or u[6] <= 0.0:
            return c
        r = u[3] / u[6]
        c[iv, 0] = u[5] * u[1] * r ** u[7] * math.log(r)
        return c

    return model.augmented(states=["n_voltage"], coupling=coupling, Qc_extra=[0.0], x0_extra=[0.0], P0_extra=[3.0**2])


def thrust_ground_effect(model: LinearModel) -> LinearModel:
    """``vz_dot += a_T c (1 / (1 - s) - 1)``, ``s = (R / 4h)^2`` (Cheeseman and Bennett), the state
    R^2, linearised about its estimate as an EKF does: the coupling's column is the slope
    ``a_T c / (16 h^2 (1 - s)^2)`` (:func:`_input` passes the height as ``h (1 - s)``) and the rest,
    ``-a_T c s^2 / (1 - s)^2``, goes in through a_V. The first order, ``a_T c s``, is 0.4 % of the
    thrust short at h = R; with the throttle between its records, the smoothed voltage and a tight
    G_acc (0.00005) it read R = 0.25 m 3-7 % high with the range's Ljung-Box p at 0.000-0.004 on all
    three flights. The formula holds for h >= R (the simulator's
    too); below, the height it is given is R's estimate, so the term stays at its h = R value. With
    1/h^2 carried on below R, a quadcopter hovering at 0.17 m with R = 0.25 m had its ground effect
    predicted at 14 % of the thrust for 6.7 %, and R read 10 % low (0.226 m) with the range's NIS at
    1.15."""
    iv = model.index("vz")

    def coupling(u):
        c = np.zeros((model.n, 1))
        if u is None or len(u) < 9 or u[1] == 0.0 or u[4] < GE_MIN_H:
            return c
        c[iv, 0] = u[5] * u[1] / (16.0 * u[4] ** 2)
        return c

    return model.augmented(states=["R2_rotor"], coupling=coupling, Qc_extra=[0.0], x0_extra=[0.0], P0_extra=[0.1**2])


def _near_the_ground(run, t_from: float) -> int:
    """thrust_ground_effect's support: the scored baro and range updates below two fitted rotor
    radii (there the first-order term adds >= 1.6 % of thrust; above, it fades as 1/h^2)."""
    r = math.sqrt(max(run.final("R2_rotor")[0], 0.0))
    iz = run.model.index("z")
    n = 0
    for name in ("baro", "range"):
        tr = run.sensors.get(name)
        if tr is not None and len(tr.t):
            z = np.interp(tr.t, run.t, run.x[:, iz])
            n += int(((tr.t >= t_from) & (z >= GE_MIN_H) & (z < 2.0 * r)).sum())
    return n


def _rotor_radius(run) -> dict:
    q, s = run.final("R2_rotor")
    r = math.sqrt(max(q, 0.0))
    return {"R": r, "sigma_R": s / (2 * r) if r > 0 else math.inf}


def _rotor_radius_limit(run, z: float) -> dict:
    """The state is R^2: its size z sigma_R2 is where the gain is, then R = sqrt of it (sigma_R, a
    linearisation at the estimate, is no guide near R = 0)."""
    return {"R": math.sqrt(z * run.final("R2_rotor")[1])}


def lag_throttle(ms: Sequence[Measurement], tc: float) -> Sequence[Measurement]:
    """The throttle as the rotors follow it through a first-order lag of time constant tc, for
    each stream of outputs (a throttle and the PWM outputs each their own: one state shared between
    them was reset at every switch) and each output within it (unused outputs are NaN and stay so:
    one NaN once reset the whole filter at every sample, and no lag was ever found).

    A logged output x_k is what was written at t_k and held to the next one, as the model holds
    its inputs (zero-order hold). Over [t_k, t_k+1) the lag's state y moves from y_k towards x_k,

        y(t_k + s) = x_k + (y_k - x_k) e^(-s/tc),

    and the record put in its place is that motion's mean over the interval,

        y_bar_k = x_k + (y_k - x_k) (tc/D) (1 - e^(-D/tc)),   D = t_k+1 - t_k,

    so that the held input gives the velocity change the lagged thrust gives (exact for a held
    input). tc -> 0 gives x_k back: the base model. (Updating the lag's state with x_k as if written
    at t_k-1, and holding y_k, reads a step written at t_k 20 ms early: a 0.05 s lag read
    0.042-0.056 s as the simulator's outputs changed timing.)"""
    if tc <= 0:
        return ms
    out: list[Measurement] = []
    state: dict[Kind, tuple[np.ndarray, np.ndarray, float]] = {}
    nxt = _next_times(ms)
    for i, m in enumerate(ms):
        if m.kind in (Kind.THROTTLE, Kind.ACTUATOR):
            x = np.asarray(m.value, dtype=float)
            last = state.get(m.kind)
            if last is None or len(last[0]) != len(x):
                y = x.copy()
            else:
                y, x_last, t_last = last
                a = 1.0 - math.exp(-max(m.t - t_last, 0.0) / tc)
                y = np.where(np.isfinite(y) & np.isfinite(x_last), y + (x_last - y) * a, x)
                y = np.where(np.isfinite(x), y, x)
            state[m.kind] = (y, x, m.t)
            d = nxt[i] - m.t
            w = tc / d * (1.0 - math.exp(-d / tc)) if d > 0 else 1.0
            m = m._replace(value=x + (y - x) * w)
        out.append(m)
    return out


def _next_times(ms: Sequence[Measurement]) -> list[float]:
    """For each record, the time of the next of its kind (its own time for the last)."""
    out = [0.0] * len(ms)
    nxt: dict = {}
    for i in range(len(ms) - 1, -1, -1):
        m = ms[i]
        out[i] = nxt.get(m.kind, m.t)
        nxt[m.kind] = m.t
    return out


#: s: the range delays the thrust model's profile starts from (its sonar's can be tenths of a second)
RANGE_DELAYS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)


def thrust_catalogue(kinds: set) -> list[Candidate]:
    has_throttle = bool(kinds & {Kind.THROTTLE, Kind.ACTUATOR})
    cands = []
    if has_throttle:
        if Kind.BATTERY_VOLTAGE in kinds:
            cands.append(
                Candidate(
                    "thrust_voltage", 1, {Kind.BATTERY_VOLTAGE}, None, thrust_voltage, state_param("n", "n_voltage")
                )
            )
        cands.append(
            Candidate(
                "thrust_ground_effect",
                1,
                set(),
                None,
                thrust_ground_effect,
                _rotor_radius,
                support=_near_the_ground,
                limit=_rotor_radius_limit,
            )
        )
        cands.append(
            Candidate(
                "actuator_lag",
                1,
                set(),
                "throttle",
                None,
                None,
                delays=(0.0, 0.03, 0.06, 0.12, 0.24, 0.4),
                reshape=lag_throttle,
            )
        )
    # the barometer's own effects act on the same measurement in this model, and so does the ToF's slant
    # under tilt (a simulated thrust test flight, nothing declared: the slant went unnamed, 3.8 cm height
    # error)
    cands += [c for c in altitude_catalogue(kinds) if c.sensor == "baro" or c.name == "range_tilt"]
    # the range's own delay, on a grid to half a second: a lagged thrust reaches the baro too, a late
    # range reading does not. On underpowered.log, with four effects in, the range innovations still
    # followed the vertical speed 0.3 s earlier (49 % of their variance), and a delayed range scored
    # Delta BIC -970 against the lag's -898 (ArduCopter 3.0 passes its sonar through a 5-sample mode filter)
    cands.append(sensor_delay("range", RANGE_DELAYS, {Kind.RANGE}))
    return [c for c in cands if c.needs <= kinds]


UNOBSERVABLE_THRUST = {
    "accel_bias": "the thrust model does not use the accelerometer",
    "accel_scale": "the thrust model does not use the accelerometer",
    "gyro_bias": "acts on the attitude, which this model takes as given: run the attitude model",
    "imu_misalignment": "acts on the IMU, which this model does not use: run the attitude model",
    "range_offset": UNOBSERVABLE["altitude"]["range_offset"] + " (this model holds its ToF offset state d_tof at 0)",
}
