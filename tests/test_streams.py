"""Stream requests that converge: each asked until acknowledged over a lossy link, everything asked
again after the vehicle restarts, and the rates fitted to a serial link's budget. The simulated
vehicle on real loopback UDP; its link drops a fifth of what it sends, acknowledgements included."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.mavlink.link import DEFAULT_STREAMS, MavlinkLink
from drivers.mavlink.streams import MIN_RATE, PRIORITY, RETRIES, StreamRequester, fit_budget, frame_bytes
from groundstation.core.measurement import Kind
from sim_bridge.bridge import LinkFaults, SimBridge
from sim_bridge.scenario import Scenario

from .conftest import async_test, free_udp_port
from .helpers import running, simulated_vehicle, until

#: MAVProxy, from the test extras (installed beside this Python by make test)
MAVPROXY = Path(sys.executable).parent / "mavproxy.py"

#: what the simulated quadcopter sends, as the ground station asks it (message -> its stream)
ASKED = {"imu": 250.0, "baro": 50.0, "range": 25.0, "gps": 5.0, "attitude": 50.0, "actuators": 50.0, "battery": 5.0}


def _settled(link: MavlinkLink, bridge: SimBridge) -> bool:
    """The vehicle sends at the rates asked, and has answered every request."""
    v = link.requester.vehicles.get(1)
    answered = v is not None and len(v.acked) + len(v.refused) == len(DEFAULT_STREAMS)
    return answered and bridge.sim.sensors.rates == ASKED


class _OnLink:
    """Simulated vehicles writing to an open link's port, each running as a task; on exit every one
    is stopped and the link closed, also when the test fails."""

    def __init__(self, link: MavlinkLink) -> None:
        self.link, self.bridges, self.tasks = link, [], []

    @property
    def port(self) -> int:
        return self.link.transport.local_address[1]

    async def start(self, seed: int, **options) -> SimBridge:
        br = SimBridge(Scenario("quad", seed=seed), udp_to=("127.0.0.1", self.port), **options)
        self.bridges.append(br)
        await br.open()
        self.tasks.append(asyncio.get_running_loop().create_task(br.run()))
        return br

    async def __aenter__(self) -> _OnLink:
        await self.link.open()
        return self

    async def __aexit__(self, *exc) -> None:
        for br in self.bridges:
            br.close()
        for t in self.tasks:
            t.cancel()
        await asyncio.gather(*self.tasks, return_exceptions=True)
        await self.link.close()


@pytest.mark.slow
@async_test(timeout=90)
async def test_every_stream_converges_at_twenty_percent_loss_and_again_after_a_restart():
    link = MavlinkLink("udpin:127.0.0.1:0", ack_timeout=0.3, check_every=1.0)
    async with _OnLink(link) as on:
        a = await on.start(4, faults=LinkFaults(loss=0.2))
        await until(lambda: _settled(link, a), 30, f"the streams asked ({a.sim.sensors.rates})")
        v = link.requester.vehicles[1]
        assert v.method == "SET_MESSAGE_INTERVAL" and not v.unanswered
        assert v.acked == {"HIGHRES_IMU", "SCALED_PRESSURE", "DISTANCE_SENSOR", "ATTITUDE", "GPS_RAW_INT",
                           "GLOBAL_POSITION_INT", "SERVO_OUTPUT_RAW", "SYS_STATUS", "BATTERY_STATUS"}  # fmt: skip
        assert a.frames_dropped > 0  # the loss was real, ACKs among it
        # the vehicle restarts after 2 s up: a new process at its default rates, its clock from zero
        await until(lambda: a.sim.t > 2.0, 10, "2 s of uptime")
        a.close()
        b = await on.start(5)
        assert b.sim.sensors.rates["imu"] == 500.0
        # the restart is seen at the vehicle's next heartbeat after its clock went back; the streams
        # arriving short (its default rates) may be asked again before it
        await until(
            lambda: v.requests == 2 and _settled(link, b), 30, f"asked again after the restart ({b.sim.sensors.rates})"
        )


@async_test(timeout=60)
async def test_a_short_stream_is_asked_again():
    """The vehicle forgets one stream's rate (a parameter reset): the link sees it arrive short of
    the rate asked and asks again."""
    link = MavlinkLink("udpin:127.0.0.1:0", ack_timeout=0.3, check_every=0.5)
    async with _OnLink(link) as on:
        br = await on.start(6)
        await until(lambda: _settled(link, br), 20, "the streams asked")
        br.sim.sensors.set_rate("baro", 5.0)  # a tenth of what was asked
        await until(lambda: br.sim.sensors.rates["baro"] == 50.0, 10, "the baro asked again")
        assert link.requester.vehicles[1].reasked.get("SCALED_PRESSURE") == 1


def test_a_57600_baud_radio_gets_the_estimators_streams_first():
    """57600 baud carries 5,760 bytes/s; the streams asked need about 24 kB/s (HIGHRES_IMU at 250 Hz
    alone 18 kB/s). Fitted: within the budget, the first streams slowed least."""
    asked = sum(hz * frame_bytes(n) for n, hz in DEFAULT_STREAMS.items())
    assert asked > 20_000
    got = fit_budget(DEFAULT_STREAMS, 5760.0)
    assert sum(hz * frame_bytes(n) for n, hz in got.items()) <= 5760.0 * 1.001
    first = list(DEFAULT_STREAMS)[:PRIORITY]
    rest = list(DEFAULT_STREAMS)[PRIORITY:]
    assert all(got[n] >= MIN_RATE for n in got)
    kept = min(got[n] / DEFAULT_STREAMS[n] for n in first)
    assert all(got[n] == MIN_RATE or got[n] / DEFAULT_STREAMS[n] <= kept for n in rest)  # slowed first, to the floor
    roomy = fit_budget(DEFAULT_STREAMS, 92_160.0)  # 921600 baud: everything as asked
    assert roomy == DEFAULT_STREAMS
    link = MavlinkLink("/dev/ttyUSB9,57600")  # not opened: the budget comes from the baud
    assert link.max_rate == pytest.approx(5760.0) and link.requester.streams == got


@async_test(timeout=60)
async def test_two_vehicles_on_one_udpin_port_are_each_asked_at_their_own_address():
    """Two simulated vehicles (system ids 1 and 2, each its own socket) write to one ``udpin``
    port: each is asked for its streams, and a request for one never reaches the other."""
    link = MavlinkLink("udpin:127.0.0.1:0", ack_timeout=0.3, check_every=1.0)
    second = link.measurements(sysid=2)  # one vehicle's own stream
    async with _OnLink(link) as on:
        bridges = [await on.start(7 + k, sysid=k) for k in (1, 2)]
        for k, br in zip((1, 2), bridges, strict=True):
            await until(lambda br=br: br.sim.sensors.rates == ASKED, 30, f"vehicle {k}'s streams asked")
        assert set(link.vehicles) == {1, 2}
        for k in (1, 2):
            # the vehicle applies a rate before its acknowledgement reaches the link: wait for the answers
            v = link.requester.vehicles[k]
            await until(lambda v=v: len(v.acked) + len(v.refused) == len(DEFAULT_STREAMS), 30, f"vehicle {k}'s answers")
        for k, br in zip((1, 2), bridges, strict=True):
            v = link.requester.vehicles[k]
            assert v.method == "SET_MESSAGE_INTERVAL" and not v.unanswered
            assert len(v.acked) + len(v.refused) == len(DEFAULT_STREAMS)
            assert br.received["COMMAND_LONG"] > 0 and br.addressed_elsewhere == 0  # its own, none of the other's
        got = second.get_nowait()
        assert len(got) > 10 and {m.source for m in got} == {"mav/2.1"}


@pytest.mark.slow
@async_test(timeout=60)
async def test_a_restart_is_a_new_segment_not_loss():
    """The vehicle restarts within a second (its sequence numbers and clock start over): the link
    counts a restart and no lost frames, says so on its event stream, and asks again."""
    link = MavlinkLink("udpin:127.0.0.1:0", ack_timeout=0.3, check_every=1.0)
    events = link.events()
    async with _OnLink(link) as on:
        a = await on.start(8)
        await until(lambda: _settled(link, a) and a.sim.t > 3.0, 30, "streams asked and 3 s up")
        a.close()
        b = await on.start(8)
        v = link.requester.vehicles[1]
        await until(lambda: v.requests == 2 and _settled(link, b), 30, "asked again after the restart")
        c = link.counters
        assert c.restarts == 1 and c.seq_lost == 0, (c.restarts, c.seq_lost)
        said = [e.reason for e in events.get_nowait()]
        assert any("vehicle 1 restarted" in r for r in said), said


#: the simulated quadcopter's messages, as DEFAULT_STREAMS asks for them
SIM_MESSAGES = ("HIGHRES_IMU", "SCALED_PRESSURE", "DISTANCE_SENSOR", "ATTITUDE", "GPS_RAW_INT",
                "GLOBAL_POSITION_INT", "SERVO_OUTPUT_RAW", "SYS_STATUS", "BATTERY_STATUS")  # fmt: skip


def _router(vehicle_port: int, gcs_port: int, state: Path, *options: str) -> list:
    """A MAVProxy router between the vehicle's port and the ground station's (no console)."""
    return [MAVPROXY, f"--master=udpin:127.0.0.1:{vehicle_port}", f"--out=udpout:127.0.0.1:{gcs_port}",
            *options, "--non-interactive", f"--state-basedir={state}", "--default-modules=link"]  # fmt: skip


async def _received_rates(link: MavlinkLink, seconds: float) -> dict[str, float]:
    """Each message's rate over a window of ``seconds`` of the wall clock, per second of the vehicle's
    clock (its newest time at each end): the simulated world pauses with its process when the machine
    stalls it, and a stream's rate is asked of the vehicle's time (on a loaded run the wall clock
    put a 250 Hz stream at 158 Hz)."""
    clock = link.receiver.decoder.clocks[1]
    before, v0 = dict(link.counters.by_type), clock.newest
    await asyncio.sleep(seconds)  # a measurement window, not a wait for an event
    dt = clock.newest - v0
    return {n: (link.counters.by_type[n] - before.get(n, 0)) / dt for n in SIM_MESSAGES}


@pytest.mark.slow
@async_test(timeout=180)
async def test_through_a_mavproxy_router_at_twenty_percent_loss_and_after_a_reboot(tmp_path):
    """The simulator (a fifth of its frames lost) behind a real MAVProxy router, which asks for no
    streams itself: every stream arrives at its asked rate less the loss, and again after the
    vehicle is restarted (a new process: its clock, sequence and default rates start over)."""
    vehicle_port, gcs_port = free_udp_port(), free_udp_port()
    link = MavlinkLink(f"udpin:127.0.0.1:{gcs_port}", ack_timeout=0.5, check_every=2.0)
    mavproxy = _router(vehicle_port, gcs_port, tmp_path, "--streamrate=-1")
    sim = ("--loss", "20", "--seed", "3", "--duration", "120")
    async with _OnLink(link):
        with running(mavproxy, stdin=subprocess.DEVNULL):
            for boot in (1, 2):
                with simulated_vehicle(vehicle_port, *sim):
                    v = await _vehicle_asked(link, boot)
                    assert v.method == "SET_MESSAGE_INTERVAL" and not v.unanswered
                    got = await _received_rates(link, WINDOW)
                    for name in SIM_MESSAGES:
                        low, high = _expected(DEFAULT_STREAMS[name], 0.8)
                        assert low <= got[name] <= high, (boot, name, got[name], DEFAULT_STREAMS[name])


WINDOW = 8.0  # [s] the rates are measured over


def _expected(asked: float, kept: float) -> tuple[float, float]:
    """The rates [Hz] a stream asked at ``asked`` arrives at over :data:`WINDOW` when a share
    ``kept`` of its frames gets through: within 4 sigma of the binomial count, less a tenth for
    a loaded machine running the simulated world behind the wall clock; at most what was asked."""
    n = asked * WINDOW
    low = (kept * n - 4.0 * (n * kept * (1.0 - kept)) ** 0.5) / WINDOW
    return 0.9 * low, 1.05 * asked


async def _vehicle_asked(link: MavlinkLink, boot: int):
    """The vehicle's streams asked and answered, for the ``boot``-th time."""

    def done() -> bool:
        v = link.requester.vehicles.get(1)
        return v is not None and v.requests >= boot and len(v.acked) + len(v.refused) == len(DEFAULT_STREAMS)

    await until(done, 60, f"the streams asked, boot {boot}")
    return link.requester.vehicles[1]


async def _streams_behind_a_default_router(tmp_path, window_s: float) -> None:
    """A MAVProxy router with its default stream rate asks the vehicle for every stream at 4 Hz, again
    and again (every 10-20 s): behind it the telemetry had fallen to a tenth after a minute and stayed
    there, with no word (and later the 5 Hz streams stayed at the router's 4 Hz, 80 %). The link
    notices the fall, says it, and asks again: over ``window_s``, every stream keeps 90 % of its
    asked rate. The rates are counted over the vehicle's own clock: a loaded machine pauses the
    simulated world (its frames are then late, not lost), and a rate over the wall clock would count
    the pause as loss."""
    vehicle_port, gcs_port = free_udp_port(), free_udp_port()
    link = MavlinkLink(f"udpin:127.0.0.1:{gcs_port}", ack_timeout=0.5, check_every=2.0)
    mavproxy = _router(vehicle_port, gcs_port, tmp_path)  # its default stream rate: 4 Hz
    clock: list[float] = []  # the vehicle's time of its latest IMU frame [s]
    imu = link.measurements()

    async def follow() -> None:
        async for m in imu:
            if m.kind is Kind.ACCEL:
                clock[:] = [m.t]

    lasts = f"{window_s + 120:.0f}"
    async with _OnLink(link):
        with running(mavproxy, stdin=subprocess.DEVNULL), simulated_vehicle(vehicle_port, "--duration", lasts):
            following = asyncio.get_running_loop().create_task(follow())
            try:
                await _vehicle_asked(link, 1)
                await until(lambda: bool(clock), 30, "the vehicle's IMU")
                start, v0 = dict(link.counters.by_type), clock[0]
                await asyncio.sleep(window_s)  # the measurement window itself
                dt = clock[0] - v0
                got = {n: (link.counters.by_type[n] - start.get(n, 0)) / dt for n in SIM_MESSAGES}
            finally:
                following.cancel()
            for name in SIM_MESSAGES:
                assert got[name] >= 0.9 * DEFAULT_STREAMS[name], (name, got[name], list(link.stream_notes))


@pytest.mark.slow
@async_test(timeout=300)
async def test_behind_a_mavproxy_router_left_at_its_defaults_the_streams_hold(tmp_path):
    """A minute behind the router: three to six of its asks, each noticed and answered."""
    await _streams_behind_a_default_router(tmp_path, 60.0)


@pytest.mark.soak
@async_test(timeout=900)
async def test_behind_a_mavproxy_router_left_at_its_defaults_the_streams_hold_for_ten_minutes(tmp_path):
    """Ten minutes behind the router, as long as a flight (``bench/router_streams.py`` prints the
    rates a minute at a time)."""
    await _streams_behind_a_default_router(tmp_path, 600.0)


@async_test(timeout=20)
async def test_a_refusal_that_comes_after_five_lost_answers_is_a_refusal_not_unanswered():
    """A loaded, lossy link loses all five answers to one stream's request; asked again later, the
    vehicle refuses it (it lacks the sensor). The stream is refused, and no longer unanswered. The
    loss is chosen here, per command, which a random-loss link cannot do on demand."""
    tries: dict[int, int] = {}
    requester: StreamRequester

    def send(msg) -> None:
        msg_id = int(msg.param1)
        tries[msg_id] = tries.get(msg_id, 0) + 1
        if msg_id == mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION:
            if tries[msg_id] <= RETRIES:
                return  # the answer lost, every try of the first round
            result = mavlink.MAV_RESULT_DENIED
        else:
            result = mavlink.MAV_RESULT_ACCEPTED
        asyncio.get_running_loop().call_soon(requester.ack, 1, msg.command, result)

    streams = {"HIGHRES_IMU": 50.0, "ATTITUDE_QUATERNION": 50.0}
    t0 = time.monotonic()
    requester = StreamRequester(
        send, lambda: {"HIGHRES_IMU": int(50 * (time.monotonic() - t0))}, streams, ack_timeout=0.01, check_every=0.2
    )
    requester.start(1, 1)
    v = requester.vehicles[1]
    await until(lambda: "ATTITUDE_QUATERNION" in v.refused, 10, "the stream asked again and refused")
    assert not v.unanswered and v.acked == {"HIGHRES_IMU"}
    for t in requester.close():
        t.cancel()
