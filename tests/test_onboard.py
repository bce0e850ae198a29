"""The simulated vehicle's autopilot: the ArduPilot parameters a diagnosis writes, kept within
their documented ranges, and the height estimate it makes with them (what it sends as
GLOBAL_POSITION_INT): wrong by the rotor wash its barometer reads until BARO1_THST_SCALE is set,
right after."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.logs.dataflash import read_dataflash
from groundstation.core.measurement import Kind
from sim_bridge.autopilot_params import AutopilotParams
from sim_bridge.bridge import SimBridge
from sim_bridge.scenario import Scenario
from sim_bridge.simulator import Sample

RHO_G = 1.225 * 9.80665  # [Pa/m] the air's weight per metre near sea level


def test_a_value_outside_its_documented_range_or_not_a_number_is_refused():
    p = AutopilotParams()
    assert p.set("BARO1_THST_SCALE", -35.0) and p["BARO1_THST_SCALE"] == -35.0
    assert not p.set("BARO1_THST_SCALE", 301.0) and not p.set("EK3_HGT_DELAY", math.nan)
    assert not p.set("INS_ACCSCAL_Z", 1.3) and p["INS_ACCSCAL_Z"] == 1.0
    assert p.set("MOT_BAT_VOLT_MAX", 0.0) and not p.set("MOT_BAT_VOLT_MAX", 3.0)  # 0 disables it


def _height_error(scale: float, k: float = 3.0, **params: float) -> tuple[float, float]:
    """The onboard estimate's and its baro's RMS error in the air [m] on the standard flight, with
    the rotor wash k [m per unit throttle] on the baro and BARO1_THST_SCALE = ``scale``."""
    br = SimBridge(Scenario.from_args("quad", 3, 40.0, [], [f"baro_thrust:k={k}"]), udp_to=("127.0.0.1", 9))
    br.autopilot.set("BARO1_THST_SCALE", scale)
    for name, value in params.items():
        assert br.autopilot.set(name, value)
    est, baro = [], []
    while br.sim.t < 40.0:
        br._tick(br.sim.t + 0.1)
        h = br.sim.vehicle.kin.height
        if h > 0.5:
            est.append(br.onboard.height - h)
            baro.append(br.onboard.baro_height - h)
    return float(np.sqrt(np.mean(np.square(est)))), float(np.sqrt(np.mean(np.square(baro))))


@pytest.mark.slow
def test_the_thrust_scale_takes_the_rotor_wash_out_of_the_vehicles_own_height():
    wrong, _ = _height_error(0.0)
    right, baro = _height_error(-RHO_G * 3.0)
    clean, _ = _height_error(0.0, k=0.0)
    assert wrong > 1.0  # about k times the hover throttle
    assert right < 0.3 * wrong and right < 2.0 * clean + 0.05
    assert baro < 0.5  # the corrected baro itself is back on the truth


def test_the_accelerometer_calibration_is_what_the_vehicle_logs_and_sends(tmp_path):
    br = SimBridge(Scenario("quad", seed=3), udp_to=("127.0.0.1", 9))
    assert br.autopilot.set("INS_ACCOFFS_Z", 0.5) and br.autopilot.set("INS_ACCSCAL_Z", 1.1)
    sample = br._onboard(Sample(3.0, "imu", (0.1, 0.2, -9.5, 0.0, 0.0, 0.0)))
    assert sample.values[:3] == pytest.approx((0.1, 0.2, (-9.5 - 0.5) * 1.1))  # ArduPilot: (raw - offset) * scale
    raw: list[float] = []
    step = br.sim.step

    def stepped():
        out = step()
        raw.extend(s.values[2] for s in out if s.sensor == "imu" and s.t > 2.0 - 1e-9)
        return out

    br.sim.step = stepped
    br._tick(4.0)  # armed at 2 s: the log holds the corrected readings
    br.flight_logs.close()
    f = tmp_path / "cal.bin"
    f.write_bytes(br.flight_logs.logs[1].data)
    az = [m.value[2] for m in read_dataflash(f).measurements if m.kind is Kind.ACCEL]
    assert len(az) == len(raw) > 500
    assert az == pytest.approx([(a - 0.5) * 1.1 for a in raw], abs=1e-5)
