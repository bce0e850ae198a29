"""The quadcopter document's thrust-model filter: observability, parameters, thrust loss."""

import csv

import numpy as np
import pytest

from drivers.replay import Replay
from groundstation.estimation.loop import EstimationLoop
from groundstation.estimation.models.quad_thrust import observability_report
from groundstation.estimation.registry import build_estimator
from sim_bridge.fast import run_fast
from sim_bridge.scenario import Scenario


def test_observability_ranks():
    r = observability_report()
    assert r["states"] == 6
    assert r["range+baro+gps, constant throttle"] == 5  # only alpha*tau + beta shows
    assert r["range+baro+gps, varying throttle"] == 6
    assert r["range+baro, constant throttle"] == 4  # and the (z, d_bar, d_tof) common mode
    assert r["range+baro, varying throttle"] == 5


def _fly(tmp_path, seconds, undeclared=()):
    sc = Scenario.from_args("quad", 3, seconds, ["range_tilt"], list(undeclared))
    run_fast(sc, tmp_path / "q.tlog", tmp_path / "q.csv")
    est = build_estimator("quad_thrust", [{"name": "range_tilt"}])
    loop = EstimationLoop([est])
    snaps = loop.snapshots.subscribe()
    for m in Replay(tmp_path / "q.tlog").iter_measurements():
        loop.push(m)
    rows = list(csv.DictReader(open(tmp_path / "q.csv")))
    return est, snaps.get_nowait(), rows


def _at(snaps, t):
    return min(snaps, key=lambda s: abs(s.t - t))


@pytest.mark.slow
def test_thrust_coefficients_and_height_on_a_simulated_flight(tmp_path):
    est, snaps, rows = _fly(tmp_path, 120.0)
    s = _at(snaps, 110.0)
    assert s.x[2] == pytest.approx(22.0, rel=0.08) and s.x[3] == pytest.approx(-1.2, abs=0.8)
    tt = np.array([float(r["t"]) for r in rows])
    h = np.array([float(r["h"]) for r in rows])
    ts = np.array([x.t for x in snaps])
    keep = (ts > 10) & (ts < 100)
    z = np.array([x.x[0] for x in snaps])[keep]
    assert np.sqrt(np.mean((z - np.interp(ts[keep], tt, h)) ** 2)) < 0.05
    for sensor in ("range", "baro"):
        a = est.filter.log.arrays(sensor)
        assert 0.7 < a["nis"][a["t"] > 10].mean() < 1.3


@pytest.mark.slow
def test_thrust_loss_with_battery_sag_shows_in_this_filter(tmp_path):
    est, snaps, rows = _fly(tmp_path, 200.0, ["thrust_voltage:n=2"])
    full_early = _at(snaps, 30.0).x[2] + _at(snaps, 30.0).x[3]  # acceleration at full throttle
    full_late = _at(snaps, 150.0).x[2] + _at(snaps, 150.0).x[3]
    assert full_late < 0.85 * full_early


def test_the_battery_load_line_is_read_from_the_log_and_fills_in_between_readings():
    """battery.py: V = V_oc(t) - k tau^2, readings at 5 Hz and the throttle at 50 Hz."""
    from groundstation.core.measurement import Kind, Measurement
    from groundstation.diagnosis.catalogue.battery import load_line, loaded_voltage

    rng = np.random.default_rng(3)
    t = np.arange(0.0, 60.0, 0.02)
    tau = 0.45 + 0.1 * np.sin(2 * np.pi * 0.7 * t) + 0.05 * rng.standard_normal(len(t))
    k = 4.8
    v_oc = 12.6 - 0.03 * t  # the pack discharging
    ms = [Measurement(ti, Kind.ACTUATOR, np.array([x] * 4), "sim") for ti, x in zip(t, tau)]
    # a reading draws the current of the throttle written before it (one written at its instant has not yet)
    ms += [
        Measurement(ti, Kind.BATTERY_VOLTAGE, np.array([v_oc[i] - k * tau[i - 1] ** 2 + rng.normal(0, 0.02)]), "sim")
        for i, ti in enumerate(t)
        if i % 10 == 0 and i
    ]
    ms.sort(key=lambda m: m.t)
    throttle = [(ti, x) for ti, x in zip(t, tau)]
    fit, sigma = load_line(ms, throttle)
    assert abs(fit - k) < 0.15 and 0 < sigma < 0.1
    # a pack that does not sag under load (or ESCs holding the voltage): nothing is claimed
    flat = [
        m._replace(value=np.array([12.0 + rng.normal(0, 0.02)])) if m.kind is Kind.BATTERY_VOLTAGE else m for m in ms
    ]
    assert load_line(flat, throttle) is None
    assert load_line([m for m in ms if m.kind is not Kind.BATTERY_VOLTAGE], throttle) is None
    # between readings: the reading taken at tau = 0.4, the throttle now 0.5
    assert loaded_voltage(11.0, 0.5, sag=k, tau2=0.4**2) == pytest.approx(11.0 - k * (0.25 - 0.16))
    assert loaded_voltage(11.0, 0.5) == 11.0  # no load line: the reading held


def test_the_open_circuit_voltage_is_smoothed_over_the_readings_without_lagging_the_discharge():
    """battery.OpenCircuitVoltage: 5 Hz readings with 20 mV of noise of a pack discharging at 30 mV/s
    (ten times the simulator's hover rate), read from a log with the throttle in effect at each reading.
    Held as read, the voltage between readings carries each reading's 20 mV; smoothed over the whole
    log, 3 mV (5-7 mV filtered forward only), not behind the discharge (a level without the drift state would lag
    it by the rate times the interval over the gain), and beyond the last reading on its drift."""
    from groundstation.core.measurement import Kind, Measurement
    from groundstation.diagnosis.catalogue.battery import (
        OpenCircuitVoltage,
        loaded_voltage,
        reading_sigma,
    )

    rng = np.random.default_rng(5)
    t = np.arange(0.0, 60.0, 0.2)
    v_true = 12.4 - 0.03 * t
    v_read = v_true + rng.normal(0.0, 0.02, len(t))
    tau = 0.45 + 0.1 * np.sin(2 * np.pi * 0.7 * t)
    throttle = [(ti, x) for ti, x in zip(t - 0.01, tau)]
    ms = [Measurement(ti, Kind.ACTUATOR, np.array([x] * 4), "sim") for ti, x in throttle]
    ms += [
        Measurement(ti, Kind.BATTERY_VOLTAGE, np.array([v - 4.8 * x * x]), "sim") for ti, v, x in zip(t, v_read, tau)
    ]
    ms.sort(key=lambda m: m.t)
    # the readings' noise from a log: the load line's residuals
    sigma = reading_sigma(ms, throttle, 4.8)
    assert sigma == pytest.approx(0.02, rel=0.15)
    oc = OpenCircuitVoltage.from_log(ms, throttle, 4.8, sigma)
    err, err_held = [], []
    for i in range(50, len(t) - 1):  # after 10 s of readings
        for s in (0.05, 0.1, 0.15):  # between this reading and the next
            truth = 12.4 - 0.03 * (t[i] + s)
            err.append(oc.at(t[i] + s) - truth)
            err_held.append(v_read[i] - truth)
    err, err_held = np.array(err), np.array(err_held)
    assert np.sqrt(np.mean(err_held**2)) > 0.018
    assert np.sqrt(np.mean(err**2)) < 0.005 and abs(np.mean(err)) < 0.002, (np.sqrt(np.mean(err**2)), np.mean(err))
    assert oc.at(t[-1] + 1.0) == pytest.approx(12.4 - 0.03 * (t[-1] + 1.0), abs=0.02)
    # the thrust model's voltage at throttle 0.5: the smoothed V_oc less the load line's sag
    assert loaded_voltage(11.0, 0.5, sag=4.8, tau2=0.16, oc=oc, t=t[-1]) == pytest.approx(oc.at(t[-1]) - 4.8 * 0.25)


def test_thrust_voltage_is_the_exact_power_law_at_its_estimate():
    """thrust.thrust_voltage: a_V (the input) + n^ times the coupling's column give a_T c ((V/V_ref)^n^ - 1),
    and the column is the derivative in n there."""
    from groundstation.diagnosis.catalogue.thrust import thrust_voltage
    from groundstation.diagnosis.catalogue.thrust_model import _voltage_terms, thrust_model

    m = thrust_voltage(thrust_model(alpha0=22.0, beta0=-1.2))
    i_n, iv = m.index("n_voltage"), m.index("vz")
    x = np.zeros(m.n)
    x[i_n] = 1.7
    a_tc, volt, v_ref = 9.0, 10.2, 12.1
    n_hat, a_v = _voltage_terms(x, i_n, volt, v_ref, a_tc)
    u = np.array([0.45, 1.0, 9.80665, volt, 1.0, a_tc, v_ref, n_hat, a_v])
    col = m.A(u)[iv, i_n]
    r = volt / v_ref
    assert a_v + n_hat * col == pytest.approx(a_tc * (r**1.7 - 1.0))
    assert col == pytest.approx(a_tc * (r**1.7 * np.log(r)))
    b = m.B[:, m.inputs.index("a_V")]  # a_V enters vz_dot as an input, 1:1
    assert b[iv] == 1.0 and np.count_nonzero(b) == 1
    assert _voltage_terms(x, None, volt, v_ref, a_tc) == (0.0, 0.0)  # the base model: no term


def test_the_live_filter_stands_on_the_ground_after_a_touchdown(tmp_path):
    """models.contact in the live filter: at a touchdown the throttle is still 0.2-0.4, which buys less
    than the weight, and the range reads nothing below its floor. Driven by it the estimate sank to
    1.5 m below the ground at 2 m/s over 1.5 s, and the baro's NIS after the landing read 2.5-3.4.
    Now the ground holds it (-3 cm at worst measured) and the thrust coefficients end near the
    simulator's 22, -1.2 (they ended at 20.4, +0.2 when the model fell through)."""
    est, snaps, rows = _fly(tmp_path, 60.0)
    tt = np.array([float(r["t"]) for r in rows])
    h = np.array([float(r["h"]) for r in rows])
    t_down = tt[np.flatnonzero(h > 0.05)[-1]]  # the touchdown
    after = [s for s in snaps if s.t > t_down - 1.0]
    assert min(s.x[0] for s in after) > -0.1 and abs(after[-1].x[0]) < 0.02 and abs(after[-1].x[1]) < 0.05
    a = est.filter.log.arrays("baro")
    assert a["nis"][a["t"] > t_down - 1.0].mean() < 1.6
    assert after[-1].x[2] == pytest.approx(22.0, rel=0.05) and after[-1].x[3] == pytest.approx(-1.2, abs=0.5)
    assert est.counters.skipped.get("landed_not_used", 0) > 0  # the ground's constraints were there
