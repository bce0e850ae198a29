"""The signals the catalogue's regressors and the discovery library read, kept current as a run goes:
the throttle and its low-passes at each rotor-wash time constant the model asks for (and the thrust
over the weight the throttle makes, with its own, where the log shows how it makes it), the
temperature, the battery, the speed over the ground (the GNSS velocity's), and the rotors'
vibration from the accelerometer."""

from __future__ import annotations

import math

from groundstation.core.measurement import Kind, Measurement
from groundstation.core.units import G
from groundstation.estimation.context import Context
from groundstation.estimation.estimator import KalmanEstimator
from groundstation.estimation.routing import collective, motor_outputs, set_throttle
from groundstation.estimation.thrust_ratio import command

VIBRATION_TC = 0.3  # s: low-pass of the accelerometer's high-frequency energy (motors running)


THROTTLE_TC = 0.5  # s: the low-passed throttle recorded beside each innovation (a signal to regress on)
#: s: the thrust over the weight smoothed over this (the accelerometer's vibration out) for the
#: regressors that read it as it is (the ground effect's)
THRUST_SMOOTH_S = 0.1


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
    #: the map from that command to the thrust over the weight (estimation.thrust_ratio), where the
    #: log shows it: the wash's other form follows the thrust (``ctx.thrust_lps``)
    ratio = est.model.options.get("thrust_ratio")
    spread = ratio.spread if ratio is not None else 0.0  # the most above the map the air's thrust reads

    def throttle(m, ctx):
        tau = collective(m, ctx)
        if tau is None:
            return
        set_throttle(ctx, tau, m.t)
        lowpass(ctx, "throttle_lp", tau, m.t, THROTTLE_TC)
        wash = share = tau
        if curve is not None and m.kind is Kind.ACTUATOR and (tcs or ratio is not None):
            # the map's own command, below 0 under the spin minimum (idle, stopped); the wash's, clipped to
            # the working range
            c = command(m, curve, motor_outputs(ctx), clip=False)
            if c is not None:
                share, wash = c, min(max(c, 0.0), 1.0)
        if ratio is not None:
            ctx.thrust_map = ratio.of(share)
            if ctx.landed is not False:
                # on the ground the accelerometer reads the ground's support: the command says the thrust
                thrust(ctx, ctx.thrust_map, m.t)
        if tcs:
            t_last = ctx.throttle_lps_t
            _lowpasses(ctx.throttle_lps, wash, m.t - t_last if t_last is not None else None)
            ctx.throttle_lps_t = m.t

    def thrust(ctx: Context, tw: float, t: float) -> None:
        """The thrust over the weight from ``t`` on: its smoothed value and the wash's low-passes."""
        t_last = ctx.thrust_lps_t
        dt = t - t_last if t_last is not None else None
        if ctx.thrust_ratio is None or dt is None:
            ctx.thrust_ratio = tw
        elif dt > 0:
            ctx.thrust_ratio += (tw - ctx.thrust_ratio) * (1.0 - math.exp(-dt / THRUST_SMOOTH_S))
        _lowpasses(ctx.thrust_lps, tw, dt)
        ctx.thrust_lps_t = t

    def _lowpasses(lps: dict[float, float], value: float, dt: float | None) -> None:
        """Each of ``lps``'s first-order low-passes (by time constant) towards ``value``, ``dt`` on."""
        for tc in tcs:
            old = lps.get(tc)
            if old is None or dt is None:
                lps[tc] = value
            elif dt > 0:
                lps[tc] = old + (value - old) * (1.0 - math.exp(-dt / tc))

    def temperature(m, ctx):
        if m.instance == 0:
            ctx.temperature = float(m.value[0])
            if ctx.temperature_0 is None:
                ctx.temperature_0 = ctx.temperature

    def voltage(m, ctx):
        ctx.voltage = float(m.value[0])

    def current(m, ctx):
        ctx.current = float(m.value[0])

    def ground_speed(m, ctx):
        vn, ve = m.value.tolist()[:2]
        if math.isfinite(vn) and math.isfinite(ve):
            ctx.ground_speed = math.hypot(vn, ve)

    def vibration(m, ctx):
        # the accelerometer's deviation from its own low-passed value: rotors turning (the two
        # low-passes of :func:`lowpass` written out: this runs at the IMU blocks' rate)
        if m.instance != 0:
            return
        v = m.value.tolist()
        f = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) if len(v) == 3 else math.sqrt(sum(x * x for x in v))
        t = m.t
        t_last = ctx.f_lp_t
        if t_last is None:
            ctx.f_lp = f
        elif t > t_last:
            ctx.f_lp += (f - ctx.f_lp) * (1.0 - math.exp(-(t - t_last) / 1.0))
        ctx.f_lp_t = t
        dev = (f - ctx.f_lp) ** 2
        t_last = ctx.vibration_t
        if t_last is None:
            ctx.vibration = dev
        elif t > t_last:
            ctx.vibration += (dev - ctx.vibration) * (1.0 - math.exp(-(t - t_last) / VIBRATION_TC))
        ctx.vibration_t = t
        if ratio is not None and ctx.landed is False and len(v) == 3:
            # in the air the accelerometer reads the thrust over the mass along the body's z axis
            # (f_z = -T/m, FRD): the thrust as it is, which the command's map only predicts. Where it
            # reads more than the command can make, the gear's support is in it too (touching down,
            # before the land detector says so): it measures the thrust no longer, and the map says it.
            # Held to that most instead, the thrust read up to 0.12 of the weight high through a touchdown's
            # second, and a wash's size 4 % small (0.96 for 1.02; with the map, 0.99)
            tw = -v[2] / G
            held = ctx.thrust_map
            thrust(ctx, tw if held is None or tw <= held + spread else held, m.t)

    chain(Kind.THROTTLE, throttle)
    chain(Kind.ACTUATOR, throttle)
    chain(Kind.TEMPERATURE, temperature)
    chain(Kind.BATTERY_VOLTAGE, voltage)
    chain(Kind.BATTERY_CURRENT, current)
    chain(Kind.VELOCITY_NED, ground_speed)
    chain(Kind.ACCEL, vibration)
