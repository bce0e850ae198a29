"""The thrust over the weight from the command (estimation/thrust_ratio.py), the rotor wash's two forms
it gives the catalogue, and the ground that holds the height from a lift-off until the range reads
(estimation/models/ground.py)."""

import json
import math

import numpy as np
import pytest

from groundstation.core.measurement import Kind, Measurement
from groundstation.core.readings import Readings
from groundstation.diagnosis.catalogue.altitude import altitude_catalogue
from groundstation.diagnosis.models import setup
from groundstation.diagnosis.runs.run import run_model
from groundstation.estimation.logs import load_log
from groundstation.estimation.stated import stated_by
from groundstation.estimation.thrust_ratio import ThrustRatio, command, thrust_ratio

from .conftest import foreign2_file

G = 9.80665


def _m(t: float, kind: Kind, value) -> Measurement:
    return Measurement(t, kind, np.atleast_1d(np.asarray(value, dtype=float)), "test", t)


def _flight(a: float, b: float, seconds: float = 60.0, seed: int = 1) -> list[Measurement]:
    """10 s on the ground (throttle 0, the ground's support in the accelerometer), ``seconds`` in the
    air with a throttle that wanders about its hover, 10 s on the ground again; in the air the
    accelerometer reads T/(m g) = a c + b along the body's z, with vibration."""
    rng = np.random.default_rng(seed)
    end = 20.0 + seconds
    ms = []
    for k in range(int(end * 10)):
        t = k * 0.1
        c = 0.0 if t < 10.0 or t > 10.0 + seconds else 0.4 + 0.08 * math.sin(0.7 * t) + 0.03 * math.sin(3.1 * t)
        ms.append(_m(t, Kind.THROTTLE, c))
    for k in range(int(end * 100)):
        t = k * 0.01
        c = 0.0 if t < 10.0 or t > 10.0 + seconds else 0.4 + 0.08 * math.sin(0.7 * t) + 0.03 * math.sin(3.1 * t)
        tw = 1.0 if c == 0.0 else a * c + b
        ms.append(_m(t, Kind.ACCEL, [0.0, 0.0, -G * tw + rng.normal(0.0, 0.5)]))
    return sorted(ms, key=lambda m: m.t)


def test_the_map_is_read_from_the_accelerometer_in_the_air():
    """T/(m g) = 1.8 c + 0.28 in the air: the fit finds it, and on the ground a command at idle makes none."""
    r = thrust_ratio(Readings.of(_flight(1.8, 0.28)), None, 4)
    assert r is not None
    assert r.a == pytest.approx(1.8, rel=0.05) and r.b == pytest.approx(0.28, abs=0.03)
    assert r.of(0.0) == 0.0 and r.of(0.4) == pytest.approx(1.0, abs=0.02)
    assert r.seconds == pytest.approx(58.0, abs=0.5)  # the air, a second clear of the take-off and the landing


def test_no_map_without_a_flight_to_fit_it_on():
    ground = [m for m in _flight(1.8, 0.28, seconds=5.0) if m.kind is Kind.ACCEL or m.value[0] == 0.0]
    assert thrust_ratio(Readings.of(ground), None, 4) is None  # no throttle above idle
    assert thrust_ratio(Readings.of(_flight(1.8, 0.28, seconds=8.0)), None, 4) is None  # 4 s in the air
    no_accel = [m for m in _flight(1.8, 0.28) if m.kind is Kind.THROTTLE]
    assert thrust_ratio(Readings.of(no_accel), None, 4) is None


def test_the_thrust_forms_are_offered_only_with_the_map():
    kinds = {Kind.ACCEL, Kind.BARO_PRESSURE, Kind.GPS, Kind.THROTTLE, Kind.TEMPERATURE}
    forms = {(c.name, c.form, c.needs_option) for c in altitude_catalogue(kinds)}
    assert ("baro_thrust", "throttle", None) in forms and ("baro_thrust", "thrust", "thrust_ratio") in forms
    assert ("baro_ground_effect", "rotors running", None) in forms
    assert ("baro_ground_effect", "thrust", "thrust_ratio") in forms


@pytest.mark.parametrize("name", ["baro_thrust_s1.bin", "baro_thrust_s2.ulg"])
def test_another_generators_thrust_over_weight_is_read_from_its_log(name):
    """The map, applied to the log's own commands, against the truth's thrust over the weight in the
    air: within a few percent of the hover's (what is left is the rotors' lag and the controller's
    jitter, which the accelerometer reads in the air); on the ground idling, the thrust the rotors'
    frequency says (the line had put 0.21 and 0 of the weight there, for the truth's 0.053); none
    before the motors are armed."""
    path = foreign2_file(name)
    log = load_log(path, imu_columns=True)
    stated = stated_by(log.tables, log.measurements)
    su = setup(log.measurements, imu=log.imu, stated=stated)
    r = su.model.options.get("thrust_ratio")
    assert isinstance(r, ThrustRatio) and r.rms < 0.06
    cmd = [(m.t, command(m, stated.motors, 4, clip=False)) for m in log.measurements if m.kind is Kind.ACTUATOR]
    t = np.array([x for x, c in cmd if c is not None])
    tw = np.array([r.of(c) for _, c in cmd if c is not None])
    truth = np.genfromtxt(path.with_name(path.stem + "_truth.csv"), delimiter=",", names=True)
    fl = np.interp(t, truth["t"], truth["in_flight"]) > 0.5
    true_tw = np.interp(t, truth["t"], truth["thrust_over_weight"])
    err = tw - true_tw
    assert abs(err[fl].mean()) < 0.02 and np.sqrt(np.mean(err[fl] ** 2)) < 0.05
    times = json.loads(path.with_name(path.stem + "_meta.json").read_text())["times"]
    assert np.all(tw[t < times["arm"]] == 0.0)
    idling = (t > times["arm"] + 0.5) & (t < times["liftoff"] - 0.5)
    assert r.idle_tw is not None and r.rotor_hz is not None
    assert np.abs(tw[idling] - true_tw[idling]).max() < 0.012, (tw[idling].mean(), true_tw[idling].mean())


def test_the_rotors_frequency_is_read_from_the_accelerometers_spectrum():
    """A rotor's vibration at 15.4 Hz and its harmonic, under white noise and a slow sway, sampled at
    200 Hz: read to a tenth of a hertz; a spectrum with no peak standing out gives none."""
    from groundstation.estimation.thrust_ratio import rotor_frequency

    rng = np.random.default_rng(3)
    t = np.arange(0.0, 4.0, 0.005)
    x = np.stack(
        [
            0.05 * np.sin(2 * np.pi * 15.4 * t) + 0.01 * np.sin(2 * np.pi * 30.8 * t + 1.0),
            0.03 * np.sin(2 * np.pi * 15.4 * t + 0.5) + 0.2 * np.sin(2 * np.pi * 0.7 * t),
            0.04 * np.cos(2 * np.pi * 15.4 * t),
        ],
        axis=1,
    ) + rng.normal(0.0, 0.02, (len(t), 3))
    f = rotor_frequency(x, 200.0)
    assert f is not None and f == pytest.approx(15.4, abs=0.1)
    assert rotor_frequency(rng.normal(0.0, 0.02, (len(t), 3)), 200.0) is None
    assert rotor_frequency(x[:100], 200.0) is None  # half a second: not enough to read it on


def test_below_the_airborne_commands_the_map_runs_to_the_idle_and_to_nothing():
    """The map with its idle point: the line from its lowest airborne command up, the idle's thrust at
    the idle command, nothing at the stopped motors', continuous and rising in between."""
    r = ThrustRatio(2.1, 0.0, 0.03, 100.0, low=0.42, zero=-0.1875, idle=-0.0625, idle_tw=0.053, rotor_hz=(15.4, 66.0))
    assert r.of(0.5) == pytest.approx(1.05) and r.of(0.42) == pytest.approx(2.1 * 0.42)
    assert r.of(-0.0625) == pytest.approx(0.053) and r.of(-0.1875) == 0.0 and r.of(-0.5) == 0.0
    c = np.linspace(-0.3, 0.6, 901)
    tw = np.array([r.of(x) for x in c])
    assert np.all(np.diff(tw) >= -1e-12) and np.max(np.abs(np.diff(tw))) < 0.01
    plain = ThrustRatio(2.1, 0.0, 0.03, 100.0)
    assert plain.of(-0.0625) == 0.0 and plain.of(0.1) == pytest.approx(0.21)


def test_the_ground_holds_the_height_from_a_lift_off_until_the_range_reads():
    """Another generator's lift-off: the wash holds the baro 45 cm low near the ground and the range
    reads nothing until 0.12 s after it. The height before any effect is found stays on the floor
    (it went 41 cm under it)."""
    path = foreign2_file("baro_ground_effect_s2.ulg")
    meta = json.loads(path.with_name("baro_ground_effect_s2_meta.json").read_text())
    log = load_log(path, imu_columns=True)
    su = setup(log.measurements, imu=log.imu, stated=stated_by(log.tables, log.measurements))
    run = run_model(su.model, su.prep, su.make)
    lift = meta["times"]["liftoff"]
    near = (run.t > lift - 1.0) & (run.t < lift + 0.3)
    assert run.x[near, su.model.index("z")].min() > -0.05


def test_a_wash_in_its_thrust_form_is_said_so_in_the_conclusion():
    from groundstation.diagnosis.effect import Effect
    from groundstation.diagnosis.report.conclusion import _named

    thrust = Effect("baro_thrust", {"k": 1.82, "k_tw": 0.865, "tc": 0.275}, {"form": "thrust"})
    throttle = Effect("baro_thrust", {"k": 1.82, "tc": 0.275}, {"form": "throttle"})
    assert _named(thrust).endswith("; it follows the thrust over the weight)")
    assert "thrust over the weight" not in _named(throttle)


def test_touching_down_the_accelerometer_is_held_to_the_thrust_the_command_makes():
    """In the air the thrust over the weight is the accelerometer's; once the gear takes the weight and
    the throttle winds down, the accelerometer reads more than the command can make (the map and three
    times its residual above it): the support is in it, and the thrust is the map's."""
    from groundstation.diagnosis.runs.signals import add_signal_rules
    from groundstation.estimation.models.altitude import altitude_model
    from groundstation.estimation.routing import altitude_estimator

    ratio = ThrustRatio(a=1.8, b=0.28, rms=0.02, seconds=60.0)
    assert ratio.most(0.4) == pytest.approx(ratio.of(0.4) + 3 * 0.03)  # the residual taken at least 0.03
    model = altitude_model()
    model.options["thrust_ratio"] = ratio
    est = altitude_estimator(model)
    add_signal_rules(est)
    est.filter.ctx.landed = False  # in the air (the ground's own rule decides it in a run)
    est.handle(_m(0.0, Kind.ATTITUDE, [0.0, 0.0, 0.0]))
    for k in range(50):  # hovering: the accelerometer and the command agree
        est.handle(_m(0.01 * k, Kind.THROTTLE, 0.4))
        est.handle(_m(0.01 * k + 0.005, Kind.ACCEL, [0.0, 0.0, -G * ratio.of(0.4)]))
    assert est.filter.ctx.thrust_ratio == pytest.approx(1.0, abs=0.01)
    for k in range(50, 200):  # on the gear, the throttle at 0.2 and the ground holding the rest
        est.filter.ctx.landed = False  # (before any land detector says so)
        est.handle(_m(0.01 * k, Kind.THROTTLE, 0.2))
        est.handle(_m(0.01 * k + 0.005, Kind.ACCEL, [0.0, 0.0, -G]))
    assert est.filter.ctx.thrust_ratio == pytest.approx(ratio.of(0.2), abs=0.01)
