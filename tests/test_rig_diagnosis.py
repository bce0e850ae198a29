"""The 3-DOF helicopter's closed loop: every effect the simulator can give the rig is found at a
realistic size on a session flown as the lab flies it (take-off from the table, elevation steps,
travel swings), with its size; a session near the linearisation point claims nothing, one far from
it the full equations only; the rig's constants written go back into the estimator and leave
nothing to find, and the controllers designed on them hold the rig where the lab's do not."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from groundstation.app.demo_cli import rig_constants
from groundstation.app.offline_flight import fly
from groundstation.control.controllers import PitchPD
from groundstation.control.feedback import FEEDBACK_3DOF
from groundstation.control.station import ControlStation
from groundstation.diagnosis.live import SessionBuffer, diagnose_window, markdown
from groundstation.diagnosis.rig.diagnose import diagnose_rig
from groundstation.estimation.logs import load_log
from groundstation.estimation.models.heli3dof_rig import Heli3dofRig
from groundstation.estimation.registry import build_estimator
from sim_bridge.effects import parse_effect
from sim_bridge.scenario import Scenario
from web.dashboard import DIAGNOSIS_MODELS

#: terms of the full equations the simulator always flies: a session may show them with anything
PHYSICS = {"elevation_trig", "travel_lever_arm"}


def simulate(tmp, *args, seconds=60, flight="standard", seed=1):
    log = tmp / f"rig-{flight}-{seed}-{abs(hash(args)) % 10**8}.tlog"
    cmd = [sys.executable, "-m", "groundstation", "sim", "--vehicle", "heli3dof", "--fast", "--flight", flight]
    cmd += ["--seed", str(seed), "--duration", str(seconds), "--log", str(log), *args]
    subprocess.run(cmd, check=True, capture_output=True, timeout=120)
    return log


def diagnosed(path, **kw):
    log = load_log(path, tables=False, imu_columns=True)
    return diagnose_rig(log.measurements, log.imu, with_kalman=kw.pop("with_kalman", False), **kw)


def claimed(d) -> dict[str, dict]:
    """Each claimed effect's fitted values (the final model's)."""
    fin = d.search.final.values
    return {st.name: {k: fin[k] for k in st.fit.free} for st in d.search.claimed}


# (undeclared effect, the candidate that must name it, the parameter and its true value, tolerance)
INJECTED = [
    # the masses kept, V_s0 = (2 l_h m_p - l_c m_c) g / (l_h K_f) moves with K_f: 8.008 / 1.08
    ("motor_constant:s=0.08", "motor_constant", "K_f", 0.1248 * 1.08, 0.02),
    ("counterweight:dm=0.02", "equilibrium_voltage", "V_s0", 6.907, 0.02),
    ("motor_asymmetry:a=0.04", "motor_asymmetry", "a", 0.04, 0.1),
    ("viscous_friction:p=0,e=0,lambda=0.08", "viscous_friction(lambda)", "c_l", 0.08 / 1.08, 0.15),
    ("viscous_friction:p=0.005,e=0,lambda=0", "viscous_friction(p)", "c_p", 0.005 / 0.044, 0.2),
    ("actuator_lag:tc=0.05", "motor_lag", "tc", 0.05, 0.25),
    ("encoder_offset:p=1.0,e=-0.8", "encoder_offset", "o_p", math.radians(1.0), 0.05),
    ("gyro_bias:x=0.01,y=-0.008,z=0.005", "gyro_bias", "b_gx", 0.01, 0.05),
    ("accel_bias:x=0.1,y=-0.08,z=0.15", "accel_bias", "b_az", 0.15, 0.05),
    ("imu_misalignment:roll=2,pitch=-1.5,yaw=0", "imu_misalignment", "m_roll", math.radians(2.0), 0.05),
]
#: one effect in the check loop (the motors' dynamics: the cheapest of the rig's to find); the rest
#: with the slow tests (``make test``)
IN_CHECK = {"motor_lag"}


#: what an effect moves besides its own constant
ALSO = {"motor_constant": {"equilibrium_voltage"}}


@pytest.mark.parametrize(
    "effect,name,param,truth,rel",
    [pytest.param(*x, id=x[1], marks=() if x[1] in IN_CHECK else pytest.mark.slow) for x in INJECTED],
)
def test_each_effect_is_found_with_its_size_and_nothing_else(tmp_path, effect, name, param, truth, rel):
    d = diagnosed(simulate(tmp_path, "--undeclared", effect))
    found = claimed(d)
    assert name in found, f"{name} not claimed: {list(found)}"
    assert set(found) - PHYSICS - {name} - ALSO.get(name, set()) == set(), found
    assert d.search.final.values[param] == pytest.approx(truth, rel=rel)
    # the model with it predicts the encoders better than the lab's
    before, after = d.prediction
    assert sum(after.rms.values()) < sum(before.rms.values())


@pytest.mark.slow
def test_near_the_linearisation_point_nothing_is_claimed(tmp_path):
    for seed in (1, 2):
        d = diagnosed(simulate(tmp_path, flight="small", seed=seed))
        assert claimed(d) == {}, seed


@pytest.mark.slow
def test_far_from_it_the_full_equations_and_nothing_else(tmp_path):
    d = diagnosed(simulate(tmp_path, flight="large", seed=3, seconds=90))
    found = claimed(d)
    assert set(found) == PHYSICS
    fin = d.search.final.values
    assert fin["w_e"] == pytest.approx(1.0, abs=0.1) and fin["w_l"] == pytest.approx(1.0, abs=0.1)
    before, after = d.prediction
    assert after.rms["lambda"] < 0.2 * before.rms["lambda"] and after.rms["e"] < 0.5 * before.rms["e"]


@pytest.mark.slow
def test_the_kalman_filter_shows_an_imu_effect_and_its_correction(tmp_path):
    d = diagnosed(simulate(tmp_path, "--undeclared", "gyro_bias:x=0.01,y=-0.008,z=0.005"), with_kalman=True)
    assert d.nis is not None
    before, after = d.nis
    assert before["encoders"] > 1.5 and after["encoders"] < 1.2
    assert abs(after["gyro"] - 1.0) < 0.5 and abs(after["accel"] - 1.0) < 0.5


@pytest.mark.slow
def test_the_command_line_writes_the_rig_file_and_the_loop_closes_on_it(tmp_path):
    log = simulate(tmp_path, "--undeclared", "encoder_offset:p=1.0,e=-0.8", "--undeclared", "counterweight:dm=0.02")
    out = tmp_path / "diag"
    run = subprocess.run(
        [sys.executable, "-m", "groundstation", "diagnose", str(log), "--model", "heli3dof", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    assert "encoder_offset" in run.stdout and "equilibrium_voltage" in run.stdout
    j = json.loads((out / "report.json").read_text())
    assert {e["name"] for e in j["effects"]} >= {"encoder_offset", "equilibrium_voltage"}
    rig_file = out / "heli3dof_rig.json"
    rig = json.loads(rig_file.read_text())["heli3dof"]["rig"]
    assert rig["encoder_offset_deg"][0] == pytest.approx(1.0, abs=0.05)
    assert rig["V_s0"] == pytest.approx(6.907, rel=0.02)
    # the estimator takes the file (an extended filter on the rig's own constants) ...
    est = build_estimator("heli3dof", vehicle=str(rig_file))
    assert est.model.f is not None
    # ... and the diagnosis started from it (the model picked from the log: a helicopter with
    # angles, motor outputs and no height sensor is a rig) finds nothing more
    again = subprocess.run(
        [sys.executable, "-m", "groundstation", "diagnose", str(log), "--out",
         str(tmp_path / "again"), "--vehicle", str(rig_file)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert again.returncode == 0, again.stderr
    second = json.loads((tmp_path / "again" / "report.json").read_text())
    assert second["model"] == "heli3dof" and second["effects"] == []


@pytest.mark.slow
def test_a_log_without_encoders_and_a_rig_that_never_flew_are_one_line_errors(tmp_path):
    quad = tmp_path / "quad.tlog"
    subprocess.run(
        [sys.executable, "-m", "groundstation", "sim", "--fast", "--duration", "20", "--log", str(quad)],
        check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    for path, words in ((quad, "reads a rig's encoders"), (simulate(tmp_path, seconds=3), "flew free for")):
        run = subprocess.run(
            [sys.executable, "-m", "groundstation", "diagnose", str(path), "--model", "heli3dof", "--out",
             str(tmp_path / "x")],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert run.returncode == 2 and words in run.stderr and "Traceback" not in run.stderr, run.stderr
        assert len(run.stderr.strip().splitlines()) == 1


def test_the_controllers_on_the_rig_constants_split_for_its_motors_and_hold_it_level():
    rig = Heli3dofRig(K_f=0.1373, V_s0=5.79, a=0.05, w_e=1.0)
    c = PitchPD.place(4.0, 1.0, rig=rig)
    level = {"p": 0.0, "p_dot": 0.0, "e": 0.0, "e_dot": 0.0}
    V_f, V_b = c.update(level, {"p_c": 0.0, "e_c": 0.0}, 0.01).command
    # equal thrusts whose sum holds the rig: K_f (1 - a) V_f = K_f (1 + a) V_b, summing to K_f V_s0
    assert V_f * 0.95 == pytest.approx(V_b * 1.05) and V_f * 0.95 + V_b * 1.05 == pytest.approx(5.79)
    # where it stands at e = 0.3 (and p = 0.2) the lift that holds it is V_s0 cos(e) / cos(p)
    tilted = {**level, "e": 0.3, "p": 0.2}
    out = c.update(tilted, {"p_c": 0.2, "e_c": 0.3}, 0.01)
    V_f, V_b = out.command
    assert V_f * 0.95 + V_b * 1.05 == pytest.approx(5.79 * math.cos(0.3) / math.cos(0.2))
    # the gains are designed on its K_f
    assert c.K_pp == pytest.approx(PitchPD.place(4.0, 1.0, K_f=0.1373).K_pp)


def test_the_control_station_builds_every_rig_controller_on_the_rig_file(tmp_path):
    rig = Heli3dofRig(K_f=0.13, V_s0=6.0, a=0.02)
    path = tmp_path / "rig.json"
    path.write_text(json.dumps({"heli3dof": {"rig": rig.as_vehicle()}}))
    loaded = rig_constants(str(path))
    assert loaded == rig
    station = ControlStation("heli3dof", None, rig=loaded)
    for name in station.controllers:
        station.select(controller=name)
        c = station.commander.controller
        assert c.V_s0 == 6.0 and c.a == 0.02, name


def test_on_a_rig_unlike_table_1_its_own_constants_hold_the_pitch_step():
    effects = ["counterweight:dm=0.03", "motor_constant:s=0.1", "motor_asymmetry:a=0.05"]
    # the rig those effects make (V_s0 = (2 l_h m_p - l_c m_c) g / (l_h K_f))
    K_f = 0.1248 * 1.1
    rig = Heli3dofRig(K_f=K_f, V_s0=(2 * 0.66 * 0.72 - 0.46 * 1.95) * 9.81 / (0.66 * K_f), a=0.05, w_e=1.0)
    err = {}
    for which, kw in (("lab", {}), ("rig", {"rig": rig})):
        f = fly(
            Scenario("heli3dof", seed=22, undeclared=[parse_effect(e) for e in effects]),
            PitchPD.place(4.0, 1.0, **kw),
            FEEDBACK_3DOF["encoders"](),
            seconds=12.0,
            reference=lambda t: {"p_c": 0.3 if t >= 6.0 else 0.0, "e_c": 0.0},
        )
        last = f.t >= f.t[-1] - 2.0
        err[which] = (abs(np.mean(f.truth["p"][last]) - 0.3), abs(np.mean(f.truth["e"][last])))
    assert err["rig"][0] < 0.2 * err["lab"][0] and err["rig"][1] < 0.2 * err["lab"][1], err


@pytest.mark.slow
def test_the_live_panel_diagnoses_a_rig_window_as_the_command_line_does(tmp_path):
    log = load_log(simulate(tmp_path, "--undeclared", "gyro_bias:x=0.01,y=-0.008,z=0.005"), tables=False)
    buffer = SessionBuffer()  # the IMU averaged into 10 ms blocks, as the dashboard keeps a session
    for m in log.measurements:
        buffer.add(m)
    j = diagnose_window(buffer.window(60.0), "heli3dof")
    assert j["model"] == "heli3dof" and "gyro_bias" in {e["name"] for e in j["effects"]}
    text = markdown(j, 60.0)
    assert "model heli3dof" in text and "gyro_bias" in text
    # a window of a multirotor's session is one line, not a traceback in the worker
    assert "error" in diagnose_window(buffer.window(60.0)[:50], "heli3dof")
    assert "heli3dof" in DIAGNOSIS_MODELS
