"""Every effect of the catalogue does what its documented equation says."""

import math

import numpy as np
import pytest

from groundstation.core.atmosphere import altitude_at
from sim_bridge.effects import REGISTRY, catalogue_markdown, parse_effect
from sim_bridge.scenario import Scenario
from sim_bridge.simulator import Simulator


def fly(effects, seconds=20.0, seed=4, vehicle="quad"):
    """Run the simulator; per sample also the truth at that instant."""
    sim = Simulator(Scenario(vehicle, seed=seed, duration=60, undeclared=[parse_effect(e) for e in effects]))
    rows = []
    for _ in range(int(seconds / sim.dt)):
        for s in sim.step():
            v = sim.vehicle
            rows.append((s, v.imu_truth(), v.kin.height, v.kin.R[2, 2], sim.truth()))
    return sim, rows


def series(rows, sensor, t0=6.0):
    return [(s, imu, h, c, tr) for s, imu, h, c, tr in rows if s.sensor == sensor and s.t >= t0]


def test_every_effect_is_documented_with_units_and_range():
    table = catalogue_markdown()
    for name, cls in REGISTRY.items():
        assert cls.equation and f"`{name}`" in table
        for p in cls.params.values():
            assert p.unit and p.low <= p.default <= p.high


def test_accel_bias_and_scale_and_gyro_bias():
    _, rows = fly(["accel_bias:z=0.3", "gyro_bias:x=0.02"])
    imu = series(rows, "imu")
    dz = np.mean([s.values[2] - t[2] for s, t, *_ in imu])
    dwx = np.mean([s.values[3] - t[3] for s, t, *_ in imu])
    assert dz == pytest.approx(0.3, abs=0.01) and dwx == pytest.approx(0.02, abs=0.001)
    _, rows = fly(["accel_scale:s=0.03"])
    imu = series(rows, "imu")
    ratio = np.mean([s.values[2] for s, *_ in imu]) / np.mean([t[2] for _, t, *_ in imu])
    assert ratio == pytest.approx(1.03, abs=0.003)


def _baro_error(rows):
    out = []
    for s, _, h, _, tr in series(rows, "baro"):
        out.append((s.t, float(altitude_at(s.values[0])) - 120.0 - h, tr))
    return out


def test_baro_bias_drift_rate():
    _, rows = fly(["baro_bias_drift:rate=0.1,sigma=0"], seconds=30)
    e = _baro_error(rows)
    t = np.array([x[0] for x in e])
    err = np.array([x[1] for x in e])
    assert np.polyfit(t, err, 1)[0] == pytest.approx(0.1, abs=0.01)


@pytest.mark.parametrize(
    "spec,check",
    [
        ("baro_thermal:k=0.5", lambda tr: 0.5 * (tr["temperature"] - 293.15)),
        (
            "baro_ground_effect:A=-2,h0=0.5",
            lambda tr: -2 * math.exp(-max(0.0, tr["h"]) / 0.5) if tr["throttle"] > 0.05 else 0.0,
        ),
        ("baro_airflow:k=0.3", lambda tr: 0.3 * tr["vd"] ** 2),
    ],
)
def test_baro_errors_follow_their_equation(spec, check):
    _, rows = fly([spec], seconds=30)
    e = _baro_error(rows)
    resid = np.array([err - check(tr) for _, err, tr in e])
    assert abs(resid.mean()) < 0.05 and resid.std() < 0.5  # what remains is the 4 Pa noise
    assert max(abs(check(tr)) for *_, tr in e) > 0.3  # and the effect was large


def test_baro_thrust_is_low_passed_throttle():
    _, rows = fly(["baro_thrust:k=4,tc=0.5"], seconds=30)
    e = [(s.t, float(altitude_at(s.values[0])) - 120.0 - h, tr) for s, _, h, _, tr in series(rows, "baro", t0=0.0)]
    before = np.mean([err for t, err, _ in e if t < 1.9])  # motors off
    flying = [(err, tr["throttle"]) for t, err, tr in e if t > 8.0]
    assert abs(before) < 0.15  # no wash without rotors
    assert np.mean([x[0] for x in flying]) == pytest.approx(4 * np.mean([x[1] for x in flying]), abs=0.2)
    # the step at spin-up is smoothed with tc = 0.5 s: about 63 % of it after 0.5 s
    spin = next(t for t, _, tr in e if tr["throttle"] > 0.05)
    at_tc = np.mean([err for t, err, _ in e if spin + 0.45 < t < spin + 0.55])
    full = np.mean([err for t, err, _ in e if spin + 2.5 < t < spin + 3.0])
    assert 0.45 < at_tc / full < 0.8


def test_range_is_slant_and_offset_adds():
    _, rows = fly(["range_offset:o=-0.04"], seconds=50)
    rng = series(rows, "range")
    err = np.array([s.values[0] - h / c for s, _, h, c, _ in rng])
    assert err.mean() == pytest.approx(-0.04, abs=0.003)
    tilted = [(s, h, c) for s, _, h, c, _ in rng if c < math.cos(math.radians(8))]
    assert tilted, "the profile tilts the vehicle"
    slant = np.array([s.values[0] + 0.04 - h for s, h, c in tilted])
    assert slant.mean() > 0.01  # longer than the height: slant


def test_sensor_delay_delivers_late():
    _, a = fly([], seconds=20)
    _, b = fly(["sensor_delay:sensor=range,seconds=0.04"], seconds=20)
    ta = {round(s.t, 4): s.values[0] for s, *_ in series(a, "range")}
    tb = {round(s.t, 4): s.values[0] for s, *_ in series(b, "range")}
    # the delayed stream shows at t + 0.04 what the prompt one showed at t (same seed, same noise)
    matches = [abs(tb[round(t + 0.04, 4)] - v) < 1e-9 for t, v in ta.items() if round(t + 0.04, 4) in tb]
    assert len(matches) > 100 and np.mean(matches) > 0.95


def test_thrust_voltage_makes_the_throttle_climb_as_the_battery_sags():
    sim_a, _ = fly([], seconds=40)
    sim_b, _ = fly(["thrust_voltage:n=2"], seconds=40)
    thr_a = np.array([r["throttle"] for r in sim_a.truth_rows if 8 < r["t"] < 40 and r["h"] > 0.5])
    thr_b = np.array([r["throttle"] for r in sim_b.truth_rows if 8 < r["t"] < 40 and r["h"] > 0.5])
    assert thr_b.mean() > thr_a.mean() + 0.01


def test_thrust_ground_effect_and_actuator_lag():
    sim, _ = fly(["thrust_ground_effect:R=0.15"], seconds=8)
    low = [r for r in sim.truth_rows if 0.1 < r["h"] < 0.3 and r["throttle"] > 0.1]
    assert low and all(r["a_thrust"] > 22.0 * r["throttle"] - 1.2 + 1e-6 for r in low)
    sim, rows = fly(["actuator_lag:tc=0.1"], seconds=8)
    applied = [r["throttle"] for r in sim.truth_rows]
    steps = np.abs(np.diff(applied))
    assert steps.max() < 0.1  # no jumps: the motors lag
    # the lag is in the motors: the outputs the log records (PWM) are the commands, which jump at arming
    pwm = [s.values[0] for s, *_ in rows if s.sensor == "actuators"]
    assert np.abs(np.diff(pwm)).max() > 0.3


def test_the_logged_outputs_are_the_command_the_motors_fly_from_then_on():
    """A log records the PWM an autopilot writes, and the motors follow it from that instant. The
    simulator once showed the command of the step just flown: at each of the autopilot's 250 Hz
    ticks the outputs read the tick before, 4 ms stale (a 0.05 s actuator lag then read 0.042 s)."""
    sim = Simulator(Scenario.from_args("quad", 3, 60.0, [], [], flight="thrust_test"))
    shown, previous, changed = None, None, 0
    while sim.t < 12.0:
        sim.step()
        flown = sim.vehicle.clipped(sim.last_command).throttle
        if shown is not None:
            assert flown == shown, sim.t
            changed += flown != previous
        previous, shown = flown, sim.actuator_outputs()[0]
    assert changed > 1000  # the autopilot moved the throttle at most of its ticks


def test_imu_misalignment_rotates_and_vibration_shakes():
    _, rows = fly(["imu_misalignment:roll=3,pitch=0,yaw=0"], seconds=10)
    imu = [s for s, *_ in series(rows, "imu", t0=0.5) if s.t < 1.9]  # standing level
    fy = np.mean([s.values[1] for s in imu])
    assert fy == pytest.approx(-9.80665 * math.sin(math.radians(3)), abs=0.02)
    _, calm = fly([], seconds=12)
    _, shaky = fly(["vibration:A=3,freq=123"], seconds=12)
    sd = lambda rows: np.std([s.values[0] for s, *_ in series(rows, "imu", t0=8)])  # noqa: E731
    assert sd(shaky) > 2 * sd(calm)
