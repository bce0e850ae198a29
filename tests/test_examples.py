"""The examples run, and say what their docstrings promise."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run(name: str, seconds: float) -> str:
    r = subprocess.run(
        [sys.executable, str(EXAMPLES / name), "--seconds", str(seconds)], capture_output=True, text=True, timeout=600
    )
    assert r.returncode == 0, r.stderr
    return r.stdout


def numbers(pattern: str, text: str) -> list[float]:
    m = re.search(pattern, text)
    assert m, f"{pattern!r} not in:\n{text}"
    return [float(x) for x in m.groups()]


def test_every_example_is_listed_and_runs_here():
    listed = set(re.findall(r"`(\d\d_\w+\.py)`", (EXAMPLES / "README.md").read_text()))
    assert listed == {p.name for p in EXAMPLES.glob("[0-9][0-9]_*.py")}


@pytest.mark.slow
def test_01_the_estimate_beats_the_range_sensor_and_its_sigma_holds_the_truth():
    out = run("01_replay_through_the_estimation_loop.py", 20)
    est, raw = numbers(r"estimate ([0-9.]+) mm, raw range ([0-9.]+) mm", out)
    assert est < raw
    within, nees = numbers(r"within 2 sigma ([0-9]+)% of the time \(95 % if honest\), NEES ([0-9.]+)", out)
    assert within > 80 and 0.2 < nees < 3.0, out


def test_02_rls_reads_the_atmospheres_diluted_slope():
    out = run("02_recursive_least_squares.py", 30)
    (a,) = numbers(r"slope a = (-[0-9.]+) m/Pa", out)
    (expected,) = numbers(r"noise: (-[0-9.]+) m/Pa", out)
    assert a == pytest.approx(expected, rel=0.05)


@pytest.mark.slow
def test_03_the_filters_beat_the_accelerometer_alone():
    out = run("03_attitude_filters.py", 30)
    (alone,) = numbers(r"accelerometer alone\s+([0-9.]+) deg", out)
    for name in ("complementary \\(ch. 8\\)", "gravity EKF", "rotor-drag EKF"):
        (e,) = numbers(name + r"\s+([0-9.]+) deg", out)
        assert e < alone


@pytest.mark.slow
def test_04_the_undeclared_effect_is_found_and_the_error_falls():
    out = run("04_diagnose_an_undeclared_effect.py", 60)
    (k,) = numbers(r"found baro_thrust: k = ([0-9.]+)", out)
    before, after = numbers(r"([0-9.]+) cm before, ([0-9.]+) cm after", out)
    assert 2.4 < k < 3.6 and after < 0.5 * before


@pytest.mark.slow
def test_05_the_live_link_streams_and_estimates():
    out = run("05_live_link_on_loopback.py", 5)
    (loss,) = numbers(r"loss ([0-9.]+) %", out)
    assert loss < 5.0 and "streams via SET_MESSAGE_INTERVAL" in out and "altitude at t =" in out


@pytest.mark.slow
def test_06_the_parameters_a_diagnosis_loads_make_the_vehicles_own_estimate_better():
    out = run("06_the_loop_closed_on_the_vehicle.py", 30)
    assert "diagnosis: added baro_thrust" in out and "(confirmed by the vehicle)" in out
    (scale,) = numbers(r"loaded BARO1_THST_SCALE = (-[0-9.]+)", out)
    assert -45.0 < scale < -27.0  # -rho*g*k: about 12 Pa/m times the 3 m per unit throttle hidden
    before, after = numbers(r"([0-9.]+) cm before, ([0-9.]+) cm after", out)
    assert before > 80.0 and after < 0.35 * before


@pytest.mark.slow
def test_07_a_search_over_two_candidates_claims_the_wash_and_nothing_else():
    out = run("07_a_diagnosis_from_its_parts.py", 60)
    (k,) = numbers(r"claimed baro_thrust: k = ([0-9.]+)", out)
    before, after = numbers(r"([0-9.]+) cm before, ([0-9.]+) cm after", out)
    assert 2.4 < k < 3.6 and after < 0.5 * before and "claimed baro_bias_drift" not in out
