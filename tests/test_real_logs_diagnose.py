"""Every flight log of ../shared/data/real diagnosed end to end by the command line, as a pilot runs
it: ``groundstation diagnose LOG`` with nothing else said. Each exits 0 with a report; the model is
the one the vehicle and the log's readings allow, and a log no model describes or feeds says why
in its report and writes no parameter."""

import json
import subprocess
import sys

import pytest

from drivers.mavlink.param_ranges import outside

from .conftest import real_file

#: log -> (the model chosen, or None for a report of the triage alone; an effect it must name)
EXPECTED = {
    "ardupilot_dataflash/ardupilot_loganalyzer_underpowered.log": ("quad_thrust", "thrust_voltage"),
    "ardupilot_dataflash/ardupilot_loganalyzer_mechanical_fail.log": ("quad_thrust", None),
    "ardupilot_dataflash/erle_pxf_copter_Loiter_RTL.bin": ("altitude", None),
    "ardupilot_dataflash/pyflightcoach_pilot_0004.BIN": (None, None),  # a plane carried on the ground: no IMU, no baro
    "mavlink_tlog/dronekit_flight_replay_flight.tlog": ("altitude", None),
    "mavlink_tlog/ardusub_small.tlog": (None, None),  # a submarine
    "crazyflie_util/0425-traj4": ("altitude", None),
    "crazyflie_util/0425-traj6": ("altitude", None),
    "crazyflie_util/0422-log00": ("altitude", None),
}


@pytest.mark.slow
@pytest.mark.parametrize("rel", sorted(EXPECTED))
def test_every_real_log_diagnoses_end_to_end(rel, tmp_path):
    log = real_file(rel)
    out = tmp_path / "report"
    r = subprocess.run(
        [sys.executable, "-m", "groundstation", "diagnose", str(log), "--out", str(out), "--jobs", "1"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert "Traceback" not in r.stderr
    j = json.loads((out / "report.json").read_text())
    model, effect = EXPECTED[rel]
    assert j.get("model") == model, (j.get("model"), j.get("model_chosen"), j["conclusion"][:500])
    assert j["vehicle_type"]["kind"] != "unknown"
    if model is None:
        assert j["conclusion"].count("Not diagnosed") == 1 and not j["effects"]
        assert not (out / "params_ardupilot.param").exists() and not (out / "params_px4.params").exists()
    else:
        assert (out / "estimates_before.csv").exists() and (out / "estimates_after.csv").exists()
        for p in j.get("parameters", []):  # nothing written outside what the autopilot documents
            assert p["value"] is None or outside(p["name"], p["value"]) is None, p
    if effect is not None:
        assert effect in [e["name"] for e in j["effects"]], j["conclusion"][:1500]
    if rel.startswith("crazyflie_util/") and j["effects"]:
        # evidence a pilot without motion capture can read, checked here against the motion capture:
        # the baro-and-IMU height with the range left out improves where the baro effects are real
        (rng,) = [lo for lo in j["left_out"] if lo["sensor"] == "range"]
        assert rng["rms_after"] < rng["rms_before"]
        assert rng["height_rmse_after"] < 0.7 * rng["height_rmse_before"], rng
