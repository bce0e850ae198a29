"""The signals the catalogue's regressors and the discovery library read, kept current as a run goes:
the throttle and its low-passes at each rotor-wash time constant the model asks for, the
temperature, the battery, and the rotors' vibration from the accelerometer."""

from __future__ import annotations

import math

from groundstation.core.measurement import Kind, Measurement
from groundstation.estimation.context import Context
from groundstation.estimation.estimator import KalmanEstimator
from groundstation.estimation.routing import collective, motor_outputs, set_throttle

VIBRATION_TC = 0.3  # s: low-pass of the accelerometer's high-frequency energy (motors running)


THROTTLE_TC = 0.5  # s: the low-passed throttle recorded beside each innovation (a signal to regress on)


def add_signal_rules(est: KalmanEstimator, throttle_tcs: tuple[float, ...] = ()) -> None:
    """Context rules that keep the regression signals current (chained after the estimator's own);
    ``throttle_tcs``: rotor-wash low-passes to keep besides the model's own."""
    own = dict(est.context)
    #: the rotor wash's time constants the model's (and the probes') regressors read (catalogue.baro_thrust)
    tcs = tuple(dict.fromkeys((*est.model.options.get("throttle_tcs", ()), *throttle_tcs)))  # each once

    def chain(kind, fn):
        prev = own.get(kind)

        def rule(m: Measurement, ctx: Context, prev=prev) -> None:
            if prev is not None:
                prev(m, ctx)
            fn(m, ctx)

        est.context[kind] = rule

    def lowpass(ctx: Context, key: str, value: float, t: float, tc: float) -> None:
        """``ctx.<key>`` low-passed towards ``value`` with time constant ``tc``; ``ctx.<key>_t`` its time."""
        t_last = getattr(ctx, key + "_t")
        if t_last is None:
            setattr(ctx, key, value)
        elif t > t_last:
            old = getattr(ctx, key)
            setattr(ctx, key, old + (value - old) * (1.0 - math.exp(-(t - t_last) / tc)))
        setattr(ctx, key + "_t", t)

    #: the motors' thrust curve the log states (estimation.stated.MotorCurve): the rotor wash's
    #: low-passes follow the thrust the outputs make, not their mean
    curve = est.model.options.get("motor_curve")

    def throttle(m, ctx):
        tau = collective(m, ctx)
        if tau is None:
            return
        set_throttle(ctx, tau, m.t)
        lowpass(ctx, "throttle_lp", tau, m.t, THROTTLE_TC)
        if tcs:
            wash = tau
            if curve is not None and m.kind is Kind.ACTUATOR:
                outputs = [x for x in m.value[: motor_outputs(ctx)].tolist() if math.isfinite(x)]
                wash = curve.thrust(outputs) if outputs else tau
            t_last, lps = ctx.throttle_lps_t, ctx.throttle_lps
            for tc in tcs:
                old = lps.get(tc)
                if old is None or t_last is None:
                    lps[tc] = wash
                elif m.t > t_last:
                    lps[tc] = old + (wash - old) * (1.0 - math.exp(-(m.t - t_last) / tc))
            ctx.throttle_lps_t = m.t

    def temperature(m, ctx):
        if m.instance == 0:
            ctx.temperature = float(m.value[0])
            if ctx.temperature_0 is None:
                ctx.temperature_0 = ctx.temperature

    def voltage(m, ctx):
        ctx.voltage = float(m.value[0])

    def current(m, ctx):
        ctx.current = float(m.value[0])

    def vibration(m, ctx):
        # the accelerometer's deviation from its own low-passed value: rotors turning
        if m.instance != 0:
            return
        f = math.sqrt(sum(v * v for v in m.value.tolist()))
        lowpass(ctx, "f_lp", f, m.t, 1.0)
        lowpass(ctx, "vibration", (f - ctx.f_lp) ** 2, m.t, VIBRATION_TC)

    chain(Kind.THROTTLE, throttle)
    chain(Kind.ACTUATOR, throttle)
    chain(Kind.TEMPERATURE, temperature)
    chain(Kind.BATTERY_VOLTAGE, voltage)
    chain(Kind.BATTERY_CURRENT, current)
    chain(Kind.ACCEL, vibration)
