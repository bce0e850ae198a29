"""The frame a log states sets which outputs are motors: an octocopter's collective is the mean of
its eight motors, not of the first four, from a DataFlash log's FRAME_CLASS or boot line and from a
ULog's rotor count and output functions."""

import io

import pytest

from drivers.logs.dataflash import read_dataflash
from drivers.logs.ulog import read_ulog
from drivers.logs.ulog_writer import UlogWriter
from groundstation.core.measurement import Kind
from groundstation.estimation.context import Context
from groundstation.estimation.routing import collective, motor_outputs_of, read_vehicle_status

#: motors 1-4 at 1600 us, 5-8 at 1400 us: 0.6 read as four outputs, 0.5 as eight
OCTO = [1600] * 4 + [1400] * 4


def collectives(measurements) -> list[float]:
    """Each ACTUATOR record's collective, read as the estimator reads it (the status first)."""
    ctx, out = Context(), []
    for m in measurements:
        if m.kind is Kind.VEHICLE_STATUS:
            read_vehicle_status(m, ctx)
        elif (c := collective(m, ctx)) is not None:
            out.append(c)
    return out


def dataflash(tmp_path, head: list[str], outputs: list[int]) -> list:
    channels = ",".join(f"C{k}" for k in range(1, len(outputs) + 1))
    lines = [
        "FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns",
        "FMT, 129, 23, PARM, QNf, TimeUS,Name,Value",
        "FMT, 130, 64, MSG, QZ, TimeUS,Message",
        f"FMT, 131, 40, RCOU, Q{'H' * len(outputs)}, TimeUS,{channels}",
        "FMT, 132, 20, CTUN, Qf, TimeUS,ThO",
        *head,
    ]
    for k in range(10):
        us = 1_000_000 + 100_000 * k
        lines += [f"RCOU, {us}, " + ", ".join(map(str, outputs)), f"CTUN, {us}, 0.3"]
    p = tmp_path / "frame.log"
    p.write_text("\n".join(lines) + "\n")
    return read_dataflash(p).measurements


@pytest.mark.parametrize(
    "head",
    [["PARM, 1000, FRAME_CLASS, 3"], ["MSG, 1000, Frame: OCTA/X"], ["PARM, 1000, FRAME_CLASS, 4"]],
    ids=["FRAME_CLASS octa", "boot line", "FRAME_CLASS octaquad"],
)
def test_an_octocopters_dataflash_collective_is_all_eight_motors(tmp_path, head):
    ms = dataflash(tmp_path, head, OCTO)
    assert ms[0].kind is Kind.VEHICLE_STATUS and ms[0].t == ms[1].t  # from the log's first sample
    assert motor_outputs_of(ms) == 8
    assert collectives(ms) == pytest.approx([0.5] * 10)


def test_a_frame_whose_first_outputs_are_not_motors_is_left_to_the_default(tmp_path):
    """A coaxial copter's outputs 1-4 are fins (its rotors on 5 and 6); no frame stated: four."""
    for head in (["PARM, 1000, FRAME_CLASS, 9"], []):
        ms = dataflash(tmp_path, head, OCTO)
        assert not any(m.kind is Kind.VEHICLE_STATUS for m in ms)
        assert collectives(ms) == pytest.approx([0.6] * 10)


def ulog(tmp_path, params: dict[str, float], outputs: list[float], system_type: int) -> list:
    w = UlogWriter(buf := io.BytesIO())
    w.define("actuator_outputs", "uint64_t timestamp;uint32_t noutputs;float[16] output")
    w.define("vehicle_status", "uint64_t timestamp;uint8_t arming_state;uint8_t system_type")
    w.info("sys_name", "PX4")
    for name, value in params.items():
        w.parameter(name, value)
    w.add("actuator_outputs")
    w.add("vehicle_status")
    w.write("vehicle_status", 500_000, 2, system_type)
    for k in range(10):
        w.write("actuator_outputs", 1_000_000 + 100_000 * k, len(outputs), *outputs, *[0.0] * (16 - len(outputs)))
    p = tmp_path / "frame.ulg"
    p.write_bytes(buf.getvalue())
    return read_ulog(p).measurements


def test_a_px4_octocopters_collective_is_its_rotor_count_of_outputs(tmp_path):
    """CA_ROTOR_COUNT says eight though the vehicle announces itself a quad (MAV_TYPE 2)."""
    ms = ulog(tmp_path, {"CA_ROTOR_COUNT": 8}, [float(x) for x in OCTO], system_type=2)
    assert motor_outputs_of(ms) == 8
    assert collectives(ms) == pytest.approx([0.5] * 10)


def test_px4s_output_functions_pick_the_motors_from_among_servos(tmp_path):
    """A servo on output 1 (function 201) and six motors on outputs 2-7 (101-106): the collective is
    the motors' mean; the servo's 1900 us is not in it."""
    params = {"CA_ROTOR_COUNT": 6, "PWM_MAIN_FUNC1": 201, **{f"PWM_MAIN_FUNC{n}": 99 + n for n in range(2, 8)}}
    outputs = [1900.0, 1500.0, 1500.0, 1500.0, 1300.0, 1300.0, 1300.0]
    ms = ulog(tmp_path, params, outputs, system_type=13)
    assert collectives(ms) == pytest.approx([0.4] * 10)
    assert [m for m in ms if m.kind is Kind.ACTUATOR][0].value.tolist() == pytest.approx([0.5] * 3 + [0.3] * 3)


def test_px4s_motor_range_is_read_from_the_first_motors_output():
    """The stated range is the first motor's output's (PWM_MAIN_FUNC2 = 101), not output 1's servo."""
    from groundstation.estimation.stated import motor_curve

    params = {"THR_MDL_FAC": 0.3, "PWM_MAIN_FUNC1": 201, "PWM_MAIN_FUNC2": 101, "PWM_MAIN_MIN1": 800}
    curve = motor_curve({**params, "PWM_MAIN_MIN2": 1100, "PWM_MAIN_MAX2": 1950})
    assert curve is not None and (curve.low, curve.high) == pytest.approx((0.1, 0.95))


@pytest.mark.parametrize("rel", ["clean_s1.bin", "clean_s2.ulg"])
def test_the_triage_weighs_a_hexacopters_six_motors(rel):
    """Another generator's hexacopter: FRAME_CLASS 2 in the .bin, CA_ROTOR_COUNT 6 in the .ulg."""
    from groundstation.diagnosis.triage.motors import _motor_count
    from groundstation.estimation.logs import load_log

    from .conftest import foreign2_file

    loaded = load_log(foreign2_file(rel), imu_columns=True)
    assert _motor_count(loaded.tables) == 6 and motor_outputs_of(loaded.measurements) == 6
