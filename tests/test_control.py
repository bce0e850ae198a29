"""Control in the loop: designs against their equations, then closed loops over real transports.

The live tests run the simulated vehicle in real time on a real pseudo-terminal
(the 3-DOF helicopter's motor board) or real UDP sockets (MAVLink), the ground
station's own link, commander, controller and feedback, and wait on what the
loop publishes, never on sleeps.
"""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest
from scipy import signal

from drivers import board_protocol as bp
from drivers.board import BinaryBoardReceiver, BoardLink
from drivers.link_state import LinkState
from drivers.mavlink.link import MavlinkLink
from groundstation.app.offline_flight import fly
from groundstation.control import design
from groundstation.control.commander import ArmRefused, Commander
from groundstation.control.controllers import (
    COAX_THRUST,
    AltitudeHold,
    LQRFeedForward,
    LQRIntegral,
    PitchPD,
    motor_voltages,
)
from groundstation.control.feedback import (
    EncoderFeedback,
    EstimatorFeedback,
    KalmanFeedback,
)
from groundstation.control.response import classify, step_fit
from groundstation.control.uplink import AttitudeTarget, BoardMotors
from groundstation.core.measurement import Kind
from groundstation.estimation.routing import altitude_estimator
from sim_bridge.bridge import MAX_CATCH_UP, TICK, SimBridge
from sim_bridge.effects import parse_effect
from sim_bridge.pty_port import PtyPort
from sim_bridge.scenario import Scenario

from .conftest import async_test, free_udp_port

# -- designs against the document's equations ----------------------------------------------------


def test_lqr_matches_the_closed_form_of_a_double_integrator():
    """Pitch is a double integrator p_dd = K1 V_d: with Q = diag(q1, q2), R = r the
    Riccati solution is K = (sqrt(q1/r), sqrt(q2/r + 2 sqrt(q1/r) / K1))."""
    K1, K2 = design.k1_k2()
    c = LQRFeedForward(np.diag([20.0, 10.0, 30.0]), np.eye(2))
    assert c.K[1, 0] == pytest.approx(np.sqrt(20.0))
    assert c.K[1, 1] == pytest.approx(np.sqrt(10.0 + 2 * np.sqrt(20.0) / K1))
    assert c.K[0, 2] == pytest.approx(np.sqrt(30.0))  # e_dot: a single integrator, K = sqrt(q/r)
    A, B, C = design.pitch_model()
    # eq. 36-37: at equilibrium y = r
    r = np.array([0.1, -0.05])
    x_ss = np.linalg.solve(A - B @ c.K, -B @ c.F @ r)
    assert C @ x_ss == pytest.approx(r)


def test_integral_lqr_is_stable_and_its_feedforward_cancels_the_integrators():
    c = LQRIntegral()
    A, B, R_ref = design.integral_model()
    assert np.all(np.linalg.eigvals(A - B @ c.K).real < 0)
    # eq. 43: C (BK - A)^-1 R_ref = I, whatever F
    C = np.zeros((2, 5))
    C[0, 0] = C[1, 2] = 1.0
    assert C @ np.linalg.solve(B @ c.K - A, R_ref) == pytest.approx(np.eye(2))


def test_pole_placement_puts_the_poles_where_asked():
    K1, _ = design.k1_k2()
    for w, z in [(4.0, 1.0), (7.39, 0.92), (5.2, 0.0)]:
        pd = PitchPD.place(w, z)
        poles = np.roots([1.0, K1 * pd.K_pd, K1 * pd.K_pp])  # eq. 22-23
        assert np.abs(poles) == pytest.approx([w, w])
        assert design.omega_zeta(K1, pd.K_pp, pd.K_pd) == pytest.approx((w, z))
    pd = PitchPD.from_poles(-17.1, -3.2)
    assert np.sort(np.roots([1.0, K1 * pd.K_pd, K1 * pd.K_pp]).real) == pytest.approx([-17.1, -3.2])


def test_responses_are_named_as_the_lab_names_them():
    t = np.linspace(0.0, 8.0, 801)
    names = []
    for zeta in (0.0, 0.5, 1.0, 1.38):
        _, y = signal.step(signal.lti([16.0], [1.0, 8.0 * zeta, 16.0]), T=t)
        names.append(classify(t + 1.0, 0.2 * y, 1.0, 0.0, 0.2))
    growing = 0.2 - 0.2 * np.exp(0.15 * t) * np.cos(4 * t)  # stays within the limit, grows
    names.append(classify(t, growing, 0.0, 0.0, 0.2))
    assert names == ["undamped", "underdamped", "critically damped", "overdamped", "unstable"]
    w, z, _ = step_fit(t + 1.0, 0.2 * signal.step(signal.lti([16.0], [1.0, 5.6, 16.0]), T=t)[1], 1.0, 0.0, 0.2)
    assert (w, z) == pytest.approx((4.0, 0.7), rel=0.02)


def test_saturation_keeps_lift_first():
    cmd, u, sat = motor_voltages(0.0, 20.0)  # V_s = 8 V: |V_d| <= 8
    assert sat and u[1] == pytest.approx(8.0) and cmd == pytest.approx([0.0, 8.0])
    cmd, u, sat = motor_voltages(20.0, 1.0)  # V_s clipped to 24 V, no room for V_d
    assert sat and cmd == pytest.approx([12.0, 12.0])
    cmd, u, sat = motor_voltages(0.5, -1.0)
    assert not sat and cmd == pytest.approx([4.75, 3.75])


# -- fast closed loops (same bytes, simulator stepped as fast as it goes) -----------------------


def _pitch_step(t):
    return {"p_c": 0.1 if t >= 5.0 else 0.0, "e_dot_c": 0.0}


def test_integral_action_removes_a_constant_disturbance_the_plain_lqr_cannot():
    sc = Scenario("heli3dof", seed=3, undeclared=[parse_effect("motor_offset:front=0.4,back=-0.4")])
    errors = {}
    for c in (LQRFeedForward(), LQRIntegral(np.diag([30.0, 10.0, 10.0, 10.0, 10.0]))):
        f = fly(sc, c, EncoderFeedback(), seconds=25.0, reference=_pitch_step)
        late = f.t > 18.0
        errors[c.name] = float(np.mean(f.truth["p"][late]) - 0.1)
    assert abs(errors["lqr"]) > 0.05  # 0.8 V of imbalance against K's pitch gain
    assert abs(errors["lqr_i"]) < 0.005


def test_anti_windup_freezes_the_integrators_while_saturated_and_lets_them_unwind():
    """An arm held against its stop (p_c far beyond reach) saturates V_d: the
    integrators must not wind up; once the error reverses they move again."""
    x = {"p": 1.2, "p_dot": 0.0, "e_dot": 0.0}
    held = {"p_c": 3.0, "e_dot_c": 0.0}
    with_aw, without = LQRIntegral(), LQRIntegral(anti_windup=False)
    for _ in range(500):
        assert with_aw.update(x, held, 0.01).saturated
        without.update(x, held, 0.01)
    assert with_aw.z[0] == 0.0 and without.z[0] == pytest.approx(-without.integral_limit)
    with_aw.update(x, {"p_c": 0.0, "e_dot_c": 0.0}, 0.01)  # error reversed: it unwinds
    assert with_aw.z[0] > 0.0
    # the altitude hold, on the ground with its collective at the top
    hold = AltitudeHold()
    for _ in range(300):
        out = hold.update({"z": 0.0, "vz": 0.0, "alpha": 5.0}, {"z_c": 10.0}, 0.01)
    assert out.saturated and hold.i == 0.0


@pytest.mark.parametrize("vehicle,thrust", [("quad", None), pytest.param("coax", COAX_THRUST, marks=pytest.mark.slow)])
def test_altitude_hold_flies_the_altitude_filter_to_the_reference(vehicle, thrust):
    c = AltitudeHold(thrust) if thrust else AltitudeHold()
    f = fly(
        Scenario(vehicle, seed=5),
        c,
        EstimatorFeedback(altitude_estimator()),
        seconds=25.0,
        arm_at=1.0,
        reference=lambda t: {"z_c": 1.0 if t < 12.0 else 1.8},
    )
    h = f.truth["h"]
    assert abs(np.mean(h[(f.t > 9) & (f.t < 12)]) - 1.0) < 0.05
    assert abs(np.mean(h[f.t > 21]) - 1.8) < 0.05
    assert f.armed[-1]


# -- live, over the real transports --------------------------------------------------------------


class _Live:
    """A live loop: the simulated vehicle, the ground station's link and commander, each
    task stopped on exit; waits are on what the loop publishes."""

    #: [s] of the wall clock the simulated vehicle catches up at once (SimBridge.run)
    catch_up = MAX_CATCH_UP

    async def _start(self, link, commander) -> None:
        """The bridge is open already (a pty must exist before the link opens it)."""
        self.link, self.cmd = link, commander
        sub = link.measurements()
        self.records = commander.records.subscribe()
        await link.open()
        self.tasks = [
            asyncio.create_task(self.bridge.run(catch_up=self.catch_up)),
            asyncio.create_task(commander.run()),
            asyncio.create_task(commander.follow(sub)),
        ]

    async def __aexit__(self, *exc):
        self.cmd.stop()
        self.bridge.close()
        await self.link.close()
        await asyncio.gather(*self.tasks)

    async def measurements(self, n):
        """Wait for n more measurements from the link."""
        sub = self.link.measurements()
        try:
            k = 0
            async for _ in sub:
                k += 1
                if k >= n:
                    return
        finally:
            sub.close()

    async def until(self, cond, timeout=15.0):
        """Wait on the commander's records until cond(record) holds."""

        async def go():
            async for rec in self.records:
                if cond(rec):
                    return rec

        return await asyncio.wait_for(go(), timeout)


class Live3dof(_Live):
    """The simulated 3-DOF rig on a pty; the ground station's board link, commander and feedback.
    The rig catches up one tick at a time (SimBridge.run's ``catch_up``): its step responses are
    measured against their design, and 20 ms at a time on a loaded machine (3 workers on 2 cores)
    the PD step with a stall was fitted at omega 4.68 rad/s for the designed 4 in one run of five."""

    catch_up = TICK

    def __init__(self, tmp_path, controller, feedback, scenario=None):
        self.port = PtyPort(tmp_path / "ttyMOTORS")
        self.bridge = SimBridge(scenario or Scenario("heli3dof", seed=1), udp_to=None, board=self.port)
        self.truth: list[dict] = []
        self.bridge.truth_sink = self.truth.append
        self.controller, self.feedback = controller, feedback

    async def __aenter__(self):
        await self.bridge.open()
        link = BoardLink(f"{self.port.path},921600", "binary", lost_after=0.3)
        await self._start(link, Commander(self.controller, self.feedback, BoardMotors(link), link=link))
        return self

    async def arm(self):
        while self.cmd.arm_refusal() is not None:
            await self.next_record_or_data()
        self.cmd.arm()

    async def next_record_or_data(self):
        await asyncio.wait_for(self.measurements(1), 5.0)


@pytest.mark.slow
@pytest.mark.parametrize("stall", [None, 0.5])
@async_test(timeout=60)
async def test_live_pd_step_response_matches_the_designed_omega_and_zeta(tmp_path, stall):
    """``stall``: the whole process (rig and ground station) blocked for 0.2 s this far into the step,
    as a loaded machine does. The rig pauses with it (SimBridge.run); when it ran on, on the last
    command, the step was fitted at omega 5.72 rad/s, zeta 1.06 in one run of three, and zeta 13-14 %
    low in the others (CI once failed at omega 5.35)."""
    w0, z0 = 4.0, 0.7
    async with Live3dof(tmp_path, PitchPD.place(w0, z0), EncoderFeedback()) as live:
        await live.arm()
        # lift off the table and settle level
        await live.until(
            lambda r: abs(r.state["e"]) < 0.02 and abs(r.state["e_dot"]) < 0.02 and abs(r.state["p"]) < 0.005
        )
        t_step = live.bridge.sim.t
        live.cmd.set_reference(p_c=0.15)
        stalled = []

        def done(r):
            if stall is not None and not stalled and live.bridge.sim.t > t_step + stall:
                stalled.append(live.bridge.sim.t)
                time.sleep(0.2)  # blocks the event loop: every task stalls
            return live.bridge.sim.t > t_step + 3.0

        await live.until(done)
        assert live.cmd.armed and len(stalled) == (stall is not None)
    tr = {k: np.array([row[k] for row in live.truth]) for k in ("t", "p")}
    w, z, _ = step_fit(tr["t"], tr["p"], t_step, 0.0, 0.15)
    assert w == pytest.approx(w0, rel=0.15) and z == pytest.approx(z0, rel=0.15)
    assert live.bridge.received.get("MOTORS", 0) > 200


@pytest.mark.slow
@async_test(timeout=90)
async def test_live_integral_action_removes_a_constant_disturbance(tmp_path):
    """Over the pty: the rig's motor board adds +0.4 V / -0.4 V (undeclared); the integral
    LQR holds the commanded pitch anyway, its integrator carrying the imbalance.

    The integrator's slow mode settles in a few seconds of rig time, later when the machine is
    loaded (the pty adds latency), so the test waits for the settling itself (the mean pitch of
    the last second within 3 mrad of the command), not for a fixed time after the step."""
    sc = Scenario("heli3dof", seed=3, undeclared=[parse_effect("motor_offset:front=0.4,back=-0.4")])
    c = LQRIntegral(np.diag([30.0, 10.0, 10.0, 10.0, 10.0]))

    def tail_error(since):
        t_now = live.bridge.sim.t
        tail = [row["p"] for row in reversed(live.truth[-2000:]) if row["t"] > t_now - 1.0]
        return abs(np.mean(tail) - 0.1) if t_now > since + 3.0 and tail else np.inf

    async with Live3dof(tmp_path, c, EncoderFeedback(), scenario=sc) as live:
        await live.arm()
        await live.until(lambda r: live.bridge.sim.t > 4.0)  # off the table
        live.cmd.set_reference(p_c=0.1)
        t0 = live.bridge.sim.t
        await live.until(lambda r: tail_error(t0) < 0.003 or live.bridge.sim.t > t0 + 20.0, timeout=60.0)
        assert live.cmd.armed
        assert tail_error(t0) < 0.003, f"pitch still {tail_error(t0):.4f} rad off 20 s after the step"
    assert abs(c.z[0]) > 0.05  # the integrator holds what the model lacks


@pytest.mark.slow
@async_test(timeout=60)
async def test_live_link_loss_stops_commanding_within_half_a_second(tmp_path):
    async with Live3dof(tmp_path, LQRFeedForward(), KalmanFeedback()) as live:
        await live.arm()
        await live.until(lambda r: live.bridge.sim.t > 3.0)
        sent_before = live.cmd.uplink.sent
        notes = live.cmd.notes.subscribe()
        live.port.unplug()  # the USB cable is pulled
        t_pull = time.monotonic()
        note = await asyncio.wait_for(notes.__anext__(), 2.0)
        assert note.startswith("disarmed: link") and live.link.state is LinkState.LOST
        last = live.cmd.uplink.last_sent_wall
        assert not live.cmd.armed and "link" in live.cmd.status
        assert sent_before > 100 and last - t_pull < 0.5
        # plugged back: data flows again, control stays disarmed until the user arms it
        live.port.plug()
        await live.next_record_or_data()
        n = live.cmd.uplink.sent
        await live.next_record_or_data()
        assert live.cmd.uplink.sent == n and not live.cmd.armed
        # and the vehicle went back to its own safe state once the commands stopped
        sim = live.bridge.sim

        async def fallback():
            while sim.externally_commanded:
                await live.next_record_or_data()

        await asyncio.wait_for(fallback(), 3.0)
        assert not live.cmd.armed


class LiveQuad(_Live):
    def __init__(self, controller=None):
        self.port = free_udp_port()
        self.bridge = SimBridge(Scenario("quad", seed=2), udp_to=("127.0.0.1", self.port))
        self.controller = controller or AltitudeHold()

    async def __aenter__(self):
        await self.bridge.open()
        link = MavlinkLink(f"udpin:127.0.0.1:{self.port}", lost_after=1.0)
        cmd = Commander(self.controller, EstimatorFeedback(altitude_estimator()), AttitudeTarget(link), link=link)
        await self._start(link, cmd)
        return self


@pytest.mark.slow
@async_test(timeout=40)
async def test_live_nothing_is_sent_to_a_vehicle_nobody_armed():
    async with LiveQuad() as live:
        await asyncio.wait_for(live.measurements(3000), 10.0)  # about 1.5 s of a live link
        assert live.link.state is LinkState.ALIVE
        assert live.cmd.uplink.sent == 0
        assert "SET_ATTITUDE_TARGET" not in live.bridge.received and "MANUAL_CONTROL" not in live.bridge.received
        assert live.bridge.commands_received == 0


@async_test(timeout=40)
async def test_live_udp_silence_disarms_and_the_vehicle_falls_back():
    async with LiveQuad() as live:
        await asyncio.wait_for(live.measurements(500), 10.0)
        notes = live.cmd.notes.subscribe()
        live.cmd.arm()
        rec = await asyncio.wait_for(live.records.__anext__(), 5.0)
        assert rec.command[0] > 0.0
        await asyncio.wait_for(live.measurements(500), 10.0)
        assert live.bridge.commands_received > 10 and live.bridge.sim.externally_commanded
        live.bridge.disconnect(3.0)  # the radio goes silent both ways
        t_cut = time.monotonic()

        async def disarmed():
            async for note in notes:
                if note.startswith("disarmed"):
                    return

        await asyncio.wait_for(disarmed(), 2.0)
        assert live.cmd.uplink.last_sent_wall - t_cut < 0.5
        assert "no measurement" in live.cmd.status


def test_arming_is_refused_with_a_reason_without_a_link_or_feedback():
    c = Commander(LQRFeedForward(), KalmanFeedback(), BoardMotors(_Sink()))
    with pytest.raises(ArmRefused, match="no fresh kalman feedback"):
        c.arm()
    assert c.tick() is None and c.uplink.sent == 0
    with pytest.raises(ValueError, match="no reference"):
        c.set_reference(z_c=1.0)
    with pytest.raises(ValueError, match="finite"):
        c.set_reference(p_c=float("nan"))


class _Sink:
    def __init__(self):
        self.data = []

    def send(self, data):
        self.data.append(data)


def test_motors_frame_is_what_the_board_protocol_says():
    sink = _Sink()
    BoardMotors(sink).send(np.array([4.25, 3.5]), 12.5)
    rx = BinaryBoardReceiver("x")
    (m,) = rx.feed(sink.data[0], 0.0)
    assert m.kind is Kind.MOTOR_VOLTAGE and m.t == pytest.approx(12.5) and list(m.value) == [4.25, 3.5]
    assert sink.data[0][:2] == bp.SYNC and sink.data[0][3] == bp.MOTORS


@async_test(timeout=60)
async def test_dashboard_control_panel_arms_sets_references_and_disarms():
    """A tab (protocol-level client) presses ARM, moves the z_c slider, tries to change the
    feedback while armed (refused), and presses DISARM; the commander follows each."""
    from groundstation.control.station import ControlStation
    from web.dashboard import Dashboard
    from web.probe import ViserProbe, gui_id

    port = free_udp_port()
    bridge = SimBridge(Scenario("quad", seed=6), udp_to=("127.0.0.1", port))
    link = MavlinkLink(f"udpin:127.0.0.1:{port}", lost_after=1.0)
    station = ControlStation("quad", link)
    sub = link.measurements()
    await link.open()
    await bridge.open()
    dash = Dashboard(port=0, plot_hz=10.0)
    panel = dash.add_control(station)
    tasks = [asyncio.create_task(c) for c in (bridge.run(), dash.run(), station.follow(sub), station.run())]
    notes = station.commander.notes.subscribe()
    try:
        probe_sub = link.measurements()
        k = 0
        async for _ in probe_sub:  # a live link with fresh estimates
            k += 1
            if k >= 500:
                break
        probe_sub.close()
        async with ViserProbe(dash.control_url) as probe:
            await probe.set_gui(gui_id(panel.take), value=True)
            await probe.set_gui(gui_id(panel.arm), value=True)
            await probe.set_gui(gui_id(panel.arm), value=True)  # ARM asks to be pressed again
            assert (await asyncio.wait_for(notes.__anext__(), 5.0)).startswith("armed")
            await probe.set_gui(gui_id(panel.sliders["z_c"]), value=1.5)
            await probe.set_gui(gui_id(panel.feedback), value="quad_thrust")
            status_id = gui_id(panel.status_md)

            async def refusal_shown():
                # the panel's callbacks run in the order viser received them, but not in step with
                # the commander's records: wait for the refusal itself (under load on CI the
                # record with z_c came first and the message was still empty)
                async for _, messages in probe.frames():
                    for m in messages:
                        if (
                            m["type"] == "GuiUpdateMessage"
                            and m.get("uuid") == status_id
                            and "disarm before" in m["updates"].get("_markdown", "")
                        ):
                            return

            await asyncio.wait_for(refusal_shown(), 10.0)
            records = station.commander.records.subscribe()

            async def reference_applied():
                async for rec in records:
                    if rec.reference["z_c"] == 1.5:
                        return rec

            rec = await asyncio.wait_for(reference_applied(), 5.0)
            assert rec.command[0] > 0 and station.feedback_name == "altitude"  # refused while armed
            assert "disarm before" in panel.message
            plot_id = gui_id(panel.plot)

            async def plotted():
                async for _, messages in probe.frames():
                    for m in messages:
                        if m["type"] == "GuiUpdateMessage" and m.get("uuid") == plot_id:
                            return m

            await asyncio.wait_for(plotted(), 5.0)
            await probe.set_gui(gui_id(panel.disarm), value=True)
            assert (await asyncio.wait_for(notes.__anext__(), 5.0)).startswith("disarmed: by the user")
        assert bridge.commands_received > 0
    finally:
        station.stop()
        bridge.close()
        await link.close()
        for t in tasks[:2]:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        dash.stop()
