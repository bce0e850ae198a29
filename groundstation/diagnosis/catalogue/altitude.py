"""The catalogue: each candidate effect as a change to the model, named as the simulator's effects are.

A candidate turns the model into an augmented one, the way a person would fix
it: an extra state for an unknown constant or drift (a random constant, so the
filter's estimate is the data's best value and its sigma the evidence), a
regressor on a measurement (its coefficient a state), a changed measurement
function (slant range), or a delay (the sensor's measurements applied at
``t - d``, ``d`` on a grid). Its parameters are read from the augmented run.

Which effects a model can show: with the accelerometer as
the altitude filter's *input*, thrust-side effects cannot appear in it at all
(``thrust_voltage``, ``thrust_ground_effect``, ``actuator_lag``: the
quadcopter thrust-model filter is where they show), and a constant offset on
the range sensor, the only precise absolute height, cannot be told from the
height itself (:data:`UNOBSERVABLE`). They are reported as such, not guessed.

Sign conventions follow the simulator's effects (``sim_bridge/effects.py``),
so a parameter found here compares directly with the one injected there.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Iterable
from dataclasses import replace
from functools import partial

import numpy as np

from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings
from groundstation.diagnosis.catalogue.candidate import Candidate, state_param, with_regressor
from groundstation.diagnosis.runs.run import CONTEXT_KINDS, Run
from groundstation.diagnosis.runs.signals import THROTTLE_TC
from groundstation.diagnosis.runs.signature import Column
from groundstation.estimation.context import Context
from groundstation.estimation.models.base import LinearModel, pad_row, slant

# -- what the diagnosis adds to the altitude filter before any candidate -----------------------------
#: the baro's zero is the mean of its first 50 readings against the estimate (models.base.
#: relative_to_estimate): 4 Pa of noise per reading leave it 5 cm off (1 sigma), more when the
#: estimate itself moves on the ground with no range reading yet. Frozen, that error is a constant
#: baro offset over thousands of updates, which any candidate with a constant part (a thrust-linked
#: term at hover throttle, a drift line) is then credited with: a clean simulated coax "had"
#: baro_thrust k = 0.2 at Delta BIC = -247 from a 10 cm zero error.
BARO_ZERO_SIGMA = 0.15


#: [m^2/s] the baro error's random walk next to a GPS: none, the zero is a constant. Outdoors a baro
#: wanders with the weather and its own temperature (a hectopascal an hour is 8 m), and with a walk
#: the filter would split a disagreement with the GPS's slow error (models.altitude.with_gps_error)
#: by their rates; but no sensor tells which of the two moved, and the split trades one flight for
#: another. Chosen by the likelihood after the effects (0 to 1e-2), a walk made the height's sigma
#: honest on the foreign flight baro_thermal_s2 (NEES 5.5 -> 1.3) and moved its height off (11.0 ->
#: 12.5 cm), and clean_gps_s2's (3.7 -> 5.7 cm) and double_s1's (4.8 -> 6.3 cm) with it
BARO_WANDER = 0.0


def baro_zero(model: LinearModel, wander: float = 0.0) -> LinearModel:
    """The baro's zero as a random constant, y_baro = z + b0 (prior: the calibration's own error),
    or with ``wander`` [m^2/s] a random walk.

    Only where another absolute height (the range sensor, a GPS) can show it: from the barometer
    alone b0 and z cannot be told apart, and the calibration stays what it was."""
    return with_regressor(model, "baro", "baro_zero", lambda ctx: 1.0, BARO_ZERO_SIGMA**2, wander)


# -- the altitude filter's candidates ----------------------------------------------------------------
def baro_bias_drift(model: LinearModel) -> LinearModel:
    """Baro error b with a constant drift rate d: b_dot = d, y_baro = z + b.

    Deterministic (no random walk on b): a walk would absorb any slow error, and a
    temperature that rises ever more slowly in flight (baro_thermal) would be taken
    for a drift; a straight line against the temperature's own curve tells them apart.
    """
    n = model.n
    meas = {}
    for key, mm in model.measurements.items():
        if mm.name == "baro":
            old = mm.row

            def row(ctx, old=old):
                r = pad_row(old(ctx), 2)
                r[0, n] = 1.0
                return r

            meas[key] = replace(mm, row=row)
    A_extra = np.array([[0.0, 1.0], [0.0, 0.0]])
    return model.augmented(
        states=["b_baro", "baro_rate"],
        A_extra=lambda u: A_extra,
        Qc_extra=[0.0, 0.0],
        x0_extra=[0.0, 0.0],
        P0_extra=list(DRIFT_PRIORS),
        measurements=meas,
    )


#: the drift's priors: its starting error [m^2] and its rate [(m/s)^2], as :func:`baro_bias_drift` sets them
DRIFT_PRIORS = (1e-4, 0.2**2)


def baro_bias_drift_columns(model: LinearModel) -> list[Column]:
    """:func:`baro_bias_drift`'s b and rate as the baro's regressors: b(t) = b0 + rate (t - t_start)."""
    return [
        Column("b_baro", DRIFT_PRIORS[0], "baro", of_time=lambda t, t0: np.ones_like(t)),
        Column("baro_rate", DRIFT_PRIORS[1], "baro", of_time=lambda t, t0: t - t0),
    ]


def range_tilt(model: LinearModel) -> LinearModel:
    """Slant range: y = z / (cos(roll) cos(pitch)) (the sensor looks along body z)."""
    meas = dict(model.measurements)
    mm = meas["range"]
    old = mm.row

    def row(ctx):
        r = np.array(old(ctx), dtype=float)
        r[0, 0] = slant(ctx)
        return r

    meas["range"] = replace(mm, row=row)
    return replace(model, measurements=meas)


def range_tilt_screen(model: LinearModel, run: Run | None) -> list[list[Column]]:
    """The slant as a regressor on the range of free size: (1 / (cos(roll) cos(pitch)) - 1) z, z the
    estimate before the update; the slant itself is this at size 1 (probed: it reads the tilt)."""
    if run is not None:
        return []
    iz = model.index("z")
    return [[Column("slant", 1.0, "range", lambda ctx, x: float(x[iz]) * (slant(ctx) - 1.0), exact=False)]]


def delay_screen(sensor: str, delays: tuple[float, ...]) -> Callable[[LinearModel, Run | None], list[list[Column]]]:
    """A delay d of the sensor's readings, y(t) = z(t - d): to first order -d vz(t) (its size the delay,
    probed: it reads the estimate's vz), and at each value of the grid the base run's own height
    then against now, z(t - d) - z(t), of free size (a late, slow baro's 0.25 s is far from first
    order: a flight with it read Delta BIC -2 to first order, and -76 through its own runs). Each
    counts only at sizes a delay can have, 0 and up: fitted freely, the lagged height took negative
    sizes (the reading *ahead* of the estimate: the filter's own lag behind its sensor) and on a
    10-minute flight without a delay gained 1037, which made four runs of the delay's grid."""

    def columns(model: LinearModel, run: Run | None) -> list[list[Column]]:
        iz, iv = model.index("z"), model.index("vz")
        if run is None:
            return [[Column("delay", 1.0, sensor, lambda ctx, x: -float(x[iv]), exact=False, at_least=0.0)]]
        t_run, z_run = run.t, run.x[:, iz]
        out = []
        for d in delays:
            if d > 0:

                def lagged(t: np.ndarray, t0: np.ndarray, d: float = d) -> np.ndarray:
                    return np.interp(t - d, t_run, z_run) - np.interp(t, t_run, z_run)

                out.append([Column(f"lag {d:g} s", 1.0, sensor, of_time=lagged, exact=False, at_least=0.0)])
        return out

    return columns


def gps_delays(kinds: set) -> list[Candidate]:
    """A late GPS: its fix (the height and, where the log has it, the receiver's vertical velocity with
    it, as one fix is late), and where it has that velocity, the height alone (a receiver that filters
    its height apart from its Doppler velocity): two forms of one delay, the likelihood taking one."""
    fix = sensor_delay("gps", GPS_DELAYS, {Kind.GPS})
    if Kind.GPS_VD not in kinds:
        return [fix]
    height = replace(fix, form="height", shifts=frozenset({Kind.GPS}))
    return [replace(fix, form="fix"), height]


def sensor_delay(sensor: str, delays: tuple[float, ...], needs: set | None = None) -> Candidate:
    """A late ``sensor``: its delay profiled on the grid ``delays``, screened first by its stand-ins."""
    return Candidate(
        "sensor_delay", 1, needs or set(), sensor, None, None, delays=delays, screen=delay_screen(sensor, delays)
    )


G = 9.80665


#: the accelerometer scale's prior variance
SCALE_PRIOR = 0.05**2


def accel_scale(model: LinearModel) -> LinearModel:
    """f_meas = (1 + s) f: along the vertical gamma_meas = a + s (a + g), so
    z_dd = gamma_meas - b - s (gamma_meas + g) to first order in s. The ``s g`` part
    looks like a bias; only the variation of gamma separates the two."""
    iv = model.index("vz")

    def coupling(u):
        c = np.zeros((model.n, 1))
        c[iv, 0] = -(float(u[0]) + G) if u is not None else -G
        return c

    return model.augmented(
        states=["accel_scale"], coupling=coupling, Qc_extra=[0.0], x0_extra=[0.0], P0_extra=[SCALE_PRIOR]
    )


def accel_scale_columns(model: LinearModel) -> list[Column]:
    """:func:`accel_scale`'s c on the vertical acceleration input: -c (gamma_meas + g)."""
    i = model.inputs.index("gamma_z")
    return [Column("accel_scale", SCALE_PRIOR, input=i, factor=lambda u: -(float(u[i]) + G))]


def _scale_param(run) -> dict:
    """The state is c = s / (1 + s) (the exact coefficient of gamma_meas + g): s = c / (1 - c)."""
    c, sc = run.final("accel_scale")
    return {"s": c / (1.0 - c), "sigma_s": sc / (1.0 - c) ** 2}


#: the largest accelerometer scale error a vehicle's IMU can have: a MEMS accelerometer's sensitivity is
#: within +-3 % of nominal from the factory (InvenSense MPU-6000 and ICM-20689, Bosch BMI088 datasheets)
#: and moves +-0.02 %/K with temperature, under 2 % more over an airframe's range; an autopilot's
#: calibration takes what is left. Twice the sum: past it a fitted scale is the model lacking
#: something else that acts through the accelerometer (a bias that steps as the IMU warms took
#: s = 0.2-0.3 on another generator's flights)
SCALE_PLAUSIBLE = 0.1


def _plausible_scale(params: dict) -> str | None:
    s = params.get("s")
    if s is None or abs(s) <= SCALE_PLAUSIBLE:
        return None
    return (
        f"s = {s:.3g} ± {params.get('sigma_s', math.nan):.2g} is no accelerometer's scale error (a MEMS "
        f"sensitivity is within a few percent; this bar is {SCALE_PLAUSIBLE:.0%}): the model lacks something "
        "else that acts through the accelerometer, such as a bias that steps"
    )


def scale_accelerometer(ms: Iterable[Measurement], s: float) -> Readings:
    """The log as an accelerometer with scale error s would have recorded it (f_meas = (1 + s) f)."""
    return Readings.of(ms).with_values(Kind.ACCEL, lambda v: v * (1.0 + s))


#: s: the rotor wash's time constants :func:`baro_thrust` is tried at before its profile is refined;
#: a rotor's wake settles at the static port in a tenth of a second to a couple of seconds
WASH_TCS = (0.15, 0.5, 1.5)


def baro_thrust(model: LinearModel, tc: float = THROTTLE_TC, *, by_thrust: bool = False) -> LinearModel:
    """Rotor wash on the static port: y_baro = z + k LPF_tc(throttle), the throttle through a
    first-order low-pass of time constant ``tc`` [s] (the wake settling). The likelihood chooses
    ``tc`` (:data:`WASH_TCS`, then its profile refined): held at the simulator's 0.5 s, another
    generator's 0.25 s wash read k = 2.53 m for 2.02 and its fix left three times the error of the
    true model. The model asks the filter for that low-pass (``options["throttle_tcs"]``,
    :func:`~groundstation.diagnosis.runs.signals.add_signal_rules`).

    ``by_thrust``: the wash as the thrust over the weight makes it, y_baro = z + k_tw LPF_tc(T / (m g)),
    the thrust read as :mod:`groundstation.estimation.thrust_ratio` reads it. Momentum theory has the
    wash's dynamic pressure follow the disc loading, the thrust; where the command makes thrust
    through an offset or a curve (an idle spin, an ESC's) the two forms part, and the likelihood
    takes the one the baro shows."""

    out = with_regressor(model, "baro", "k_thrust", _wash(tc, by_thrust), WASH_PRIOR)
    out.options["throttle_tcs"] = (*out.options.get("throttle_tcs", ()), tc)
    return out


#: [m^2 per unit throttle squared] the wash coefficient's prior
WASH_PRIOR = 10.0**2


def _wash(tc: float, by_thrust: bool = False) -> Callable[[Context], float]:
    def regressor(ctx: Context) -> float:
        return (ctx.thrust_lps if by_thrust else ctx.throttle_lps).get(tc, 0.0)

    return regressor


def baro_thrust_columns(model: LinearModel, tc: float = THROTTLE_TC, *, by_thrust: bool = False) -> list[Column]:
    """:func:`baro_thrust`'s k at time constant ``tc`` as the baro's regressor."""
    wash = _wash(tc, by_thrust)
    return [Column("k_thrust", WASH_PRIOR, "baro", lambda ctx, x: wash(ctx), throttle_tc=tc)]


def thrust_form(fn: Callable) -> Callable:
    """``fn`` (a wash's augment or columns) in its thrust form."""
    return partial(fn, by_thrust=True)


def _by_thrust_param(run) -> dict:
    """k_tw [m per unit thrust over weight] and k, the same per unit of the command (the slope of the
    map times k_tw): what an autopilot's compensation, proportional to its throttle, takes."""
    k, sk = run.final("k_thrust")
    a = run.model.options["thrust_ratio"].a
    return {"k": k * a, "sigma_k": sk * a, "k_tw": k, "sigma_k_tw": sk}


def with_throttle_stand_in(cands: list[Candidate]) -> list[Candidate]:
    """The catalogue for a log whose throttle is a stand-in (motors running or not, from the IMU's vibration or the
    range: :func:`~groundstation.diagnosis.runs.run.motors_from_vibration`): a step with no time course of its own, so
    the rotor wash is held at its default time constant. Chosen by the likelihood against such a step, on a Crazyflie
    log the wash's 2 s took part of the baro's drift (0.064 m/s for the data's README's 0.09-0.13)."""
    return [replace(c, shapes=(), refine_shape=False) if c.refine_shape else c for c in cands]


def _temperature(ctx: Context) -> float:
    t0 = ctx.temperature_0
    return ctx.temperature - t0 if t0 is not None and ctx.temperature is not None else 0.0


#: [m] the heights over which the rotor wash's pressure field near the ground may fall off (its
#: e-folding height h0, about a rotor diameter): the candidate takes the one the log's likelihood picks
GROUND_HEIGHTS = (0.25, 0.5, 1.0)


def _ground(h0: float, by_thrust: bool = False) -> Callable[[Context], float]:
    def regressor(ctx: Context) -> float:
        # pressure field near the ground while the rotors run: exp(-h/h0), h from the estimate. A
        # logged throttle says when they run; the vibration (low-passed 0.3 s) only stands in for one,
        # as it lingers ~1 s after the motors stop (seed 1033: that second took A from -1.49 to -1.35).
        # ``by_thrust``: as strong as the thrust over the weight (the disc loading,
        # estimation.thrust_ratio), so weak at idle on the ground and full in the hover
        if by_thrust:
            strength = ctx.thrust_ratio or 0.0
        elif ctx.throttle is not None:
            strength = 1.0 if ctx.throttle > 0.05 else 0.0
        else:
            strength = 1.0 if ctx.vibration is not None and ctx.vibration > 0.05 else 0.0
        return strength * math.exp(-max(0.0, ctx.z) / h0) if strength else 0.0

    return regressor


#: [m^2] the ground effect's size, prior
GROUND_PRIOR = 3.0**2


def _ground_effect(model: LinearModel, h0: float = 0.5, *, by_thrust: bool = False) -> LinearModel:
    return with_regressor(model, "baro", "A_ground", _ground(h0, by_thrust), GROUND_PRIOR)


def _plausible_ground(params: dict) -> str | None:
    """A rotor's ground cushion raises the pressure at the static port, so the baro reads low near
    the ground (A < 0): what the autopilots' compensations take (ArduCopter's take-off and touch-down
    handling of "negative baro disturbances due to rotor wash ground interaction", EK3_GND_EFF_DZ,
    EKF2_GND_EFF_DZ), and a Crazyflie's real logs show (the data README: the baro dips at spin-up). A
    baro reading high there is something else that happens low down, at take-off and landing."""
    A = params.get("A")
    if A is None or A <= 0:
        return None
    return (
        f"A = {A:+.3g} m: the baro reads high near the ground, where a rotor's ground effect makes it read "
        "low; the model lacks something else that acts at take-off and landing"
    )


def _ground_effect_columns(model: LinearModel, h0: float = 0.5, *, by_thrust: bool = False) -> list[Column]:
    g = _ground(h0, by_thrust)
    return [Column("A_ground", GROUND_PRIOR, "baro", lambda ctx, x: g(ctx), exact=False)]  # reads the estimate


#: the temperature coefficient's prior [(m/K)^2]
THERMAL_PRIOR = 1.0


def _thermal(model: LinearModel) -> LinearModel:
    return with_regressor(model, "baro", "k_thermal", _temperature, THERMAL_PRIOR)


def _thermal_columns(model: LinearModel) -> list[Column]:
    return [Column("k_thermal", THERMAL_PRIOR, "baro", lambda ctx, x: _temperature(ctx))]


#: [s] the delays each sensor's profile is scanned over: past the most its autopilot can be told
#: (EKF2_RNG_DELAY, EKF2_BARO_DELAY and EKF2_GPS_DELAY 0-300 ms; EK3_HGT_DELAY and GPS_DELAY_MS
#: 0-250 ms) by at least two grid steps, so that a delay at that most is located, not left at the
#: range's edge (a GPS fix 0.4 s late on a grid ending at 0.4 s was not named in its own form, and
#: its height alone was, at 0.32 s, beside a rotor wash the rest of the lag drew). The scan stops
#: two values past a profile's fall (:func:`~groundstation.diagnosis.scoring.trials.scan_grid`):
#: a flight without a delay runs none of the longer ones
RANGE_DELAYS = (0.0, 0.04, 0.08, 0.12, 0.16, 0.2, 0.24, 0.28, 0.32, 0.36, 0.4)
BARO_DELAYS = (0.0, 0.06, 0.12, 0.18, 0.24, 0.3, 0.36, 0.42)
GPS_DELAYS = (0.0, 0.08, 0.16, 0.24, 0.32, 0.4, 0.48, 0.56, 0.64)


def gps_in_altitude(kinds: set) -> bool:
    """Whether the altitude model measures the GPS's height: only where no range sensor is (with
    one, the GPS's slow wander would only hide the baro's effects from the range)."""
    return Kind.GPS in kinds and Kind.RANGE not in kinds


def altitude_catalogue(kinds: set) -> list[Candidate]:
    """The candidates the altitude filter can show, given the log's kinds."""
    baro_kinds = {Kind.BARO_PRESSURE, Kind.BARO_ALTITUDE}
    has_baro = bool(kinds & baro_kinds)
    has_throttle = bool(kinds & {Kind.THROTTLE, Kind.ACTUATOR})
    cands = [
        Candidate(
            "range_tilt", 0, {Kind.RANGE, Kind.ATTITUDE}, "range", range_tilt, lambda run: {}, screen=range_tilt_screen
        ),
        Candidate(
            "accel_scale",
            1,
            {Kind.ACCEL},
            None,
            accel_scale,
            _scale_param,
            perturb=scale_accelerometer,
            columns=accel_scale_columns,
            plausible=_plausible_scale,
        ),
        sensor_delay("range", RANGE_DELAYS, {Kind.RANGE}),
    ]
    if gps_in_altitude(kinds):
        cands += gps_delays(kinds)
    if has_baro and kinds & BARO_REFERENCES:
        cands += [
            Candidate(
                "baro_bias_drift",
                2,
                set(),
                "baro",
                baro_bias_drift,
                state_param("rate", "baro_rate"),
                columns=baro_bias_drift_columns,
            ),
            sensor_delay("baro", BARO_DELAYS),
        ]
        if Kind.TEMPERATURE in kinds:
            cands.append(
                Candidate(
                    "baro_thermal",
                    1,
                    {Kind.TEMPERATURE},
                    "baro",
                    _thermal,
                    state_param("k", "k_thermal"),
                    columns=_thermal_columns,
                )
            )
        if has_throttle:
            cands += [
                Candidate(
                    "baro_thrust",
                    1,
                    set(),
                    "baro",
                    augment,
                    params,
                    shapes=WASH_TCS,
                    shape_name="tc",
                    refine_shape=True,
                    columns=columns,
                    form=form,
                    needs_option=option,
                    fitted=fitted,
                )
                for augment, params, columns, form, option, fitted in (
                    (baro_thrust, state_param("k", "k_thrust"), baro_thrust_columns, "throttle", None, ()),
                    (
                        thrust_form(baro_thrust),
                        _by_thrust_param,
                        thrust_form(baro_thrust_columns),
                        "thrust",
                        "thrust_ratio",
                        ("k_tw",),
                    ),
                )
            ]
        cands += [
            Candidate(
                "baro_ground_effect",
                1,
                set(),
                "baro",
                augment,
                state_param("A", "A_ground"),
                shapes=GROUND_HEIGHTS,
                shape_name="h0",
                columns=columns,
                form=form,
                needs_option=option,
                plausible=_plausible_ground,
            )
            for augment, columns, form, option in (
                (_ground_effect, _ground_effect_columns, "rotors running", None),
                (thrust_form(_ground_effect), thrust_form(_ground_effect_columns), "thrust", "thrust_ratio"),
            )
        ]
    return [c for c in cands if c.needs <= kinds]


#: the absolute heights a baro error can be seen against: without one, a baro error and the height
#: (or an accelerometer error integrated into it) cannot be told apart
BARO_REFERENCES = frozenset({Kind.RANGE, Kind.GPS})


def unobservable_in(kinds: set) -> dict[str, str]:
    """Effects this log's sensors cannot show, beyond the model's own list."""
    if kinds & {Kind.BARO_PRESSURE, Kind.BARO_ALTITUDE} and not kinds & BARO_REFERENCES:
        why = (
            "the baro is the log's only absolute height (no range sensor, no GPS): an error of the baro "
            "cannot be told from the height itself, nor from an accelerometer error integrated into it"
        )
        return {name: why for name in ("baro_bias_drift", "baro_thermal", "baro_thrust", "baro_ground_effect")}
    return {}


#: effects this model cannot show, and why (reported, not guessed)
UNOBSERVABLE = {
    "altitude": {
        "range_offset": "a constant offset on the range sensor, the only precise absolute height, cannot be told "
        "from the height itself (the baro is calibrated against the estimate); it shows only "
        "against an external reference (motion capture), where it is measured",
        "thrust_voltage": "thrust-side: with the accelerometer as input this model never predicts thrust; "
        "run the quad_thrust model",
        "thrust_ground_effect": "thrust-side: run the quad_thrust model",
        "actuator_lag": "thrust-side: run the quad_thrust model",
        "gyro_bias": "acts on the attitude, which this model takes as given: run the attitude model",
        "imu_misalignment": "acts on the attitude and on gravity's projection (a small tilt of the vertical "
        "looks like an accelerometer bias here): run the attitude model",
    },
}


def shift(ms: Iterable[Measurement], kinds: Collection[Kind], d: float) -> Readings:
    """The given kinds' measurements taken as of ``t - d`` (a sensor delay undone), re-sorted."""
    return Readings.of(ms).shifted(kinds, d).in_time_order(CONTEXT_KINDS)


#: effects of geometry and timing: the sweep's bar for their height error is 80 % down, not 50 %
GEOMETRIC = {"range_tilt", "sensor_delay", "imu_misalignment"}

SENSOR_KINDS = {"range": {Kind.RANGE}, "baro": {Kind.BARO_PRESSURE, Kind.BARO_ALTITUDE}, "gps": {Kind.GPS, Kind.GPS_VD}}


def delayed_kinds(cand: Candidate) -> Collection[Kind]:
    """The kinds a sensor's delay moves: its own (``Candidate.shifts``), else all of its sensor's."""
    return cand.shifts if cand.shifts is not None else SENSOR_KINDS.get(cand.sensor or "", set())
