"""The simulated vehicle over real transports, and its recorded sessions."""

import asyncio
import csv
import json
import math
from collections import defaultdict

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.mavlink.link import LinkState, MavlinkLink
from drivers.replay import Replay
from groundstation.core.measurement import Kind
from sim_bridge.bridge import LinkFaults, SimBridge
from sim_bridge.fast import run_fast
from sim_bridge.pty_port import PtyPort
from sim_bridge.scenario import Scenario

from .conftest import async_test

REQUESTED = {
    Kind.ACCEL: 250.0,
    Kind.BARO_PRESSURE: 50.0,
    Kind.RANGE: 25.0,
    Kind.ATTITUDE: 50.0,
    Kind.GPS: 5.0,
    Kind.ACTUATOR: 50.0,
    Kind.BATTERY_VOLTAGE: 5.0,
}


async def _fly(bridge: SimBridge, link: MavlinkLink, seconds: float):
    sub = link.measurements()
    got = []

    async def consume():
        async for m in sub:
            got.append(m)

    task = asyncio.create_task(consume())
    await bridge.run(seconds)
    await asyncio.sleep(0.1)  # the last datagrams in flight (loopback)
    task.cancel()
    return got


def _rates(ms, t0, t1):
    counts = defaultdict(int)
    for m in ms:
        if t0 <= m.t < t1:
            counts[m.kind] += 1
    return {k: counts[k] / (t1 - t0) for k in REQUESTED}


@pytest.mark.slow
@async_test(timeout=60)
async def test_udp_every_sensor_at_its_requested_rate_and_the_recording_replays(tmp_path):
    link = MavlinkLink("udpin:127.0.0.1:0", record=tmp_path / "s.tlog")
    await link.open()
    bridge = SimBridge(
        Scenario("quad", seed=2, duration=60), udp_to=("127.0.0.1", link.transport.local_address[1]), speed=4.0
    )
    await bridge.open()
    try:
        live = await _fly(bridge, link, 12.0)
    finally:
        bridge.close()
        await link.close()
    assert link.stream_method[1] == "SET_MESSAGE_INTERVAL"
    assert link.counters.seq_lost == 0 and link.counters.crc_errors == 0
    rates = _rates(live, 6.0, 12.0)  # after the streams were set, in flight (range valid)
    for kind, hz in REQUESTED.items():
        assert rates[kind] == pytest.approx(hz, rel=0.05), (kind, rates[kind])
    # the recording plays back to the very same measurements
    # (to the tlog's microsecond resolution of receive time, which untimed
    # messages are stamped through; the file also holds what arrived after the
    # live consumer stopped)
    rp = Replay(tmp_path / "s.tlog")
    replayed = [m for m in rp.iter_measurements() if m.source == "replay/1.1"]
    live = [m for m in live if m.source == "mav/1.1"]
    assert 0 <= len(replayed) - len(live) < 20
    for a, b in zip(replayed, live):
        assert (a.kind, a.instance) == (b.kind, b.instance)
        assert a.t == pytest.approx(b.t, abs=2e-6)
        np.testing.assert_array_equal(np.nan_to_num(a.value), np.nan_to_num(b.value))


@async_test(timeout=60)
async def test_serial_pty_link_and_commands_fly_the_vehicle(tmp_path):
    port = PtyPort(tmp_path / "ttySIM")
    port.plug()
    bridge = SimBridge(Scenario("quad", seed=3), udp_to=None, pty=port, speed=2.0, command_timeout=0.3)
    await bridge.open()
    link = MavlinkLink(f"{port.path},921600", heartbeat_hz=5.0)
    events = link.events()
    await link.open()
    try:
        runner = asyncio.create_task(bridge.run(20.0))
        async for ev in events:
            if ev.state is LinkState.ALIVE:
                break
        # fly by MANUAL_CONTROL: full-ish throttle climbs, as the ground station commands
        for _ in range(40):
            link.send(mavlink.MAVLink_manual_control_message(1, 0, 0, 800, 0, 0))
            await asyncio.sleep(0.02)
        assert bridge.commands_received > 10 and bridge.sim.externally_commanded
        assert bridge.sim.vehicle.tau == pytest.approx(0.8)
        assert bridge.sim.vehicle.kin.height > 0.2  # it climbed on our command
        # commands stop: the vehicle falls back to its own autopilot within the timeout
        t_stop = bridge.sim.t
        while bridge.sim.externally_commanded:
            await asyncio.sleep(0.02)
        assert bridge.sim.t - t_stop <= 0.3 + 0.1
        assert bridge.received.get("HEARTBEAT", 0) > 0  # GCS heartbeats came down the pty
        bridge.close()
        await runner
    finally:
        bridge.close()
        await link.close()


@async_test(timeout=60)
async def test_injected_loss_and_corruption_are_seen_by_the_ground_station():
    link = MavlinkLink("udpin:127.0.0.1:0", streams={})
    await link.open()
    bridge = SimBridge(
        Scenario("quad", seed=4),
        udp_to=("127.0.0.1", link.transport.local_address[1]),
        faults=LinkFaults(loss=0.2, corrupt=0.05),
        speed=4.0,
    )
    await bridge.open()
    try:
        await _fly(bridge, link, 8.0)
    finally:
        bridge.close()
        await link.close()
    c = link.counters
    sent = bridge.frames_sent + bridge.frames_dropped
    assert c.loss_percent_of(1) == pytest.approx(100 * (bridge.frames_dropped + c.crc_errors) / sent, abs=1.5)
    assert 15 < c.loss_percent_of(1) < 30 and c.crc_errors > 0


def test_fast_mode_is_deterministic_and_complete(tmp_path):
    sc = lambda: Scenario.from_args("quad", 5, 20.0, ["baro_thrust:k=3"], ["range_offset:o=-0.04"])  # noqa: E731
    a = run_fast(sc(), tmp_path / "a.tlog", tmp_path / "a.csv")
    b = run_fast(sc(), tmp_path / "b.tlog", tmp_path / "b.csv")
    assert (tmp_path / "a.tlog").read_bytes() == (tmp_path / "b.tlog").read_bytes()
    assert a.frames == b.frames > 10000
    # the declared file names only the declared effect; the truth names both
    declared = json.loads((tmp_path / "a.declared.json").read_text())
    assert [e["name"] for e in declared["effects"]] == ["baro_thrust"]
    assert "range_offset" not in (tmp_path / "a.declared.json").read_text()
    truth = json.loads((tmp_path / "a.truth.json").read_text())
    assert [e["name"] for e in truth["undeclared"]] == ["range_offset"]
    rows = list(csv.DictReader(open(tmp_path / "a.csv")))
    assert len(rows) == 2000 and {"t", "h", "roll", "throttle", "voltage", "range_true"} <= rows[0].keys()
    # the undeclared range offset is in the data: range - truth slant range ~ -4 cm
    rp = Replay(tmp_path / "a.tlog")
    rng = [(m.t, m.value[0]) for m in rp.iter_measurements() if m.kind is Kind.RANGE and m.t > 6]
    tt = np.array([float(r["t"]) for r in rows])
    slant = np.array([float(r["range_true"]) for r in rows])
    err = [d - np.interp(t, tt, slant) for t, d in rng]
    assert np.mean(err) == pytest.approx(-0.04, abs=0.006)


@pytest.mark.parametrize("vehicle", ["quad", "coax", "heli3dof"])
def test_every_vehicle_records_a_session(tmp_path, vehicle):
    r = run_fast(Scenario(vehicle, seed=1, duration=15.0), tmp_path / "v.tlog", tmp_path / "v.csv")
    rp = Replay(tmp_path / "v.tlog")
    kinds = {m.kind for m in rp.iter_measurements()}
    assert {Kind.ACCEL, Kind.GYRO, Kind.ATTITUDE, Kind.ACTUATOR} <= kinds
    if vehicle != "heli3dof":
        assert {Kind.BARO_PRESSURE, Kind.RANGE, Kind.GPS} <= kinds
    assert rp.receiver.counters.crc_errors == 0 and r.frames > 1000


def test_baro_reads_the_standard_atmosphere(tmp_path):
    from groundstation.core.atmosphere import altitude_at

    run_fast(Scenario("quad", seed=6, duration=20.0), tmp_path / "q.tlog", tmp_path / "q.csv")
    rows = list(csv.DictReader(open(tmp_path / "q.csv")))
    tt = np.array([float(r["t"]) for r in rows])
    h = np.array([float(r["h"]) for r in rows])
    baro = [(m.t, m.value[0]) for m in Replay(tmp_path / "q.tlog").iter_measurements() if m.kind is Kind.BARO_PRESSURE]
    err = np.array([altitude_at(p) - 120.0 - np.interp(t, tt, h) for t, p in baro])
    assert abs(err.mean()) < 0.1 and 0.2 < err.std() < 0.5  # 4 Pa of noise is ~0.33 m


@async_test(timeout=40)
async def test_set_attitude_target_and_disconnect_on_demand(tmp_path):
    port = PtyPort(tmp_path / "ttyQ")
    port.plug()
    bridge = SimBridge(Scenario("quad", seed=8), udp_to=None, pty=port, speed=2.0, command_timeout=0.3)
    await bridge.open()
    link = MavlinkLink(f"{port.path},921600", heartbeat_hz=5.0, lost_after=0.5, streams={})
    events = link.events()
    await link.open()
    runner = asyncio.create_task(bridge.run(60.0))
    try:
        async for ev in events:
            if ev.state is LinkState.ALIVE:
                break
        half = math.radians(10) / 2
        q = [math.cos(half), math.sin(half), 0.0, 0.0]  # 10 deg of roll
        for _ in range(30):
            link.send(mavlink.MAVLink_set_attitude_target_message(0, 1, 1, 0b00000111, q, 0, 0, 0.0, 0.7))
            await asyncio.sleep(0.02)
        assert bridge.sim.externally_commanded and bridge.sim.vehicle.tau == pytest.approx(0.7)
        assert bridge.sim.last_command.roll == pytest.approx(math.radians(10), abs=1e-6)
        bridge.disconnect(1.0)  # the radio drops out for a second
        async for ev in events:
            if ev.state is LinkState.LOST:
                break
        async for ev in events:
            if ev.state is LinkState.ALIVE:
                break
    finally:
        bridge.close()
        await runner
        await link.close()


@pytest.mark.slow
def test_a_scenario_file_the_simulator_cannot_fly_is_a_one_line_error(tmp_path):
    """A scenario file that is not JSON, names a sensor setting the simulator has not, or an ESC
    protocol its PX4 log cannot state: exit 2, one line naming the file's fault, nothing written."""
    import subprocess
    import sys

    cases = {
        "broken.json": ("{not json", "cannot read scenario"),
        "setting.json": ('{"sensors": {"imu_rate": 250}}', "unknown sensor setting 'imu_rate'"),
        "esc.json": ('{"sensors": {"esc": "oneshot"}}', "unknown ESC protocol 'oneshot'; use one of pwm, dshot"),
    }
    for name, (text, words) in cases.items():
        scenario = tmp_path / name
        scenario.write_text(text)
        log = tmp_path / f"{name}.ulg"
        r = subprocess.run(
            [sys.executable, "-m", "groundstation", "sim", "--fast", "--scenario", str(scenario), "--log", str(log)],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert r.returncode == 2 and words in r.stderr, (name, r.returncode, r.stderr)
        assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert not log.exists()
