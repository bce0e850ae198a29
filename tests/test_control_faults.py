"""Control never acts on a non-finite or implausible value: the real commander, controllers and
feedback flying the simulated vehicle through faults injected on the wire (a MAVLink frame
re-packed with a NaN, as a damaged sensor or a buggy autopilot sends one)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundstation.app.offline_flight import fly
from groundstation.control.commander import Commander
from groundstation.control.controllers import AltitudeHold, LQRIntegral, PitchPD
from groundstation.control.feedback import EncoderFeedback, EstimatorFeedback
from groundstation.control.uplink import AttitudeTarget
from groundstation.estimation.routing import altitude_estimator
from sim_bridge.scenario import Scenario


def test_the_controllers_pass_a_nan_through_instead_of_clamping_it_to_a_command():
    """Python's min and max drop NaN: a NaN height became a collective of 0.277 and a NaN pitch
    8 V on one motor. Clamped NaN-aware, the command is NaN, which the commander refuses."""
    assert math.isnan(AltitudeHold().update({"z": math.nan, "vz": 0.0}, {"z_c": 1.0}, 0.01).command[0])
    assert math.isnan(AltitudeHold().update({"z": 1.0, "vz": 0.0, "pitch": math.nan}, {"z_c": 1.0}, 0.01).command[0])
    pd = PitchPD.place(4.0, 1.0).update(
        {"p": math.nan, "p_dot": 0.0, "e": 0.0, "e_dot": 0.0}, {"p_c": 0, "e_c": 0}, 0.01
    )
    assert np.isnan(pd.command).all()
    lqr = LQRIntegral()
    out = lqr.update({"p": 0.0, "p_dot": math.nan, "e_dot": 0.0}, {"p_c": 0.0, "e_dot_c": 0.0}, 0.01)
    assert np.isnan(out.command).all()


class _Sink:
    def __init__(self) -> None:
        self.sent = []

    def send(self, msg) -> None:
        self.sent.append(msg)


@pytest.mark.parametrize(
    "state, reason",
    [
        ({"z": math.nan, "vz": 0.0}, "z = nan is not finite"),
        ({"z": 1.0, "vz": 0.0, "pitch": math.nan}, "pitch = nan is not finite"),
        ({"z": 1.0, "vz": 0.0, "roll": 3.1}, "roll = 3.1 is outside its plausible range"),
        ({"z": 1.0, "vz": 0.0, "alpha": -4.0}, "alpha = -4 is outside its plausible range"),
    ],
)
def test_a_bad_state_disarms_at_the_next_tick_with_its_value_named(state, reason):
    class Fixed(EstimatorFeedback):
        def __init__(self):
            self.name, self.kinds, self.x = "fixed", frozenset(), {"z": 1.0, "vz": 0.0}

        def state(self):
            return dict(self.x)

    fb, sink, now = Fixed(), _Sink(), [0.0]
    cmd = Commander(AltitudeHold(), fb, AttitudeTarget(sink), clock=lambda: now[0])
    cmd._last_rx, cmd._t_vehicle = 0.0, 0.0  # a live link just delivered a reading
    cmd.arm()
    assert cmd.tick() is not None and len(sink.sent) == 1
    fb.x = state
    assert cmd.tick() is None and not cmd.armed and len(sink.sent) == 1
    assert reason in cmd.status, cmd.status
    assert "fixed feedback" in cmd.arm_refusal()  # and it cannot be armed on it again


def _tampered(msg_name: str, field: str, value: float, after: float):
    """A tamper that re-packs the first ``msg_name`` frame sent after ``after`` s with ``field`` set."""
    parser = mavlink.MAVLink(None)
    packer = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    done = []

    def tamper(frame: bytes, t: float) -> bytes:
        if done or t < after:
            return frame
        try:
            msgs = parser.parse_buffer(frame) or []
        except mavlink.MAVError:  # not a MAVLink frame (the 3-DOF rig's board protocol)
            return frame
        if len(msgs) != 1 or msgs[0].get_type() != msg_name:
            return frame
        msg = msgs[0]
        setattr(msg, field, value)
        packer.seq = msg.get_seq()
        done.append(t)
        return bytes(msg.pack(packer))

    return tamper, done


def _hold(tamper, seconds: float = 14.0):
    fb = EstimatorFeedback(altitude_estimator())
    f = fly(
        Scenario("quad", seed=5),
        AltitudeHold(),
        fb,
        seconds=seconds,
        arm_at=1.0,
        reference=lambda t: {"z_c": 1.0},
        tamper=tamper,
    )
    commands = f.command()
    assert np.all(np.isfinite(commands)) and np.all((commands >= 0.0) & (commands <= 1.0))
    return f, fb


@pytest.mark.parametrize("message, field", [("HIGHRES_IMU", "yacc"), ("ATTITUDE", "pitch")])
def test_one_nan_frame_is_rejected_and_the_altitude_hold_flies_on(message, field):
    """The quad holds 1 m on the altitude filter; one frame with a NaN arrives at 8 s. The reading is
    rejected and counted (with it the filter went NaN, and the NaN, laundered by min and max, became a
    collective of 0.277 while armed: the quad fell; or, as a tilt, full throttle: it climbed to 5.3 m),
    and the hold flies on at its reference."""
    tamper, when = _tampered(message, field, math.nan, 8.0)
    f, fb = _hold(tamper)
    assert when, "the fault was never injected"
    assert f.armed[-1], [text for _, text in f.history]
    if message == "HIGHRES_IMU":
        assert fb.estimator.counters.skipped.get("accel_not_finite") == 1
    h = f.truth["h"][f.t > when[0] + 1.0]
    assert abs(h.mean() - 1.0) < 0.05 and h.min() > 0.8, (h.min(), h.max())


def test_a_vehicle_upside_down_disarms_the_altitude_hold_at_once():
    """A state the controller cannot fly on (a roll of 3 rad from the autopilot's attitude: the
    vehicle reads upside down) disarms before any command is computed from it, with the value named;
    the vehicle, no longer commanded, is flown by its own autopilot again."""
    tamper, when = _tampered("ATTITUDE", "roll", 3.0, 8.0)
    f, _ = _hold(tamper)
    assert when
    disarm = [text for _, text in f.history if text.startswith("disarmed")]
    assert disarm and "roll = 3 is outside its plausible range" in disarm[0], f.history
    after = [r for r in f.records if r.t > when[0] + 0.011]
    assert not after, f"{len(after)} commands sent after the fault"
    h = f.truth["h"][f.t > when[0]]
    assert h.min() > 0.3 and h.max() < 3.0, (h.min(), h.max())


def test_an_encoder_glitch_disarms_the_3dof_rig_before_the_motors_see_it():
    """The 3-DOF rig on its encoders: one ENCODERS frame (valid CRC) whose pitch count jumps by
    10 000 (a counter glitch, a bad cable) reads the arm far past anything it can reach, at a rate
    of hundreds of rad/s. The PD disarms at the next tick, naming the value; no motor command
    follows it."""
    from drivers import board_protocol as bp

    done = []

    def glitch(frame: bytes, t: float) -> bytes:
        if done or t < 3.0 or frame[:2] != bp.SYNC or frame[3] != bp.ENCODERS:
            return frame
        t_us, p, e, lam, cpr = bp.PAYLOADS[bp.ENCODERS][1].unpack(frame[6 : 6 + frame[5]])
        done.append(t)
        return bp.frame(bp.ENCODERS, frame[4], bp.PAYLOADS[bp.ENCODERS][1].pack(t_us, p + 10_000, e, lam, cpr))

    f = fly(
        Scenario("heli3dof", seed=1), PitchPD.place(4.0, 1.0), EncoderFeedback(), seconds=5.0, arm_at=0.5, tamper=glitch
    )
    assert done, "the glitch was never injected"
    disarm = [text for _, text in f.history if text.startswith("disarmed")]
    assert disarm and "outside its plausible range" in disarm[0], f.history
    assert not [r for r in f.records if r.t > done[0] + 0.011]
