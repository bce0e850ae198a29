"""The MAVLink link over real loopback UDP and TCP, against a vehicle sending real frames."""

import asyncio
import os
import socket
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from drivers.mavlink.link import LinkState, MavlinkLink
from groundstation.core.measurement import Kind
from sim_bridge.mavlink_vehicle import MavlinkVehicle

from .conftest import async_test, free_tcp_port, free_udp_port


async def _next_state(events, want: LinkState, timeout=5.0):
    async def _w():
        async for ev in events:
            if ev.state is want:
                return ev

    return await asyncio.wait_for(_w(), timeout)


async def _take(sub, n, timeout=5.0):
    out = []

    async def _w():
        async for m in sub:
            out.append(m)
            if len(out) >= n:
                return

    await asyncio.wait_for(_w(), timeout)
    return out


async def _udp_pair(tmp_path=None, ack="accept", mavlink1=False, **kw):
    port = free_udp_port()
    link = MavlinkLink(
        f"udpin:127.0.0.1:{port}", record=tmp_path / "s.tlog" if tmp_path else None, ack_timeout=0.3, **kw
    )
    sub, events = link.measurements(), link.events()
    await link.open()
    veh = MavlinkVehicle(udp_to=("127.0.0.1", port), ack=ack, mavlink1=mavlink1)
    await veh.open()
    return link, veh, sub, events


@async_test()
async def test_measurements_heartbeats_and_stream_requests(tmp_path):
    link, veh, sub, events = await _udp_pair(tmp_path)
    try:
        veh.heartbeat()
        await _next_state(events, LinkState.ALIVE)
        for i in range(20):
            veh.send(mavlink.MAVLink_scaled_pressure_message(1000 + 40 * i, 1000.0 + i, 0.0, 2000, 0))
        got = await _take(sub, 41)  # heartbeat status + 20 x (pressure, temperature)
        baro = [m for m in got if m.kind is Kind.BARO_PRESSURE]
        assert [m.value[0] for m in baro] == pytest.approx([100000.0 + 100 * i for i in range(20)])
        # The ground station answers as a GCS: heartbeats, and SET_MESSAGE_INTERVAL per stream.
        await veh.wait_for("HEARTBEAT")
        hb = [m for m in veh.received if m.get_type() == "HEARTBEAT"][0]
        assert hb.type == mavlink.MAV_TYPE_GCS and hb._header.srcSystem == 255
        await veh.wait_for("COMMAND_LONG", len(link.streams))
        assert veh.message_intervals[mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE] == pytest.approx(1e6 / 50)
        assert link.stream_method[1] == "SET_MESSAGE_INTERVAL"
        assert not veh.data_stream_requests
    finally:
        await link.close()
        veh.close()
    # The session recording holds the vehicle's frames and ours, readable by pymavlink.
    conn = mavutil.mavlink_connection(str(tmp_path / "s.tlog"))
    types = []
    while (m := conn.recv_match()) is not None:
        types.append((m.get_type(), m.get_srcSystem()))
    assert types.count(("SCALED_PRESSURE", 1)) == 20
    assert ("HEARTBEAT", 255) in types and ("COMMAND_LONG", 255) in types


@pytest.mark.slow
@pytest.mark.parametrize("ack", ["ignore", "deny"])
@async_test()
async def test_falls_back_to_request_data_stream(ack):
    link, veh, sub, events = await _udp_pair(ack=ack)
    try:
        veh.heartbeat()
        await veh.wait_for("REQUEST_DATA_STREAM", 7)
        assert link.stream_method[1] == "REQUEST_DATA_STREAM"
        assert (mavlink.MAV_DATA_STREAM_RAW_SENSORS, 50) in veh.data_stream_requests
    finally:
        await link.close()
        veh.close()


@async_test()
async def test_mavlink1_vehicle_gets_mavlink1_heartbeats():
    link, veh, sub, events = await _udp_pair(mavlink1=True, heartbeat_hz=20.0)
    try:
        veh.heartbeat()
        await _next_state(events, LinkState.ALIVE)
        veh.received.clear()
        veh.received_types.clear()
        await veh.wait_for("HEARTBEAT")
        hb = [m for m in veh.received if m.get_type() == "HEARTBEAT"][0]
        assert hb.get_msgbuf()[0] == 0xFE
    finally:
        await link.close()
        veh.close()


@async_test()
async def test_link_lost_after_silence_and_resumes():
    link, veh, sub, events = await _udp_pair(lost_after=0.3)
    try:
        veh.heartbeat()
        await _next_state(events, LinkState.ALIVE)
        lost = await _next_state(events, LinkState.LOST)  # the vehicle says nothing more
        assert "no valid message" in lost.reason
        veh.heartbeat()
        await _next_state(events, LinkState.ALIVE)
    finally:
        await link.close()
        veh.close()


@async_test()
async def test_counters_sequence_gaps_bad_crc_and_garbage():
    link, veh, sub, events = await _udp_pair()
    try:
        veh.heartbeat()
        await _next_state(events, LinkState.ALIVE)
        for i in range(10):
            veh.send(mavlink.MAVLink_attitude_message(100 + i, 0, 0, 0, 0, 0, 0))
        veh.mav.seq = (veh.mav.seq + 5) % 256  # five frames "lost in the air"
        good = veh.send(mavlink.MAVLink_attitude_message(200, 0, 0, 0, 0, 0, 0))
        bad = bytearray(veh.encode(mavlink.MAVLink_attitude_message(300, 0.5, 0, 0, 0, 0, 0)))
        bad[15] ^= 0x55
        veh.send_bytes(bytes(bad))
        veh.send_bytes(os.urandom(64).replace(b"\xfd", b"\x00").replace(b"\xfe", b"\x00"))
        veh.send(mavlink.MAVLink_attitude_message(400, 0.25, 0, 0, 0, 0, 0))
        got = await _take(sub, 1 + 2 * 12)
        c = link.counters
        assert c.seq_lost == 6  # five skipped + the corrupted frame
        assert c.crc_errors == 1 and c.bad_data >= 1
        assert got[-2].kind is Kind.ATTITUDE and got[-2].value[0] == pytest.approx(0.25)
        assert c.by_type["ATTITUDE"] == 12 and good
    finally:
        await link.close()
        veh.close()


@async_test(timeout=60)
async def test_flooding_peer_is_bounded_and_counted():
    link, veh, sub, events = await _udp_pair(buffer=1000)
    slow = link.measurements(maxlen=1000)
    try:
        veh.heartbeat()
        await _next_state(events, LinkState.ALIVE)
        frame = veh.encode(mavlink.MAVLink_attitude_message(1, 0, 0, 0, 0, 0, 0))
        sock = veh._sock
        for _ in range(400):  # 20,000 frames in bursts the socket buffer holds
            for _ in range(50):
                try:
                    sock.sendto(frame, veh.udp_to)
                except BlockingIOError:
                    break
            await asyncio.sleep(0)  # let the link read them
        # The kernel drops what overflows the socket buffer, so a heartbeat sent
        # once might never arrive: beat until one after the flood gets through.
        after = asyncio.Event()
        link.message_hooks.append(lambda m, t: m.get_type() == "HEARTBEAT" and after.set())
        veh.start_heartbeat(20.0)
        await asyncio.wait_for(after.wait(), 10)
        assert link.counters.by_type["ATTITUDE"] > 5000
        assert slow.backlog <= 1000 and slow.dropped > 0
        assert link.counters.dropped > 0 and link.state is LinkState.ALIVE
    finally:
        await link.close()
        veh.close()


@async_test()
async def test_tcp_client_reconnects_when_the_peer_returns():
    port = free_tcp_port()
    enc = mavlink.MAVLink(None, 1, 1)
    hb = bytes(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(enc))
    served = asyncio.Event()

    async def handle(reader, writer):
        writer.write(hb)
        await writer.drain()
        served.set()
        await reader.read(1)  # wait for the ground station's heartbeat
        writer.close()  # then drop the connection

    server = await asyncio.start_server(handle, "127.0.0.1", port)
    link = MavlinkLink(f"tcp:127.0.0.1:{port}", streams={})
    events = link.events()
    try:
        await link.open()
        await _next_state(events, LinkState.ALIVE)
        await _next_state(events, LinkState.LOST)
        served.clear()
        await asyncio.wait_for(served.wait(), 5)  # the link came back by itself
        await _next_state(events, LinkState.ALIVE)
    finally:
        await link.close()
        server.close()
        await server.wait_closed()


@async_test()
async def test_udpout_reaches_a_listening_vehicle():
    veh = MavlinkVehicle(udp_listen=("127.0.0.1", 0))
    await veh.open()
    link = MavlinkLink(f"udpout:127.0.0.1:{veh.port}", heartbeat_hz=20.0)
    sub = link.measurements()
    await link.open()
    try:
        await veh.wait_for("HEARTBEAT")  # our heartbeat tells the vehicle where we are
        veh.heartbeat()
        veh.send(mavlink.MAVLink_attitude_message(1000, 0.3, 0, 0, 0, 0, 0))
        got = await _take(sub, 3)
        assert any(m.kind is Kind.ATTITUDE and m.value[0] == pytest.approx(0.3) for m in got)
        assert link.state is LinkState.ALIVE
    finally:
        await link.close()
        veh.close()


@async_test()
async def test_tcpin_serves_a_connecting_vehicle():
    port = free_tcp_port()
    link = MavlinkLink(f"tcpin:127.0.0.1:{port}", heartbeat_hz=20.0, streams={})
    sub = link.measurements()
    await link.open()
    enc = mavlink.MAVLink(None, 1, 1)
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(bytes(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(enc)))
        writer.write(bytes(mavlink.MAVLink_attitude_message(1000, -0.2, 0, 0, 0, 0, 0).pack(enc)))
        await writer.drain()
        got = await _take(sub, 3)
        assert any(m.kind is Kind.ATTITUDE and m.value[0] == pytest.approx(-0.2) for m in got)
        back = mavlink.MAVLink(None)
        msgs = []
        while not any(m.get_type() == "HEARTBEAT" for m in msgs):
            msgs += back.parse_buffer(await asyncio.wait_for(reader.read(1024), 5)) or []
    finally:
        writer.close()
        await link.close()


def _attitude_frames(n: int, mav=None) -> tuple[list[bytes], object]:
    mav = mav or mavlink.MAVLink(None, 1, 1)
    frames = []
    for i in range(n):
        frames.append(mavlink.MAVLink_attitude_message(i + 1, 0, 0, 0, 0, 0, 0).pack(mav))
        mav.seq = (mav.seq + 1) % 256
    return frames, mav


def test_a_burst_of_lost_frames_over_128_is_loss_and_a_reordered_frame_is_not():
    from drivers.mavlink.receiver import MavlinkReceiver

    frames, _ = _attitude_frames(600)
    r = MavlinkReceiver()
    for i, f in enumerate(frames[:100] + frames[300:310]):  # 200 frames lost in one burst
        r.feed(f, 1000.0 + i * 1e-3)
    assert r.counters.seq_lost == 200  # counted as a restart of the sender's counter, this was 0
    r.feed(frames[305], 1000.2)  # a duplicate, 4 behind: no loss
    assert r.counters.seq_lost == 200
    r.feed(frames[400], 1003.0)  # after 2.8 s of silence the gap says nothing (a reboot restarts it)
    assert r.counters.seq_lost == 200 and r.counters.loss_percent == pytest.approx(100 * 200 / 312)


@async_test()
async def test_the_kernels_own_drops_are_counted_and_receive_times_are_the_kernels(monkeypatch):
    """A socket buffer far too small, a burst while the event loop is busy: the kernel drops
    datagrams, and says how many; the loss shown is at least that. Each datagram that got through
    carries its arrival time, not the time the busy loop came to read it."""
    from drivers.transports import UdpTransport

    monkeypatch.setattr(UdpTransport, "rcvbuf", 4096)
    port = free_udp_port()
    link = MavlinkLink(f"udpin:127.0.0.1:{port}", streams={})
    sub = link.measurements()
    await link.open()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        frames, _ = _attitude_frames(502)
        # one first: Linux switches receive timestamps on a moment after a socket asks for them
        sock.sendto(frames[0], ("127.0.0.1", port))
        await _take(sub, 1)
        t_sent = time.time()
        for f in frames[1:501]:  # the event loop is busy here: nobody reads
            sock.sendto(f, ("127.0.0.1", port))
        time.sleep(0.2)  # the loop stays busy a while longer; the datagrams wait in the kernel
        got = await _take(sub, 1)
        arrived = link.counters.by_type["ATTITUDE"] - 1
        assert 0 < arrived < 500
        # the kernel's count comes with the next datagram queued after the drops
        sock.sendto(frames[501], ("127.0.0.1", port))
        await _take(sub, 1)
        c = link.counters
        assert c.kernel_dropped == 500 - arrived
        assert c.lost == 500 - arrived  # by sequence fewer: a gap over 256 wraps
        assert got[0].t_rx < t_sent + 0.1  # as it arrived, not 0.2 s later when read
    finally:
        sock.close()
        await link.close()


@async_test(timeout=30)
async def test_254_forged_system_ids_are_counted_not_followed():
    """The audit's 254 forged system ids had each been asked for streams and given export files: a
    link follows at most MAX_VEHICLES vehicles and counts the rest."""
    from drivers.mavlink.link import MAX_VEHICLES

    port = free_udp_port()
    link = MavlinkLink(f"udpin:127.0.0.1:{port}", streams={"ATTITUDE": 10.0})
    last_heard = asyncio.Event()
    link.message_hooks.append(lambda m, _t: m._header.srcSystem == 254 and last_heard.set())
    await link.open()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for sysid in range(1, 255):
            enc = mavlink.MAVLink(None, sysid, 1)
            tx.sendto(bytes(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(enc)), ("127.0.0.1", port))
        await last_heard.wait()  # (the hooks run after the heartbeat is taken)
        assert len(link.vehicles) == MAX_VEHICLES and len(link.vehicles_ignored) == 254 - MAX_VEHICLES
    finally:
        tx.close()
        await link.close()


@async_test(timeout=30)
async def test_what_the_vehicle_says_is_on_the_event_line():
    """STATUSTEXT ("PreArm: Need 3D Fix", "Low Battery!") had been shown nowhere live."""
    port = free_udp_port()
    link = MavlinkLink(f"udpin:127.0.0.1:{port}")
    events = link.events()
    await link.open()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        enc = mavlink.MAVLink(None, 1, 1)
        tx.sendto(bytes(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(enc)), ("127.0.0.1", port))
        tx.sendto(
            bytes(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_WARNING, b"PreArm: Need 3D Fix").pack(enc)),
            ("127.0.0.1", port),
        )

        async def said():
            async for ev in events:
                if "says" in ev.reason:
                    return ev.reason

        reason = await asyncio.wait_for(said(), 10.0)
        assert reason == "vehicle 1 says (warning): PreArm: Need 3D Fix"
        assert list(link.status_texts) == [reason]
    finally:
        tx.close()
        await link.close()
