"""Thrust lost as the battery sags, traced beside the altitude model from the accelerometer's thrust
curve (diagnosis/catalogue/thrust_side.py), and the parameters a diagnosis never writes outside the ranges their
autopilots document (drivers/mavlink/param_ranges.py)."""

import numpy as np
import pytest

from drivers.mavlink.param_ranges import outside
from groundstation.diagnosis.catalogue.thrust_side import voltage_effect
from groundstation.diagnosis.models import setup
from groundstation.diagnosis.runs.run import run_model
from groundstation.estimation.logs import load_log
from groundstation.estimation.stated import stated_by

from .conftest import bench_module, foreign2_file


def traced(name: str, accel_bias=None):
    """``voltage_effect`` on a flight of the second source, ``accel_bias(t)`` [m/s^2] added to its
    accelerometer's body z where given."""
    log = load_log(foreign2_file(name), imu_columns=True)
    if accel_bias is not None:
        log = bench_module("foreign").with_accel_bias(log, accel_bias)
    su = setup(log.measurements, imu=log.imu, stated=stated_by(log.tables, log.measurements))
    return voltage_effect(su.prep, run_model(su.model, su.prep, su.make))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["thrust_voltage_s1.bin", "thrust_voltage_s2.ulg"])
def test_open_loop_escs_thrust_loss_is_claimed_with_its_exponent(name):
    """Another generator's hexacopter on open-loop ESCs: thrust goes with (V / V_ref)^2."""
    e = traced(name)
    assert e is not None and e.evidence["claimed"], e
    assert e.params["n"] == pytest.approx(2.0, rel=0.15), e.params
    assert e.evidence["thrust_rms_after"] < 0.5 * e.evidence["thrust_rms_before"]
    assert all(g > 0 for g in e.evidence["held_out_gain_by_block"])


@pytest.mark.slow
@pytest.mark.parametrize("name", ["clean_range_s1.bin", "clean_range_s2.ulg", "clean_s1.bin", "baro_thrust_s2.ulg"])
def test_closed_loop_escs_claim_nothing(name):
    """The same airframe on ESCs that hold the rotor speed whatever the voltage: no claim (a thrust
    that rises as the pack sags is no battery's effect, and a weak one is not evidence)."""
    e = traced(name)
    assert e is None or not e.evidence["claimed"], e


@pytest.mark.slow
def test_an_accelerometer_bias_moving_as_the_imu_warms_is_not_thrust_lost_with_the_battery():
    """The indoor .bin flight, its ESCs holding the rotor speed, with the accelerometer's body-z bias
    moving 0.03 m/s^2 per K as its IMU warms (+0.3 m/s^2 over the log): pack and IMU both move one way
    through the flight. Without the altitude filter's bias taken out, n read 1.46 and was claimed; with
    it, what is left is no larger than the bias's move, and is said so."""
    path = foreign2_file("clean_range_s1.bin")
    truth = np.genfromtxt(path.with_name("clean_range_s1_truth.csv"), delimiter=",", names=True)
    e = traced(path.name, lambda t: 0.03 * (np.interp(t, truth["t"], truth["imu_temp_c"]) - truth["imu_temp_c"][0]))
    assert e is not None and not e.evidence["claimed"], e
    assert "the accelerometer's bias moved" in e.evidence["reason"], e.evidence
    assert e.evidence["thrust_change"] < 2 * e.evidence["bias_change"]
    assert abs(e.params["n"]) < 1.0, e.params


def test_no_parameter_is_written_outside_its_documented_range():
    assert outside("INS_ACCSCAL_Z", 1.314) is not None  # a submarine's depth sensor read as a barometer
    assert outside("INS_ACCSCAL_Z", 1.03) is None
    assert "0.1 to 100" in (outside("EK3_ALT_M_NSE", 136.5) or "")
    assert outside("RNGFND1_GNDCLEAR", 3.0) is not None  # ArduPilot's range starts at 5 cm
    assert outside("SOME_UNLISTED_PARAM", 1e9) is None


@pytest.mark.parametrize(("seed", "n"), [(21, 2.0), (23, 0.0)])
def test_our_simulators_thrust_loss_is_traced_beside_the_altitude_model(tmp_path, seed, n):
    """``diagnose LOG`` with nothing said picks the altitude model, and beside it the accelerometer's
    thrust curve names an undeclared thrust loss with the battery (n = 2) and nothing on a clean flight."""
    from sim_bridge.fast import run_fast
    from sim_bridge.scenario import Scenario

    log = tmp_path / "q.tlog"
    undeclared = [f"thrust_voltage:n={n:g}"] if n else []
    run_fast(Scenario.from_args("quad", seed, 60.0, ["range_tilt"], undeclared), log, tmp_path / "q.csv")
    loaded = load_log(log, imu_columns=True)
    su = setup(loaded.measurements, imu=loaded.imu, stated=stated_by(loaded.tables, loaded.measurements))
    e = voltage_effect(su.prep, run_model(su.model, su.prep, su.make))
    assert e is not None
    if n:
        assert e.evidence["claimed"] and e.params["n"] == pytest.approx(n, rel=0.1), e
    else:
        assert not e.evidence["claimed"] and abs(e.params["n"]) < 3 * e.params["sigma_n"] + 0.05, e
